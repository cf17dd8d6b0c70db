"""Photo-consistency of two coloured clouds: the turn about a symmetry axis decided by colour.

A plain turned bowl with a painted or inlaid motif has one free turn about
its axis in shape; the colour its posed photos give each point fixes it.
Raw colours do not: under one lamp the shading and the highlights of a
surface point differ between two placements.  Each point is therefore given
a class (body or motif) by its chromaticity, which the shading does not
change, after dropping the points a highlight or a grazing view may have
coloured; the turn that makes the classes of overlapping points agree is
weighed against the best turn a distinct angle away by a block sign test.
See docs/processing.md, section "Colour where shape is silent".
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from processing.geometry.registration.cells import cell_labels
from processing.geometry.registration.clouds import SAME_FACE_DEG, query_workers
from processing.geometry.registration.transforms import _rodrigues, transform_points

__all__ = ["ColourClasses", "ColourTurn", "PointColours", "colour_classes", "colour_points", "colour_turn_sd_deg",
           "label_evidence",
           "otsu_threshold", "revolution_axis", "sampling_turn_sd_deg", "turn_by_colour", "MIXED_SHARE"]

#: Points whose chromaticity lies farther than this share of the way from both classes' means are left
#: unlabelled: the camera's lens mixes the two pigments along a motif's edge, and because chromaticity weighs
#: the brighter pigment more, the mix's midpoint moves off the edge by an amount that grows with the spread.
MIXED_SHARE = 0.35


@dataclass(frozen=True)
class PointColours:
    """The colours posed photos give a cloud's points, and how each point was seen.

    Attributes
    ----------
    colours
        ``(N, 3)`` linear RGB; NaN where no photo sees a point.
    lamp_dirs
        Optional ``(N, 3)`` unit directions toward the lamp at each point,
        in the cloud's frame, for the photo that gave its colour (the table
        turns under a lamp fixed in the room).
    camera_mm
        Optional ``(N, 3)`` the camera's centre (mm, cloud frame) of that photo.
    pixel_mm
        Optional ``(N,)`` the side of that photo's pixel on a surface facing
        the camera at the point (mm: its depth over the focal length in
        pixels); with ``camera_mm`` it states how finely the photos locate a
        border between colours (:func:`sampling_turn_sd_deg`).
    """

    colours: NDArray[np.float64]
    lamp_dirs: NDArray[np.float64] | None = None
    camera_mm: NDArray[np.float64] | None = None
    pixel_mm: NDArray[np.float64] | None = None


@dataclass(frozen=True)
class ColourClasses:
    """Two colour classes (body and decoration) of two clouds' points.

    Attributes
    ----------
    source, target
        ``(N,)`` and ``(M,)`` labels: 0 or 1, -1 where a point has no
        trustworthy colour.
    threshold
        Otsu's threshold on the chromaticity along its principal direction.
    effectiveness
        Otsu's separability ``eta`` (between-class over total variance,
        0..1; about 0.64 for one Gaussian, near 1 for two distinct colours).
    gap
        Distance between the two classes' mean chromaticities.
    minority
        Fraction of the labelled points in the smaller class.
    usable
        Whether there are two classes to register by (see :func:`colour_classes`).
    why
        Why not, or ``""``.
    """

    source: NDArray[np.int8]
    target: NDArray[np.int8]
    threshold: float
    effectiveness: float
    gap: float
    minority: float
    usable: bool
    why: str


@dataclass(frozen=True)
class ColourTurn:
    """The turn about a symmetry axis that makes two clouds' colour classes agree best.

    Attributes
    ----------
    transform
        4 x 4 source -> target: the given pose turned by ``angle_deg`` about the axis.
    angle_deg
        The turn applied to the given pose (deg, in [-180, 180)).
    sigma
        Evidence for this turn over the best turn at least ``distinct_deg``
        away (:func:`label_evidence`).
    second_deg
        The rotation between the two (deg).
    disagree_best, disagree_second
        Fraction of the compared points whose classes disagree under each turn.
    cells, points
        Cells and points the evidence rests on.
    sigma_deg
        Standard deviation of the turn (deg): the spread of the fine sweep's
        vertex over bootstrap resamples of its cells (:func:`_bootstrap_vertex`).
    """

    transform: NDArray[np.float64]
    angle_deg: float
    sigma: float
    second_deg: float
    disagree_best: float
    disagree_second: float
    cells: int
    points: int
    sigma_deg: float = math.nan


def otsu_threshold(values: ArrayLike, bins: int = 256) -> tuple[float, float]:
    """Otsu's threshold of ``values`` and its separability ``eta`` (between-class / total variance).

    Parameters
    ----------
    values
        Finite values.
    bins
        Histogram bins over their range.

    Returns
    -------
    threshold, eta
        Values above ``threshold`` are one class; ``eta`` in 0..1 (NaN for
        constant values).

    References
    ----------
    .. [1] Otsu, N. (1979). A threshold selection method from gray-level
       histograms. IEEE Trans. SMC 9(1), 62-66. doi:10.1109/TSMC.1979.4310076

    Examples
    --------
    >>> t, eta = otsu_threshold([0.1] * 90 + [0.9] * 10)
    >>> bool(0.1 < t < 0.9), round(eta, 3)
    (True, 1.0)
    """
    v = np.asarray(values, dtype=np.float64).ravel()
    lo, hi = float(v.min()), float(v.max())
    if not hi > lo:
        return lo, math.nan
    hist, edges = np.histogram(v, bins=bins, range=(lo, hi))
    centres = 0.5 * (edges[:-1] + edges[1:])
    p = hist / hist.sum()
    w0 = np.cumsum(p)
    m0 = np.cumsum(p * centres)
    mt = m0[-1]
    with np.errstate(invalid="ignore", divide="ignore"):
        between = (mt * w0 - m0) ** 2 / (w0 * (1.0 - w0))
    between[~np.isfinite(between)] = 0.0
    k = int(np.argmax(between))
    total = float(np.sum(p * (centres - mt) ** 2))
    return float(edges[k + 1]), float(between[k] / total) if total > 0 else math.nan


def _trusted(points: NDArray[np.float64], normals: NDArray[np.float64] | None, pc: PointColours,
             highlight_deg: float, min_cos: float) -> NDArray[np.float64]:
    """``(N, 2)`` chromaticity ``(r, g) / (r + g + b)`` of the points whose colour can be trusted, NaN elsewhere.

    Dropped: unseen or black points; with normals, lamp and camera also points
    the lamp lights at a grazing angle, the camera sees at a grazing angle, or
    the camera sees within ``highlight_deg`` of the lamp's mirror direction
    (a highlight shows the lamp's colour, not the surface's).
    """
    c = np.asarray(pc.colours, dtype=np.float64).reshape(-1, 3)
    s = c.sum(axis=1)
    ok = np.all(np.isfinite(c), axis=1) & (s > 0) & np.all(c >= 0, axis=1)
    if normals is not None and pc.lamp_dirs is not None and pc.camera_mm is not None:
        n = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
        lamp = np.asarray(pc.lamp_dirs, dtype=np.float64)
        lamp = lamp / np.maximum(np.linalg.norm(lamp, axis=1, keepdims=True), 1e-12)
        view = np.asarray(pc.camera_mm, dtype=np.float64) - points
        view = view / np.maximum(np.linalg.norm(view, axis=1, keepdims=True), 1e-12)
        with np.errstate(invalid="ignore"):
            cos_l = np.sum(n * lamp, axis=1)
            cos_v = np.sum(n * view, axis=1)
            mirror = 2.0 * cos_l[:, None] * n - lamp
            glint = np.sum(mirror * view, axis=1)
            ok &= (cos_l > min_cos) & (cos_v > min_cos) & (glint < math.cos(math.radians(highlight_deg)))
    out = np.full((len(c), 2), np.nan)
    out[ok] = c[ok, :2] / s[ok, None]
    return out


def colour_classes(
    source_mm: ArrayLike, source: PointColours, target_mm: ArrayLike, target: PointColours, *,
    source_normals: ArrayLike | None = None, target_normals: ArrayLike | None = None,
    highlight_deg: float = 30.0, min_cos: float = 0.2, min_eta: float = 0.8, min_gap: float = 0.05,
    min_minority: float = 0.002, mixed_share: float = MIXED_SHARE,
) -> ColourClasses:
    """Body and decoration of two clouds by their chromaticity, with Otsu's threshold on both together.

    Parameters
    ----------
    source_mm, target_mm
        ``(N, 3)`` and ``(M, 3)`` points (mm), each in its own frame.
    source, target
        Their colours (and, optionally, how each point was lit and seen).
    source_normals, target_normals
        Optional outward unit normals; with lamp and camera they drop
        highlights and grazing views.
    highlight_deg
        Points seen within this angle of the lamp's mirror direction are dropped.
    min_cos
        Smallest cosine of the lamp and of the view to the normal.
    min_eta
        Smallest Otsu separability of two classes (one Gaussian gives about
        ``2 / pi``, 0.64).
    min_gap
        Smallest distance between the classes' mean chromaticities (several
        times the spread an 8-bit colour or a shading error gives a mid-grey).
    min_minority
        Smallest fraction of the smaller class in each cloud.
    mixed_share
        Points whose projected chromaticity lies more than this share of the way from both classes'
        means toward the other (0.35: the middle 30 % of the interval) are left unlabelled (-1): a
        lens-mixed edge of the motif, whose chromaticity midpoint sits off the true edge.

    Returns
    -------
    ColourClasses
        The labels and figures; ``usable`` is False for a single colour.

    Notes
    -----
    Chromaticity ``(r, g) / (r + g + b)`` does not change with the shading
    (the cosine of the lamp, a point's distance to it) nor with a cast
    shadow lit by the room, which a point cloud cannot know; it does change
    in a highlight, which the lamp and camera let us drop.  Both clouds'
    chromaticities are projected on their principal direction and split by
    one Otsu threshold, so that one pigment is one class in both.  A motif
    that differs from the body only in lightness (black on white) would need
    the albedo instead, and with it the shadows.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> pts = rng.normal(size=(400, 3))
    >>> red = np.tile([0.6, 0.1, 0.1], (400, 1)); red[:20] = [0.02, 0.02, 0.02]
    >>> cl = colour_classes(pts, PointColours(red), pts, PointColours(red))
    >>> cl.usable, int(cl.source.sum()) in (20, 380)
    (True, True)
    >>> grey = PointColours(np.full((400, 3), 0.3))
    >>> colour_classes(pts, grey, pts, grey).usable
    False
    """
    sp, tp = np.asarray(source_mm, dtype=np.float64), np.asarray(target_mm, dtype=np.float64)
    sn = None if source_normals is None else np.asarray(source_normals, dtype=np.float64)
    tn = None if target_normals is None else np.asarray(target_normals, dtype=np.float64)
    cs = _trusted(sp, sn, source, highlight_deg, min_cos)
    ct = _trusted(tp, tn, target, highlight_deg, min_cos)
    ls, lt = np.full(len(cs), -1, np.int8), np.full(len(ct), -1, np.int8)
    oks, okt = np.isfinite(cs[:, 0]), np.isfinite(ct[:, 0])
    both = np.concatenate([cs[oks], ct[okt]])

    def none(why: str, thr: float = math.nan, eta: float = math.nan, gap: float = 0.0,
             minority: float = 0.0) -> ColourClasses:
        return ColourClasses(ls, lt, thr, eta, gap, minority, False, why)

    if oks.sum() < 10 or okt.sum() < 10:
        return none("too few points with a trustworthy colour")
    centred = both - both.mean(axis=0)
    evals, evecs = np.linalg.eigh(centred.T @ centred / len(both))
    if not evals[-1] > 0:
        return none("one colour: every point has the same chromaticity")
    u = evecs[:, -1]
    proj = centred @ u
    thr, eta = otsu_threshold(proj)
    hi = proj > thr
    gap = float(np.linalg.norm(both[hi].mean(axis=0) - both[~hi].mean(axis=0))) if 0 < hi.sum() < len(hi) else 0.0
    label = hi.astype(np.int8)
    if 0 < hi.sum() < len(hi):                       # a mixed edge: neither pigment's chromaticity, left out
        lo_mean, hi_mean = float(proj[~hi].mean()), float(proj[hi].mean())
        span = hi_mean - lo_mean
        label[(proj > lo_mean + mixed_share * span) & (proj < hi_mean - mixed_share * span)] = -1
    ls[oks] = label[: oks.sum()]
    lt[okt] = label[oks.sum():]
    minor = 1 if hi.mean() < 0.5 else 0
    frac = min(float(np.mean(ls[oks] == minor)), float(np.mean(lt[okt] == minor)))
    if not (eta >= min_eta):
        return none(f"one colour: chromaticities are not two classes (Otsu separability {eta:.2f} < {min_eta:g})",
                    thr, eta, gap, frac)
    if gap < min_gap:
        return none(f"one colour: the two chromaticity classes are {gap:.3f} apart (< {min_gap:g})", thr, eta, gap, frac)
    if frac < min_minority:
        return none(f"the second colour covers {frac:.2%} of a cloud's coloured points (< {min_minority:.1%})",
                    thr, eta, gap, frac)
    return ColourClasses(ls, lt, thr, eta, gap, frac, True, "")


def label_evidence(disagree_a: ArrayLike, disagree_b: ArrayLike, positions_mm: ArrayLike,
                   cell_mm: float) -> tuple[float, int, int]:
    r"""Significance of pose A over pose B from the class disagreements of the same points under each.

    Parameters
    ----------
    disagree_a, disagree_b
        ``(N,)`` 1 where a point's class differs from its partner's under
        that pose, 0 where it agrees, NaN without a partner.
    positions_mm
        ``(N, 3)`` the points' positions (mm) in one frame.
    cell_mm
        Edge of the cubic cells (mm): at least the length over which
        disagreements are correlated (a pixel's footprint, the fitted normals'
        neighbourhood).

    Returns
    -------
    sigma, cells, points
        The significance (positive favours A), the cells where the poses
        differ and the points compared.

    Notes
    -----
    With ``delta_i = d_{B,i} - d_{A,i}`` summed per cell to ``S_j``: under
    the hypothesis that both poses are equally right, swapping A and B
    only changes each cell's sign, so the cells are symmetric about zero
    and the variance of their total is estimated from the cells that favour
    B alone, ``2 sum_{S_j < 0} S_j^2`` (a feature that favours A does not
    inflate it; every correlation within a cell does).  It is not taken
    below the variance for independent points that disagree at the pooled
    rate ``p`` of both poses, ``2 N p (1 - p)`` over ``N`` points.  The
    statistic

    .. math:: z = \sum_j S_j \Big/ \sqrt{\max\big(2 \textstyle\sum_{S_j<0} S_j^2,\; 2 N p (1 - p)\big)}

    is about standard normal under that hypothesis.  It needs no noise
    model: its null is calibrated on the data themselves (as
    :func:`~processing.geometry.registration.pose_evidence.pose_evidence`
    does for range residuals).

    References
    ----------
    .. [1] Künsch, H. R. (1989). The jackknife and the bootstrap for general
       stationary observations. Annals of Statistics 17(3), 1217-1241.
       doi:10.1214/aos/1176347265

    Examples
    --------
    >>> pos = np.stack([np.arange(100.0), np.zeros(100), np.zeros(100)], 1)
    >>> a, b = np.zeros(100), np.zeros(100); b[:10] = 1
    >>> z, cells, n = label_evidence(a, b, pos, 2.0)
    >>> round(z, 2), cells, n
    (3.24, 5, 100)

    Disagreements that do not depend on the pose are noise:

    >>> a[::7] = 1; b = np.roll(a, 3)
    >>> bool(abs(label_evidence(a, b, pos, 2.0)[0]) < 3)
    True
    """
    da = np.asarray(disagree_a, dtype=np.float64).ravel()
    db = np.asarray(disagree_b, dtype=np.float64).ravel()
    pos = np.asarray(positions_mm, dtype=np.float64).reshape(-1, 3)
    use = np.isfinite(da) & np.isfinite(db)
    if use.sum() < 2:
        return 0.0, 0, int(use.sum())
    delta = db[use] - da[use]
    key = np.floor((pos[use] - pos[use].min(axis=0)) / cell_mm).astype(np.int64)
    cell, _ = cell_labels(key)
    sums = np.bincount(cell, weights=delta)
    p = 0.5 * float(np.mean(da[use] + db[use]))
    var = max(2.0 * float(np.sum(np.minimum(sums, 0.0) ** 2)), 2.0 * len(delta) * p * (1.0 - p))
    z = float(sums.sum()) / math.sqrt(var) if var > 0 else 0.0
    return z, int(np.sum(sums != 0)), int(use.sum())


def _turned(t: NDArray[np.float64], axis: NDArray[np.float64], point: NDArray[np.float64],
            angles_rad: NDArray[np.float64]) -> NDArray[np.float64]:
    """``t`` turned about an axis (target frame) by each angle: ``(K, 4, 4)``."""
    rot = _rodrigues(angles_rad[:, None] * axis[None, :])
    out = np.zeros((len(angles_rad), 4, 4))
    out[:, :3, :3] = rot @ t[:3, :3]
    out[:, :3, 3] = np.einsum("kij,j->ki", rot, t[:3, 3] - point) + point
    out[:, 3, 3] = 1.0
    return out


def _disagreement(src: NDArray[np.float64], ls: NDArray[np.int8], tree: cKDTree, lt: NDArray[np.int8],
                  poses: NDArray[np.float64], max_distance_mm: float,
                  normals: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None) -> NDArray[np.float64]:
    """``(K, N)``: 1 where a source point's class differs from its nearest target point's, 0 where equal, NaN without one.

    With ``normals`` (source, target; oriented) a nearest point whose normal is more than
    :data:`~processing.geometry.registration.clouds.SAME_FACE_DEG` from the source point's is no
    partner: it lies on the other face of a thin wall.
    """
    out = np.full((len(poses), len(src)), np.nan)
    min_cos = math.cos(math.radians(SAME_FACE_DEG))
    for k, t in enumerate(poses):   # a few hundred poses, each a vectorised query
        d, idx = tree.query(transform_points(t, src), distance_upper_bound=max_distance_mm,
                            workers=query_workers(len(src)))
        hit = np.isfinite(d)
        i = np.minimum(idx, len(lt) - 1)
        other = lt[i]
        hit &= other >= 0
        if normals is not None:
            hit &= np.einsum("ij,ij->i", normals[0] @ t[:3, :3].T, normals[1][i]) >= min_cos
        out[k, hit] = (ls[hit] != other[hit]).astype(np.float64)
    return out


def _v_vertex(angles_deg: NDArray[np.float64], cost: NDArray[np.float64]) -> float:
    """The vertex of ``a + b |angle - vertex|`` fitted to ``cost`` by least squares (vertex on a 1/4-step grid)."""
    step = float(angles_deg[1] - angles_deg[0]) / 4.0 if len(angles_deg) > 1 else 1.0
    vertices = np.arange(angles_deg[0], angles_deg[-1] + 1e-9, step)
    best, err = float(angles_deg[int(np.argmin(cost))]), math.inf
    for v in vertices:
        x = np.column_stack([np.ones_like(angles_deg), np.abs(angles_deg - v)])
        coef, *_ = np.linalg.lstsq(x, cost, rcond=None)
        e = float(np.sum((x @ coef - cost) ** 2))
        if coef[1] > 0 and e < err:
            best, err = float(v), e
    return best


def turn_by_colour(
    source_mm: ArrayLike, source_labels: ArrayLike, target_mm: ArrayLike, target_labels: ArrayLike,
    transform: ArrayLike, axis: ArrayLike, point_mm: ArrayLike, *, max_distance_mm: float, cell_mm: float,
    distinct_deg: float = 8.0, coarse_deg: float = 2.0, fine_deg: float = 0.1, max_points: int = 4000,
    seed: int = 0, source_normals: ArrayLike | None = None, target_normals: ArrayLike | None = None,
) -> ColourTurn:
    """The turn of ``transform`` about a symmetry axis that makes the clouds' colour classes agree best.

    Parameters
    ----------
    source_mm, target_mm
        ``(N, 3)`` and ``(M, 3)`` points (mm).
    source_labels, target_labels
        ``(N,)`` and ``(M,)`` classes (:func:`colour_classes`), -1 unknown.
    transform
        4 x 4 source -> target pose that fits the shapes (any turn about the
        axis fits them as well).
    axis, point_mm
        The symmetry axis (unit direction) and a point on it, target frame.
    max_distance_mm
        Largest distance of a source point to its target partner (mm).
    cell_mm
        Cell of the evidence test (mm), see :func:`label_evidence`.
    distinct_deg
        Turns closer than this are the same pose; the evidence is weighed
        against the best turn at least this far away.
    coarse_deg, fine_deg
        Steps of the full sweep and of its refinement (deg).
    max_points
        Labelled source points used in the sweep: every point of the
        smaller class and an even random subsample of the larger, weighted
        back (the evidence uses all points of both clouds).
    seed
        Seed of the subsample.
    source_normals, target_normals
        Optional ``(N, 3)`` and ``(M, 3)`` oriented (outward) unit normals:
        a nearest point whose normal is more than
        :data:`~processing.geometry.registration.clouds.SAME_FACE_DEG` from
        the other point's is then no partner (the other face of a thin wall).

    Returns
    -------
    ColourTurn
        The best turn, its evidence over the best distinct one, and the figures.

    Notes
    -----
    The cost of a turn is the fraction of compared source points whose class
    differs from their nearest target point's; the sweep is rigid (every
    turn shares the given pose's axis and fit), coarse over a full turn and
    then fine about its best.

    Examples
    --------
    A cylinder painted dark on one side, turned by 70 deg about its axis:

    >>> rng = np.random.default_rng(0)
    >>> phi, z = rng.uniform(-np.pi, np.pi, 8000), rng.uniform(0, 40, 8000)
    >>> pts = np.stack([30 * np.cos(phi), 30 * np.sin(phi), z], 1)
    >>> lab = (np.abs(phi) < 0.5).astype(np.int8)
    >>> turn = _turned(np.eye(4), np.array([0, 0, 1.0]), np.zeros(3), np.radians([70.0]))[0]
    >>> res = turn_by_colour(pts, lab, transform_points(turn, pts), lab, np.eye(4), [0, 0, 1], [0, 0, 0],
    ...                      max_distance_mm=1.5, cell_mm=3.0)
    >>> bool(abs(res.angle_deg - 70.0) < 0.5), bool(res.sigma > 5)
    (True, True)
    """
    src_all = np.asarray(source_mm, dtype=np.float64)
    ls_all = np.asarray(source_labels, dtype=np.int8)
    tgt_all = np.asarray(target_mm, dtype=np.float64)
    lt_all = np.asarray(target_labels, dtype=np.int8)
    keep = ls_all >= 0
    src_all, ls_all = src_all[keep], ls_all[keep]
    oriented = source_normals is not None and target_normals is not None
    ns_all = np.asarray(source_normals, dtype=np.float64)[keep] if oriented else None
    nt_all = np.asarray(target_normals, dtype=np.float64) if oriented else None
    # the sweep: every point of the smaller class, an even subsample of the larger one, weighted back
    minor = int(np.mean(ls_all) < 0.5)
    few = np.flatnonzero(ls_all == minor)
    many = np.flatnonzero(ls_all != minor)
    room = max(max_points - len(few), 1)
    pick = many if len(many) <= room else np.random.default_rng(seed).choice(many, room, replace=False)
    sub = np.concatenate([few, pick])
    src, ls = src_all[sub], ls_all[sub]
    fwd = (ns_all, nt_all) if ns_all is not None and nt_all is not None else None
    fwd_sub = (fwd[0][sub], fwd[1]) if fwd is not None else None
    weight = np.concatenate([np.ones(len(few)), np.full(len(pick), len(many) / max(len(pick), 1))])
    tree = cKDTree(tgt_all)
    t0 = np.asarray(transform, dtype=np.float64)
    u = np.asarray(axis, dtype=np.float64)
    u = u / np.linalg.norm(u)
    c = np.asarray(point_mm, dtype=np.float64)

    def costs(angles_deg: NDArray[np.float64]) -> NDArray[np.float64]:
        d = _disagreement(src, ls, tree, lt_all, _turned(t0, u, c, np.radians(angles_deg)), max_distance_mm,
                          fwd_sub)
        w = np.where(np.isfinite(d), weight, 0.0)
        n = w.sum(axis=1)
        return np.where(n > 0, np.sum(np.nan_to_num(d) * w, axis=1) / np.maximum(n, 1e-300), 1.0)

    coarse = np.arange(-180.0, 180.0, coarse_deg)
    cost = costs(coarse)
    a0 = float(coarse[int(np.argmin(cost))])
    # fine: every labelled point of both clouds; the vertex of a V fitted to the cost, which grows with
    # the points a border moves over, is steadier than the noisy minimum of a few border points
    fine = a0 + np.arange(-coarse_deg, coarse_deg + 1e-9, fine_deg)
    fposes = _turned(t0, u, c, np.radians(fine))
    tk = lt_all >= 0
    back_tree = cKDTree(src_all)
    bwd = (fwd[1][tk], fwd[0]) if fwd is not None else None
    both = np.concatenate([_disagreement(src_all, ls_all, tree, lt_all, fposes, max_distance_mm, fwd),
                           _disagreement(tgt_all[tk], lt_all[tk], back_tree, ls_all, np.linalg.inv(fposes),
                                         max_distance_mm, bwd)], axis=1)
    best = _v_vertex(fine, np.nansum(both, axis=1))
    at = np.concatenate([transform_points(_turned(t0, u, c, np.radians([a0]))[0], src_all), tgt_all[tk]])
    sd = _bootstrap_vertex(fine, both, at, cell_mm, seed)
    away = np.abs((coarse - best + 180.0) % 360.0 - 180.0) >= distinct_deg
    second = float(coarse[away][int(np.argmin(cost[away]))]) if away.any() else best
    poses = _turned(t0, u, c, np.radians([best, second]))
    # the evidence: every labelled point of both clouds, each against its partner in the other
    d = _disagreement(src_all, ls_all, tree, lt_all, poses, max_distance_mm, fwd)
    back = _disagreement(tgt_all[tk], lt_all[tk], back_tree, ls_all,
                         np.linalg.inv(poses), max_distance_mm, bwd)
    da, db = np.concatenate([d[0], back[0]]), np.concatenate([d[1], back[1]])
    pos = np.concatenate([transform_points(poses[0], src_all), tgt_all[tk]])
    z, cells, points = label_evidence(da, db, pos, cell_mm)
    wrapped = (best + 180.0) % 360.0 - 180.0
    return ColourTurn(poses[0], wrapped, z, abs((second - best + 180.0) % 360.0 - 180.0),
                      float(np.nanmean(da)) if np.isfinite(da).any() else math.nan,
                      float(np.nanmean(db)) if np.isfinite(db).any() else math.nan, cells, points, sd)


def _bootstrap_vertex(angles_deg: NDArray[np.float64], disagree: NDArray[np.float64], positions_mm: NDArray[np.float64],
                      cell_mm: float, seed: int, resamples: int = 200) -> float:
    """Standard deviation (deg) of :func:`_v_vertex` of the summed ``(K, N)`` disagreements over resampled cells.

    The points are pooled into cubic cells of ``cell_mm`` (neighbouring
    points share a border and a colour fit); the cells are drawn with
    replacement ``resamples`` times and the vertex found again each time
    (Efron & Tibshirani 1993, doi:10.1007/978-1-4899-4541-9).
    """
    from processing.geometry.registration.turn_uncertainty import position_cells

    cell = position_cells(positions_mm, cell_mm)
    per_cell = np.zeros((int(cell.max()) + 1, len(angles_deg)))
    np.add.at(per_cell, cell, np.nan_to_num(disagree).T)
    n = len(per_cell)
    counts = np.random.default_rng(seed).multinomial(n, np.full(n, 1.0 / n), size=resamples)
    cost = counts @ per_cell                                        # (B, K)
    step = float(angles_deg[1] - angles_deg[0]) / 4.0 if len(angles_deg) > 1 else 1.0
    vertices = np.arange(angles_deg[0], angles_deg[-1] + 1e-9, step)
    x = np.stack([np.ones((len(vertices), len(angles_deg))), np.abs(angles_deg[None] - vertices[:, None])], -1)
    coef = np.linalg.pinv(x) @ cost.T                              # (V, 2, B)
    err = np.sum((x @ coef - cost.T[None]) ** 2, axis=1)            # (V, B)
    err = np.where(coef[:, 1] > 0, err, np.inf)
    best = vertices[np.argmin(err, axis=0)]
    return float(np.std(best))


def sampling_turn_sd_deg(points_mm: ArrayLike, labels: ArrayLike, colours: PointColours, axis: ArrayLike,
                          point_mm: ArrayLike, reach_mm: float, *, min_sin: float = 0.2) -> float:
    """Standard deviation (deg) of a turn about an axis that the photos' pixels leave in one cloud's colour borders.

    A photo places a border between two colours only to within its pixel:
    where inside the pixel the border falls does not show, and the same
    frame colours every point of a stretch of border, so the cells'
    bootstrap (:func:`_bootstrap_vertex`) cannot see the shift.  Taken as
    uniform over the pixel's footprint along the turn's direction, it is
    ``footprint / sqrt(12)``, here the median over the cloud's border
    points of the footprint as an angle about the axis.

    Parameters
    ----------
    points_mm
        ``(N, 3)`` the cloud's points (mm), in the frame of ``axis``.
    labels
        ``(N,)`` colour classes, -1 unknown (:func:`colour_classes`).
    colours
        The cloud's :class:`PointColours`; without ``pixel_mm`` and
        ``camera_mm`` the colours are taken as measured at the points
        themselves and the answer is 0.
    axis, point_mm
        The symmetry axis (direction) and a point on it, the cloud's frame.
    reach_mm
        A border point has a point of the other class within twice this (mm).
    min_sin
        Smallest sine between the turn's direction and the view (a view
        along the turn's direction stretches a pixel without bound; the
        colours' own ``min_cos`` keeps it above 0.2).

    Returns
    -------
    float
        The standard deviation (deg); 0 without pixel sizes or border points.

    References
    ----------
    .. [1] Sheppard, W. F. (1897). On the calculation of the most probable
       values of frequency-constants, for data arranged according to
       equidistant divisions of a scale. Proceedings of the London
       Mathematical Society 29, 353-380. doi:10.1112/plms/s1-29.1.353

    Examples
    --------
    A cylinder of radius 30 mm painted on one half, each point seen face on
    from 300 mm by a camera of focal length 600 px (a pixel is 0.5 mm on
    the surface, 0.955 deg about the axis):

    >>> phi = np.radians(np.arange(-180.0, 180.0, 0.5))
    >>> z = np.arange(0.0, 10.0, 0.5)
    >>> pp, zz = np.meshgrid(phi, z)
    >>> pts = np.stack([30 * np.cos(pp.ravel()), 30 * np.sin(pp.ravel()), zz.ravel()], 1)
    >>> lab = (pp.ravel() > 0).astype(np.int8)
    >>> out = pts * np.array([1.0, 1.0, 0.0]) / 30.0
    >>> pc = PointColours(np.ones((len(pts), 3)), None, pts + 300.0 * out, np.full(len(pts), 0.5))
    >>> round(sampling_turn_sd_deg(pts, lab, pc, [0, 0, 1], [0, 0, 0], 0.3), 3)
    0.276
    """
    if colours.pixel_mm is None or colours.camera_mm is None:
        return 0.0
    p = np.asarray(points_mm, dtype=np.float64).reshape(-1, 3)
    lab = np.asarray(labels).ravel()
    pixel = np.asarray(colours.pixel_mm, dtype=np.float64).ravel()
    cam = np.asarray(colours.camera_mm, dtype=np.float64).reshape(-1, 3)
    keep = (lab >= 0) & np.isfinite(pixel) & np.all(np.isfinite(cam), axis=1)
    if not (np.any(lab[keep] == 0) and np.any(lab[keep] == 1)):
        return 0.0
    pts, cls = p[keep], lab[keep]
    near = np.stack([np.isfinite(cKDTree(pts[cls == c]).query(pts, distance_upper_bound=2.0 * reach_mm)[0])
                     for c in (0, 1)], axis=1)
    at = np.flatnonzero(keep)[near[np.arange(len(cls)), 1 - cls]]       # the border points
    u = np.asarray(axis, dtype=np.float64)
    u = u / np.linalg.norm(u)
    tangent = np.cross(u, p[at] - np.asarray(point_mm, dtype=np.float64))
    radius = np.linalg.norm(tangent, axis=1)
    ok = radius > 1e-9
    if not ok.any():
        return 0.0
    at, tangent, radius = at[ok], tangent[ok] / radius[ok, None], radius[ok]
    view = cam[at] - p[at]
    view /= np.maximum(np.linalg.norm(view, axis=1, keepdims=True), 1e-12)
    sin = np.sqrt(np.maximum(1.0 - np.einsum("ij,ij->i", tangent, view) ** 2, 0.0))
    footprint_deg = np.degrees(pixel[at] / np.maximum(sin, min_sin) / radius)
    return float(np.median(footprint_deg)) / math.sqrt(12.0)


def colour_turn_sd_deg(turn: ColourTurn, source_mm: ArrayLike, source_labels: ArrayLike, source: PointColours,
                       target_mm: ArrayLike, target_labels: ArrayLike, target: PointColours, axis: ArrayLike,
                       point_mm: ArrayLike, reach_mm: float) -> float:
    """Standard deviation (deg) of a colour-decided turn: the borders' scatter and both clouds' photo sampling.

    Parameters
    ----------
    turn
        The turn (:func:`turn_by_colour`); its ``sigma_deg`` is the bootstrap's part.
    source_mm, source_labels, source
        The source cloud's points (mm, its own frame), colour classes and colours.
    target_mm, target_labels, target
        The same for the target.
    axis, point_mm
        The symmetry axis and a point on it, target frame (``turn.transform`` carries them to the source's).
    reach_mm
        The partner distance (:func:`sampling_turn_sd_deg`).

    Returns
    -------
    float
        ``hypot(turn.sigma_deg, source's sampling, target's sampling)`` (deg).
    """
    u = np.asarray(axis, dtype=np.float64)
    c = np.asarray(point_mm, dtype=np.float64)
    r, shift = turn.transform[:3, :3], turn.transform[:3, 3]
    return math.hypot(turn.sigma_deg,
                      sampling_turn_sd_deg(source_mm, source_labels, source, r.T @ u, r.T @ (c - shift), reach_mm),
                      sampling_turn_sd_deg(target_mm, target_labels, target, u, c, reach_mm))


def colour_points(
    points_mm: ArrayLike, normals: ArrayLike, frames: Sequence[Any], images: Sequence[Any], *,
    min_cos: float = 0.2, highlight_deg: float = 30.0, cell_px: float | None = None,
) -> PointColours:
    """Colours of a pass's points from its posed frames: each point from the frame that sees it most frontally.

    The pass's points are in its own table frame, so a frame of that pass is
    posed with the pass pose the identity
    (:meth:`~processing.appearance.frame_poses.FramePose.from_chain`).  A
    frame colours a point when the point faces its camera and its (most
    directly lighting) lamp at more than ``min_cos``, the camera is more than
    ``highlight_deg`` from the lamp's mirror direction (a highlight shows the
    lamp's colour; without a lamp calibration, frames without lamps: only the
    view is checked and ``lamp_dirs`` is None), and no nearer point of the cloud hides it: the points'
    camera depths are binned into cells of ``cell_px`` pixels (default: two
    sample spacings as the frame sees them), the nearest depth of each
    cell's 3 x 3 neighbourhood is the surface's, and a point deeper than it
    by more than a sample spacing plus three spacings times the tangent of
    its view angle is hidden.  There is no mesh yet when passes are
    registered; the cloud itself is the occluder.

    Parameters
    ----------
    points_mm, normals
        ``(N, 3)`` points (mm) and outward unit normals of the pass.
    frames
        :class:`~processing.appearance.frame_poses.FramePose` of the pass's
        frames, posed in the pass's frame (pass pose the identity).
    images
        ``images[k]``: linear ``(H, W, 3)`` image of ``frames[k]`` (a lazy
        sequence is read one frame at a time).
    min_cos, highlight_deg, cell_px
        See above.

    Returns
    -------
    PointColours
        The colour, lamp direction, camera centre and pixel size of each
        point (NaN where no frame colours it), for ``source_colours`` / ``target_colours`` of
        :func:`~processing.geometry.registration.register_pair` and
        ``colours`` of ``register_passes``.

    Raises
    ------
    InputError
        Points and normals of different shapes, or an image of another size
        than its frame's.

    Examples
    --------
    A grey plane seen from above by one frame whose left half is red:

    >>> from processing.appearance.frame_poses import FramePose, MeshLamp
    >>> xy = np.stack(np.meshgrid(np.arange(-10, 10.0), np.arange(-10, 10.0)), -1).reshape(-1, 2)
    >>> pts = np.column_stack([xy, np.zeros(len(xy))])
    >>> nrm = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    >>> k = [[200.0, 0, 50], [0, 200.0, 50], [0, 0, 1]]
    >>> cam = np.diag([1.0, -1.0, -1.0, 1.0]); cam[2, 3] = 100.0     # 100 mm above, looking down
    >>> f = FramePose("f", 1, 0.0, (100, 100), k, np.zeros(5), cam, (MeshLamp("lamp", "distant", [0.6, 0, 0.8]),))
    >>> img = np.full((100, 100, 3), 0.5, np.float32); img[:, :50] = [0.8, 0.1, 0.1]
    >>> pc = colour_points(pts, nrm, [f], [img])
    >>> bool(np.all(pc.colours[pts[:, 0] < -1, 0] > 0.7)), bool(np.all(pc.colours[pts[:, 0] > 1, 1] > 0.45))
    (True, True)
    """
    from processing.appearance.frame_poses import AppearanceError
    from processing.appearance.observations import bilinear
    from processing.appearance.projection import project_points

    p = np.asarray(points_mm, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or n.shape != p.shape:
        raise AppearanceError(f"colour_points: points {p.shape} and normals {n.shape} must both be (N, 3)")
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    spacing = _median_spacing(p)
    colours = np.full((len(p), 3), np.nan)
    lamp_dirs = np.full((len(p), 3), np.nan)
    camera = np.full((len(p), 3), np.nan)
    pixel = np.full(len(p), np.nan)
    best = np.full(len(p), min_cos)
    glint_cos = math.cos(math.radians(highlight_deg))
    lit = all(frame.lamps for frame in frames)
    for k, frame in enumerate(frames):
        centre = frame.camera_centre_mm
        view = centre - p
        dist = np.linalg.norm(view, axis=1)
        view /= dist[:, None]
        cos_v = np.sum(n * view, axis=1)
        candidate = cos_v > best
        if lit:
            lamps = _lamp_directions(frame, p)
            cos_l_all = np.einsum("nlc,nc->nl", lamps, n)
            which = np.argmax(cos_l_all, axis=1)
            lamp = lamps[np.arange(len(p)), which]
            cos_l = cos_l_all[np.arange(len(p)), which]
            mirror = 2.0 * cos_l[:, None] * n - lamp
            candidate &= (cos_l > min_cos) & (np.sum(mirror * view, axis=1) < glint_cos)
        if not candidate.any():
            continue
        uv, depth = project_points(p, frame)
        w, h = frame.image_size
        inside = np.all(np.isfinite(uv), axis=1) & (depth > 0)
        inside &= (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)
        candidate &= inside
        if not candidate.any():
            continue
        cell = cell_px or max(1.0, 2.0 * spacing * float(frame.K[0, 0]) / float(np.median(depth[inside])))
        tan_v = np.sqrt(np.maximum(1.0 - cos_v ** 2, 0.0)) / np.maximum(cos_v, min_cos)
        candidate &= depth <= _surface_depth(uv, depth, inside, cell) + spacing * (1.0 + 3.0 * tan_v)
        if not candidate.any():
            continue
        img = np.asarray(images[k], dtype=np.float32)
        if img.ndim != 3 or img.shape[:2] != (h, w) or img.shape[2] < 3:
            raise AppearanceError(f"frame {frame.name!r}: image of shape {img.shape}; expected ({h}, {w}, 3)")
        idx = np.flatnonzero(candidate)
        colours[idx] = bilinear(img[..., :3], uv[idx])
        if lit:
            lamp_dirs[idx] = lamp[idx]
        camera[idx] = centre
        pixel[idx] = depth[idx] / float(frame.K[0, 0])
        best[idx] = cos_v[idx]
    return PointColours(colours, lamp_dirs if lit else None, camera, pixel)


def _surface_depth(uv: NDArray[np.float64], depth: NDArray[np.float64], inside: NDArray[np.bool_],
                   cell_px: float) -> NDArray[np.float64]:
    """The nearest camera depth (mm) in the 3 x 3 cells of ``cell_px`` around each point (inf outside the image)."""
    from scipy.ndimage import minimum_filter

    ij = np.floor(uv[inside] / cell_px).astype(np.int64)
    zbuf = np.full((int(ij[:, 1].max()) + 1, int(ij[:, 0].max()) + 1), np.inf)
    np.minimum.at(zbuf, (ij[:, 1], ij[:, 0]), depth[inside])
    zbuf = minimum_filter(zbuf, size=3, mode="nearest")
    out = np.full(len(depth), np.inf)
    out[inside] = zbuf[ij[:, 1], ij[:, 0]]
    return out


def _lamp_directions(frame: Any, points: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(N, L, 3)`` unit directions from each point toward each of the frame's lamps."""
    out = np.empty((len(points), len(frame.lamps), 3))
    for j, lamp in enumerate(frame.lamps):
        v = np.asarray(lamp.vector, dtype=np.float64)
        d = np.broadcast_to(v, points.shape) if lamp.kind == "distant" else v - points
        out[:, j] = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    return out


def _median_spacing(points: NDArray[np.float64]) -> float:
    """Median distance from a point to its nearest neighbour (mm), from at most 5000 points."""
    every = max(1, len(points) // 5000)
    d, _ = cKDTree(points).query(points[::every], k=2, workers=query_workers(len(points) // every))
    return float(np.median(d[:, 1]))


def revolution_axis(
    points_mm: ArrayLike, normals: ArrayLike, iterations: int = 10
) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """The axis of the surface of revolution that best fits points with normals, and how well it fits.

    On a surface of revolution every normal line meets the axis: turning a
    point ``x`` about the axis (direction ``u``, through ``c``) moves it
    along the surface, ``n . (u x (x - c)) = 0``, which is linear in ``u``
    and ``v = c x u``: ``(x x n) . u + n . v = 0`` (Pottmann & Randrup
    1998).  The least-squares ``u`` with ``|u| = 1`` is the smallest
    eigenvector of the Schur complement of the normal equations; the rows
    are then reweighted by Tukey's biweight of the angle by which each
    normal leaves its meridian plane (``4.685`` robust deviations), so that
    a rim's or a feature's normals do not tilt the axis.

    Parameters
    ----------
    points_mm, normals
        ``(N, 3)`` points (mm) and unit normals (either sign).
    iterations
        Reweighting rounds.

    Returns
    -------
    axis, point, spread_deg
        Unit direction, the point of the axis nearest the points' centroid
        (mm), and the robust deviation (1.4826 x the median absolute
        angle, deg) by which the normals leave their meridian planes: a
        degree or two on a turned object, tens of degrees on a shape that is
        not one.

    References
    ----------
    .. [1] Pottmann, H., Randrup, T. (1998). Rotational and helical surface
       approximation for reverse engineering. Computing 60(4), 307-322.

    Examples
    --------
    A cone about the axis through (5, 0, 0) along (0, 0.6, 0.8):

    >>> rng = np.random.default_rng(0)
    >>> t, phi = rng.uniform(5, 30, 2000), rng.uniform(0, 2 * np.pi, 2000)
    >>> local = np.stack([0.5 * t * np.cos(phi), 0.5 * t * np.sin(phi), t], 1)
    >>> nrm = np.stack([np.cos(phi), np.sin(phi), -0.5 * np.ones_like(phi)], 1) / np.sqrt(1.25)
    >>> rot = np.array([[1, 0, 0], [0, 0.8, 0.6], [0, -0.6, 0.8]]).T
    >>> u, c, spread = revolution_axis(local @ rot.T + [5, 0, 0], nrm @ rot.T)
    >>> np.round(np.abs(u), 6).tolist(), round(float(c[0]), 6), spread < 1e-6
    ([0.0, 0.6, 0.8], 5.0, True)
    """
    x = np.asarray(points_mm, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    centre = x.mean(axis=0)
    x = x - centre
    xn = np.cross(x, n)
    w = np.ones(len(x))
    u, c, spread = np.array([0.0, 0.0, 1.0]), np.zeros(3), math.inf
    for _ in range(max(1, iterations)):
        a = (xn * w[:, None]).T @ xn
        cc = (xn * w[:, None]).T @ n
        b = (n * w[:, None]).T @ n + 1e-12 * np.eye(3)
        u = np.linalg.eigh(a - cc @ np.linalg.solve(b, cc.T))[1][:, 0]
        v = -np.linalg.solve(b, cc.T @ u)
        c = np.cross(u, v)
        arm = np.linalg.norm(np.cross(x - c, u), axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            angle = np.arcsin(np.clip((xn @ u + n @ v) / arm, -1.0, 1.0))
        angle = np.where(arm > 1e-9, angle, 0.0)
        spread = 1.4826 * float(np.median(np.abs(angle)))
        k = 4.685 * max(spread, 1e-9)
        w = np.clip(1.0 - (angle / k) ** 2, 0.0, None) ** 2
    c = c - (c @ u) * u                      # the axis point nearest the centroid (the origin here)
    return u, c + centre, math.degrees(spread)
