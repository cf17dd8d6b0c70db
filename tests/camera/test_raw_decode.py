"""RAW decoding against the simulated sensor's truth: levels, linearity, masks, modes, metadata, bad files."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from mocks.camera_sim import SensorModel
from mocks.dng_writer import write_dng
from processing.camera.raw_decode import (
    RawDecodeError,
    bilinear_demosaic,
    bin2x2,
    decode_raw,
    preview_srgb8,
    sniff_format,
)
from tests.camera.chart_shots import chart_shot


@pytest.fixture(scope="module")
def shot(tmp_path_factory):
    return chart_shot(tmp_path_factory.mktemp("raw"), "classic24", width=240, height=160)


def _inside(labels: np.ndarray, k: int) -> np.ndarray:
    """Binned pixels whose four photosites all lie on patch k."""
    return ((labels[0::2, 0::2] == k) & (labels[0::2, 1::2] == k)
            & (labels[1::2, 0::2] == k) & (labels[1::2, 1::2] == k))


# ---------------------------------------------------------------------------------------------- levels

def test_per_cell_black_and_white_level_are_recovered_exactly(tmp_path):
    black = [600, 610, 620, 630]              # R, G1, G2, B cells of RGGB
    white = 15000
    cell_values = [1000, 5000, 9000, 14999]
    mosaic = np.empty((24, 32), np.uint16)
    for k, v in enumerate(cell_values):
        mosaic[k // 2::2, k % 2::2] = v
    p = write_dng(tmp_path / "levels.dng", mosaic, black_level=black, white_level=white)
    img = decode_raw(p, mode="bin2x2")
    assert img.black_levels == tuple(float(b) for b in black)
    assert img.white_level == white and img.cfa_pattern == "RGGB"
    expected = [(v - b) / (white - b) for v, b in zip(cell_values, black)]
    r, g1, g2, b = expected
    np.testing.assert_allclose(img.rgb[3, 4], [r, (g1 + g2) / 2, b], rtol=1e-6)
    assert not img.saturated.any() and not img.dead.any()
    demo = decode_raw(p, mode="demosaic")
    np.testing.assert_allclose(demo.rgb[0, 0, 0], r, rtol=1e-6)      # an R site keeps its own value
    np.testing.assert_allclose(demo.rgb[1, 1, 2], b, rtol=1e-6)      # a B site too


def test_white_level_does_not_move_with_the_content(tmp_path):
    """LibRaw's content-adjusted maximum must not leak in: a dark and a bright file scale alike."""
    dark = np.full((24, 24), 2000, np.uint16)
    bright = dark.copy()
    bright[:4, :4] = 16000
    a = decode_raw(write_dng(tmp_path / "dark.dng", dark, black_level=500, white_level=16383))
    b = decode_raw(write_dng(tmp_path / "bright.dng", bright, black_level=500, white_level=16383))
    assert a.white_level == b.white_level == 16383
    assert a.rgb[-1, -1, 1] == b.rgb[-1, -1, 1] == pytest.approx(1500 / 15883, rel=1e-6)


def test_levels_and_metadata_match_the_simulated_camera(shot):
    sensor = SensorModel()
    img = decode_raw(shot.path)
    assert img.black_levels == (sensor.black_level,) * 4 and img.white_level == sensor.white_level
    assert img.exposure_time == pytest.approx(shot.raw.exposure_time, rel=1e-9)
    assert img.iso == sensor.iso and (img.make, img.model) == (sensor.make, sensor.model)
    assert img.path == shot.path and img.mode == "bin2x2" and img.scale == 2
    np.testing.assert_allclose(img.as_shot_neutral, shot.raw.as_shot_neutral, rtol=1e-5)
    np.testing.assert_allclose(img.xyz_to_camera, shot.raw.color_matrix, atol=1e-5)


# ---------------------------------------------------------------------------------------------- linearity

def test_patch_means_follow_the_camera_signal_from_colour_science(shot):
    """Mean of each patch = radiance x Nikon D5100 sensitivities (colour-science's table, read directly)."""
    import colour

    sensor = SensorModel()
    grid = shot.frame.grid
    sens = colour.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"]
    s = np.array([sens[w] for w in grid.wavelengths])                # table values at the grid, no interpolation
    ohta = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    refl = np.array([[sd[w] for w in grid.wavelengths] for sd in ohta.values()])
    radiance = refl * shot.frame.light / math.pi
    signal = radiance @ (s * grid.step)                               # (24, 3)
    dn_per_signal = sensor.quantum_scale * shot.raw.exposure_time / sensor.gain_e_per_dn
    expected = signal * dn_per_signal / (sensor.white_level - sensor.black_level)
    img = decode_raw(shot.path)
    measured = np.array([img.rgb[_inside(shot.frame.labels, k)].mean(axis=0) for k in range(24)])
    # shot noise of a patch mean over >= 100 binned pixels is below 0.1 %; rounding to DN adds < 1e-4
    np.testing.assert_allclose(measured, expected, rtol=3e-3, atol=2e-4)
    # and proportional: one gain for all patches and channels
    ratio = measured[expected > 0.05] / expected[expected > 0.05]
    assert ratio.std() / ratio.mean() < 2e-3


# ---------------------------------------------------------------------------------------------- masks

def test_saturation_mask_matches_the_electrons_reaching_the_well(tmp_path):
    sensor = SensorModel()
    s = chart_shot(tmp_path, "classic24", width=120, height=80, exposure_boost=2.5)
    mu = s.raw.mean_electrons
    demo = decode_raw(s.path, mode="demosaic")
    binned = decode_raw(s.path, mode="bin2x2")
    well = sensor.well_e
    # Poisson noise at the well is 0.6 %: 5 % either side is beyond doubt
    sure, never = mu > 1.05 * well, mu < 0.95 * well
    assert sure.any() and never.any()
    photosite_sat = (s.raw.bayer >= sensor.white_level)
    assert photosite_sat[sure].all() and not photosite_sat[never].any()
    assert demo.saturated[sure].all()
    cell_sure = sure[0::2, 0::2] | sure[0::2, 1::2] | sure[1::2, 0::2] | sure[1::2, 1::2]
    cell_never = never[0::2, 0::2] & never[0::2, 1::2] & never[1::2, 0::2] & never[1::2, 1::2]
    assert binned.saturated[cell_sure].all() and not binned.saturated[cell_never].any()
    # a saturated pixel reads 1.0 in the channel whose photosite clipped
    r_sites = sure[0::2, 0::2]
    np.testing.assert_allclose(binned.rgb[..., 0][r_sites], 1.0)


def test_dead_photosites_are_masked_and_left_out(tmp_path):
    mosaic = np.full((24, 24), 4600, np.uint16)        # flat: 4000 DN over a black of 600
    mosaic[10, 10] = 0                                  # an R site (even, even) of RGGB
    mosaic[5, 6] = 0                                    # a G site (odd row, even col)
    p = write_dng(tmp_path / "dead.dng", mosaic, black_level=600, white_level=16383)
    flat = 4000 / (16383 - 600)
    b = decode_raw(p, mode="bin2x2")
    assert b.dead[5, 5] and b.dead.sum() == 1           # a dead R kills its cell; the dead G is replaced by its twin
    np.testing.assert_allclose(b.rgb[2, 3, 1], flat, rtol=1e-6)
    assert np.all(np.isfinite(b.rgb))
    d = decode_raw(p, mode="demosaic")
    assert d.dead[10, 10] and d.dead[5, 6]
    np.testing.assert_allclose(d.rgb[~d.dead], flat, rtol=1e-6)      # interpolation never uses a dead site
    # the dead R site has no other R sample within the bilinear kernel: masked, finite, not interpolated
    assert d.dead.sum() == 2 and np.all(np.isfinite(d.rgb))
    np.testing.assert_allclose(d.rgb[10, 10, 1:], flat, rtol=1e-6)


def test_binning_and_demosaic_agree_on_flat_patches(shot):
    b = decode_raw(shot.path, mode="bin2x2")
    d = decode_raw(shot.path, mode="demosaic")
    assert d.rgb.shape == (160, 240, 3) and b.rgb.shape == (80, 120, 3)
    for k in (0, 6, 13, 18, 21):
        core = shot.frame.labels == k
        # away from the patch edge, where the bilinear kernel mixes neighbours
        from scipy.ndimage import binary_erosion

        core = binary_erosion(core, iterations=2)
        np.testing.assert_allclose(d.rgb[core].mean(axis=0), b.rgb[_inside(shot.frame.labels, k)].mean(axis=0),
                                   rtol=3e-3, atol=2e-4)


@settings(max_examples=40, deadline=None)
@given(arrays(np.uint16, (6, 8), elements=st.integers(0, 4095)), st.integers(0, 400))
def test_extreme_mosaics_give_finite_bounded_values(mosaic, black):
    """Any mosaic from 0 to the white level: finite, within [-black/(white-black), 1], masks consistent."""
    from processing.camera.raw_decode import _normalised_mosaic

    white = 4095.0
    values, sat, dead = _normalised_mosaic(mosaic, np.full(4, float(black)), white, black > 16)
    assert np.all(np.isfinite(values)) and values.max() <= 1.0 and values.min() >= -black / (white - black) - 1e-6
    np.testing.assert_array_equal(sat, mosaic >= white)
    for fn in (bin2x2, bilinear_demosaic):
        rgb, s, d = fn(values, np.array([0, 1, 1, 2]), sat, dead)
        assert np.all(np.isfinite(rgb)) and rgb.max() <= 1.0 + 1e-6
        assert s.any() == sat.any()


# ---------------------------------------------------------------------------------------------- preview

def test_preview_balances_the_neutral_patches(shot):
    img = decode_raw(shot.path)
    prev = preview_srgb8(img)
    assert prev.dtype == np.uint8 and prev.shape == img.rgb.shape
    white = prev[_inside(shot.frame.labels, 18)].mean(axis=0)
    grey = prev[_inside(shot.frame.labels, 21)].mean(axis=0)
    assert np.ptp(white) < 6 and np.ptp(grey) < 6           # neutral: R = G = B within a few codes
    assert white.mean() > grey.mean() + 50
    # without the file's neutral, grey world still gives a usable (roughly balanced) preview
    img.as_shot_neutral = None
    again = preview_srgb8(img)[_inside(shot.frame.labels, 18)].mean(axis=0)
    assert np.ptp(again) < 40


# ---------------------------------------------------------------------------------------------- bad input

def test_missing_empty_and_folder(tmp_path):
    with pytest.raises(RawDecodeError, match="no such file"):
        decode_raw(tmp_path / "nothing.dng")
    (tmp_path / "empty.dng").write_bytes(b"")
    with pytest.raises(RawDecodeError, match="empty"):
        decode_raw(tmp_path / "empty.dng")
    with pytest.raises(RawDecodeError, match="folder"):
        decode_raw(tmp_path)


def test_images_that_are_not_raw(tmp_path):
    import tifffile
    from PIL import Image

    img = Image.fromarray(np.zeros((32, 32, 3), np.uint8))
    img.save(tmp_path / "shot.jpg", format="JPEG")
    img.save(tmp_path / "shot.png", format="PNG")
    tifffile.imwrite(tmp_path / "shot.tif", np.zeros((32, 32, 3), np.uint8), photometric="rgb")
    with pytest.raises(RawDecodeError, match="this is a JPEG, not a RAW file; give the camera's DNG/CR2/NEF/ARW"):
        decode_raw(tmp_path / "shot.jpg")
    with pytest.raises(RawDecodeError, match="this is a PNG, not a RAW file"):
        decode_raw(tmp_path / "shot.png")
    with pytest.raises(RawDecodeError, match="this is a TIFF image, not a RAW file"):
        decode_raw(tmp_path / "shot.tif")


def test_truncated_and_corrupt_raw(tmp_path, shot):
    data = shot.path.read_bytes()
    (tmp_path / "cut.dng").write_bytes(data[: len(data) // 2])
    with pytest.raises(RawDecodeError, match="corrupt or truncated"):
        decode_raw(tmp_path / "cut.dng")
    (tmp_path / "junk.nef").write_bytes(b"\x00\x01garbage" * 500)
    with pytest.raises(RawDecodeError, match="junk.nef"):
        decode_raw(tmp_path / "junk.nef")


def test_non_bayer_sensor_is_refused(tmp_path):
    """A linear (already demosaiced) DNG has three samples per pixel, no CFA."""
    import tifffile

    rgb = np.full((32, 32, 3), 1000, np.uint16)
    extratags = [(50706, 1, 4, (1, 4, 0, 0), True), (50717, 4, 1, 16383, True),
                 (50721, 10, 9, (1, 1, 0, 1, 0, 1, 0, 1, 1, 1, 0, 1, 0, 1, 0, 1, 1, 1), True),
                 (271, 2, 0, "Kogei", True), (272, 2, 0, "Linear", True)]
    tifffile.imwrite(tmp_path / "linear.dng", rgb, photometric=34892, planarconfig="contig", extratags=extratags,
                     subfiletype=0)
    with pytest.raises(RawDecodeError, match="not a 2 x 2 RGB Bayer mosaic"):
        decode_raw(tmp_path / "linear.dng")


def test_unknown_mode(shot):
    with pytest.raises(RawDecodeError, match="mode must be one of bin2x2, demosaic"):
        decode_raw(shot.path, mode="superres")


def test_sniffing_names_common_containers():
    assert sniff_format(b"\x89PNG\r\n\x1a\n....") == "PNG"
    assert sniff_format(b"\x00\x00\x00\x18ftypheic....") == "HEIF"
    assert sniff_format(b"\x00\x00\x00\x18ftypcrx ....") == "ISOBMFF"        # Canon CR3 goes on to LibRaw
    assert sniff_format(b"FUJIFILMCCD-RAW ") == "unknown"


@pytest.mark.parametrize("pattern", ["BGGR", "GRBG", "GBRG"])
def test_other_cfa_patterns_put_each_colour_in_its_channel(tmp_path, pattern):
    dn = {"R": 1600, "G": 3600, "B": 9600}
    mosaic = np.empty((24, 24), np.uint16)
    for k, letter in enumerate(pattern):
        mosaic[k // 2::2, k % 2::2] = dn[letter]
    p = write_dng(tmp_path / f"{pattern}.dng", mosaic, black_level=600, white_level=16383, cfa_pattern=pattern)
    for mode in ("bin2x2", "demosaic"):
        img = decode_raw(p, mode=mode)
        assert img.cfa_pattern == pattern
        np.testing.assert_allclose(img.rgb[3, 3], [(dn[c] - 600) / 15783 for c in "RGB"], rtol=1e-6)


def test_truncated_raw_prints_nothing_of_libraw_on_stderr(tmp_path, shot, capfd):
    """LibRaw prints "FILE: Unexpected end of file" from C on fd 2; kogei's one-line error carries it instead."""
    data = shot.path.read_bytes()
    (tmp_path / "cut.dng").write_bytes(data[: len(data) // 2])
    with pytest.raises(RawDecodeError) as info:
        decode_raw(tmp_path / "cut.dng")
    assert capfd.readouterr().err == ""
    assert "corrupt or truncated (LibRawIOError: Unexpected end of file); copy the file from the camera again" \
        in str(info.value)
    assert str(tmp_path / "cut.dng") not in str(info.value).split(": ", 1)[1]    # LibRaw's own prefix dropped
    img = decode_raw(shot.path)                                                  # a valid file: as before, and fd 2 back
    assert img.rgb.shape == (80, 120, 3)
    os.write(2, b"fd 2 restored\n")
    assert capfd.readouterr().err == "fd 2 restored\n"


def test_libraw_stderr_is_held_back_per_decode_across_threads(tmp_path, shot, capfd):
    """Decodes in worker threads (the window's) each keep their own message; fd 2 ends where it began."""
    from concurrent.futures import ThreadPoolExecutor

    data = shot.path.read_bytes()
    paths = []
    for i in range(4):
        paths.append(tmp_path / f"cut{i}.dng")
        paths[-1].write_bytes(data[: len(data) // 2])
        paths.append(shot.path)

    def one(p):
        try:
            return decode_raw(p).rgb.shape
        except RawDecodeError as exc:
            return str(exc)

    with ThreadPoolExecutor(4) as pool:
        results = list(pool.map(one, paths))
    assert capfd.readouterr().err == ""
    for p, r in zip(paths, results):
        assert r == (80, 120, 3) if p == shot.path else (r.startswith(f"{p}: ") and "Unexpected end of file" in r)
