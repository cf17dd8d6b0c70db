"""Camera response: sensitivities by name or CSV, the channel matrix, camera RGB against an independent integral."""

from __future__ import annotations

import colour
import numpy as np
import pytest

from processing.camera.response import (
    CameraResponseError,
    camera_rgb,
    camera_sensitivities,
    channel_matrix,
)
from processing.spectral.spectra import SpectralGrid, light_spectrum, resample

GRID = SpectralGrid(400, 700, 5)


def test_camera_rgb_matches_a_1nm_integral_of_colour_science_tables():
    sd = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]["orange"]
    wl = np.arange(400, 701, 1.0)
    s = colour.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"]
    sens = np.stack([np.interp(wl, s.wavelengths, s.values[:, c]) for c in range(3)], axis=1)
    d65 = colour.SDS_ILLUMINANTS["D65"]
    ref = np.trapezoid(sens * (np.interp(wl, d65.wavelengths, d65.values)
                               * np.interp(wl, sd.wavelengths, sd.values))[:, None], wl, axis=0)
    e = light_spectrum("D65", GRID)
    got = camera_rgb(resample(sd.wavelengths, sd.values, GRID), e, camera_sensitivities(GRID), GRID)
    unit = e[(560 - 400) // 5] / d65[560]          # the two D65 tables' scales
    assert np.allclose(got, unit * ref, rtol=0.01)


def test_two_lights_give_six_channels_each_the_single_light_response():
    s = camera_sensitivities(GRID)
    d65, a = light_spectrum("D65", GRID), light_spectrum("A", GRID)
    refl = np.linspace(0.1, 0.8, GRID.size)
    six = camera_rgb(refl, np.stack([d65, a]), s, GRID)
    assert six.shape == (6,)
    assert np.allclose(six[:3], camera_rgb(refl, d65, s, GRID))
    assert np.allclose(six[3:], camera_rgb(refl, a, s, GRID))


def test_sensitivities_from_csv_equal_the_named_camera(tmp_path):
    m = colour.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"]
    path = tmp_path / "cam.csv"
    rows = ["nm,r,g,b"] + [f"{w},{r},{g},{b}" for w, (r, g, b) in zip(m.wavelengths, m.values)]
    path.write_text("\n".join(rows))
    assert np.allclose(camera_sensitivities(GRID, path), camera_sensitivities(GRID))
    assert np.allclose(camera_sensitivities(GRID, str(path)), camera_sensitivities(GRID))


@pytest.mark.parametrize(
    "text, words",
    [
        ("nm,r,g,b\n400,1,1,1\n500,1,x,1\n", "line 3"),
        ("400,1,1,1\n500,1,1\n", "line 2: expected 4 columns"),
        ("400,1,1,1\n500,1,-1,1\n", "line 2, column 3"),
        ("400,1,1,1\n390,1,1,1\n", "does not increase"),
        ("400,1,nan,1\n500,1,1,1\n", "NaN"),
        ("400,1,1,1\n", "at least two"),
    ],
)
def test_bad_csv_names_line_and_column(tmp_path, text, words):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(CameraResponseError, match=words):
        camera_sensitivities(SpectralGrid(400, 500, 50), path)


@pytest.mark.parametrize(
    "call, words",
    [
        (lambda: camera_sensitivities(GRID, "No Such Camera"), "unknown camera"),
        (lambda: camera_sensitivities(SpectralGrid(360, 700, 5)), "must lie inside"),
        (lambda: camera_rgb(np.ones(5), np.ones(GRID.size), np.ones((GRID.size, 3)), GRID), "last axis"),
        (lambda: camera_rgb(np.full(GRID.size, np.nan), np.ones(GRID.size), np.ones((GRID.size, 3)), GRID), "finite"),
        (lambda: camera_rgb(-np.ones(GRID.size), np.ones(GRID.size), np.ones((GRID.size, 3)), GRID), ">= 0"),
        (lambda: camera_rgb(np.ones((0, GRID.size)), np.ones(GRID.size), np.ones((GRID.size, 3)), GRID), "empty"),
        (lambda: channel_matrix(np.ones((GRID.size, 3)), np.zeros(GRID.size), GRID), "not all zero"),
        (lambda: channel_matrix(np.ones((4, 3)), np.ones(GRID.size), GRID), "sensitivities must be"),
    ],
)
def test_bad_input_raises_a_clear_error(call, words):
    with pytest.raises(CameraResponseError, match=words):
        call()
