r"""PNG encoding of 8-bit images (Pillow).

Examples
--------
>>> import numpy as np
>>> png_bytes(np.zeros((2, 3, 3), np.uint8))[:8]
b'\x89PNG\r\n\x1a\n'
"""

from __future__ import annotations

import io

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["png_bytes"]


def png_bytes(image8: ArrayLike) -> bytes:
    """Encode an 8-bit image as PNG.

    Parameters
    ----------
    image8
        uint8 ``(H, W)``, ``(H, W, 3)`` or ``(H, W, 4)``.

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
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(img)).save(buf, format="PNG")
    return buf.getvalue()
