"""The swatch chart gains are unbiased in every channel: noisy chart frames average to the noise-free gain.

The simulated chart frame's noise-free signal gives the same gain in R, G and B (the model, camera and
binning agree; ``tests/integration/test_swatch_chain.py``).  A systematic departure of one channel -- 2 x 2 binning mixing
neighbouring patches at the sampling window's edge differently per CFA colour, a skewed estimator at low
counts, dark patches near the black level, the choice of patches -- would survive averaging over many
exposures, while pixel noise (EMVA Standard 1288, release 4.0: shot, read and quantisation noise, zero-mean
in the linear signal) averages away as one over the square root of the frame count.  The frames go through
the whole chain a session uses: simulated exposure, DNG, ``bin2x2`` decode, ``grid_chart_means``,
``chart_gains``.
"""

from __future__ import annotations

import numpy as np

from mocks.camera_sim import SensorModel, simulate_raw, write_raw
from mocks.swatch_world import SwatchWorld
from processing.camera.raw_decode import decode_raw
from processing.cloth.fit import chart_gains, grid_chart_means
from processing.cloth.swatch_geometry import SwatchGeometry

COTTON = ("cotton:a_t=0.3,a_b=0.6,weft_a_t=0.3,weft_a_b=0.6,specular=0.08,internal=0.15,diffuse=0.7,"
          "warp_colour=#c08040,weft_colour=#c08040")
W, H = 96, 72                 # the end-to-end cotton runs' frame size
FRAMES = 60


def _binned(a: np.ndarray) -> np.ndarray:
    """Same-colour photosites of each RGGB cell: R, mean of the two G, B (the decoder's 2 x 2 binning)."""
    return np.stack([a[0::2, 0::2], (a[0::2, 1::2] + a[1::2, 0::2]) / 2, a[1::2, 1::2]], axis=-1)


def test_noisy_chart_frames_average_to_the_noise_free_gain(tmp_path):
    # the simulated chart frame does not depend on the lamp direction, so one lamp covers both passes of a
    # swatch session (the cotton runs' second lamp is at (0, 0.866, 0.5))
    world = SwatchWorld.swatch(COTTON, width=W, height=H)
    geometry = SwatchGeometry.from_dict(world.geometry())
    chart = world.frame("chart", 0.0)
    world.light_direction = (0.0, 0.866, 0.5)
    np.testing.assert_array_equal(world.frame("chart", 0.0).radiance, chart.radiance)
    first = simulate_raw(chart.radiance, chart.grid, chart.light, seed=1)
    # the noise-free signal in the decoder's units (DN above black over the white-to-black range)
    img = decode_raw(write_raw(tmp_path / "c.dng", first), mode="bin2x2")
    black = np.asarray(img.black_levels[:3], dtype=np.float64)
    noise_free = _binned(first.mean_electrons) / ((img.white_level - black) * SensorModel().gain_e_per_dn)
    g0 = chart_gains(grid_chart_means(noise_free), geometry)
    np.testing.assert_allclose(g0, g0[1], rtol=1e-9)                  # the same in every channel, noise-free

    gains = []
    for seed in range(1, FRAMES + 1):
        frame = first if seed == 1 else simulate_raw(chart.radiance, chart.grid, chart.light, seed=seed)
        decoded = decode_raw(write_raw(tmp_path / f"c{seed}.dng", frame), mode="bin2x2")
        gains.append(chart_gains(grid_chart_means(decoded.rgb.astype(np.float64)), geometry))
    rel = np.asarray(gains) / g0 - 1.0                                   # (frames, 3)
    ratio = rel[:, [0, 2]] - rel[:, [1]]                                 # R/G and B/G, to first order
    # the noise is there (about 0.06-0.11 % per channel and frame at 96 x 72) ...
    assert np.all(rel.std(axis=0, ddof=1) > 2e-4)
    # ... and averages away: each channel's and each ratio's mean is within 4 standard errors of zero.  A
    # 0.17 % bias of red against green (the size seen in one session's four-frame gains) would be over 10
    # standard errors here
    sem = rel.std(axis=0, ddof=1) / np.sqrt(FRAMES)
    assert np.all(np.abs(rel.mean(axis=0)) < 4 * sem), (rel.mean(axis=0), sem)
    sem_ratio = ratio.std(axis=0, ddof=1) / np.sqrt(FRAMES)
    assert np.all(np.abs(ratio.mean(axis=0)) < 4 * sem_ratio), (ratio.mean(axis=0), sem_ratio)
    assert np.all(4 * sem_ratio < 1.7e-3 / 2)                            # the test can see a 0.17 % bias

