"""Gathering a region's observations for the forward fit (private helper of :mod:`.forward_fit`).

The observations of a set of vertices (CSR slices of :class:`Observations`), their
angles to the normal, the point lamp's relative irradiance and an optional shadow
test toward the lamp by Open3D ray casting.
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.errors import InputError

__all__ = ["RegionSamples", "FitError", "region_samples", "HIGHLIGHT_DEG"]

#: An observation within this angle of the mirror direction (normal to half vector) sees a highlight.
HIGHLIGHT_DEG = 15.0


class FitError(InputError):
    """Bad input to the forward fit; the message names the argument and what to give."""


@dataclass(frozen=True)
class RegionSamples:
    """The lit, unclipped observations of one region, ready for the forward model.

    Attributes
    ----------
    signal, sigma
        ``(n, 3)`` chart-normalised camera RGB and its noise standard deviation.
    cos_i, cos_o, cos_h, cos_d
        ``(n,)`` cosines of light and view with the normal, of the half vector with the normal and
        of the light with the half vector.
    irradiance
        ``(n,)`` the lamp's relative irradiance ``(d_ref / d)^2`` (1 for a distant lamp).
    vertex, frame
        ``(n,)`` vertex and frame index of each sample.
    clipped_share
        Share of the lit observations dropped because a channel was clipped.
    n_gathered
        Observations of the region before any was dropped.
    n_shadowed
        Observations dropped because the lamp is below the surface or hidden by the mesh.
    clipped_highlight
        Clipped observations within :data:`HIGHLIGHT_DEG` of the mirror direction.
    facet_rad
        ``(n,)`` RMS angle between the vertex normal and the normals of its triangles (radians; the
        normal error of a faceted mesh), or None when the triangles were not given.
    """

    signal: NDArray[np.float64]
    sigma: NDArray[np.float64]
    cos_i: NDArray[np.float64]
    cos_o: NDArray[np.float64]
    cos_h: NDArray[np.float64]
    cos_d: NDArray[np.float64]
    irradiance: NDArray[np.float64]
    vertex: NDArray[np.int64]
    frame: NDArray[np.int64]
    clipped_share: float
    n_gathered: int = 0
    n_shadowed: int = 0
    clipped_highlight: int = 0
    facet_rad: NDArray[np.float64] | None = None

    def __len__(self) -> int:
        return int(len(self.cos_i))

    def subset(self, keep: NDArray[np.int64]) -> RegionSamples:
        """The samples at indices ``keep`` (the counts of dropped observations are kept).

        Parameters
        ----------
        keep
            Indices into the samples.

        Returns
        -------
        RegionSamples
        """
        return RegionSamples(self.signal[keep], self.sigma[keep], self.cos_i[keep], self.cos_o[keep],
                             self.cos_h[keep], self.cos_d[keep], self.irradiance[keep], self.vertex[keep],
                             self.frame[keep], self.clipped_share, self.n_gathered, self.n_shadowed,
                             self.clipped_highlight, None if self.facet_rad is None else self.facet_rad[keep])


def _gather(offsets: NDArray[np.int64], vertex_ids: NDArray[np.int64]) -> NDArray[np.int64]:
    """Observation indices of ``vertex_ids`` from CSR ``offsets`` (vectorised ranges)."""
    start, stop = offsets[vertex_ids], offsets[vertex_ids + 1]
    length = stop - start
    total = int(length.sum())
    if total == 0:
        return np.zeros(0, dtype=np.int64)
    base = np.repeat(start - np.concatenate([[0], np.cumsum(length)[:-1]]), length)
    return base + np.arange(total, dtype=np.int64)


def _lamp_table(frames: Sequence, lamp: int) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Per frame the lamp's vector ``(K, 3)`` and whether it is a point lamp ``(K,)``."""
    try:
        lamps = [f.lamps[lamp] for f in frames]
    except (IndexError, AttributeError, TypeError):
        raise FitError(f"frames: every frame needs a lamp number {lamp} in .lamps (FramePose)") from None
    return (np.array([np.asarray(m.vector, dtype=np.float64) for m in lamps]).reshape(-1, 3),
            np.array([m.kind == "point" for m in lamps], dtype=bool))


def _lamp_irradiance(vec: NDArray[np.float64], point: NDArray[np.bool_], frame: NDArray[np.int64],
                    pos: NDArray[np.float64], vertices: NDArray[np.float64],
                    reference_mm: float | None) -> NDArray[np.float64]:
    """Per observation the lamp's relative irradiance ``(d_ref / d)^2`` (1 for a distant lamp).

    ``vec``/``point`` per frame (:func:`_lamp_table`), ``frame`` and ``pos`` (mm) per observation;
    ``d_ref`` is ``reference_mm``, or the distance from frame 0's lamp to the centroid of ``vertices``.
    """
    dist = np.linalg.norm(vec[frame] - pos, axis=1)
    d_ref = float(np.linalg.norm(vec[0] - vertices.mean(axis=0))) if reference_mm is None else float(reference_mm)
    return np.where(point[frame], (d_ref / np.maximum(dist, 1e-9)) ** 2, 1.0)


def _facet_rad(vertices: NDArray[np.float64], triangles: ArrayLike, vertex: NDArray[np.int64],
               normal: NDArray[np.float64]) -> NDArray[np.float64]:
    """Per observation the RMS angle (radians) between its normal and the normals of its vertex's triangles."""
    t = np.asarray(triangles, dtype=np.int64)
    fn = np.cross(vertices[t[:, 1]] - vertices[t[:, 0]], vertices[t[:, 2]] - vertices[t[:, 0]])
    fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
    vn = np.zeros_like(vertices)
    vn[vertex] = normal
    corner = t.reshape(-1)
    cos = np.einsum("ij,ij->i", vn[corner], np.repeat(fn, 3, axis=0))
    ang2 = np.arccos(np.clip(np.abs(cos), -1.0, 1.0)) ** 2
    total = np.bincount(corner, weights=ang2, minlength=len(vertices))
    count = np.bincount(corner, minlength=len(vertices))
    return np.sqrt(total / np.maximum(count, 1))[vertex]


def _inner(ids: NDArray[np.int64], triangles: ArrayLike, n_vertices: int) -> NDArray[np.int64]:
    """``ids`` less the region's border vertices, unless fewer than half would remain.

    A border vertex shares a triangle with a vertex outside; its pixels mix both sides of the border.
    """
    t = np.asarray(triangles, dtype=np.int64)
    inside = np.zeros(n_vertices, dtype=bool)
    inside[ids] = True
    tin = inside[t]
    mixed = tin.any(axis=1) & ~tin.all(axis=1)
    border = np.zeros(n_vertices, dtype=bool)
    border[t[mixed][tin[mixed]]] = True
    keep = ids[~border[ids]]
    return keep if 2 * keep.size >= ids.size else ids


def _occluded(points: NDArray[np.float64], normals: NDArray[np.float64], toward: NDArray[np.float64],
              point: NDArray[np.bool_], vertices: NDArray[np.float64], triangles: ArrayLike) -> NDArray[np.bool_]:
    """True where the mesh hides the lamp from the point (rays from just above the surface)."""
    import open3d as o3d

    from processing.appearance.projection import raycasting_scene

    scene = raycasting_scene(vertices, triangles)
    size = float(np.linalg.norm(np.ptp(vertices, axis=0)))
    origin = points + normals * (1e-4 * size)
    out = np.zeros(len(points), dtype=bool)
    for is_point, tfar in ((True, 1.0), (False, np.inf)):
        sel = np.flatnonzero(point == is_point)
        if sel.size:
            d = toward[sel] - origin[sel] if is_point else toward[sel]
            rays = np.concatenate([origin[sel], d], axis=1).astype(np.float32)
            out[sel] = scene.test_occlusions(o3d.core.Tensor(rays), tfar=float(tfar)).numpy()
    return out


#: The last shadow tests: weak references to the observations, vertices and triangles they belong to,
#: the lamps (per frame vector and kind), which observations were tested and their answers.
_OCCLUSION: dict = {}


def _weak(x) -> weakref.ref | None:
    try:
        return weakref.ref(x)
    except TypeError:
        return None


def _occlusion(owners: tuple, vec: NDArray[np.float64], point: NDArray[np.bool_], obs_idx: NDArray[np.int64],
               points: NDArray[np.float64], normals: NDArray[np.float64], toward: NDArray[np.float64],
               point_obs: NDArray[np.bool_], vertices: NDArray[np.float64], triangles: ArrayLike) -> NDArray[np.bool_]:
    """:func:`_occluded` for observations ``obs_idx``, each observation's ray cast once.

    ``owners`` is ``(obs, vertices, triangles)`` as given to :func:`region_samples`, ``vec``/``point``
    the lamps (:func:`_lamp_table`).  The fit gathers the observations of a region several times (its
    interior, all of it, its pieces); an observation's shadow test depends only on the observation,
    the mesh and the lamp, so the answers are kept for the objects of the last call (compared by
    identity, held weakly) and the same lamps.
    """
    c = _OCCLUSION
    refs = [_weak(o) for o in owners]
    if any(r is None for r in refs):
        return _occluded(points, normals, toward, point_obs, vertices, triangles)
    if not (c and all(r() is o for r, o in zip(c["refs"], owners)) and np.array_equal(c["vec"], vec)
            and np.array_equal(c["point"], point)):
        n_obs = len(owners[0].frame)
        c.clear()
        c.update(refs=refs, vec=vec.copy(), point=point.copy(), tested=np.zeros(n_obs, dtype=bool),
                 hidden=np.zeros(n_obs, dtype=bool))
    tested, hidden = c["tested"], c["hidden"]
    new = np.flatnonzero(~tested[obs_idx])
    if new.size:
        hidden[obs_idx[new]] = _occluded(points[new], normals[new], toward[new], point_obs[new], vertices, triangles)
        tested[obs_idx[new]] = True
    return hidden[obs_idx]


def region_samples(obs, vertices: ArrayLike, frames: Sequence, vertex_ids: ArrayLike, *, lamp: int = 0,
                   drop_clipped: bool = True, triangles: ArrayLike | None = None,
                   reference_mm: float | None = None) -> RegionSamples:
    """The observations of a region at their true angles, lit by lamp ``lamp``.

    Parameters
    ----------
    obs
        :class:`processing.appearance.observations.Observations` of the mesh.
    vertices
        ``(V, 3)`` mesh vertices in M, mm.
    frames
        The frames' :class:`processing.appearance.frame_poses.FramePose` (``obs.frame`` indexes them).
    vertex_ids
        Vertices of the region.
    lamp
        Index of the lamp in ``obs.light_dir`` and ``frames[k].lamps``.
    drop_clipped
        Drop observations with a clipped channel (their share is reported).
    triangles
        ``(T, 3)`` the mesh's triangles: when given, observations whose lamp the mesh hides
        (self-shadow) are dropped, so they are not fitted as a dark material, and each observation
        gets the RMS angle between its normal and its vertex's triangles' (``facet_rad``); the
        region's border vertices are left out (their pixels mix both sides of the border) unless
        that would leave fewer than half of them.
    reference_mm
        ``d_ref`` of the irradiance ``(d_ref / d)^2``; None: the distance from frame 0's lamp to the
        centroid of ``vertices`` (the same for every region of a mesh, so amplitudes compare).

    Returns
    -------
    RegionSamples
        Observations with the light and the view above the surface, lit, and unclipped.

    Raises
    ------
    FitError
        Vertex ids outside the mesh, or frames without lamp ``lamp``.
    """
    verts = np.asarray(vertices, dtype=np.float64)
    ids = np.unique(np.asarray(vertex_ids, dtype=np.int64).reshape(-1))
    if ids.size and (ids[0] < 0 or ids[-1] >= obs.n_vertices or obs.n_vertices != len(verts)):
        raise FitError(f"vertex_ids must index the {obs.n_vertices} vertices of the observations "
                       f"(vertices has {len(verts)})")
    if not 0 <= lamp < len(obs.lamp_names):
        raise FitError(f"lamp={lamp}: the observations have {len(obs.lamp_names)} lamp(s)")
    if triangles is not None and ids.size:
        ids = _inner(ids, triangles, len(verts))
    idx = _gather(np.asarray(obs.offsets, dtype=np.int64), ids)
    vec, point = _lamp_table(frames, lamp)
    n = obs.normal[idx].astype(np.float64)
    v = obs.view_dir[idx].astype(np.float64)
    li = obs.light_dir[idx, lamp].astype(np.float64)
    h = li + v
    h /= np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-12)
    cos_i, cos_o = np.einsum("ij,ij->i", n, li), np.einsum("ij,ij->i", n, v)
    cos_h, cos_d = np.clip(np.einsum("ij,ij->i", n, h), 0, 1), np.clip(np.einsum("ij,ij->i", h, li), 0, 1)
    fr = obs.frame[idx].astype(np.int64)
    pos = verts[obs.vertex[idx]]
    irr = _lamp_irradiance(vec, point, fr, pos, verts, reference_mm)
    lit = (cos_i > 0) & (cos_o > 0)
    if triangles is not None and lit.any():
        s = np.flatnonzero(lit)
        lit[s] &= ~_occlusion((obs, vertices, triangles), vec, point, idx[s], pos[s], n[s], vec[fr[s]],
                              point[fr[s]], verts, triangles)
    clipped = np.asarray(obs.clipped[idx], dtype=bool)
    keep = lit & ~clipped if drop_clipped else lit
    share = float((lit & clipped).sum() / max(int(lit.sum()), 1))
    hl = int((lit & clipped & (cos_h > np.cos(np.radians(HIGHLIGHT_DEG)))).sum())
    k = np.flatnonzero(keep)
    facet = None if triangles is None else _facet_rad(verts, triangles, obs.vertex[idx[k]].astype(np.int64), n[k])
    return RegionSamples(obs.signal[idx[k]].astype(np.float64), obs.sigma[idx[k]].astype(np.float64), cos_i[k],
                         cos_o[k], cos_h[k], cos_d[k], irr[k], obs.vertex[idx[k]].astype(np.int64), fr[k], share,
                         int(idx.size), int((~lit).sum()), hl, facet)
