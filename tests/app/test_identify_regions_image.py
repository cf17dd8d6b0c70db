"""``kogei identify --regions``: a label image whose header declares an image bomb is one line."""

from __future__ import annotations

import struct
import zlib

import pytest

from app.errors import UsageError
from app.workflows.identification import read_labels


def _png_header(width: int, height: int) -> bytes:
    """A PNG that declares ``width`` x ``height`` grey pixels and holds none."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"")) + chunk(b"IEND", b""))


def test_a_label_image_declaring_40000_squared_pixels_is_one_line(tmp_path):
    """OpenCV refuses a 40000 x 40000 header with cv2.error, which escaped as a traceback."""
    path = tmp_path / "bomb.png"
    path.write_bytes(_png_header(40000, 40000))
    with pytest.raises(UsageError, match="--regions .*bomb.png: OpenCV refuses to read it") as err:
        read_labels(path, (16, 16))
    assert "\n" not in str(err.value)
