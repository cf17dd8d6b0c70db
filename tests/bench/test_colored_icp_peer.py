"""The peer bench's colours for Open3D's coloured ICP: which points are kept and how their colours are scaled."""

from __future__ import annotations

import numpy as np
import pytest

from bench.colored_icp_peer import peer_colours


def test_rgb_is_scaled_by_its_99th_percentile_and_uncoloured_points_dropped():
    rng = np.random.default_rng(3)
    rgb = rng.uniform(0.0, 0.4, size=(1000, 3))
    rgb[::7] = np.nan                                       # points no photo saw
    keep, shown = peer_colours(rgb, "rgb")
    assert keep.sum() == 1000 - len(range(0, 1000, 7)) and not keep[::7].any()
    scale = np.percentile(rgb[keep], 99)
    np.testing.assert_allclose(shown, np.clip(rgb[keep] / scale, 0.0, 1.0))
    assert shown.max() == 1.0 and np.mean(shown == 1.0) <= 0.011


def test_chromaticity_removes_the_lamps_shading():
    base = np.array([0.30, 0.12, 0.08])                     # a red lacquer, lit at several strengths
    rgb = np.outer([0.2, 0.5, 1.0, 3.0], base)
    _, shown = peer_colours(rgb, "chromaticity")
    np.testing.assert_allclose(shown, np.tile(base / base.max(), (4, 1)), rtol=1e-12)


def test_an_unknown_colour_mode_is_refused():
    with pytest.raises(ValueError, match="colour mode must be 'rgb' or 'chromaticity', got 'hsv'"):
        peer_colours(np.ones((2, 3)), "hsv")
