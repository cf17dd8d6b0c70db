"""The CFA fringe prediction against the false colour a Bayer sensor and the 2 x 2 binning really make.

Ground truth: a grey (equal-channel) image with a smooth highlight, sampled through each Bayer pattern
and binned by the project's own decode (:func:`processing.camera.raw_decode.bin2x2`); every channel of
the truth is equal, so a binned pixel's channel ratio to its green is the false colour itself.
"""

from __future__ import annotations

import numpy as np
import pytest

from processing.camera.cfa_fringe import CfaFringeError, cfa_fringe, channel_offsets, transformed_fringe
from processing.camera.raw_decode import bin2x2


def _binned_grey(level: np.ndarray, pattern: str) -> np.ndarray:
    idx = np.array(["RGB".index(c) for c in pattern])
    mosaic = level.astype(np.float32)              # grey: every channel sees the same level
    no = np.zeros(level.shape, bool)
    rgb, _, _ = bin2x2(mosaic, idx, no, no)
    return rgb.astype(np.float64)


@pytest.mark.parametrize("pattern", ["RGGB", "BGGR", "GRBG", "GBRG"])
def test_prediction_follows_the_false_colour_of_a_highlight_flank(pattern):
    yy, xx = np.mgrid[0:64, 0:64] + 0.5
    level = np.exp(-((yy - 30.0) ** 2 + (xx - 34.0) ** 2) / (2 * 6.0**2)) + 0.02   # sigma 6 photosites
    rgb = _binned_grey(level, pattern)
    actual = rgb / rgb[..., 1:2] - 1.0             # the false colour relative to green
    pred = cfa_fringe(rgb, pattern)
    pred_rel = (1 + pred) / (1 + pred[..., 1:2]) - 1.0
    flank = (np.abs(actual[..., [0, 2]]).max(axis=2) > 0.05) & (rgb[..., 1] > 0.05)
    assert flank.sum() > 50, "the highlight has a flank with a visible fringe"
    # tolerance: the prediction is exact for an exponential profile; a Gaussian's curvature and the
    # gradient's finite differences leave up to about a third of the fringe; the sign is always right
    for c in (0, 2):
        a, p = actual[..., c][flank], pred_rel[..., c][flank]
        assert np.all(np.sign(a) == np.sign(p)), pattern
        assert np.median(np.abs(p - a) / np.abs(a)) < 0.35, pattern


def test_no_gradient_no_fringe_and_a_scale_changes_nothing():
    flat = np.full((6, 8, 3), 0.4)
    assert np.abs(cfa_fringe(flat)).max() == 0.0
    ramp = np.exp(-0.5 * np.arange(8.0))[:, None, None] * np.ones((8, 6, 3))
    np.testing.assert_allclose(transformed_fringe(ramp, "RGGB", 3.0 * np.eye(3)), cfa_fringe(ramp, "RGGB"),
                               atol=1e-12)
    assert transformed_fringe(ramp, "RGGB", np.eye(6)) is None     # a two-exposure transform: no prediction


def test_greens_sit_at_the_centre_and_red_blue_opposite():
    for pattern in ("RGGB", "BGGR", "GRBG", "GBRG"):
        o = channel_offsets(pattern)
        np.testing.assert_array_equal(o[1], [0.0, 0.0])
        np.testing.assert_array_equal(o[0], -o[2])


@pytest.mark.parametrize("bad", [np.zeros((4, 4)), np.full((4, 4, 3), np.nan), np.zeros((1, 4, 3))])
def test_bad_images_are_refused_with_the_parameter_named(bad):
    with pytest.raises(CfaFringeError, match="rgb must be"):
        cfa_fringe(bad)


def test_bad_pattern_is_refused():
    with pytest.raises(CfaFringeError, match="cfa_pattern"):
        cfa_fringe(np.ones((4, 4, 3)), "RGBW")
