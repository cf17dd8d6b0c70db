"""``kogei identify --regions``: a label image whose header declares an image bomb is one line."""

from __future__ import annotations

import pytest

from app.errors import UsageError
from app.workflows.identification import read_labels
from tests.app.cli_checks import png_header


def test_a_label_image_declaring_40000_squared_pixels_is_one_line(tmp_path):
    """OpenCV refuses a 40000 x 40000 header with cv2.error, which escaped as a traceback."""
    path = tmp_path / "bomb.png"
    path.write_bytes(png_header(40000, 40000))
    with pytest.raises(UsageError, match="--regions .*bomb.png: OpenCV refuses to read it") as err:
        read_labels(path, (16, 16))
    assert "\n" not in str(err.value)
