"""Smooth completion of holes: a smooth height field fitted around each hole.

Matsuda et al. (section 2) complete the parts a scan missed by fitting a
smooth surface (NURBS patches) to the measured data around each hole.  Here
each hole of a mesh (a connected unsupported region, see
:mod:`processing.geometry.mesh_support`) is completed the same way:

1. **Direction.**  The hole's border is the set of directed edges of
   supported triangles that adjoin the hole, oriented as in those triangles.
   A closed surface oriented outward goes around a hole clockwise seen from
   outside, so the border's vector area ``A = 1/2 sum v_a x v_b`` points
   inward: the hole's outward direction is ``N = -A / |A|``.  Projected
   along ``N`` the border encloses the largest area of any projection, so
   the plane through the border's centroid normal to ``N`` is the domain of
   a height field ``h(u, v)``.
2. **Ring.**  The data within ``ring_factor`` times the border's diameter of
   the border, and any data inside the border, whose normals face ``N``
   (within 75 degrees) are the samples.
3. **Surface.**  Two smooth height fields are fitted to the ring:
   a least-squares sphere (one branch of it; the algebraic fit of Kasa 1976)
   plus a thin-plate spline of the residual, and a thin-plate spline alone
   (Duchon 1977; ``scipy``'s ``RBFInterpolator``, linear polynomial part,
   light smoothing for the range noise).  The spline minimises the bending
   energy ``int h_uu^2 + 2 h_uv^2 + h_vv^2``, so it continues the ring's
   slope and curvature across the hole; the sphere carries curvature over
   wide holes where a spline alone flattens (a 26 mm hole in a 40 mm
   sphere: mean error 0.04 mm with the sphere, 0.36 mm without).  A fit
   whose RMS residual on the ring exceeds ``2.5 noise + 0.1 spacing`` is
   rejected; of two acceptable fits the one that predicts each quarter of
   the ring from the other three best is kept (for holes wider than 8
   support thresholds).  When neither is acceptable -- the ring is no
   height field, as the walls around a flat cut such as the underside of
   an object standing on the table -- the least-squares plane through the
   data at the border closes the hole (the minimal assumption).  When the
   plane the object stands on is known, a hole facing it from just above
   is closed on it, whatever the ring says: the underside rests on the
   table, and a fill must not pass below it.
4. **Guide points.**  The plane is sampled on a square grid (1.5 point
   spacings); the samples inside the projected border (even-odd crossing
   rule, vectorised per grid row) are lifted onto ``h`` and get the normals
   of ``h``; samples within the support threshold of the data are dropped
   (so a fit never doubles measured surface, even where a few samples lie
   inside the hole: two layers a fraction of a millimetre apart would give
   the Poisson surface a spurious tunnel).

The returned guide points, added to the data, make a second screened
Poisson reconstruction close every hole along the fitted surface.

Examples
--------
>>> inside_polygon([[0.5, 0.5], [2.0, 0.5]], [[[0, 0], [1, 0]], [[1, 0], [1, 1]],
...                                          [[1, 1], [0, 1]], [[0, 1], [0, 0]]]).tolist()
[True, False]
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import RBFInterpolator
from scipy.spatial import cKDTree

from processing.geometry.mesh_support import SupportReport
from processing.geometry.mesh_topology import edge_twins

__all__ = ["HoleFit", "HoleGuides", "hole_guide_points", "inside_polygon"]

#: Fewest ring samples for a fit to the ring (else the plane through the border data).
_MIN_RING = 12
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
#: Spline smoothing per fitted sample (scipy ``RBFInterpolator`` units, mm).
_SMOOTHING = 1e-3


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


class _SphereSpline:
    """Height field: one branch of a least-squares sphere plus a spline of the residual."""

    def __init__(self, samples: NDArray[np.float64], smoothing: float) -> None:
        x = samples
        design = np.column_stack([2.0 * x, np.ones(x.shape[0])])
        sol, *_ = np.linalg.lstsq(design, np.einsum("ij,ij->i", x, x), rcond=None)
        self.centre = sol[:3]
        r2 = sol[3] + self.centre @ self.centre
        self.radius = float(np.sqrt(r2)) if r2 > 0 else float("nan")
        self.sign = 1.0 if np.median(x[:, 2] - self.centre[2]) >= 0 else -1.0
        base = self.base(x[:, :2])
        self.valid = bool(np.all(np.isfinite(base)))
        self.spline = (
            RBFInterpolator(x[:, :2], x[:, 2] - base, kernel="thin_plate_spline", degree=1, smoothing=smoothing)
            if self.valid
            else None
        )

    def base(self, uv: NDArray[np.float64]) -> NDArray[np.float64]:
        q = self.radius**2 - np.einsum("ij,ij->i", uv - self.centre[:2], uv - self.centre[:2])
        out = np.full(uv.shape[0], np.nan)
        ok = q >= 0
        out[ok] = self.centre[2] + self.sign * np.sqrt(q[ok])
        return out

    def __call__(self, uv: NDArray[np.float64]) -> NDArray[np.float64]:
        assert self.spline is not None
        return self.base(uv) + self.spline(uv)


class _Plane:
    """Least-squares plane ``h = a + b u + c v`` (the border of a hole ringed by walls)."""

    def __init__(self, samples: NDArray[np.float64]) -> None:
        design = np.column_stack([np.ones(samples.shape[0]), samples[:, 0], samples[:, 1]])
        self.coef, *_ = np.linalg.lstsq(design, samples[:, 2], rcond=None)

    def __call__(self, uv: NDArray[np.float64]) -> NDArray[np.float64]:
        return self.coef[0] + uv @ self.coef[1:]


class _Floor:
    """The plane z = z0 (world) as a height field over a hole's local frame."""

    def __init__(self, z0_local: float, e1: NDArray, e2: NDArray, normal: NDArray) -> None:
        self.z0, self.a, self.b, self.c = z0_local, float(e1[2]), float(e2[2]), float(normal[2])

    def __call__(self, uv: NDArray[np.float64]) -> NDArray[np.float64]:
        return (self.z0 - uv[:, 0] * self.a - uv[:, 1] * self.b) / self.c


def _plain_spline(samples: NDArray[np.float64], smoothing: float) -> RBFInterpolator:
    return RBFInterpolator(samples[:, :2], samples[:, 2], kernel="thin_plate_spline", degree=1, smoothing=smoothing)


def _fit(kind: str, samples: NDArray[np.float64]) -> Any:
    smoothing = _SMOOTHING * samples.shape[0]
    if kind == "sphere":
        model = _SphereSpline(samples, smoothing)
        return model if model.valid else None
    return _plain_spline(samples, smoothing)


def _rms(model: Any, samples: NDArray[np.float64]) -> float:
    r = model(samples[:, :2]) - samples[:, 2]
    return float(np.sqrt(np.mean(r * r))) if np.all(np.isfinite(r)) else float("inf")


def _sector_cv(kind: str, samples: NDArray[np.float64]) -> float:
    """RMS error predicting each quarter of the ring from the other three."""
    angle = np.arctan2(samples[:, 1] - samples[:, 1].mean(), samples[:, 0] - samples[:, 0].mean())
    sector = np.minimum(((angle + np.pi) / (0.5 * np.pi)).astype(np.int64), 3)
    err = []
    for k in range(4):
        test = sector == k
        if test.sum() < 3 or (~test).sum() < _MIN_RING:
            continue
        model = _fit(kind, samples[~test])
        if model is None:
            return float("inf")
        r = model(samples[test, :2]) - samples[test, 2]
        if not np.all(np.isfinite(r)):
            return float("inf")
        err.append(r * r)
    return float(np.sqrt(np.mean(np.concatenate(err)))) if err else float("inf")


def _choose_ring_model(samples: NDArray[np.float64], tolerance: float, cross_validate: bool) -> tuple[Any, str, float]:
    """Best of sphere + spline and plain spline on the ring, or (None, reason, rms)."""
    fitted = []
    worst = 0.0
    for kind in ("sphere", "spline"):
        try:
            model = _fit(kind, samples)
        except (np.linalg.LinAlgError, ValueError):
            model = None
        if model is None:
            continue
        rms = _rms(model, samples)
        worst = max(worst, rms)
        if rms <= tolerance:
            fitted.append((model, kind, rms))
    if not fitted:
        return None, f"no smooth height field fits the ring (RMS {worst:.3g} mm > {tolerance:.3g} mm)", worst
    if len(fitted) > 1 and cross_validate:
        scores = [_sector_cv(kind, samples) for _, kind, _ in fitted]
        return fitted[int(np.argmin(scores))]
    return fitted[0]


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
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    dp = np.asarray(data_points, dtype=np.float64)
    dn = np.asarray(data_normals, dtype=np.float64)
    if not (np.isfinite(spacing_mm) and spacing_mm > 0):
        raise ValueError(f"spacing_mm must be a finite distance > 0 (mm), got {spacing_mm!r}")
    if not (np.isfinite(noise_mm) and noise_mm >= 0):
        raise ValueError(f"noise_mm must be a finite distance >= 0 (mm), got {noise_mm!r}")
    if floor_z_mm is not None and not np.isfinite(floor_z_mm):
        raise ValueError(f"floor_z_mm must be a finite height (mm) or None, got {floor_z_mm!r}")
    if tree is None:
        tree = cKDTree(dp)
    tolerance = 2.5 * float(noise_mm) + 0.1 * float(spacing_mm)
    rng = np.random.default_rng(seed)
    if report.n_holes:
        edges, edge_hole = _border_edges(t, report)
    else:
        edges, edge_hole = np.zeros((0, 2), np.int64), np.zeros(0, np.int64)
    cos_ring = np.cos(np.radians(_RING_MAX_ANGLE_DEG))
    out_p, out_n, out_h, fits = [], [], [], []
    for h in range(report.n_holes):
        e = edges[edge_hole == h]
        none = np.zeros(3)
        if e.shape[0] < 3:
            fits.append(HoleFit(h, False, "no border with the data (an isolated region)", 0, 0, 0.0, none))
            continue
        va, vb = v[e[:, 0]], v[e[:, 1]]
        area_vec = 0.5 * np.cross(va, vb).sum(axis=0)
        border_len = float(np.linalg.norm(vb - va, axis=1).sum())
        amag = float(np.linalg.norm(area_vec))
        if amag <= 1e-6 * border_len**2:
            fits.append(HoleFit(h, False, "the border encloses no area in any direction", 0, 0, 0.0, none))
            continue
        normal = -area_vec / amag
        e1, e2 = _basis(normal)
        loop = np.unique(e.reshape(-1))
        origin = v[loop].mean(axis=0)
        frame = np.stack([e1, e2, normal])
        loop_uv = (v[loop] - origin) @ frame[:2].T
        seg = np.stack([(va - origin) @ frame[:2].T, (vb - origin) @ frame[:2].T], axis=1)
        lo, hi = loop_uv.min(axis=0), loop_uv.max(axis=0)
        diameter = float(np.hypot(*(hi - lo)))
        radius = max(ring_factor * diameter, 3.0 * report.threshold_mm)
        # data within `radius` of the border, facing the hole's direction
        box = (dp >= v[loop].min(axis=0) - radius).all(axis=1) & (dp <= v[loop].max(axis=0) + radius).all(axis=1)
        near = np.flatnonzero(box)
        near = near[(dn[near] @ normal) > cos_ring]
        if near.size:
            # ... and the data inside the hole, if any (sparse samples the fit must honour)
            gap, _ = cKDTree(v[loop]).query(dp[near], distance_upper_bound=radius, workers=-1)
            inside = inside_polygon((dp[near] - origin) @ frame[:2].T, seg)
            near = near[np.isfinite(gap) | inside]
        ring = near
        model, how, rms, n_fit = None, "", 0.0, 0
        if ring.size >= _MIN_RING:
            if ring.size > max_fit_samples:
                ring = ring[rng.choice(ring.size, max_fit_samples, replace=False)]
            samples = (dp[ring] - origin) @ frame.T
            model, how, rms = _choose_ring_model(samples, tolerance, diameter >= 8.0 * report.threshold_mm)
            n_fit = int(samples.shape[0])
        reject = how if model is None and how else ""
        # the data at the border (nearest samples of the border vertices)
        _, rim = tree.query(v[loop], workers=-1)
        rim = np.unique(rim)
        rim_z = float(np.median(dp[rim, 2]))
        if (
            floor_z_mm is not None
            and normal[2] < -np.cos(np.radians(_FLOOR_MAX_ANGLE_DEG))
            and abs(rim_z - floor_z_mm) <= _FLOOR_SNAP_MM
        ):
            # the underside of an object resting on the table
            model = _Floor(float(floor_z_mm) - origin[2], e1, e2, normal)
            how, rms, n_fit = "table plane", rim_z - float(floor_z_mm), int(rim.size)
        elif model is None:
            samples = (dp[rim] - origin) @ frame.T
            n_fit = int(samples.shape[0])
            if n_fit < 3:
                fits.append(HoleFit(h, False, "fewer than 3 samples around the hole", 0, n_fit, 0.0, normal))
                continue
            model = _Plane(samples)
            how, rms = "border", _rms(model, samples)
            if reject:
                how = f"border ({reject})"
        step = _GUIDE_STEP * float(spacing_mm)
        n_cells = float(np.prod(np.ceil((hi - lo) / step) + 1))
        if n_cells > _MAX_GRID:
            step *= float(np.sqrt(n_cells / _MAX_GRID))
        gu = np.arange(lo[0], hi[0] + step, step)
        gv = np.arange(lo[1], hi[1] + step, step)
        grid = np.stack(np.meshgrid(gu, gv, indexing="xy"), axis=-1).reshape(-1, 2)
        grid = grid[inside_polygon(grid, seg)]
        if grid.shape[0] == 0:
            fits.append(HoleFit(h, False, "the hole is narrower than the point spacing", 0, n_fit, rms, normal))
            continue
        d = 0.5 * step
        hh = model(grid)
        du = (model(grid + [d, 0.0]) - model(grid - [d, 0.0])) / (2 * d)
        dv = (model(grid + [0.0, d]) - model(grid - [0.0, d])) / (2 * d)
        if isinstance(model, _SphereSpline) and not (
            np.all(np.isfinite(hh)) and np.all(np.isfinite(du)) and np.all(np.isfinite(dv))
        ):
            model = _fit("spline", samples)
            how, rms = "spline", _rms(model, samples)
            hh = model(grid)
            du = (model(grid + [d, 0.0]) - model(grid - [d, 0.0])) / (2 * d)
            dv = (model(grid + [0.0, d]) - model(grid - [0.0, d])) / (2 * d)
        if not np.all(np.isfinite(hh)) or np.abs(hh).max() > 2.0 * diameter + 10.0 * report.threshold_mm:
            fits.append(HoleFit(h, False, "the fitted surface runs away from the border", 0, n_fit, rms, normal))
            continue
        pts = origin + grid[:, :1] * e1 + grid[:, 1:] * e2 + hh[:, None] * normal
        nrm = normal - du[:, None] * e1 - dv[:, None] * e2
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        if floor_z_mm is not None:  # nothing below the table
            above = pts[:, 2] >= floor_z_mm - 1e-9
            pts, nrm = pts[above], nrm[above]
        dist, _ = tree.query(pts, distance_upper_bound=_KEEP_OFF * report.threshold_mm, workers=-1)
        off = ~np.isfinite(dist)
        pts, nrm = pts[off], nrm[off]
        fits.append(HoleFit(h, bool(pts.shape[0]), how if pts.shape[0] else "the fit lies on the data",
                            int(pts.shape[0]), n_fit, rms, normal))
        out_p.append(pts)
        out_n.append(nrm)
        out_h.append(np.full(pts.shape[0], h, np.int64))
    if out_p:
        return HoleGuides(np.concatenate(out_p), np.concatenate(out_n), np.concatenate(out_h), tuple(fits))
    return HoleGuides(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, np.int64), tuple(fits))
