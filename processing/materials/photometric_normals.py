"""Mesh normals refined by the photos: each vertex's normal tilted to where its highlights say it points.

A scanned mesh's normals are a few degrees off the object's (range noise smoothed by the surface
reconstruction), and a polished metal's highlight is narrower than that: the gloss lobe of an RMS
slope of 0.15 halves its brightness 5 degrees from its peak.  The highlights then appear where the
mesh says they cannot, and no material explains them.  The photos hold the answer: every vertex is
seen in many frames at known view and light directions, and with its region's material fitted the
brightness of each view is a function of the normal alone.

Each vertex's normal is chosen among tilts of the mesh normal (a grid, then a finer grid around the
best) by the cost

    sum over its views of rho(|W (y - p(m))|^2)  +  tilt^2 / (2 prior^2)
    + sum over its mesh neighbours of |delta_v - delta_u|^2 / (2 smooth^2)

with ``p(m)`` the region material's prediction at normal ``m`` (:meth:`ForwardModel.predict`, lobe
by lobe: each lobe's colour depends on ``cos_d`` only, which no normal changes), ``W`` the noise
plus a relative model error, ``rho`` the Cauchy loss (a view the model cannot explain -- a clipped
neighbour, a mixed pixel at a border -- cannot pull the normal far), ``delta`` the correction
``m - n`` (the corrections of neighbouring vertices agree: the scan's error is smooth over a few
millimetres), minimised by iterated conditional modes.  Vertices without a fitted material, or
without lit views, keep their mesh normal.

References
----------
.. [1] Woodham, R. J. (1980). Photometric method for determining surface orientation from multiple
   images. Optical Engineering 19(1), 139-144. doi:10.1117/12.7972479
.. [2] Nehab, D., Rusinkiewicz, S., Davis, J., Ramamoorthi, R. (2005). Efficiently combining
   positions and normals for precise 3D geometry. ACM Trans. Graph. 24(3), 536-543.
   doi:10.1145/1073204.1073226
.. [3] Besag, J. (1986). On the statistical analysis of dirty pictures. J. R. Stat. Soc. B 48(3),
   259-302. doi:10.1111/j.2517-6161.1986.tb01412.x (iterated conditional modes)
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.appearance._surface_features import adjacency
from processing.materials._forward_fit_samples import (
    HIGHLIGHT_DEG,
    FitError,
    _lamp_irradiance,
    _lamp_table,
    _occluded,
)
from processing.materials.lobes import Material, lobe_geometry

__all__ = ["NormalRefinement", "refine_normals", "MAX_TILT_DEG", "PRIOR_DEG", "SMOOTH_DEG", "MIN_DECIDING"]

#: Largest tilt searched away from the mesh normal.
MAX_TILT_DEG = 8.0
#: Prior standard deviation of the mesh normals' error.
PRIOR_DEG = 3.0
#: Standard deviation of the difference between neighbouring vertices' corrections.
SMOOTH_DEG = 2.0
_COARSE_STEP_DEG = 2.0
_FINE_STEP_DEG = 0.5
#: Views farther than this from the mirror direction (at the mesh normal, beyond the search radius)
#: are left out: a gloss lobe is dark there whatever the normal, and a diffuse lobe's shading is a
#: far weaker clue than a highlight.
_VIEW_REACH_DEG = 22.0
_CAUCHY = 3.0
_MODEL_ERROR = 0.03
#: Lobes narrower than this RMS slope (the mirror spike) are left out of the prediction: the
#: spike is clipped, or narrower than the pixels' footprint.
_SPIKE_ROUGHNESS = 0.03
#: Views near the mirror direction a vertex needs for its normal to count as decided by them.
MIN_DECIDING = 1


@dataclass(frozen=True)
class NormalRefinement:
    """Refined vertex normals.

    Attributes
    ----------
    normals
        ``(V, 3)`` unit normals (the mesh's where nothing was refined).
    tilt_deg
        ``(V,)`` angle between the refined and the mesh normal.
    decided
        ``(V,)`` True where the views decide the normal: at least :data:`MIN_DECIDING` of them within
        :data:`processing.materials.forward_fit.HIGHLIGHT_DEG` of the mirror direction.  Elsewhere
        the normal follows its neighbours' corrections (or stays the mesh's).
    cost_before, cost_after
        The data cost (robust, summed over every view used) at the mesh normals and at the refined
        ones.
    n_views
        Views used.
    """

    normals: NDArray[np.float64]
    tilt_deg: NDArray[np.float64]
    decided: NDArray[np.bool_]
    cost_before: float
    cost_after: float
    n_views: int


def _frames(n: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Two unit tangents ``(V, 3)`` orthogonal to each normal."""
    helper = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(n, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return t1, np.cross(n, t1)


def _grid(step_deg: float, half_deg: float) -> NDArray[np.float64]:
    """``(K, 2)`` tangent-plane tilts (tan of the angles) on a square grid within a disc of ``half_deg``."""
    a = np.arange(-half_deg, half_deg + 1e-9, step_deg)
    g = np.stack(np.meshgrid(a, a, indexing="ij"), axis=-1).reshape(-1, 2)
    return np.tan(np.radians(g[np.hypot(g[:, 0], g[:, 1]) <= half_deg + 1e-9]))


@dataclass(frozen=True)
class _Views:
    """The lit, unclipped views of the vertices that have a material."""

    vertex: NDArray[np.int64]
    signal: NDArray[np.float64]
    inv_var: NDArray[np.float64]
    light: NDArray[np.float64]
    view: NDArray[np.float64]
    half: NDArray[np.float64]
    cos_d: NDArray[np.float64]
    irradiance: NDArray[np.float64]
    colours: list[list[NDArray[np.float64]]]    # per region, per kept lobe: (n_r, 3) weight * colour(cos_d)
    lobes: list[list]                           # per region, its kept lobes
    region_rows: list[NDArray[np.int64]]        # per region, its rows


def _views(obs, verts: NDArray[np.float64], triangles: NDArray[np.int64] | None, frames: Sequence,
           vertex_region: NDArray[np.int64], materials: Sequence[Material | None], model, lamp: int,
           reference_mm: float | None, reach_deg: float) -> _Views:
    has = np.zeros(len(materials) + 1, dtype=bool)
    has[:-1] = [m is not None for m in materials]
    reg = vertex_region[obs.vertex]
    keep = (reg >= 0) & has[np.where(reg >= 0, reg, len(materials))] & ~np.asarray(obs.clipped, dtype=bool)
    n = obs.normal.astype(np.float64)
    li = obs.light_dir[:, lamp].astype(np.float64)
    vd = obs.view_dir.astype(np.float64)
    keep &= (np.einsum("ij,ij->i", n, li) > 0.05) & (np.einsum("ij,ij->i", n, vd) > 0.05)
    half = li + vd
    half /= np.maximum(np.linalg.norm(half, axis=1, keepdims=True), 1e-12)
    keep &= np.einsum("ij,ij->i", n, half) >= np.cos(np.radians(min(reach_deg, 89.0)))
    idx = np.flatnonzero(keep)
    vec, point = _lamp_table(frames, lamp)
    fr = obs.frame[idx].astype(np.int64)
    vx = obs.vertex[idx].astype(np.int64)
    pos = verts[vx]
    if triangles is not None and idx.size:
        lit = ~_occluded(pos, n[idx], vec[fr], point[fr], verts, triangles)
        idx, fr, vx, pos = idx[lit], fr[lit], vx[lit], pos[lit]
    irr = _lamp_irradiance(vec, point, fr, pos, verts, reference_mm)
    light, view = li[idx], vd[idx]
    h = half[idx]
    cos_d = np.clip(np.einsum("ij,ij->i", h, light), 0.0, 1.0)
    y = obs.signal[idx].astype(np.float64)
    var = np.maximum(obs.sigma[idx].astype(np.float64), 1e-4) ** 2 + (_MODEL_ERROR * np.maximum(y, 0.0)) ** 2
    rows_of = vertex_region[vx]
    colours, lobes, rows = [], [], []
    for r, mat in enumerate(materials):
        sel = np.flatnonzero(rows_of == r) if mat is not None else np.zeros(0, dtype=np.int64)
        kept = [lobe for lobe in (mat.lobes if mat is not None else ())
                if lobe.kind == "lambert" or (lobe.kind == "microfacet" and lobe.roughness >= _SPIKE_ROUGHNESS)]
        colours.append([lobe.weight * model.colour(lobe.spectral, cos_d[sel]) for lobe in kept])
        lobes.append(kept)
        rows.append(sel)
    return _Views(vx, y, 1.0 / var, light, view, h, cos_d, irr, colours, lobes, rows)


def _data_cost(views: _Views, m: NDArray[np.float64], n_vertices: int) -> NDArray[np.float64]:
    """Per vertex, the robust cost of its views at per-view normals ``m`` ``(n, 3)``."""
    ci = np.einsum("ij,ij->i", m, views.light)
    co = np.einsum("ij,ij->i", m, views.view)
    ch = np.clip(np.einsum("ij,ij->i", m, views.half), 0.0, 1.0)
    cd = views.cos_d
    pred = np.zeros_like(views.signal)
    for rows, kept, cols in zip(views.region_rows, views.lobes, views.colours):
        if rows.size == 0:
            continue
        shade = np.pi * views.irradiance[rows] * np.clip(ci[rows], 0.0, None)
        for lobe, col in zip(kept, cols):
            g = lobe_geometry(lobe, np.clip(ci[rows], 0.0, None), np.clip(co[rows], 0.0, None), ch[rows], cd[rows])
            pred[rows] += (shade * g)[:, None] * col
    r2 = ((views.signal - pred) ** 2 * views.inv_var).sum(axis=1)
    rho = _CAUCHY ** 2 * np.log1p(r2 / _CAUCHY ** 2)
    return np.bincount(views.vertex, weights=rho, minlength=n_vertices)


def _tilted(n0: NDArray[np.float64], t1: NDArray[np.float64], t2: NDArray[np.float64],
            ab: NDArray[np.float64]) -> NDArray[np.float64]:
    m = n0 + ab[..., :1] * t1 + ab[..., 1:] * t2
    return m / np.linalg.norm(m, axis=-1, keepdims=True)


def _search(views: _Views, n0: NDArray[np.float64], t1: NDArray[np.float64], t2: NDArray[np.float64],
            centre: NDArray[np.float64], grid: NDArray[np.float64], src: NDArray[np.int64],
            dst: NDArray[np.int64], prior_rad: float, smooth_rad: float, active: NDArray[np.bool_],
            iterations: int) -> NDArray[np.float64]:
    """ICM over ``centre + grid`` tilts per vertex; returns the chosen ``(V, 2)`` tilts."""
    nv = len(n0)
    data = np.empty((nv, len(grid)))
    for k, step in enumerate(grid):
        ab = centre + step
        data[:, k] = _data_cost(views, _tilted(n0, t1, t2, ab)[views.vertex], nv)
    tilt2 = (centre[:, None, :] + grid[None]) ** 2
    data += tilt2.sum(axis=2) / (2.0 * prior_rad ** 2)
    best = np.argmin(data, axis=1)
    ab = centre + grid[best]
    ab[~active] = 0.0
    for _ in range(iterations):
        delta = _tilted(n0, t1, t2, ab) - n0
        total = data.copy()
        deg = np.bincount(src, minlength=nv).astype(np.float64)
        mean = np.stack([np.bincount(src, weights=delta[dst, c], minlength=nv) for c in range(3)], axis=1)
        sq = np.bincount(src, weights=(delta[dst] ** 2).sum(axis=1), minlength=nv)
        for k, step in enumerate(grid):
            dk = _tilted(n0, t1, t2, centre + step) - n0
            total[:, k] += (deg * (dk ** 2).sum(axis=1) - 2.0 * (dk * mean).sum(axis=1) + sq) / (2.0 * smooth_rad ** 2)
        ab = centre + grid[np.argmin(total, axis=1)]
        ab[~active] = 0.0
    return ab


def refine_normals(obs, vertices: ArrayLike, triangles: ArrayLike, normals: ArrayLike, frames: Sequence,
                   vertex_region: ArrayLike,
                   materials: Sequence[Material | None], model, *, lamp: int = 0, reference_mm: float | None = None,
                   max_tilt_deg: float = MAX_TILT_DEG, prior_deg: float = PRIOR_DEG, smooth_deg: float = SMOOTH_DEG,
                   shadows: bool = True, iterations: int = 3) -> NormalRefinement:
    """Vertex normals tilted to where the region materials' highlights put them.

    Parameters
    ----------
    obs
        :class:`processing.appearance.observations.Observations` of the mesh.
    vertices, triangles, normals
        The mesh (mm) and its unit vertex normals (the starting point and the prior's centre).
    frames
        The frames' :class:`processing.appearance.frame_poses.FramePose` (``obs.frame`` indexes them).
    vertex_region
        ``(V,)`` region of each vertex (-1: none).
    materials
        Per region its fitted material, in the chart-normalised units of
        :meth:`processing.materials.forward_fit.ForwardModel.predict` (e.g.
        ``get_material(fit.spec)``), or None to leave the region's normals alone.
    model
        The :class:`processing.materials.forward_fit.ForwardModel` (camera and lamp).
    lamp
        Lamp index.
    reference_mm
        ``d_ref`` of a point lamp's irradiance ``(d_ref / d)^2`` (as in the fit).
    max_tilt_deg, prior_deg, smooth_deg
        Search radius, prior standard deviation of the mesh normals' error and of the difference
        of neighbouring corrections (degrees).
    shadows
        Leave out views whose lamp the mesh hides.
    iterations
        ICM sweeps at each grid level.

    Returns
    -------
    NormalRefinement

    Raises
    ------
    FitError
        Shapes that do not match, or search settings that are not positive.

    Examples
    --------
    A flat gold plate whose mesh normal is 4 degrees off, seen at many angles:

    >>> from processing.materials.photometric_normals import _example
    >>> ref, true_tilt = _example()
    >>> bool(abs(ref.tilt_deg.mean() - true_tilt) < 1.0), bool(ref.cost_after < ref.cost_before)
    (True, True)
    """
    verts = np.asarray(vertices, dtype=np.float64)
    tris = np.asarray(triangles, dtype=np.int64)
    vreg = np.asarray(vertex_region, dtype=np.int64).reshape(-1)
    if vreg.shape != (len(verts),) or obs.n_vertices != len(verts):
        raise FitError(f"vertex_region must hold one region per vertex ({len(verts)}), and the observations "
                       f"must be of this mesh ({obs.n_vertices} vertices)")
    if vreg.max(initial=-1) >= len(materials):
        raise FitError(f"vertex_region names region {int(vreg.max())} but {len(materials)} materials were given")
    for name, value in (("max_tilt_deg", max_tilt_deg), ("prior_deg", prior_deg), ("smooth_deg", smooth_deg)):
        if not (np.isfinite(value) and value > 0):
            raise FitError(f"{name} must be > 0 degrees, got {value!r}")
    nv = len(verts)
    n0 = np.asarray(normals, dtype=np.float64)
    if n0.shape != (nv, 3) or not np.all(np.isfinite(n0)):
        raise FitError(f"normals must be ({nv}, 3) finite unit vectors, got shape {n0.shape}")
    n0 = n0 / np.maximum(np.linalg.norm(n0, axis=1, keepdims=True), 1e-12)
    obs = dataclasses.replace(obs, normal=n0[obs.vertex].astype(np.float32))
    views = _views(obs, verts, tris if shadows else None, frames, vreg, materials, model, lamp, reference_mm,
                   max_tilt_deg + _VIEW_REACH_DEG)
    active = np.bincount(views.vertex, minlength=nv) > 0
    t1, t2 = _frames(n0)
    graph = adjacency(tris, nv).tocoo()
    src, dst = graph.row.astype(np.int64), graph.col.astype(np.int64)
    prior, smooth = np.radians(prior_deg), np.radians(smooth_deg)
    ab = _search(views, n0, t1, t2, np.zeros((nv, 2)), _grid(min(_COARSE_STEP_DEG, max_tilt_deg), max_tilt_deg),
                 src, dst, prior, smooth, active, iterations)
    ab = _search(views, n0, t1, t2, ab, _grid(_FINE_STEP_DEG, 2 * _FINE_STEP_DEG), src, dst, prior, smooth,
                 active, iterations)
    m = _tilted(n0, t1, t2, ab)
    before = float(_data_cost(views, n0[views.vertex], nv).sum())
    after = float(_data_cost(views, m[views.vertex], nv).sum())
    tilt = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", m, n0), -1.0, 1.0)))
    near = np.einsum("ij,ij->i", m[views.vertex], views.half) >= np.cos(np.radians(HIGHLIGHT_DEG))
    decided = np.bincount(views.vertex[near], minlength=nv) >= MIN_DECIDING
    return NormalRefinement(m, tilt, decided, before, after, int(len(views.vertex)))


def _example() -> tuple[NormalRefinement, float]:
    """A flat gold plate (normal tilted 4 deg from the mesh's) in 36 views; for the doctest."""
    import types

    from processing.appearance.observations import Observations
    from processing.camera.response import camera_sensitivities
    from processing.materials.forward_fit import ForwardModel
    from processing.materials.presets import get_material
    from processing.spectral.spectra import SpectralGrid, light_spectrum

    g = SpectralGrid(400, 700, 10)
    model = ForwardModel(camera_sensitivities(g), light_spectrum("D65", g), g)
    gold = get_material("gold")
    xs = np.arange(-2.0, 3.0)
    verts = np.array([[x, y, 0.0] for y in xs for x in xs])
    idx = np.arange(25).reshape(5, 5)
    tris = np.concatenate([np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1]], -1).reshape(-1, 3),
                           np.stack([idx[1:, 1:], idx[1:, :-1], idx[:-1, 1:]], -1).reshape(-1, 3)])
    true_tilt = 4.0
    true_n = np.array([np.sin(np.radians(true_tilt)), 0.0, np.cos(np.radians(true_tilt))])
    light = np.array([0.0, 0.0, 1.0])
    az = np.radians(np.arange(0.0, 360.0, 10.0))
    rows = []
    for el in (np.radians(14.0), np.radians(8.0)):
        views = np.stack([np.sin(el) * np.cos(az), np.sin(el) * np.sin(az), np.full_like(az, np.cos(el))], 1)
        rows.append(views)
    views = np.concatenate(rows)
    k = len(views)
    h = (views + light) / np.linalg.norm(views + light, axis=1, keepdims=True)
    s = types.SimpleNamespace(cos_i=np.full(k, true_n @ light), cos_o=views @ true_n, cos_h=h @ true_n,
                              cos_d=h @ light, irradiance=np.ones(k))
    signal = model.predict(gold, s)
    n = len(verts) * k
    obs = Observations(len(verts), tuple(f"f{i}" for i in range(k)), ("lamp",),
                       np.arange(0, n + 1, k, dtype=np.int64), np.repeat(np.arange(len(verts)), k).astype(np.int32),
                       np.tile(np.arange(k), len(verts)).astype(np.int32), np.zeros((n, 2), np.float32),
                       np.tile(signal, (len(verts), 1)).astype(np.float32), np.full((n, 3), 0.002, np.float32),
                       np.zeros(n, bool), np.tile([0.0, 0.0, 1.0], (n, 1)).astype(np.float32),
                       np.tile(views, (len(verts), 1)).astype(np.float32),
                       np.tile(light, (n, 1, 1)).astype(np.float32), np.zeros((n, 1), np.float32),
                       np.full(n, 100.0, np.float32))
    lamp = types.SimpleNamespace(vector=light, kind="distant")
    frames = [types.SimpleNamespace(lamps=[lamp])] * k
    return refine_normals(obs, verts, tris, np.tile([0.0, 0.0, 1.0], (len(verts), 1)), frames,
                          np.zeros(len(verts), np.int64), [gold], model,
                          shadows=False), true_tilt
