"""The false colour a 2 x 2 binned Bayer image carries where the brightness changes fast.

A ``bin2x2`` pixel (:func:`processing.camera.raw_decode.bin2x2`) takes its red, green and
blue from different photosites of one 2 x 2 CFA cell: in an ``RGGB`` cell the red photosite
sits a quarter of an output pixel up and left of the cell's centre, the blue one a quarter
down and right, and the two greens average to the centre.  Where the brightness falls by a
factor ``exp(g)`` per output pixel along a direction, a channel sampled at offset ``o`` reads
``exp(g . o)`` times the light at the centre: a relative colour error
``e_c = exp(o_c . grad(ln I)) - 1``, exact where the brightness is locally exponential (Gunturk
et al. 2005, on the colour artefacts of CFA sampling).
On a glossy metal's highlight, a few pixels across, ``|grad ln I|`` reaches 1 per pixel and
more, so red and blue are off by +-25 % in opposite directions: grey shibuichi reads gold.

:func:`cfa_fringe` predicts ``e`` per pixel from the image's own brightness (the channel
sum, so the gradient is not itself the fringe; of the two one-sided differences the steeper, so
a highlight narrower than a pixel is not taken for a flat top), for the material identification to carry as
a colour uncertainty of the region (:func:`processing.materials.identification.identify_material`,
``colour_error``).

References
----------
.. [1] Gunturk, B. K., Glotzbach, J., Altunbasak, Y., Schafer, R. W., Mersereau, R. M. (2005).
   Demosaicking: color filter array interpolation. IEEE Signal Processing Magazine 22(1),
   44-54. doi:10.1109/MSP.2005.1407714

Examples
--------
>>> ramp = np.exp(-0.4 * np.arange(6.0))[:, None, None] * np.ones((6, 4, 3))   # falls downwards
>>> e = cfa_fringe(ramp, "RGGB")
>>> np.round(e[3, 2], 3).tolist()       # red (sampled higher up) reads bright, blue dark, green right
[0.105, 0.0, -0.095]
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.errors import InputError

__all__ = ["cfa_fringe", "transformed_fringe", "channel_offsets", "MAX_FRINGE", "CfaFringeError"]

#: Largest relative colour error one pixel is given (a prediction beyond it means nothing more than "this
#: pixel has no colour": at a silhouette or a pinpoint highlight).
MAX_FRINGE = 3.0
_CHANNELS = {"R": 0, "G": 1, "B": 2}


class CfaFringeError(InputError):
    """A bad image or CFA pattern for :func:`cfa_fringe`; the message names the parameter."""


def channel_offsets(cfa_pattern: str) -> NDArray[np.float64]:
    """Where each channel of a ``bin2x2`` pixel was sampled, relative to the cell's centre.

    Parameters
    ----------
    cfa_pattern
        The 2 x 2 CFA in row order, e.g. ``"RGGB"``.

    Returns
    -------
    ndarray
        ``(3, 2)`` mean (row, column) offset of each channel's photosites, in output pixels.

    Raises
    ------
    CfaFringeError
        Not a 2 x 2 Bayer pattern of R, G, B.

    Examples
    --------
    >>> channel_offsets("RGGB").tolist()
    [[-0.25, -0.25], [0.0, 0.0], [0.25, 0.25]]
    """
    p = str(cfa_pattern).upper()
    if len(p) != 4 or sorted(p) != ["B", "G", "G", "R"]:
        raise CfaFringeError(f"cfa_pattern must be a 2 x 2 Bayer pattern such as 'RGGB', got {cfa_pattern!r}")
    offsets = np.zeros((3, 2))
    counts = np.zeros(3)
    for k, letter in enumerate(p):
        c = _CHANNELS[letter]
        offsets[c] += ((k // 2 - 0.5) / 2.0, (k % 2 - 0.5) / 2.0)
        counts[c] += 1
    return offsets / counts[:, None]


def _steeper_gradient(a: NDArray[np.float64], axis: int) -> NDArray[np.float64]:
    """The steeper of the two one-sided differences along ``axis`` (its sign kept).

    On a smooth slope both equal the central difference; on a highlight narrower than a pixel the
    central difference is near 0 at the peak while the photosites of one cell see very different
    light, and the steeper side says how much.
    """
    d = np.diff(a, axis=axis)
    pad_lo = [(0, 0)] * a.ndim
    pad_hi = [(0, 0)] * a.ndim
    pad_lo[axis], pad_hi[axis] = (1, 0), (0, 1)
    back = np.pad(d, pad_lo, mode="edge")
    fwd = np.pad(d, pad_hi, mode="edge")
    return np.where(np.abs(fwd) >= np.abs(back), fwd, back)


def cfa_fringe(rgb: ArrayLike, cfa_pattern: str = "RGGB", *, floor: float | None = None) -> NDArray[np.float64]:
    """Predicted relative colour error of every pixel of a ``bin2x2`` image (signed, per channel).

    Parameters
    ----------
    rgb
        ``(H, W, 3)`` linear camera values of a ``bin2x2`` decode, >= 0.
    cfa_pattern
        The sensor's 2 x 2 CFA (:attr:`processing.camera.raw_decode.RawImage.cfa_pattern`).
    floor
        Brightness (channel sum) below which a pixel counts as this floor in the logarithm, so
        read noise in the dark does not read as a steep gradient; None: 1 % of the image's 99th
        percentile.

    Returns
    -------
    ndarray
        ``(H, W, 3)`` relative error ``e_c = exp(o_c . grad(ln I)) - 1`` of each channel, at most
        :data:`MAX_FRINGE`; a channel reads ``(1 + e_c)`` times what the cell's centre receives.

    Raises
    ------
    CfaFringeError
        ``rgb`` not ``(H, W, 3)`` (H, W >= 2) or not finite, or a bad ``cfa_pattern`` or ``floor``.

    References
    ----------
    .. [1] Gunturk et al. (2005), doi:10.1109/MSP.2005.1407714.

    Examples
    --------
    >>> flat = np.full((4, 4, 3), 0.3)
    >>> float(np.abs(cfa_fringe(flat)).max())           # no gradient, no false colour
    0.0
    """
    a = np.asarray(rgb, dtype=np.float64)
    if a.ndim != 3 or a.shape[2] != 3 or min(a.shape[:2]) < 2 or not np.all(np.isfinite(a)):
        raise CfaFringeError(f"rgb must be a finite (H, W, 3) image with H, W >= 2, got shape {a.shape}")
    offsets = channel_offsets(cfa_pattern)
    level = np.maximum(a, 0.0).sum(axis=2)
    if floor is None:
        floor = 0.01 * float(np.percentile(level, 99))
    if not (np.isfinite(floor) and floor >= 0):
        raise CfaFringeError(f"floor must be a brightness >= 0, got {floor!r}")
    log_i = np.log(np.maximum(level, max(floor, 1e-12)))
    g_row, g_col = _steeper_gradient(log_i, 0), _steeper_gradient(log_i, 1)
    shift = g_row[..., None] * offsets[:, 0] + g_col[..., None] * offsets[:, 1]
    return np.clip(np.expm1(np.clip(shift, -20.0, 20.0)), -1.0, MAX_FRINGE)


def transformed_fringe(rgb: ArrayLike, cfa_pattern: str, matrix: ArrayLike) -> NDArray[np.float64] | None:
    """:func:`cfa_fringe` of a ``bin2x2`` image carried through a 3 x 3 colour transform.

    The fringe is predicted on the decoded RAW, where each channel is one photosite, carried
    through the transform (row form, ``out = rgb @ matrix``, e.g. the chart transform
    :attr:`processing.camera.transfer.ChartTransform.matrix`) as an absolute error and returned
    relative to the transformed pixel, clipped to +-:data:`MAX_FRINGE`.

    Parameters
    ----------
    rgb
        ``(H, W, 3)`` linear camera values of a ``bin2x2`` decode.
    cfa_pattern
        The sensor's 2 x 2 CFA.
    matrix
        ``(3, 3)`` row-form transform; any other shape (a two-exposure transform): None.

    Returns
    -------
    ndarray or None
        ``(H, W, 3)`` relative colour error in the transformed units.

    Examples
    --------
    >>> ramp = np.exp(-0.4 * np.arange(6.0))[:, None, None] * np.ones((6, 4, 3))
    >>> np.round(transformed_fringe(ramp, "RGGB", 2 * np.eye(3))[3, 2], 3).tolist()   # a scale changes nothing
    [0.105, 0.0, -0.095]
    """
    m = np.asarray(matrix, dtype=np.float64)
    a = np.maximum(np.asarray(rgb, dtype=np.float64), 0.0)
    if m.shape != (3, 3):
        return None
    error = (cfa_fringe(a, cfa_pattern) * a) @ m
    out = a @ m
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(np.abs(out) > 1e-12, error / np.where(np.abs(out) > 1e-12, out, 1.0), 0.0)
    return np.clip(rel, -MAX_FRINGE, MAX_FRINGE)
