"""Smooth completion of holes: a smooth height field fitted around each hole, sampled as guide points.

Matsuda et al. (section 2) complete the parts a scan missed by fitting a
smooth surface (NURBS patches) to the measured data around each hole.  Here
each hole of a mesh (a connected unsupported region, see
:mod:`processing.geometry.mesh_support`) gets a direction from its border, a
ring of data around it, a sphere plus thin-plate spline (or a spline, or the
plane of the border data, or the table plane) fitted to the ring, and guide
points on that surface inside the border; added to the data, they make a
second screened Poisson reconstruction close every hole along the fitted
surface.  See docs/processing.md, section "Hole filling".

References
----------
.. [1] Matsuda, Tanaka, Ichikawa, Mochizuki, Muroya, Kitamura. CG
   reproduction of a craft object based on a light reflection model. IPSJ
   technical report.
.. [2] Kasa, I. (1976). A circle fitting procedure and its error analysis.
   IEEE Trans. Instrum. Meas. 25(1), 8-14.
.. [3] Pratt, V. (1987). Direct least-squares fitting of algebraic surfaces.
   SIGGRAPH 1987. doi:10.1145/37402.37420
.. [4] Duchon, J. (1977). Splines minimizing rotation-invariant semi-norms
   in Sobolev spaces. Constructive Theory of Functions of Several Variables,
   Lecture Notes in Mathematics 571.

Examples
--------
>>> inside_polygon([[0.5, 0.5], [2.0, 0.5]], [[[0, 0], [1, 0]], [[1, 0], [1, 1]],
...                                          [[1, 1], [0, 1]], [[0, 1], [0, 0]]]).tolist()
[True, False]
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from processing.errors import InputError
from processing.geometry.height_fields import _MIN_RING, _choose_ring_model, _fit, _Floor, _Plane, _rms, _SphereSpline
from processing.geometry.mesh_support import SupportReport
from processing.geometry.mesh_topology import edge_twins

__all__ = ["HoleFit", "HoleGuides", "hole_guide_points", "inside_polygon"]

#: Ring samples must face the hole's direction within this angle.
_RING_MAX_ANGLE_DEG = 75.0
#: Largest number of guide-grid samples per hole (the grid is coarsened beyond).
_MAX_GRID = 400_000
#: A hole faces the floor when its direction is within this angle of -z.
_FLOOR_MAX_ANGLE_DEG = 30.0
#: ... and its border data lie within this height (mm) of the floor.
_FLOOR_SNAP_MM = 2.0
#: Guide points closer to the data than this fraction of the support threshold are dropped.
_KEEP_OFF = 1.0
#: Guide grid step in point spacings.
_GUIDE_STEP = 1.5


@dataclass(frozen=True)
class HoleFit:
    """How one hole was completed.

    Attributes
    ----------
    hole
        Index of the hole in the support report.
    fitted
        True when guide points were produced.
    reason
        What was done, or why nothing was: ``"sphere"`` (sphere plus spline
        fitted to the ring), ``"spline"`` (spline fitted to the ring),
        ``"border (why the ring fits were rejected)"`` (plane through the
        data at the border), ``"table plane"`` (closed on the table top;
        ``fit_rms_mm`` is then the height of the border data above it);
        otherwise why the hole was not fitted.
    n_guide_points
        Guide points produced.
    n_fit_samples
        Samples the surface was fitted to.
    fit_rms_mm
        RMS residual (mm) of the surface at its samples.
    direction
        ``(3,)`` outward direction N of the hole.
    """

    hole: int
    fitted: bool
    reason: str
    n_guide_points: int
    n_fit_samples: int
    fit_rms_mm: float
    direction: NDArray[np.float64]


@dataclass(frozen=True)
class HoleGuides:
    """Guide points on the fitted surfaces of all holes.

    Attributes
    ----------
    points, normals
        float64 ``(G, 3)`` positions (mm) and unit outward normals.
    hole
        int64 ``(G,)`` hole index of each guide point.
    fits
        One :class:`HoleFit` per hole.
    """

    points: NDArray[np.float64]
    normals: NDArray[np.float64]
    hole: NDArray[np.int64]
    fits: tuple[HoleFit, ...]


def inside_polygon(query: ArrayLike, edges: ArrayLike) -> NDArray[np.bool_]:
    """Even-odd test of 2-D points against a set of polygon edges.

    Parameters
    ----------
    query
        ``(Q, 2)`` points.
    edges
        ``(E, 2, 2)`` segments (start, end); their order and direction do not
        matter, several loops may be mixed.

    Returns
    -------
    ndarray of bool
        ``(Q,)``: an odd number of edges crosses the ray from the point
        toward +x.
    """
    q = np.asarray(query, dtype=np.float64).reshape(-1, 2)
    e = np.asarray(edges, dtype=np.float64).reshape(-1, 2, 2)
    if q.shape[0] == 0 or e.shape[0] == 0:
        return np.zeros(q.shape[0], bool)
    ys, row = np.unique(q[:, 1], return_inverse=True)
    row = row.reshape(-1)
    y0, y1 = e[:, 0, 1], e[:, 1, 1]
    x0, x1 = e[:, 0, 0], e[:, 1, 0]
    # crossings of every row's line with every edge (half-open rule on y)
    spans = (y0[None, :] > ys[:, None]) != (y1[None, :] > ys[:, None])
    r_idx, e_idx = np.nonzero(spans)
    t = (ys[r_idx] - y0[e_idx]) / (y1[e_idx] - y0[e_idx])
    xc = x0[e_idx] + t * (x1[e_idx] - x0[e_idx])
    # one global sorted array: row-major offsets keep rows apart
    lo = min(float(xc.min()) if xc.size else 0.0, float(q[:, 0].min()))
    hi = max(float(xc.max()) if xc.size else 0.0, float(q[:, 0].max()))
    big = (hi - lo) + 1.0
    keys = np.sort(r_idx * big + (xc - lo))
    per_row = np.bincount(r_idx, minlength=ys.size)
    row_end = np.cumsum(per_row)
    below_or_at = np.searchsorted(keys, row * big + (q[:, 0] - lo), side="right")
    right = row_end[row] - below_or_at
    return (right % 2) == 1


def _basis(normal: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Two unit vectors completing ``normal`` to a right-handed orthonormal frame."""
    helper = np.eye(3)[int(np.argmin(np.abs(normal)))]
    e1 = np.cross(normal, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(normal, e1)


def _border_edges(triangles: NDArray[np.int64], report: SupportReport) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Directed edges of supported triangles adjoining a hole, and that hole's index."""
    edge_id, count = edge_twins(triangles)
    a = triangles.reshape(-1)
    b = triangles[:, [1, 2, 0]].reshape(-1)
    tri = np.repeat(np.arange(triangles.shape[0]), 3)
    idx = np.flatnonzero(count[edge_id] == 2)
    order = idx[np.argsort(edge_id[idx], kind="stable")]
    first, second = order[0::2], order[1::2]
    lab = report.hole_label
    sup = ~report.unsupported
    rows, holes = [], []
    for this, other in ((first, second), (second, first)):
        sel = sup[tri[this]] & (lab[tri[other]] >= 0)
        rows.append(this[sel])
        holes.append(lab[tri[other[sel]]])
    rows_a = np.concatenate(rows)
    return np.stack([a[rows_a], b[rows_a]], axis=1), np.concatenate(holes)


def hole_guide_points(
    vertices: ArrayLike,
    triangles: ArrayLike,
    report: SupportReport,
    data_points: ArrayLike,
    data_normals: ArrayLike,
    *,
    spacing_mm: float,
    noise_mm: float,
    tree: cKDTree | None = None,
    ring_factor: float = 0.3,
    max_fit_samples: int = 800,
    floor_z_mm: float | None = None,
    seed: int = 0,
) -> HoleGuides:
    """Guide points on a smooth surface fitted around every hole.

    Per hole: its outward direction from the border's vector area, the data
    in a ring around it, the best smooth height field fitted to the ring (or
    the plane of the border data, or the table plane under an underside),
    sampled on a grid inside the projected border; see docs/processing.md,
    section "Hole filling".

    Parameters
    ----------
    vertices, triangles
        The mesh whose holes are completed (mm).
    report
        Its :class:`~processing.geometry.mesh_support.SupportReport`.
    data_points, data_normals
        ``(N, 3)`` measured points (mm) and their unit outward normals.
    spacing_mm
        Point spacing (mm): sets the guide grid step (1.5 spacings).
    noise_mm
        Noise of the data (mm, e.g. from :func:`processing.geometry.fusion.noise_level`):
        a ring fit whose RMS residual exceeds ``2.5 noise_mm + 0.1 spacing_mm``
        is rejected (the ring is no height field, e.g. the walls around a
        flat cut) and the border is used.
    tree
        Optional ``cKDTree`` of ``data_points``.
    ring_factor
        Ring width as a fraction of the border's diameter (at least three
        support thresholds).
    max_fit_samples
        Ring samples kept for the fit (random subset beyond).
    floor_z_mm
        Optional height (mm) of a plane the object stands on (the table top,
        z = 0 in the first pass's table frame): no guide point goes below it,
        and a hole facing down (within 30 degrees) whose border data lie
        within 2 mm of it is closed on it (the underside resting on it).
    seed
        Seed of that subset.

    Returns
    -------
    HoleGuides
        The guide points (mm) with their normals and holes, and one
        :class:`HoleFit` per hole.

    Raises
    ------
    ValueError
        ``spacing_mm`` not a positive finite distance, ``noise_mm`` negative
        or not finite, ``floor_z_mm`` not finite.

    References
    ----------
    .. [1] Pratt, V. (1987). Direct least-squares fitting of algebraic
       surfaces. SIGGRAPH 1987. doi:10.1145/37402.37420
    .. [2] Duchon, J. (1977). Splines minimizing rotation-invariant
       semi-norms in Sobolev spaces. Lecture Notes in Mathematics 571.
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    dp = np.asarray(data_points, dtype=np.float64)
    dn = np.asarray(data_normals, dtype=np.float64)
    if not (np.isfinite(spacing_mm) and spacing_mm > 0):
        raise InputError(f"spacing_mm must be a finite distance > 0 (mm), got {spacing_mm!r}")
    if not (np.isfinite(noise_mm) and noise_mm >= 0):
        raise InputError(f"noise_mm must be a finite distance >= 0 (mm), got {noise_mm!r}")
    if floor_z_mm is not None and not np.isfinite(floor_z_mm):
        raise InputError(f"floor_z_mm must be a finite height (mm) or None, got {floor_z_mm!r}")
    if tree is None:
        tree = cKDTree(dp)
    opt = _Options(threshold_mm=report.threshold_mm, tolerance_mm=2.5 * float(noise_mm) + 0.1 * float(spacing_mm),
                   spacing_mm=spacing_mm, ring_factor=ring_factor, max_fit_samples=max_fit_samples,
                   floor_z_mm=floor_z_mm)
    rng = np.random.default_rng(seed)
    if report.n_holes:
        edges, edge_hole = _border_edges(t, report)
    else:
        edges, edge_hole = np.zeros((0, 2), np.int64), np.zeros(0, np.int64)
    out_p, out_n, out_h, fits = [], [], [], []
    for h in range(report.n_holes):
        fit, pts, nrm = _guide_hole(h, edges[edge_hole == h], v, dp, dn, tree, rng, opt)
        fits.append(fit)
        if pts is not None and nrm is not None:
            out_p.append(pts)
            out_n.append(nrm)
            out_h.append(np.full(pts.shape[0], h, np.int64))
    if out_p:
        return HoleGuides(np.concatenate(out_p), np.concatenate(out_n), np.concatenate(out_h), tuple(fits))
    return HoleGuides(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, np.int64), tuple(fits))


@dataclass(frozen=True)
class _Options:
    """Settings of :func:`hole_guide_points` shared by every hole (lengths in mm)."""

    threshold_mm: float
    tolerance_mm: float
    spacing_mm: float
    ring_factor: float
    max_fit_samples: int
    floor_z_mm: float | None


@dataclass(frozen=True)
class _HoleFrame:
    """A hole's outward direction, its local frame and its border projected on the frame's plane."""

    normal: NDArray[np.float64]
    e1: NDArray[np.float64]
    e2: NDArray[np.float64]
    loop: NDArray[np.int64]
    origin: NDArray[np.float64]
    frame: NDArray[np.float64]
    seg: NDArray[np.float64]
    lo: NDArray[np.float64]
    hi: NDArray[np.float64]
    diameter: float
    radius: float


class _Fit(NamedTuple):
    """A height field over a hole's frame, what it is, its RMS residual (mm), and the samples it was fitted to."""

    model: Any
    how: str
    rms: float
    n_fit: int
    samples: NDArray[np.float64] | None


def _guide_hole(h: int, e: NDArray[np.int64], v: NDArray[np.float64], dp: NDArray[np.float64],
                dn: NDArray[np.float64], tree: cKDTree, rng: np.random.Generator, opt: _Options
                ) -> tuple[HoleFit, NDArray[np.float64] | None, NDArray[np.float64] | None]:
    """Guide points and normals of one hole with border edges ``e``, or None and why it was not fitted."""
    none = np.zeros(3)
    if e.shape[0] < 3:
        return HoleFit(h, False, "no border with the data (an isolated region)", 0, 0, 0.0, none), None, None
    fr = _hole_frame(e, v, opt)
    if fr is None:
        return HoleFit(h, False, "the border encloses no area in any direction", 0, 0, 0.0, none), None, None
    fit = _fit_border(fr, v, dp, tree, _fit_ring(fr, v, dp, dn, rng, opt), opt)
    if fit.model is None:
        return HoleFit(h, False, "fewer than 3 samples around the hole", 0, fit.n_fit, 0.0, fr.normal), None, None
    grid, step = _guide_grid(fr, opt.spacing_mm)
    if grid.shape[0] == 0:
        return (HoleFit(h, False, "the hole is narrower than the point spacing", 0, fit.n_fit, fit.rms, fr.normal),
                None, None)
    fit, hh, du, dv = _heights(fit, grid, step)
    if not np.all(np.isfinite(hh)) or np.abs(hh).max() > 2.0 * fr.diameter + 10.0 * opt.threshold_mm:
        return (HoleFit(h, False, "the fitted surface runs away from the border", 0, fit.n_fit, fit.rms, fr.normal),
                None, None)
    pts, nrm = _lift(fr, grid, hh, du, dv, tree, opt)
    return (HoleFit(h, bool(pts.shape[0]), fit.how if pts.shape[0] else "the fit lies on the data",
                    int(pts.shape[0]), fit.n_fit, fit.rms, fr.normal), pts, nrm)


def _hole_frame(e: NDArray[np.int64], v: NDArray[np.float64], opt: _Options) -> _HoleFrame | None:
    """The hole's direction ``N = -A / |A|`` from its border's vector area, and its frame; None if ``A`` vanishes."""
    va, vb = v[e[:, 0]], v[e[:, 1]]
    area_vec = 0.5 * np.cross(va, vb).sum(axis=0)
    border_len = float(np.linalg.norm(vb - va, axis=1).sum())
    amag = float(np.linalg.norm(area_vec))
    if amag <= 1e-6 * border_len**2:
        return None
    normal = -area_vec / amag
    e1, e2 = _basis(normal)
    loop = np.unique(e.reshape(-1))
    origin = v[loop].mean(axis=0)
    frame = np.stack([e1, e2, normal])
    loop_uv = (v[loop] - origin) @ frame[:2].T
    seg = np.stack([(va - origin) @ frame[:2].T, (vb - origin) @ frame[:2].T], axis=1)
    lo, hi = loop_uv.min(axis=0), loop_uv.max(axis=0)
    diameter = float(np.hypot(*(hi - lo)))
    radius = max(opt.ring_factor * diameter, 3.0 * opt.threshold_mm)
    return _HoleFrame(normal=normal, e1=e1, e2=e2, loop=loop, origin=origin, frame=frame, seg=seg, lo=lo, hi=hi,
                      diameter=diameter, radius=radius)


def _ring_samples(fr: _HoleFrame, v: NDArray[np.float64], dp: NDArray[np.float64],
                  dn: NDArray[np.float64]) -> NDArray[np.int64]:
    """Indices of the data within the ring radius of the border (or inside it) whose normals face the hole."""
    cos_ring = np.cos(np.radians(_RING_MAX_ANGLE_DEG))
    box = ((dp >= v[fr.loop].min(axis=0) - fr.radius).all(axis=1)
           & (dp <= v[fr.loop].max(axis=0) + fr.radius).all(axis=1))
    near = np.flatnonzero(box)
    near = near[(dn[near] @ fr.normal) > cos_ring]
    if near.size:
        # ... and the data inside the hole, if any (sparse samples the fit must honour)
        gap, _ = cKDTree(v[fr.loop]).query(dp[near], distance_upper_bound=fr.radius, workers=-1)
        inside = inside_polygon((dp[near] - fr.origin) @ fr.frame[:2].T, fr.seg)
        near = near[np.isfinite(gap) | inside]
    return near


def _fit_ring(fr: _HoleFrame, v: NDArray[np.float64], dp: NDArray[np.float64], dn: NDArray[np.float64],
              rng: np.random.Generator, opt: _Options) -> _Fit:
    """The best smooth height field fitted to the ring (no model, and why, when none fits)."""
    ring = _ring_samples(fr, v, dp, dn)
    model, how, rms, n_fit, samples = None, "", 0.0, 0, None
    if ring.size >= _MIN_RING:
        if ring.size > opt.max_fit_samples:
            ring = ring[rng.choice(ring.size, opt.max_fit_samples, replace=False)]
        samples = (dp[ring] - fr.origin) @ fr.frame.T
        model, how, rms = _choose_ring_model(samples, opt.tolerance_mm, fr.diameter >= 8.0 * opt.threshold_mm)
        n_fit = int(samples.shape[0])
    return _Fit(model, how, rms, n_fit, samples)


def _fit_border(fr: _HoleFrame, v: NDArray[np.float64], dp: NDArray[np.float64], tree: cKDTree, fit: _Fit,
                opt: _Options) -> _Fit:
    """The table plane under a downward hole resting on it, else the ring fit, else the plane of the border data."""
    model, how, rms, n_fit, samples = fit
    reject = how if model is None and how else ""
    # the data at the border (nearest samples of the border vertices)
    _, rim = tree.query(v[fr.loop], workers=-1)
    rim = np.unique(rim)
    rim_z = float(np.median(dp[rim, 2]))
    floor_z_mm = opt.floor_z_mm
    if (
        floor_z_mm is not None
        and fr.normal[2] < -np.cos(np.radians(_FLOOR_MAX_ANGLE_DEG))
        and abs(rim_z - floor_z_mm) <= _FLOOR_SNAP_MM
    ):
        # the underside of an object resting on the table
        model = _Floor(float(floor_z_mm) - fr.origin[2], fr.e1, fr.e2, fr.normal)
        how, rms, n_fit = "table plane", rim_z - float(floor_z_mm), int(rim.size)
    elif model is None:
        samples = (dp[rim] - fr.origin) @ fr.frame.T
        n_fit = int(samples.shape[0])
        if n_fit < 3:
            return _Fit(None, how, rms, n_fit, samples)
        model = _Plane(samples)
        how, rms = "border", _rms(model, samples)
        if reject:
            how = f"border ({reject})"
    return _Fit(model, how, rms, n_fit, samples)


def _guide_grid(fr: _HoleFrame, spacing_mm: float) -> tuple[NDArray[np.float64], float]:
    """The square grid (1.5 spacings, coarser for huge holes) inside the projected border, and its step (mm)."""
    step = _GUIDE_STEP * float(spacing_mm)
    n_cells = float(np.prod(np.ceil((fr.hi - fr.lo) / step) + 1))
    if n_cells > _MAX_GRID:
        step *= float(np.sqrt(n_cells / _MAX_GRID))
    gu = np.arange(fr.lo[0], fr.hi[0] + step, step)
    gv = np.arange(fr.lo[1], fr.hi[1] + step, step)
    grid = np.stack(np.meshgrid(gu, gv, indexing="xy"), axis=-1).reshape(-1, 2)
    return grid[inside_polygon(grid, fr.seg)], step


def _heights(fit: _Fit, grid: NDArray[np.float64], step: float
             ) -> tuple[_Fit, NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Heights and slopes of the fit on the grid; a sphere branch that leaves the grid is replaced by a spline."""
    model, how, rms, n_fit, samples = fit
    d = 0.5 * step
    hh = model(grid)
    du = (model(grid + [d, 0.0]) - model(grid - [d, 0.0])) / (2 * d)
    dv = (model(grid + [0.0, d]) - model(grid - [0.0, d])) / (2 * d)
    if isinstance(model, _SphereSpline) and not (
        np.all(np.isfinite(hh)) and np.all(np.isfinite(du)) and np.all(np.isfinite(dv))
    ):
        assert samples is not None
        model = _fit("spline", samples)
        how, rms = "spline", _rms(model, samples)
        hh = model(grid)
        du = (model(grid + [d, 0.0]) - model(grid - [d, 0.0])) / (2 * d)
        dv = (model(grid + [0.0, d]) - model(grid - [0.0, d])) / (2 * d)
    return _Fit(model, how, rms, n_fit, samples), hh, du, dv


def _lift(fr: _HoleFrame, grid: NDArray[np.float64], hh: NDArray[np.float64], du: NDArray[np.float64],
          dv: NDArray[np.float64], tree: cKDTree, opt: _Options) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Grid points lifted onto the fit with its normals, less those below the floor or on the data."""
    pts = fr.origin + grid[:, :1] * fr.e1 + grid[:, 1:] * fr.e2 + hh[:, None] * fr.normal
    nrm = fr.normal - du[:, None] * fr.e1 - dv[:, None] * fr.e2
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    if opt.floor_z_mm is not None:  # nothing below the table
        above = pts[:, 2] >= opt.floor_z_mm - 1e-9
        pts, nrm = pts[above], nrm[above]
    dist, _ = tree.query(pts, distance_upper_bound=_KEEP_OFF * opt.threshold_mm, workers=-1)
    off = ~np.isfinite(dist)
    return pts[off], nrm[off]
