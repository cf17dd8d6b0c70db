"""A cloud far smaller than its partner collapses on the pair's search grid: refused, never a traceback.

A cloud of 10 or 50 points in a 1 mm cube against a 100 mm object kept one
point at the draft search voxel (4 mm), and ``_Level.roughness`` indexed the
1-D result of a ``k = 1`` k-d tree query (IndexError).
"""

from __future__ import annotations

import numpy as np
import pytest

from processing.geometry.registration import MIN_POINTS, RegistrationError, register_pair, register_passes
from processing.geometry.registration.clouds import _Level
from processing.geometry.registration.symmetry import _smooth


def _object(n: int = 3000) -> np.ndarray:
    """Points on a bumpy ellipsoid about 100 mm across."""
    rng = np.random.default_rng(3)
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    r = 1.0 + 0.1 * np.sin(3 * u[:, 0]) * np.cos(2 * u[:, 1])
    return u * r[:, None] * np.array([50.0, 35.0, 25.0])


def _speck(n: int) -> np.ndarray:
    return np.random.default_rng(n).uniform(0.0, 1.0, (n, 3))


@pytest.mark.parametrize("n", [10, 50])
def test_a_speck_against_an_object_is_refused_as_a_pair_and_left_out_of_passes(n):
    match = (rf"only 1 point\(s\) remain on the [\d.]+ mm grid the pair is searched on \(registration needs "
             rf"at least {MIN_POINTS}\).*register clouds of similar extent, or crop the larger one")
    with pytest.raises(RegistrationError, match="source: " + match):
        register_pair(_speck(n), _object(), preset="draft")
    # among several passes the speck is left out, the others kept: one bad pass never stops a session's processing
    res = register_passes([_object(), _speck(n)], names=["object", "tiny"], preset="draft")
    assert res.poses[0].transform is not None and res.poses[1].transform is None
    assert "tiny is not connected to object" in res.poses[1].reason


def test_one_point_levels_give_roughness_zero_and_a_smooth_mask():
    one = _Level(np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]))
    assert one.roughness(1.0) == 0.0
    assert _smooth(one).tolist() == [True]
    two = _Level(np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.2]]), np.array([[0.0, 0.0, 1.0]] * 2))
    assert np.isfinite(two.roughness(1.0))
