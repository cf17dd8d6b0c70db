"""Global search without an initial guess: batched point-to-plane ICP from many rotations.

A few hundred to a few thousand starting rotations (super-Fibonacci), plus
the identity and optionally the FPFH + RANSAC estimate, run a cheap
point-to-plane ICP all at once on downsampled clouds, pruned by successive
halving; see docs/processing.md, section "Registration of passes".
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from processing.geometry.registration.clouds import _Cloud, _Level, _NearestGrid
from processing.geometry.registration.presets import RegistrationPreset
from processing.geometry.registration.transforms import _rodrigues, _rotation_angle_deg, rotation_samples

__all__: list[str] = []


def _batch_icp(
    rot: NDArray[np.float64],
    trans: NDArray[np.float64],
    src: NDArray[np.float64],
    tgt: NDArray[np.float64],
    tgt_n: NDArray[np.float64],
    grid: _NearestGrid,
    taus: Sequence[float],
    score_tau: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Point-to-plane ICP of ``K`` candidate poses at once; returns the poses and their scores.

    Each iteration linearises ``R <- exp([w]) R``, ``t <- exp([w]) t + v`` and
    solves the damped 6 x 6 normal equations of the residuals
    ``(x - q) . n_q`` of the correspondences closer than ``tau``.
    """
    rot = rot.copy()
    trans = trans.copy()
    eye6 = np.eye(6)
    src_t = src.T
    for tau in taus:
        x = np.matmul(rot, src_t).transpose(0, 2, 1) + trans[:, None, :]
        idx = grid(x)
        nq = tgt_n[idx]
        diff = x - tgt[idx]
        w = (np.sum(diff * diff, axis=2) < tau * tau).astype(np.float64)
        r = np.sum(diff * nq, axis=2)
        jac = np.concatenate([np.cross(x, nq), nq], axis=2)
        jw = jac * w[..., None]
        a = np.matmul(jw.transpose(0, 2, 1), jac)
        b = -np.matmul(jw.transpose(0, 2, 1), r[..., None])
        damp = 1e-3 * np.trace(a, axis1=1, axis2=2)[:, None, None] / 6.0 + 1e-9
        step = np.linalg.solve(a + damp * eye6, b)[..., 0]
        omega = step[:, :3]
        ang = np.linalg.norm(omega, axis=1, keepdims=True)
        omega = omega * np.minimum(1.0, 0.5 / np.maximum(ang, 1e-12))
        dr = _rodrigues(omega)
        rot = dr @ rot
        trans = np.matmul(dr, trans[..., None])[..., 0] + step[:, 3:]
    score, _, _ = _batch_score(rot, trans, src, tgt, tgt_n, grid, taus[-1], score_tau)
    return rot, trans, score


def _batch_score(
    rot: NDArray[np.float64],
    trans: NDArray[np.float64],
    src: NDArray[np.float64],
    tgt: NDArray[np.float64],
    tgt_n: NDArray[np.float64],
    grid: _NearestGrid,
    tau: float,
    score_tau: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Truncated quadratic score of ``K`` poses, with the per-point contributions and matches ``(K, N)``.

    Source -> target, with the approximate nearest neighbours of ``grid``.
    """
    x = np.matmul(rot, src.T).transpose(0, 2, 1) + trans[:, None, :]
    idx = grid(x)
    diff = x - tgt[idx]
    hit = np.sum(diff * diff, axis=2) < tau * tau
    r = np.sum(diff * tgt_n[idx], axis=2)
    part = np.where(hit, np.maximum(0.0, 1.0 - (r / score_tau) ** 2), 0.0)
    return part.mean(axis=1), part, hit


def _centroid_shift(rot: NDArray[np.float64], c_s: NDArray[np.float64], c_t: NDArray[np.float64]) -> NDArray[np.float64]:
    """Translations ``(K, 3)`` that map the source centroid onto the target centroid after each rotation."""
    return c_t - np.einsum("kij,j->ki", rot, c_s)


def _fpfh_candidate(src: _Level, tgt: _Level, voxel: float, seed: int) -> NDArray[np.float64] | None:
    """FPFH + RANSAC estimate (Rusu et al. 2009), or None if it finds nothing."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    param = o3d.geometry.KDTreeSearchParamHybrid(radius=5.0 * voxel, max_nn=100)
    fs = reg.compute_fpfh_feature(src.pcd, param)
    ft = reg.compute_fpfh_feature(tgt.pcd, param)
    o3d.utility.random.seed(seed)
    res = reg.registration_ransac_based_on_feature_matching(
        src.pcd, tgt.pcd, fs, ft, True, 1.5 * voxel,
        reg.TransformationEstimationPointToPoint(False), 3,
        [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9),
         reg.CorrespondenceCheckerBasedOnDistance(1.5 * voxel)],
        reg.RANSACConvergenceCriteria(20000, 0.999),
    )
    if res.fitness <= 0.0:
        return None
    return np.asarray(res.transformation, dtype=np.float64)


def _global_search(
    src: _Cloud, tgt: _Cloud, scale: float, preset: RegistrationPreset, rng: np.random.Generator
) -> list[NDArray[np.float64]]:
    """Distinct coarse hypotheses (4 x 4, best first) from the sampled rotations."""
    voxel = preset.search_voxel * scale
    s_lvl, t_lvl = src.level(voxel), tgt.level(voxel)
    grid = t_lvl.grid(voxel / 2.0, 6.0 * voxel)
    c_s, c_t = s_lvl.points.mean(axis=0), t_lvl.points.mean(axis=0)

    rot = np.concatenate([np.eye(3)[None], rotation_samples(preset.rotation_samples)])
    trans = _centroid_shift(rot, c_s, c_t)
    sub = _subsample(s_lvl.points, preset.search_points, rng)
    # stage A: every start, few points, shrinking correspondence distance
    taus_a = voxel * np.array([6.0, 4.0, 3.0, 2.5, 2.0, 2.0])
    rot, trans, score = _chunked_icp(rot, trans, sub, t_lvl, grid, taus_a, taus_a[-1])
    keep = max(4 * preset.hypotheses, math.ceil(preset.search_keep * len(rot)))
    order = np.argsort(-score)[:keep]
    rot, trans = rot[order], trans[order]
    if preset.fpfh:
        t_f = _fpfh_candidate(s_lvl, t_lvl, voxel, int(rng.integers(1 << 30)))
        if t_f is not None:
            rot = np.concatenate([rot, t_f[None, :3, :3]])
            trans = np.concatenate([trans, t_f[None, :3, 3]])
    # stage B: the survivors, more points, tight distance
    full = _subsample(s_lvl.points, 4 * preset.search_points, rng)
    taus_b = voxel * np.array([2.0, 2.0, 1.5, 1.5, 1.5, 1.5, 1.5, 1.5])
    rot, trans, score = _chunked_icp(rot, trans, full, t_lvl, grid, taus_b, taus_b[-1])
    order = np.argsort(-score)
    poses = np.zeros((len(order), 4, 4))
    poses[:, :3, :3] = rot[order]
    poses[:, :3, 3] = trans[order]
    poses[:, 3, 3] = 1.0
    return _distinct(poses, c_s, preset, scale)[: preset.hypotheses]


def _chunked_icp(
    rot: NDArray[np.float64],
    trans: NDArray[np.float64],
    src: NDArray[np.float64],
    tgt: _Level,
    grid: _NearestGrid,
    taus: NDArray[np.float64],
    score_tau: float,
    budget: int = 400_000,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """:func:`_batch_icp` in chunks of candidates that keep the arrays a few tens of MB."""
    step = max(1, budget // max(1, len(src)))
    pts, nrm = tgt.padded
    parts = [
        _batch_icp(rot[k : k + step], trans[k : k + step], src, pts, nrm, grid, taus, score_tau)
        for k in range(0, len(rot), step)
    ]
    return tuple(np.concatenate([p[i] for p in parts]) for i in range(3))  # type: ignore[return-value]


def _distinct(
    poses: NDArray[np.float64], c_s: NDArray[np.float64], preset: RegistrationPreset, scale: float,
    limit: int | None = None,
) -> list[NDArray[np.float64]]:
    """Greedy non-maximum suppression of poses (already sorted best first); at most ``limit`` (default 4 x hypotheses)."""
    limit = 4 * preset.hypotheses if limit is None else limit
    kept: list[NDArray[np.float64]] = []
    centres = np.einsum("kij,j->ki", poses[:, :3, :3], c_s) + poses[:, :3, 3]
    alive = np.ones(len(poses), dtype=bool)
    for k in range(len(poses)):  # loop over hypotheses (a few dozen), not points
        if not alive[k]:
            continue
        kept.append(poses[k])
        if len(kept) >= limit:
            break
        same = (_rotation_angle_deg(poses[k, :3, :3][None], poses[:, :3, :3]) < preset.distinct_deg) & (
            np.linalg.norm(centres - centres[k], axis=1) < preset.distinct_fraction * scale
        )
        alive &= ~same
    return kept


def _subsample(points: NDArray[np.float64], n: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """At most ``n`` of the points, drawn at random without replacement."""
    if len(points) <= n:
        return points
    return points[rng.choice(len(points), n, replace=False)]
