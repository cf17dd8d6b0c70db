"""DNG writer: LibRaw (rawpy) reads back the mosaic, the levels, the CFA and the colour tags."""

from __future__ import annotations

import numpy as np
import pytest
import rawpy
import tifffile
from hypothesis import given, settings
from hypothesis import strategies as st

from mocks.dng_writer import MIN_SIDE, DngWriteError, write_dng

CM = np.array([[0.95, -0.24, -0.08], [-0.50, 1.20, 0.25], [-0.19, 0.28, 0.69]])
# LibRaw's xyz_rgb (sRGB primaries, D65), LibRaw src/tables/colordata.cpp
XYZ_RGB = np.array([[0.412453, 0.357580, 0.180423], [0.212671, 0.715160, 0.072169], [0.019334, 0.119193, 0.950227]])


def _mosaic(h=32, w=48, lo=100, hi=4095, seed=0):
    return np.random.default_rng(seed).integers(lo, hi + 1, (h, w)).astype(np.uint16)


@pytest.mark.parametrize("pattern", ["RGGB", "BGGR", "GRBG", "GBRG"])
def test_rawpy_round_trip(tmp_path, pattern):
    bayer = _mosaic()
    black = [100, 101, 102, 103]
    path = write_dng(tmp_path / "f.dng", bayer, black_level=black, white_level=4095, cfa_pattern=pattern,
                     color_matrix=CM, as_shot_neutral=[0.5, 1.0, 0.8], exposure_time=1 / 125, iso=200)
    with rawpy.imread(str(path)) as raw:
        assert np.array_equal(raw.raw_image_visible, bayer)
        assert raw.white_level == 4095
        assert raw.color_desc == b"RGBG"
        # LibRaw numbers the green that shares a row with blue 3; map the written cells to its indices
        letters = {"R": 0, "G": 1, "B": 2}
        cells = [letters[c] for c in pattern]
        blue_row = cells.index(2) // 2
        expected = np.array(cells)
        expected[[i for i, c in enumerate(cells) if c == 1 and i // 2 == blue_row]] = 3
        assert raw.raw_pattern.ravel().tolist() == expected.tolist()
        # black level per LibRaw channel = the level written at the cell of that channel
        per_channel = [0] * 4
        for cell, ch in enumerate(expected):
            per_channel[ch] = black[cell]
        assert list(raw.black_level_per_channel) == per_channel
        # AsShotNeutral -> camera white balance multipliers 1/neutral, green = 1
        wb = np.array(raw.camera_whitebalance[:3])
        assert np.allclose(wb / wb[1], [2.0, 1.0, 1.25], rtol=1e-6)


def test_color_matrix_reaches_libraw(tmp_path):
    """LibRaw's camera->sRGB matrix is pinv of row-normalised ColorMatrix1 @ xyz_rgb (dcraw's cam_xyz_coeff)."""
    path = write_dng(tmp_path / "f.dng", _mosaic(), black_level=0, white_level=4095, color_matrix=CM)
    cam_rgb = CM @ XYZ_RGB
    cam_rgb /= cam_rgb.sum(axis=1, keepdims=True)
    expected = np.linalg.pinv(cam_rgb)
    with rawpy.imread(str(path)) as raw:
        assert np.allclose(raw.color_matrix[:, :3], expected, atol=2e-4)


def test_tags_written(tmp_path):
    path = write_dng(tmp_path / "f.dng", _mosaic(), black_level=64, white_level=4095, exposure_time=1 / 250,
                     iso=400, make="Nikon", model="D5100", calibration_illuminant="D65")
    with tifffile.TiffFile(path) as tif:
        tags = tif.pages[0].tags
        assert tags["NewSubfileType"].value == 0
        assert tags["PhotometricInterpretation"].value == 32803
        assert tags["Compression"].value == 1
        assert bytes(tags["DNGVersion"].value) == b"\x01\x04\x00\x00"
        assert tags["UniqueCameraModel"].value == "Nikon D5100"
        assert tags["ExposureTime"].value == (1, 250)
        assert tags["ISOSpeedRatings"].value == 400
        assert tags["CalibrationIlluminant1"].value == 21
        assert tags["CFARepeatPatternDim"].value == (2, 2)
    assert not [p for p in tmp_path.iterdir() if p.name != "f.dng"], "no temporary file may remain"


def test_replaces_atomically(tmp_path):
    a, b = _mosaic(seed=1), _mosaic(seed=2)
    write_dng(tmp_path / "f.dng", a, black_level=0, white_level=4095)
    write_dng(tmp_path / "f.dng", b, black_level=0, white_level=4095)
    with rawpy.imread(str(tmp_path / "f.dng")) as raw:
        assert np.array_equal(raw.raw_image_visible, b)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.dng"]


@settings(max_examples=8, deadline=None)
@given(h=st.integers(MIN_SIDE // 2, 24).map(lambda v: 2 * v), w=st.integers(MIN_SIDE // 2, 24).map(lambda v: 2 * v),
       bits=st.sampled_from([12, 14, 16]), seed=st.integers(0, 2**16))
def test_round_trip_sizes_and_depths(tmp_path_factory, h, w, bits, seed):
    white = (1 << bits) - 1
    bayer = np.random.default_rng(seed).integers(0, white + 1, (h, w)).astype(np.uint16)
    bayer[0, 0], bayer[-1, -1] = 0, white            # both extremes present
    path = write_dng(tmp_path_factory.mktemp("d") / "f.dng", bayer, black_level=0, white_level=white)
    with rawpy.imread(str(path)) as raw:
        assert np.array_equal(raw.raw_image_visible, bayer)
        assert raw.white_level == white


@pytest.mark.parametrize(
    "kwargs, words",
    [
        ({"bayer_uint16": np.zeros((31, 40), np.uint16)}, "even height"),
        ({"bayer_uint16": np.zeros((10, 10), np.uint16)}, "LibRaw"),
        ({"bayer_uint16": np.zeros((32, 32), np.float32)}, "dtype uint16"),
        ({"bayer_uint16": np.full((32, 32), 5000, np.uint16)}, "above white_level"),
        ({"cfa_pattern": "RGBX"}, "cfa_pattern"),
        ({"cfa_pattern": "RRGG"}, "cfa_pattern"),
        ({"black_level": [1, 2]}, "black_level"),
        ({"black_level": -1}, "black_level"),
        ({"black_level": 5000}, "white_level"),
        ({"color_matrix": np.eye(2)}, "color_matrix"),
        ({"color_matrix": np.full((3, 3), np.nan)}, "color_matrix"),
        ({"as_shot_neutral": [1, 0, 1]}, "as_shot_neutral"),
        ({"exposure_time": 0}, "exposure_time"),
        ({"iso": 0}, "iso"),
        ({"calibration_illuminant": "F99"}, "calibration_illuminant"),
    ],
)
def test_bad_input(tmp_path, kwargs, words):
    args = {"bayer_uint16": np.zeros((32, 32), np.uint16), "black_level": 0, "white_level": 4095}
    args.update(kwargs)
    bayer = args.pop("bayer_uint16")
    with pytest.raises(DngWriteError, match=words):
        write_dng(tmp_path / "f.dng", bayer, **args)
    assert not list(tmp_path.iterdir())


def test_missing_folder(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        write_dng(tmp_path / "nope" / "f.dng", np.zeros((32, 32), np.uint16), black_level=0, white_level=4095)
