"""An object's pixels split into candidate material regions without ground truth.

Matsuda et al., section 4.2, identify one material per region; this module
provides the regions when no label image exists: the booth backdrop is
measured on the frame's border ring and removed, dark pixels are dropped,
and the lit object pixels are clustered by the chromaticity of a small
window around each.  docs/materials.md, section "Regions without ground
truth", gives the steps and their limits; docs/batch.md, section "The
materials step", how the batch pipeline uses them.

References
----------
.. [1] Matsuda, Tanaka, Ichikawa, Mochizuki, Muroya, Kitamura, "CG
   reproduction of a craft object based on a light reflection model", IPSJ
   technical report (no DOI), section 4.2.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.errors import InputError

__all__ = ["Segmentation", "SegmentationError", "border_backdrop", "segment_regions"]


class SegmentationError(InputError):
    """The image or a parameter cannot be segmented; the message says which and why."""


@dataclass(frozen=True)
class Segmentation:
    """Result of :func:`segment_regions`.

    Attributes
    ----------
    labels
        ``(H, W)`` cluster index + 1 per lit object pixel, 0 elsewhere; 1 is the largest cluster.
    backdrop
        ``(H, W)`` pixels taken for backdrop.
    backdrop_rgb
        ``(3,)`` the backdrop's median level per channel (1.0 = white diffuser).
    centres
        ``(K, 3)`` chromaticity of each cluster (rows in label order).
    """

    labels: NDArray[np.int64]
    backdrop: NDArray[np.bool_]
    backdrop_rgb: NDArray[np.float64]
    centres: NDArray[np.float64]


def border_backdrop(rel: ArrayLike, mask: ArrayLike, border: float = 0.06) -> NDArray[np.float64]:
    """Median level per channel of the unmasked pixels in the frame's border ring.

    Parameters
    ----------
    rel
        ``(H, W, 3)`` levels relative to a white diffuser.
    mask
        ``(H, W)`` usable pixels.
    border
        Width of the ring as a fraction of the shorter side (at least one pixel).

    Returns
    -------
    ndarray
        ``(3,)`` median level per channel (1.0 = white diffuser).

    Raises
    ------
    SegmentationError
        The ring holds no usable (unmasked, finite) pixel.

    Examples
    --------
    >>> rel = np.full((10, 10, 3), 0.05); rel[3:7, 3:7] = 0.8
    >>> border_backdrop(rel, np.ones((10, 10), bool)).tolist()
    [0.05, 0.05, 0.05]
    """
    x = np.asarray(rel, dtype=np.float64)
    m = np.asarray(mask, dtype=bool)
    h, w = m.shape
    b = max(1, int(round(border * min(h, w))))
    ring = np.zeros((h, w), bool)
    ring[:b], ring[-b:], ring[:, :b], ring[:, -b:] = True, True, True, True
    sel = ring & m & np.isfinite(x).all(axis=2)
    if not sel.any():
        raise SegmentationError("the frame's border shows no usable pixel, so the backdrop cannot be measured; "
                                "frame the object with backdrop around it")
    return np.median(x[sel], axis=0)


def segment_regions(rel: ArrayLike, mask: ArrayLike, *, clusters: int = 6, min_level: float = 0.005,
                    backdrop_factor: float = 1.6, backdrop_chroma: float = 0.06, min_pixels: int = 8,
                    border: float = 0.06, smooth: int = 2, seed: int = 0) -> Segmentation:
    """Backdrop removed, lit object pixels clustered by chromaticity.

    The backdrop is measured on the frame's border ring; pixels near its
    level and chromaticity are backdrop.  Of the rest, masked pixels and
    pixels darker than ``min_level`` are dropped, and the lit pixels are
    clustered by k-means on the chromaticity of the summed RGB in a small
    window around each (docs/materials.md, "Regions without ground truth").

    Parameters
    ----------
    rel
        ``(H, W, 3)`` camera RGB relative to a white diffuser lit like the chart (dimensionless).
    mask
        ``(H, W)`` pixels neither saturated nor dead in the RAW.
    clusters
        Most clusters to form (fewer when there are few pixels: at least ``min_pixels`` each).
    min_level
        Pixels whose brightest channel is below this fraction of the white are ignored.
    backdrop_factor
        A pixel within this factor of the backdrop's level (either way) and ...
    backdrop_chroma
        ... within this chromaticity distance of the backdrop's is backdrop.
    min_pixels
        Clusters smaller than this are dropped (label 0).
    border
        Width of the border ring measuring the backdrop (fraction of the shorter side).
    smooth
        Half-width (pixels) of the window whose lit pixels' summed RGB gives each pixel's chromaticity.
    seed
        Seed of the k-means initialisation (the result is deterministic).

    Returns
    -------
    Segmentation
        Labels (1 the largest cluster, 0 not a lit object pixel), backdrop
        mask, backdrop level and cluster chromaticities.

    Raises
    ------
    SegmentationError
        Mismatched shapes, a parameter out of range, or a border ring
        without usable pixels.

    Examples
    --------
    >>> rel = np.full((20, 20, 3), 0.05)
    >>> rel[5:15, 5:10] = (0.6, 0.4, 0.1)        # a gold-like patch
    >>> rel[5:15, 12:17] = (0.1, 0.2, 0.5)       # a blue patch, two pixels apart
    >>> seg = segment_regions(rel, np.ones((20, 20), bool), clusters=2)
    >>> sorted(np.bincount(seg.labels.ravel()).tolist())
    [50, 50, 300]
    >>> int(seg.backdrop.sum())
    300
    """
    x = np.asarray(rel, dtype=np.float64)
    m = np.asarray(mask, dtype=bool)
    _check_arguments(x, m, clusters, min_level, backdrop_factor, backdrop_chroma, min_pixels)
    m = m & np.isfinite(x).all(axis=2)
    x = np.where(m[..., None], np.maximum(x, 0.0), 0.0)
    back = border_backdrop(x, m, border)
    backdrop = _backdrop_mask(x, m, back, backdrop_factor, backdrop_chroma)
    lit = m & ~backdrop & (x.max(axis=2) >= min_level)
    labels = np.zeros(m.shape, np.int64)
    n = int(lit.sum())
    k = min(clusters, n // min_pixels)
    if k < 1:
        return Segmentation(labels, backdrop, back, np.zeros((0, 3)))
    feats = _window_chromaticity(x, lit, smooth)
    # k-means++ draws seeds in proportion to squared distances: fewer distinct colours than clusters
    # would leave all distances 0 (no seed to draw), so k never exceeds the distinct colours
    k = min(k, len(np.unique(np.round(feats, 6), axis=0)))
    idx = _cluster_indices(feats, k, n, seed)
    counts = np.bincount(idx, minlength=k)
    order = [c for c in np.argsort(-counts, kind="stable") if counts[c] >= min_pixels]
    lut = np.zeros(k, np.int64)
    for new, old in enumerate(order, start=1):
        lut[old] = new
    labels[lit] = lut[idx]
    centres = np.array([feats[idx == old].mean(axis=0) for old in order]).reshape(-1, 3)
    return Segmentation(labels, backdrop, back, centres)


def _check_arguments(x: NDArray[np.float64], m: NDArray[np.bool_], clusters: int, min_level: float,
                     backdrop_factor: float, backdrop_chroma: float, min_pixels: int) -> None:
    """Refuse mismatched shapes and parameters out of range."""
    if x.ndim != 3 or x.shape[2] != 3 or m.shape != x.shape[:2]:
        raise SegmentationError(f"rel must be (H, W, 3) and mask (H, W); got {x.shape} and {m.shape}")
    if not (isinstance(clusters, int) and 1 <= clusters <= 64):
        raise SegmentationError(f"clusters must be an integer 1..64, got {clusters!r}")
    if not (0 < min_level < 1 and backdrop_factor > 1 and 0 < backdrop_chroma < 1 and min_pixels >= 1):
        raise SegmentationError("min_level must be in (0, 1), backdrop_factor > 1, backdrop_chroma in (0, 1), "
                                f"min_pixels >= 1; got {min_level}, {backdrop_factor}, {backdrop_chroma}, {min_pixels}")


def _backdrop_mask(x: NDArray[np.float64], m: NDArray[np.bool_], back: NDArray[np.float64],
                   backdrop_factor: float, backdrop_chroma: float) -> NDArray[np.bool_]:
    """Pixels near the backdrop's level and chromaticity, plus the silhouette ring no brighter than it."""
    from scipy.ndimage import binary_dilation

    total = x.sum(axis=2)
    chroma = x / np.maximum(total, 1e-12)[..., None]
    level = total / 3.0
    b_level = float(back.mean())
    b_chroma = back / max(float(back.sum()), 1e-12)
    near_level = (level <= b_level * backdrop_factor) & (level >= b_level / backdrop_factor)
    near_chroma = np.linalg.norm(chroma - b_chroma, axis=2) <= backdrop_chroma
    backdrop = m & near_level & near_chroma
    # a binned cell on the silhouette mixes backdrop photosites with the object's (one channel from each):
    # the ring next to the backdrop, no brighter than the backdrop, goes with it
    backdrop |= m & binary_dilation(backdrop) & (level <= b_level)
    return backdrop


def _window_chromaticity(x: NDArray[np.float64], lit: NDArray[np.bool_], smooth: int) -> NDArray[np.float64]:
    """``(n, 3)`` chromaticity of the summed RGB of the lit pixels in the window around each lit pixel."""
    from scipy.ndimage import uniform_filter

    # a mirror's highlight may light one photosite of a CFA cell: per-pixel chromaticity is then one
    # channel only; the sum over a small window of lit pixels (as identification sums a region) is not
    window = 2 * smooth + 1
    local = np.stack([uniform_filter(np.where(lit, x[..., c], 0.0), size=window, mode="constant")
                      for c in range(3)], axis=2)
    return (local / np.maximum(local.sum(axis=2), 1e-12)[..., None])[lit]


def _cluster_indices(feats: NDArray[np.float64], k: int, n: int, seed: int) -> NDArray[np.int64]:
    """k-means cluster index of each of the ``n`` features (all 0 when ``k == 1``)."""
    from scipy.cluster.vq import kmeans2

    if k == 1:
        return np.zeros(n, np.int64)
    # k-means++ seeding, a fixed seed: the same frame always gives the same regions
    with warnings.catch_warnings():
        # an empty cluster is harmless: it is dropped below like any cluster under min_pixels
        warnings.filterwarnings("ignore", "One of the clusters is empty", UserWarning)
        _, idx = kmeans2(feats, k, minit="++", seed=np.random.default_rng(seed))
    return idx
