"""Exposure brackets of RAW frames merged into one linear high-dynamic-range image.

Each frame is decoded to linear camera RGB (:func:`processing.camera.raw_decode.decode_raw`: black
subtracted, 1.0 = the white level, not white balanced) and divided by its exposure, taken from the
file's own metadata (exposure time ``t``, aperture ``N``, ISO ``S``): a value ``x`` stands for the
radiance ``x * L(N, t, S)`` with ``L = k N^2 / (t S)`` the average scene luminance of an exposure
(colour-hdri's :func:`colour_hdri.average_luminance`, ``k = 12.5``), so frames shot at different
settings land on one scale.  The merge is the weighted mean of the frames (Debevec and Malik 1997)
with

* the weight of a pixel from its largest channel through colour-hdri's
  :func:`colour_hdri.double_sigmoid_anchored_function` (0 below 2.5 % and above 97.5 % of the white
  level, 1 between 20 % and 80 %), so the three channels of a pixel come from the same frames and
  its colour stays consistent;
* times the frame's exposure ``1 / L``: with photon noise the variance of ``x L`` falls as the
  exposure grows, so this is the minimum-variance weighting of Granados et al. (2010) up to the
  read noise;
* zero where a photosite of the pixel reached the white level or is dead (the decoder's masks); a
  small floor elsewhere (1e-4), so a pixel too dark in every frame takes the longest exposure;
* a pixel saturated in every frame keeps the shortest exposure's values, a lower bound, and is
  reported in :attr:`HdrImage.saturated`.

The frames are decoded one at a time (the next one in a second thread while the current one is
summed) and merged in blocks of rows into two float32 sums (weighted values and weights), never
stacked: the memory is the two sums, the shortest frame and two decoded frames.

References
----------
Debevec, P. E., & Malik, J. (1997). Recovering high dynamic range radiance maps from photographs.
Proceedings of SIGGRAPH 97, 369-378. doi:10.1145/258734.258884

Granados, M., Ajdin, B., Wand, M., Theobalt, C., Seidel, H.-P., & Lensch, H. P. A. (2010). Optimal
HDR reconstruction with linear digital cameras. CVPR 2010, 215-222. doi:10.1109/CVPR.2010.5540208

Examples
--------
>>> round(exposure_scale(0.01, 8.0, 100), 3)         # 12.5 * 8^2 / (0.01 * 100)
800.0
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from processing.errors import InputError

__all__ = ["HdrMergeError", "HdrImage", "exposure_scale", "exposure_settings", "frame_weights", "merge_brackets",
           "MAX_SATURATED_FRACTION"]

#: Largest share of pixels saturated in every frame before the merge is refused.
MAX_SATURATED_FRACTION = 0.5
_FLOOR_WEIGHT = 1e-4
_BLOCK_PIXELS = 1 << 18
_TABLE_SIZE = 4096


class HdrMergeError(InputError):
    """Brackets that cannot be merged; the one-line message names the file and what to do."""


@dataclass
class HdrImage:
    """A merged linear HDR image of camera RGB and where it comes from.

    Attributes
    ----------
    rgb
        ``(H, W, 3)`` float32 camera RGB per unit exposure: a frame's value times ``L(N, t, S)``
        (:func:`exposure_scale`); not white balanced; >= 0.
    saturated
        ``(H, W)`` bool: saturated in every frame (``rgb`` is a lower bound there).
    frames
        The files merged, in the order given.
    exposures
        ``L(N, t, S)`` of each frame.
    settings
        ``(exposure_time_s, f_number, iso)`` of each frame.
    mode
        The decoder's resolution setting.
    notes
        Anything the caller should say (frames that added nothing, ...).
    """

    rgb: NDArray[np.float32] = field(repr=False)
    saturated: NDArray[np.bool_] = field(repr=False)
    frames: tuple[Path, ...]
    exposures: tuple[float, ...]
    settings: tuple[tuple[float, float, float], ...]
    mode: str
    notes: list[str] = field(default_factory=list)

    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)``."""
        return self.rgb.shape[0], self.rgb.shape[1]


def exposure_scale(exposure_time_s: float, f_number: float, iso: float) -> float:
    """Scene luminance per unit of a frame's normalised value: ``k N^2 / (t S)``, ``k = 12.5``.

    Parameters
    ----------
    exposure_time_s
        Exposure time ``t`` (s, > 0).
    f_number
        Aperture ``N`` (> 0).
    iso
        ISO speed ``S`` (> 0).

    Returns
    -------
    float
        colour-hdri's :func:`colour_hdri.average_luminance` of the settings.

    Examples
    --------
    >>> exposure_scale(1 / 60, 4.0, 400) / exposure_scale(1 / 30, 4.0, 400)    # half the time: twice the scale
    2.0
    """
    from colour_hdri import average_luminance

    return float(average_luminance(float(f_number), float(exposure_time_s), float(iso)))


@functools.lru_cache(maxsize=1)
def _weight_table() -> NDArray[np.float32]:
    """colour-hdri's double sigmoid plus the floor, tabulated at 4096 steps over [0, 1]."""
    from colour_hdri import double_sigmoid_anchored_function

    with np.errstate(divide="ignore"):         # its sigmoid divides by zero exactly at the anchors (limit 0)
        w = double_sigmoid_anchored_function(np.linspace(0.0, 1.0, _TABLE_SIZE))
    table = (np.nan_to_num(w, nan=0.0) + _FLOOR_WEIGHT).astype(np.float32)
    table.setflags(write=False)
    return table


def frame_weights(peak: NDArray[np.floating], usable: NDArray[np.bool_], exposure: float) -> NDArray[np.float32]:
    """Merge weights of one frame's pixels from their largest channel.

    colour-hdri's :func:`colour_hdri.double_sigmoid_anchored_function` is tabulated once at 4096
    steps over [0, 1] (its largest step is below 0.1 % of the weight's range) and looked up.

    Parameters
    ----------
    peak
        ``(...)`` largest channel of each pixel (1.0 = white level).
    usable
        ``(...)`` False where a photosite of the pixel is saturated or dead.
    exposure
        The frame's ``L(N, t, S)``; the weight falls as ``1 / L`` (photon-noise optimal).

    Returns
    -------
    ndarray
        ``(...)`` float32 weights, 0 where not usable.

    Examples
    --------
    >>> [round(float(w), 4) for w in frame_weights(np.array([0.01, 0.5, 0.99]), np.ones(3, bool), 1.0)]
    [0.0001, 1.0001, 0.0001]
    """
    p = np.clip(np.asarray(peak, dtype=np.float32), 0.0, 1.0)
    idx = (p * np.float32(_TABLE_SIZE - 1) + np.float32(0.5)).astype(np.intp)
    w = _weight_table()[idx]
    w *= np.asarray(usable, dtype=np.float32) * np.float32(1.0 / exposure)
    return w


def exposure_settings(img, f_number: float | None = None) -> tuple[float, float, float]:
    """``(t, N, S)`` of a decoded frame, or a one-line error naming the file and the missing value.

    Parameters
    ----------
    img
        A decoded frame (:class:`processing.camera.raw_decode.RawImage`).
    f_number
        The aperture to use when the file records none.

    Returns
    -------
    tuple
        Exposure time (s), aperture, ISO.

    Raises
    ------
    HdrMergeError
        The file records no exposure time, aperture (and none given) or ISO.
    """
    t, n, s = float(img.exposure_time), float(img.f_number), float(img.iso)
    if not n > 0 and f_number is not None:
        n = float(f_number)
    missing = [name for name, v in (("exposure time", t), ("aperture (FNumber)", n), ("ISO", s))
               if not (np.isfinite(v) and v > 0)]
    if missing:
        hint = " or give the aperture with --f-number" if missing == ["aperture (FNumber)"] else ""
        raise HdrMergeError(f"{img.path}: the file records no {' and no '.join(missing)}, so its exposure is unknown; "
                            f"shoot the brackets with a camera that writes them{hint}")
    return t, n, s


def _check_f_number(f_number: float | None) -> None:
    if f_number is not None and not (isinstance(f_number, (int, float)) and np.isfinite(f_number) and f_number > 0):
        raise HdrMergeError(f"f_number must be the lens aperture (> 0), got {f_number!r}")


def _accumulate(img, exposure: float, num: NDArray[np.float32], den: NDArray[np.float32]) -> int:
    """Add one frame's weighted values and weights to the sums, in blocks of rows; returns its useful pixels."""
    h, w = img.shape
    rows = max(1, _BLOCK_PIXELS // w)
    useful = 0
    for r0 in range(0, h, rows):
        sl = slice(r0, min(h, r0 + rows))
        rgb = img.rgb[sl]
        usable = ~(img.saturated[sl] | img.dead[sl])
        peak = np.maximum(np.maximum(rgb[..., 0], rgb[..., 1]), rgb[..., 2])     # faster than max(axis=2)
        wt = frame_weights(peak, usable, exposure)
        useful += int(np.count_nonzero(wt > _FLOOR_WEIGHT / exposure * 1.5))
        num[sl] += rgb * (wt * np.float32(exposure))[..., None]
        den[sl] += wt
    return useful


def merge_brackets(paths: Sequence[str | os.PathLike[str]], *, mode: str = "demosaic", f_number: float | None = None,
                   max_saturated_fraction: float = MAX_SATURATED_FRACTION,
                   decode: Callable | None = None, prefetch: bool = True) -> HdrImage:
    """Merge exposure brackets of one view into a linear HDR image (see the module's description).

    Parameters
    ----------
    paths
        The RAW frames (one or more, any order), all of the same size.
    mode
        ``"demosaic"`` (full resolution) or ``"bin2x2"`` (a quarter of the pixels, a quarter of the memory).
    f_number
        The aperture of frames whose files do not record it (a manual lens); None: required in the files.
    max_saturated_fraction
        Refuse when more than this share of the pixels is saturated in every frame.
    decode
        The decoder (default :func:`processing.camera.raw_decode.decode_raw`), ``decode(path, mode=mode)``.
    prefetch
        Decode the next frame in a second thread while the current one is summed (two frames in memory).

    Returns
    -------
    HdrImage

    Raises
    ------
    HdrMergeError
        No frames, a frame without exposure time / aperture / ISO, frames of different sizes, brackets
        saturated almost everywhere.
    RawDecodeError
        A file that is not a readable RAW frame.
    """
    if decode is None:
        from processing.camera.raw_decode import decode_raw as decode
    _check_f_number(f_number)
    files = [Path(p) for p in paths]
    if not files:
        raise HdrMergeError("no bracket frames given; give the RAW files of one view at several exposures")
    num = den = None
    exposures, settings, notes = [], [], []
    shortest: tuple[float, NDArray[np.float32] | None] = (np.inf, None)
    all_saturated = None
    pool = ThreadPoolExecutor(max_workers=1) if prefetch and len(files) > 1 else None
    pending = pool.submit(decode, files[0], mode=mode) if pool is not None else None
    try:
        for i, p in enumerate(files):
            img = pending.result() if pending is not None else decode(p, mode=mode)
            if pool is not None:            # the next frame decodes while this one is summed
                pending = pool.submit(decode, files[i + 1], mode=mode) if i + 1 < len(files) else None
            shortest, all_saturated, num, den = _add_frame(img, p, files[0], f_number, num, den, all_saturated,
                                                           shortest, exposures, settings, notes)
            del img
    finally:
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)
    frac = float(all_saturated.mean())
    if frac > max_saturated_fraction:
        short = files[int(np.argmax(exposures))]
        raise HdrMergeError(f"{short}: {100 * frac:.0f} % of the pixels are saturated in every bracket (even this "
                            "shortest exposure); add shorter exposures or stop the lens down")
    out = _finish(num, den, shortest)
    return HdrImage(out, all_saturated, tuple(files), tuple(exposures), tuple(settings), mode, notes)


def _add_frame(img, p: Path, first: Path, f_number: float | None, num, den, all_saturated, shortest,
               exposures: list, settings: list, notes: list):
    """Sum one decoded frame into the merge; returns the updated shortest frame, masks and sums."""
    t, n, s = exposure_settings(img, f_number)
    scale = exposure_scale(t, n, s)
    if num is None:
        num = np.zeros(img.rgb.shape, np.float32)
        den = np.zeros(img.shape, np.float32)
        all_saturated = img.saturated.copy()
    elif img.shape != num.shape[:2]:
        raise HdrMergeError(f"{p}: {img.shape[1]} x {img.shape[0]} pixels, but {first} has "
                            f"{num.shape[1]} x {num.shape[0]}; merge frames of one view and one decode mode")
    else:
        all_saturated &= img.saturated
    if _accumulate(img, scale, num, den) == 0:
        notes.append(f"{p.name}: no pixel well exposed (t = {t:g} s)")
    if scale > shortest[0] or shortest[1] is None:        # the largest L is the shortest exposure
        shortest = (scale, img.rgb if shortest[1] is None else _copy_into(shortest[1], img.rgb))
    exposures.append(scale)
    settings.append((t, n, s))
    return shortest, all_saturated, num, den


def _copy_into(buffer: NDArray[np.float32], rgb: NDArray[np.float32]) -> NDArray[np.float32]:
    buffer[...] = rgb
    return buffer


def _finish(num: NDArray[np.float32], den: NDArray[np.float32],
            shortest: tuple[float, NDArray[np.float32] | None]) -> NDArray[np.float32]:
    """``num / den`` in place (clipped at 0); pixels without weight take the shortest exposure's values."""
    scale, short = shortest
    h, w = den.shape
    rows = max(1, _BLOCK_PIXELS // w)
    for r0 in range(0, h, rows):
        sl = slice(r0, min(h, r0 + rows))
        d = den[sl]
        empty = d <= 0
        block = num[sl]
        block /= np.where(empty, 1.0, d)[..., None]
        if empty.any():
            block[empty] = short[sl][empty] * np.float32(scale)
        np.maximum(block, 0.0, out=block)
    return num
