"""The luminance bounds of a camera's metamer set, against physics: the truth is always inside, a camera
meeting the Luther condition leaves no doubt, and the bounds scale with the light."""

from __future__ import annotations

import numpy as np
import pytest

from processing.camera.response import camera_sensitivities
from processing.spectral.checks import SpectralEstimationError
from processing.spectral.estimation.metamer_set import luminance_range
from processing.spectral.reflectance_database import load_reflectances
from processing.spectral.spectra import SpectralGrid, cmfs, light_spectrum

G = SpectralGrid(400, 700, 10)


def _luminance(rho: np.ndarray, light: np.ndarray) -> np.ndarray:
    return rho * light @ cmfs(G)[:, 1] * G.step


def test_the_true_luminance_lies_within_the_bounds_for_a_real_camera():
    sens = camera_sensitivities(G, "Nikon 5100 (NPL)")
    light = light_spectrum("D65", G)
    refl = load_reflectances("colorchecker", G).spectra
    lo, hi = luminance_range(refl * light @ sens * G.step, sens, light, G, upper=1.0)
    y = _luminance(refl, light)
    # each reflectance is itself a metamer of its camera values: inside the bounds up to the solver's tolerance
    assert np.all(lo <= y * (1 + 1e-7)) and np.all(hi >= y * (1 - 1e-7))
    # and the camera does not meet the Luther condition: the bounds are open, widest for coloured patches
    assert np.all(hi - lo > 0.01 * y)


def test_a_camera_that_sees_xyz_leaves_no_doubt():
    light = light_spectrum("A", G)
    refl = load_reflectances("colorchecker", G).spectra[:6]
    camera = cmfs(G) @ np.array([[1.0, 0.2, 0.0], [0.0, 0.9, 0.1], [0.3, 0.0, 1.1]])  # any invertible mix of X, Y, Z
    lo, hi = luminance_range(refl * light @ camera * G.step, camera, light, G, upper=1.0)
    np.testing.assert_allclose(lo, _luminance(refl, light), rtol=1e-6)
    np.testing.assert_allclose(hi, _luminance(refl, light), rtol=1e-6)


@pytest.mark.parametrize("scale", [1e-9, 1e6])
def test_without_an_upper_bound_the_bounds_scale_with_the_values(scale):
    sens = camera_sensitivities(G, "Nikon 5100 (NPL)")
    flat = np.ones(G.size)
    values = load_reflectances("colorchecker", G).spectra[[14, 12]] @ sens * G.step
    lo1, hi1 = luminance_range(values, sens, flat, G)
    lo, hi = luminance_range(values * scale, sens, flat, G)
    np.testing.assert_allclose(lo, lo1 * scale, rtol=1e-6)
    np.testing.assert_allclose(hi, hi1 * scale, rtol=1e-6)


def test_a_smaller_set_of_spectra_gives_narrower_bounds():
    sens = camera_sensitivities(G, "Nikon 5100 (NPL)")
    light = light_spectrum("D65", G)
    refl = load_reflectances("colorchecker", G).spectra
    smooth = np.linalg.svd(load_reflectances("training", G).spectra, full_matrices=False)[2][:8]
    values = refl[[14, 12, 22]] * light @ sens * G.step
    lo_any, hi_any = luminance_range(values, sens, light, G)
    lo_s, hi_s = luminance_range(values, sens, light, G, basis=smooth)
    assert np.all(lo_s >= lo_any * (1 - 1e-7)) and np.all(hi_s <= hi_any * (1 + 1e-7))
    assert np.all(hi_s - lo_s < hi_any - lo_any)


def test_values_no_spectrum_can_give_have_no_bounds():
    sens = camera_sensitivities(G, "Nikon 5100 (NPL)")
    lo, hi = luminance_range([[-1.0, 1.0, 1.0], [1.0, 1.0, 1.0]], sens, np.ones(G.size), G)
    assert np.isnan(lo[0]) and np.isnan(hi[0])
    assert np.isfinite(lo[1]) and np.isfinite(hi[1]) and hi[1] >= lo[1]


@pytest.mark.parametrize("kwargs, words", [
    ({"camera_values": [[1.0, 2.0]]}, "3 channels"),
    ({"camera_values": [[1.0, np.nan, 2.0]]}, "finite"),
    ({"light": np.ones(5)}, "light must be"),
    ({"sensitivities": np.ones((5, 3))}, "sensitivities must be"),
    ({"sensitivities": np.c_[np.ones(G.size), np.ones(G.size), np.zeros(G.size)]}, "sees none"),
])
def test_bad_input_is_one_clear_error(kwargs, words):
    args = {"camera_values": [[1.0, 1.0, 1.0]], "sensitivities": camera_sensitivities(G, "Nikon 5100 (NPL)"),
            "light": np.ones(G.size)}
    args.update(kwargs)
    with pytest.raises(SpectralEstimationError, match=words):
        luminance_range(args["camera_values"], args["sensitivities"], args["light"], G)
