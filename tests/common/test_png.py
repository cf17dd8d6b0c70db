"""PNG encoding: lossless at every compression level; the package's helpers import on first use."""

from __future__ import annotations

import io
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from processing.common.png import png_bytes
from processing.errors import InputError


@pytest.mark.parametrize("level", [0, 3, 6, 9])
def test_every_compression_level_decodes_to_the_same_pixels(level):
    img = np.random.default_rng(1).integers(0, 256, (40, 60, 3), dtype=np.uint8)
    img[10:30, 20:50] = (0, 255, 255)            # a flat area, as an overlay's outline and backdrop have
    back = np.asarray(Image.open(io.BytesIO(png_bytes(img, compress_level=level))))
    np.testing.assert_array_equal(back, img)


def test_lower_level_is_larger_but_not_much_on_a_flat_image():
    img = np.zeros((200, 300, 3), np.uint8)
    img[50:150, 100:200] = 200
    assert len(png_bytes(img, compress_level=1)) >= len(png_bytes(img, compress_level=9))


@pytest.mark.parametrize("level", [-1, 10, 2.5, "3"])
def test_bad_compression_level_is_refused(level):
    with pytest.raises(InputError, match="compress_level"):
        png_bytes(np.zeros((2, 2), np.uint8), compress_level=level)


def test_file_helpers_import_without_numpy():
    # the fake gphoto2, started once per photograph, needs only the file helpers
    code = "import sys, processing.common.files, processing.common; print('numpy' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


def test_package_names_still_resolve():
    import processing.common as common

    assert common.png_bytes is png_bytes
    assert callable(common.atomic_write_text) and callable(common.rotation_z)
    with pytest.raises(AttributeError):
        common.no_such_helper  # noqa: B018
