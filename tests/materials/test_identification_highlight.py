"""One image's identification where one image cannot tell: a few-pixel highlight through a Bayer sensor.

Ground truth: the simulated material's colour forward-modelled into the model camera (the candidates' own
model, so only the sensor's colour filter pattern and its 2 x 2 binning stand between the truth and the
pixels).  A grey nami-shibuichi highlight a few pixels across reads gold-coloured on its flank (red
sampled nearer the peak, blue farther); the identification, told the predicted fringe
(:func:`processing.camera.cfa_fringe.cfa_fringe`), must not name gold with confidence; a well-lit flat
gold patch must still be named gold with confidence.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from processing.camera.cfa_fringe import cfa_fringe
from processing.camera.raw_decode import bin2x2
from processing.camera.response import camera_sensitivities, channel_matrix
from processing.materials.identification import candidate_set, identify_material
from processing.materials.lobes import material_brdf
from processing.materials.presets import get_material
from processing.spectral.estimation.fit import SpectralEstimationError
from processing.spectral.spectra import SpectralGrid, light_spectrum

GRID = SpectralGrid(400, 700, 10)
E = light_spectrum("D65", GRID)
SENS = camera_sensitivities(GRID)
CANDS = candidate_set(SENS, E, GRID)


def _colour(name: str) -> np.ndarray:
    t = math.radians(30.0)
    signal = material_brdf(get_material(name), math.cos(t), 1.0, math.cos(t / 2), math.cos(t / 2),
                           GRID.wavelengths) * (math.pi * math.cos(t))
    return signal @ channel_matrix(SENS, E, GRID)


def _binned(colour: np.ndarray, level: np.ndarray, rng: np.random.Generator, noise: float = 0.005) -> np.ndarray:
    """An RGGB sensor's photosites of ``colour * level`` with relative noise, binned 2 x 2 by the decode."""
    raw = colour[None, None, :] * level[..., None]
    raw = raw * (0.6 / raw[..., 1].max())
    cfa = np.zeros(level.shape, np.intp)
    cfa[0::2, 1::2] = cfa[1::2, 0::2] = 1
    cfa[1::2, 1::2] = 2
    mosaic = np.take_along_axis(raw, cfa[..., None], axis=2)[..., 0]
    mosaic = mosaic * (1 + noise * rng.standard_normal(mosaic.shape))
    no = np.zeros(level.shape, bool)
    rgb, _, _ = bin2x2(mosaic.astype(np.float32), np.array([0, 1, 1, 2]), no, no)
    return rgb.astype(np.float64)


def test_a_grey_highlight_is_not_called_gold_confidently_but_a_clean_gold_patch_is():
    rng = np.random.default_rng(3)
    yy, xx = np.mgrid[0:40, 0:40] + 0.5
    level = np.exp(-((yy - 12.0) ** 2 + (xx - 20.0) ** 2) / (2 * 2.5**2))      # a highlight of 2.5 photosites
    rgb = _binned(_colour("nami-shibuichi"), level, rng)
    fringe = cfa_fringe(rgb, "RGGB")
    # the 5 x 5 click just below the peak, where the brightness falls fastest (as a user clicks a highlight)
    win = (slice(6, 11), slice(8, 13))
    px, err = rgb[win].reshape(-1, 3), fringe[win].reshape(-1, 3)
    blind = identify_material(px, CANDS)
    told = identify_material(px, CANDS, colour_error=err)
    assert blind.material == "gold"              # the fringe really moves grey toward gold's colour
    assert not (told.material == "gold" and told.confidence >= 0.9)
    assert told.confidence < 0.9 and "nami-shibuichi" in told.group           # a short list holding the truth

    flat = _binned(_colour("gold"), np.ones((40, 40)), rng)
    found = identify_material(flat.reshape(-1, 3), CANDS, colour_error=cfa_fringe(flat, "RGGB").reshape(-1, 3))
    assert found.material == "gold" and found.confidence >= 0.9


def test_colour_error_of_the_wrong_size_or_not_finite_is_refused():
    px = np.tile(_colour("gold"), (4, 1))
    with pytest.raises(SpectralEstimationError, match="colour_error must hold"):
        identify_material(px, CANDS, colour_error=np.zeros((3, 3)))
    with pytest.raises(SpectralEstimationError, match="colour_error must hold"):
        identify_material(px, CANDS, colour_error=np.full((4, 3), np.nan))


def test_a_black_region_is_refused():
    with pytest.raises(SpectralEstimationError, match="black in every channel"):
        identify_material(np.zeros((25, 3)), CANDS)
