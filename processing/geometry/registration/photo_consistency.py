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
import warnings
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
           "label_evidence", "photo_ids",
           "otsu_threshold", "revolution_axis", "turn_by_colour", "MIXED_SHARE", "MIN_SHARED_POINTS"]

#: Points whose chromaticity lies farther than this share of the way from both classes' means are left
#: unlabelled: the camera's lens mixes the two pigments along a motif's edge, and because chromaticity weighs
#: the brighter pigment more, the mix's midpoint moves off the edge by an amount that grows with the spread.
MIXED_SHARE = 0.35

#: Fewest points of the decoration (the smaller colour class, both clouds counted) that must meet the
#: decoration of the other cloud under a turn for colour to decide it; the classes' own floor.  A turn
#: that puts each pass's decoration where the other pass's photos did not see it meets none: the object
#: might as well bear two such decorations, one seen by each pass.  On the simulated plain bowl the turns
#: within 1.2 deg of the truth met 96-5,300 such points, the turns 8 deg or more off none.
MIN_SHARED_POINTS = 20


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
        pixels); it sets how far around a point the two colours of a border
        are sought (:func:`colour_classes`).
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
        vertex over bootstrap resamples of blocks of points
        (:func:`_bootstrap_vertex`), blocks of ``cell_mm`` or twice the
        gap between a scan's profiles (:func:`_sampling_gap`), the wider.
    group_sd_deg
        The jackknife standard deviation of that vertex over the photos that
        coloured the points (:func:`_jackknife_vertex`): one photo places a
        whole stretch of border, so its errors move together, which the
        cells' resampling cannot see.  NaN when the photos were not given
        (or none of them holds a border), infinite when one photo holds
        every border.
    shared_points
        Points of the smaller colour class, of both clouds, whose partner
        under this turn is of that class too: how much of the decoration the
        two passes compare at this turn.  A turn that puts each pass's
        decoration where the other pass's photos did not see it agrees with
        nothing and disagrees with nothing, so its cost can be the lowest of
        all; this count is what tells such a turn from one the decoration
        supports.
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
    group_sd_deg: float = math.nan
    shared_points: int = 0


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
    min_minority_points: int = 20, mixed_share: float = MIXED_SHARE,
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
    min_minority_points
        Fewest points of the smaller class in each cloud: a few specks are
        not a decoration, and the evidence's null, estimated from the cells,
        needs more than a handful.  Whether a small decoration holds the
        turn is the evidence's to say (:func:`turn_by_colour`), not its
        share of the cloud.
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
    count = min(int(np.sum(ls == minor)), int(np.sum(lt == minor)))
    if not (eta >= min_eta):
        return none(f"one colour: chromaticities are not two classes (Otsu separability {eta:.2f} < {min_eta:g})",
                    thr, eta, gap, frac)
    if gap < min_gap:
        return none(f"one colour: the two chromaticity classes are {gap:.3f} apart (< {min_gap:g})", thr, eta, gap, frac)
    if count < min_minority_points:
        return none(f"the second colour covers {count} of a cloud's coloured points (< {min_minority_points})",
                    thr, eta, gap, frac)
    ls = _unmix_borders(sp, source, oks, ls, mixed_share, sn)
    lt = _unmix_borders(tp, target, okt, lt, mixed_share, tn)
    return ColourClasses(ls, lt, thr, eta, gap, frac, True, "")


def _unmix_borders(points: NDArray[np.float64], pc: PointColours, trusted: NDArray[np.bool_],
                   label: NDArray[np.int8], mixed_share: float, normals: NDArray[np.float64] | None, *,
                   radius_px: float = 6.0, min_each: int = 3, neighbours: int = 96) -> NDArray[np.int8]:
    """``label`` with the points near a border between classes re-decided by their share of the two local colours.

    A photo seen through a lens colours a point near a border with a mix of
    the two pigments, ``s (a C1 + (1 - a) C0)``: ``a`` the share of the
    light the pixel gathers from pigment 1, ``s`` the shading.  Its
    chromaticity weighs the brighter pigment more, so a threshold on it
    moves the border into the darker one; the linear colour does not.  Each
    colour is divided by the cosine of its lamp (with normals and lamps:
    neighbours coloured by photos taken at other table angles are then
    comparable), and the point is projected on the segment between its two
    *ends*: the median colours of the purer half of each class's points
    within ``radius_px`` of its photo's pixels (at least two spacings to the
    eighth neighbour, so that each class has points across the scan's
    profiles); ``a`` is where the projection falls.  Points with ``a``
    farther than ``mixed_share`` of the way from both ends are left
    unlabelled (-1); points without ``min_each`` points of each class
    around keep their label.
    """
    rgb = np.asarray(pc.colours, dtype=np.float64)
    if normals is not None and pc.lamp_dirs is not None:
        with np.errstate(invalid="ignore"):
            rgb = rgb / np.maximum(np.einsum("ij,ij->i", normals, pc.lamp_dirs), 0.2)[:, None]
    core = np.flatnonzero(trusted & (label >= 0))
    if not (np.any(label[core] == 0) and np.any(label[core] == 1)):
        return label
    floor = 2.0 * _median_spacing(points[core], 8)
    pixel = np.asarray(pc.pixel_mm, dtype=np.float64) if pc.pixel_mm is not None else np.full(len(points), np.nan)
    radius = np.where(np.isfinite(pixel), np.maximum(radius_px * pixel, floor), floor)
    # the points within reach of both classes
    cand = np.flatnonzero(trusted)
    reach = float(radius[cand].max())
    close = np.ones(len(cand), dtype=bool)
    for c in (0, 1):
        d, _ = cKDTree(points[core[label[core] == c]]).query(points[cand], distance_upper_bound=reach,
                                                              workers=query_workers(len(cand)))
        close &= d <= radius[cand]
    cand = cand[close]
    if not len(cand):
        return label
    k = min(neighbours, len(core))
    d, j = cKDTree(points[core]).query(points[cand], k=k, distance_upper_bound=reach,
                                       workers=query_workers(len(cand)))
    d, j = d.reshape(len(cand), k), j.reshape(len(cand), k)
    nb = core[np.minimum(j, len(core) - 1)]                        # (C, k) indices into the cloud
    masks = [(d <= radius[cand, None]) & (label[nb] == c) for c in (0, 1)]
    enough = (masks[0].sum(axis=1) >= min_each) & (masks[1].sum(axis=1) >= min_each)
    with warnings.catch_warnings(), np.errstate(invalid="ignore", divide="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)     # a point without neighbours of a class: NaN, dropped
        ends = [np.nanmedian(np.where(m[..., None], rgb[nb], np.nan), axis=1) for m in masks]
        # the lens mixes each class's points next to the border too: each end is the median of the purer
        # half of its class's neighbours (those farther from the other end)
        seg = ends[1] - ends[0]
        nb_share = np.einsum("ckj,cj->ck", rgb[nb] - ends[0][:, None], seg) / np.einsum("ij,ij->i", seg, seg)[:, None]
        for c, m in enumerate(masks):
            mid = np.nanmedian(np.where(m, nb_share, np.nan), axis=1, keepdims=True)
            purer = m & ((nb_share <= mid) if c == 0 else (nb_share >= mid))
            ends[c] = np.nanmedian(np.where(purer[..., None], rgb[nb], np.nan), axis=1)
        seg = ends[1] - ends[0]
        a = np.einsum("ij,ij->i", rgb[cand] - ends[0], seg) / np.einsum("ij,ij->i", seg, seg)
    a[~enough] = np.nan
    fit = np.isfinite(a)
    out = label.copy()
    new = np.where(a > 0.5, 1, 0).astype(np.int8)
    new[(a > mixed_share) & (a < 1.0 - mixed_share)] = -1
    out[cand[fit]] = new[fit]
    return out

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
    source_groups: ArrayLike | None = None, target_groups: ArrayLike | None = None,
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
    source_groups, target_groups
        Optional ``(N,)`` and ``(M,)`` integers: the photo that coloured
        each point (:func:`photo_ids`); with both, the turn's spread over
        leaving out one photo at a time (``ColourTurn.group_sd_deg``).

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

    Every painted point of both clouds meets paint there (1,258 a cloud):

    >>> res.shared_points
    2516
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
    sub, weight = _sweep_sample(ls_all, max_points, seed)
    src, ls = src_all[sub], ls_all[sub]
    fwd = (ns_all, nt_all) if ns_all is not None and nt_all is not None else None
    fwd_sub = (fwd[0][sub], fwd[1]) if fwd is not None else None
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
    # the points a border moves over, is steadier than the noisy minimum of a few border points.  The V
    # is fitted over +-coarse_deg about its own vertex (the window moved until it settles): a window
    # off-centre weighs one side's slope more and pulls the vertex toward it.
    fine = a0 + np.arange(-coarse_deg - 1.0, coarse_deg + 1.0 + 1e-9, fine_deg)
    fposes = _turned(t0, u, c, np.radians(fine))
    tk = lt_all >= 0
    back_tree = cKDTree(src_all)
    bwd = (fwd[1][tk], fwd[0]) if fwd is not None else None
    both = np.concatenate([_disagreement(src_all, ls_all, tree, lt_all, fposes, max_distance_mm, fwd),
                           _disagreement(tgt_all[tk], lt_all[tk], back_tree, ls_all, np.linalg.inv(fposes),
                                         max_distance_mm, bwd)], axis=1)
    best, win = _settled_vertex(fine, np.nansum(both, axis=1), a0, coarse_deg, fine_deg)
    at = np.concatenate([transform_points(_turned(t0, u, c, np.radians([a0]))[0], src_all), tgt_all[tk]])
    # blocks wider than the gap between a scan's profiles: the points of two neighbouring profiles meet a
    # border at one phase of the profiles, so their errors go together
    block = max(cell_mm, 2.0 * _sampling_gap(src_all), 2.0 * _sampling_gap(tgt_all))
    sd = _bootstrap_vertex(fine[win], both[win], at, block, seed)
    group_sd = math.nan
    if source_groups is not None and target_groups is not None:
        groups = _both_groups(np.asarray(source_groups, dtype=np.int64)[keep],
                              np.asarray(target_groups, dtype=np.int64)[tk])
        group_sd = _jackknife_vertex(fine[win], both[win], groups)
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
                      float(np.nanmean(db)) if np.isfinite(db).any() else math.nan, cells, points, sd, group_sd,
                      _shared_minority(np.concatenate([ls_all, lt_all[tk]]), da))


def _shared_minority(labels: NDArray[np.int8], disagree: NDArray[np.float64]) -> int:
    """Points of the smaller class whose partner agrees (``disagree`` 0): :attr:`ColourTurn.shared_points`."""
    minor = 1 if labels.size and np.mean(labels == 1) < 0.5 else 0
    return int(np.sum((labels == minor) & (disagree == 0.0)))


def _sweep_sample(labels: NDArray[np.int8], max_points: int, seed: int) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """Indices of the sweep's points and their weights: the smaller class whole, the larger one subsampled, weighted back."""
    minor = int(np.mean(labels) < 0.5)
    few = np.flatnonzero(labels == minor)
    many = np.flatnonzero(labels != minor)
    room = max(max_points - len(few), 1)
    pick = many if len(many) <= room else np.random.default_rng(seed).choice(many, room, replace=False)
    weight = np.concatenate([np.ones(len(few)), np.full(len(pick), len(many) / max(len(pick), 1))])
    return np.concatenate([few, pick]), weight


def _settled_vertex(fine_deg_grid: NDArray[np.float64], total: NDArray[np.float64], a0: float, half_deg: float,
                    step_deg: float) -> tuple[float, NDArray[np.bool_]]:
    """The vertex of a V fitted over +-``half_deg`` about the vertex itself, and that window of the grid.

    The window starts at ``a0`` and moves to the vertex until it settles
    (at most four moves, at most 1 deg from ``a0``): a window off-centre
    weighs one side's slope more and pulls the vertex toward it.
    """
    centre = a0
    for _ in range(4):
        win = np.abs(fine_deg_grid - centre) <= half_deg + 1e-9
        best = _v_vertex(fine_deg_grid[win], total[win])
        moved = float(np.clip(round((best - a0) / step_deg) * step_deg, -1.0, 1.0)) + a0
        if abs(moved - centre) < 0.5 * step_deg:
            break
        centre = moved
    return best, win


def _both_groups(source: NDArray[np.int64], target: NDArray[np.int64]) -> NDArray[np.int64]:
    """The photos of both clouds numbered apart (the target's after the source's); -1 stays -1."""
    return np.concatenate([source, np.where(target >= 0, target + 1 + int(np.max(source, initial=0)), -1)])


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


def photo_ids(colours: PointColours) -> NDArray[np.int64]:
    """``(N,)`` the index of the photo that coloured each point, told apart by the camera's centre; -1 for none.

    Parameters
    ----------
    colours
        A cloud's colours; without ``camera_mm`` the photos are unknown.

    Returns
    -------
    numpy.ndarray
        Integers from 0, -1 where a point has no colour or its photo is unknown.

    Examples
    --------
    >>> pc = PointColours(np.ones((4, 3)), None, np.array([[0, 0, 9.0], [1, 0, 9], [0, 0, 9], [np.nan] * 3]))
    >>> photo_ids(pc).tolist()
    [0, 1, 0, -1]
    """
    rgb = np.asarray(colours.colours, dtype=np.float64).reshape(-1, 3)
    seen = np.all(np.isfinite(rgb), axis=1)
    out = np.full(len(rgb), -1, dtype=np.int64)
    if colours.camera_mm is None:
        return out
    cam = np.asarray(colours.camera_mm, dtype=np.float64).reshape(-1, 3)
    seen &= np.all(np.isfinite(cam), axis=1)
    if seen.any():
        _, inverse = np.unique(np.round(cam[seen], 6), axis=0, return_inverse=True)
        out[seen] = inverse.ravel()
    return out


def _jackknife_vertex(angles_deg: NDArray[np.float64], disagree: NDArray[np.float64], groups: NDArray[np.int64]) -> float:
    """Jackknife standard deviation (deg) of :func:`_v_vertex` of the summed ``(K, N)`` disagreements over ``groups``.

    Each group that holds a disagreement under some turn (a photo whose
    points meet a border) is left out in turn; ``sqrt((g - 1) / g * sum
    (v_i - mean v)^2)`` over the ``g`` vertices (Quenouille 1956,
    doi:10.1093/biomet/43.3-4.353).  Points of group -1 (unknown) are
    never left out.  NaN when no group holds one (the photos are unknown);
    infinite when one photo holds them all: what that photo shares over
    all of its points (its pose, its pixels' phase) moves the whole turn,
    and nothing measures it.
    """
    d = np.nan_to_num(disagree)
    total = d.sum(axis=1)
    ids, inverse = np.unique(groups, return_inverse=True)
    per = np.zeros((len(ids), len(angles_deg)))
    np.add.at(per, inverse.ravel(), d.T)
    per = per[(ids >= 0) & (per.sum(axis=1) > 0)]
    if len(per) < 2:
        return math.inf if len(per) else math.nan
    v = np.array([_v_vertex(angles_deg, total - row) for row in per])
    return float(math.sqrt((len(v) - 1) / len(v) * np.sum((v - v.mean()) ** 2)))


def colour_turn_sd_deg(turn: ColourTurn) -> float:
    """Standard deviation (deg) of a colour-decided turn: the borders' scatter and the photos' shifts, in quadrature.

    Parameters
    ----------
    turn
        The turn (:func:`turn_by_colour`): its ``sigma_deg``, the blocks'
        bootstrap, sees errors that differ from one stretch of border to the
        next; its ``group_sd_deg``, the jackknife over the photos that
        coloured the points, sees errors that a photo shares over all the
        border it coloured (its pixels' phase on the border, its blur, its
        shading, its pose).

    Returns
    -------
    float
        ``hypot(sigma_deg, group_sd_deg)`` (deg); the bootstrap alone
        without the photos (``group_sd_deg`` NaN); infinite when one photo
        holds every border.

    Examples
    --------
    >>> t = ColourTurn(np.eye(4), 0.0, 9.0, 30.0, 0.01, 0.2, 50, 4000, 0.06, 0.08)
    >>> round(colour_turn_sd_deg(t), 3)
    0.1
    """
    group = 0.0 if math.isnan(turn.group_sd_deg) else turn.group_sd_deg
    return math.hypot(turn.sigma_deg, group)


def colour_points(
    points_mm: ArrayLike, normals: ArrayLike, frames: Sequence[Any], images: Sequence[Any], *,
    min_cos: float = 0.2, highlight_deg: float = 30.0, cell_px: float | None = None, blur_px: float = 3.0,
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
    registered; the cloud itself is the occluder, of the lamp too: seen from
    the lamp the same way (a distant lamp along its direction, a point lamp
    from its position; cells of two spacings), a point that a nearer point
    shades is in a cast shadow, which shows the room's light and not the
    lamp's, and that frame does not colour it.  Nor does a frame colour a
    point within ``blur_px`` pixels of the cloud's outline in its image (the
    lens mixes the colour with the background's): an empty cell in the
    frame's image, cells no finer than the spacing to a point's eighth
    neighbour (the gap between the scan's profiles), marks the outline.
    Another frame that lights and sees such a point may colour it.

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
    min_cos, highlight_deg, cell_px, blur_px
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
    >>> seen = np.isfinite(pc.colours[:, 0])
    >>> bool(np.all(pc.colours[seen & (pts[:, 0] < -1), 0] > 0.7)), bool(np.all(pc.colours[seen & (pts[:, 0] > 1), 1] > 0.45))
    (True, True)
    >>> rim = (xy.min(axis=1) == -10) | (xy.max(axis=1) == 9)                # the plane's outline
    >>> bool(seen[np.abs(xy).max(axis=1) < 6].all()), bool(seen[rim].any())
    (True, False)
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
    gap = _sampling_gap(p)
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
            lamp = _lamp_lit(frame, p, n, view, candidate, min_cos, glint_cos, spacing)
        if not candidate.any():
            continue
        uv, depth = project_points(p, frame)
        w, h = frame.image_size
        if not _seen_clearly(frame, uv, depth, cos_v, candidate, (spacing, gap), min_cos, cell_px, blur_px):
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


def _lamp_lit(frame: Any, p: NDArray[np.float64], n: NDArray[np.float64], view: NDArray[np.float64],
              candidate: NDArray[np.bool_], min_cos: float, glint_cos: float, spacing: float) -> NDArray[np.float64]:
    """Keep in ``candidate`` the points the frame's lamp lights directly, off its glint; each point's lamp direction.

    A point in a lamp's cast shadow (:func:`_shadowed`) shows the room's
    light, not the lamp's, and is dropped.
    """
    lamps = _lamp_directions(frame, p)
    cos_l_all = np.einsum("nlc,nc->nl", lamps, n)
    which = np.argmax(cos_l_all, axis=1)
    lamp = lamps[np.arange(len(p)), which]
    cos_l = cos_l_all[np.arange(len(p)), which]
    mirror = 2.0 * cos_l[:, None] * n - lamp
    candidate &= (cos_l > min_cos) & (np.sum(mirror * view, axis=1) < glint_cos)
    for j, each in enumerate(frame.lamps):
        mine = candidate & (which == j)
        if mine.any():
            candidate[mine] &= ~_shadowed(p, each, cos_l, spacing)[mine]
    return lamp


def _seen_clearly(frame: Any, uv: NDArray[np.float64], depth: NDArray[np.float64], cos_v: NDArray[np.float64],
                  candidate: NDArray[np.bool_], spacing_gap_mm: tuple[float, float], min_cos: float,
                  cell_px: float | None, blur_px: float) -> bool:
    """Keep in ``candidate`` the points inside the frame, in front and away from the outline; whether any is left.

    Hidden points lie behind the nearest depth of their pixel's neighbourhood
    (:func:`_surface_depth`).  The lens spreads a pixel over its neighbours
    (``blur_px``): by the object's outline the colour mixes with the
    background.  The space between two of the scan's profiles is not
    background: the points' pixels are closed over the gap between profiles
    first (:func:`_near_background`).
    """
    spacing, gap = spacing_gap_mm
    w, h = frame.image_size
    inside = np.all(np.isfinite(uv), axis=1) & (depth > 0)
    inside &= (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)
    candidate &= inside
    if not candidate.any():
        return False
    px_per_mm = float(frame.K[0, 0]) / float(np.median(depth[inside]))
    cell = cell_px or max(1.0, 2.0 * spacing * px_per_mm)
    tan_v = np.sqrt(np.maximum(1.0 - cos_v ** 2, 0.0)) / np.maximum(cos_v, min_cos)
    candidate &= depth <= _surface_depth(uv, depth, inside, cell) + spacing * (1.0 + 3.0 * tan_v)
    candidate &= ~_near_background(uv, inside, (h, w), gap * px_per_mm, blur_px)
    return bool(candidate.any())


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


def _near_background(uv: NDArray[np.float64], inside: NDArray[np.bool_], size_hw: tuple[int, int], gap_px: float,
                     blur_px: float) -> NDArray[np.bool_]:
    """Whether a pixel no point covers lies within ``blur_px`` of each point's pixel (its colour mixes with it).

    The pixels the points fall in are closed (dilated, then eroded) by a
    square of side ``gap_px``, so that gaps between the scan's profiles are
    covered; what stays uncovered is the background, or surface the pass
    did not measure.  Points outside the image count as near it.
    """
    from scipy.ndimage import binary_closing, maximum_filter

    r = max(1, math.ceil(0.5 * gap_px))
    b = max(1, math.ceil(blur_px))
    pad = r + b + 1
    ij = np.floor(uv[inside]).astype(np.int64) + pad
    covered = np.zeros((size_hw[0] + 2 * pad, size_hw[1] + 2 * pad), dtype=bool)
    covered[ij[:, 1], ij[:, 0]] = True
    covered = binary_closing(covered, structure=np.ones((2 * r + 1, 2 * r + 1), dtype=bool))
    near = maximum_filter(~covered, size=2 * b + 1, mode="constant", cval=True)
    out = np.ones(len(uv), dtype=bool)
    out[inside] = near[ij[:, 1], ij[:, 0]]
    return out


def _shadowed(points: NDArray[np.float64], lamp: Any, cos_l: NDArray[np.float64], spacing: float) -> NDArray[np.bool_]:
    """Whether a nearer point of the cloud stands between each point and ``lamp`` (a cast shadow).

    The lamp is treated as a camera: a distant lamp projects the points
    along its direction, a point lamp through its position (the angle from
    the mean direction, scaled by the median distance); depths are binned
    in cells of two sample spacings and a point deeper than the nearest
    depth of its 3 x 3 cells by a spacing plus three spacings times the
    tangent of its lamp angle is in shadow, as :func:`colour_points` tests
    the camera's view.
    """
    v = np.asarray(lamp.vector, dtype=np.float64)
    if lamp.kind == "distant":
        axis = v / np.linalg.norm(v)
        depth = -(points @ axis)
        flat = points - np.outer(points @ axis, axis)
        scale = 1.0
    else:
        ray = points - v
        depth = np.linalg.norm(ray, axis=1)
        ray /= np.maximum(depth[:, None], 1e-12)
        axis = -ray.mean(axis=0)
        axis /= max(float(np.linalg.norm(axis)), 1e-12)
        along = -(ray @ axis)
        flat = np.where(along[:, None] > 0.1, ray / np.maximum(along, 0.1)[:, None], np.nan)
        scale = float(np.median(depth))
    e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    cell = 2.0 * spacing
    uv = np.column_stack([flat @ e1, flat @ e2]) * scale
    inside = np.all(np.isfinite(uv), axis=1)
    if not inside.any():
        return np.zeros(len(points), dtype=bool)
    uv = uv - np.nanmin(uv[inside], axis=0)
    tan_l = np.sqrt(np.maximum(1.0 - cos_l ** 2, 0.0)) / np.maximum(cos_l, 0.05)
    return inside & (depth > _surface_depth(uv, depth, inside, cell) + spacing * (1.0 + 3.0 * tan_l))


def _lamp_directions(frame: Any, points: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(N, L, 3)`` unit directions from each point toward each of the frame's lamps."""
    out = np.empty((len(points), len(frame.lamps), 3))
    for j, lamp in enumerate(frame.lamps):
        v = np.asarray(lamp.vector, dtype=np.float64)
        d = np.broadcast_to(v, points.shape) if lamp.kind == "distant" else v - points
        out[:, j] = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    return out


def _sampling_gap(points: NDArray[np.float64], k: int = 64) -> float:
    """The widest spacing of a scan's sampling (mm), the gap between its profiles.

    The 90th percentile, over at most 2000 points, of the distance to the
    nearest of ``k`` neighbours more than 60 deg off the line of the point's
    eight nearest.  A laser profiler samples densely along each profile and sparsely across
    them; this is the spacing across, and the plain spacing where the
    sampling is even.
    """
    every = max(1, len(points) // 2000)
    at = points[::every]
    k = min(k, len(points) - 1)
    if k < 9:
        return _median_spacing(points)
    d, j = cKDTree(points).query(at, k=k + 1, workers=query_workers(len(at)))
    off = points[j[:, 1:]] - at[:, None, :]                       # (S, k, 3)
    near = off[:, :8] - off[:, :8].mean(axis=1, keepdims=True)
    line = np.linalg.eigh(np.einsum("ski,skj->sij", near, near))[1][:, :, -1]      # the local line's direction
    along = np.abs(np.einsum("ski,si->sk", off, line))
    across = along < 0.5 * d[:, 1:]                               # more than 60 deg off the line
    gap = np.where(across.any(axis=1), np.where(across, d[:, 1:], np.inf).min(axis=1), d[:, -1])
    return float(np.percentile(gap, 90))


def _median_spacing(points: NDArray[np.float64], k: int = 1) -> float:
    """Median distance from a point to its ``k``-th nearest neighbour (mm), from at most 5000 points."""
    every = max(1, len(points) // 5000)
    d, _ = cKDTree(points).query(points[::every], k=k + 1, workers=query_workers(len(points) // every))
    return float(np.median(d[:, k]))


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
