"""One image's identification told what the sensor and the chart transform do to a region's colour.

Ground truth: the candidates' own forward model (so only the sensor and the transform stand between the
truth and the pixels) and the reliability bench's simulated clicks (``bench/reliability.py``: a
colour-science camera shifted and widened, a ColorChecker 3 x 3, a Bayer sensor with read noise and the
``bin2x2`` decode).

* An error that arises in the sensor's channels (1.75 % per channel, the default model error) and goes
  through a transform that takes differences of large channels: told the transform, the true candidate's
  chi-square follows its 2 degrees of freedom (mean 2 over 400 draws: the mean of 400 chi-square(2) values
  has a standard error of 0.1, so 1.5-2.6 is five of them); not told, it is several times larger.
* Metals whose usable pixels lie at the read-noise floor read red after the transform; told the read
  noise, none is named urushi-red with confidence >= 0.9 (the bench's seed 911 is one the identification
  not told named urushi-red at 0.95).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from processing.camera.response import camera_sensitivities, channel_matrix
from processing.camera.transfer import transformed_read_noise
from processing.materials.identification import DEFAULT_MODEL_ERROR, candidate_set, identify_material
from processing.materials.lobes import material_brdf
from processing.materials.presets import get_material
from processing.spectral.estimation.fit import SpectralEstimationError
from processing.spectral.spectra import SpectralGrid, light_spectrum

GRID = SpectralGrid(400, 700, 10)
E = light_spectrum("D65", GRID)
SENS = camera_sensitivities(GRID)
CANDS = candidate_set(SENS, E, GRID)
#: A row-form chart transform whose model blue is a difference of large channels (as for the Sigma camera).
M = np.array([[1.07, -1.37, 0.40], [-0.39, 1.71, -1.53], [0.15, -0.31, 1.64]])


def _colour(name: str) -> np.ndarray:
    t = math.radians(30.0)
    signal = material_brdf(get_material(name), math.cos(t), 1.0, math.cos(t / 2), math.cos(t / 2),
                           GRID.wavelengths) * (math.pi * math.cos(t))
    return signal @ channel_matrix(SENS, E, GRID)


def test_an_error_of_the_sensor_channels_carried_by_the_transform_is_weighed_right():
    rng = np.random.default_rng(0)
    truth = _colour("nami-shibuichi")
    i = CANDS.names.index("nami-shibuichi")
    raw_truth = truth @ np.linalg.inv(M)
    told, blind = [], []
    for _ in range(400):
        raw = raw_truth * (1.0 + DEFAULT_MODEL_ERROR * rng.standard_normal(3))     # the region's colour error
        px = np.tile(raw, (50, 1)) * (1.0 + 1e-4 * rng.standard_normal((50, 3))) @ M
        told.append(identify_material(px, CANDS, noise=1e-4, transform=M).chi2[i])
        blind.append(identify_material(px, CANDS, noise=1e-4).chi2[i])
    # told the transform, the true material's chi-square averages its 2 degrees of freedom (3 channels, one
    # fitted scale); over 400 draws the mean's own spread is about 0.1, and the band leaves room for the
    # linearised error model.  Blind to the transform, the blue channel's amplified error inflates it.
    mean_told = float(np.mean(told))
    assert mean_told >= 1.5 and mean_told <= 2.6, mean_told
    assert np.mean(blind) > 3 * np.mean(told)


def test_identity_transform_changes_nothing_and_bad_transforms_are_refused():
    px = np.tile(_colour("gold"), (20, 1)) * (1 + 0.01 * np.random.default_rng(1).standard_normal((20, 3)))
    a, b = identify_material(px, CANDS), identify_material(px, CANDS, transform=np.eye(3))
    assert np.allclose(a.chi2, b.chi2) and a.material == b.material == "gold"
    with pytest.raises(SpectralEstimationError, match="transform must be"):
        identify_material(px, CANDS, transform=np.zeros((3, 3)))
    with pytest.raises(SpectralEstimationError, match="dark_noise must be"):
        identify_material(px, CANDS, dark_noise=np.ones((2, 2)))


def test_a_well_lit_patch_keeps_its_confident_answer():
    for name, answer in (("gold", "gold"), ("urushi-red", "urushi-red")):
        raw = np.tile(_colour(name) @ np.linalg.inv(M), (100, 1))
        raw *= 0.2 / raw[:, 1].mean()
        px = np.maximum(raw * (1 + 0.005 * np.random.default_rng(2).standard_normal(raw.shape)), 0) @ M
        found = identify_material(px, CANDS, dark_noise=transformed_read_noise(M, 5e-4), transform=M)
        assert found.material == answer and found.confidence >= 0.9, (name, found)


def test_metal_clicks_at_the_read_noise_floor_are_not_called_urushi_red():
    br = pytest.importorskip("bench.reliability")
    pytest.importorskip("colour")
    from processing.spectral.reflectance_database import load_reflectances

    chart = load_reflectances("colorchecker", GRID).spectra
    metals = ["silver", "aluminium", "platinum", "copper", "nami-shibuichi", "tin", "gold"]
    fooled = wrong = 0
    for seed in range(900, 960):
        rng = np.random.default_rng(seed)
        truth = metals[seed % len(metals)]
        sens, _ = br._true_camera(rng, GRID)
        t = br._chart_transform(rng, sens, SENS, E, chart, GRID)
        drawn = br._highlight_patch(rng, br._true_material(rng, truth), E, sens, t, GRID, br.COLOUR_ERROR)
        if drawn is None:
            continue
        px, err, _ = drawn
        try:
            blind = identify_material(px, CANDS, colour_error=err)
        except SpectralEstimationError:
            continue
        told = identify_material(px, CANDS, colour_error=err, transform=t,
                                 dark_noise=transformed_read_noise(t, br.READ_NOISE))
        fooled += blind.material == "urushi-red" and blind.confidence >= 0.9
        wrong += told.material == "urushi-red" and told.confidence >= 0.9
    assert fooled >= 1          # the mechanism is in these draws
    assert wrong == 0
