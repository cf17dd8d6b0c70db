"""``kogei probe``: a probe from simulated brackets, and every bad input as one line with exit 2."""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.cli import main
from mocks.camera_sim import simulate_raw, write_raw
from mocks.probe_world import ProbeWorld, write_probe_shots
from processing.geometry.camera_calibration import CameraCalibration
from processing.lighting.environment_map import read_environment
from tests.app.cli_checks import fails_with_one_line

SIZE = (240, 160)


def _calibration(world: ProbeWorld, folder) -> str:
    """The world's true camera as a camera_calibration.json (what kogei calibrate --camera would find)."""
    cal = CameraCalibration(SIZE, world.camera_intrinsics(), np.zeros(5), np.eye(4), room_to_camera=world.room_to_camera())
    path = folder / "camera_calibration.json"
    path.write_text(json.dumps(cal.to_dict()))
    return str(path)


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    base = tmp_path_factory.mktemp("probe")
    world = ProbeWorld.probe(20.0, width=SIZE[0], height=SIZE[1])
    chart, frames = write_probe_shots(world, base / "shots")
    return base, world, chart, frames, _calibration(world, base)


def _args(chart, cal, out, *frames, radius="20"):
    return ["probe", *map(str, frames), "--chart", str(chart), "--camera-calibration", cal, "--sphere-radius", radius,
            "--out", str(out)]


def test_probe_writes_a_spectral_map_and_its_report(station, tmp_path, capsys):
    base, world, chart, frames, cal = station
    assert main(_args(chart, cal, tmp_path / "p.exr", *frames)) == 0
    out = capsys.readouterr().out
    assert "p.exr" in out and "7 brackets" in out
    env = read_environment(tmp_path / "p.exr", world.grid)
    report = json.loads((tmp_path / "p.json").read_text())
    assert env.width == 2 * env.height == 2 * report["map"]["height"]
    # the sphere is placed where the simulation put it: its outline is 41 px in radius here, and 0.2 px of
    # outline error moves it 0.5 % (1.3 mm) along the line of sight
    assert np.linalg.norm(np.subtract(report["sphere"]["centre_room_mm"], world.sphere_centre_mm(0.0))) < 2.0
    # the floor (grey, straight down) is seen and has about its true luminance in units of the chart's white
    truth = float(world.environment.luminance([[0.0, 0.0, -1.0]])[0]) / world.chart_white_luminance()
    assert abs(float(env.luminance([[0.0, 0.0, -1.0]])[0]) / truth - 1.0) < 0.05


def test_a_folder_of_raw_files_is_read_like_the_files(station, tmp_path):
    base, world, chart, frames, cal = station
    assert main(_args(chart, cal, tmp_path / "a.exr", frames[0].parent) + ["--quiet"]) == 0
    assert main(_args(chart, cal, tmp_path / "b.exr", *frames) + ["--quiet"]) == 0
    a, b = read_environment(tmp_path / "a.exr"), read_environment(tmp_path / "b.exr")
    assert np.array_equal(a.coefficients, b.coefficients)


def test_brackets_saturated_everywhere(station, tmp_path, capsys):
    base, world, chart, _, cal = station
    _, frames = write_probe_shots(world, tmp_path / "over", times_s=(0.5, 2.0), chart_time_s=None)
    fails_with_one_line(_args(chart, cal, tmp_path / "p.exr", *frames), capsys, tmp_path, "probe-1.dng",
                        "saturated")


def test_missing_exposure_metadata(station, tmp_path, capsys):
    base, world, chart, frames, cal = station
    f = world.frame("object")
    raw = simulate_raw(f.radiance, f.grid, f.light, exposure_s=0.01)
    raw.exposure_time = None
    raw.f_number = 8.0
    bad = write_raw(tmp_path / "no-time.dng", raw)
    fails_with_one_line(_args(chart, cal, tmp_path / "p.exr", frames[0], bad), capsys, tmp_path, "no-time.dng",
                        "exposure time")


def test_probe_sphere_not_found(station, tmp_path, capsys):
    base, world, chart, _, cal = station
    away = ProbeWorld.probe(20.0, width=SIZE[0], height=SIZE[1], camera_target_mm=(300.0, 0.0, 37.0))
    _, frames = write_probe_shots(away, tmp_path / "away", chart_time_s=None)
    fails_with_one_line(_args(chart, cal, tmp_path / "p.exr", *frames), capsys, tmp_path, "probe-1.dng",
                        "no sphere found")


def test_missing_chart_and_calibration_are_named(station, tmp_path, capsys):
    base, world, chart, frames, cal = station
    fails_with_one_line(["probe", *map(str, frames), "--camera-calibration", cal, "--sphere-radius", "20", "--out",
                         str(tmp_path / "p.exr")], capsys, tmp_path, "--chart")
    fails_with_one_line(["probe", *map(str, frames), "--chart", str(chart), "--sphere-radius", "20", "--out",
                         str(tmp_path / "p.exr")], capsys, tmp_path, "--camera-calibration")
    fails_with_one_line(_args(chart, cal, tmp_path / "p.exr", *frames, radius="-3"), capsys, tmp_path,
                        "--sphere-radius")
    fails_with_one_line(_args(chart, cal, tmp_path / "p.png", *frames), capsys, tmp_path, ".exr")
    fails_with_one_line(_args(chart, cal, tmp_path / "p.exr", tmp_path / "nothing.dng"), capsys, tmp_path,
                        "nothing.dng")


@pytest.mark.parametrize(("option", "value", "needle"), [
    ("--sphere-radius", "1e-300", "--sphere-radius must be the mirror sphere's radius in mm, 1 to 500"),
    ("--sphere-radius", "1e300", "--sphere-radius must be the mirror sphere's radius in mm, 1 to 500"),
    ("--sphere-radius", "nan", "--sphere-radius must be the mirror sphere's radius in mm, 1 to 500"),
    ("--sphere-reflectance", "1e-300", "--sphere-reflectance must be the mirror's reflectance, 0.02 to 1"),
    ("--sphere-reflectance", "0.01", "under 0.02 it is not a mirror"),
    ("--sphere-reflectance", "1.5", "--sphere-reflectance must be the mirror's reflectance, 0.02 to 1"),
])
def test_absurd_sphere_parameters_are_refused_before_the_work(station, tmp_path, capsys, option, value, needle):
    """1e-300 mm was a scipy traceback, 1e300 mm a garbage map reported as success, reflectance 1e-300 a warning."""
    base, world, chart, frames, cal = station
    argv = (_args(chart, cal, tmp_path / "p.exr", *frames, radius=value) if option == "--sphere-radius"
            else [*_args(chart, cal, tmp_path / "p.exr", *frames), option, value])
    fails_with_one_line(argv, capsys, tmp_path, needle)
