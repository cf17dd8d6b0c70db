"""Colour difference between a photo and a rendering of it, in CIEDE2000 per pixel.

Both images hold chart-normalised linear camera RGB (a white diffuser facing
the lamp at the chart's irradiance reads (1, 1, 1)).  :func:`compare_images`
takes both through the same camera-RGB -> XYZ matrix, to CIELAB relative to
that white diffuser, and measures CIEDE2000 per pixel over the object's
pixels, the mask eroded by a margin (silhouette pixels mix the backdrop).
:func:`camera_to_xyz_matrix` fits that matrix for a camera and a lamp on the
ColorChecker's 24 reflectances (least squares of XYZ on camera RGB, both
relative to the white diffuser), so a rendering and a photo from the same
camera are compared in one colour space whatever the matrix's residual
error.

References
----------
Sharma, G., Wu, W., Dalal, E. N. (2005). The CIEDE2000 color-difference
formula: implementation notes, supplementary test data, and mathematical
observations. Color Research & Application 30(1), 21-30.
doi:10.1002/col.20070

CIE 015:2018 Colorimetry, 4th edition. doi:10.25039/TR.015.2018

Examples
--------
>>> import numpy as np
>>> img = np.full((6, 6, 3), 0.3, np.float32)
>>> res = compare_images(img, img, np.ones((6, 6), bool), np.eye(3), white_xyz=[0.95, 1.0, 1.09])
>>> res.mean_de2000, res.n_pixels
(0.0, 4)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from processing.errors import InputError

__all__ = ["ImageComparison", "PhotoComparisonError", "compare_images", "noise_floor", "camera_to_xyz_matrix",
           "signal_to_lab", "pool_blocks", "MIN_SIGNAL"]

#: Lowest signal accepted (sensor noise around black); values in [MIN_SIGNAL, 0) count as 0.
MIN_SIGNAL = -0.05


class PhotoComparisonError(InputError):
    """An image, mask or colour matrix cannot be compared; the message names it."""


@dataclass(frozen=True)
class ImageComparison:
    """CIEDE2000 between a photo and its rendering over the object's pixels.

    Attributes
    ----------
    mean_de2000, p95_de2000, median
        Mean, 95th percentile and median CIEDE2000 over the compared pixels.
    n_pixels
        Number of compared pixels (the mask eroded by the edge margin); when compared in blocks
        (``pool_px > 1``), the number of compared blocks.
    error_map
        ``(H, W)`` float32 CIEDE2000 per pixel, NaN outside the compared pixels (in blocks: each
        block's value on all its pixels).
    """

    mean_de2000: float
    p95_de2000: float
    median: float
    n_pixels: int
    error_map: NDArray[np.float32] = field(repr=False)

    @property
    def median_de2000(self) -> float:
        """The median CIEDE2000 (:attr:`median`)."""
        return self.median

    def to_dict(self) -> dict[str, Any]:
        """The figures (no map) as a JSON-ready dict."""
        return {"mean_de2000": self.mean_de2000, "p95_de2000": self.p95_de2000,
                "median_de2000": self.median, "n_pixels": self.n_pixels}


def _matrix3(value: ArrayLike, name: str) -> NDArray[np.float64]:
    try:
        m = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        m = np.array([np.nan])
    if m.shape != (3, 3) or not np.all(np.isfinite(m)) or abs(np.linalg.det(m)) < 1e-12:
        raise PhotoComparisonError(f"{name}: give a finite invertible 3 x 3 matrix (camera RGB -> XYZ)")
    return m


def signal_to_lab(signal: ArrayLike, camera_to_xyz: ArrayLike, white_xyz: ArrayLike | None = None) -> NDArray[np.float64]:
    """CIELAB of chart-normalised camera RGB, relative to the white diffuser.

    Parameters
    ----------
    signal
        ``(..., 3)`` camera RGB, white diffuser = (1, 1, 1); finite, >= 0.
    camera_to_xyz
        ``(3, 3)``: ``xyz = camera_to_xyz @ rgb``.
    white_xyz
        XYZ of the reference white; None: ``camera_to_xyz @ (1, 1, 1)``
        (the white diffuser).  Only its chromaticity and Y scale matter.

    Returns
    -------
    ndarray
        ``(..., 3)`` L*, a*, b*.

    Examples
    --------
    >>> np.round(signal_to_lab([1.0, 1.0, 1.0], np.eye(3)), 6).tolist()
    [100.0, 0.0, 0.0]
    """
    import colour

    m = _matrix3(camera_to_xyz, "camera_to_xyz")
    white = m @ np.ones(3) if white_xyz is None else np.asarray(white_xyz, dtype=np.float64)
    if white.shape != (3,) or not np.all(np.isfinite(white)) or not np.all(white > 0):
        raise PhotoComparisonError(f"white_xyz: give three finite XYZ values > 0, got {white.tolist()}")
    xyz = np.asarray(signal, dtype=np.float64) @ m.T / white[1]
    xy = colour.XYZ_to_xy(white / white[1])
    return np.asarray(colour.XYZ_to_Lab(xyz, illuminant=xy), dtype=np.float64)


def _checked_image(image: ArrayLike, name: str, shape: tuple[int, ...] | None) -> NDArray[np.float64]:
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3 or 0 in img.shape or (shape is not None and img.shape != shape):
        want = "(H, W, 3)" if shape is None else str(shape)
        raise PhotoComparisonError(f"{name}: give a {want} camera RGB image, got shape {img.shape}")
    if not np.issubdtype(img.dtype, np.number):
        raise PhotoComparisonError(f"{name}: give a numeric image, got dtype {img.dtype}")
    return img


def _compared_pixels(mask: ArrayLike, shape: tuple[int, int], edge_margin_px: int) -> NDArray[np.bool_]:
    m = np.asarray(mask)
    if m.shape != shape or m.dtype != np.bool_:
        raise PhotoComparisonError(f"mask: give a bool array of shape {shape}, got {m.dtype} {m.shape}")
    if isinstance(edge_margin_px, bool) or int(edge_margin_px) != edge_margin_px or edge_margin_px < 0:
        raise PhotoComparisonError(f"edge_margin_px: give a whole number of pixels >= 0, got {edge_margin_px!r}")
    if edge_margin_px > 0:
        m = ndimage.binary_erosion(m, iterations=int(edge_margin_px))
    if not m.any():
        raise PhotoComparisonError(f"mask: no object pixel is left after eroding {edge_margin_px} px; "
                                   "render the object larger or lower edge_margin_px")
    return m


def _pixel_values(image: NDArray[Any], sel: NDArray[np.bool_], name: str) -> NDArray[np.float64]:
    values = image[sel].astype(np.float64)
    if not np.all(np.isfinite(values)):
        raise PhotoComparisonError(f"{name}: {int(np.sum(~np.isfinite(values).all(axis=1)))} object pixel(s) are "
                                   "NaN or infinite; mask them out or fix the image")
    if np.any(values < MIN_SIGNAL):
        raise PhotoComparisonError(f"{name}: object pixels down to {float(values.min()):.3g} (below {MIN_SIGNAL}); "
                                   "give black-subtracted, chart-normalised linear camera RGB")
    return np.maximum(values, 0.0)


def _block_size(pool_px: Any) -> int:
    if isinstance(pool_px, bool) or not isinstance(pool_px, (int, np.integer)) or pool_px < 1:
        raise PhotoComparisonError(f"pool_px: give a whole number of pixels >= 1, got {pool_px!r}")
    return int(pool_px)


def pool_blocks(signal: ArrayLike, mask: ArrayLike, block_px: int) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Mean linear signal over ``block_px x block_px`` blocks whose pixels are all in ``mask``.

    The blocks tile the image from its top-left corner; rows and columns past the last whole
    block are dropped.  Averaging linear values (before any colour conversion) is what a camera
    with ``block_px`` times larger pixels would record, so comparing pooled images compares the
    colours at that spatial scale; independent noise falls by ``block_px``.

    Parameters
    ----------
    signal
        ``(H, W, C)`` linear values.
    mask
        ``(H, W)`` bool.
    block_px
        Block side (>= 1 pixels).

    Returns
    -------
    pooled : ndarray
        ``(H // block_px, W // block_px, C)`` float64 block means (of all the block's pixels).
    kept : ndarray
        ``(H // block_px, W // block_px)`` bool: every pixel of the block is in ``mask``.

    Examples
    --------
    >>> img = np.arange(16, dtype=float).reshape(4, 4, 1)
    >>> m = np.ones((4, 4), bool)
    >>> m[0, 0] = False
    >>> pooled, kept = pool_blocks(img, m, 2)
    >>> pooled[..., 0].tolist(), kept.tolist()
    ([[2.5, 4.5], [10.5, 12.5]], [[False, True], [True, True]])
    """
    s = _block_size(block_px)
    img = np.asarray(signal, dtype=np.float64)
    m = np.asarray(mask, dtype=bool)
    if img.ndim != 3 or m.shape != img.shape[:2]:
        raise PhotoComparisonError(f"pool_blocks: give an (H, W, C) image and an (H, W) mask, got {img.shape} "
                                   f"and {m.shape}")
    h, w = img.shape[0] // s, img.shape[1] // s
    if h == 0 or w == 0:
        raise PhotoComparisonError(f"pool_blocks: the image ({img.shape[1]} x {img.shape[0]}) is smaller than one "
                                   f"{s} px block; give a smaller pool_px")
    blocks = img[:h * s, :w * s].reshape(h, s, w, s, -1)
    kept = m[:h * s, :w * s].reshape(h, s, w, s).all(axis=(1, 3))
    return blocks.mean(axis=(1, 3)), kept


def compare_images(photo_signal: ArrayLike, render_signal: ArrayLike, mask: ArrayLike, camera_to_xyz: ArrayLike, *,
                   white_xyz: ArrayLike | None = None, edge_margin_px: int = 2, pool_px: int = 1) -> ImageComparison:
    """Mean, p95 and map of CIEDE2000 between a photo and its rendering over the object's pixels.

    Parameters
    ----------
    photo_signal, render_signal
        ``(H, W, 3)`` chart-normalised linear camera RGB (white diffuser = 1).
    mask
        ``(H, W)`` bool: the object's pixels (e.g. the rendering's mask).
    camera_to_xyz
        ``(3, 3)`` camera RGB -> XYZ (:func:`camera_to_xyz_matrix`), applied to both images.
    white_xyz
        The reference white's XYZ; None: ``camera_to_xyz @ (1, 1, 1)``.
    edge_margin_px
        Erode the mask by this many pixels (the silhouette mixes the backdrop).
    pool_px
        Compare at this spatial scale: both images' linear values averaged over ``pool_px x
        pool_px`` blocks lying wholly inside the eroded mask (:func:`pool_blocks`) before the
        conversion to CIELAB; 1 compares pixel by pixel.

    Returns
    -------
    ImageComparison

    Raises
    ------
    PhotoComparisonError
        Mismatched shapes, a non-bool mask, no pixel (block) left, NaN or strongly
        negative values on compared pixels, a singular matrix.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> grey = np.full((64, 64, 3), 0.05)
    >>> noisy = grey + 0.005 * rng.standard_normal(grey.shape)
    >>> m, ok = np.eye(3), np.ones((64, 64), bool)
    >>> [round(compare_images(noisy, grey, ok, m, pool_px=s).mean_de2000, 1) for s in (1, 4)]   # noise sd / 4
    [8.5, 2.7]
    """
    import colour

    photo = _checked_image(photo_signal, "photo_signal", None)
    rend = _checked_image(render_signal, "render_signal", photo.shape)
    sel = _compared_pixels(mask, photo.shape[:2], edge_margin_px)
    s = _block_size(pool_px)
    if s > 1:
        pp = _pixel_values(photo, sel, "photo_signal")        # checks the compared pixels
        pr = _pixel_values(rend, sel, "render_signal")
        p_img = np.zeros(photo.shape, np.float64)
        r_img = np.zeros(photo.shape, np.float64)
        p_img[sel], r_img[sel] = pp, pr
        p_img, kept = pool_blocks(p_img, sel, s)
        r_img, _ = pool_blocks(r_img, sel, s)
        if not kept.any():
            raise PhotoComparisonError(f"mask: no {s} x {s} px block lies wholly inside the object; give a "
                                       "smaller pool_px")
        lab_p = signal_to_lab(p_img[kept], camera_to_xyz, white_xyz)
        lab_r = signal_to_lab(r_img[kept], camera_to_xyz, white_xyz)
        de = np.asarray(colour.delta_E(lab_p, lab_r, method="CIE 2000"), dtype=np.float64)
        blocks = np.full(kept.shape, np.nan, dtype=np.float32)
        blocks[kept] = de
        error_map = np.full(photo.shape[:2], np.nan, dtype=np.float32)
        error_map[:kept.shape[0] * s, :kept.shape[1] * s] = np.repeat(np.repeat(blocks, s, axis=0), s, axis=1)
        return ImageComparison(float(np.mean(de)), float(np.percentile(de, 95)), float(np.median(de)), int(de.size),
                               error_map)
    lab_p = signal_to_lab(_pixel_values(photo, sel, "photo_signal"), camera_to_xyz, white_xyz)
    lab_r = signal_to_lab(_pixel_values(rend, sel, "render_signal"), camera_to_xyz, white_xyz)
    de = np.asarray(colour.delta_E(lab_p, lab_r, method="CIE 2000"), dtype=np.float64)
    error_map = np.full(photo.shape[:2], np.nan, dtype=np.float32)
    error_map[sel] = de
    return ImageComparison(float(np.mean(de)), float(np.percentile(de, 95)), float(np.median(de)), int(de.size),
                           error_map)


def noise_floor(render_signal: ArrayLike, mask: ArrayLike, camera_to_xyz: ArrayLike, noise_ab: ArrayLike, *,
                white_xyz: ArrayLike | None = None, edge_margin_px: int = 2, seed: int = 0, cfa: str | None = None,
                frames: int = 1, pool_px: int = 1) -> ImageComparison:
    """CIEDE2000 between a rendering and the same rendering with the sensor's noise: what a perfect model scores.

    A photo carries shot and read noise, so even the true materials on the true shape do not reach
    0; this is the comparison :func:`compare_images` would report for them, pixel by pixel, with
    noise of variance ``a + b * signal`` per channel (the noise model of the observations) drawn
    with ``seed``.  With ``cfa`` the noise is drawn on a Bayer mosaic of the rendering and both
    the noisy and the clean mosaic are demosaicked bilinearly
    (:func:`processing.camera.raw_decode.bilinear_demosaic`, what the photos' ``demosaic`` decode
    does), so the floor carries the interpolation's averaging and correlation of the noise, as
    the photos do; without it each pixel and channel gets independent noise (an upper bound for
    demosaicked photos).  ``frames`` > 1: the photo is the linear mean of that many frames with
    independent noise (variance divided by ``frames``).

    Parameters
    ----------
    render_signal
        ``(H, W, 3)`` chart-normalised linear camera RGB.
    mask
        ``(H, W)`` bool: the compared pixels (before erosion).
    camera_to_xyz
        ``(3, 3)`` camera RGB -> XYZ.
    noise_ab
        ``(a, b)`` of the noise variance ``a + b * signal`` (signal units).
    white_xyz, edge_margin_px
        As in :func:`compare_images`.
    seed
        Seed of the noise.
    cfa
        ``"RGGB"``, ``"BGGR"``, ``"GRBG"`` or ``"GBRG"``: the noise on that mosaic, then
        demosaicked (H and W even); None: independent noise per pixel and channel.
    frames
        The photo averages this many frames (>= 1).
    pool_px
        Compared at this scale (:func:`compare_images`).

    Returns
    -------
    ImageComparison

    Raises
    ------
    PhotoComparisonError
        A negative or non-finite noise model, an unknown pattern, odd image size with ``cfa``,
        ``frames`` < 1, and the errors of :func:`compare_images`.

    Examples
    --------
    >>> import numpy as np
    >>> from processing.camera.response import camera_sensitivities
    >>> from processing.spectral.spectra import SpectralGrid, light_spectrum
    >>> g = SpectralGrid(400, 700, 10)
    >>> m = camera_to_xyz_matrix(camera_sensitivities(g), light_spectrum("D65", g), g)
    >>> grey = np.full((20, 20, 3), 0.18)
    >>> [round(noise_floor(grey, np.ones((20, 20), bool), m, ab).mean_de2000, 1)
    ...  for ab in ((0.0, 0.0), (1e-8, 1e-6), (1e-5, 1e-4))]         # noiseless, 0.24 % and 2.4 % of the grey
    [0.0, 0.3, 3.3]
    """
    ab = np.asarray(noise_ab, dtype=np.float64).reshape(-1)
    if ab.shape != (2,) or not np.all(np.isfinite(ab)) or np.any(ab < 0):
        raise PhotoComparisonError(f"noise_ab must be two finite values a, b >= 0 (variance a + b * signal), "
                                   f"got {np.asarray(noise_ab).tolist()!r}")
    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 1:
        raise PhotoComparisonError(f"frames: give the number of averaged frames, a whole number >= 1, got {frames!r}")
    rend = _checked_image(render_signal, "render_signal", None).astype(np.float64)
    rng = np.random.default_rng(seed)
    if cfa is None:
        sd = np.sqrt((ab[0] + ab[1] * np.maximum(rend, 0.0)) / frames)
        noisy = rend + sd * rng.standard_normal(rend.shape)
    else:
        rend, noisy = _mosaic_noise(rend, ab, frames, cfa, rng)
    return compare_images(noisy, rend, mask, camera_to_xyz, white_xyz=white_xyz, edge_margin_px=edge_margin_px,
                          pool_px=pool_px)


def _mosaic_noise(rend: NDArray[np.float64], ab: NDArray[np.float64], frames: int, cfa: str,
                  rng: np.random.Generator) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The demosaicked clean and noisy images of ``rend`` seen through a Bayer mosaic ``cfa``."""
    from processing.camera.raw_decode import bilinear_demosaic

    pattern = str(cfa).upper()
    if pattern not in ("RGGB", "BGGR", "GRBG", "GBRG"):
        raise PhotoComparisonError(f"cfa: give a Bayer pattern RGGB, BGGR, GRBG or GBRG, got {cfa!r}")
    h, w = rend.shape[:2]
    if h % 2 or w % 2:
        raise PhotoComparisonError(f"cfa: the image must have an even size to be mosaicked, got {w} x {h}")
    index = np.array(["RGB".index(c) for c in pattern])
    pick = np.empty((h, w), np.int64)
    for k, c in enumerate(index):
        pick[k // 2::2, k % 2::2] = c
    clean = np.take_along_axis(np.nan_to_num(rend), pick[..., None], axis=2)[..., 0]
    sd = np.sqrt((ab[0] + ab[1] * np.maximum(clean, 0.0)) / frames)
    noisy = clean + sd * rng.standard_normal(clean.shape)
    none = np.zeros((h, w), bool)
    return (bilinear_demosaic(clean, index, none, none)[0].astype(np.float64),
            bilinear_demosaic(noisy, index, none, none)[0].astype(np.float64))


def camera_to_xyz_matrix(sensitivities: ArrayLike, light: ArrayLike, grid: Any,
                         chart: str = "ColorChecker N Ohta") -> NDArray[np.float64]:
    """Camera RGB -> XYZ matrix fitted on the ColorChecker under a lamp (both relative to the white diffuser).

    Camera signal of patch ``R``: ``sum R E s_c / sum E s_c``; its XYZ:
    ``XYZ(R E) / Y(E)``; the matrix minimises the squared XYZ error over
    the 24 patches (least squares).

    Parameters
    ----------
    sensitivities
        ``(L, 3)`` camera sensitivities on ``grid``.
    light
        ``(L,)`` lamp spectrum on ``grid``.
    grid
        The :class:`processing.spectral.spectra.SpectralGrid`.
    chart
        The chart in colour-science's ``SDS_COLOURCHECKERS``.

    Returns
    -------
    ndarray
        ``(3, 3)``: ``xyz = M @ rgb``.

    Examples
    --------
    >>> from processing.camera.response import camera_sensitivities
    >>> from processing.spectral.spectra import SpectralGrid, light_spectrum
    >>> g = SpectralGrid(400, 700, 10)
    >>> m = camera_to_xyz_matrix(camera_sensitivities(g), light_spectrum("D65", g), g)
    >>> bool(abs((m @ [1, 1, 1])[1] - 1.0) < 0.05)
    True
    """
    import colour

    from processing.spectral.display import spectra_to_xyz
    from processing.spectral.spectra import resample

    s = np.asarray(sensitivities, dtype=np.float64)
    e = np.asarray(light, dtype=np.float64)
    if s.shape != (grid.size, 3) or e.shape != (grid.size,) or not (np.all(np.isfinite(s)) and np.all(np.isfinite(e))):
        raise PhotoComparisonError(f"camera_to_xyz_matrix: give ({grid.size}, 3) sensitivities and a ({grid.size},) "
                                   "light on the grid, finite")
    white_rgb = e @ s
    if not np.all(white_rgb > 0):
        raise PhotoComparisonError("camera_to_xyz_matrix: the light gives no signal in some camera channel")
    if chart not in colour.SDS_COLOURCHECKERS:
        raise PhotoComparisonError(f"camera_to_xyz_matrix chart {chart!r}: choose one of colour.SDS_COLOURCHECKERS")
    refl = np.stack([resample(sd.wavelengths, sd.values, grid) for sd in colour.SDS_COLOURCHECKERS[chart].values()])
    rgb = (refl * e) @ s / white_rgb
    xyz = spectra_to_xyz(refl * e, grid) / spectra_to_xyz(e, grid)[1]
    return np.linalg.lstsq(rgb, xyz, rcond=None)[0].T
