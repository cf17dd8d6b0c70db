"""Writing rendered images: 8-bit sRGB PNG and float32 XYZ TIFF, atomically.

Each file is first written to a temporary file in the target directory and
then renamed over the target (:func:`processing.common.files.atomic_path`),
so a reader (or a crash) never sees a half-written image.

Examples
--------
>>> import tempfile, pathlib
>>> d = pathlib.Path(tempfile.mkdtemp())
>>> write_png(d / "a.png", np.zeros((2, 3, 3), np.uint8)).name
'a.png'
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from processing.common.files import atomic_path
from render.errors import RenderInputError

__all__ = ["write_png", "write_xyz_tiff", "read_xyz_tiff"]


@contextmanager
def _atomic(path: str | os.PathLike[str]) -> Iterator[Path]:
    """A temporary file beside ``path``, renamed over it at the end; the target's folder must exist."""
    target = Path(path)
    if target.is_dir():
        raise RenderInputError(f"output path '{target}' is a directory; give a file name")
    parent = target.parent if str(target.parent) else Path(".")
    if not parent.is_dir():
        raise RenderInputError(f"output directory '{parent}' does not exist; create it first")
    with atomic_path(target, make_parents=False) as tmp:
        yield tmp


def write_png(path: str | os.PathLike[str], srgb8: ArrayLike, alpha: ArrayLike | None = None) -> Path:
    """Write an 8-bit sRGB image as PNG.

    Parameters
    ----------
    path
        Target file.
    srgb8
        uint8 ``(H, W, 3)`` (or ``(H, W, 4)`` with alpha).
    alpha
        Optional coverage ``(H, W)``: uint8, or float in [0, 1] (scaled to 255).

    Returns
    -------
    Path
        The written file.

    Raises
    ------
    RenderInputError
        A bad image or alpha array, a directory as target, or a missing
        output folder.
    """
    img = np.asarray(srgb8)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] not in (3, 4) or 0 in img.shape:
        raise RenderInputError(
            f"write_png needs a non-empty uint8 (H, W, 3) or (H, W, 4) array, got {img.dtype} {img.shape}"
        )
    if alpha is not None:
        a = np.asarray(alpha)
        if a.shape != img.shape[:2]:
            raise RenderInputError(f"write_png alpha must have shape {img.shape[:2]}, got {a.shape}")
        if a.dtype != np.uint8:
            if not np.all(np.isfinite(a)):
                raise RenderInputError("write_png alpha contains NaN or infinite values")
            a = np.round(np.clip(a, 0.0, 1.0) * 255.0).astype(np.uint8)
        img = np.concatenate([img[:, :, :3], a[:, :, None]], axis=2)
    from PIL import Image

    mode = "RGBA" if img.shape[2] == 4 else "RGB"
    with _atomic(path) as tmp:
        Image.fromarray(np.ascontiguousarray(img), mode=mode).save(tmp, format="PNG")
    return Path(path)


def write_xyz_tiff(path: str | os.PathLike[str], xyz: ArrayLike) -> Path:
    """Write CIE XYZ as a float32 3-sample TIFF (photometric minisblack, planar contig).

    The values are stored as computed (a white Lambertian surface facing the
    key light has Y = 1); the description tag says so.

    Parameters
    ----------
    path
        Target file.
    xyz
        ``(H, W, 3)`` finite values.

    Returns
    -------
    Path
        The written file.

    Raises
    ------
    RenderInputError
        Not a non-empty finite ``(H, W, 3)`` array, a directory as target,
        or a missing output folder.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> xyz = np.random.default_rng(0).random((4, 5, 3)).astype(np.float32)
    >>> path = write_xyz_tiff(pathlib.Path(tempfile.mkdtemp()) / "x.tiff", xyz)
    >>> bool(np.array_equal(read_xyz_tiff(path), xyz))
    True
    """
    import tifffile

    arr = np.asarray(xyz)
    if arr.ndim != 3 or arr.shape[2] != 3 or 0 in arr.shape:
        raise RenderInputError(f"write_xyz_tiff needs a non-empty (H, W, 3) array, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise RenderInputError("write_xyz_tiff: xyz contains NaN or infinite values")
    arr = np.ascontiguousarray(arr, dtype=np.float32)
    with _atomic(path) as tmp:
        tifffile.imwrite(
            tmp,
            arr,
            photometric="minisblack",
            planarconfig="contig",
            extrasamples=None,
            description="CIE 1931 XYZ, float32, white Lambertian facing the key light has Y = 1",
        )
    return Path(path)


def read_xyz_tiff(path: str | os.PathLike[str]) -> np.ndarray:
    """Read back a file of :func:`write_xyz_tiff` as float32 ``(H, W, 3)``.

    Parameters
    ----------
    path
        A TIFF written by :func:`write_xyz_tiff`.

    Returns
    -------
    ndarray
        float32 ``(H, W, 3)`` CIE XYZ as stored.

    Raises
    ------
    RenderInputError
        The file does not hold 3-sample pixels.
    """
    import tifffile

    arr = tifffile.imread(path)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise RenderInputError(f"'{path}' is not a 3-sample XYZ TIFF (shape {arr.shape})")
    return arr.astype(np.float32, copy=False)
