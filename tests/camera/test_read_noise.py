"""The read noise of one decoded pixel carried by the chart transform, against simulated photosites.

Independent reference: many 2 x 2 cells of pure read noise (Gaussian, ``s`` per photosite) through the
decode's own ``bin2x2`` and a chart transform; the sample covariance of the transformed pixels must match
:func:`processing.camera.transfer.transformed_read_noise`.  With 40 000 pixels a covariance entry's sampling
error is about ``sqrt(2 / 40 000)`` = 0.7 % of the diagonal scale, so 3 % is four standard errors.
"""

from __future__ import annotations

import numpy as np
import pytest

from processing.camera.raw_decode import bin2x2
from processing.camera.transfer import READ_NOISE, transformed_read_noise
from processing.spectral.checks import SpectralEstimationError

#: A chart transform of a camera whose red and blue are weaker than its green (columns: model R, G, B).
M = np.array([[1.4, -0.3, 0.1], [-0.5, 1.9, -0.6], [0.2, -0.4, 1.5]])


def test_covariance_matches_binned_photosites_through_the_transform():
    rng = np.random.default_rng(0)
    s = 5e-4
    mosaic = (s * rng.standard_normal((400, 400))).astype(np.float32)
    no = np.zeros(mosaic.shape, bool)
    rgb, _, _ = bin2x2(mosaic, np.array([0, 1, 1, 2]), no, no)
    cam = rgb.reshape(-1, 3).astype(np.float64) @ M
    sample = np.cov(cam, rowvar=False)
    predicted = transformed_read_noise(M, s)
    scale = np.sqrt(np.outer(np.diag(predicted), np.diag(predicted)))
    assert np.all(np.abs(sample - predicted) <= 0.03 * scale)


def test_default_and_bad_input():
    assert np.allclose(np.diag(transformed_read_noise(np.eye(3))), READ_NOISE**2 * np.array([1.0, 0.5, 1.0]))
    assert np.allclose(np.diag(transformed_read_noise(np.eye(3), mode="demosaic")), READ_NOISE**2)
    with pytest.raises(SpectralEstimationError, match="chart transform"):
        transformed_read_noise(np.eye(2))
    with pytest.raises(SpectralEstimationError, match="read_noise"):
        transformed_read_noise(np.eye(3), -1.0)
