"""``kogei mock --world board[:TILT]`` and ``--world mirror-sphere[:R[:OFF]]`` build the calibration worlds."""

from __future__ import annotations

import argparse

import pytest

from app.cli.mock import _build_world, add_parser
from app.errors import UsageError
from mocks.board_world import BoardWorld
from mocks.mirror_world import MirrorWorld


def _args(*argv):
    parser = argparse.ArgumentParser(prog="kogei")
    add_parser(parser.add_subparsers(dest="command"))
    return parser.parse_args(["mock", *argv])


def test_board_worlds():
    w = _build_world(_args("--world", "board"))
    assert isinstance(w, BoardWorld) and w.tilts_deg == (0.0, 40.0, 55.0)
    assert (w.width, w.height, w.fov_deg) == (960, 640, 25.0)
    assert _build_world(_args("--world", "board:30")).tilts_deg == (30.0,)


def test_mirror_sphere_worlds():
    w = _build_world(_args("--world", "mirror-sphere"))
    assert isinstance(w, MirrorWorld) and (w.sphere_radius_mm, w.offsets_mm) == (20.0, (35.0,))
    w = _build_world(_args("--world", "mirror-sphere:15:40"))
    assert (w.sphere_radius_mm, w.offsets_mm, float(w.pose[0, 3])) == (15.0, (40.0,), 40.0)


@pytest.mark.parametrize("spec, words", [("board:steep", "TILT"), ("board:95", "tilt_deg"),
                                         ("board:10:2", "board:TILT_DEG"), ("mirror-sphere:x", "RADIUS_MM"),
                                         ("mirror-sphere:20:-5", "offsets_mm")])
def test_bad_specs(spec, words):
    with pytest.raises(UsageError, match=words):
        _build_world(_args("--world", spec))
    with pytest.raises(UsageError, match="material"):
        _build_world(_args("--world", "board", "--material", "gold"))


def test_the_printed_capture_commands_use_the_calibration_plans():
    """kogei mock --world board / mirror-sphere suggests the calibration plan, camera only, no laser."""
    from app.cli.mock import _calibration_plan, capture_commands
    from mocks.board_world import BoardWorld
    from mocks.mirror_world import MirrorWorld
    from mocks.world import World

    info = {"turntable": "/s/t", "profiler": "/s/p", "gphoto2": "/s/g", "hotfolder": "/s/h", "control": "/s/c"}
    board = capture_commands(info, plan=_calibration_plan(BoardWorld.charuco(width=96, height=64)))["gphoto2"]
    assert "--plan camera-calibration" in board and "--laser" not in board and "--steps" not in board
    mirror = capture_commands(info, plan=_calibration_plan(MirrorWorld.mirror_sphere(18.0, 30.0, width=96,
                                                                                      height=64)))["hotfolder"]
    assert "--plan lamp-calibration --sphere-radius 18" in mirror and "--shutter" in mirror
    assert _calibration_plan(World.hawk(2000)) is None


def test_the_sphere_world_prints_the_scanner_calibration_scan():
    """kogei mock --world sphere suggests the one-pass, camera-less scan of docs/processing.md and the calibrate step."""
    from app.cli.mock import _calibration_plan, _next_command, _session_name, capture_commands
    from mocks.world import World

    sphere = World.calibration_sphere(20.0, 40.0, chart_first=False)
    plan = _calibration_plan(sphere)
    info = {"turntable": "/s/t", "profiler": "/s/p", "gphoto2": "/s/g", "hotfolder": "/s/h", "control": "/s/c"}
    cmds = capture_commands(info, plan=plan, session=_session_name(plan))
    assert cmds["gphoto2"] == ("kogei capture --plan sphere-calibration --turntable /s/t --laser /s/p --camera none "
                               "--steps 90 --out calibration-session --unattended")
    # the hot-folder line takes the sphere's photos (they tie the camera to the scanner), never a chart
    assert "--camera-angles 0,30," in cmds["hotfolder"] and "--camera hotfolder:/s/h" in cmds["hotfolder"]
    assert _next_command(sphere, plan) == "kogei calibrate calibration-session --sphere-radius 20"
    hawk_then = _next_command(World.hawk(2000), None)
    assert hawk_then.startswith("kogei process kogei-session --calibration calibration-session")


def test_probe_world_and_its_printed_commands():
    """kogei mock --world probe[:R] builds the lit room with the chrome ball and suggests the probe plan."""
    from app.cli.mock import _calibration_plan, _next_command, capture_commands
    from mocks.probe_world import ProbeWorld

    w = _build_world(_args("--world", "probe:15"))
    assert isinstance(w, ProbeWorld) and w.sphere_radius_mm == 15.0 and w.shows_chart
    plan = _calibration_plan(w)
    info = {"turntable": "/s/t", "profiler": "/s/p", "gphoto2": "/s/g", "hotfolder": "/s/h", "control": "/s/c"}
    assert "--plan probe --sphere-radius 15" in capture_commands(info, plan=plan)["gphoto2"]
    assert _next_command(w, plan).startswith("kogei probe probe-session")
    with pytest.raises(UsageError, match="RADIUS_MM"):
        _build_world(_args("--world", "probe:big"))


def test_filtered_probe_world_shoots_through_the_filter_and_suggests_two_sets(tmp_path):
    """probe:R:filtered: every frame (the chart's too) through the magenta notch; kept through the station file."""
    import numpy as np

    from app.cli.mock import _calibration_plan, _next_command, _session_name
    from mocks.probe_world import FILTERS, PROBE_FILTER, ProbeWorld, filter_transmission

    w = _build_world(_args("--world", "probe:15:filtered"))
    plain = ProbeWorld.probe(15.0)
    assert w.lens_filter == PROBE_FILTER and plain.lens_filter is None
    t = filter_transmission(*FILTERS[PROBE_FILTER], w.grid.wavelengths)
    for kind in ("chart", "object"):
        np.testing.assert_allclose(w.frame(kind).radiance, plain.frame(kind).radiance * t, rtol=1e-12)
    # the fake gphoto2 program rebuilds the world from the station file's mapping
    assert ProbeWorld.from_dict(w.to_dict()).lens_filter == PROBE_FILTER
    plan = _calibration_plan(w)
    assert _session_name(plan, w) == "probe-filtered-session"
    then = _next_command(w, plan, tmp_path / "lens-filter.csv")
    assert "--filter-frames probe-filtered-session" in then and "lens-filter.csv" in then
    with pytest.raises(UsageError, match="filtered"):
        _build_world(_args("--world", "probe:15:red"))
