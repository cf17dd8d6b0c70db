"""The camera's point spread, measured by matching a rendering of a posed photo to the photo.

A camera's lens and its optical low-pass (anti-aliasing) filter spread every
point of the scene over about a photosite before the colour filter array
samples it; a ray-cast rendering draws the scene through a pinhole.  Where
the image changes fast (a mirror-like highlight, a material's edge, a cast
shadow's edge) the photo is the rendering convolved with that spread.  With
the object's shape and materials measured and the frame posed, the spread is
what remains to match: :func:`fit_point_spread` blurs the pinhole rendering
by Gaussians of standard deviation ``sigma`` (pixels) within the object
(:func:`spread_within`) and keeps the ``sigma`` whose
rendering is closest to the photo in the least-squares sense on
``asinh(signal / level)`` (linear below ``level``, logarithmic above), over the
object's unclipped pixels away from its outline (where the photo also mixes
in the backdrop, which is not rendered).  In plain linear units the few
brightest highlights -- where a fitted material's misfit is largest -- decide
alone and ask for ever more spread: on the simulated station's demo session
(lens 1 photosite, bilinear demosaic) linear least squares gave 1.45 px and,
at 240 x 180, ran to the grid's end; on the asinh scale 1.13 and 0.99 px, and
the held-out comparison with them is closer (docs/validation.md).

A Gaussian is the usual one-parameter model of a lens plus a birefringent
low-pass filter near focus (the line-spread of a slanted-edge measurement,
ISO 12233, is close to Gaussian for such systems).  The figure measured this
way also takes up what the materials' fit left unexplained at fine scale
(a highlight fitted a little too wide asks for less spread), so it is the
spread *of this rendering* against these photos: the one to use when
comparing renderings with photos of the same session.

References
----------
ISO 12233:2017.  Photography -- Electronic still picture imaging --
Resolution and spatial frequency responses.

Knutsson, H., Westin, C.-F. (1993). Normalized and differential
convolution.  IEEE CVPR, 515-523.  doi:10.1109/CVPR.1993.341081
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from processing.errors import InputError

__all__ = ["PointSpreadFit", "PointSpreadError", "fit_point_spread", "spread_within", "SPREAD_GRID_PX",
           "TRUNCATE_SIGMAS", "LEVEL"]

#: The spreads tried (pixels, Gaussian standard deviation): a pinhole to two photosites.
SPREAD_GRID_PX = tuple(np.round(np.arange(0.0, 2.0001, 0.125), 3).tolist())
#: Signal (chart-normalised: a white diffuser reads 1) where the comparison turns from linear to logarithmic.
LEVEL = 0.01
#: The Gaussian kernel's reach in standard deviations (scipy's default truncation).
TRUNCATE_SIGMAS = 4.0
_MIN_PIXELS = 200


class PointSpreadError(InputError):
    """The point spread cannot be measured from these images; the message says why and what to give."""


@dataclass(frozen=True)
class PointSpreadFit:
    """The spread that matches the rendering to the photos best.

    Attributes
    ----------
    sigma_px
        Gaussian standard deviation (pixels), refined between the grid's
        nodes by a parabola through the three around the minimum.
    rms_at_sigma, rms_pinhole
        Root-mean-square difference of ``asinh(signal / level)`` at
        ``sigma_px``'s nearest grid node and without spread.
    curve
        ``(sigma, rms)`` per grid node.
    n_pixels
        Pixels compared (all images).
    at_limit
        The best spread is the grid's largest: the true one may be larger (or the rendering
        misses fine detail the photos have not: a material fitted too smooth).
    """

    sigma_px: float
    rms_at_sigma: float
    rms_pinhole: float
    curve: tuple[tuple[float, float], ...]
    n_pixels: int
    at_limit: bool = False

    def to_dict(self) -> dict[str, object]:
        """JSON-ready figures."""
        return {"sigma_px": self.sigma_px, "rms_at_sigma": self.rms_at_sigma, "rms_pinhole": self.rms_pinhole,
                "n_pixels": self.n_pixels, "at_limit": self.at_limit, "curve": [list(c) for c in self.curve]}


def fit_point_spread(photos: Sequence[ArrayLike], renderings: Sequence[ArrayLike], masks: Sequence[ArrayLike], *,
                     clip_level: float | ArrayLike | None = None, sigmas_px: Sequence[float] = SPREAD_GRID_PX,
                     level: float = LEVEL) -> PointSpreadFit:
    """The Gaussian point spread that brings pinhole renderings closest to their photos.

    Parameters
    ----------
    photos
        ``(H, W, 3)`` linear photos (the same units as the renderings).
    renderings
        Their ``(H, W, 3)`` pinhole renderings (:func:`render.photo_signal.render_signal` with no spread).
    masks
        ``(H, W)`` bool: the rendered object's measured pixels.
    clip_level
        Photo signal at which the sensor saturates (scalar or per channel); such pixels and their
        neighbours within the largest spread's reach are left out.  None: keep all.
    sigmas_px
        The spreads to try (pixels, ascending, >= 0, at least 3).
    level
        Signal (the images' units) below which differences count linearly and above which
        logarithmically; the default suits chart-normalised signal (a white diffuser reads 1).

    Returns
    -------
    PointSpreadFit

    Raises
    ------
    PointSpreadError
        Images of different shapes, non-finite photo values on the object, or fewer than 200
        comparable pixels.

    Examples
    --------
    >>> from scipy.ndimage import gaussian_filter
    >>> rng = np.random.default_rng(0)
    >>> sharp = np.zeros((64, 64, 3)); sharp[20:44, 20:44] = 0.1; sharp[30, 25:40] = 5.0   # a line highlight
    >>> photo = gaussian_filter(sharp, (0.8, 0.8, 0)) + rng.normal(0, 0.002, sharp.shape)
    >>> mask = np.zeros((64, 64), bool); mask[10:54, 10:54] = True
    >>> fit = fit_point_spread([photo], [sharp], [mask])
    >>> round(fit.sigma_px, 1), fit.rms_at_sigma < fit.rms_pinhole
    (0.8, True)
    """
    if not (np.isfinite(level) and level > 0):
        raise PointSpreadError(f"level must be a signal > 0, got {level!r}")
    grid = np.asarray(sigmas_px, dtype=np.float64)
    if grid.ndim != 1 or grid.size < 3 or not np.all(np.isfinite(grid)) or grid[0] < 0 or np.any(np.diff(grid) <= 0):
        raise PointSpreadError(f"sigmas_px must be >= 3 ascending spreads >= 0 px, got {list(sigmas_px)!r}")
    if not (len(photos) == len(renderings) == len(masks)) or len(photos) == 0:
        raise PointSpreadError(f"give one rendering and one mask per photo, got {len(photos)} photos, "
                               f"{len(renderings)} renderings and {len(masks)} masks")
    reach = int(math.ceil(TRUNCATE_SIGMAS * grid[-1])) + 1
    sse = np.zeros(grid.size)
    n = 0
    for k, (photo, render, mask) in enumerate(zip(photos, renderings, masks, strict=True)):
        p = np.asarray(photo, dtype=np.float64)
        r = np.asarray(render, dtype=np.float64)
        m = np.asarray(mask, dtype=bool)
        if p.shape != r.shape or p.ndim != 3 or p.shape[:2] != m.shape:
            raise PointSpreadError(f"image {k}: photo {p.shape}, rendering {r.shape} and mask {m.shape} differ; "
                                   f"render the photo's own frame")
        m = m & np.all(np.isfinite(r), axis=-1)
        if not np.all(np.isfinite(p[m])):
            raise PointSpreadError(f"image {k}: the photo has NaN or infinite values on the object; decode it again")
        use = ndimage.binary_erosion(m, iterations=reach)
        if clip_level is not None:
            clipped = np.any(p >= np.asarray(clip_level, dtype=np.float64), axis=-1)
            use &= ~ndimage.binary_dilation(clipped, iterations=reach)
        if not use.any():
            continue
        n += int(use.sum())
        target = np.arcsinh(p[use] / level)
        for j, s in enumerate(grid):
            blurred = np.asarray(spread_within(r, m, float(s)), dtype=np.float64) if s > 0 else r
            sse[j] += float(np.sum((np.arcsinh(blurred[use] / level) - target) ** 2))
    if n < _MIN_PIXELS:
        raise PointSpreadError(f"only {n} object pixels lie {reach} px inside the outline and away from clipping "
                               f"(need {_MIN_PIXELS}); give larger or less clipped frames")
    rms = np.sqrt(sse / (3 * n))
    j = int(np.argmin(rms))
    sigma = float(grid[j])
    if 0 < j < grid.size - 1:
        x = grid[j - 1:j + 2]
        a, b, _ = np.polyfit(x, sse[j - 1:j + 2], 2)         # the parabola through the three nodes
        if a > 0:
            sigma = float(np.clip(-b / (2 * a), x[0], x[2]))
    curve = tuple((float(s), float(e)) for s, e in zip(grid, rms, strict=True))
    return PointSpreadFit(sigma, float(rms[j]), float(rms[0]) if grid[0] == 0 else float("nan"), curve, n,
                          j == grid.size - 1)


def spread_within(image: ArrayLike, mask: ArrayLike, sigma_px: float) -> NDArray[np.float32]:
    """A Gaussian point spread of ``sigma_px`` pixels over the ``mask`` pixels of ``image`` only.

    Normalised convolution: ``G * (image mask) / G * mask``, so pixels outside
    the mask (the backdrop, unmeasured faces) neither enter nor dim it.

    Parameters
    ----------
    image
        ``(H, W, C)`` linear image.
    mask
        ``(H, W)`` bool: the pixels to spread over.
    sigma_px
        Gaussian standard deviation (pixels), > 0.

    Returns
    -------
    numpy.ndarray
        ``(H, W, C)`` float32: the spread values on the mask, ``image`` elsewhere.

    Examples
    --------
    >>> img = np.zeros((15, 15, 3)); img[7, 7] = 1.0
    >>> out = spread_within(img, np.ones((15, 15), bool), 1.0)
    >>> round(float(out[..., 0].sum()), 4), round(float(out[7, 7, 0]), 3)
    (1.0, 0.159)
    >>> half = np.ones((15, 15, 3)); left = np.zeros((15, 15), bool); left[:, :8] = True
    >>> float(spread_within(half, left, 1.0)[7, 7, 0])     # the unmasked half does not dim the edge
    1.0
    """
    img = np.asarray(image, dtype=np.float64)
    m = np.asarray(mask, dtype=bool)
    vals = np.where(m[..., None], np.nan_to_num(img), 0.0)
    sig = (sigma_px, sigma_px, 0.0)
    num = ndimage.gaussian_filter(vals, sigma=sig, mode="constant")
    den = ndimage.gaussian_filter(m.astype(np.float64), sigma=(sigma_px, sigma_px), mode="constant")
    out = np.where(m[..., None], num / np.maximum(den, 1e-12)[..., None], img)
    return out.astype(np.float32)
