"""Refinement and scoring of poses: point-to-plane ICP over a voxel pyramid, fit in both directions, verdict.

See docs/processing.md, section "Registration of passes".
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from processing.geometry.registration.clouds import _Cloud, _Level
from processing.geometry.registration.presets import RegistrationPreset
from processing.geometry.registration.results import PairResult
from processing.geometry.registration.transforms import _rodrigues, pose_difference, transform_points

__all__: list[str] = []


def _pyramid(preset: RegistrationPreset, scale: float, *clouds: _Cloud) -> tuple[float, ...]:
    """The ICP voxel sizes (mm) of a pair: the preset's fractions of ``scale``, not finer than the sample spacing.

    Voxels finer than the clouds' sample spacing only add noisy normals.
    """
    floor = preset.min_voxel_spacing * max(c.spacing for c in clouds)
    out: list[float] = []
    for frac in preset.icp_voxels:
        v = max(frac * scale, floor)
        if not out or v < out[-1] * 0.999:
            out.append(v)
    return tuple(out)


def _icp_pyramid(
    src: _Cloud, tgt: _Cloud, preset: RegistrationPreset, init: NDArray[np.float64],
    levels: Sequence[float], first_distance: float | None = None, settled: bool = False,
) -> NDArray[np.float64]:
    """Point-to-plane ICP down a pyramid of voxel sizes (mm), partners restricted to agreeing normals.

    Residuals are weighted by Tukey's biweight with ``k`` = half a voxel
    (a whole voxel on the first level unless the pose has ``settled`` at a
    coarser level already): normals fitted across sharp edges and points
    beyond the other cloud's border would otherwise pull the pose by tenths of
    a degree.  A point's partner is its nearest target point whose normal is
    within ``max_partner_deg`` of its own (:meth:`_Level.partners`): across a
    thin wall the nearest point is often on the other face.
    """
    t = np.asarray(init, dtype=np.float64)
    signed = src.oriented and tgt.oriented
    min_cos = math.cos(math.radians(preset.max_partner_deg))
    for k, voxel in enumerate(levels):
        dist = preset.icp_distance * voxel
        if k == 0 and first_distance is not None:
            dist = max(dist, first_distance)
        kernel = (0.5 * dist) if (k == 0 and not settled) else 0.5 * voxel
        points, normals = src.level(voxel).source_sample(preset.icp_points)
        t = _icp(points, normals, tgt.level(voxel), t, dist, kernel, min_cos, signed, preset.icp_iterations)
    return t


#: Iterations :func:`_settle` allows, in multiples of the preset's ``icp_iterations``.
SETTLE_ITERATIONS = 4


def _settle(
    src: _Cloud, tgt: _Cloud, preset: RegistrationPreset, init: NDArray[np.float64], voxel: float,
) -> NDArray[np.float64]:
    """The pose refined at one level (``voxel`` mm) until ICP converges.

    At most :data:`SETTLE_ITERATIONS` times the preset's ``icp_iterations``.
    Along a nearly free axis (a surface of revolution with a small boss) the
    fit's basin is flat and point-to-plane ICP creeps: the ``icp_iterations``
    of a pyramid level can leave the turn degrees from where the fit
    converges (on a simulated vase turned 6 deg from the truth: 3.2 deg after
    one level's iterations, 1.2 deg converged), and poses compared there are
    compared where neither fits the feature that tells them apart.
    """
    longer = replace(preset, icp_iterations=SETTLE_ITERATIONS * preset.icp_iterations)
    return _icp_pyramid(src, tgt, longer, init, [voxel], settled=True)


def _icp(
    points: NDArray[np.float64], normals: NDArray[np.float64], tgt: _Level, init: NDArray[np.float64],
    dist: float, kernel: float, min_cos: float, signed: bool, iterations: int,
) -> NDArray[np.float64]:
    """Point-to-plane ICP of source points (with normals) onto a level, Tukey-weighted; returns the pose.

    Each iteration pairs every point with :meth:`_Level.partners` within
    ``dist`` (mm), weights the residuals ``r = (x - q) . n_q`` by Tukey's
    biweight ``(1 - (r / kernel)^2)^2`` and solves the 6 x 6 normal equations
    for a small motion (Chen & Medioni 1992), applied as an exact rotation.
    It stops when neither the fraction of paired points nor their RMS
    distance changes by 1e-7 (Open3D's criteria) or after ``iterations``.
    """
    t = init.copy()
    previous = (math.nan, math.nan)
    for _ in range(iterations + 1):
        x = points @ t[:3, :3].T + t[:3, 3]
        nx = normals @ t[:3, :3].T
        d, idx = tgt.partners(x, nx, dist, min_cos, signed)
        hit = np.isfinite(d)
        n_hit = int(hit.sum())
        if n_hit < 6:
            break
        state = (n_hit / len(points), math.sqrt(float(d[hit] @ d[hit]) / n_hit))
        if abs(state[0] - previous[0]) < 1e-7 and abs(state[1] - previous[1]) < 1e-7:
            break
        previous = state
        if _ == iterations:
            break
        xh, nq = x[hit], tgt.normals[idx[hit]]
        r = np.einsum("ij,ij->i", xh - tgt.points[idx[hit]], nq)
        w = np.clip(1.0 - (r / kernel) ** 2, 0.0, None) ** 2
        jac = np.concatenate([np.cross(xh, nq), nq], axis=1)
        jw = jac * w[:, None]
        a = jw.T @ jac
        b = -(jw.T @ r)
        if not np.all(np.isfinite(a)) or np.linalg.matrix_rank(a) < 6:
            break
        step = np.linalg.solve(a, b)
        update = np.eye(4)
        update[:3, :3] = _rodrigues(step[None, :3])[0]
        update[:3, 3] = step[3:]
        t = update @ t
    return t


def _refine_distinct(
    src: _Cloud, tgt: _Cloud, preset: RegistrationPreset,
    hyps: Sequence[NDArray[np.float64]], levels: Sequence[float],
) -> list[NDArray[np.float64]]:
    """ICP of each hypothesis level by level (voxel sizes in mm), merging hypotheses that meet in one basin."""
    poses = list(hyps)
    centre = src.level(levels[0]).points.mean(axis=0)[None]
    for k, voxel in enumerate(levels):
        out: list[NDArray[np.float64]] = []
        for h in poses:
            t = _icp_pyramid(src, tgt, preset, h, [voxel], settled=k > 0)
            differences = (pose_difference(t, o, centre) for o in out)
            if all(rot > 1.0 or disp > voxel for rot, disp in differences):
                out.append(t)
        poses = out
    return poses


@dataclass(frozen=True)
class _Score:
    """Fit of a pose in both directions; ``score`` is filled in by :meth:`at`.

    ``residuals`` holds the point-to-plane residual of every point of the
    source and of the target level (NaN where there is no partner within the
    correspondence distance).
    """

    overlap_source: float
    overlap_target: float
    rmse_mm: float
    normal_agreement: float
    score: float = math.nan
    tau_s: float = math.nan
    expected_mm: float = math.nan
    residuals: tuple[NDArray[np.float64], NDArray[np.float64]] = (np.zeros(0), np.zeros(0))

    def at(self, tau_s: float) -> _Score:
        """The fit with its truncated quadratic score at scale ``tau_s`` (mean of both directions)."""
        score = 0.5 * sum(float(np.mean(_contribution(r, tau_s))) if len(r) else 0.0 for r in self.residuals)
        return replace(self, score=score, tau_s=tau_s)


def _contribution(r: NDArray[np.float64], tau_s: float) -> NDArray[np.float64]:
    """Truncated quadratic ``max(0, 1 - (r / tau_s)^2)``, 0 where ``r`` is NaN (no partner)."""
    with np.errstate(invalid="ignore"):
        return np.where(np.isnan(r), 0.0, np.maximum(0.0, 1.0 - (np.nan_to_num(r) / tau_s) ** 2))


def _common_quality(
    ra: NDArray[np.float64], rb: NDArray[np.float64], tau_s: float
) -> tuple[float, float, int]:
    """Mean contribution of two poses over the points matched under both, and the number of those points.

    The jointly overlapping part is where partial views cannot favour either pose.
    """
    both = ~np.isnan(ra) & ~np.isnan(rb)
    n = int(both.sum())
    if n == 0:
        return 0.0, 0.0, 0
    return float(_contribution(ra[both], tau_s).mean()), float(_contribution(rb[both], tau_s).mean()), n


def _one_way(
    a: _Level, b: _Level, t: NDArray[np.float64], tau: float, signed: bool, min_cos: float
) -> tuple[float, NDArray[np.float64], float]:
    """Overlap fraction of ``a`` mapped by ``t`` onto ``b``, its point-to-plane residuals and summed normal cosines.

    Partners are the nearest points whose normals agree to ``min_cos`` (:meth:`_Level.partners`).
    """
    x = transform_points(t, a.points)
    nx = a.normals @ t[:3, :3].T
    d, idx = b.partners(x, nx, tau, min_cos, signed)
    hit = np.isfinite(d)
    r = np.full(len(x), np.nan)
    if not hit.any():
        return 0.0, r, 0.0
    i = idx[hit]
    r[hit] = np.einsum("ij,ij->i", x[hit] - b.points[i], b.normals[i])
    cos = np.einsum("ij,ij->i", nx[hit], b.normals[i])
    if not signed:
        cos = np.abs(cos)
    return float(hit.mean()), r, float(np.sum(cos))


def _evaluate(src: _Cloud, tgt: _Cloud, t: NDArray[np.float64], voxel: float, preset: RegistrationPreset) -> _Score:
    """Overlap, point-to-plane residuals and normal agreement of a pose, both directions (no partner on the other face)."""
    tau = preset.icp_distance * voxel
    s_lvl, t_lvl = src.level(voxel), tgt.level(voxel)
    signed = src.oriented and tgt.oriented
    # only the other face of a thin wall (normals more than 180 - max_partner_deg apart) is no partner here:
    # leaving out the partners across a box's 90 deg edges too changes which points the two poses of a
    # symmetric shape match, and their evidence with it (a box was verified 180 deg wrong at 6.2 sigma)
    min_cos = -math.cos(math.radians(preset.max_partner_deg))
    fs, rs, cs = _one_way(s_lvl, t_lvl, t, tau, signed, min_cos)
    ft, rt, ct = _one_way(t_lvl, s_lvl, np.linalg.inv(t), tau, signed, min_cos)
    r = np.concatenate([rs, rt])
    r = r[~np.isnan(r)]
    n = len(r)
    return _Score(
        overlap_source=fs,
        overlap_target=ft,
        rmse_mm=math.sqrt(float(r @ r) / n) if n else math.inf,
        normal_agreement=(cs + ct) / n if n else 0.0,
        expected_mm=_expected_residual(src, tgt, voxel),
        residuals=(rs, rt),
    )


def _expected_residual(src: _Cloud, tgt: _Cloud, voxel: float) -> float:
    """Point-to-plane RMS residual expected at the right pose at this level (mm)."""
    spacing = max(voxel, src.spacing, tgt.spacing)
    a, b = src.level(voxel).roughness(spacing), tgt.level(voxel).roughness(spacing)
    return math.sqrt(0.5 * (a * a + b * b))


def _score_scale(src: _Cloud, tgt: _Cloud, voxel: float, preset: RegistrationPreset) -> float:
    """Scale of the truncated quadratic score (mm).

    Three times the residual expected at the right pose from the clouds'
    roughness, kept within [0.02, score_scale] voxels.
    """
    expected = _expected_residual(src, tgt, voxel)
    return float(np.clip(3.0 * expected, 0.02 * voxel, preset.score_scale * voxel))


def _scored(fits: Sequence[_Score], tau_s: float) -> list[_Score]:
    """The fits scored on one scale ``tau_s`` (mm), see :func:`_score_scale`."""
    return [f.at(tau_s) for f in fits]


def _short_of(value: float) -> str:
    """``value`` to one decimal, rounded down: a figure short of a threshold never prints as the threshold.

    Examples
    --------
    >>> _short_of(4.96), _short_of(-0.04), _short_of(12.0)
    ('4.9', '-0.1', '12.0')
    """
    return f"{math.floor(value * 10.0) / 10.0:.1f}"


def _verdict(
    sc: _Score, margin: float, second_deg: float, voxel: float, preset: RegistrationPreset,
    evidence: float = math.nan, ambiguous: bool | None = None,
) -> tuple[bool, str]:
    """Whether a fit passes the preset's checks, and ``"ok"`` or every reason it does not.

    ``ambiguous`` says whether a competing pose is neither clearly worse
    (``margin``) nor ruled out by the ``evidence`` where the two differ
    (standard deviations, :mod:`~processing.geometry.registration.pose_evidence`);
    None: judged by the margin alone.
    """
    reasons = []
    overlap = max(sc.overlap_source, sc.overlap_target)
    if not overlap >= preset.min_overlap:
        reasons.append(
            f"overlap {overlap:.1%} is below {preset.min_overlap:.0%} (the clouds share too little "
            "surface, or the pose is wrong)"
        )
    max_rmse = preset.max_rmse * max(sc.expected_mm, 0.01 * voxel)
    if not sc.rmse_mm <= max_rmse:
        reasons.append(
            f"RMS residual {sc.rmse_mm:.3g} mm exceeds {max_rmse:.3g} mm ({preset.max_rmse:g} x "
            "the clouds' own roughness)"
        )
    if sc.normal_agreement < preset.min_normal_agreement:
        reasons.append(
            f"matched normals disagree (mean cosine {sc.normal_agreement:.2f} < "
            f"{preset.min_normal_agreement:.2f})"
        )
    if ambiguous is None:
        ambiguous = math.isfinite(margin) and margin < preset.min_margin
    if ambiguous:
        where = (f"; where the two differ the evidence is {_short_of(evidence)} sigma of the range noise "
                 f"< {preset.min_evidence:g}" if math.isfinite(evidence) else "")
        reasons.append(
            f"ambiguous: a second pose {second_deg:.1f} deg away fits "
            f"{'nearly as well' if margin >= 0 else 'better'} where both overlap (margin {margin:.1%} < "
            f"{preset.min_margin:.0%}{where}; a nearly symmetric shape?); pick points to register this pair"
        )
    return (not reasons), "; ".join(reasons) if reasons else "ok"


def _pair_scale(*clouds: _Cloud) -> float:
    """Size ``D`` of a set of clouds: the largest bounding-box diagonal (mm)."""
    return max(c.diagonal for c in clouds)


def _pair_result(
    indices: tuple[int, int], t: NDArray[np.float64], sc: _Score, margin: float, second_deg: float,
    ok: bool, reason: str, start: float, method: str, evidence: float = math.nan,
) -> PairResult:
    """The :class:`PairResult` of a fit, timed from ``start`` (``time.perf_counter``)."""
    return PairResult(
        source=indices[0], target=indices[1], transform=t,
        overlap=max(sc.overlap_source, sc.overlap_target),
        overlap_source=sc.overlap_source, overlap_target=sc.overlap_target,
        rmse_mm=sc.rmse_mm, expected_rmse_mm=sc.expected_mm, normal_agreement=sc.normal_agreement,
        score=sc.score,
        margin=margin, second_rotation_deg=second_deg, verified=ok, reason=reason,
        seconds=time.perf_counter() - start, method=method, evidence_sigma=evidence,
    )
