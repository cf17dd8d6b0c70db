"""``kogei probe`` with a second bracket set through a colour filter: six channels, a map of K basis spectra.

The simulated camera shoots the chart and the ball twice, the second time through the idealised magenta notch
filter of :data:`mocks.probe_world.PROBE_FILTER` (its transmission written as the CSV a data sheet gives).
Every bad input of the second set is one line naming the option, exit 2.
"""

from __future__ import annotations

import json

import pytest

from app.cli import main
from mocks.probe_world import ProbeWorld, write_filtered_shots, write_probe_shots
from processing.lighting.environment_map import read_environment
from tests.app.cli_checks import fails_with_one_line
from tests.app.test_probe_command import SIZE, _calibration


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    base = tmp_path_factory.mktemp("probe2")
    world = ProbeWorld.probe(20.0, width=SIZE[0], height=SIZE[1])
    chart, frames = write_probe_shots(world, base / "plain")
    *_, csv = write_filtered_shots(world, base / "filtered")
    return base, world, chart, frames, _calibration(world, base), csv


def _args(station, out, *extra):
    base, _, chart, frames, cal, csv = station
    return ["probe", *map(str, frames), "--chart", str(chart), "--camera-calibration", cal, "--sphere-radius", "20",
            "--out", str(out), "--filter-frames", str(base / "filtered"), "--filter-chart",
            str(base / "filtered" / "chart.dng"), "--filter", str(csv), *extra]


def test_two_sets_write_a_map_of_six_basis_spectra(station, tmp_path, capsys):
    _, world, *_ = station
    assert main(_args(station, tmp_path / "p.exr")) == 0
    out = capsys.readouterr().out
    assert "7 brackets + 7 through the filter" in out and "keeps 6 basis spectra" in out
    env = read_environment(tmp_path / "p.exr", world.grid)
    report = json.loads((tmp_path / "p.json").read_text())
    assert env.coefficients.shape[2] == 6 and report["spectral"]["method"] == "twolight"
    assert (env.basis >= 0).all() and (env.coefficients >= 0).all()
    # the six basis spectra hold the estimated spectra: 99 % of directions within 0.002 in xy (measured 0.00003),
    # the spectra within 5 % (median; measured 1.2 %)
    assert report["spectral"]["projection_dxy_p99"] < 0.002
    assert report["spectral"]["projection_spectral_median"] < 0.05
    # the floor (grey, straight down) has its true luminance in units of the chart's white (measured 0.9 %)
    truth = float(world.environment.luminance([[0.0, 0.0, -1.0]])[0]) / world.chart_white_luminance()
    assert abs(float(env.luminance([[0.0, 0.0, -1.0]])[0]) / truth - 1.0) < 0.05


def test_fewer_basis_spectra_on_request(station, tmp_path):
    _, world, *_ = station
    assert main(_args(station, tmp_path / "p.exr", "--components", "3", "--quiet")) == 0
    env = read_environment(tmp_path / "p.exr", world.grid)
    assert env.coefficients.shape[2] == 3


def test_bad_second_set_inputs_are_named(station, tmp_path, capsys):
    base, world, chart, frames, cal, csv = station
    one = ["probe", *map(str, frames), "--chart", str(chart), "--camera-calibration", cal, "--sphere-radius", "20",
           "--out", str(tmp_path / "p.exr")]
    fails_with_one_line(one + ["--filter-frames", str(base / "filtered")], capsys, tmp_path, "--filter CSV")
    fails_with_one_line(one + ["--filter", str(csv)], capsys, tmp_path, "--filter-frames")
    fails_with_one_line(one + ["--components", "4"], capsys, tmp_path, "--components", "--filter-frames")
    fails_with_one_line(one + ["--method", "twolight"], capsys, tmp_path, "twolight", "--filter-frames")
    fails_with_one_line(_args(station, tmp_path / "p.exr", "--method", "wiener"), capsys, tmp_path, "wiener")
    fails_with_one_line(_args(station, tmp_path / "p.exr", "--components", "9"), capsys, tmp_path, "--components",
                        "1-6")
    fails_with_one_line(one + ["--filter-frames", str(tmp_path / "none"), "--filter", str(csv)], capsys, tmp_path,
                        "--filter-frames", "not a folder")
    fails_with_one_line(one + ["--filter-frames", str(frames[0].parent), "--filter", str(csv)], capsys, tmp_path,
                        "probe-1.dng", "also one of the brackets")
    empty = tmp_path / "empty"
    empty.mkdir()
    fails_with_one_line(one + ["--filter-frames", str(empty), "--filter", str(csv)], capsys, tmp_path, "no RAW files")
    percent = tmp_path / "percent.csv"
    percent.write_text("wavelength_nm,transmission\n380,50\n780,90\n")
    args = _args(station, tmp_path / "p.exr")
    args[args.index("--filter") + 1] = str(percent)
    fails_with_one_line(args, capsys, tmp_path, "percent.csv", "divide by 100")
    short = tmp_path / "short.csv"
    short.write_text("wavelength_nm,transmission\n450,0.5\n650,0.9\n")
    args[args.index("--filter") + 1] = str(short)
    fails_with_one_line(args, capsys, tmp_path, "short.csv", "400-700 nm")
    fails_with_one_line(one + ["--filter-frames", str(base / "filtered"), "--filter", str(csv)], capsys, tmp_path,
                        "--filter-chart")


def test_a_second_set_of_another_size_is_refused(station, tmp_path, capsys):
    base, world, *_ = station
    other = ProbeWorld.probe(20.0, width=SIZE[0] // 2, height=SIZE[1] // 2)
    write_filtered_shots(other, tmp_path / "small")
    args = _args(station, tmp_path / "p.exr")
    args[args.index("--filter-frames") + 1] = str(tmp_path / "small")
    fails_with_one_line(args, capsys, tmp_path, "--filter-frames", "one place")
