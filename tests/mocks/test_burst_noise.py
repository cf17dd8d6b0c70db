"""Bursts of the simulated camera: every shot at one view has its own sensor noise, shot 0 the old one.

Physics reference: the sensor model's variance per photosite in DN, ``mu_e / g^2 + (read_e / g)^2 +
1/12`` (shot noise, read noise, quantisation; ``mocks.camera_sim.expose``).  Two shots of one view
then differ by noise of twice that variance, and the linear mean of N shots keeps 1/N of it.
"""

from __future__ import annotations

import numpy as np
import pytest

from mocks.camera_sim import SensorModel, simulate_raw
from mocks.noise_seed import angle_key, frame_seed, stable_seed
from processing.spectral.spectra import SpectralGrid

GRID = SpectralGrid(400, 700, 20)
SENSOR = SensorModel()


def _shots(n: int, size: int = 256, level: float = 0.002) -> np.ndarray:
    """``n`` shots (n, size, size) in DN above black of one flat grey view, burst shots 0 .. n-1."""
    radiance = np.full((size, size, GRID.size), level)
    return np.stack([simulate_raw(radiance, GRID, np.ones(GRID.size), sensor=SENSOR, exposure_s=0.01,
                                  seed=frame_seed(7, 1, "object", 60.0, shot=j)).bayer.astype(np.float64)
                     - SENSOR.black_level for j in range(n)])


def _model_variance(mean_dn: np.ndarray) -> np.ndarray:
    g = SENSOR.gain_e_per_dn
    return mean_dn * g / g**2 + (SENSOR.read_noise_e / g) ** 2 + 1.0 / 12.0


def _site_residual(img: np.ndarray) -> np.ndarray:
    """A flat view's noise: each photosite less the mean of its Bayer site (R, G, G, B levels differ)."""
    out = img.copy()
    for i in (0, 1):
        for j in (0, 1):
            out[i::2, j::2] -= img[i::2, j::2].mean()
    return out


def test_shot_zero_keeps_the_seed_of_a_frame_without_a_burst():
    # the seed a frame had before bursts existed: byte-identical frames for sessions without a burst
    assert frame_seed(3, 2, "object", 90.0) == stable_seed("frame", 3, 2, "object", angle_key(90.0))
    assert frame_seed(3, 2, "object", 90.0, shot=0) == frame_seed(3, 2, "object", 90.0)
    seeds = {frame_seed(3, 2, "object", 90.0, shot=j) for j in range(16)}
    assert len(seeds) == 16
    with pytest.raises(ValueError, match="shot"):
        frame_seed(3, 2, "object", 90.0, shot=-1)


def test_two_shots_differ_by_independent_noise():
    a, b = _shots(2)
    assert not np.array_equal(a, b)
    expected = 2.0 * _model_variance(0.5 * (a + b)).mean()
    # n = 65536 differences: the variance's relative standard error is sqrt(2/n) = 0.6 %; 4 % allows the
    # model's approximations (quantisation as uniform) with a margin.
    assert np.mean((a - b) ** 2) == pytest.approx(expected, rel=0.04)
    # independent, not merely different: the two shots' noise is uncorrelated (|r| < 4 sigma = 4/sqrt(n))
    r = np.corrcoef(_site_residual(a).ravel(), _site_residual(b).ravel())[0, 1]
    assert abs(r) < 4.0 / np.sqrt(a.size)


@pytest.mark.parametrize("n", [4, 16])
def test_the_mean_of_a_burst_has_the_noise_over_sqrt_n(n):
    shots = _shots(n, size=128)
    single = shots[0]
    mean = shots.mean(axis=0)

    def channel_variance(img: np.ndarray) -> float:      # a flat view: the spread within each Bayer site
        return float(np.mean([img[i::2, j::2].var(ddof=1) for i in (0, 1) for j in (0, 1)]))

    v1 = _model_variance(single.mean()).item()
    assert channel_variance(single) == pytest.approx(v1, rel=0.06)
    # 4 x 4096 samples per estimate: relative standard error about 1 %; 6 % tolerance
    assert channel_variance(mean) == pytest.approx(v1 / n, rel=0.06)
    assert np.sqrt(channel_variance(mean) / channel_variance(single)) == pytest.approx(1 / np.sqrt(n), rel=0.04)
