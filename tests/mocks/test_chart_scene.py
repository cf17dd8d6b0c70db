"""The laid-out chart of the simulated world: geometry, radiance, serialisation, errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mocks.chart_scene import FRAME_REFLECTANCE, ChartPlacement, chart_corners, chart_patch_reflectances
from mocks.world import BACKDROP_REFLECTANCE, World, WorldError, chart_reflectances
from processing.camera.chart_layout import chart_layout
from tests.camera.chart_shots import chart_world


def test_classic_layout_radiance_labels_and_corners():
    w = chart_world("classic24", 240, 160, chart_placement=ChartPlacement(size=0.8))
    f = w.frame("chart")
    e = w.light_spectrum()
    refl = chart_reflectances(w.grid)
    assert sorted(np.unique(f.labels).tolist()) == list(range(-1, 24))
    for k in (0, 18, 23):
        np.testing.assert_allclose(f.radiance[f.labels == k], np.broadcast_to(refl[k] * e / math.pi,
                                                                               ((f.labels == k).sum(), e.size)))
    # the card: 192 px wide (0.8 of 240), aspect 16.75 : 11.25, centred (pixel centres at integers)
    c = f.chart_corners
    np.testing.assert_allclose(c[1, 0] - c[0, 0], 192.0)
    np.testing.assert_allclose(c[3, 1] - c[0, 1], 192.0 * 11.25 / 16.75)
    np.testing.assert_allclose(c.mean(axis=0), [119.5, 79.5])
    # the frame between patches is black card, outside it the backdrop
    frame_px = f.radiance[80, int(c[0, 0]) + 1]
    np.testing.assert_allclose(frame_px, FRAME_REFLECTANCE * e / math.pi)
    np.testing.assert_allclose(f.radiance[2, 2], BACKDROP_REFLECTANCE * e / math.pi)
    # each patch is a square of the layout's size: 2.5 units of 192/16.75 px
    side = 2.5 * 192 / 16.75
    for k in (0, 23):
        assert abs((f.labels == k).sum() - side ** 2) < 2 * 2 * side


def test_rotation_moves_patch_one():
    lay = chart_layout("classic24")
    upright = chart_corners(lay, 400, 300, ChartPlacement())
    turned = chart_corners(lay, 400, 300, ChartPlacement(rotation_deg=180))
    np.testing.assert_allclose(turned, upright[[2, 3, 0, 1]], atol=1e-9)
    quarter = chart_corners(lay, 400, 300, ChartPlacement(rotation_deg=90))
    # counter-clockwise as seen: the chart's top-left corner goes to the bottom-left
    assert quarter[0, 0] < 200 and quarter[0, 1] > 150


def test_tilt_foreshortens_the_far_side():
    lay = chart_layout("classic24")
    c = chart_corners(lay, 400, 300, ChartPlacement(tilt_deg=(30, 0)))
    top, bottom = c[1, 0] - c[0, 0], c[2, 0] - c[3, 0]
    assert top != pytest.approx(bottom) and min(top, bottom) < 280 < max(top, bottom) * 1.2


def test_sg_and_vinyl_spectra_are_physical():
    w = chart_world("vinyl18")
    for name, n in (("sg140", 140), ("vinyl18", 18)):
        r = chart_patch_reflectances(name, w.grid)
        assert r.shape == (n, w.grid.size) and np.all((r > 0) & (r <= 1))


def test_round_trip_and_settings():
    import json

    w = World.hawk(2_000, chart_layout="sg140", chart_placement={"center": [0.4, 0.6], "size": 0.5,
                                                                 "rotation_deg": 12, "tilt_deg": [5, -5]})
    again = World.from_dict(json.loads(json.dumps(w.to_dict())))
    assert again.chart_layout == "sg140" and again.chart_placement == w.chart_placement
    with pytest.raises(WorldError, match="chart_layout must be"):
        chart_world("classic25")
    with pytest.raises(WorldError, match="chart_placement: chart size"):
        chart_world("classic24", chart_placement={"size": -1})
    with pytest.raises(WorldError, match="chart_placement: chart tilt_deg"):
        chart_world("classic24", chart_placement={"tilt_deg": (80, 0)})


def test_grid_layout_is_unchanged_by_default():
    w = chart_world("grid", 48, 32)
    f = w.frame("chart")
    assert f.chart_corners is None and sorted(np.unique(f.labels).tolist()) == list(range(-1, 24))
