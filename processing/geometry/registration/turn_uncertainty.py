"""Uncertainty of a refined pose's rotation, above all of the turn about a nearly free axis.

A nearly symmetric object (a thrown vase with a small boss, a bowl told
apart only by its decoration) fixes the turn about its axis by a small area:
the evidence can pick the right turn while the refined angle is still a
fraction of a degree off.  Such a pair is verified only when the stated
uncertainty of its rotation is within the preset's tolerance.  See
docs/processing.md, section "Nearly symmetric shapes: the turn's uncertainty".
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.geometry.registration.cells import cell_labels
from processing.geometry.registration.photo_consistency import _turned
from processing.geometry.registration.pose_evidence import _MAD_TO_SIGMA, posed_nearest

__all__ = ["position_cells", "profile_turn", "rotation_covariance", "turn_sigma_deg"]

#: Half the span (deg) of the turns over which a fit's cost is profiled about the symmetry axis, and their
#: step: several times the turn over which a point changes its nearest partner (a voxel at the object's
#: radius, about 0.7 deg for a 0.56 mm voxel at 45 mm), within a boss's or a motif's own half width.
PROFILE_SPAN_DEG, PROFILE_STEP_DEG = 3.0, 0.2


def position_cells(positions_mm: ArrayLike, cell_mm: float) -> NDArray[np.int64]:
    """Index of the cubic cell of ``cell_mm`` (mm) each position falls in, 0 .. cells - 1.

    Parameters
    ----------
    positions_mm
        ``(N, 3)`` positions (mm).
    cell_mm
        Edge of the cells (mm), on a grid through the origin.

    Returns
    -------
    numpy.ndarray
        ``(N,)`` cell indices, numbered in the order of the cells' grid coordinates.

    Examples
    --------
    >>> position_cells([[0.1, 0, 0], [0.9, 0, 0], [1.2, 0, 0]], 1.0).tolist()
    [0, 0, 1]
    """
    p = np.asarray(positions_mm, dtype=np.float64).reshape(-1, 3)
    key = np.floor(p / float(cell_mm)).astype(np.int64)
    if len(key):
        key -= key.min(axis=0)
    return cell_labels(key)[0].astype(np.int64)


def rotation_covariance(
    points_mm: ArrayLike, normals: ArrayLike, target_points_mm: ArrayLike, target_normals: ArrayLike,
    transform: ArrayLike, *, reach_mm: float, kernel_mm: float, cell_mm: float, min_cos: float = 0.5,
) -> NDArray[np.float64]:
    r"""Covariance of the rotation of a point-to-plane fit (rad^2), robust to residuals correlated within cells.

    The fit is the Tukey-weighted point-to-plane ICP's: a point ``x`` (moved
    by ``transform``) pairs with its nearest target point ``q`` within
    ``reach_mm`` whose normal ``n`` agrees with its own (cosine at least
    ``min_cos``), residual ``r = (x - q) . n``, Jacobian ``J = [x x n, n]``
    of a small motion ``x + w x x + v``, weight ``w = (1 - (r / k)^2)^2``.
    The covariance of ``(w, v)`` is the cluster-robust sandwich
    ``A^-1 B A^-1`` with ``A = sum w J J^T`` and ``B = sum_c g_c g_c^T``,
    ``g_c = sum_{i in c} w_i r_i J_i`` over cubic cells of ``cell_mm``: the
    residuals of neighbouring points (one voxel's normal fit, one sampling
    profile across a feature) are not independent, and a residual's model
    error counts as its spread does.

    Parameters
    ----------
    points_mm, normals
        ``(N, 3)`` source points (mm) and unit normals, in their own frame.
    target_points_mm, target_normals
        ``(M, 3)`` target points (mm) and unit normals.
    transform
        ``(4, 4)`` the refined pose, source -> target.
    reach_mm, kernel_mm
        Farthest partner and Tukey's ``k`` (mm), as the fit's last level.
    cell_mm
        Cell of the clusters (mm).
    min_cos
        Smallest cosine between a point's normal and its partner's.

    Returns
    -------
    numpy.ndarray
        ``(3, 3)`` covariance of the rotation vector ``w`` (rad^2, target
        frame), the translation marginalised; infinite where the fit leaves
        a motion free.

    References
    ----------
    .. [1] Chen, Y., Medioni, G. (1992). Object modelling by registration of
       multiple range images. Image and Vision Computing 10(3), 145-155.
       doi:10.1016/0262-8856(92)90066-C
    .. [2] Liang, K.-Y., Zeger, S. L. (1986). Longitudinal data analysis using
       generalized linear models. Biometrika 73(1), 13-22.
       doi:10.1093/biomet/73.1.13

    Examples
    --------
    A noisy sphere fits any turn: its rotation is free.  A box's is fixed:

    >>> rng = np.random.default_rng(0)
    >>> d = rng.normal(size=(4000, 3)); d /= np.linalg.norm(d, axis=1, keepdims=True)
    >>> cov = rotation_covariance(20 * d + rng.normal(0, 0.05, (4000, 1)) * d, d, 20 * d, d, np.eye(4),
    ...                          reach_mm=2.0, kernel_mm=0.5, cell_mm=3.0)
    >>> bool(np.isinf(cov).all())
    True
    >>> u = rng.uniform(-10, 10, (6000, 2)); f = rng.integers(0, 6, 6000)
    >>> ax, s = f // 2, np.where(f % 2, 10.0, -10.0)
    >>> pts = np.zeros((6000, 3)); nrm = np.zeros((6000, 3))
    >>> pts[np.arange(6000), ax] = s; nrm[np.arange(6000), ax] = np.sign(s)
    >>> pts[np.arange(6000), (ax + 1) % 3] = u[:, 0]; pts[np.arange(6000), (ax + 2) % 3] = u[:, 1]
    >>> noisy = pts + rng.normal(0, 0.05, (6000, 1)) * nrm
    >>> cov = rotation_covariance(noisy, nrm, pts, nrm, np.eye(4), reach_mm=1.0, kernel_mm=0.5, cell_mm=3.0)
    >>> bool(np.degrees(np.sqrt(np.max(np.linalg.eigvalsh(cov)))) < 0.01)
    True
    """
    x, nx, tp, tn, d, idx = posed_nearest(points_mm, normals, target_points_mm, target_normals, transform, reach_mm)
    hit = np.isfinite(d)
    hit[hit] = np.einsum("ij,ij->i", nx[hit], tn[idx[hit]]) >= min_cos
    free = np.full((3, 3), np.inf)
    if hit.sum() < 6:
        return free
    xh, q, n = x[hit], tp[idx[hit]], tn[idx[hit]]
    r = np.einsum("ij,ij->i", xh - q, n)
    w = np.clip(1.0 - (r / kernel_mm) ** 2, 0.0, None) ** 2
    jac = np.concatenate([np.cross(xh, n), n], axis=1)
    # about the points' centroid, so that rotation and translation are not needlessly correlated
    centre = np.average(xh, axis=0, weights=np.maximum(w, 1e-12))
    jac[:, :3] = np.cross(xh - centre, n)
    a = (jac * w[:, None]).T @ jac
    cells = position_cells(xh, cell_mm)
    g = np.zeros((int(cells.max()) + 1, 6))
    np.add.at(g, cells, jac * (w * r)[:, None])
    b = g.T @ g
    scale = np.sqrt(np.maximum(np.diag(a), 1e-300))
    an = a / np.outer(scale, scale)
    if not np.all(np.isfinite(an)) or np.linalg.cond(an) > 1e12:
        return free
    ainv = np.linalg.inv(an) / np.outer(scale, scale)
    cov = ainv @ b @ ainv
    return 0.5 * (cov[:3, :3] + cov[:3, :3].T)


def turn_sigma_deg(covariance: ArrayLike, axis: ArrayLike | None = None) -> tuple[float, NDArray[np.float64]]:
    """Standard deviation (deg) of the rotation about ``axis``, or about the least certain axis, and that axis.

    Parameters
    ----------
    covariance
        ``(3, 3)`` covariance of a rotation vector (rad^2), see :func:`rotation_covariance`.
    axis
        Optional unit direction; None: the covariance's largest eigenvector.

    Returns
    -------
    sigma_deg, axis
        The standard deviation (deg; inf when free) and the unit axis.

    Examples
    --------
    >>> s, u = turn_sigma_deg(np.diag(np.radians([0.1, 0.2, 0.5]) ** 2))
    >>> round(s, 6), u.round(6).tolist()
    (0.5, [0.0, 0.0, 1.0])
    >>> round(turn_sigma_deg(np.diag(np.radians([0.1, 0.2, 0.5]) ** 2), [1, 0, 0])[0], 6)
    0.1
    """
    cov = np.asarray(covariance, dtype=np.float64)
    if not np.all(np.isfinite(cov)):
        u = np.array([0.0, 0.0, 1.0]) if axis is None else np.asarray(axis, dtype=np.float64)
        return math.inf, u / np.linalg.norm(u)
    if axis is None:
        vals, vecs = np.linalg.eigh(cov)
        u = vecs[:, -1] * (1.0 if vecs[np.argmax(np.abs(vecs[:, -1])), -1] >= 0 else -1.0)
        return math.degrees(math.sqrt(max(float(vals[-1]), 0.0))), u
    u = np.asarray(axis, dtype=np.float64)
    u = u / np.linalg.norm(u)
    return math.degrees(math.sqrt(max(float(u @ cov @ u), 0.0))), u


def profile_turn(turns_deg: ArrayLike, costs: ArrayLike, cells: ArrayLike) -> tuple[float, float]:
    r"""The turn that minimises a cost profiled over turns, and its standard deviation, robust to cells.

    Each cell's cost over the turns is fitted by a parabola
    ``C_c(d) ~ a_c d^2 + b_c d + e_c`` (least squares over all the turns):
    smoothed over the profile's span, the jumps of a residual as its point
    changes its nearest partner (the roughness that gives a fit on a nearly
    featureless surface a local minimum wherever its partners happen to
    fall, and which a fit's local curvature counts as information) average
    out, and only what the whole span shows holds the turn.  The vertex is
    ``d* = -sum b_c / (2 sum a_c)``; as an M-estimate with the cells as
    clusters its variance is ``sum_c (b_c + 2 a_c d*)^2 / (2 sum a_c)^2``
    (each cell's slope at the vertex is its score).  It assumes the summed
    cost is one parabola over the span: where its floor is flat over a
    degree or more (a relief about twice the range noise) the vertex stays
    near the span's centre and the deviation comes out too small.

    Parameters
    ----------
    turns_deg
        ``(K,)`` the turns (deg), at least 3 distinct.
    costs
        ``(K, N)`` each point's cost at each turn (e.g. its squared residual over the noise's variance).
    cells
        ``(N,)`` each point's cell (integers >= 0): points of one cell share their errors.

    Returns
    -------
    vertex_deg, sigma_deg
        The turn (deg) at the vertex and its standard deviation (deg);
        NaN and inf when the summed curvature is not positive (the profile
        has no minimum: nothing holds the turn over the span).

    References
    ----------
    .. [1] Huber, P. J. (1967). The behavior of maximum likelihood estimates under nonstandard conditions.
       Proceedings of the Fifth Berkeley Symposium on Mathematical Statistics and Probability 1, 221-233.
    .. [2] Liang, K.-Y., Zeger, S. L. (1986). Longitudinal data analysis using
       generalized linear models. Biometrika 73(1), 13-22.
       doi:10.1093/biomet/73.1.13

    Examples
    --------
    400 cells, each a parabola whose minimum is drawn about 0.3 deg with a
    spread of 1 deg: the vertex is their mean, and its deviation their
    standard deviation over sqrt(400):

    >>> rng = np.random.default_rng(1)
    >>> d = np.linspace(-2.0, 2.0, 21)
    >>> mu = rng.normal(0.3, 1.0, 400)
    >>> v, sd = profile_turn(d, (d[:, None] - mu) ** 2, np.arange(400))
    >>> bool(abs(v - mu.mean()) < 1e-9), bool(abs(sd - mu.std() / 20) < 1e-9), round(sd, 3)
    (True, True, 0.046)
    >>> profile_turn(d, np.ones((21, 400)), np.arange(400))
    (nan, inf)
    """
    d = np.asarray(turns_deg, dtype=np.float64)
    c = np.asarray(costs, dtype=np.float64)
    labels = np.asarray(cells, dtype=np.int64)
    if len(np.unique(d)) < 3 or c.shape != (len(d), len(labels)) or not len(labels):
        raise ValueError("profile_turn needs costs (turns, points) at 3 or more distinct turns and a cell per point")
    per_cell = np.zeros((int(labels.max()) + 1, len(d)))
    np.add.at(per_cell, labels, c.T)
    a, b, _ = np.linalg.pinv(np.stack([d * d, d, np.ones_like(d)], axis=1)) @ per_cell.T
    curvature = 2.0 * float(a.sum())
    if not curvature > 0.0:
        return math.nan, math.inf
    vertex = -float(b.sum()) / curvature
    # each cell's score over the curvature before squaring: costs near the float range do not overflow
    return vertex, math.sqrt(float(np.sum(((b + 2.0 * a * vertex) / curvature) ** 2)))


def _profiled(s_lvl: Any, t_lvl: Any, t: NDArray[np.float64], axis: NDArray[np.float64],
              centre: NDArray[np.float64], voxel: float) -> tuple[float, float]:
    """:func:`profile_turn` of pose ``t`` turned about ``axis`` through ``centre`` (target frame), at level ``voxel``.

    The cost is each point's squared residual against its true surface
    partner (the evidence's, both clouds' points: within two voxels, under
    the point, normals agreeing), over the noise's variance (the residuals'
    robust spread at ``t``).  It is not capped: a feature's slope carries
    its residuals past any cap within the span, which would flatten the
    profile where it is steepest.  Only points with a partner at every turn
    count, so that none enters or leaves the sum; cells of three voxels, as
    the sandwich's.
    """
    from processing.geometry.registration.symmetry import EVIDENCE_REACH_VOXELS, _partner_residuals
    from processing.geometry.registration.transforms import transform_points

    turns = np.arange(-PROFILE_SPAN_DEG, PROFILE_SPAN_DEG + 1e-9, PROFILE_STEP_DEG)
    poses = _turned(t, axis, centre, np.radians(turns))
    res = np.array([_partner_residuals(s_lvl, t_lvl, p, EVIDENCE_REACH_VOXELS * voxel, voxel) for p in poses])
    every = np.all(np.isfinite(res), axis=0)
    if every.sum() < 6:
        return math.nan, math.inf
    r = res[:, every]
    noise = _MAD_TO_SIGMA * float(np.median(np.abs(r[len(turns) // 2])))
    if not noise > 0.0:
        return math.nan, math.inf
    cost = r * r / noise ** 2
    where = np.concatenate([transform_points(t, s_lvl.points), t_lvl.points])[every]
    return profile_turn(turns, cost, position_cells(where, 3.0 * voxel))


def _about_axis_deg(t: NDArray[np.float64], ref: NDArray[np.float64], axis: NDArray[np.float64]) -> float:
    """The turn (deg) about ``axis`` of the rotation taking pose ``ref`` to pose ``t`` (target frame)."""
    from scipy.spatial.transform import Rotation

    rv = Rotation.from_matrix((t @ np.linalg.inv(ref))[:3, :3]).as_rotvec()
    return math.degrees(float(rv @ axis))


def _shifted_level(cloud: Any, voxel: float, shift: NDArray[np.float64]) -> Any:
    """The cloud's level on a ``voxel`` grid offset by ``shift`` (mm): the same surface sampled at another phase.

    Open3D's grid starts at the cloud's lower corner, so translating the
    cloud does not move it: a lone point below the corner (dropped after)
    sets the grid's origin.
    """
    from processing.geometry.registration.clouds import _downsample, _Level

    anchor = cloud.points.min(axis=0) - 10.0 * voxel - shift
    pts = np.concatenate([cloud.points, anchor[None]])
    nrm = None if cloud.normals is None else np.concatenate([cloud.normals, [[0.0, 0.0, 1.0]]])
    coarse: list[Any] = []

    def coarser() -> Any:   # built only if a normal needs it
        if not coarse:
            coarse.append(_Level(*_drop_near(*_downsample(pts, nrm, 2.0 * voxel), anchor, voxel)))
        return coarse[0]

    return _Level(*_drop_near(*_downsample(pts, nrm, voxel, coarser), anchor, voxel))


def _drop_near(points: NDArray[np.float64], normals: NDArray[np.float64], where: NDArray[np.float64],
               radius: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The points (and normals) farther than ``radius`` from ``where``."""
    keep = np.linalg.norm(points - where, axis=1) > radius
    return points[keep], normals[keep]


def _turn_spread(
    src: Any, tgt: Any, t: NDArray[np.float64], axis: NDArray[np.float64], voxel: float, preset: Any,
    point: ArrayLike,
) -> tuple[float, float, tuple[float, ...]]:
    """The standard deviation (deg) of a refined pose's turn about ``axis``, its noise part, the refits' turns.

    The axis is the symmetry axis through ``point`` (target frame): turned
    about a parallel line elsewhere the surface would also shift, and every
    turn would seem held.

    Three parts, added in quadrature.  The noise: the larger of the
    cluster-robust sandwich of the fit (:func:`rotation_covariance`, cells
    of three voxels), which covers the range noise and residuals correlated
    within a cell, and the standard deviation of the vertex of the fit's
    cost profiled over turns of +- :data:`PROFILE_SPAN_DEG` about the axis
    (:func:`profile_turn`), which does not credit as information what only
    the fit's current partners show (on a relief a few times the noise the
    sandwich stated a tenth of the error).  The spread: the same fit made
    again from ``t`` in the other direction (target onto source), and in
    both directions on voxel grids offset by half a voxel (each cloud
    sampled at another phase, :func:`_shifted_level`), which covers the
    bias of a feature sampled by few profiles.  And the basin: the fit made
    again from ``t`` turned by +- :data:`PROFILE_SPAN_DEG` about the axis on
    the offset grid; where a feature holds the turn both refits reach one
    minimum, where none does they stay or wander apart, and half their
    distance is a turn the data allow.  Probed from the profile's span, not
    from the tolerance's ends: on a relief twice the range noise the fit's
    cost has shallow minima about a degree apart, so refits from +- 0.5 deg
    fell back to the fit while the fit itself lay 0.9-1.5 deg from the
    truth; from +- 3 deg they stay 1-5 deg out, where a boss brings them
    back to one turn.  The spread is the RMS of all five refits' turns from
    ``t`` over sqrt(2): a refit and ``t`` are two estimates of the turn,
    their difference twice as variable as either (two refits from the ends
    that land together away from ``t`` count there).
    """
    from processing.geometry.registration.refinement import _icp

    s_lvl, t_lvl = src.level(voxel), tgt.level(voxel)
    dist, kernel = preset.icp_distance * voxel, 0.5 * voxel
    min_cos = math.cos(math.radians(preset.max_partner_deg))
    signed = src.oriented and tgt.oriented
    pts, nrm = s_lvl.source_sample(preset.icp_points)
    cov = rotation_covariance(pts, nrm, t_lvl.points, t_lvl.normals, t, reach_mm=dist, kernel_mm=kernel,
                              cell_mm=3.0 * voxel, min_cos=min_cos)
    sand, _ = turn_sigma_deg(cov, axis)
    axis, centre = np.asarray(axis, dtype=np.float64), np.asarray(point, dtype=np.float64)
    # the profile's evaluations are spared when the sandwich already leaves the turn unbounded
    noise = max(sand, _profiled(s_lvl, t_lvl, t, axis, centre, voxel)[1]) if math.isfinite(sand) else math.inf
    if not math.isfinite(noise):
        return math.inf, math.inf, ()
    iterations = 2 * preset.icp_iterations
    q, m = t_lvl.source_sample(preset.icp_points)
    bwd = np.linalg.inv(_icp(q, m, s_lvl, np.linalg.inv(t), dist, kernel, min_cos, signed, iterations))
    turns = [_about_axis_deg(bwd, t, axis)]
    shift = np.full(3, 0.5 * voxel)
    a, b = _shifted_level(src, voxel, shift), _shifted_level(tgt, voxel, shift)
    p, n = a.source_sample(preset.icp_points)
    fwd = _icp(p, n, b, t, dist, kernel, min_cos, signed, iterations)
    q, m = b.source_sample(preset.icp_points)
    bwd = np.linalg.inv(_icp(q, m, a, np.linalg.inv(t), dist, kernel, min_cos, signed, iterations))
    turns += [_about_axis_deg(fwd, t, axis), _about_axis_deg(bwd, t, axis)]
    # the basin: refits from the profile's ends, on the offset grid, must reach one minimum
    starts = _turned(t, axis, centre, np.radians([-PROFILE_SPAN_DEG, PROFILE_SPAN_DEG]))
    ends = [_about_axis_deg(_icp(p, n, b, start, dist, kernel, min_cos, signed, iterations), t, axis)
            for start in starts]
    basin = 0.5 * abs(ends[1] - ends[0])
    # a refit and ``t`` are two estimates: their difference has twice the variance of either
    spread = math.sqrt(0.5 * float(np.mean(np.square(turns + ends))))
    sd = math.sqrt(noise * noise + spread * spread + basin * basin)
    return sd, noise, tuple(round(x, 4) for x in turns + ends)
