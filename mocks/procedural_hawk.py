"""A procedural hawk's head: a closed, outward-oriented triangle mesh with
material regions.

The object of Matsuda et al. ("CG Reproduction of a Craft Object Based on a
Light Reflection Model", section 1) is the "Twelve Hawks" of the National
Museum of Modern Art, Tokyo: Meiji metalwork hawks in nami-shibuichi with a
beak of gold and urushi and copper eyes.  This module builds a stand-in for
such a head in code, as ground truth for the scanner simulation and as the
demo object of the renderer: a rounded skull on a neck cut flat at z = 0, a
hooked beak with a cere and nostrils, eyes under brow ridges and rows of
overlapping feathers.

Construction (vectorised; +z up, +x the way the beak points)

1. **Implicit shape.**  ``F(p) < 0`` inside: a smooth union (polynomial
   smooth minimum, Quilez 2013) of ellipsoids for cranium, face, snout and
   jaw, a flaring elliptic neck, two brow ridges, two eyeballs and a straight
   two-part beak (upper mandible longer than the lower), intersected with
   the half-space ``z >= 0`` (the neck cut).  ``F`` is star-shaped about a
   centre ``c`` inside the head: every ray from ``c`` crosses ``F = 0`` once.
2. **Parametrisation.**  The surface is ``c + r(d) d`` over unit directions
   ``d``, with ``r(d)`` the zero of ``F`` along the ray (Illinois regula falsi,
   bracketed from a tabulated radius).  The directions come from an
   equal-angle cube sphere (Ronchi, Iacono & Paolucci 1996) with ``12 n^2``
   triangles, mapped through a coarse grid of directions that is relaxed
   once (coarse to fine, tangential area-centroid smoothing on the surface,
   moves that would fold a triangle are undone) so that triangles have
   nearly equal area on the surface.  A radial graph over a triangulated
   sphere is an embedded closed surface: the mesh is a watertight two-manifold
   of genus 0 by construction.
3. **Relief.**  Feathers, nostrils and the gape line are displacements along
   the normal of the smooth surface, a few tenths of a millimetre deep.
   Feather rows are the level sets of ``log rho`` and columns the angle
   ``phi`` of a conformal bipolar map of the (relaxed, hence nearly
   isometric) parameter sphere, with poles at the beak and at the neck cut:
   rows circle the beak, feathers flow from the face over the crown and down
   the nape and throat, tips pointing backwards; front rows overlap the rows
   behind.  Feathers too small for the mesh to resolve fade out.
4. **Hooked beak.**  The half-space in front of the face (``x > x_s``) is bent
   downwards along a spine of increasing curvature ``kappa(s)`` (Barr 1984,
   "Global and local deformations of solid primitives", the bend).  The map
   ``(s, y, d) -> P(s) + d N(s) + y e_y`` has Jacobian ``1 + kappa(s) d`` > 0
   on the object, so it stays embedded; the upper mandible curls down in
   front of the tip of the lower one.
5. **Regions and normals.**  Vertices are labelled from the part of ``F`` they
   lie on (head, beak, cere, eye, pupil), triangles by majority; vertex normals
   are normalised sums of the incident area-weighted face normals.

The finished mesh is scaled to millimetres (about 67 mm from the beak to the
back of the neck, 75 mm high) and translated so that its lowest point lies on
``z = 0`` and its bounding box is centred on the z axis (the turntable axis).
The seed-independent tables (radius table, relaxed grid, feather layout) are
computed once per process and cached read-only.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import sparse

from processing.common.rotation import rotation_z

__all__ = [
    "HAWK_PRESET_TRIANGLES",
    "REGION_NAMES",
    "DEFAULT_MATERIALS",
    "HawkMesh",
    "hawk_head",
]

#: Triangle counts of the named presets (``draft`` / ``standard`` / ``reference``).
HAWK_PRESET_TRIANGLES: dict[str, int] = {
    "draft": 60_000,
    "standard": 250_000,
    "reference": 1_000_000,
}

#: Region labels; ``HawkMesh.region`` holds indices into this tuple.
REGION_NAMES: tuple[str, ...] = ("head", "beak", "cere", "eye", "pupil")

#: Material of each region (Matsuda et al.: nami-shibuichi body, gold and
#: urushi beak, copper eyes).
DEFAULT_MATERIALS: dict[str, str] = {
    "head": "nami-shibuichi",
    "beak": "gold",
    "cere": "urushi-black",
    "eye": "copper",
    "pupil": "urushi-black",
}

_MIN_TRIANGLES = 2_000
_MAX_TRIANGLES = 20_000_000

# ---------------------------------------------------------------------------
# Shape parameters, in model units (frame before the beak is bent); the
# finished mesh is scaled by _SCALE to millimetres.
# ---------------------------------------------------------------------------
_SCALE = 1.2
_CENTRE = np.array([0.0, 0.0, 40.0])  # rays start here, inside the head
_R_MAX = 80.0  # every ray leaves the object before this distance
_MARCH_STEP = 0.4  # step of the outermost-zero search along a ray

_CRANIUM_C = np.array([-4.0, 0.0, 48.0])
_CRANIUM_R = np.array([20.0, 15.5, 14.0])
_FACE_C = np.array([6.0, 0.0, 41.0])
_FACE_R = np.array([13.0, 12.5, 10.0])
_SNOUT_C = np.array([6.0, 0.0, 47.0])
_SNOUT_R = np.array([9.0, 8.0, 6.0])
_JAW_C = np.array([5.0, 0.0, 33.0])
_JAW_R = np.array([11.0, 9.5, 7.0])
_NECK_TOP = np.array([-6.0, 0.0, 36.0])
_NECK_BOTTOM = np.array([-4.0, 0.0, -5.0])
_NECK_R_TOP = np.array([11.5, 11.0])  # (across the axis in the x-z plane, along y)
_NECK_R_BOTTOM = np.array([17.5, 16.0])
_NECK_FLARE = 1.6  # radius grows as (fraction of the length) ** _NECK_FLARE

_BROW_C = np.array([8.0, 11.2, 51.5])  # ridge on the +y side; mirrored for -y
_BROW_R = np.array([9.5, 4.2, 3.2])
_BROW_YAW = np.deg2rad(24.0)
_BROW_PITCH = np.deg2rad(8.0)

_EYE_C = np.array([8.9, 8.36, 46.0])  # eyeball on the +y side; mirrored for -y
_EYE_R = 6.2
_EYE_AXIS = np.array([0.5, 0.85, 0.1]) / np.linalg.norm([0.5, 0.85, 0.1])
_PUPIL_HALF_ANGLE = np.deg2rad(24.0)

# beak: spine along +x at height _BEAK_Z; s = x - _BEND_X is the arc length
_BEND_X = 14.0
_BEAK_Z = 37.0
_BEAK_S0 = -12.0  # buried start of the beak inside the face
_UPPER_LEN = 21.0
_LOWER_LEN = 10.0
_CERE_LEN = 8.5  # the cere covers the upper mandible up to this s
_TIP_R = 0.45
_KAPPA0 = 0.03  # curvature of the spine: _KAPPA0 + _KAPPA1 (s / _UPPER_LEN) ** _KAPPA_POW
_KAPPA1 = 0.196
_KAPPA_POW = 2.0

_NOSTRIL_S = 7.0
_NOSTRIL_D = 4.0
_NOSTRIL_R = 1.1
_NOSTRIL_DEPTH = 0.7
_GAPE_FRONT = np.array([17.0, 35.6])  # (x, z) of the gape line at the beak ...
_GAPE_BACK = np.array([6.5, 36.8])  # ... and at the corner of the mouth, under the eye
_GAPE_WIDTH = 0.5
_GAPE_DEPTH = 0.35

# feathers
_FEATHER_ROW_LOG = 0.115  # row spacing in log rho near the beak (conformal part)
_FEATHER_ROW_MAX = 3.2  # largest row spacing (crown, nape, neck)
_FEATHER_ASPECT = 1.35  # feather width / row spacing
_FEATHER_BULGE = 0.7  # how far a tip bulges backwards, in rows (< 1)
_FEATHER_HEIGHT = 0.3  # step at the tip of a full-size feather
_FEATHER_POLE_BEAK = np.array([40.0, 0.0, 37.0])  # rows circle the beak ...
_FEATHER_POLE_NECK = np.array([-5.0, 0.0, 0.0])  # ... and the neck cut

# parametrisation: radius table, relaxed coarse grids
_TABLE_N = 64
_SEED_N = 16
_PARAM_N = 32
_RELAX_LEVELS = (8, 16, 32)
_RELAX_ITERATIONS = (300, 200, 100)
_RELAX_SHAPE = 0.15
_RELAX_STEP = 0.5
# the parameter cube sphere is turned 45 degrees about z: its corners (where
# triangles come out largest) lie in mirror pairs, away from the eyes
_PARAM_ROTATION = np.array([[np.sqrt(0.5), -np.sqrt(0.5), 0.0],
                            [np.sqrt(0.5), np.sqrt(0.5), 0.0],
                            [0.0, 0.0, 1.0]])


@dataclass
class HawkMesh:
    """A closed triangle mesh of a hawk's head with per-triangle regions.

    Attributes
    ----------
    vertices
        ``(V, 3)`` float64 positions in millimetres; +z up, the neck cut on
        ``z = 0``, centred on the z axis, the beak pointing to +x.
    triangles
        ``(T, 3)`` int32 vertex indices, counter-clockwise seen from outside.
    vertex_normals
        ``(V, 3)`` float64 unit outward normals.
    region
        ``(T,)`` uint8 index into ``region_names`` per triangle.
    region_names
        Names of the regions (``REGION_NAMES``).

    Examples
    --------
    >>> mesh = hawk_head(2_000)
    >>> mesh.vertices.shape[1], mesh.triangles.dtype.name, mesh.region_names[:2]
    (3, 'int32', ('head', 'beak'))
    """

    vertices: NDArray[np.float64]
    triangles: NDArray[np.int32]
    vertex_normals: NDArray[np.float64]
    region: NDArray[np.uint8]
    region_names: tuple[str, ...] = REGION_NAMES

    @property
    def n_triangles(self) -> int:
        """Number of triangles."""
        return int(self.triangles.shape[0])

    def region_mask(self, name: str) -> NDArray[np.bool_]:
        """Boolean ``(T,)`` mask of the triangles of region ``name``.

        Examples
        --------
        >>> mesh = hawk_head(2_000)
        >>> bool(mesh.region_mask("beak").any())
        True
        """
        if name not in self.region_names:
            raise ValueError(
                f"unknown region {name!r}; the regions are {', '.join(self.region_names)}"
            )
        return self.region == self.region_names.index(name)

    def to_open3d(self) -> Any:
        """An ``open3d.geometry.TriangleMesh`` with these vertices, triangles
        and normals (open3d is imported here, not at module import)."""
        import open3d as o3d

        mesh = o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(np.ascontiguousarray(self.vertices)),
            o3d.utility.Vector3iVector(np.ascontiguousarray(self.triangles, dtype=np.int32)),
        )
        mesh.vertex_normals = o3d.utility.Vector3dVector(
            np.ascontiguousarray(self.vertex_normals)
        )
        return mesh


# ---------------------------------------------------------------------------
# Small helpers
# ---------------------------------------------------------------------------
def _smin(a: NDArray, b: NDArray, k: float) -> NDArray:
    """Polynomial smooth minimum (Quilez); equals min(a, b) where |a-b| >= k."""
    h = np.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return b + (a - b) * h - k * h * (1.0 - h)


def _smax(a: NDArray, b: NDArray, k: float) -> NDArray:
    return -_smin(-a, -b, k)


def _smoothstep(e0: float, e1: float, x: NDArray) -> NDArray:
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _ellipsoid(x: NDArray, y: NDArray, z: NDArray, centre: NDArray, radii: NDArray) -> NDArray:
    """Distance bound to an axis-aligned ellipsoid (Quilez' k0 (k0-1)/k1)."""
    qx = (x - centre[0]) / radii[0]
    qy = (y - centre[1]) / radii[1]
    qz = (z - centre[2]) / radii[2]
    k0 = np.sqrt(qx * qx + qy * qy + qz * qz)
    qx /= radii[0]
    qy /= radii[1]
    qz /= radii[2]
    k1 = np.sqrt(qx * qx + qy * qy + qz * qz)
    return k0 * (k0 - 1.0) / np.maximum(k1, 1e-12)


def _rotation_zy(yaw: float, pitch: float) -> NDArray:
    """Rotation by ``pitch`` about y, then by ``yaw`` about z (radians): ``Rz(yaw) @ Ry(pitch)``."""
    cy, sy = np.cos(pitch), np.sin(pitch)
    ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    return rotation_z(yaw) @ ry


def _cross(a: NDArray, b: NDArray) -> NDArray:
    """Row-wise cross product of (N, 3) arrays."""
    out = np.empty_like(a)
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def _unit(v: NDArray) -> NDArray:
    return v / np.linalg.norm(v)


# world -> local rotation of the brow ridge on the +y side (mirrored for -y)
_BROW_ROT = _rotation_zy(-_BROW_YAW, _BROW_PITCH).T


# ---------------------------------------------------------------------------
# The implicit shape (frame before bending); negative inside
# ---------------------------------------------------------------------------
def _neck(x: NDArray, y: NDArray, z: NDArray) -> NDArray:
    axis = _NECK_BOTTOM - _NECK_TOP
    length = float(np.linalg.norm(axis))
    u = axis / length
    ex = _unit(np.cross(np.array([0.0, 1.0, 0.0]), u))
    rx, ry, rz = x - _NECK_TOP[0], y - _NECK_TOP[1], z - _NECK_TOP[2]
    t = rx * u[0] + ry * u[1] + rz * u[2]
    a = rx * ex[0] + ry * ex[1] + rz * ex[2]
    frac = np.clip(t / length, 0.0, 1.0) ** _NECK_FLARE
    ra = _NECK_R_TOP[0] + (_NECK_R_BOTTOM[0] - _NECK_R_TOP[0]) * frac
    rb = _NECK_R_TOP[1] + (_NECK_R_BOTTOM[1] - _NECK_R_TOP[1]) * frac
    q = np.sqrt((a / ra) ** 2 + (y / rb) ** 2)
    side = (q - 1.0) * np.minimum(ra, rb)
    return np.maximum(side, -t)  # open below (cut by z >= 0), capped at the top


def _brows(x: NDArray, ya: NDArray, z: NDArray) -> NDArray:
    dx, dy, dz = x - _BROW_C[0], ya - _BROW_C[1], z - _BROW_C[2]
    m = _BROW_ROT
    lx = m[0, 0] * dx + m[0, 1] * dy + m[0, 2] * dz
    ly = m[1, 0] * dx + m[1, 1] * dy + m[1, 2] * dz
    lz = m[2, 0] * dx + m[2, 1] * dy + m[2, 2] * dz
    return _ellipsoid(lx, ly, lz, np.zeros(3), _BROW_R)


def _head(x: NDArray, y: NDArray, z: NDArray) -> NDArray:
    """Skull, face, jaw, neck and brow ridges (no beak, no eyes)."""
    head = _smin(_ellipsoid(x, y, z, _CRANIUM_C, _CRANIUM_R),
                 _ellipsoid(x, y, z, _FACE_C, _FACE_R), 6.0)
    head = _smin(head, _ellipsoid(x, y, z, _SNOUT_C, _SNOUT_R), 4.0)
    head = _smin(head, _ellipsoid(x, y, z, _JAW_C, _JAW_R), 5.0)
    head = _smin(head, _neck(x, y, z), 8.0)
    return _smin(head, _brows(x, np.abs(y), z), 3.0)


def _beak_profiles(s: NDArray) -> tuple[NDArray, ...]:
    """Cross-section profiles (model units) of the upper and lower mandible at arc length s."""
    su = np.clip(s / _UPPER_LEN, 0.0, 1.0)
    sl = np.clip(s / _LOWER_LEN, 0.0, 1.0)
    up_top = -1.0 + 10.5 * (1.0 - su) ** 0.6
    up_bot = -2.0 + 1.2 * su
    up_w = 6.8 * (1.0 - su) ** 0.55
    lo_top = np.full_like(sl, -1.2)
    lo_bot = -1.2 - 5.0 * (1.0 - sl) ** 0.6
    lo_w = 5.3 * np.sqrt(1.0 - sl * sl)
    return up_top, up_bot, up_w, lo_top, lo_bot, lo_w


def _section(ya: NDArray, d: NDArray, top: NDArray, bot: NDArray, w: NDArray,
             narrow_top: float) -> NDArray:
    """Distance bound to an egg-shaped cross-section (wider at the bottom)."""
    half = np.maximum(0.5 * (top - bot), _TIP_R)
    dn = (d - 0.5 * (top + bot)) / half
    w_eff = np.maximum(w, _TIP_R) * (1.0 - narrow_top * np.clip(dn, -1.0, 1.0))
    q = np.sqrt((ya / w_eff) ** 2 + dn * dn)
    return (q - 1.0) * np.minimum(w_eff, half)


def _beak_parts(x: NDArray, ya: NDArray, z: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """Distance bounds of the upper and lower mandible, and the arc length s."""
    s = x - _BEND_X
    d = z - _BEAK_Z
    up_top, up_bot, up_w, lo_top, lo_bot, lo_w = _beak_profiles(s)
    upper = _section(ya, d, up_top, up_bot, up_w, 0.35)
    upper = np.maximum(_smax(upper, s - _UPPER_LEN, 0.4), _BEAK_S0 - s)
    lower = _section(ya, d, lo_top, lo_bot, lo_w, 0.0)
    lower = np.maximum(_smax(lower, s - _LOWER_LEN, 0.6), _BEAK_S0 - s)
    return upper, lower, s


def _nostril_centre() -> tuple[float, float, float]:
    up_top, up_bot, up_w, *_ = _beak_profiles(np.array([_NOSTRIL_S]))
    half = 0.5 * (up_top[0] - up_bot[0])
    dn = (_NOSTRIL_D - 0.5 * (up_top[0] + up_bot[0])) / half
    w_eff = up_w[0] * (1.0 - 0.35 * dn)
    y = w_eff * np.sqrt(max(1.0 - dn * dn, 0.0))
    return _BEND_X + _NOSTRIL_S, float(y), _BEAK_Z + _NOSTRIL_D


_NOSTRIL_C = np.array(_nostril_centre())


def _nostril_dent(p: NDArray) -> NDArray:
    """Inward displacement (model units) of the round nostril on each side of the cere."""
    dx = p[:, 0] - _NOSTRIL_C[0]
    dz = p[:, 2] - _NOSTRIL_C[2]
    q = (dx * dx + dz * dz) / (_NOSTRIL_R * _NOSTRIL_R)
    side = _smoothstep(0.3, 0.7, np.abs(p[:, 1]) / _NOSTRIL_C[1])
    return _NOSTRIL_DEPTH * side * np.clip(1.0 - q, 0.0, None) ** 2


def _gape_line(p: NDArray) -> NDArray:
    """0..1 weight of the gape line (mouth corner) on both sides of the face."""
    seg = _GAPE_BACK - _GAPE_FRONT
    rel_x = p[:, 0] - _GAPE_FRONT[0]
    rel_z = p[:, 2] - _GAPE_FRONT[1]
    t = np.clip((rel_x * seg[0] + rel_z * seg[1]) / (seg @ seg), 0.0, 1.0)
    dist2 = (rel_x - t * seg[0]) ** 2 + (rel_z - t * seg[1]) ** 2
    side = _smoothstep(2.0, 5.0, np.abs(p[:, 1]))
    return side * np.exp(-dist2 / (_GAPE_WIDTH * _GAPE_WIDTH)) * (1.0 - _smoothstep(0.85, 1.0, t))


def _eyes(x: NDArray, ya: NDArray, z: NDArray) -> NDArray:
    dx, dy, dz = x - _EYE_C[0], ya - _EYE_C[1], z - _EYE_C[2]
    return np.sqrt(dx * dx + dy * dy + dz * dz) - _EYE_R


def _field(x: NDArray, y: NDArray, z: NDArray, parts: bool = False) -> Any:
    """The implicit function F in the unbent frame (model units, negative inside).

    With ``parts=True`` returns ``(F, head, upper, lower, eyes, s)``.
    """
    ya = np.abs(y)
    head = _head(x, y, z)
    upper, lower, s = _beak_parts(x, ya, z)
    f = _smin(head, _smin(upper, lower, 0.5), 3.0)
    eyes = _eyes(x, ya, z)
    f = _smin(f, eyes, 0.8)
    f = _smax(f, -z, 1.0)
    if parts:
        return f, head, upper, lower, eyes, s
    return f


def _field_along(dirs: NDArray, r: NDArray) -> NDArray:
    """F at ``centre + r * dirs`` (r broadcast against the rows of dirs)."""
    return _field(_CENTRE[0] + r * dirs[..., 0], _CENTRE[1] + r * dirs[..., 1],
                  _CENTRE[2] + r * dirs[..., 2])


# ---------------------------------------------------------------------------
# Cube sphere
# ---------------------------------------------------------------------------
def _face_lattice(n: int) -> NDArray:
    """Integer lattice coordinates ``(6, n+1, n+1, 3)`` of the six cube faces.

    Face ``2 * axis + side`` lies on ``lattice[axis] == side * n``; its grid
    indices (i, j) run along the two other axes in increasing order.
    """
    i = np.arange(n + 1)
    a, b = np.meshgrid(i, i, indexing="ij")
    faces = []
    for axis in range(3):
        others = [k for k in range(3) if k != axis]
        for side in (0, n):
            c = np.empty((n + 1, n + 1, 3), dtype=np.int64)
            c[..., axis] = side
            c[..., others[0]] = a
            c[..., others[1]] = b
            faces.append(c)
    return np.stack(faces)


def _lattice_directions(lattice: NDArray, n: int) -> NDArray:
    """Unit directions of cube-lattice points (equal-angle mapping)."""
    t = np.tan(0.25 * np.pi * (2.0 * lattice.astype(np.float64) / n - 1.0))
    t[lattice == 0] = -1.0
    t[lattice == n] = 1.0
    return t / np.linalg.norm(t, axis=-1, keepdims=True)


def _cube_sphere(n: int) -> tuple[NDArray, NDArray, NDArray]:
    """Closed cube-sphere triangulation with ``12 n^2`` triangles.

    Returns unit directions ``(V, 3)`` (turned by ``_PARAM_ROTATION``), outward
    triangles ``(T, 3)`` and the face-grid address ``(V, 3)`` = (face, i, j) of
    every vertex (one of its faces for vertices on cube edges).
    """
    lattice = _face_lattice(n)
    keys = (lattice[..., 0] * (n + 1) + lattice[..., 1]) * (n + 1) + lattice[..., 2]
    _, first, inverse = np.unique(keys.ravel(), return_index=True, return_inverse=True)
    ids = inverse.reshape(6, n + 1, n + 1)
    dirs = _lattice_directions(lattice.reshape(-1, 3)[first], n) @ _PARAM_ROTATION.T
    address = np.stack(np.unravel_index(first, (6, n + 1, n + 1)), axis=-1)
    # quads (i, j)-(i+1, j)-(i+1, j+1)-(i, j+1) turn counter-clockwise about
    # e_i x e_j, which points outwards on faces +x, -y and +z; transpose the rest
    flip = np.array([True, False, False, True, True, False])
    ids = np.where(flip[:, None, None], ids.transpose(0, 2, 1), ids)
    a = ids[:, :-1, :-1].ravel()
    b = ids[:, 1:, :-1].ravel()
    c = ids[:, 1:, 1:].ravel()
    d = ids[:, :-1, 1:].ravel()
    tris = np.concatenate([np.stack([a, b, c], -1), np.stack([a, c, d], -1)])
    return dirs, tris, address


def _spherical_orientation(dirs: NDArray, tris: NDArray) -> NDArray:
    """Positive for triangles counter-clockwise seen from outside the sphere."""
    p0, p1, p2 = dirs[tris[:, 0]], dirs[tris[:, 1]], dirs[tris[:, 2]]
    return np.einsum("ij,ij->i", _cross(p1 - p0, p2 - p0), p0 + p1 + p2)


def _face_coordinates(dirs: NDArray, n: int) -> tuple[NDArray, NDArray, NDArray]:
    """Face index and continuous grid coordinates (0..n) of unit directions."""
    ad = np.abs(dirs)
    axis = np.argmax(ad, axis=1)
    rows = np.arange(len(dirs))
    main = dirs[rows, axis]
    face = 2 * axis + (main > 0.0)
    o1 = np.where(axis == 0, 1, 0)
    o2 = np.where(axis == 2, 1, 2)
    scale = 1.0 / np.abs(main)
    gi = (np.arctan(dirs[rows, o1] * scale) / (0.25 * np.pi) + 1.0) * (0.5 * n)
    gj = (np.arctan(dirs[rows, o2] * scale) / (0.25 * np.pi) + 1.0) * (0.5 * n)
    return face, gi, gj


def _bilinear(grid: NDArray, face: NDArray, gi: NDArray, gj: NDArray) -> NDArray:
    """Bilinear interpolation of per-face grids ``(6, n+1, n+1)``."""
    n = grid.shape[1] - 1
    i0 = np.clip(np.floor(gi).astype(np.int64), 0, n - 1)
    j0 = np.clip(np.floor(gj).astype(np.int64), 0, n - 1)
    fi = gi - i0
    fj = gj - j0
    return ((1.0 - fi) * (1.0 - fj) * grid[face, i0, j0] + fi * (1.0 - fj) * grid[face, i0 + 1, j0]
            + (1.0 - fi) * fj * grid[face, i0, j0 + 1] + fi * fj * grid[face, i0 + 1, j0 + 1])


# ---------------------------------------------------------------------------
# Surface radius along rays from the centre
# ---------------------------------------------------------------------------
def _march(dirs: NDArray, chunk: int = 1024) -> tuple[NDArray, NDArray]:
    """Bracket the outermost zero of F along each ray by stepping inwards."""
    radii = np.arange(_R_MAX, 0.0, -_MARCH_STEP)
    lo = np.empty(len(dirs))
    hi = np.empty(len(dirs))
    for start in range(0, len(dirs), chunk):
        d = dirs[start:start + chunk, None, :]
        inside = _field_along(d, radii[None, :]) <= 0.0
        if inside[:, 0].any() or not inside.any(axis=1).all():
            raise RuntimeError("procedural hawk: the shape does not fit the ray-marching range")
        k = np.argmax(inside, axis=1)
        lo[start:start + chunk] = radii[k]
        hi[start:start + chunk] = radii[k - 1]
    return lo, hi


def _solve(dirs: NDArray, lo: NDArray, hi: NDArray, f_lo: NDArray, f_hi: NDArray,
           iterations: int = 7) -> NDArray:
    """Zero of F(c + r d) in [lo, hi] (F(lo) <= 0 < F(hi)) by the Illinois method."""
    last = np.zeros(len(dirs), dtype=np.int8)
    r = lo
    for _ in range(iterations):
        r = lo + (hi - lo) * (f_lo / (f_lo - f_hi))
        f = _field_along(dirs, r)
        inside = f <= 0.0
        f_hi = np.where(inside & (last == 1), 0.5 * f_hi, f_hi)
        f_lo = np.where(~inside & (last == -1), 0.5 * f_lo, f_lo)
        lo = np.where(inside, r, lo)
        f_lo = np.where(inside, f, f_lo)
        hi = np.where(inside, hi, r)
        f_hi = np.where(inside, f_hi, f)
        last = np.where(inside, 1, -1).astype(np.int8)
    return lo + (hi - lo) * (f_lo / (f_lo - f_hi))


def _radius(dirs: NDArray, guess: NDArray | None = None, iterations: int = 5) -> NDArray:
    """Radius of the surface along ``dirs``, bracketed around ``guess`` (or by marching)."""
    lo = np.empty(len(dirs))
    hi = np.empty(len(dirs))
    f_lo = np.empty(len(dirs))
    f_hi = np.empty(len(dirs))
    todo = np.ones(len(dirs), dtype=bool)
    if guess is not None:
        for width in (0.3, 1.5):
            idx = np.flatnonzero(todo)
            l, h = guess[idx] - width, guess[idx] + width
            fl, fh = _field_along(dirs[idx], l), _field_along(dirs[idx], h)
            ok = (fl <= 0.0) & (fh > 0.0)
            lo[idx[ok]], hi[idx[ok]], f_lo[idx[ok]], f_hi[idx[ok]] = l[ok], h[ok], fl[ok], fh[ok]
            todo[idx[ok]] = False
    if todo.any():
        idx = np.flatnonzero(todo)
        lo[idx], hi[idx] = _march(dirs[idx])
        f_lo[idx] = _field_along(dirs[idx], lo[idx])
        f_hi[idx] = _field_along(dirs[idx], hi[idx])
    return _solve(dirs, lo, hi, f_lo, f_hi, iterations)


@lru_cache(maxsize=1)
def _parametrisation() -> tuple[NDArray, NDArray]:
    """Radius table and relaxed coarse parameter grid (independent of the seed).

    Returns the surface radius on the face grids of a ``_TABLE_N`` cube sphere,
    ``(6, n+1, n+1)``, and unit directions ``(6, m+1, m+1, 3)`` on the face
    grids of a ``_PARAM_N`` cube sphere, relaxed (``_relax``, coarse to fine
    over ``_RELAX_LEVELS``) so that their surface triangles have nearly equal
    areas.
    """
    seed_dirs = _lattice_directions(_face_lattice(_SEED_N).reshape(-1, 3), _SEED_N)
    seed = _radius(seed_dirs).reshape(6, _SEED_N + 1, _SEED_N + 1)
    table_dirs = _lattice_directions(_face_lattice(_TABLE_N).reshape(-1, 3), _TABLE_N)
    face, gi, gj = _face_coordinates(table_dirs, _SEED_N)
    table = _radius(table_dirs, _bilinear(seed, face, gi, gj)).reshape(6, _TABLE_N + 1, -1)

    grid = None
    for level, iterations in zip(_RELAX_LEVELS, _RELAX_ITERATIONS):
        dirs, tris, address = _cube_sphere(level)
        if grid is not None:
            scale = (grid.shape[1] - 1) / level
            dirs = _piecewise_linear(grid, address, scale)
        dirs = _relax(dirs, tris, table, iterations)
        grid = dirs[_cube_sphere_ids(level)]
    if (_spherical_orientation(dirs, tris) <= 0.0).any():
        raise RuntimeError("procedural hawk: the relaxed parametrisation folded")
    table.flags.writeable = False
    grid.flags.writeable = False
    return table, grid


def _relax(dirs: NDArray, tris: NDArray, table: NDArray, iterations: int) -> NDArray:
    """Move directions so that their surface points spread evenly.

    Each step moves every surface point part of the way towards a blend of
    the area-weighted centroid of its incident triangles (which evens out
    triangle areas) and the mean of its neighbours (which keeps triangles
    well shaped), keeps the tangential part of that move, and projects back
    onto the surface along the ray.  Moves that would fold a triangle are
    undone.
    """
    nv, nt = len(dirs), len(tris)
    corner_of = sparse.csr_matrix(
        (np.ones(3 * nt), (tris.T.ravel(), np.tile(np.arange(nt), 3))), shape=(nv, nt))
    edges = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    mean_of = sparse.csr_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(nv, nv))
    mean_of = sparse.diags(1.0 / np.asarray(mean_of.sum(axis=1)).ravel()) @ mean_of
    for _ in range(iterations):
        face, gi, gj = _face_coordinates(dirs, _TABLE_N)
        p = _CENTRE + _bilinear(table, face, gi, gj)[:, None] * dirs
        p0, p1, p2 = p[tris[:, 0]], p[tris[:, 1]], p[tris[:, 2]]
        fn = _cross(p1 - p0, p2 - p0)
        area = np.sqrt(np.einsum("ij,ij->i", fn, fn))
        acc = corner_of @ np.column_stack([area[:, None] * (p0 + p1 + p2), area, fn])
        centroid = acc[:, :3] / (3.0 * acc[:, 3:4])
        normal = acc[:, 4:] / np.linalg.norm(acc[:, 4:], axis=1, keepdims=True)
        move = (1.0 - _RELAX_SHAPE) * centroid + _RELAX_SHAPE * (mean_of @ p) - p
        # keep only the tangential part: a normal offset would drift along oblique rays
        move -= np.einsum("ij,ij->i", move, normal)[:, None] * normal
        target = p + _RELAX_STEP * move - _CENTRE
        new = target / np.linalg.norm(target, axis=1, keepdims=True)
        # never fold: vertices of triangles that would flip keep their old direction
        while True:
            flipped = _spherical_orientation(new, tris) <= 0.0
            if not flipped.any():
                break
            keep = np.unique(tris[flipped])
            new[keep] = dirs[keep]
        dirs = new
    return dirs


def _piecewise_linear(grid: NDArray, address: NDArray, scale: float) -> NDArray:
    """Directions at face-grid addresses, linear on the triangles of a coarser
    cube sphere whose face grids hold ``grid`` ``(6, m+1, m+1, 3)``.

    ``scale`` converts the addresses' grid index to the coarse grid index.
    Each coarse quad (i, j) is split along its (i, j)-(i+1, j+1) diagonal as
    in ``_cube_sphere``, so a valid coarse triangulation maps to a valid
    refinement.
    """
    m = grid.shape[1] - 1
    gi = address[:, 1] * scale
    gj = address[:, 2] * scale
    f = address[:, 0]
    i0 = np.clip(np.floor(gi).astype(np.int64), 0, m - 1)
    j0 = np.clip(np.floor(gj).astype(np.int64), 0, m - 1)
    fi = (gi - i0)[:, None]
    fj = (gj - j0)[:, None]
    a = grid[f, i0, j0]
    c = grid[f, i0 + 1, j0 + 1]
    lower = fi >= fj  # triangle (a, b, c) with b = (i+1, j); else (a, c, d), d = (i, j+1)
    other = np.where(lower, grid[f, i0 + 1, j0], grid[f, i0, j0 + 1])
    w_a = np.where(lower, 1.0 - fi, 1.0 - fj)
    w_c = np.where(lower, fj, fi)
    w_o = np.where(lower, fi - fj, fj - fi)
    dirs = w_a * a + w_c * c + w_o * other
    return dirs / np.linalg.norm(dirs, axis=1, keepdims=True)


def _cube_sphere_ids(n: int) -> NDArray:
    """Vertex index ``(6, n+1, n+1)`` of every face-grid point of ``_cube_sphere(n)``."""
    lattice = _face_lattice(n)
    keys = (lattice[..., 0] * (n + 1) + lattice[..., 1]) * (n + 1) + lattice[..., 2]
    _, inverse = np.unique(keys.ravel(), return_inverse=True)
    return inverse.reshape(6, n + 1, n + 1)


# ---------------------------------------------------------------------------
# Feather relief
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class _FeatherLayout:
    frame: tuple[NDArray, NDArray, NDArray, complex]  # neck pole, e1, e2, w of beak pole
    scale: float  # surface length (model units) per unit of parameter-sphere length
    ell: NDArray  # log rho at the knots
    u: NDArray  # row coordinate at the knots
    slope: NDArray  # du / d log rho at the knots
    row0: int  # first row index
    columns: NDArray  # feathers per row, rows row0, row0 + 1, ...


def _feather_coordinates(q: NDArray, frame: tuple) -> tuple[NDArray, NDArray, NDArray]:
    """Bipolar coordinates ``(log rho, phi, k)`` of parameter directions ``q``.

    ``w`` is the stereographic projection of ``q`` from the neck pole and
    ``w - w_b = rho exp(i phi)`` with ``w_b`` the image of the beak pole.  The
    map is conformal; ``k`` is the length on the unit sphere of one unit of
    ``log rho`` (and of one radian of ``phi``).
    """
    n, e1, e2, wb = frame
    denom = np.maximum(1.0 - q @ n, 1e-9)
    wx = (q @ e1) / denom - wb.real
    wy = (q @ e2) / denom - wb.imag
    rho = np.maximum(np.hypot(wx, wy), 1e-12)
    return np.log(rho), np.arctan2(wy, wx), denom * rho


@lru_cache(maxsize=1)
def _feather_layout() -> _FeatherLayout:
    """Feather rows and columns on the parameter sphere.

    The relaxed parametrisation spreads the surface evenly over the parameter
    sphere, so lengths there are surface lengths up to one ``scale``.  The
    poles are the parameter directions of the beak and of the neck cut.  Rows
    are conformal (spacing ``_FEATHER_ROW_LOG`` in log rho) where that makes
    them smaller than ``_FEATHER_ROW_MAX``, i.e. around the beak; beyond, and
    down the neck where the conformal grid would shrink again, the row
    spacing is held at the largest size reached.
    """
    table, grid = _parametrisation()
    q = _lattice_directions(_face_lattice(_PARAM_N), _PARAM_N).reshape(-1, 3) @ _PARAM_ROTATION.T
    d = grid.reshape(-1, 3)
    face, gi, gj = _face_coordinates(d, _TABLE_N)
    p = _CENTRE + _bilinear(table, face, gi, gj)[:, None] * d
    _, tris, _ = _cube_sphere(_PARAM_N)
    ids = _cube_sphere_ids(_PARAM_N).ravel()
    pv = np.zeros((ids.max() + 1, 3))
    pv[ids] = p
    area = 0.5 * np.linalg.norm(np.cross(pv[tris[:, 1]] - pv[tris[:, 0]],
                                         pv[tris[:, 2]] - pv[tris[:, 0]]), axis=1).sum()
    scale = float(np.sqrt(area / (4.0 * np.pi)))
    n = q[np.argmax(d @ _unit(_FEATHER_POLE_NECK - _CENTRE))]
    b = q[np.argmax(d @ _unit(_FEATHER_POLE_BEAK - _CENTRE))]
    e1 = _unit(b - (b @ n) * n)
    e2 = np.cross(n, e1)
    frame = (n, e1, e2, complex(b @ e1, b @ e2) / (1.0 - b @ n))

    ell, _, k = _feather_coordinates(q, frame)
    order = np.argsort(ell)
    chunks = np.array_split(order, 48)
    knots = np.array([ell[c].mean() for c in chunks])
    ring = scale * np.array([np.median(k[c]) for c in chunks])  # surface length per unit of log rho
    row_len = np.minimum(_FEATHER_ROW_MAX, _FEATHER_ROW_LOG * np.maximum.accumulate(ring))
    slope = ring / row_len
    u = np.concatenate([[0.0], np.cumsum(0.5 * (slope[1:] + slope[:-1]) * np.diff(knots))])
    row0 = int(np.floor(u[0])) - 3
    rows = np.arange(row0, int(np.ceil(u[-1])) + 4)
    ell_rows = _extrapolated(rows.astype(np.float64), u, knots, 1.0 / slope[0], 1.0 / slope[-1])
    ring_rows = np.interp(ell_rows, knots, ring)
    len_rows = np.interp(ell_rows, knots, row_len)
    columns = np.maximum(np.round(2.0 * np.pi * ring_rows / (_FEATHER_ASPECT * len_rows)), 8)
    for arr in (n, e1, e2, knots, u, slope, columns):
        arr.flags.writeable = False
    return _FeatherLayout(frame, scale, knots, u, slope, row0, columns.astype(np.int64))


def _extrapolated(x: NDArray, xp: NDArray, fp: NDArray, left: float, right: float) -> NDArray:
    """np.interp continued linearly with the given end slopes."""
    y = np.interp(x, xp, fp)
    y = np.where(x < xp[0], fp[0] + (x - xp[0]) * left, y)
    return np.where(x > xp[-1], fp[-1] + (x - xp[-1]) * right, y)


def _feather_height(q: NDArray, edge: float, seed: int) -> NDArray:
    """Feather relief height (model units) at parameter directions ``q``.

    Rows ``j`` of feathers are bounded by the outlines ``u = U_j(v)``: arcs
    bulging backwards (towards the neck) between the tips of neighbouring
    feathers, alternate rows offset by half a feather.  A point belongs to the
    frontmost row whose outline lies behind it (front feathers overlap the
    ones behind); its height rises from the previous outline to its own and
    drops at the tip.  Feathers that the mesh (mean edge ``edge``) cannot
    resolve fade out.
    """
    layout = _feather_layout()
    n_rows = len(layout.columns)
    rng = np.random.default_rng(seed)
    phase = rng.uniform(-0.2, 0.2, n_rows)
    gain = rng.uniform(0.7, 1.3, (n_rows, int(layout.columns.max())))
    bulge = _FEATHER_BULGE * rng.uniform(0.85, 1.0, n_rows)

    ell, phi, k = _feather_coordinates(q, layout.frame)
    u = _extrapolated(ell, layout.ell, layout.u, layout.slope[0], layout.slope[-1])
    turns = phi / (2.0 * np.pi)

    def across(j: NDArray) -> tuple[NDArray, NDArray]:
        jj = np.clip(j - layout.row0, 0, n_rows - 1)
        t = turns * layout.columns[jj] - 0.5 * np.mod(j, 2) - phase[jj]
        return t, jj

    def outline(j: NDArray) -> NDArray:
        t, jj = across(j)
        fr = t - np.floor(t)
        return j + 1.0 + bulge[jj] * (1.0 - 4.0 * (fr - 0.5) ** 2)

    j = np.floor(u).astype(np.int64)
    j = np.where(outline(j - 1) > u, j - 1, j)  # the frontmost row covering the point
    top = outline(j)
    bottom = outline(j - 1)
    t = np.clip((u - bottom) / (top - bottom), 0.0, 1.0)
    tv, jj = across(j)
    col = np.mod(np.floor(tv).astype(np.int64), layout.columns[jj])
    lateral = tv - np.floor(tv)  # 0..1 across the feather, 0.5 on its shaft
    g = 1.0 + (gain[jj, col] - 1.0) * np.sin(np.pi * lateral) ** 2
    profile = t**0.8 * (1.0 - _smoothstep(0.86, 1.0, t))
    shaft = 0.3 * t * np.exp(-(((lateral - 0.5) / 0.06) ** 2))
    # local row spacing on the surface; small feathers are shallower, unresolved ones fade
    slope = np.interp(ell, layout.ell, layout.slope)
    row_len = layout.scale * k / slope
    size = np.clip(row_len / _FEATHER_ROW_MAX, 0.0, 1.0)
    resolve = _smoothstep(2.5 * edge, 5.0 * edge, row_len)
    return _FEATHER_HEIGHT * size * resolve * g * (profile + shaft)


def _relief_mask(upper: NDArray, lower: NDArray, eyes: NDArray, z: NDArray) -> NDArray:
    """1 on feathered skin, 0 on the beak, eyes, bare eye ring and neck cut."""
    beak = np.minimum(upper, lower)
    return (_smoothstep(0.5, 2.5, beak) * _smoothstep(1.0, 2.2, eyes)
            * _smoothstep(0.5, 3.0, z))


# ---------------------------------------------------------------------------
# Bending the beak
# ---------------------------------------------------------------------------
@lru_cache(maxsize=1)
def _bend_table() -> tuple[NDArray, NDArray, NDArray, NDArray]:
    s = np.linspace(0.0, _R_MAX, 8001)
    kappa = (_KAPPA0 * _smoothstep(0.0, 4.0, s)
             + _KAPPA1 * np.clip(s / _UPPER_LEN, 0.0, 1.0) ** _KAPPA_POW)
    ds = np.diff(s)
    theta = np.concatenate([[0.0], np.cumsum(0.5 * (kappa[1:] + kappa[:-1]) * ds)])
    c = np.cos(theta)
    sn = np.sin(theta)
    px = _BEND_X + np.concatenate([[0.0], np.cumsum(0.5 * (c[1:] + c[:-1]) * ds)])
    pz = _BEAK_Z - np.concatenate([[0.0], np.cumsum(0.5 * (sn[1:] + sn[:-1]) * ds)])
    for a in (s, theta, px, pz):
        a.flags.writeable = False
    return s, theta, px, pz


def _bend(p: NDArray) -> NDArray:
    """Bend the half-space x > _BEND_X downwards along the beak spine."""
    s_tab, th_tab, px_tab, pz_tab = _bend_table()
    out = p.copy()
    m = p[:, 0] > _BEND_X
    s = p[m, 0] - _BEND_X
    d = p[m, 2] - _BEAK_Z
    th = np.interp(s, s_tab, th_tab)
    out[m, 0] = np.interp(s, s_tab, px_tab) + d * np.sin(th)
    out[m, 2] = np.interp(s, s_tab, pz_tab) + d * np.cos(th)
    return out


# ---------------------------------------------------------------------------
# Regions and normals
# ---------------------------------------------------------------------------
def _vertex_labels(p: NDArray, head: NDArray, upper: NDArray, lower: NDArray,
                   eyes: NDArray, s: NDArray) -> NDArray:
    labels = np.zeros(len(p), dtype=np.uint8)
    beak = np.minimum(upper, lower)
    on_beak = (beak < head) & (beak < 0.4)
    labels[on_beak] = REGION_NAMES.index("beak")
    labels[on_beak & (upper <= lower) & (s < _CERE_LEN)] = REGION_NAMES.index("cere")
    on_eye = eyes < 0.15
    axis_y = _EYE_AXIS[1] * np.sign(p[:, 1])
    rel = p - _EYE_C * np.stack([np.ones(len(p)), np.sign(p[:, 1]), np.ones(len(p))], axis=-1)
    dist = np.maximum(np.linalg.norm(rel, axis=1), 1e-12)
    cos_a = (rel[:, 0] * _EYE_AXIS[0] + rel[:, 1] * axis_y + rel[:, 2] * _EYE_AXIS[2]) / dist
    labels[on_eye] = REGION_NAMES.index("eye")
    labels[on_eye & (cos_a > np.cos(_PUPIL_HALF_ANGLE))] = REGION_NAMES.index("pupil")
    return labels


def _triangle_labels(vertex_labels: NDArray, tris: NDArray) -> NDArray:
    """Majority of the three vertex labels (the largest index if all differ)."""
    a, b, c = (vertex_labels[tris[:, k]] for k in range(3))
    return np.where((a == b) | (a == c), a, np.where(b == c, b, np.maximum(np.maximum(a, b), c)))


def _vertex_normals(vertices: NDArray, triangles: NDArray) -> NDArray:
    """Unit vertex normals: normalised sums of the incident (area-weighted) face normals."""
    v0 = vertices[triangles[:, 0]]
    fn = _cross(vertices[triangles[:, 1]] - v0, vertices[triangles[:, 2]] - v0)
    idx = triangles.T.ravel()
    n = len(vertices)
    acc = np.stack([np.bincount(idx, weights=np.tile(fn[:, k], 3), minlength=n)
                    for k in range(3)], axis=-1)
    return acc / np.linalg.norm(acc, axis=1, keepdims=True)


# ---------------------------------------------------------------------------
# Public entry point
# ---------------------------------------------------------------------------
def hawk_head(triangles: int = 250_000, *, seed: int = 0) -> HawkMesh:
    """Build the procedural hawk's head with about ``triangles`` triangles.

    Parameters
    ----------
    triangles
        Requested number of triangles (2 000 to 20 000 000).  The mesh has
        ``12 n^2`` triangles with ``n = round(sqrt(triangles / 12))``: within
        about ``sqrt(12 / triangles)`` of the request (< 8 % at 2 000,
        1.5 % at the draft preset).  See ``HAWK_PRESET_TRIANGLES``.
    seed
        Seed of the small random variations of the feathers (row phase,
        height, tip shape); the same seed gives the same mesh.

    Returns
    -------
    HawkMesh
        Closed, outward-oriented mesh in millimetres on the ``z = 0`` plane.

    Examples
    --------
    >>> mesh = hawk_head(HAWK_PRESET_TRIANGLES["draft"] // 20)
    >>> mesh.n_triangles
    3072
    >>> float(mesh.vertices[:, 2].min())
    0.0
    """
    if isinstance(triangles, (bool, np.bool_)) or not isinstance(triangles, (int, np.integer)):
        raise TypeError(
            f"hawk_head: triangles must be an integer count, got {triangles!r}; "
            f"use e.g. HAWK_PRESET_TRIANGLES['draft'] ({HAWK_PRESET_TRIANGLES['draft']})"
        )
    if not _MIN_TRIANGLES <= triangles <= _MAX_TRIANGLES:
        raise ValueError(
            f"hawk_head: triangles must be between {_MIN_TRIANGLES} and {_MAX_TRIANGLES}, "
            f"got {triangles}"
        )
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)):
        raise TypeError(f"hawk_head: seed must be an integer, got {seed!r}")
    if seed < 0:
        raise ValueError(f"hawk_head: seed must be >= 0, got {seed}")

    table, grid = _parametrisation()
    n = int(round(np.sqrt(triangles / 12.0)))
    q, tris, address = _cube_sphere(n)
    dirs = _piecewise_linear(grid, address, _PARAM_N / n)
    if (_spherical_orientation(dirs, tris) <= 0.0).any():
        raise RuntimeError("procedural hawk: the parametrisation folded")
    face, gi, gj = _face_coordinates(dirs, _TABLE_N)
    radius = _radius(dirs, _bilinear(table, face, gi, gj))
    base = _CENTRE + radius[:, None] * dirs

    # feather relief (and the nostrils)
    fn = _cross(base[tris[:, 1]] - base[tris[:, 0]], base[tris[:, 2]] - base[tris[:, 0]])
    mean_area = 0.5 * float(np.sqrt(np.einsum("ij,ij->i", fn, fn)).mean())
    edge = float(np.sqrt(4.0 * mean_area / np.sqrt(3.0)))  # of an equilateral triangle
    _, head, upper, lower, eyes, s = _field(base[:, 0], base[:, 1], base[:, 2], parts=True)
    height = _feather_height(q, edge, seed) * _relief_mask(upper, lower, eyes, base[:, 2])
    gape = _gape_line(base)
    height = height * (1.0 - gape) - _nostril_dent(base) - _GAPE_DEPTH * gape
    labels = _triangle_labels(_vertex_labels(base, head, upper, lower, eyes, s), tris)

    # relief along the normal of the smooth surface
    vertices = _SCALE * _bend(base + height[:, None] * _vertex_normals(base, tris))
    vertices[:, 2] -= vertices[:, 2].min()
    lo = vertices[:, :2].min(axis=0)
    hi = vertices[:, :2].max(axis=0)
    vertices[:, :2] -= 0.5 * (lo + hi)
    triangles_out = tris.astype(np.int32)
    normals = _vertex_normals(vertices, triangles_out)
    return HawkMesh(vertices, triangles_out, normals, labels)
