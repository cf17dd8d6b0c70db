"""Nearly symmetric shapes: weak directions of the fit, sweeps about a weak axis, margins over competitors.

A surface of revolution turns about its axis without changing the fit
(Gelfand et al. 2003); such pairs are swept about that axis and reported as
ambiguous when a competing pose fits nearly as well.  See docs/processing.md,
section "Registration of passes".
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from processing.geometry.registration.clouds import _Cloud, _Level, query_workers
from processing.geometry.registration.global_search import _batch_score, _chunked_icp, _distinct, _subsample
from processing.geometry.registration.pose_evidence import (
    PoseEvidence,
    border_points,
    pose_evidence,
    surface_residuals,
)
from processing.geometry.registration.presets import RegistrationPreset
from processing.geometry.registration.refinement import _common_quality, _evaluate, _icp_pyramid, _Score, _settle
from processing.geometry.registration.transforms import (
    _rodrigues,
    _rotation_angle_deg,
    pose_difference,
    transform_points,
)

__all__: list[str] = []


def _stability(
    src: _Level, tgt: _Level, t: NDArray[np.float64], tau: float
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], float]:
    """Eigen-analysis of the point-to-plane information matrix at a pose.

    Gelfand, Ikemoto, Rusinkiewicz & Levoy, "Geometrically stable sampling for
    the ICP algorithm" (3DIM 2003): with rows ``[(x - c) x n / L, n]`` (``c``
    the centroid of the matched points, ``L`` their RMS radius), a small
    eigenvalue of ``J^T J / N`` relative to the largest is a motion that
    leaves the residuals nearly unchanged: a surface of revolution turns
    about its axis, a cylinder also slides along it, a sphere turns freely.

    Returns ascending eigenvalues ``(6,)``, eigenvectors ``(6, 6)`` (columns),
    the centre ``c`` (target frame) and ``L``.
    """
    x = transform_points(t, src.points)
    d, idx = tgt.tree.query(x, distance_upper_bound=tau, workers=query_workers(len(x)))
    hit = np.isfinite(d)
    if hit.sum() < 6:
        return np.zeros(6), np.eye(6), x.mean(axis=0), 1.0
    xh = x[hit]
    nq = tgt.normals[idx[hit]]
    c = xh.mean(axis=0)
    arm = xh - c
    length = float(np.sqrt(np.mean(np.sum(arm * arm, axis=1))))
    jac = np.concatenate([np.cross(arm, nq) / length, nq], axis=1)
    evals, evecs = np.linalg.eigh(jac.T @ jac / len(jac))
    return evals, evecs, c, length


def _weak_axis(
    src: _Level, tgt: _Level, t: NDArray[np.float64], voxel: float, preset: RegistrationPreset,
    nearly: float = 1.0,
) -> tuple[NDArray[np.float64], NDArray[np.float64]] | str | None:
    """The axis (direction, point) of a single weak rotation at ``t``.

    A reason if the pose is undetermined in another way, or None if the fit
    is stable.  With ``nearly`` > 1 a single rotation below ``nearly`` times
    ``min_stability`` counts as weak too (when nothing is below
    ``min_stability`` itself): a small feature on a surface of revolution
    lifts the turn about its axis a little, but the turned poses still
    compete and must be swept and weighed.
    """
    evals, evecs, c, length = _stability(src, tgt, t, preset.icp_distance * voxel)
    if evals[-1] <= 0:
        return "undetermined: no matched points to judge the fit"
    ratio = evals / evals[-1]
    weak = ratio < preset.min_stability
    if not weak.any():
        weak = ratio < nearly * preset.min_stability
        if weak.sum() != 1 or float(np.linalg.norm(evecs[:3, 0])) <= 0.7:
            return None
    e = evecs[:, 0]
    rot_part = float(np.linalg.norm(e[:3]))
    if weak.sum() == 1 and rot_part > 0.7:
        omega = e[:3] / length
        v = e[3:]
        point = c + np.cross(omega, v) / float(omega @ omega)
        return omega / np.linalg.norm(omega), point
    return (
        f"undetermined: {int(weak.sum())} direction(s) of motion barely change the fit "
        f"(stability {ratio[0]:.1e} < {preset.min_stability:g}); the shape is nearly a sphere, "
        "cylinder or plane: pick points to register this pair"
    )


def _axis_turns(
    t: NDArray[np.float64], axis: NDArray[np.float64], point: NDArray[np.float64], steps: int
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """``t`` turned about an axis (target frame) by ``steps`` even angles, and the same upside down.

    Upside down is after a half turn about an axis across it; returns the
    rotations, translations and the rotation angle of each from ``t`` (deg).
    """
    phi = 2.0 * np.pi * np.arange(steps) / steps
    turn = _rodrigues(phi[:, None] * axis[None, :])
    across = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    flip = _rodrigues(np.pi * across[None, :] / np.linalg.norm(across))[0]
    turn = np.concatenate([turn, turn @ flip])
    rot = turn @ t[:3, :3]
    trans = np.einsum("kij,j->ki", turn, t[:3, 3] - point) + point
    return rot, trans, _rotation_angle_deg(turn, np.eye(3))


def _axis_sweep(
    src: _Cloud, tgt: _Cloud, t: NDArray[np.float64], axis: NDArray[np.float64], point: NDArray[np.float64],
    voxel: float, preset: RegistrationPreset, rng: np.random.Generator, score_tau: float,
) -> list[NDArray[np.float64]]:
    """Distinct poses found by turning ``t`` about an axis (target frame) in even steps, refined by batched ICP.

    The batched ICP runs at ``voxel`` (mm).
    """
    s_lvl, t_lvl = src.level(voxel), tgt.level(voxel)
    rot, trans, _ = _axis_turns(t, axis, point, preset.sweep_steps)
    pts = _subsample(s_lvl.points, 4 * preset.search_points, rng)
    grid = t_lvl.grid(voxel / 2.0, 3.0 * voxel)
    taus = voxel * np.array([3.0, 2.0, 2.0, 2.0, 1.5, 1.5, 1.5, 1.5])
    rot, trans, score = _chunked_icp(rot[1:], trans[1:], pts, t_lvl, grid, taus, score_tau)
    order = np.argsort(-score)
    poses = np.zeros((len(order), 4, 4))
    poses[:, :3, :3] = rot[order]
    poses[:, :3, 3] = trans[order]
    poses[:, 3, 3] = 1.0
    scale = max(src.diagonal, tgt.diagonal)
    # every distinct turn, not only the best-scoring few: before refinement the turned poses carry the
    # error of the estimated axis, so their scores do not yet tell which one the feature favours
    return _distinct(poses, s_lvl.points.mean(axis=0), preset, scale, limit=len(poses))


def _competitor_margin(
    overlap: float, others: Sequence[tuple[float, float, float, int, float]], matched: int
) -> tuple[float, float]:
    """Relative margin of a pose over its strongest competitor.

    ``others`` holds, per pose distinct from it, ``(overlap, own, theirs, n,
    rotation_deg)``: its overlap fraction, the mean truncated quadratic
    contribution of this pose (``own``) and of the competitor (``theirs``) over
    the ``n`` points both match, and the rotation between the two.  A
    competitor explains at least half as much of the clouds and shares at
    least a quarter of this pose's ``matched`` points; the margin is the
    smallest ``(own - theirs) / own``.  The comparison is on the common
    points, not on the overlap: partial views of a symmetric shape overlap more
    or less depending on how their missing parts line up, which is no evidence.
    Returns ``(1.0, nan)`` without competitors.
    """
    margin, deg = 1.0, math.nan
    for ov, own, theirs, n, rot in others:
        if ov >= 0.5 * overlap and n >= 0.25 * matched:
            m = (own - theirs) / own if own > 0 else 0.0
            if m < margin:
                margin, deg = m, rot
    return margin, deg


#: A competing pose: ``(margin, rotation_deg, evidence, pose, fit)``, see :func:`_competitors`.
_Competitor = tuple[float, float, PoseEvidence, NDArray[np.float64], _Score]

#: Cell edge of the evidence test in voxels of the level where poses are compared: the radius of the
#: neighbourhood the level's normals are fitted over (3 voxels), over which residuals of neighbouring
#: points share most of their plane.
EVIDENCE_CELL_VOXELS = 3.0


def _evidence(
    src: _Cloud, tgt: _Cloud, t_a: NDArray[np.float64], sc_a: _Score, t_b: NDArray[np.float64], sc_b: _Score,
    voxel: float, memo: dict[Any, Any] | None = None,
) -> PoseEvidence:
    """Evidence for pose ``t_a`` over ``t_b`` on the points of both levels that move between them.

    Source points are placed in the target frame by ``t_a``; a point moves when
    the two poses put it more than two voxels apart (elsewhere the two cannot
    differ).  The residuals are those of true surface partners under each
    pose (:func:`_partner_residuals`), not the fits' nearest neighbours
    (``sc_a``, ``sc_b`` are kept for the interface): a point paired across a
    border under one pose only would weigh as a feature.  See
    :func:`~processing.geometry.registration.pose_evidence.pose_evidence`.
    A pose's residuals depend on the pose alone: ``memo`` (a dict kept for
    one pair of clouds) holds them, so that a pose weighed against many
    others is paired once.
    """
    s_lvl, t_lvl = src.level(voxel), tgt.level(voxel)
    s_pts, t_pts = s_lvl.points, t_lvl.points
    xa, xb = transform_points(t_a, s_pts), transform_points(t_b, s_pts)
    ya, yb = transform_points(np.linalg.inv(t_a), t_pts), transform_points(np.linalg.inv(t_b), t_pts)
    moves = np.concatenate([np.linalg.norm(xa - xb, axis=1), np.linalg.norm(ya - yb, axis=1)]) > 2.0 * voxel
    moves &= np.concatenate([_smooth(s_lvl), _smooth(t_lvl)])
    pos = np.concatenate([xa, t_pts])
    reach_partner = EVIDENCE_REACH_VOXELS * voxel
    memo = {} if memo is None else memo
    ra, rb = (_memo(memo, (t.tobytes(), voxel), lambda t=t: _partner_residuals(s_lvl, t_lvl, t, reach_partner, voxel))
              for t in (t_a, t_b))
    reach = 2.0 * EVIDENCE_CELL_VOXELS * voxel
    rel = np.linalg.inv(t_a) @ t_b
    gap = np.concatenate([_self_gap(s_lvl, rel, reach, voxel), _self_gap(t_lvl, t_a @ np.linalg.inv(t_b), reach, voxel)])
    # two tests, each calibrated: over every moving cell (a feature covering many cells) and over the cells
    # where the predicted surfaces differ (a small one); the stronger counts, at most doubling the chance of
    # a false accept (the union bound)
    diluted = pose_evidence(ra, rb, pos, EVIDENCE_CELL_VOXELS * voxel, moves)
    focused = pose_evidence(ra, rb, pos, EVIDENCE_CELL_VOXELS * voxel, moves, gap_mm=gap)
    return focused if focused.sigma > diluted.sigma else diluted


#: Farthest surface partner of the evidence test, in voxels (the fits' correspondence distance at ``standard``).
EVIDENCE_REACH_VOXELS = 2.0
#: Largest angle between a point's normal and its partner's in the evidence test (deg): a point paired with a
#: surface at a steeper angle (a rim, the far side of a thin wall) is no surface partner.
EVIDENCE_MAX_ANGLE_DEG = 30.0


def _partner_residuals(s_lvl: _Level, t_lvl: _Level, t: NDArray[np.float64], reach: float,
                       spacing: float) -> NDArray[np.float64]:
    """Residuals of both levels' points under pose ``t`` (source then target), NaN without a true partner.

    See :func:`~processing.geometry.registration.pose_evidence.surface_residuals`:
    the partner lies under the point (tangent offset within one ``spacing``),
    its normal agrees within :data:`EVIDENCE_MAX_ANGLE_DEG` and it is not on
    its cloud's border (:func:`_border`).
    """
    rs = surface_residuals(s_lvl.points, s_lvl.normals, t_lvl.points, t_lvl.normals, t, reach, spacing,
                           EVIDENCE_MAX_ANGLE_DEG, _border(t_lvl, spacing), t_lvl.tree)
    rt = surface_residuals(t_lvl.points, t_lvl.normals, s_lvl.points, s_lvl.normals, np.linalg.inv(t), reach,
                           spacing, EVIDENCE_MAX_ANGLE_DEG, _border(s_lvl, spacing), s_lvl.tree)
    return np.concatenate([rs, rt])


def _memo(memo: dict[Any, Any], key: Any, make: Callable[[], Any]) -> Any:
    """``memo[key]``, made by ``make()`` the first time it is asked for."""
    if key not in memo:
        memo[key] = make()
    return memo[key]


def _border(level: _Level, spacing: float) -> NDArray[np.bool_]:
    """The level's border points (:func:`~processing.geometry.registration.pose_evidence.border_points`), cached."""
    cache = level.__dict__.setdefault("_border_masks", {})
    key = round(float(spacing), 9)
    if key not in cache:
        cache[key] = border_points(level.points, level.normals, spacing)
    return cache[key]


def _self_gap(level: _Level, motion: NDArray[np.float64], reach: float, spacing: float) -> NDArray[np.float64]:
    """How far apart two poses predict the surface at each point of a cloud, from the cloud's own geometry.

    Two poses of a pair differ by a rigid ``motion`` of one cloud relative to
    itself (``inv(t_a) @ t_b`` for the source, ``t_a @ inv(t_b)`` for the
    target).  Where the cloud moved by ``motion`` (or its inverse) lies on the
    cloud itself, the poses predict the same surface there and no residual can
    tell them apart; where it lands off it (a boss turned onto a plain belly),
    the distance to the cloud's tangent plane is the difference the residuals
    will show.  0 where the moved point has no point of the cloud within
    ``reach`` (mm) and ``spacing`` (mm, the sample spacing) of the line along
    its normal either way: the cloud cannot say what is there.
    """
    out = np.zeros(len(level.points))
    for m in (motion, np.linalg.inv(motion)):
        x = transform_points(m, level.points)
        d, idx = level.tree.query(x, distance_upper_bound=reach, workers=query_workers(len(x)))
        hit = np.isfinite(d)
        g = np.full(len(x), np.nan)
        off = x[hit] - level.points[idx[hit]]
        along = np.sum(off * level.normals[idx[hit]], axis=1)
        # a point moved past the cloud's border finds its nearest neighbour beside it, not under it
        under = np.linalg.norm(off - along[:, None] * level.normals[idx[hit]], axis=1) <= spacing
        g[np.flatnonzero(hit)[under]] = np.abs(along[under])
        out = np.fmax(out, g)
    return out


def _smooth(level: _Level, k: int = 12, factor: float = 4.0) -> NDArray[np.bool_]:
    """Points where the surface is locally smooth: surface variation within ``factor`` times the cloud's median.

    The surface variation ``lambda_0 / (lambda_0 + lambda_1 + lambda_2)`` of
    the ``k`` nearest neighbours' covariance (Pauly, Gross & Kobbelt 2002) is
    large at sharp edges and rims, where point-to-plane residuals depend on
    which neighbour is matched rather than on the pose; a smooth feature such
    as a boss stays far below it.
    """
    cached = getattr(level, "_smooth_mask", None)
    if cached is not None:
        return cached
    k = min(k, len(level.points))
    _, idx = level.tree.query(level.points, k=k, workers=query_workers(len(level.points)))
    idx = idx.reshape(len(level.points), k)   # k = 1 would give a 1-D array
    nb = level.points[idx]
    d = nb - nb.mean(axis=1, keepdims=True)
    evals = np.linalg.eigvalsh(np.einsum("nki,nkj->nij", d, d))
    var = evals[:, 0] / np.maximum(evals.sum(axis=1), 1e-300)
    mask = var <= factor * float(np.median(var))
    level._smooth_mask = mask  # type: ignore[attr-defined]  # the level's points never change
    return mask


def _competitors(
    src: _Cloud, tgt: _Cloud, voxel: float, poses: Sequence[NDArray[np.float64]], scores: Sequence[_Score],
    best: int, centre: NDArray[np.float64], scale: float, preset: RegistrationPreset,
    memo: dict[Any, Any] | None = None,
) -> list[_Competitor]:
    """The distinct poses that compete with ``poses[best]``: margin, rotation, evidence and pose of each.

    A competitor explains at least half as much of the clouds and shares at
    least a quarter of the best pose's matched points (see
    :func:`_competitor_margin`); its evidence is :func:`_evidence` at
    ``voxel`` (the level where the fits were evaluated), with ``memo`` as there.
    """
    return list(_each_competitor(src, tgt, voxel, poses, scores, best, centre, scale, preset, memo))


def _each_competitor(
    src: _Cloud, tgt: _Cloud, voxel: float, poses: Sequence[NDArray[np.float64]], scores: Sequence[_Score],
    best: int, centre: NDArray[np.float64], scale: float, preset: RegistrationPreset,
    memo: dict[Any, Any] | None = None,
) -> Iterator[_Competitor]:
    """:func:`_competitors` one at a time, in the order of ``poses`` (the evidence of each computed when asked for)."""
    b = scores[best]
    rb = np.concatenate(b.residuals)
    matched = int(np.sum(~np.isnan(rb)))
    overlap = max(b.overlap_source, b.overlap_target)
    for t, sc in zip(poses, scores):
        rot, disp = pose_difference(poses[best], t, centre[None])
        if rot >= preset.distinct_deg or disp >= preset.distinct_fraction * scale:
            own, theirs, n = _common_quality(rb, np.concatenate(sc.residuals), b.tau_s)
            if max(sc.overlap_source, sc.overlap_target) >= 0.5 * overlap and n >= 0.25 * matched:
                m = (own - theirs) / own if own > 0 else 0.0
                yield m, rot, _evidence(src, tgt, poses[best], b, t, sc, voxel, memo), t, sc


def _by_evidence(
    src: _Cloud, tgt: _Cloud, voxel: float, pose: NDArray[np.float64], score: _Score,
    rivals: Sequence[_Competitor], centre: NDArray[np.float64], scale: float, preset: RegistrationPreset,
    memo: dict[Any, Any] | None = None,
) -> tuple[NDArray[np.float64], _Score, list[_Competitor]]:
    """Of a pose and its competitors, the one with the most evidence against all the others.

    The best-scoring pose over the whole overlap is not always the right one
    when only a small feature tells the poses apart; each candidate is weighed
    against every other where they differ and the one whose weakest evidence
    is highest wins (a candidate without competitors of its own counts as
    infinitely supported only if it was the given pose).  The candidates are
    the given pose and the ``hypotheses`` competitors with the least evidence
    against them (those that fit better than it where they differ); each is
    weighed against all (``memo`` as in :func:`_evidence`), and no further
    once one competitor's evidence shows it cannot beat the best so far (the
    answer is the same).  Returns that pose, its fit and its competitors.
    """
    poses = [pose] + [c[3] for c in rivals]
    scores = [score] + [c[4] for c in rivals]
    best_key, out = -math.inf, (pose, score, list(rivals))
    top = [0] + [1 + k for k in np.argsort([c[2].sigma for c in rivals])[: preset.hypotheses]]
    for i in top:
        if i == 0:
            mine = list(rivals)
        else:
            # weighed at its own settled fit, as the given pose is (see refinement._settle)
            poses[i] = _settle(src, tgt, preset, poses[i], voxel)
            scores[i] = _evaluate(src, tgt, poses[i], voxel, preset).at(scores[i].tau_s)
            mine, beaten = [], False
            for c in _each_competitor(src, tgt, voxel, poses, scores, i, centre, scale, preset, memo):
                mine.append(c)
                if c[2].sigma <= best_key:   # its weakest evidence cannot exceed the best so far: no need for the rest
                    beaten = True
                    break
            if beaten or not mine:
                continue
        key = min((c[2].sigma for c in mine), default=math.inf)
        if key > best_key:
            best_key, out = key, (poses[i], scores[i], mine)
    return out


def _decision(competitors: Sequence[_Competitor], preset: RegistrationPreset) -> tuple[float, float, float, bool]:
    """``(margin, rotation_deg, evidence_sigma, ambiguous)`` of a pose over its competitors.

    A competitor is ruled out when the pose fits better than it by at least
    ``min_margin`` where both match, or when the evidence where they differ
    reaches ``min_evidence`` standard deviations.  The figures reported are
    those of the strongest competitor not ruled out (else of the one with the
    least evidence); ``(1.0, nan, nan, False)`` without competitors.
    """
    if not competitors:
        return 1.0, math.nan, math.nan, False
    margin = min(c[0] for c in competitors)
    open_ = [c for c in competitors if c[0] < preset.min_margin and c[2].sigma < preset.min_evidence]
    pool = open_ or list(competitors)
    worst = min(pool, key=lambda c: c[2].sigma)
    return margin, worst[1], worst[2].sigma, bool(open_)


def _refined_competitor(
    src: _Cloud, tgt: _Cloud, t: NDArray[np.float64], voxel: float, preset: RegistrationPreset,
) -> NDArray[np.float64]:
    """A rigidly turned pose refined by ICP at one level (``voxel`` mm), so that its fit is judged at its best.

    Point-to-plane ICP does not slide a pose along an exact symmetry, so a
    competitor on a surface of revolution stays where it was turned to.
    """
    return _icp_pyramid(src, tgt, preset, t, [voxel], settled=True)


def _sweep_margin(
    src: _Cloud, tgt: _Cloud, t: NDArray[np.float64], axis: NDArray[np.float64], point: NDArray[np.float64],
    voxel: float, preset: RegistrationPreset, rng: np.random.Generator, score_tau: float,
) -> tuple[float, float, NDArray[np.float64] | None]:
    """Quality margin of ``t`` over the same pose turned rigidly about a weak axis, and that turned pose.

    There is no refinement, so that a continuous symmetry cannot slide the
    competitors back onto ``t``; see :func:`_competitor_margin`.  The pose is
    the strongest competitor's (None without competitors).
    """
    s_lvl, t_lvl = src.level(voxel), tgt.level(voxel)
    rot, trans, deg = _axis_turns(t, axis, point, preset.sweep_steps)
    pts = _subsample(s_lvl.points, 4 * preset.search_points, rng)
    grid = t_lvl.grid(voxel / 2.0, 3.0 * voxel)
    tgt_p, tgt_n = t_lvl.padded
    _, part, hit = _batch_score(rot, trans, pts, tgt_p, tgt_n, grid, preset.icp_distance * voxel, score_tau)
    overlap = hit.mean(axis=1)
    both = hit & hit[0]
    n = both.sum(axis=1)
    own = (part[0] * both).sum(axis=1) / np.maximum(n, 1)
    theirs = (part * both).sum(axis=1) / np.maximum(n, 1)
    far = np.flatnonzero(deg >= preset.distinct_deg)
    others = [(overlap[k], own[k], theirs[k], int(n[k]), deg[k]) for k in far]
    margin, second = _competitor_margin(float(overlap[0]), others, int(hit[0].sum()))
    pose = None
    ok = far[(overlap[far] >= 0.5 * overlap[0]) & (n[far] >= 0.25 * hit[0].sum())]
    if len(ok):
        m = np.where(own[ok] > 0, (own[ok] - theirs[ok]) / np.where(own[ok] > 0, own[ok], 1.0), 0.0)
        k = int(ok[np.argmin(m)])
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = rot[k], trans[k]
    return margin, second, pose
