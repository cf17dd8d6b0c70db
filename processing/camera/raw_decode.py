"""RAW decoding: linear, un-white-balanced camera RGB from a Bayer RAW file (DNG/CR2/NEF/ARW).

LibRaw (through ``rawpy``) parses the file and unpacks the mosaic; the black
level per CFA cell, the file's own white level, the saturated and dead
photosite masks, 2 x 2 binning or bilinear demosaicking are done here, so
that every number is traceable to the file's metadata.  :func:`preview_srgb8`
makes a white-balanced sRGB preview for chart detection and display.
docs/colour-pipeline.md, "Decoding", describes each choice.

References
----------
Gunturk, B. K., Glotzbach, J., Altunbasak, Y., Schafer, R. W., Mersereau,
R. M. (2005). Demosaicking: color filter array interpolation. IEEE Signal
Processing Magazine 22(1), 44-54. doi:10.1109/MSP.2005.1407714

Adobe Systems (2012). Digital Negative (DNG) Specification, version 1.4.0.0,
chapter 6 (no DOI).

IEC 61966-2-1:1999, Multimedia systems and equipment -- Colour measurement
and management -- Default RGB colour space -- sRGB (no DOI).
"""

from __future__ import annotations

import functools
import os
import sys
import tempfile
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from processing.errors import InputError
from processing.spectral.display import encode_srgb8

__all__ = [
    "DECODE_MODES",
    "RawDecodeError",
    "RawImage",
    "decode_raw",
    "bin2x2",
    "bilinear_demosaic",
    "preview_srgb8",
    "sniff_format",
]

#: Resolution settings of :func:`decode_raw`.
DECODE_MODES = ("bin2x2", "demosaic")

#: A photosite reading 0 DN is dead only when the black level is above this (DN).
_DEAD_BLACK_MIN = 16

_RAW_HINT = "give the camera's DNG/CR2/NEF/ARW"

#: Held while file descriptor 2 is redirected: one decode at a time swaps it (the GUI decodes in worker threads).
_STDERR_LOCK = threading.Lock()


class RawDecodeError(InputError):
    """A RAW file cannot be decoded; the message names the file and what to do."""


@dataclass
class RawImage:
    """Linear camera RGB of one RAW frame and its metadata.

    Parameters
    ----------
    rgb, saturated, dead, black_levels, white_level, cfa_pattern, exposure_time, iso, f_number
        The attributes below, in this order,
    make, model, path, mode, scale, as_shot_neutral, xyz_to_camera
        followed by these.

    Attributes
    ----------
    rgb
        float32 ``(H, W, 3)`` camera R, G, B, black subtracted and divided by
        ``white - black`` (1.0 = saturation); not white balanced.
    saturated
        bool ``(H, W)``: a photosite contributing to the pixel reached the
        white level.
    dead
        bool ``(H, W)``: a contributing photosite is dead (reads 0 DN).
    black_levels
        Black level of each cell of the 2 x 2 CFA in row order (DN).
    white_level
        Saturation level (DN).
    cfa_pattern
        The 2 x 2 CFA cell in row order, e.g. ``"RGGB"``.
    exposure_time
        Seconds (0 if the file does not say).
    iso
        ISO speed (0 if the file does not say).
    f_number
        Aperture (0 if the file does not say).
    make, model
        Camera identification.
    path
        The file decoded.
    mode
        ``"bin2x2"`` or ``"demosaic"``.
    scale
        Photosites per output pixel along each axis (2 for ``bin2x2``).
        Output pixel ``(x, y)`` is centred on sensor coordinate
        ``scale * (x, y) + (scale - 1) / 2`` (pixel centres at integers).
    as_shot_neutral
        Camera RGB of the scene white (max 1), or None if absent.
    xyz_to_camera
        ``(3, 3)`` XYZ -> camera matrix (DNG ColorMatrix), or None if absent.
    """

    rgb: NDArray[np.float32] = field(repr=False)
    saturated: NDArray[np.bool_] = field(repr=False)
    dead: NDArray[np.bool_] = field(repr=False)
    black_levels: tuple[float, float, float, float]
    white_level: float
    cfa_pattern: str
    exposure_time: float
    iso: float
    f_number: float
    make: str
    model: str
    path: Path
    mode: str
    scale: int
    as_shot_neutral: NDArray[np.float64] | None = None
    xyz_to_camera: NDArray[np.float64] | None = field(default=None, repr=False)

    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)`` of the decoded image."""
        return self.rgb.shape[0], self.rgb.shape[1]

    def to_sensor(self, xy: NDArray[np.float64]) -> NDArray[np.float64]:
        """Image coordinates ``(..., 2)`` (x, y) -> full-resolution sensor coordinates.

        Parameters
        ----------
        xy
            ``(..., 2)`` pixel coordinates of this image (pixel centres at integers).

        Returns
        -------
        ndarray
            ``(..., 2)`` float64 sensor photosite coordinates.

        Examples
        --------
        >>> img = RawImage(np.zeros((2, 2, 3), np.float32), np.zeros((2, 2), bool), np.zeros((2, 2), bool),
        ...                (0, 0, 0, 0), 1.0, "RGGB", 0.01, 100, 0, "", "", Path("x"), "bin2x2", 2)
        >>> img.to_sensor(np.array([1.0, 0.0])).tolist()
        [2.5, 0.5]
        """
        return np.asarray(xy, dtype=np.float64) * self.scale + (self.scale - 1) / 2.0

    def from_sensor(self, xy: NDArray[np.float64]) -> NDArray[np.float64]:
        """Full-resolution sensor coordinates ``(..., 2)`` -> this image's coordinates.

        Parameters
        ----------
        xy
            ``(..., 2)`` sensor photosite coordinates (centres at integers).

        Returns
        -------
        ndarray
            ``(..., 2)`` float64 pixel coordinates of this image.
        """
        return (np.asarray(xy, dtype=np.float64) - (self.scale - 1) / 2.0) / self.scale


# ---------------------------------------------------------------------------------------------- file checks

_MAGIC: tuple[tuple[bytes, int, str], ...] = (
    (b"\xff\xd8\xff", 0, "JPEG"),
    (b"\x89PNG\r\n\x1a\n", 0, "PNG"),
    (b"GIF8", 0, "GIF"),
    (b"%PDF", 0, "PDF"),
    (b"PK\x03\x04", 0, "ZIP"),
    (b"8BPS", 0, "Photoshop"),
)


def sniff_format(head: bytes) -> str:
    r"""Name the container of a file from its first bytes.

    Parameters
    ----------
    head
        The file's first bytes (16 are enough).

    Returns
    -------
    str
        One of ``"JPEG"``, ``"PNG"``, ``"GIF"``, ``"PDF"``, ``"ZIP"``,
        ``"Photoshop"``, ``"WebP"``, ``"HEIF"``, ``"TIFF"`` (also DNG, NEF,
        ARW, CR2), ``"ISOBMFF"`` (e.g. CR3) or ``"unknown"`` (e.g. RAF, ORF,
        RW2).

    Examples
    --------
    >>> sniff_format(b"\xff\xd8\xff\xe0\x00\x10JFIF"), sniff_format(b"II*\x00\x08\x00\x00\x00")
    ('JPEG', 'TIFF')
    """
    for magic, offset, name in _MAGIC:
        if head[offset:offset + len(magic)] == magic:
            return name
    if head[:4] == b"RIFF" and head[8:12] == b"WEBP":
        return "WebP"
    if head[4:8] == b"ftyp":
        brand = head[8:12]
        if brand in (b"heic", b"heix", b"hevc", b"mif1", b"msf1", b"avif"):
            return "HEIF"
        return "ISOBMFF"
    if head[:4] in (b"II*\x00", b"MM\x00*"):
        return "TIFF"
    return "unknown"


@contextmanager
def _c_stderr_caught() -> Iterator[list[str]]:
    """File descriptor 2 sent to a temporary file while the block runs; the list gets what was written there.

    LibRaw reports a truncated file by printing ``"FILE: Unexpected end of file"`` from C to fd 2 before
    it raises, a line that would precede kogei's own one-line error.  Redirecting ``sys.stderr`` cannot
    catch C output, so the descriptor itself is swapped (under a lock) and restored when the block ends.
    If fd 2 cannot be duplicated (it is closed), nothing is redirected.
    """
    caught: list[str] = []
    with _STDERR_LOCK, tempfile.TemporaryFile() as sink:
        try:
            sys.stderr.flush()
            saved = os.dup(2)
        except (OSError, ValueError, AttributeError):
            yield caught
            return
        os.dup2(sink.fileno(), 2)
        try:
            yield caught
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            caught.append(sink.read().decode("utf-8", "replace"))


def _libraw_said(caught: list[str], path: Path) -> str:
    """What LibRaw printed, on one line without the file name it starts with (``""`` if nothing)."""
    text = " ".join(line.strip() for line in "".join(caught).splitlines() if line.strip())
    return text.replace(f"{os.fspath(path)}: ", "")


def _read_libraw(rawpy, path: Path):
    """``rawpy.imread`` and the unpack with LibRaw's C messages held back: the file or the error, and the messages."""
    with _c_stderr_caught() as caught:
        try:
            raw = rawpy.imread(os.fspath(path))
            _ = raw.raw_image_visible  # forces the unpack, where truncated data shows
            error = None
        except rawpy.LibRawError as exc:
            raw, error = None, exc
    said = _libraw_said(caught, path)
    if error is None and said:
        print("".join(caught), end="", file=sys.stderr)     # a valid file's messages, as before
    return raw, error, said


def _open(path: Path):
    """The file opened and unpacked by LibRaw, or a :class:`RawDecodeError` that says what the file is."""
    import rawpy

    if not path.exists():
        raise RawDecodeError(f"{path}: no such file; check the path ({_RAW_HINT})")
    if path.is_dir():
        raise RawDecodeError(f"{path}: is a folder, not a RAW file; {_RAW_HINT}")
    try:
        with open(path, "rb") as fh:
            head = fh.read(16)
    except OSError as exc:
        raise RawDecodeError(f"{path}: cannot be read ({exc.strerror}); check its permissions") from None
    if not head:
        raise RawDecodeError(f"{path}: the file is empty (an interrupted download?); {_RAW_HINT}")
    kind = sniff_format(head)
    if kind not in ("TIFF", "ISOBMFF", "unknown"):
        raise RawDecodeError(f"{path}: this is a {kind}, not a RAW file; {_RAW_HINT}")
    raw, error, said = _read_libraw(rawpy, path)
    try:
        if error is not None:
            raise error
    except rawpy.LibRawFileUnsupportedError:
        if kind == "TIFF":
            raise RawDecodeError(f"{path}: this is a TIFF image, not a RAW file; {_RAW_HINT}") from None
        raise RawDecodeError(f"{path}: not a RAW format LibRaw knows (corrupt or not a RAW file); {_RAW_HINT}") \
            from None
    except (rawpy.LibRawIOError, rawpy.LibRawDataError, rawpy.LibRawTooBigError) as exc:
        detail = f"{type(exc).__name__}: {said}" if said else type(exc).__name__
        raise RawDecodeError(
            f"{path}: the RAW data is corrupt or truncated ({detail}); copy the file from the camera again"
        ) from None
    except rawpy.LibRawError as exc:
        raise RawDecodeError(f"{path}: LibRaw cannot decode it ({type(exc).__name__}: {exc}); {_RAW_HINT}") \
            from None
    return raw


def _cfa_string(raw, path: Path) -> tuple[str, NDArray[np.int64]]:
    """The 2 x 2 CFA as letters and LibRaw's colour index of each cell (0 R, 1 G, 2 B, 3 second G)."""
    import rawpy

    desc = raw.color_desc.decode("ascii", "replace")
    pattern = np.asarray(raw.raw_pattern) if raw.raw_pattern is not None else None
    ok = (
        raw.raw_type == rawpy.RawType.Flat
        and raw.num_colors == 3
        and pattern is not None
        and pattern.shape == (2, 2)
        and desc[:3] == "RGB"
    )
    if ok:
        # the visible area's own first cell: a sensor margin of odd width shifts the pattern
        pattern = np.asarray(raw.raw_colors_visible[:2, :2])
        letters = "".join(desc[int(c)] for c in pattern.ravel())
        ok = sorted(letters) == ["B", "G", "G", "R"]
    if not ok:
        shape = None if pattern is None else pattern.shape
        raise RawDecodeError(
            f"{path}: the sensor is not a 2 x 2 RGB Bayer mosaic (raw type {raw.raw_type.name}, colours "
            f"{desc!r}, pattern {shape}); X-Trans, Foveon and linear (demosaiced) DNGs are not supported — "
            "shoot with a Bayer-sensor camera"
        )
    return letters, pattern.ravel().astype(np.int64)


def _tiff_metadata(path: Path) -> dict[str, object]:
    """Exposure, camera name and ColorMatrix1 from the TIFF/EXIF tags of a TIFF-based RAW (DNG, NEF, ARW, CR2).

    Preferred over LibRaw's copies: LibRaw keeps the exposure time as float32
    and replaces a DNG's ColorMatrix by its own table when it knows the model.
    """
    import tifffile

    out: dict[str, object] = {}
    names = {"ISOSpeedRatings": "iso", "ExposureTime": "exposure_time", "FNumber": "f_number"}
    try:
        with tifffile.TiffFile(path) as tif:
            tags = {tag.name: tag.value for tag in tif.pages[0].tags.values()}
    except Exception:  # noqa: BLE001 - a non-TIFF RAW (CR3, RAF, ...) has none; metadata is optional
        return out
    exif = tags.get("ExifTag") if isinstance(tags.get("ExifTag"), dict) else {}
    for source in (tags, exif):
        for key, name in names.items():
            if key in source and name not in out:
                try:
                    v = _tag_number(source[key])
                except (TypeError, ValueError, IndexError, ZeroDivisionError):
                    continue
                if np.isfinite(v) and v > 0:
                    out[name] = v
    for key in ("Make", "Model"):
        if isinstance(tags.get(key), str):
            out[key.lower()] = tags[key].strip("\x00 ")
    cm = tags.get("ColorMatrix1")
    if isinstance(cm, tuple) and len(cm) in (9, 18):
        vals = np.array(cm, dtype=np.float64)
        if vals.size == 18:            # (numerator, denominator) pairs
            den = vals[1::2]
            vals = np.divide(vals[0::2], den, out=np.full(9, np.nan), where=den != 0)
        if np.all(np.isfinite(vals)):
            out["color_matrix"] = vals.reshape(3, 3)
    return out


def _tag_number(value) -> float:
    """A TIFF tag's number: a rational ``(numerator, denominator)``, the first of a tuple, or the value."""
    if isinstance(value, tuple) and len(value) == 2:
        return value[0] / value[1]
    if isinstance(value, tuple):
        value = value[0]
    return float(value)


# ---------------------------------------------------------------------------------------------- mosaics

def _normalised_mosaic(mosaic: NDArray[np.uint16], cell_black: NDArray[np.float64], white: float,
                       black_positive: bool) -> tuple[NDArray[np.float32], NDArray[np.bool_], NDArray[np.bool_]]:
    """Photosite values in units of saturation, and the saturated / dead photosites."""
    h, w = mosaic.shape
    black = np.empty((2, 2), np.float32)
    black.flat[:] = cell_black
    scale = (1.0 / (white - cell_black)).astype(np.float32).reshape(2, 2)
    out = mosaic.astype(np.float32)
    # per-cell black and scale through strided views, no full-size broadcast tables
    for i in range(2):
        for j in range(2):
            view = out[i::2, j::2]
            view -= black[i, j]
            view *= scale[i, j]
    saturated = mosaic >= white
    dead = (mosaic == 0) if black_positive else np.zeros((h, w), bool)
    if dead.any():
        out[dead] = 0.0
    return out, saturated, dead


def bin2x2(mosaic: NDArray[np.floating], colour_index: NDArray[np.int64], saturated: NDArray[np.bool_],
           dead: NDArray[np.bool_]) -> tuple[NDArray[np.float32], NDArray[np.bool_], NDArray[np.bool_]]:
    """One RGB pixel per 2 x 2 CFA cell: R, mean of the two G, B.

    Parameters
    ----------
    mosaic
        ``(H, W)`` normalised photosite values, H and W even.
    colour_index
        Colour of each cell of the 2 x 2 CFA in row order (0 R, 1 G, 2 B).
    saturated, dead
        ``(H, W)`` photosite masks.

    Returns
    -------
    rgb : ndarray
        ``(H/2, W/2, 3)`` float32 in the units of ``mosaic``; a dead green is
        replaced by the cell's other green.
    saturated, dead : ndarray
        ``(H/2, W/2)`` masks: any photosite of the cell saturated; the red or
        blue photosite, or both greens, dead.

    Examples
    --------
    >>> m = np.array([[1.0, 2.0], [4.0, 3.0]], np.float32)      # R G / G B
    >>> no = np.zeros((2, 2), bool)
    >>> rgb, s, d = bin2x2(m, np.array([0, 1, 1, 2]), no, no)
    >>> rgb[0, 0].tolist()
    [1.0, 3.0, 3.0]
    """
    cells = [mosaic[i::2, j::2] for i in range(2) for j in range(2)]
    dcells = [dead[i::2, j::2] for i in range(2) for j in range(2)]
    h2, w2 = cells[0].shape
    rgb = np.empty((h2, w2, 3), np.float32)
    greens = [k for k in range(4) if colour_index[k] == 1]
    for k in range(4):
        if colour_index[k] != 1:
            rgb[..., colour_index[k]] = cells[k]
    g1, g2 = greens
    gsum = cells[g1] * ~dcells[g1] + cells[g2] * ~dcells[g2]
    gcount = (~dcells[g1]).astype(np.float32) + ~dcells[g2]
    rgb[..., 1] = gsum / np.maximum(gcount, 1.0)
    sat = saturated[0::2, 0::2] | saturated[0::2, 1::2] | saturated[1::2, 0::2] | saturated[1::2, 1::2]
    red_blue_dead = np.zeros((h2, w2), bool)
    for k in range(4):
        if colour_index[k] != 1:
            red_blue_dead |= dcells[k]
    dd = red_blue_dead | (dcells[g1] & dcells[g2])
    return rgb, sat, dd


_KERNEL_RB = np.array([[1, 2, 1], [2, 4, 2], [1, 2, 1]], np.float32)
_KERNEL_G = np.array([[0, 1, 0], [1, 4, 1], [0, 1, 0]], np.float32)


def bilinear_demosaic(mosaic: NDArray[np.floating], colour_index: NDArray[np.int64], saturated: NDArray[np.bool_],
                      dead: NDArray[np.bool_]) -> tuple[NDArray[np.float32], NDArray[np.bool_], NDArray[np.bool_]]:
    """Full-resolution RGB by bilinear interpolation of each colour's samples (normalised convolution).

    Each channel is ``conv(values * mask) / conv(mask)`` with the bilinear
    kernel, ``mask`` marking that colour's live photosites; so edges and dead
    photosites need no special case.  Borders are mirrored about the edge
    photosite, which keeps the CFA's parity, so without dead photosites
    ``conv(mask)`` is the same in every 2 x 2 cell and is computed once.  A
    pixel is saturated (dead) when a photosite inside its kernel support for
    any channel is.

    Parameters
    ----------
    mosaic
        ``(H, W)`` normalised photosite values, H and W even.
    colour_index
        Colour of each cell of the 2 x 2 CFA in row order (0 R, 1 G, 2 B).
    saturated, dead
        ``(H, W)`` photosite masks.

    Returns
    -------
    rgb : ndarray
        ``(H, W, 3)`` float32 in the units of ``mosaic``.
    saturated : ndarray
        ``(H, W)`` bool: a saturated photosite lies in the pixel's kernel support.
    dead : ndarray
        ``(H, W)`` bool: the pixel is a dead photosite, or every sample of a
        channel in reach is dead.

    References
    ----------
    Gunturk, B. K., Glotzbach, J., Altunbasak, Y., Schafer, R. W., Mersereau,
    R. M. (2005). Demosaicking: color filter array interpolation. IEEE Signal
    Processing Magazine 22(1), 44-54, "Single-channel interpolation".
    doi:10.1109/MSP.2005.1407714

    Examples
    --------
    >>> m = np.tile(np.array([[1.0, 2.0], [2.0, 3.0]], np.float32), (2, 2))     # flat R=1 G=2 B=3
    >>> no = np.zeros((4, 4), bool)
    >>> rgb, s, d = bilinear_demosaic(m, np.array([0, 1, 1, 2]), no, no)
    >>> np.allclose(rgb, [1, 2, 3])
    True
    """
    import cv2

    h, w = mosaic.shape
    rgb = np.empty((h, w, 3), np.float32)
    sat = np.zeros((h, w), bool)
    dd = dead.copy()
    any_dead, any_sat = bool(dead.any()), bool(saturated.any())
    mirror = cv2.BORDER_REFLECT_101
    src = np.asarray(mosaic, dtype=np.float32)
    for c in range(3):
        cells = [(k // 2, k % 2) for k in range(4) if colour_index[k] == c]
        kernel = _KERNEL_G if c == 1 else _KERNEL_RB
        plane = np.zeros((h, w), np.float32)
        for i, j in cells:
            plane[i::2, j::2] = src[i::2, j::2]
        if any_sat:
            channel_sat = np.zeros((h, w), np.uint8)
            for i, j in cells:
                channel_sat[i::2, j::2] = saturated[i::2, j::2]
            support = (kernel > 0).astype(np.uint8)
            sat |= cv2.dilate(channel_sat, support, borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0
        channel = rgb[..., c]
        if any_dead:
            live = np.zeros((h, w), np.float32)
            for i, j in cells:
                live[i::2, j::2] = 1.0
            live[dead] = 0.0
            plane[dead] = 0.0
            weight = cv2.filter2D(live, -1, kernel, borderType=mirror)
            lost = weight <= 0                     # every sample in reach is dead
            dd |= lost
            channel[...] = cv2.filter2D(plane, -1, kernel, borderType=mirror) / np.where(lost, 1.0, weight)
        else:
            tile = np.zeros((6, 6), np.float32)
            for i, j in cells:
                tile[i::2, j::2] = 1.0
            cell_weight = cv2.filter2D(tile, -1, kernel)[2:4, 2:4]      # centre cell: no border in reach
            value = cv2.filter2D(plane, -1, kernel, borderType=mirror)
            for i in range(2):
                for j in range(2):
                    channel[i::2, j::2] = value[i::2, j::2] / cell_weight[i, j]
    return rgb, sat, dd


def decode_raw(path: str | os.PathLike[str], *, mode: str = "bin2x2") -> RawImage:
    """Decode a Bayer RAW file into linear, un-white-balanced camera RGB.

    Parameters
    ----------
    path
        A DNG, CR2, NEF, ARW or other Bayer RAW file LibRaw reads.
    mode
        ``"bin2x2"`` (one pixel per 2 x 2 CFA cell) or ``"demosaic"``
        (full resolution, bilinear).

    Returns
    -------
    RawImage
        ``rgb`` float32 with 1.0 = saturation, black subtracted per CFA cell,
        not white balanced; the saturated and dead masks; the file's
        metadata.

    Raises
    ------
    RawDecodeError
        Missing, empty, truncated or corrupt file; a JPEG/PNG/TIFF/HEIF given
        as RAW; a sensor that is not a 2 x 2 RGB Bayer mosaic; an unknown mode.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> from mocks.dng_writer import write_dng
    >>> p = write_dng(pathlib.Path(tempfile.mkdtemp()) / "a.dng", np.full((24, 24), 2148, np.uint16),
    ...               black_level=100, white_level=4196)
    >>> img = decode_raw(p)
    >>> img.rgb.shape, float(img.rgb[0, 0, 1])
    ((12, 12, 3), 0.5)
    """
    if mode not in DECODE_MODES:
        raise RawDecodeError(f"mode must be one of {', '.join(DECODE_MODES)}, got {mode!r}")
    p = Path(os.fspath(path))
    raw = _open(p)
    try:
        letters, colour_index = _cfa_string(raw, p)
        mosaic, cell_black, white = _mosaic_levels(raw, p, colour_index)
        idx = np.where(colour_index == 3, 1, colour_index)
        neutral, libraw_cm, libraw_meta = _libraw_colour(raw)
        # normalised before the file is closed: the mosaic is a view of LibRaw's buffer
        values, sat, dead = _normalised_mosaic(mosaic, cell_black, white, bool(cell_black.min() > _DEAD_BLACK_MIN))
    finally:
        raw.close()
    meta, xyz_to_cam, make, model = _file_metadata(p, libraw_meta, libraw_cm)
    if mode == "bin2x2":
        rgb, s, d = bin2x2(values, idx, sat, dead)
        scale = 2
    else:
        rgb, s, d = bilinear_demosaic(values, idx, sat, dead)
        scale = 1
    return RawImage(
        rgb=rgb, saturated=s, dead=d,
        black_levels=tuple(float(b) for b in cell_black),  # type: ignore[arg-type]
        white_level=white, cfa_pattern=letters,
        exposure_time=meta["exposure_time"], iso=meta["iso"], f_number=meta["f_number"],
        make=make, model=model, path=p, mode=mode, scale=scale,
        as_shot_neutral=neutral, xyz_to_camera=xyz_to_cam,
    )


def _mosaic_levels(raw, p: Path, colour_index: NDArray[np.int64]) -> tuple[NDArray, NDArray[np.float64], float]:
    """The visible mosaic cut to whole CFA cells, the black level of each cell (DN) and the white level (DN)."""
    mosaic = np.asarray(raw.raw_image_visible)
    h, w = mosaic.shape
    if h < 2 or w < 2:
        raise RawDecodeError(f"{p}: the raw image is only {w} x {h} photosites")
    if h % 2 or w % 2:           # a whole number of CFA cells keeps the cell pattern and the binning aligned
        mosaic = mosaic[: h - h % 2, : w - w % 2]
    # LibRaw's per-colour black: index with the cell's colour index (0 R, 1 G, 2 B, 3 second G)
    black_by_colour = np.asarray(raw.black_level_per_channel, dtype=np.float64)
    cell_black = black_by_colour[colour_index]
    white = float(raw.white_level)
    if not np.all(white > cell_black):
        raise RawDecodeError(
            f"{p}: white level {white:g} DN is not above the black levels {cell_black.tolist()}; the file's "
            "metadata is damaged"
        )
    return mosaic, cell_black, white


def _libraw_colour(raw) -> tuple[NDArray[np.float64] | None, NDArray[np.float64], dict[str, float]]:
    """LibRaw's as-shot neutral (max 1, None if absent), its XYZ -> camera matrix and its exposure metadata."""
    neutral = None
    wb = np.asarray(raw.camera_whitebalance[:3], dtype=np.float64)
    if np.all(np.isfinite(wb)) and np.all(wb > 0):
        neutral = (1.0 / wb) / np.max(1.0 / wb)
    libraw_cm = np.asarray(raw.rgb_xyz_matrix, dtype=np.float64)[:3]
    other = raw.other
    libraw_meta = {"exposure_time": float(other.shutter_speed), "iso": float(other.iso_speed),
                   "f_number": float(other.aperture)}
    return neutral, libraw_cm, libraw_meta


def _file_metadata(
    p: Path, libraw_meta: dict[str, float], libraw_cm: NDArray[np.float64]
) -> tuple[dict[str, float], NDArray[np.float64] | None, str, str]:
    """Exposure, XYZ -> camera matrix (None if unusable), make and model: the TIFF tags first, LibRaw's otherwise."""
    tiff = _tiff_metadata(p)
    meta = {k: float(tiff.get(k, v if np.isfinite(v) and v > 0 else 0.0)) for k, v in libraw_meta.items()}
    cm = np.asarray(tiff.get("color_matrix", libraw_cm), dtype=np.float64)
    xyz_to_cam = cm if np.all(np.isfinite(cm)) and abs(np.linalg.det(cm)) > 1e-12 else None
    make, model = str(tiff.get("make", "")), str(tiff.get("model", ""))
    return meta, xyz_to_cam, make, model


# ---------------------------------------------------------------------------------------------- preview

_XYZ_TO_SRGB = np.array([[3.2404542, -1.5371385, -0.4985314],
                         [-0.9692660, 1.8760108, 0.0415560],
                         [0.0556434, -0.2040259, 1.0572252]])
_D65_XYZ = np.array([0.95047, 1.0, 1.08883])


@functools.lru_cache(maxsize=1)
def _srgb_lut() -> NDArray[np.uint8]:
    """SRGB 8-bit code of each 16-bit linear value: a cache of :func:`processing.spectral.display.encode_srgb8`."""
    lut = encode_srgb8(np.arange(65536, dtype=np.float64) / 65535.0)
    lut.setflags(write=False)
    return lut


def _display_matrix(raw: RawImage) -> NDArray[np.float64]:
    """Camera RGB -> linear sRGB: balance by the neutral, then ColorMatrix^-1 with white kept white."""
    rgb = raw.rgb
    if raw.as_shot_neutral is not None:
        neutral = np.asarray(raw.as_shot_neutral, dtype=np.float64)
    else:
        # grey world: the mean of the unsaturated pixels is taken as neutral
        step = max(1, int(np.sqrt(rgb.shape[0] * rgb.shape[1] / 250_000)))
        sample = rgb[::step, ::step].reshape(-1, 3)
        ok = ~raw.saturated[::step, ::step].ravel()
        mean = sample[ok].mean(axis=0) if ok.any() else np.ones(3)
        neutral = mean / mean.max() if np.all(mean > 0) else np.ones(3)
    balance = np.diag(1.0 / neutral)
    if raw.xyz_to_camera is None:
        return balance
    cm = raw.xyz_to_camera
    cam_white = cm @ _D65_XYZ
    if not np.all(cam_white > 0):
        return balance
    return _XYZ_TO_SRGB @ np.linalg.inv(cm) @ np.diag(cam_white) @ balance


def preview_srgb8(raw: RawImage, *, percentile: float = 99.0, level: float = 0.9) -> NDArray[np.uint8]:
    """A white-balanced, exposure-normalised sRGB preview ``(H, W, 3)`` uint8 (R, G, B order).

    The as-shot neutral balances the image (grey world when the file has
    none); the camera colours go to sRGB through the file's ColorMatrix when
    present (the DNG convention: camera -> XYZ by the inverse ColorMatrix
    with the neutral kept white, then XYZ -> sRGB); the exposure is scaled
    so the ``percentile`` of the luminance lands at ``level``; the sRGB
    transfer curve is :func:`processing.spectral.display.encode_srgb8`;
    saturated pixels are shown white.

    Parameters
    ----------
    raw
        A decoded frame.
    percentile
        Percentile (0-100] of the luminance that sets the exposure.
    level
        Linear level (0, 1] that percentile is scaled to.

    Returns
    -------
    ndarray
        ``(H, W, 3)`` uint8 sRGB, the size of ``raw.rgb``.

    Raises
    ------
    RawDecodeError
        ``percentile`` or ``level`` out of range.

    References
    ----------
    Adobe Systems (2012). Digital Negative (DNG) Specification, version
    1.4.0.0, chapter 6 (no DOI).

    IEC 61966-2-1:1999, default RGB colour space -- sRGB (no DOI).

    Examples
    --------
    >>> img = RawImage(np.full((4, 4, 3), 0.25, np.float32), np.zeros((4, 4), bool), np.zeros((4, 4), bool),
    ...                (0, 0, 0, 0), 1.0, "RGGB", 0.01, 100, 0, "", "", Path("x"), "bin2x2", 2)
    >>> preview_srgb8(img)[0, 0].tolist()      # 0.9 linear -> 243 sRGB
    [243, 243, 243]
    """
    if not (0 < percentile <= 100 and 0 < level <= 1):
        raise RawDecodeError(f"percentile must be in (0, 100] and level in (0, 1], got {percentile!r}, {level!r}")
    import cv2

    m = _display_matrix(raw)
    h, w = raw.shape
    step = max(1, int(np.sqrt(h * w / 250_000)))
    # luminance of a subsample sets the exposure; cv2.transform applies a 3 x 3 matrix per pixel
    # (NumPy's (N, 3) @ (3, 3) is far slower on large images)
    lum_weights = (np.array([0.2126, 0.7152, 0.0722]) @ m).reshape(1, 3)
    lum = cv2.transform(np.ascontiguousarray(raw.rgb[::step, ::step]), lum_weights.astype(np.float32))
    ref = float(np.percentile(lum, percentile)) if lum.size else 0.0
    gain = level / ref if ref > 0 and np.isfinite(ref) else 1.0
    lin = cv2.transform(raw.rgb, (m * (gain * 65535.0)).astype(np.float32))
    np.clip(lin, 0.0, 65535.0, out=lin)
    out = _srgb_lut()[lin.astype(np.uint16)]
    if raw.saturated.any():
        out[raw.saturated] = 255
    return out
