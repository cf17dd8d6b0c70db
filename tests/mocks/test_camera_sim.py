"""Simulated camera: signals from real sensitivities, the noise model, clipping, exposure, metadata."""

from __future__ import annotations

import colour
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mocks.camera_sim import (
    CameraSimError,
    SensorModel,
    camera_sensitivities,
    channel_signal,
    expose,
    lens_blur,
    mosaic,
    simulate_raw,
    white_balance_neutral,
    xyz_to_camera_matrix,
)
from processing.spectral.spectra import SpectralGrid, light_spectrum, resample

GRID = SpectralGrid(400, 700, 5)


def _reference_rgb(reflectance_sd, illuminant_sd):
    """Independent 1-nm trapezoid integral of sensitivity x illuminant x reflectance over 400-700 nm."""
    wl = np.arange(400, 701, 1.0)
    s = colour.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"]
    sens = np.stack([np.interp(wl, s.wavelengths, s.values[:, c]) for c in range(3)], axis=1)
    e = np.interp(wl, illuminant_sd.wavelengths, illuminant_sd.values)
    r = np.interp(wl, reflectance_sd.wavelengths, reflectance_sd.values)
    return np.trapezoid(sens * (e * r)[:, None], wl, axis=0)


@pytest.mark.parametrize("patch", ["neutral 5 (.70 D)", "red", "blue"])
def test_raw_ratios_match_the_integral(patch):
    sd = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"][patch]
    e = light_spectrum("D65", GRID)
    refl = resample(sd.wavelengths, sd.values, GRID)
    radiance = np.broadcast_to(refl * e / np.pi * 0.01, (64, 64, GRID.size))
    sensor = SensorModel(read_noise_e=2.0)
    frame = simulate_raw(radiance, GRID, e, sensor=sensor, exposure_s=0.01, seed=1)
    raw = frame.bayer.astype(np.float64) - frame.black_level
    means = np.array([raw[0::2, 0::2].mean(), 0.5 * (raw[0::2, 1::2].mean() + raw[1::2, 0::2].mean()),
                      raw[1::2, 1::2].mean()])
    ref = _reference_rgb(sd, colour.SDS_ILLUMINANTS["D65"])
    assert np.allclose(means / means[1], ref / ref[1], rtol=0.01)
    # absolute level: electrons = signal x quantum_scale x t, DN = e / gain
    unit = e[(560 - 400) // 5] / colour.SDS_ILLUMINANTS["D65"][560]     # the two D65 tables' scales
    expected_g = unit * ref[1] / np.pi * 0.01 * sensor.quantum_scale * 0.01 / sensor.gain_e_per_dn
    assert means[1] == pytest.approx(expected_g, rel=0.01)


def test_noise_matches_shot_plus_read_model():
    sensor = SensorModel(read_noise_e=6.0, gain_e_per_dn=2.5)
    signal = np.full((300, 300), 0.4)           # mean 0.4 x 2.2e6 x 0.01 = 8800 e
    dn, mu = expose(signal, sensor, 0.01, np.random.default_rng(3))
    x = dn.astype(np.float64) - sensor.black_level
    g = sensor.gain_e_per_dn
    assert x.mean() == pytest.approx(mu.mean() / g, rel=2e-3)
    var_model = mu.mean() / g**2 + (sensor.read_noise_e / g) ** 2 + 1 / 12
    # sample variance of n = 90000 values has relative standard error sqrt(2/n) = 0.5 %
    assert x.var(ddof=1) == pytest.approx(var_model, rel=0.03)


def test_dark_frame_is_read_noise_only():
    sensor = SensorModel(read_noise_e=8.0, gain_e_per_dn=2.0, black_level=1024)
    dn, _ = expose(np.zeros((200, 200)), sensor, 0.01, np.random.default_rng(5))
    x = dn.astype(np.float64)
    assert x.mean() == pytest.approx(1024, abs=0.1)
    assert x.var(ddof=1) == pytest.approx((8.0 / 2.0) ** 2 + 1 / 12, rel=0.05)


def test_clipping_at_white_level_and_saturation_fault():
    sensor = SensorModel(bits=12, black_level=256, read_noise_e=3.0)
    grid = SpectralGrid(400, 700, 20)
    radiance = np.full((32, 32, grid.size), 0.0005)
    normal = simulate_raw(radiance, grid, np.ones(grid.size), sensor=sensor, seed=0)
    boosted = simulate_raw(radiance, grid, np.ones(grid.size), sensor=sensor, seed=0, exposure_boost=1000.0)
    assert normal.white_level == 4095 and normal.bayer.max() < 4095
    assert np.all(boosted.bayer == 4095)
    assert boosted.bayer.dtype == np.uint16


def test_exposure_time_scales_the_signal():
    sensor = SensorModel(read_noise_e=0.0)
    sig = np.full((100, 100), 0.2)
    a, _ = expose(sig, sensor, 0.005, np.random.default_rng(0))
    b, _ = expose(sig, sensor, 0.010, np.random.default_rng(1))
    ma, mb = (v.astype(np.float64).mean() - sensor.black_level for v in (a, b))
    assert mb / ma == pytest.approx(2.0, rel=0.01)


@settings(max_examples=20, deadline=None)
@given(level=st.floats(0, 50), bits=st.sampled_from([12, 14]), t=st.floats(1e-5, 1.0))
def test_raw_always_within_levels(level, bits, t):
    sensor = SensorModel(bits=bits, black_level=64)
    dn, _ = expose(np.full((4, 4), level), sensor, t, np.random.default_rng(0))
    assert dn.min() >= 0 and dn.max() <= sensor.white_level


def test_mosaic_positions():
    rgb = np.zeros((4, 4, 3))
    rgb[..., 0], rgb[..., 1], rgb[..., 2] = 1, 2, 3
    assert mosaic(rgb, "BGGR")[:2, :2].tolist() == [[3, 2], [2, 1]]
    assert mosaic(rgb, "GRBG")[:2, :2].tolist() == [[2, 1], [3, 2]]


def test_sensitivities_follow_colour_science():
    s = camera_sensitivities(GRID)
    ref = colour.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"]
    i = int(np.flatnonzero(ref.wavelengths == 550)[0])
    assert np.allclose(s[(550 - 400) // 5], ref.values[i])


def test_color_matrix_maps_white_and_fits_the_chart():
    m = xyz_to_camera_matrix(GRID)
    wp = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]
    xyz_w = colour.xy_to_XYZ(wp)
    cam_w = m @ xyz_w
    assert cam_w.max() == pytest.approx(1.0, abs=0.01)
    # the fitted matrix predicts chart camera RGB (relative to the white's largest channel) from XYZ (white Y = 1)
    chart = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    d65 = colour.SDS_ILLUMINANTS["D65"]
    white = _reference_rgb(colour.SpectralDistribution(np.ones(301), np.arange(400, 701)), d65).max()
    for sd in list(chart.values())[::3]:
        with colour.utilities.suppress_warnings(colour_runtime_warnings=True):
            xyz = colour.sd_to_XYZ(sd, cmfs, d65) / 100
        assert np.allclose(m @ xyz, _reference_rgb(sd, d65) / white, atol=0.03)


def test_white_balance_neutral():
    e = light_spectrum("A", GRID)
    n = white_balance_neutral(e, GRID)
    ref = _reference_rgb(colour.SpectralDistribution(np.ones(301), np.arange(400, 701)), colour.SDS_ILLUMINANTS["A"])
    assert np.allclose(n, ref / ref.max(), rtol=0.01)


@pytest.mark.parametrize(
    "call, words",
    [
        (lambda: channel_signal(np.ones(5), GRID), "wavelengths of the grid"),
        (lambda: channel_signal(np.full(GRID.size, np.nan), GRID), "finite"),
        (lambda: channel_signal(np.ones(GRID.size), GRID, "No Such Camera"), "unknown camera"),
        (lambda: expose(np.ones((2, 2)), SensorModel(), 0.0, np.random.default_rng()), "exposure_s"),
        (lambda: expose(-np.ones((2, 2)), SensorModel(), 0.01, np.random.default_rng()), "non-negative"),
        (lambda: mosaic(np.ones((3, 4, 3))), "even"),
        (lambda: SensorModel(bits=10), "bits"),
        (lambda: SensorModel(black_level=5000, bits=12), "black_level"),
        (lambda: SensorModel(gain_e_per_dn=0), "gain_e_per_dn"),
        (lambda: SensorModel(cfa_pattern="RGB"), "cfa_pattern"),
        (lambda: simulate_raw(np.ones((4, GRID.size)), GRID, np.ones(GRID.size)), r"\(H, W, L\)"),
        (lambda: lens_blur(np.ones((4, 4)), -1.0), "sigma_px"),
        (lambda: lens_blur(np.ones((4, 4)), float("nan")), "sigma_px"),
        (lambda: lens_blur(np.ones(4)), r"\(H, W\)"),
    ],
)
def test_bad_input(call, words):
    with pytest.raises(CameraSimError, match=words):
        call()


def test_the_lens_lets_a_one_photosite_glint_reach_every_colour_of_its_cfa_cell():
    """Why the simulated camera has a lens: through a pinhole a glint one photosite wide lights one colour of its
    RGGB cell (false colour no demosaic undoes); spread by a Gaussian of one photosite every colour sees it, and the
    spread conserves the light."""
    white = np.ones(GRID.size)
    glint = np.zeros((16, 16, GRID.size))
    glint[8, 8] = 50.0 * white                                   # a red site of the RGGB mosaic (even row, even column)
    sharp = mosaic(channel_signal(glint, GRID))
    spread = mosaic(channel_signal(lens_blur(glint, 1.0), GRID))
    cell = (slice(8, 10), slice(8, 10))
    assert np.count_nonzero(sharp[cell]) == 1
    assert np.all(spread[cell] > 0.05 * spread[cell].max())
    assert lens_blur(glint, 1.0).sum() == pytest.approx(glint.sum(), rel=1e-9)
    assert np.array_equal(lens_blur(glint, 0.0), glint)          # 0: a pinhole


@pytest.mark.parametrize("shape", [(1, 1), (4, 4), (2, 2, 3), (3, 7, 1), (40, 30, 31), (5, 6, 600)])
@pytest.mark.parametrize("sigma_px", [1e-9, 0.3, 1.0, 2.5])
def test_the_lens_is_scipys_gaussian_over_the_image_plane(shape, sigma_px):
    """The reference: SciPy's Gaussian filter with edges extended by their nearest pixel, along the two image
    axes only, at any size (smaller than the kernel too) and any channel count (above OpenCV's 512 too)."""
    from scipy.ndimage import gaussian_filter

    img = np.random.default_rng(7).random(shape) * 1e3
    ref = gaussian_filter(img, sigma=(sigma_px, sigma_px) + (0.0,) * (img.ndim - 2), mode="nearest")
    out = lens_blur(img, sigma_px)
    assert out.shape == img.shape and out.dtype == np.float64
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-12 * 1e3)
    assert lens_blur(np.zeros((0, 5, 3)), 1.0).shape == (0, 5, 3)
