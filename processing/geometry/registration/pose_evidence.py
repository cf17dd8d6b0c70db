"""Evidence between two competing poses: a block significance test of their log-likelihood ratio.

A nearly symmetric object (a thrown vase with a small boss) has two or more
poses that fit almost the whole overlap equally well; only the points near
the distinguishing feature tell them apart.  A global margin (how much better
one pose fits on average) dilutes that local evidence in the overlap's area;
this module weighs it against the range noise instead, on the residuals of
true surface partners (:func:`surface_residuals`: a partner under the point,
normals agreeing, not on its cloud's border, :func:`border_points`).  See
docs/processing.md, section "Nearly symmetric shapes: evidence".
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.geometry.registration.cells import cell_labels
from processing.geometry.registration.clouds import query_workers

__all__ = ["PoseEvidence", "border_points", "pose_evidence", "posed_nearest", "surface_residuals"]

#: Consistency constant of the median absolute deviation for a Gaussian.
_MAD_TO_SIGMA = 1.482602218505602


@dataclass(frozen=True)
class PoseEvidence:
    """The evidence for pose A over pose B where they differ.

    Attributes
    ----------
    sigma
        Significance of A over B, in standard deviations of the statistic
        under the hypothesis that both poses are equally right (positive
        favours A; 0 when no point tells them apart).
    log_likelihood_ratio
        ``ln L(A) - ln L(B)`` per independent cell (see
        :func:`pose_evidence`), in nats.
    noise_mm
        Robust standard deviation of A's residuals (mm), the noise the
        evidence is weighed against.
    cells
        Number of cells (independent blocks) tested.
    points
        Number of points tested.
    background_cells
        Number of cells where the two poses predict the same surface, whose
        spread calibrates the null (0 without ``gap_mm``).
    """

    sigma: float
    log_likelihood_ratio: float
    noise_mm: float
    cells: int
    points: int
    background_cells: int = 0


def pose_evidence(
    residuals_a_mm: ArrayLike,
    residuals_b_mm: ArrayLike,
    positions_mm: ArrayLike,
    cell_mm: float,
    compare: ArrayLike | None = None,
    cap_sigma: float = 6.0,
    min_noise: float = 0.0,
    gap_mm: ArrayLike | None = None,
    min_gap_sigma: float = 3.0,
) -> PoseEvidence:
    r"""Significance of pose A over pose B from the residuals that change between them.

    Parameters
    ----------
    residuals_a_mm, residuals_b_mm
        ``(N,)`` point-to-plane residuals of the same points under pose A and
        pose B (mm); NaN where a point has no partner under that pose.
    positions_mm
        ``(N, 3)`` the points' positions in one frame (mm), for the cells.
    cell_mm
        Edge of the cubic cells (mm): at least the length over which the
        residuals of neighbouring points are correlated (the neighbourhood the
        normals are fitted over), so that one cell is about one independent
        observation.
    compare
        Optional ``(N,)`` booleans: the points to compare, typically those
        that move between the two poses (elsewhere the poses cannot differ).
        Default: every point.
    cap_sigma
        A residual counts at most ``cap_sigma`` noise deviations (the
        truncated quadratic of a Gaussian with an outlier floor), so that a
        few mismatches at the clouds' borders cannot outweigh a feature.
    min_noise
        Smallest noise deviation (the residuals' unit): the resolution of the
        measurement, for residuals that can be exactly zero.
    gap_mm
        Optional ``(N,)`` distance (mm) between the surfaces the two poses
        predict at each point, measured on the clouds' own geometry (see
        Notes); NaN where one pose predicts no surface.  When given, only the
        cells where the predictions differ by more than the noise are tested
        (the *informative* cells) and the others calibrate the null.
        Default: every compared cell is tested.
    min_gap_sigma
        A cell is informative when the median of its points' gaps exceeds
        ``min_gap_sigma`` noise deviations.

    Returns
    -------
    PoseEvidence
        The significance, the per-cell log-likelihood ratio and the figures
        they rest on.

    Raises
    ------
    ValueError
        Residuals and positions of different lengths or a cell size that is
        not a positive finite number.

    Notes
    -----
    With Gaussian range noise of standard deviation ``sigma`` on the
    residuals, the log-likelihood ratio of pose A over pose B on the points
    ``i`` both match is

    .. math:: \Lambda = \sum_i \frac{r_{B,i}^2 - r_{A,i}^2}{2 \sigma^2}
              = \sum_i \frac{\delta_i}{2 \sigma^2}.

    Where the two poses put a point on the same surface, ``delta_i`` is
    noise of mean zero; where they differ (a boss landing on a plain
    surface) it is large.  Mismatches (a point near a border paired across
    an edge) are not Gaussian: each squared residual is capped at
    ``(c sigma)^2``, ``c = cap_sigma``, the log-likelihood of a Gaussian
    with a uniform floor for outliers.  Dense points do not add independent evidence:
    residuals of neighbours share the fitted normal and the plane they are
    measured against.  The points are therefore grouped into cubic cells of
    edge ``cell_mm`` whose sums ``S_j`` of ``delta`` are the independent
    blocks (the block bootstrap's unit), and the statistic is the
    significance of their total

    .. math:: z = \frac{\sum_j S_j}{\sqrt{V}}, \qquad
              V = \max\Big(2 \sum_{S_j < 0} S_j^2,\; M n (2 \sigma_A^2)^2\Big)

    over the ``M`` cells.  Under the hypothesis that both poses are equally
    right the ``S_j`` are symmetric about zero (swapping A and B changes
    nothing but the sign), so the variance of the total is estimated from
    the cells that favour B alone: the cells on a feature that favours A do
    not inflate it, while every mismatch and every correlation within a cell
    does.  ``V`` is not less than the variance for independent points,
    ``(2 sigma_A^2)^2`` per point for ``r_B^2 - r_A^2`` with ``r`` normal of
    deviation ``sigma_A`` (the robust, median absolute deviation, deviation of
    A's residuals), ``n`` the median number of points per cell.  Under the
    null hypothesis ``z`` is about standard normal; a pose is worth accepting
    over its competitor only when ``z`` is overwhelming
    (``RegistrationPreset.min_evidence``, 5 sigma).

    A small feature is diluted when every cell is tested: the cells where the
    two poses predict the same surface add nothing but spread.  Given
    ``gap_mm``, the distance between the surfaces the two poses predict at
    each point (each cloud against itself moved by the poses' relative
    motion, so that it depends on neither pose's residuals), only the cells
    whose median gap exceeds ``min_gap_sigma`` noise deviations are tested.
    The other cells, where the poses predict the same surface, are samples of
    the null whatever the truth: the spread per point of their sums (the
    Gaussian core, from the median absolute deviation of ``S_j / sqrt(n_j)``,
    correlations within a cell included) replaces ``(2 sigma_A^2)^2`` in the
    floor of ``V`` (over the tested points), scaled by ``(s / sigma_A)^4``
    when the tested points' robust deviation ``s`` of A's residuals is larger
    (there A fits no better than a larger noise, and so does the spread).
    The cells favouring B among the tested ones still bound ``V`` from below
    (mismatches, heavy tails).  The reported
    log-likelihood ratio counts each cell once:
    ``sum_j S_j / (2 sigma_A^2)`` divided by the mean number of points per cell.

    References
    ----------
    .. [1] Künsch, H. R. (1989). The jackknife and the bootstrap for general
       stationary observations. Annals of Statistics 17(3), 1217-1241.
       doi:10.1214/aos/1176347265 (blocks of neighbouring observations as
       the independent units of a correlated series).
    .. [2] Huber, P. J., Ronchetti, E. M. (2009). Robust Statistics, 2nd ed.,
       Wiley, section 5.1 (the median absolute deviation).
       doi:10.1002/9780470434697
    .. [3] Torr, P. H. S., Zisserman, A. (2000). MLESAC: a new robust
       estimator with application to estimating image geometry. CVIU 78(1),
       138-156. doi:10.1006/cviu.1999.0832 (Gaussian inliers with a uniform
       outlier floor: the capped squared residual).

    Examples
    --------
    A plane measured with 0.05 mm noise on a 0.5 mm grid; pose B puts a 1 mm
    bump of 3 mm radius where A has none -- a feature covering about 1 % of
    the 60 x 60 mm overlap:

    >>> rng = np.random.default_rng(0)
    >>> g = np.arange(0, 60, 0.5)
    >>> xy = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    >>> pos = np.column_stack([xy, np.zeros(len(xy))])
    >>> r_a = rng.normal(0, 0.05, len(xy))
    >>> bump = 1.0 * np.exp(-0.5 * np.sum((xy - 30) ** 2, axis=1) / 3.0 ** 2)
    >>> r_b = rng.normal(0, 0.05, len(xy)) + bump
    >>> ev = pose_evidence(r_a, r_b, pos, cell_mm=3.0)
    >>> ev.cells, bool(ev.sigma > 20)
    (400, True)

    Without the bump the two poses are equally right and the evidence is noise:

    >>> bool(abs(pose_evidence(r_a, r_b - bump, pos, cell_mm=3.0).sigma) < 3)
    True

    A bump half as high and of 1.5 mm radius (0.2 % of the overlap) is
    diluted over every cell; tested where the predicted surfaces differ (the
    bump's own cells), against the spread of the others, it weighs far more:

    >>> small = 0.5 * np.exp(-0.5 * np.sum((xy - 30) ** 2, axis=1) / 1.5 ** 2)
    >>> r_s = r_b - bump + small
    >>> diluted = pose_evidence(r_a, r_s, pos, cell_mm=3.0)
    >>> focused = pose_evidence(r_a, r_s, pos, cell_mm=3.0, gap_mm=small)
    >>> bool(focused.sigma > 3 * diluted.sigma), focused.cells < 10, focused.background_cells > 390
    (True, True, True)
    """
    ra = np.asarray(residuals_a_mm, dtype=np.float64).ravel()
    rb = np.asarray(residuals_b_mm, dtype=np.float64).ravel()
    pos = np.asarray(positions_mm, dtype=np.float64).reshape(-1, 3)
    gap = None if gap_mm is None else np.asarray(gap_mm, dtype=np.float64).ravel()
    if not (len(ra) == len(rb) == len(pos)) or (gap is not None and len(gap) != len(ra)):
        raise ValueError(f"residuals_a_mm, residuals_b_mm, positions_mm (and gap_mm) must have one entry per point, "
                         f"got {len(ra)}, {len(rb)}, {len(pos)}" + ("" if gap is None else f" and {len(gap)}"))
    if not (math.isfinite(cell_mm) and cell_mm > 0):
        raise ValueError(f"cell_mm must be a positive cell size in mm, got {cell_mm!r}")
    use = np.isfinite(ra) & np.isfinite(rb) & np.all(np.isfinite(pos), axis=1)
    if compare is not None:
        use &= np.asarray(compare, dtype=bool).ravel()
    if use.sum() < 2:
        return PoseEvidence(0.0, 0.0, math.nan, 0, int(use.sum()))
    ra, rb, pos = ra[use], rb[use], pos[use]
    noise = max(_MAD_TO_SIGMA * float(np.median(np.abs(ra - np.median(ra)))), float(min_noise))
    if not noise > 0:
        return PoseEvidence(0.0, 0.0, noise, 0, int(use.sum()))
    cap = (cap_sigma * noise) ** 2
    delta = np.minimum(rb * rb, cap) - np.minimum(ra * ra, cap)
    key = np.floor((pos - pos.min(axis=0)) / cell_mm).astype(np.int64)
    cell, counts = cell_labels(key)
    sums = np.bincount(cell, weights=delta)
    point_var = (2.0 * noise * noise) ** 2        # of r_B^2 - r_A^2 for one independent point
    background = 0
    if gap is not None:
        informative = _informative_cells(np.nan_to_num(gap[use], nan=0.0), cell, len(sums),
                                         min_gap_sigma * noise)
        back_sums, back_counts = sums[~informative], counts[~informative]
        sums, counts = sums[informative], counts[informative]
        background = len(back_sums)
        if background >= _MIN_BACKGROUND_CELLS:
            # the cells where both poses predict the same surface are samples of the null: their spread
            # per point, correlations and mismatches included, is the spread the tested cells would have
            # if the two poses were equally right there
            # (its Gaussian core: the median absolute deviation of the cells' sums scaled to one point; the
            # heavy tail of mismatches, where the tested cells have one, is in the cells favouring B)
            core = _MAD_TO_SIGMA * float(np.median(np.abs(back_sums / np.sqrt(back_counts))))
            point_var = max(point_var, core * core)
        # the null's spread scales with the fourth power of the residuals' deviation: where the favoured
        # pose fits no better than noise of a larger deviation (both poses wrong there), so does the spread
        if np.any(informative):
            local = _MAD_TO_SIGMA * float(np.median(np.abs(ra[informative[cell]])))
            point_var *= max(1.0, local / noise) ** 4
    m = len(sums)
    if m == 0:
        return PoseEvidence(0.0, 0.0, noise, 0, 0, background)
    llr = float(sums.sum()) / float(counts.mean()) / (2.0 * noise * noise)
    floor2 = float(np.sum(counts)) * point_var if gap is not None else m * float(np.median(counts)) * point_var
    spread2 = max(2.0 * float(np.sum(np.minimum(sums, 0.0) ** 2)), floor2)
    z = float(sums.sum()) / math.sqrt(spread2)
    return PoseEvidence(z, llr, noise, m, int(np.sum(counts)), background)


#: Fewest background cells whose spread is trusted as the null's.
_MIN_BACKGROUND_CELLS = 20


def _informative_cells(gap: np.ndarray, cell: np.ndarray, cells: int, threshold: float) -> np.ndarray:
    """Cells whose points' median ``|gap|`` exceeds ``threshold``: where the two poses predict different surfaces.

    The median of a cell, not each point's gap, decides, so that the choice
    hardly depends on the noise of single residuals (a point chosen for its
    own large noise would widen the test's spread).
    """
    order = np.lexsort((np.abs(gap), cell))
    sorted_cell = cell[order]
    start = np.searchsorted(sorted_cell, np.arange(cells), side="left")
    stop = np.searchsorted(sorted_cell, np.arange(cells), side="right")
    g = np.abs(gap)[order]
    return 0.5 * (g[(start + stop - 1) // 2] + g[(start + stop) // 2]) > threshold


def border_points(points_mm: ArrayLike, normals: ArrayLike, spacing_mm: float, k: int = 12,
                  max_offset: float = 0.4) -> NDArray[np.bool_]:
    """Points on a cloud's border: their neighbourhood lies to one side of them.

    Parameters
    ----------
    points_mm, normals
        ``(N, 3)`` the cloud's points (mm) and unit normals.
    spacing_mm
        Sample spacing (mm); neighbours are the ``k`` nearest within 2.5 spacings.
    k
        Neighbours looked at.
    max_offset
        A point is on the border when the centroid of its neighbours, in the
        tangent plane, lies farther from it than ``max_offset`` times their
        RMS distance from it (0 for a full disc of neighbours, about 0.6 for a
        half disc), or when it has fewer than ``k / 3`` neighbours.

    Returns
    -------
    numpy.ndarray
        ``(N,)`` booleans, True on the border.

    Examples
    --------
    >>> g = np.arange(0.0, 10.0, 0.5)
    >>> xy = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    >>> pts = np.column_stack([xy, np.zeros(len(xy))])
    >>> edge = border_points(pts, np.tile([0.0, 0.0, 1.0], (len(pts), 1)), 0.5)
    >>> bool(edge[(xy[:, 0] == 0) & (xy[:, 1] == 5)][0]), bool(edge[(xy[:, 0] == 5) & (xy[:, 1] == 5)][0])
    (True, False)
    """
    from scipy.spatial import cKDTree

    pts = np.asarray(points_mm, dtype=np.float64).reshape(-1, 3)
    nrm = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    k = min(int(k) + 1, len(pts))
    dist, idx = cKDTree(pts).query(pts, k=k, distance_upper_bound=2.5 * spacing_mm,
                                   workers=query_workers(len(pts)))
    dist, idx = dist.reshape(len(pts), -1)[:, 1:], idx.reshape(len(pts), -1)[:, 1:]
    found = np.isfinite(dist)
    nb = pts[np.minimum(idx, len(pts) - 1)] - pts[:, None, :]
    nb = nb - np.einsum("nkj,nj->nk", nb, nrm)[:, :, None] * nrm[:, None, :]   # in the tangent plane
    nb[~found] = 0.0
    n = found.sum(axis=1)
    centroid = nb.sum(axis=1) / np.maximum(n, 1)[:, None]
    rms = np.sqrt(np.sum(nb * nb, axis=(1, 2)) / np.maximum(n, 1))
    return (n < max(3, (k - 1) / 3.0)) | (np.linalg.norm(centroid, axis=1) > max_offset * np.maximum(rms, 1e-300))


def posed_nearest(points_mm: ArrayLike, normals: ArrayLike, target_points_mm: ArrayLike, target_normals: ArrayLike,
                  transform: ArrayLike, reach_mm: float, tree: Any = None) -> tuple[NDArray[np.float64], ...]:
    """Points and normals moved by ``transform`` and each one's nearest target point within ``reach_mm``.

    Parameters
    ----------
    points_mm, normals
        ``(n, 3)`` source points (mm) and their unit normals.
    target_points_mm, target_normals
        ``(m, 3)`` target points (mm) and their unit normals.
    transform
        ``(4, 4)`` source -> target pose.
    reach_mm
        Farthest partner (mm).
    tree
        A ``scipy.spatial.cKDTree`` of the target points to reuse; None builds one.

    Returns
    -------
    tuple of ndarray
        ``(x, nx, target_points, target_normals, d, idx)``: the moved points and normals, the target
        arrays as float ``(m, 3)``, and each point's distance to its nearest target point (inf beyond
        the reach) and that point's index (``m`` beyond the reach).

    Examples
    --------
    >>> x, nx, tp, tn, d, idx = posed_nearest([[0.0, 0.0, 0.0]], [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]],
    ...                                       [[0.0, 0.0, 1.0]], np.eye(4), 2.0)
    >>> float(d[0]), int(idx[0])
    (1.0, 0)
    """
    from scipy.spatial import cKDTree

    pts = np.asarray(points_mm, dtype=np.float64).reshape(-1, 3)
    nrm = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    tp = np.asarray(target_points_mm, dtype=np.float64).reshape(-1, 3)
    tn = np.asarray(target_normals, dtype=np.float64).reshape(-1, 3)
    t = np.asarray(transform, dtype=np.float64)
    x = pts @ t[:3, :3].T + t[:3, 3]
    nx = nrm @ t[:3, :3].T
    d, idx = (tree if tree is not None else cKDTree(tp)).query(x, distance_upper_bound=reach_mm,
                                                               workers=query_workers(len(x)))
    return x, nx, tp, tn, d, idx


def surface_residuals(points_mm: ArrayLike, normals: ArrayLike, target_points_mm: ArrayLike,
                      target_normals: ArrayLike, transform: ArrayLike, reach_mm: float, spacing_mm: float,
                      max_angle_deg: float = 30.0, target_border: ArrayLike | None = None,
                      tree: Any = None) -> NDArray[np.float64]:
    """Point-to-plane residuals of points moved by a pose, only where the partner is a true surface partner.

    Parameters
    ----------
    points_mm, normals
        ``(N, 3)`` the points (mm) and their unit normals, in their own frame.
    target_points_mm, target_normals
        ``(M, 3)`` the surface they are compared with (mm) and its unit normals.
    transform
        ``(4, 4)`` the pose taking the points into the target's frame.
    reach_mm
        Farthest partner (mm).
    spacing_mm
        The target's sample spacing (mm): a moved point lies *over* its
        partner when its offset from it in the partner's tangent plane is at
        most one spacing.
    max_angle_deg
        Largest angle between the moved point's normal and its partner's (sign ignored).
    target_border
        Optional ``(M,)`` booleans, the target's border points
        (:func:`border_points`), which are not partners: a point beyond the
        target's border finds one beside it, not under it.
    tree
        Optional ``scipy.spatial.cKDTree`` of ``target_points_mm`` (built when absent).

    Returns
    -------
    numpy.ndarray
        ``(N,)`` signed distances (mm) along the partner's normal to its
        tangent plane; NaN where the point has no true partner.

    Examples
    --------
    A plane 0.1 mm above a 10 x 10 mm plane: a partner inside, none beyond the border or on it:

    >>> g = np.arange(0.0, 10.0, 0.5)
    >>> xy = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    >>> tgt = np.column_stack([xy, np.zeros(len(xy))])
    >>> up = np.tile([0.0, 0.0, 1.0], (len(xy), 1))
    >>> src = np.array([[5.0, 5.0, 0.1], [11.0, 5.0, 0.1], [5.0, 5.0, 0.1]])
    >>> n = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    >>> r = surface_residuals(src, n, tgt, up, np.eye(4), 2.0, 0.5, target_border=border_points(tgt, up, 0.5))
    >>> np.round(r, 3).tolist()
    [0.1, nan, nan]
    """
    x, nx, tp, tn, d, idx = posed_nearest(points_mm, normals, target_points_mm, target_normals, transform, reach_mm,
                                          tree)
    out = np.full(len(x), np.nan)
    hit = np.flatnonzero(np.isfinite(d))
    if not len(hit):
        return out
    j = idx[hit]
    off = x[hit] - tp[j]
    along = np.einsum("ij,ij->i", off, tn[j])
    lateral = np.linalg.norm(off - along[:, None] * tn[j], axis=1)
    ok = (lateral <= spacing_mm) & (np.abs(np.einsum("ij,ij->i", nx[hit], tn[j])) >= math.cos(math.radians(max_angle_deg)))
    if target_border is not None:
        ok &= ~np.asarray(target_border, dtype=bool)[j]
    out[hit[ok]] = along[ok]
    return out
