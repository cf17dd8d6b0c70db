"""Confidence-weighted fusion of an oriented point cloud on a voxel grid.

Where the passes of a scan overlap, a surface patch is measured several
times with different quality (incidence angle, range).  Before the surface
is reconstructed (Kazhdan & Hoppe 2013, screened Poisson: every sample
carries the same weight) the samples are merged per voxel as in volumetric
range-image fusion (Curless & Levoy 1996, "A volumetric method for building
complex models from range images", section 3: a weighted average of the
measurements with weights from the sensor's confidence):

* points of one voxel whose normals point the same way (the same dominant
  axis and sign; a thin wall's two faces are kept apart) become one sample at
  the confidence-weighted mean position, with the normalised
  confidence-weighted sum of their normals;
* points below a minimum confidence are dropped first.

So well-seen samples dominate poorly seen ones, overlapping passes do not
count twice in the screening term, and the range noise is averaged down by
about ``sqrt(n)`` for ``n`` samples per voxel.  Across voxels (a poor pass
interleaved with a good one), :func:`dominated_samples` marks the samples
whose confidence is well below the best confidence of the samples around
them facing the same way: where a better measurement of the same surface
exists, the poor one is left out; where none exists, it is kept.

References
----------
.. [1] Curless, B., Levoy, M. (1996). A volumetric method for building
   complex models from range images. SIGGRAPH 1996.
.. [2] Kazhdan, M., Hoppe, H. (2013). Screened Poisson surface
   reconstruction. ACM TOG 32(3), 29. doi:10.1145/2487228.2487237

Examples
--------
>>> pts = [[0.01, 0.0, 0.0], [0.03, 0.0, 0.0], [5.0, 0.0, 0.0]]
>>> nrm = [[0, 0, 1], [0, 0, 1], [0, 0, 1]]
>>> fused = fuse_points(pts, nrm, [1.0, 0.25, 1.0], voxel_mm=0.5)
>>> fused.points[:, 0].round(3).tolist(), fused.counts.tolist()
([0.014, 5.0], [2, 1])
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from processing.errors import InputError

__all__ = [
    "FusedCloud",
    "fuse_points",
    "dominated_samples",
    "point_spacing",
    "noise_level",
    "validate_oriented_cloud",
]

#: Points with normals shorter than this are rejected as missing normals.
_MIN_NORMAL_LENGTH = 1e-6


@dataclass(frozen=True)
class FusedCloud:
    """Result of :func:`fuse_points`.

    Attributes
    ----------
    points
        float64 ``(M, 3)`` fused positions (mm).
    normals
        float64 ``(M, 3)`` unit normals.
    confidence
        float64 ``(M,)`` confidence-weighted mean confidence of the merged
        points, in (0, 1].
    counts
        int64 ``(M,)`` number of input points merged into each sample.
    voxel_mm
        Edge of the fusion voxels (mm).
    n_input
        Number of input points.
    n_low_confidence
        Input points dropped for a confidence below the minimum.
    """

    points: NDArray[np.float64]
    normals: NDArray[np.float64]
    confidence: NDArray[np.float64]
    counts: NDArray[np.int64]
    voxel_mm: float
    n_input: int
    n_low_confidence: int


def _as_float_array(value: ArrayLike, name: str) -> NDArray[np.float64]:
    """``value`` as a float64 array; a ValueError naming ``name`` if it holds no numbers."""
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be an array of numbers ({exc})") from None


def validate_oriented_cloud(
    points: ArrayLike,
    normals: ArrayLike | None,
    confidence: ArrayLike | None = None,
    *,
    min_points: int = 1,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Check an oriented cloud and return float64 copies (unit normals).

    Parameters
    ----------
    points
        ``(N, 3)`` positions (mm), finite.
    normals
        ``(N, 3)`` normals, finite and non-zero (any length; normalised here).
    confidence
        Optional ``(N,)`` confidence in [0, 1]; None gives 1 everywhere.
    min_points
        Smallest acceptable N.

    Returns
    -------
    points, unit normals, confidence
        float64 ``(N, 3)`` (mm), ``(N, 3)`` and ``(N,)``.

    Raises
    ------
    ValueError
        Naming the parameter: wrong shape, too few points, NaN or infinite
        values, missing or zero normals, confidence outside [0, 1].

    Examples
    --------
    >>> validate_oriented_cloud([[0, 0, 0]], [[0, 0, 2]])[1].tolist()
    [[0.0, 0.0, 1.0]]
    >>> validate_oriented_cloud([[0, 0, float("nan")]], [[0, 0, 1]])
    Traceback (most recent call last):
    ...
    processing.errors.InputError: points: 1 of 1 points have NaN or infinite coordinates (first: point 0 = [0.0, 0.0, nan]); drop invalid samples before meshing
    """
    p = _as_float_array(points, "points")
    if p.size == 0:
        raise InputError(
            f"points: the cloud is empty; at least {min_points} points are needed to reconstruct a surface"
        )
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"points must have shape (N, 3), got {p.shape}")
    n = p.shape[0]
    if n < min_points:
        raise InputError(
            f"points: only {n} points; at least {min_points} are needed to reconstruct a surface "
            "(scan more of the object or lower the fusion voxel)"
        )
    finite = np.all(np.isfinite(p), axis=1)
    if not finite.all():
        bad = np.flatnonzero(~finite)
        raise InputError(
            f"points: {bad.size} of {n} points have NaN or infinite coordinates (first: point {bad[0]} = "
            f"{p[bad[0]].tolist()}); drop invalid samples before meshing"
        )
    if normals is None:
        raise InputError(
            "normals: the cloud has no normals; surface reconstruction needs outward normals "
            "(estimate and orient them toward the sensor when building the cloud)"
        )
    nr = _as_float_array(normals, "normals")
    if nr.shape != p.shape:
        raise InputError(f"normals must have the shape of points {p.shape}, got {nr.shape}")
    length = np.linalg.norm(nr, axis=1)
    bad_n = ~(np.isfinite(length) & (length > _MIN_NORMAL_LENGTH))
    if bad_n.any():
        bad = np.flatnonzero(bad_n)
        raise InputError(
            f"normals: {bad.size} of {n} normals are NaN, infinite or zero (first: normal {bad[0]} = "
            f"{nr[bad[0]].tolist()}); estimate normals for every point or drop those points"
        )
    nr = nr / length[:, None]
    if confidence is None:
        c = np.ones(n)
    else:
        c = _as_float_array(confidence, "confidence").reshape(-1)
        if c.shape[0] != n:
            raise InputError(f"confidence must have one value per point ({n}), got {c.shape[0]}")
        bad_c = ~(np.isfinite(c) & (c >= 0.0) & (c <= 1.0))
        if bad_c.any():
            bad = np.flatnonzero(bad_c)
            raise InputError(
                f"confidence: {bad.size} values are NaN or outside [0, 1] (first: confidence[{bad[0]}] = "
                f"{c[bad[0]]}); confidence is a weight in [0, 1]"
            )
    return p, nr, c


def point_spacing(points: ArrayLike, *, tree: cKDTree | None = None, sample: int = 20_000, seed: int = 0) -> float:
    """Median distance (mm) from a point to its nearest neighbour.

    Estimated on a random subset of ``sample`` query points (all neighbours
    are searched in the full cloud).

    Parameters
    ----------
    points
        ``(N, 3)`` positions (mm), N >= 2.
    tree
        Optional ``cKDTree`` of the points.
    sample
        Largest number of query points.
    seed
        Seed of the random subset.

    Returns
    -------
    float
        The median nearest-neighbour distance (mm).

    Raises
    ------
    ValueError
        Fewer than 2 points.

    Examples
    --------
    >>> g = np.stack(np.meshgrid(np.arange(20.0), np.arange(20.0), [0.0]), -1).reshape(-1, 3) * 0.5
    >>> point_spacing(g)
    0.5
    """
    p = np.asarray(points, dtype=np.float64)
    if p.shape[0] < 2:
        raise InputError(f"points: need at least 2 points to measure their spacing, got {p.shape[0]}")
    t = tree if tree is not None else cKDTree(p)
    if p.shape[0] > sample:
        q = p[np.random.default_rng(seed).choice(p.shape[0], sample, replace=False)]
    else:
        q = p
    d, _ = t.query(q, k=2, workers=-1)
    return float(np.median(d[:, 1]))


def noise_level(
    points: ArrayLike, *, tree: cKDTree | None = None, k: int = 16, sample: int = 2_000, seed: int = 0
) -> float:
    """Median RMS distance (mm) of a point's ``k`` neighbours to their best plane.

    On a smooth surface sampled much more finely than it curves, with noise
    well below the point spacing, this is the noise across the surface times
    ``sqrt(median(chi2(k - 3)) / k)`` (0.88 for k = 16: the plane absorbs 3
    degrees of freedom, and the median of a chi-square lies below its mean).
    Noise comparable to the spacing reads lower still (the nearest neighbours
    in 3-D favour similar heights).  Estimated around ``sample`` random points.

    Parameters
    ----------
    points
        ``(N, 3)`` positions (mm), N >= ``k``.
    tree
        Optional ``cKDTree`` of the points.
    k
        Neighbours per plane fit.
    sample
        Number of random points around which the planes are fitted.
    seed
        Seed of the random points.

    Returns
    -------
    float
        The median RMS distance to the planes (mm).

    Raises
    ------
    ValueError
        Fewer than ``k`` points.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> g = np.c_[rng.random((20000, 2)) * 20, 0.05 * rng.standard_normal(20000)]
    >>> bool(0.04 < noise_level(g) < 0.05)
    True
    """
    p = np.asarray(points, dtype=np.float64)
    if p.shape[0] < k:
        raise InputError(f"points: need at least k={k} points to estimate the noise, got {p.shape[0]}")
    t = tree if tree is not None else cKDTree(p)
    rng = np.random.default_rng(seed)
    q = p[rng.choice(p.shape[0], min(sample, p.shape[0]), replace=False)]
    _, idx = t.query(q, k=k, workers=-1)
    nb = p[idx]
    nb = nb - nb.mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", nb, nb) / k
    smallest = np.linalg.eigvalsh(cov)[:, 0]
    return float(np.sqrt(max(float(np.median(smallest)), 0.0)))


def dominated_samples(
    points: ArrayLike,
    normals: ArrayLike,
    confidence: ArrayLike,
    *,
    radius_mm: float,
    ratio: float,
    tree: cKDTree | None = None,
    max_neighbours: int = 24,
) -> NDArray[np.bool_]:
    """Samples outclassed by a better sample of the same surface nearby.

    Parameters
    ----------
    points, normals
        ``(N, 3)`` positions (mm) and unit normals.
    confidence
        ``(N,)`` confidence in [0, 1].
    radius_mm
        Neighbourhood radius (mm), about two point spacings.
    ratio
        A sample is dominated when its confidence is below ``ratio`` times
        the largest confidence among its neighbours (up to
        ``max_neighbours``) within ``radius_mm`` whose normals are within 60
        degrees of its own; in [0, 1], 0 marks nothing.
    tree
        Optional ``cKDTree`` of the points.

    Returns
    -------
    ndarray of bool
        ``(N,)``, True for dominated samples.

    Raises
    ------
    ValueError
        ``ratio`` outside [0, 1], ``radius_mm`` not a positive finite distance.

    Examples
    --------
    >>> p = [[0, 0, 0], [0.1, 0, 0], [5, 0, 0]]
    >>> n = [[0, 0, 1]] * 3
    >>> dominated_samples(p, n, [1.0, 0.2, 0.2], radius_mm=0.5, ratio=0.5).tolist()
    [False, True, False]
    """
    if not 0.0 <= ratio <= 1.0:
        raise InputError(f"ratio must be in [0, 1], got {ratio!r}")
    if not (np.isfinite(radius_mm) and radius_mm > 0):
        raise InputError(f"radius_mm must be a finite distance > 0 (mm), got {radius_mm!r}")
    p = np.asarray(points, dtype=np.float64)
    nr = np.asarray(normals, dtype=np.float64)
    c = np.asarray(confidence, dtype=np.float64)
    if ratio == 0.0 or p.shape[0] < 2:
        return np.zeros(p.shape[0], bool)
    t = tree if tree is not None else cKDTree(p)
    k = min(max_neighbours, p.shape[0])
    dist, idx = t.query(p, k=k, distance_upper_bound=radius_mm, workers=-1)
    valid = np.isfinite(dist)
    idx = np.where(valid, idx, 0)
    facing = np.einsum("nj,nkj->nk", nr, nr[idx]) > 0.5
    best = np.max(np.where(valid & facing, c[idx], 0.0), axis=1)
    return c < ratio * best


def fuse_points(
    points: ArrayLike,
    normals: ArrayLike,
    confidence: ArrayLike | None = None,
    *,
    voxel_mm: float,
    min_confidence: float = 0.0,
) -> FusedCloud:
    """Merge an oriented cloud per voxel with confidence weights.

    Parameters
    ----------
    points
        ``(N, 3)`` positions (mm).
    normals
        ``(N, 3)`` outward normals (any non-zero length).
    confidence
        ``(N,)`` per-point confidence in [0, 1] (None: all 1).
    voxel_mm
        Voxel edge (mm), > 0; about the point spacing merges overlapping
        passes without losing resolution.
    min_confidence
        Points with confidence below this (and all points of confidence 0)
        are dropped, in [0, 1).

    Returns
    -------
    FusedCloud
        One sample per voxel and facing, with its confidence and count.

    Raises
    ------
    ValueError
        Bad cloud (see :func:`validate_oriented_cloud`), bad ``voxel_mm`` or
        ``min_confidence``, or no point left above ``min_confidence``.
    """
    if not (isinstance(voxel_mm, (int, float, np.floating, np.integer)) and np.isfinite(voxel_mm) and voxel_mm > 0):
        raise InputError(f"voxel_mm must be a finite length > 0 (mm), got {voxel_mm!r}")
    if not (0.0 <= float(min_confidence) < 1.0):
        raise InputError(f"min_confidence must be in [0, 1), got {min_confidence!r}")
    p, n, c = validate_oriented_cloud(points, normals, confidence)
    keep = (c >= min_confidence) & (c > 0.0)
    n_low = int(np.count_nonzero(~keep))
    if not keep.any():
        raise InputError(
            f"confidence: all {p.shape[0]} points have confidence below min_confidence={min_confidence}; "
            "nothing is left to mesh"
        )
    p, n, c = p[keep], n[keep], c[keep]
    lo = p.min(axis=0)
    idx = np.floor((p - lo) / float(voxel_mm)).astype(np.int64)
    dims = idx.max(axis=0) + 1
    if float(np.prod(dims.astype(np.float64))) * 6.0 >= 2.0**62:
        raise InputError(
            f"voxel_mm={voxel_mm} is too small for a cloud of extent {(p.max(axis=0) - lo).tolist()} mm"
        )
    axis = np.argmax(np.abs(n), axis=1)
    bucket = 2 * axis + (n[np.arange(n.shape[0]), axis] < 0)
    key = np.ravel_multi_index((idx[:, 0], idx[:, 1], idx[:, 2]), dims) * 6 + bucket
    _, inv, counts = np.unique(key, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    m = counts.size
    wsum = np.bincount(inv, weights=c, minlength=m)
    fp = np.empty((m, 3))
    fn = np.empty((m, 3))
    for k in range(3):
        fp[:, k] = np.bincount(inv, weights=c * p[:, k], minlength=m) / wsum
        fn[:, k] = np.bincount(inv, weights=c * n[:, k], minlength=m)
    length = np.linalg.norm(fn, axis=1)
    weak = length <= 1e-9 * wsum
    if weak.any():  # opposite normals cancelled: keep the normal of one member
        first = np.zeros(m, np.int64)
        first[inv[::-1]] = np.arange(inv.size)[::-1]
        fn[weak] = n[first[weak]]
        length[weak] = 1.0
    fn /= length[:, None]
    conf = np.bincount(inv, weights=c * c, minlength=m) / wsum
    return FusedCloud(
        points=fp,
        normals=fn,
        confidence=conf,
        counts=counts.astype(np.int64),
        voxel_mm=float(voxel_mm),
        n_input=int(keep.size),
        n_low_confidence=n_low,
    )
