"""A light probe of the simulated room against the room's truth: luminance and chromaticity per region.

The simulated camera shoots a chart on the table and 7 brackets of a chrome ball in a room of known
light (:mod:`mocks.probe_world`); ``build_probe`` merges, finds the ball, unwraps and makes the map
spectral with the chart.  The recovered map is in units of the chart's white, so the truth is divided
by the luminance of a white diffuser where the chart lies.  Compared over the directions the ball shows
(the masked caps are not measured), region by region, away from region borders (2 map rows), where the
map's blur mixes neighbours.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from scipy.ndimage import binary_erosion

from app.workflows.light_probe import ProbeInputs, build_probe
from mocks.probe_world import (
    ROOM_REGIONS,
    ProbeWorld,
    region_labels,
    write_filtered_shots,
    write_light_csv,
    write_probe_shots,
)
from processing.geometry.camera_calibration import CameraCalibration
from processing.spectral.display import spectra_to_xyz

SIZE = (480, 320)
LIGHTS_AND_GREYS = ("floor", "ceiling", "window", "lamp 1", "lamp 2", "lamp 3")
WALLS = ("red wall", "green wall", "blue wall", "yellow wall")


@pytest.fixture(scope="module")
def shots(tmp_path_factory):
    world = ProbeWorld.probe(20.0, width=SIZE[0], height=SIZE[1])
    folder = tmp_path_factory.mktemp("room")
    chart, frames = write_probe_shots(world, folder)
    cal = CameraCalibration.from_dict(json.loads(json.dumps(CameraCalibration(
        SIZE, world.camera_intrinsics(), np.zeros(5), np.eye(4), room_to_camera=world.room_to_camera()).to_dict())))
    return world, ProbeInputs(frames, chart, cal, 20.0, "room"), folder


def _compared(world, result):
    env = result.environment
    d = env.directions()
    recovered = spectra_to_xyz(env.spectral_radiance(d), env.grid)
    truth = spectra_to_xyz(world.environment.spectral_radiance(d), world.grid) / world.chart_white_luminance()
    labels = region_labels(env.height)
    return env, result.observed, recovered, truth, labels


@pytest.fixture(scope="module")
def probe(shots):
    world, inputs, _ = shots
    return _compared(world, build_probe(inputs))


def _xy(xyz: np.ndarray) -> np.ndarray:
    return xyz[..., :2] / xyz.sum(axis=-1, keepdims=True)


def _region(labels, observed, name):
    inside = binary_erosion(labels == ROOM_REGIONS.index(name), iterations=2) & observed
    assert inside.sum() >= 10, name
    return inside


def test_total_luminance_of_the_seen_directions(probe):
    # what lights an object: the solid-angle integral.  Target 5 %; measured 1.0 % (the chart's grey scale)
    env, observed, rec, truth, _ = probe
    w = env.solid_angles() * observed
    assert abs(float((rec[..., 1] * w).sum() / (truth[..., 1] * w).sum()) - 1.0) < 0.05


@pytest.mark.parametrize("name", LIGHTS_AND_GREYS)
def test_lights_and_greys_luminance_and_chromaticity(probe, name):
    # target: luminance within 5 %, chromaticity (CIE 1931 xy) within 0.005; measured 1 % and 0.004: the chart's
    # light is stated as D65, but the coloured walls tint it by 0.0033 in xy (with it stated exactly: 0.0013)
    env, observed, rec, truth, labels = probe
    m = _region(labels, observed, name)
    assert abs(float(np.median(rec[m][:, 1] / truth[m][:, 1])) - 1.0) < 0.05
    assert np.abs(_xy(rec[m].mean(axis=0)) - _xy(truth[m].mean(axis=0))).max() < 0.005


@pytest.mark.parametrize("name", WALLS)
def test_saturated_walls_within_the_estimators_reach(probe, name):
    # the ColorChecker's red, green, blue and yellow as walls: three camera channels cannot tell their spectra
    # from the training set's nearest, as for reflectance.  Measured: luminance up to 9 %, xy up to 0.033 (red);
    # bounds 12 % and 0.045 (the estimator's limit, not the probe's: camera RGB is within 0.1 % of the truth)
    env, observed, rec, truth, labels = probe
    m = _region(labels, observed, name)
    assert abs(float(np.median(rec[m][:, 1] / truth[m][:, 1])) - 1.0) < 0.12
    assert np.abs(_xy(rec[m].mean(axis=0)) - _xy(truth[m].mean(axis=0))).max() < 0.045


def test_the_chart_light_stated_exactly_removes_the_white_point_error(shots):
    # the walls tint the chart's light 0.0033 in xy away from D65; given as a measured spectrum (CSV, as from a
    # spectrometer) the greys come within 0.003 (measured 0.0013-0.0023; 0.004 with D65 stated)
    world, inputs, folder = shots
    csv = write_light_csv(world, folder / "chart-light.csv")
    env, observed, rec, truth, labels = _compared(world, build_probe(inputs, light=str(csv)))
    for name in ("floor", "ceiling", "window"):
        m = _region(labels, observed, name)
        assert np.abs(_xy(rec[m].mean(axis=0)) - _xy(truth[m].mean(axis=0))).max() < 0.003, name


@pytest.fixture(scope="module")
def two_sets(shots):
    """The same room through the magenta notch filter too: six channels; the chart's light given as measured."""
    world, inputs, folder = shots
    filter_chart, filter_frames, filter_csv = write_filtered_shots(world, folder / "filtered")
    both = replace(inputs, filter_frames=filter_frames, filter_chart=filter_chart, filter_transmission=filter_csv)
    return _compared(world, build_probe(both, light=str(write_light_csv(world, folder / "measured-light.csv"))))


@pytest.mark.parametrize("name", WALLS)
def test_two_bracket_sets_bring_the_walls_within_the_target(two_sets, name):
    # target: luminance within 5 %, xy within 0.005.  Six channels (the second set through the filter), the
    # two-light root polynomial, six basis spectra.  Measured at this size: luminance within 1.8 %, xy 0.0009 /
    # 0.0023 / 0.0040 / 0.0025 (red, green, blue, yellow) 4 map rows from borders -- at 2 rows the green wall
    # reads 0.015: at 320 px high the ball's image blurs the wall with the window beside it (three channels:
    # 0.020 / 0.017 / 0.005 / 0.002 at 4 rows, the red wall 10 % too bright)
    env, observed, rec, truth, labels = two_sets
    m = binary_erosion(labels == ROOM_REGIONS.index(name), iterations=4) & observed
    assert m.sum() >= 10
    assert abs(float(np.median(rec[m][:, 1] / truth[m][:, 1])) - 1.0) < 0.05
    assert np.abs(_xy(rec[m].mean(axis=0)) - _xy(truth[m].mean(axis=0))).max() < 0.005
