"""PNG and XYZ TIFF output: round trips, alpha, atomic replacement, bad input."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile
from PIL import Image

from render.errors import RenderInputError
from render.image_io import read_xyz_tiff, write_png, write_xyz_tiff


def test_png_round_trip_rgb_and_alpha(tmp_path):
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (7, 5, 3), dtype=np.uint8)
    write_png(tmp_path / "a.png", img)
    back = np.asarray(Image.open(tmp_path / "a.png"))
    assert back.shape == (7, 5, 3) and np.array_equal(back, img)
    mask = np.linspace(0, 1, 35).reshape(7, 5)
    write_png(tmp_path / "b.png", img, alpha=mask)
    rgba = np.asarray(Image.open(tmp_path / "b.png"))
    assert rgba.shape == (7, 5, 4) and np.array_equal(rgba[..., :3], img)
    np.testing.assert_array_equal(rgba[..., 3], np.round(mask * 255).astype(np.uint8))


def test_xyz_tiff_is_float32_three_samples_and_reads_back(tmp_path):
    xyz = np.random.default_rng(1).random((6, 9, 3)).astype(np.float32) * 3.0
    path = write_xyz_tiff(tmp_path / "x.tiff", xyz)
    with tifffile.TiffFile(path) as tif:
        page = tif.pages[0]
        assert page.dtype == np.float32 and page.samplesperpixel == 3
        assert "XYZ" in page.description
    np.testing.assert_array_equal(tifffile.imread(path), xyz)
    np.testing.assert_array_equal(read_xyz_tiff(path), xyz)


def test_writes_are_atomic_a_failed_write_keeps_the_old_file(tmp_path, monkeypatch):
    target = tmp_path / "img.png"
    good = np.full((4, 4, 3), 200, np.uint8)
    write_png(target, good)
    before = target.read_bytes()

    import PIL.Image

    def broken_save(self, fp, *args, **kwargs):
        with open(fp, "wb") as fh:
            fh.write(b"partial")
        raise OSError("disk full")

    monkeypatch.setattr(PIL.Image.Image, "save", broken_save)
    with pytest.raises(OSError, match="disk full"):
        write_png(target, np.zeros((4, 4, 3), np.uint8))
    assert target.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["img.png"]       # no temporary file left


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda p: write_png(p / "a.png", np.zeros((4, 4, 3), np.float32)), "uint8"),
        (lambda p: write_png(p / "a.png", np.zeros((4, 4), np.uint8)), r"\(H, W, 3\)"),
        (lambda p: write_png(p / "a.png", np.zeros((0, 4, 3), np.uint8)), "non-empty"),
        (lambda p: write_png(p / "a.png", np.zeros((4, 4, 3), np.uint8), alpha=np.zeros((3, 4))), "alpha must"),
        (lambda p: write_png(p / "a.png", np.zeros((2, 2, 3), np.uint8), alpha=np.full((2, 2), np.nan)), "NaN"),
        (lambda p: write_png(p / "missing" / "a.png", np.zeros((2, 2, 3), np.uint8)), "does not exist"),
        (lambda p: write_png(p, np.zeros((2, 2, 3), np.uint8)), "is a directory"),
        (lambda p: write_xyz_tiff(p / "x.tiff", np.zeros((4, 4))), r"\(H, W, 3\)"),
        (lambda p: write_xyz_tiff(p / "x.tiff", np.full((2, 2, 3), np.inf)), "NaN or infinite"),
    ],
)
def test_bad_output_requests(tmp_path, call, message):
    with pytest.raises(RenderInputError, match=message):
        call(tmp_path)


def test_reading_a_non_xyz_tiff_is_refused(tmp_path):
    tifffile.imwrite(tmp_path / "grey.tiff", np.zeros((4, 4), np.float32))
    with pytest.raises(RenderInputError, match="not a 3-sample XYZ TIFF"):
        read_xyz_tiff(tmp_path / "grey.tiff")
