"""Photo-consistency of two coloured clouds: the turn about a symmetry axis decided by colour.

A plain turned bowl with a painted or inlaid motif has one free turn about
its axis in shape; the colour its posed photos give each point fixes it.
See docs/processing.md, section "Colour where shape is silent".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from processing.geometry.registration.pose_evidence import PoseEvidence, pose_evidence
from processing.geometry.registration.transforms import _rodrigues, transform_points

__all__ = ["ColourTurn", "chromaticity", "colour_residuals", "turn_by_colour"]


@dataclass(frozen=True)
class ColourTurn:
    """The turn about a symmetry axis that makes two coloured clouds agree best.

    Attributes
    ----------
    transform
        4 x 4 source -> target: the given pose turned by ``angle_deg`` about the axis.
    angle_deg
        The turn applied to the given pose (deg, in (-180, 180]).
    evidence
        Evidence for this turn over the best turn at least ``distinct_deg``
        away (:func:`~processing.geometry.registration.pose_evidence.pose_evidence`
        on the colour residuals).
    second_deg
        The rotation between the two (deg).
    """

    transform: NDArray[np.float64]
    angle_deg: float
    evidence: PoseEvidence
    second_deg: float


def chromaticity(colours: ArrayLike) -> NDArray[np.float64]:
    """``(r, g) / (r + g + b)`` of ``(N, 3)`` linear colours: colour without the shading's intensity.

    NaN where a colour is NaN or black.

    Examples
    --------
    >>> chromaticity([[2.0, 1.0, 1.0], [0.5, 0.25, 0.25]]).tolist()
    [[0.5, 0.25], [0.5, 0.25]]
    """
    c = np.asarray(colours, dtype=np.float64).reshape(-1, 3)
    s = c.sum(axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = c[:, :2] / s
    out[~(s[:, 0] > 0)] = np.nan
    return out


def colour_residuals(
    source_mm: NDArray[np.float64], source_chroma: NDArray[np.float64], target_tree: cKDTree,
    target_chroma: NDArray[np.float64], transforms: NDArray[np.float64], max_distance_mm: float,
) -> NDArray[np.float64]:
    """Chromaticity difference ``(K, N)`` of each source point to its nearest target point under ``K`` poses.

    NaN where the nearest target point is farther than ``max_distance_mm`` or
    either colour is unknown.

    Examples
    --------
    >>> t = np.eye(4)[None]
    >>> tgt = np.array([[0.0, 0, 0], [10, 0, 0]])
    >>> r = colour_residuals(np.array([[0.1, 0, 0]]), np.array([[0.4, 0.3]]), cKDTree(tgt),
    ...                      np.array([[0.4, 0.4], [0.3, 0.3]]), t, 1.0)
    >>> np.round(r, 6).tolist()
    [[0.1]]
    """
    out = np.full((len(transforms), len(source_mm)), np.nan)
    for k, t in enumerate(transforms):   # a few hundred poses, each a vectorised query
        d, idx = target_tree.query(transform_points(t, source_mm), distance_upper_bound=max_distance_mm, workers=-1)
        hit = np.isfinite(d)
        diff = source_chroma[hit] - target_chroma[idx[hit]]
        out[k, hit] = np.sqrt(np.sum(diff * diff, axis=1))
    return out


def _turned(t: NDArray[np.float64], axis: NDArray[np.float64], point: NDArray[np.float64],
            angles_rad: NDArray[np.float64]) -> NDArray[np.float64]:
    """``t`` turned about an axis (target frame) by each angle: ``(K, 4, 4)``."""
    rot = _rodrigues(angles_rad[:, None] * axis[None, :])
    out = np.zeros((len(angles_rad), 4, 4))
    out[:, :3, :3] = rot @ t[:3, :3]
    out[:, :3, 3] = np.einsum("kij,j->ki", rot, t[:3, 3] - point) + point
    out[:, 3, 3] = 1.0
    return out


def turn_by_colour(
    source_mm: ArrayLike, source_colours: ArrayLike, target_mm: ArrayLike, target_colours: ArrayLike,
    transform: ArrayLike, axis: ArrayLike, point_mm: ArrayLike, *, max_distance_mm: float, cell_mm: float,
    distinct_deg: float = 8.0, coarse_deg: float = 2.0, fine_deg: float = 0.1, max_points: int = 6000,
    seed: int = 0, min_chroma_noise: float = 0.005,
) -> ColourTurn:
    """The turn of ``transform`` about a symmetry axis that makes the clouds' colours agree best.

    Parameters
    ----------
    source_mm, target_mm
        ``(N, 3)`` and ``(M, 3)`` points (mm).
    source_colours, target_colours
        ``(N, 3)`` and ``(M, 3)`` linear colours of the points from posed
        photos; NaN where no photo sees a point.
    transform
        4 x 4 source -> target pose that fits the shapes (any turn about the
        axis fits them as well).
    axis, point_mm
        The symmetry axis (unit direction) and a point on it, target frame.
    max_distance_mm
        Largest distance of a source point to its target partner (mm).
    cell_mm
        Cell of the evidence test (mm), see
        :func:`~processing.geometry.registration.pose_evidence.pose_evidence`.
    distinct_deg
        Turns closer than this are the same pose; the evidence is weighed
        against the best turn at least this far away.
    coarse_deg, fine_deg
        Steps of the full sweep and of its refinement (deg).
    max_points
        Source points used (an even random subsample).
    seed
        Seed of the subsample.
    min_chroma_noise
        Smallest chromaticity noise the evidence is weighed against (about
        the resolution of an 8-bit colour on a mid-grey surface).

    Returns
    -------
    ColourTurn
        The best turn, its evidence over the best distinct one, and that rotation.

    Notes
    -----
    The colour of a point is compared as chromaticity ``(r, g) / (r + g + b)``
    (:func:`chromaticity`), so that the shading -- which differs between two
    placements under one lamp -- does not count; a motif of another
    pigment or metal does.  The cost of a turn is the sum of the capped
    squared chromaticity differences; the sweep is rigid (every turn shares
    the given pose's axis and fit), coarse over a full turn and then fine
    about its best.

    Examples
    --------
    A cylinder painted red on one side, turned by 70 deg about its axis:

    >>> rng = np.random.default_rng(0)
    >>> phi, z = rng.uniform(-np.pi, np.pi, 8000), rng.uniform(0, 40, 8000)
    >>> pts = np.stack([30 * np.cos(phi), 30 * np.sin(phi), z], 1)
    >>> col = np.where((np.abs(phi) < 0.5)[:, None], [0.6, 0.1, 0.1], [0.2, 0.2, 0.2])
    >>> turn = _turned(np.eye(4), np.array([0, 0, 1.0]), np.zeros(3), np.radians([70.0]))[0]
    >>> res = turn_by_colour(pts, col, transform_points(turn, pts), col, np.eye(4), [0, 0, 1], [0, 0, 0],
    ...                      max_distance_mm=1.5, cell_mm=3.0)
    >>> bool(abs(res.angle_deg - 70.0) < 0.5), bool(res.evidence.sigma > 5)
    (True, True)
    """
    src = np.asarray(source_mm, dtype=np.float64)
    tgt = np.asarray(target_mm, dtype=np.float64)
    cs, ct = chromaticity(source_colours), chromaticity(target_colours)
    keep = np.all(np.isfinite(cs), axis=1)
    src, cs = src[keep], cs[keep]
    if len(src) > max_points:
        pick = np.random.default_rng(seed).choice(len(src), max_points, replace=False)
        src, cs = src[pick], cs[pick]
    tree = cKDTree(tgt)
    t0 = np.asarray(transform, dtype=np.float64)
    u = np.asarray(axis, dtype=np.float64)
    u = u / np.linalg.norm(u)
    c = np.asarray(point_mm, dtype=np.float64)

    def costs(angles_deg: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        r = colour_residuals(src, cs, tree, ct, _turned(t0, u, c, np.radians(angles_deg)), max_distance_mm)
        scale = np.nanmedian(r[np.isfinite(r)]) if np.isfinite(r).any() else 1.0
        cap = (6.0 * max(float(scale), 1e-6)) ** 2
        filled = np.where(np.isfinite(r), np.minimum(r * r, cap), cap)
        return filled.mean(axis=1), r

    coarse = np.arange(-180.0, 180.0, coarse_deg)
    cost, _ = costs(coarse)
    a0 = float(coarse[int(np.argmin(cost))])
    fine = a0 + np.arange(-coarse_deg, coarse_deg + 1e-9, fine_deg)
    fcost, _ = costs(fine)
    best = float(fine[int(np.argmin(fcost))])
    away = np.abs((coarse - best + 180.0) % 360.0 - 180.0) >= distinct_deg
    second = float(coarse[away][int(np.argmin(cost[away]))]) if away.any() else math.nan
    angles = np.array([best, second if math.isfinite(second) else best])
    _, r = costs(angles)
    t_best = _turned(t0, u, c, np.radians(angles[:1]))[0]
    ev = pose_evidence(r[0], r[1], transform_points(t_best, src), cell_mm, min_noise=min_chroma_noise)
    wrapped = (best + 180.0) % 360.0 - 180.0
    return ColourTurn(t_best, wrapped, ev, abs((second - best + 180.0) % 360.0 - 180.0))
