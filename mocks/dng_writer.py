"""Write a Bayer mosaic as an uncompressed DNG 1.4 file that LibRaw reads.

Adobe Digital Negative Specification 1.4.0.0 (2012): a single-IFD DNG whose
main image is the raw CFA mosaic (``NewSubFileType = 0``,
``PhotometricInterpretation = 32803`` "CFA") with the tags a raw decoder
needs to interpret it:

=====================  =====  ============================================
tag                    code   value written
=====================  =====  ============================================
NewSubFileType         254    0 (full-resolution main image)
CFARepeatPatternDim    33421  (2, 2)
CFAPattern             33422  colour index per cell (0 R, 1 G, 2 B)
CFAPlaneColor          50710  (0, 1, 2)
CFALayout              50711  1 (rectangular)
DNGVersion             50706  (1, 4, 0, 0)
DNGBackwardVersion     50707  (1, 1, 0, 0)
UniqueCameraModel      50708  ``"<make> <model>"``
BlackLevelRepeatDim    50713  (2, 2)
BlackLevel             50714  one level per CFA cell (DN)
WhiteLevel             50717  saturation level (DN)
ColorMatrix1           50721  XYZ -> camera, 3 x 3 SRATIONAL
CalibrationIlluminant1 50778  EXIF LightSource code (21 = D65)
AsShotNeutral          50728  camera RGB of the scene white
ExposureTime           33434  seconds (RATIONAL)
ISOSpeedRatings        34855  ISO
=====================  =====  ============================================

The file is written with :mod:`tifffile` (``extratags``) to a temporary file
in the destination's folder, flushed, ``fsync``-ed and renamed over the
destination (:func:`processing.common.files.atomic_path`), so a reader never
sees a partial DNG.
"""

from __future__ import annotations

import io
import os
from collections.abc import Sequence
from fractions import Fraction
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.common.files import atomic_path
from processing.errors import InputError

__all__ = [
    "CFA_COLOURS",
    "LIGHT_SOURCES",
    "MIN_SIDE",
    "DngWriteError",
    "dng_bytes",
    "write_dng",
]

#: Colour index of each letter in a CFA pattern string (DNG CFAPlaneColor 0, 1, 2).
CFA_COLOURS: dict[str, int] = {"R": 0, "G": 1, "B": 2}

#: EXIF LightSource codes accepted for ``calibration_illuminant``.
LIGHT_SOURCES: dict[str, int] = {"A": 17, "B": 18, "C": 19, "D55": 20, "D65": 21, "D75": 22, "D50": 23}

#: Smallest height and width LibRaw accepts for a raw image (pixels).
MIN_SIDE = 22

_DEFAULT_MATRIX = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


class DngWriteError(InputError):
    """A parameter of :func:`write_dng` is not valid; the message names it."""


def _rational(value: float, what: str, *, signed: bool) -> tuple[int, int]:
    v = float(value)
    if not np.isfinite(v):
        raise DngWriteError(f"{what} must be finite, got {value!r}")
    if not signed and v < 0:
        raise DngWriteError(f"{what} must be >= 0, got {value!r}")
    f = Fraction(v).limit_denominator(1_000_000)
    limit = 2**31 - 1 if signed else 2**32 - 1
    num, den = f.numerator, f.denominator
    while abs(num) > limit or den > limit:
        num, den = num // 2, max(den // 2, 1)
    return num, den


def _cfa(pattern: str) -> tuple[int, int, int, int]:
    if not isinstance(pattern, str) or len(pattern) != 4 or any(c not in CFA_COLOURS for c in pattern.upper()):
        raise DngWriteError(
            f"cfa_pattern must be four letters of R, G, B for the 2 x 2 cell in row order "
            f"(e.g. 'RGGB', 'BGGR'), got {pattern!r}"
        )
    p = pattern.upper()
    if sorted(set(p)) != ["B", "G", "R"]:
        raise DngWriteError(f"cfa_pattern {pattern!r} must contain R, G and B")
    return tuple(CFA_COLOURS[c] for c in p)  # type: ignore[return-value]


def _levels(black_level: float | Sequence[float], white_level: int) -> tuple[list[int], int]:
    black = np.atleast_1d(np.asarray(black_level, dtype=np.float64))
    if black.size == 1:
        black = np.repeat(black, 4)
    if black.shape != (4,) or not np.all(np.isfinite(black)) or np.any(black < 0):
        raise DngWriteError(
            f"black_level must be one level >= 0 or four (one per CFA cell, row order), got {black_level!r}"
        )
    if black.astype(np.int64).astype(np.float64).tolist() != black.tolist():
        raise DngWriteError(f"black_level must be whole numbers of DN, got {black_level!r}")
    if isinstance(white_level, bool) or not float(white_level).is_integer():
        raise DngWriteError(f"white_level must be a whole number of DN, got {white_level!r}")
    white = int(white_level)
    if not 0 < white <= 65535 or white <= black.max():
        raise DngWriteError(
            f"white_level must be in (max black level, 65535], got {white_level!r} with black {black.tolist()}"
        )
    return [int(b) for b in black], white


def _extratags(
    cfa: tuple[int, ...],
    black: list[int],
    white: int,
    color_matrix: NDArray[np.float64],
    illuminant: int,
    neutral: NDArray[np.float64],
    exposure_time: float | None,
    iso: int,
    make: str,
    model: str,
    f_number: float | None = None,
) -> list[tuple]:
    cm = [x for v in color_matrix.ravel() for x in _rational(v, "color_matrix entry", signed=True)]
    asn = [x for v in neutral for x in _rational(v, "as_shot_neutral entry", signed=False)]
    unique = f"{make} {model}".strip()
    # (code, dtype, count, value, writeonce); dtypes: 1 BYTE, 2 ASCII, 3 SHORT, 4 LONG, 5 RATIONAL, 10 SRATIONAL
    return [
        (33421, 3, 2, (2, 2), True),
        (33422, 1, 4, cfa, True),
        (50710, 1, 3, (0, 1, 2), True),
        (50711, 3, 1, 1, True),
        (50706, 1, 4, (1, 4, 0, 0), True),
        (50707, 1, 4, (1, 1, 0, 0), True),
        (50708, 2, 0, unique, True),
        (50713, 3, 2, (2, 2), True),
        (50714, 4, 4, tuple(black), True),
        (50717, 4, 1, white, True),
        (50721, 10, 9, tuple(cm), True),
        (50778, 3, 1, illuminant, True),
        (50728, 5, 3, tuple(asn), True),
        (34855, 3, 1, iso, True),
    ] + ([] if exposure_time is None else
         [(33434, 5, 1, _rational(exposure_time, "exposure_time", signed=False), True)]) \
      + ([] if f_number is None else [(33437, 5, 1, _rational(f_number, "f_number", signed=False), True)])


def dng_bytes(
    bayer_uint16: ArrayLike,
    *,
    black_level: float | Sequence[float],
    white_level: int,
    cfa_pattern: str = "RGGB",
    color_matrix: ArrayLike = _DEFAULT_MATRIX,
    calibration_illuminant: str = "D65",
    as_shot_neutral: ArrayLike = (1.0, 1.0, 1.0),
    exposure_time: float | None = 0.01,
    iso: int = 100,
    make: str = "Kogei",
    model: str = "Simulated",
    f_number: float | None = None,
) -> bytes:
    """The DNG file of a Bayer mosaic as bytes (see :func:`write_dng`).

    Examples
    --------
    >>> data = dng_bytes(np.zeros((24, 32), np.uint16), black_level=0, white_level=4095)
    >>> data[:4] in (b"II*\\x00", b"MM\\x00*")
    True
    """
    import tifffile

    bayer = np.asarray(bayer_uint16)
    if bayer.ndim != 2 or min(bayer.shape) < MIN_SIDE or bayer.shape[0] % 2 or bayer.shape[1] % 2:
        raise DngWriteError(
            f"bayer_uint16 must be a 2-D mosaic with even height and width >= {MIN_SIDE} "
            f"(LibRaw rejects smaller raw images), got shape {bayer.shape}"
        )
    if bayer.dtype != np.uint16:
        raise DngWriteError(
            f"bayer_uint16 must have dtype uint16 (raw DN), got {bayer.dtype}; convert with .astype(np.uint16) "
            "after clipping to [0, white_level]"
        )
    cfa = _cfa(cfa_pattern)
    black, white = _levels(black_level, white_level)
    if int(bayer.max(initial=0)) > white:
        raise DngWriteError(
            f"bayer_uint16 has values up to {int(bayer.max())} above white_level {white}; clip the mosaic first"
        )
    cm = np.asarray(color_matrix, dtype=np.float64)
    if cm.shape != (3, 3) or not np.all(np.isfinite(cm)):
        raise DngWriteError(f"color_matrix must be a finite 3 x 3 XYZ -> camera matrix, got shape {cm.shape}")
    if calibration_illuminant not in LIGHT_SOURCES:
        raise DngWriteError(
            f"calibration_illuminant must be one of {', '.join(LIGHT_SOURCES)}, got {calibration_illuminant!r}"
        )
    neutral = np.asarray(as_shot_neutral, dtype=np.float64)
    if neutral.shape != (3,) or not np.all(np.isfinite(neutral)) or np.any(neutral <= 0):
        raise DngWriteError(f"as_shot_neutral must be three camera-RGB values > 0, got {as_shot_neutral!r}")
    if exposure_time is not None and not (np.isfinite(float(exposure_time)) and float(exposure_time) > 0):
        raise DngWriteError(f"exposure_time must be > 0 seconds (or None: not recorded), got {exposure_time!r}")
    if f_number is not None and not (np.isfinite(float(f_number)) and float(f_number) > 0):
        raise DngWriteError(f"f_number must be > 0 (or None: not recorded), got {f_number!r}")
    if isinstance(iso, bool) or not float(iso).is_integer() or not 0 < int(iso) <= 65535:
        raise DngWriteError(f"iso must be a whole number in 1..65535, got {iso!r}")
    for what, text in (("make", make), ("model", model)):
        if not isinstance(text, str) or not text.isascii() or "\x00" in text:
            raise DngWriteError(f"{what} must be an ASCII string, got {text!r}")
    tags = _extratags(cfa, black, white, cm, LIGHT_SOURCES[calibration_illuminant], neutral,
                      None if exposure_time is None else float(exposure_time), int(iso), make, model,
                      None if f_number is None else float(f_number))
    buffer = io.BytesIO()
    with tifffile.TiffWriter(buffer, bigtiff=False) as tif:
        tif.write(
            np.ascontiguousarray(bayer),
            photometric=32803,
            compression=None,
            planarconfig=None,
            subfiletype=0,
            metadata=None,
            software=False,
            extratags=[(271, 2, 0, make, True), (272, 2, 0, model, True)] + tags,
        )
    return buffer.getvalue()


def write_dng(
    path: str | os.PathLike[str],
    bayer_uint16: ArrayLike,
    *,
    black_level: float | Sequence[float],
    white_level: int,
    cfa_pattern: str = "RGGB",
    color_matrix: ArrayLike = _DEFAULT_MATRIX,
    calibration_illuminant: str = "D65",
    as_shot_neutral: ArrayLike = (1.0, 1.0, 1.0),
    exposure_time: float | None = 0.01,
    iso: int = 100,
    make: str = "Kogei",
    model: str = "Simulated",
    f_number: float | None = None,
) -> Path:
    """Write an uncompressed DNG 1.4 of a Bayer mosaic, atomically.

    Parameters
    ----------
    path
        Destination ``.dng`` file; its folder must exist.  An existing file
        is replaced atomically.
    bayer_uint16
        ``(H, W)`` uint16 raw values in DN, H and W even and at least
        :data:`MIN_SIDE`.
    black_level
        One level or four (per cell of the 2 x 2 CFA, row order), DN.
    white_level
        Saturation level in DN (e.g. 4095 for 12 bits, 16383 for 14 bits).
    cfa_pattern
        The 2 x 2 colour filter cell in row order, e.g. ``"RGGB"``.
    color_matrix
        ColorMatrix1: 3 x 3 matrix from CIE XYZ to camera RGB under
        ``calibration_illuminant`` (DNG convention).
    calibration_illuminant
        Name of the illuminant of ``color_matrix`` (``"D65"``, ``"A"``, ...).
    as_shot_neutral
        Camera RGB of the scene white, normalised as the caller likes.
    exposure_time
        Seconds (None: the file records no exposure time, as some tethering tools write).
    iso
        ISO speed.
    make, model
        Camera make and model (UniqueCameraModel is ``"make model"``).
    f_number
        The lens aperture (EXIF FNumber); None: not recorded.

    Returns
    -------
    Path
        The path written.

    Raises
    ------
    DngWriteError
        A parameter is not valid (the message names it and the valid range).
    FileNotFoundError
        The destination folder does not exist.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> p = write_dng(d / "a.dng", np.full((24, 24), 64, np.uint16), black_level=64, white_level=4095)
    >>> p.name, p.stat().st_size > 0
    ('a.dng', True)
    """
    data = dng_bytes(
        bayer_uint16,
        black_level=black_level,
        white_level=white_level,
        cfa_pattern=cfa_pattern,
        color_matrix=color_matrix,
        calibration_illuminant=calibration_illuminant,
        as_shot_neutral=as_shot_neutral,
        exposure_time=exposure_time,
        iso=iso,
        make=make,
        model=model,
        f_number=f_number,
    )
    target = Path(path)
    if not target.parent.is_dir():
        raise FileNotFoundError(f"write_dng: the folder {target.parent} does not exist; create it first")
    with atomic_path(target, make_parents=False) as tmp:
        os.chmod(tmp, 0o644)
        tmp.write_bytes(data)
    return target
