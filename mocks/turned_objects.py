"""Turned objects for the simulated world: a thrown vase with a boss, decorated bowls, a bare bowl.

Wheel-thrown and lathe-turned pieces are surfaces of revolution; their passes
differ only by a small feature or by decoration.  These meshes are the truth
for registration of nearly symmetric shapes (``kogei mock --world vase``,
``inlaid-bowl``, ``plain-bowl``, ``plain-bowl:bare``; docs/simulator.md,
section "Turned objects"):

* ``vase`` -- a closed vase (foot, belly, neck, dished mouth), 80 mm high and
  52 mm across, of ``urushi-red`` with a **boss**: a Gaussian bump of
  :data:`BOSS_HEIGHT_MM` (20 times the station's 0.05 mm range noise) and
  standard deviation :data:`BOSS_SIGMA_MM` on the belly, standing more than
  ten times the noise (0.5 mm) above the surface over about 55 mm^2
  (0.37 % of its 14 500 mm^2, about 0.7 % of what two passes share); and a
  **faint painted band** (``urushi-red:diffuse=0.6``, no relief) round the
  shoulder.
* ``inlaid-bowl`` -- a footed bowl 91 mm across and 40 mm high, ``urushi-red``,
  with a motif of ``urushi-black`` inlaid on its outer and inner walls,
  sunk :data:`INLAY_DEPTH_MM` (twice the range noise: shallow relief).
* ``plain-bowl`` -- the same bowl shape, perfectly symmetric, ``urushi-red``
  with the motif painted in ``urushi-black`` with no relief at all: ambiguous
  in shape, decided by colour only.  (A metal inlay would look black in the
  booth, which has no environment for it to mirror.)
* ``plain-bowl:bare`` -- the same bowl without any decoration: ambiguous in
  shape and in colour.

The mesh of a surface of revolution is a profile polyline ``(r, z)`` from the
axis back to the axis, resampled evenly along its length and revolved in
``segments`` steps; both ends are poles, so the mesh is closed and its
triangles face outward.  Regions are given per triangle from its centroid
(azimuth and height); the motif is an asymmetric set of ellipses on the
surface, so it fixes the turn about the axis.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "BOSS_HEIGHT_MM",
    "BOSS_SIGMA_MM",
    "INLAY_DEPTH_MM",
    "TURNED_OBJECTS",
    "TurnedMesh",
    "revolve",
    "turned_object",
]

#: Height of the vase's boss above the belly (mm): 20 times the station's range noise.
BOSS_HEIGHT_MM = 1.0
#: Standard deviation of the boss's Gaussian profile (mm).
BOSS_SIGMA_MM = 3.5
#: Depth by which the inlaid bowl's motif is sunk into the surface (mm): shallow relief.
INLAY_DEPTH_MM = 0.1
#: The turned objects by name.
TURNED_OBJECTS = ("vase", "inlaid-bowl", "plain-bowl", "plain-bowl:bare")


@dataclass(frozen=True)
class TurnedMesh:
    """A turned object: closed triangle mesh (mm, +z the turning axis) with regions.

    Attributes
    ----------
    vertices, triangles
        ``(V, 3)`` mm and ``(T, 3)`` indices, outward-facing.
    region
        ``(T,)`` region index per triangle.
    region_names
        Region names.
    materials
        Material spec per region name.
    feature_area_mm2
        Surface area of the shape feature standing more than 0.5 mm (ten
        times the station's range noise) off the surface of revolution; 0
        for a shape without one.
    """

    vertices: NDArray[np.float64]
    triangles: NDArray[np.int64]
    region: NDArray[np.int64]
    region_names: tuple[str, ...]
    materials: dict[str, str]
    feature_area_mm2: float


def revolve(profile_r_mm: ArrayLike, profile_z_mm: ArrayLike, segments: int) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """A closed surface of revolution about +z from a profile that starts and ends on the axis.

    Parameters
    ----------
    profile_r_mm, profile_z_mm
        ``(P,)`` profile, ``P >= 3``; the first and last radius are 0 (the
        poles), the others > 0.  The triangles are turned to face outward
        (positive signed volume) whichever way the profile runs.
    segments
        Steps round the axis (>= 3).

    Returns
    -------
    vertices, triangles
        ``(2 + (P - 2) segments, 3)`` mm and the triangles.

    Examples
    --------
    A cylinder 10 mm across and 5 mm high, closed by two discs:

    >>> v, t = revolve([0, 5, 5, 0], [0, 0, 5, 5], 8)
    >>> v.shape, t.shape
    ((18, 3), (32, 3))
    """
    r = np.asarray(profile_r_mm, dtype=np.float64)
    z = np.asarray(profile_z_mm, dtype=np.float64)
    if r.ndim != 1 or r.shape != z.shape or len(r) < 3 or r[0] != 0 or r[-1] != 0 or np.any(r[1:-1] <= 0):
        raise ValueError("profile: (P,) radii and heights, P >= 3, 0 at both ends and > 0 between")
    if segments < 3:
        raise ValueError(f"segments must be >= 3, got {segments}")
    rings = len(r) - 2
    phi = 2.0 * np.pi * np.arange(segments) / segments
    ring_v = np.stack([r[1:-1, None] * np.cos(phi), r[1:-1, None] * np.sin(phi),
                       np.broadcast_to(z[1:-1, None], (rings, segments))], axis=-1).reshape(-1, 3)
    vertices = np.concatenate([[[0.0, 0.0, z[0]]], ring_v, [[0.0, 0.0, z[-1]]]])
    k = np.arange(segments)
    k1 = (k + 1) % segments
    top = len(vertices) - 1
    tris = [np.stack([np.zeros(segments, np.int64), 1 + k1, 1 + k], axis=1)]
    i = np.arange(rings - 1)[:, None]
    a, b = 1 + i * segments + k, 1 + i * segments + k1
    c, d = a + segments, b + segments
    tris.append(np.stack([a, b, d], axis=-1).reshape(-1, 3))
    tris.append(np.stack([a, d, c], axis=-1).reshape(-1, 3))
    last = 1 + (rings - 1) * segments
    tris.append(np.stack([last + k, last + k1, np.full(segments, top)], axis=1))
    tri = np.concatenate(tris).astype(np.int64)
    a0, a1, a2 = vertices[tri[:, 0]], vertices[tri[:, 1]], vertices[tri[:, 2]]
    if np.sum(np.einsum("ij,ij->i", a0, np.cross(a1, a2))) < 0:   # signed volume: face outward
        tri = tri[:, ::-1].copy()
    return vertices, tri


def _resample(points: list[tuple[float, float]], step_mm: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A polyline resampled at about ``step_mm`` along its length (its corners kept)."""
    p = np.asarray(points, dtype=np.float64)
    out = [p[:1]]
    for a, b in zip(p[:-1], p[1:]):
        n = max(1, math.ceil(float(np.linalg.norm(b - a)) / step_mm))
        s = np.arange(1, n + 1)[:, None] / n
        out.append(a + s * (b - a))
    q = np.concatenate(out)
    return q[:, 0], q[:, 1]


def _vase_profile(step_mm: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Foot, belly, neck and a dished mouth (mm), bottom pole to top pole."""
    z = np.linspace(1.0, 78.0, 78)
    belly = 26.0 * np.exp(-0.5 * ((z - 30.0) / 17.0) ** 2)
    r = np.maximum(9.0 + 0.8 * (z - 60.0).clip(0, None), 6.0 + belly)  # flaring lip above the neck
    r = np.minimum(r, 26.5)
    pts = [(0.0, 0.5), (12.0, 0.0), (14.0, 0.5)] + list(zip(r.tolist(), z.tolist()))
    pts += [(r[-1] + 0.5, 79.0), (r[-1] - 1.0, 80.0), (0.0, 76.0)]
    return _resample(pts, step_mm)


def _bowl_profile(step_mm: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Foot ring, outer wall, rounded rim and inner wall of a bowl (mm), bottom pole to inner pole."""
    t = np.linspace(0.0, 1.0, 40)
    outer = [(19.0 + 26.0 * math.sin(0.5 * math.pi * s) ** 0.8, 5.0 + 33.0 * s ** 1.4) for s in t]
    inner = [(r - 3.0 * (1.0 - 0.1 * (1 - s)), z + 1.0) for (r, z), s in zip(outer[::-1], t[::-1])]
    pts = [(0.0, 2.0), (15.0, 2.0), (16.0, 0.0), (19.0, 0.0), (19.5, 3.0)] + outer[1:]
    pts += [(45.6, 39.0), (44.8, 40.0), (43.6, 39.6)]
    pts += [(r, z) for r, z in inner if r < 42.8 and z > 6.0] + [(0.0, 6.0)]
    return _resample(pts, step_mm)


def _motif(vertices: NDArray[np.float64], tris: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Triangles of the bowl's motif: an asymmetric group of ellipses (a large leaf, two small ones, a dot)."""
    c = vertices[tris].mean(axis=1)
    az = np.degrees(np.arctan2(c[:, 1], c[:, 0]))
    rr = np.linalg.norm(c[:, :2], axis=1)
    hit = np.zeros(len(c), dtype=bool)
    # (azimuth deg, height mm, half width along the surface mm, half height mm)
    for az0, z0, w, h in ((0.0, 24.0, 14.0, 8.0), (55.0, 16.0, 6.0, 4.0), (80.0, 30.0, 5.0, 3.0),
                          (200.0, 20.0, 3.0, 3.0)):
        d_az = (az - az0 + 180.0) % 360.0 - 180.0
        arc = np.radians(d_az) * rr
        hit |= (arc / w) ** 2 + ((c[:, 2] - z0) / h) ** 2 <= 1.0
    return hit


def _normals(vertices: NDArray[np.float64], tris: NDArray[np.int64]) -> NDArray[np.float64]:
    """Area-weighted vertex normals (outward for an outward-facing mesh)."""
    fn = np.cross(vertices[tris[:, 1]] - vertices[tris[:, 0]], vertices[tris[:, 2]] - vertices[tris[:, 0]])
    vn = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(vn, tris[:, k], fn)
    return vn / np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-12)


def _areas(vertices: NDArray[np.float64], tris: NDArray[np.int64]) -> NDArray[np.float64]:
    """Triangle areas (mm^2)."""
    e = np.cross(vertices[tris[:, 1]] - vertices[tris[:, 0]], vertices[tris[:, 2]] - vertices[tris[:, 0]])
    return 0.5 * np.linalg.norm(e, axis=1)


def turned_object(name: str, step_mm: float = 0.8) -> TurnedMesh:
    """One of :data:`TURNED_OBJECTS` as a mesh in millimetres, standing on ``z = 0``.

    Parameters
    ----------
    name
        ``"vase"``, ``"inlaid-bowl"``, ``"plain-bowl"`` or ``"plain-bowl:bare"``.
    step_mm
        Edge length of the profile and, at the widest radius, round the axis
        (mm); the default resolves the boss (sigma 3 mm) and the motif.

    Returns
    -------
    TurnedMesh
        The mesh, its regions and materials and the area of its shape feature.

    Raises
    ------
    ValueError
        An unknown name or a step that is not in (0, 5] mm.

    Examples
    --------
    >>> vase = turned_object("vase", step_mm=1.5)
    >>> vase.region_names, 45 < vase.feature_area_mm2 < 65
    (('body', 'band'), True)
    >>> bowl = turned_object("plain-bowl", step_mm=1.5)
    >>> bowl.materials, bowl.feature_area_mm2
    ({'body': 'urushi-red', 'motif': 'urushi-black'}, 0.0)
    """
    if name not in TURNED_OBJECTS:
        raise ValueError(f"unknown turned object {name!r}; choose one of {', '.join(TURNED_OBJECTS)}")
    if not (math.isfinite(step_mm) and 0 < step_mm <= 5):
        raise ValueError(f"step_mm must be in (0, 5] mm, got {step_mm!r}")
    r, z = _vase_profile(step_mm) if name == "vase" else _bowl_profile(step_mm)
    segments = max(24, math.ceil(2 * math.pi * float(r.max()) / step_mm))
    v, t = revolve(r, z, segments)
    feature = 0.0
    if name == "vase":
        n = _normals(v, t)
        centre = np.array([26.0, 0.0, 30.0])   # on the belly at azimuth 0
        bump = BOSS_HEIGHT_MM * np.exp(-0.5 * np.sum((v - centre) ** 2, axis=1) / BOSS_SIGMA_MM ** 2)
        v = v + n * bump[:, None]
        high = bump[t].mean(axis=1) > 0.5
        feature = float(_areas(v, t)[high].sum())
        shoulder = v[t].mean(axis=1)[:, 2]
        region = ((shoulder > 46.0) & (shoulder < 52.0)).astype(np.int64)
        return TurnedMesh(v, t, region, ("body", "band"),
                          {"body": "urushi-red", "band": "urushi-red:diffuse=0.6"}, feature)
    if name == "plain-bowl:bare":
        return TurnedMesh(v, t, np.zeros(len(t), np.int64), ("body",), {"body": "urushi-black"}, 0.0)
    motif = _motif(v, t)
    if name == "inlaid-bowl":
        inside = np.zeros(len(v), dtype=bool)
        inside[np.unique(t[motif])] = True
        inside[np.unique(t[~motif])] = False        # the motif's border stays on the surface
        v = v - _normals(v, t) * (INLAY_DEPTH_MM * inside)[:, None]
        return TurnedMesh(v, t, motif.astype(np.int64), ("body", "motif"),
                          {"body": "urushi-red", "motif": "urushi-black"}, 0.0)
    return TurnedMesh(v, t, motif.astype(np.int64), ("body", "motif"),
                      {"body": "urushi-red", "motif": "urushi-black"}, 0.0)
