r"""PNG encoding of 8-bit images (Pillow).

Examples
--------
>>> import numpy as np
>>> png_bytes(np.zeros((2, 3, 3), np.uint8))[:8]
b'\x89PNG\r\n\x1a\n'
>>> png_bytes(np.zeros((2, 3, 3), np.uint8), compress_level=3)[:8]
b'\x89PNG\r\n\x1a\n'
"""

from __future__ import annotations

import io

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["png_bytes"]


def png_bytes(image8: ArrayLike, compress_level: int = 6) -> bytes:
    """Encode an 8-bit image as PNG.

    Parameters
    ----------
    image8
        uint8 ``(H, W)``, ``(H, W, 3)`` or ``(H, W, 4)``.
    compress_level
        zlib level 0-9 (lossless at every level): 6, Pillow's default, or 3 for images written
        in bulk (a 960 x 640 photo: 0.06 s against 0.2 s, 4 % larger).

    Returns
    -------
    bytes
        The PNG file's bytes.

    Raises
    ------
    processing.errors.InputError
        The array is empty, not uint8, or not one of those shapes.
    """
    from PIL import Image

    from processing.errors import InputError

    img = np.asarray(image8)
    if img.dtype != np.uint8 or 0 in img.shape or not (img.ndim == 2 or (img.ndim == 3 and img.shape[2] in (3, 4))):
        raise InputError(f"png_bytes needs a non-empty uint8 (H, W), (H, W, 3) or (H, W, 4) array, "
                         f"got {img.dtype} {img.shape}")
    if not (isinstance(compress_level, int) and 0 <= compress_level <= 9):
        raise InputError(f"compress_level must be an integer 0-9, got {compress_level!r}")
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(img)).save(buf, format="PNG", compress_level=compress_level)
    return buf.getvalue()
