"""``kogei capture --plan probe`` on the simulated station, then ``kogei probe SESSION``: brackets set by gphoto2."""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.capture.devices import build_devices
from app.capture.runner import CaptureHooks, CapturePlan, run_capture
from app.cli import main
from app.session import Session
from app.workflows.station_calibration import install_station_calibration
from mocks.probe_world import ProbeWorld
from mocks.station import SimulatedStation
from processing.camera.raw_decode import decode_raw
from processing.geometry.camera_calibration import CameraCalibration
from processing.lighting.environment_map import read_environment

SIZE = (240, 160)

# the fixture captures 8 frames through the fake gphoto2 program (one process each): about a minute
pytestmark = pytest.mark.slow


def test_plan_probe_actions_and_round_trip():
    plan = CapturePlan("probe", sphere_radius_mm=20.0)
    acts = plan.actions()
    assert [a.kind for a in acts] == ["chart"] + ["frame"] * 7
    assert [a.shutter for a in acts[1:]] == ["1/4000", "1/1000", "1/250", "1/60", "1/15", "1/4", "1"]
    assert CapturePlan.from_dict(json.loads(json.dumps(plan.to_dict()))) == plan
    with pytest.raises(ValueError, match="shutter speed"):
        CapturePlan("probe", brackets=("fast",))
    with pytest.raises(ValueError, match="probe plan"):
        CapturePlan("scan", brackets=("1/60",))


def _capture(world: ProbeWorld, plan: CapturePlan, root, station_root, *, seed: int):
    """Capture ``plan`` of ``world`` through the simulated station's fake gphoto2 into the session ``root``."""
    with SimulatedStation(world, root=station_root, seed=seed) as st:
        config = {"turntable": {"port": str(st.turntable_path)},
                  "camera": {"kind": "gphoto2", "executable": str(st.gphoto2_path)}}
        s = Session.create(root, plan=plan.to_dict())
        try:
            run_capture(s, plan, build_devices(config, s.root), CaptureHooks(before_pass=lambda p, n: st.place(p)))
        finally:
            s.close()
    return root


@pytest.fixture(scope="module")
def probe_session(tmp_path_factory):
    base = tmp_path_factory.mktemp("probe-capture")
    world = ProbeWorld.probe(20.0, width=SIZE[0], height=SIZE[1])
    root = _capture(world, CapturePlan("probe", sphere_radius_mm=20.0), base / "probe", base / "station", seed=3)
    cal = CameraCalibration(SIZE, world.camera_intrinsics(), np.zeros(5), np.eye(4), room_to_camera=world.room_to_camera())
    with Session.open(root) as s:
        install_station_calibration(s, "camera_calibration", cal.to_dict())
    return root, world


def test_the_brackets_carry_their_shutter_speeds(probe_session):
    root, _ = probe_session
    manifest = Session.read(root)
    frames = sorted((r for r in manifest["captures"].values() if r.get("kind") == "frame"), key=lambda r: r["index"])
    assert [r["shutter"] for r in frames] == list(CapturePlan("probe").brackets)
    times = [decode_raw(root / r["file"]).exposure_time for r in frames]
    assert np.allclose(times, [1 / 4000, 1 / 1000, 1 / 250, 1 / 60, 1 / 15, 1 / 4, 1.0], rtol=1e-6)
    assert decode_raw(root / frames[0]["file"]).f_number == 8.0


def test_kogei_probe_reads_the_session(probe_session, tmp_path, capsys):
    root, world = probe_session
    assert main(["probe", str(root), "--out", str(tmp_path / "room.exr")]) == 0
    env = read_environment(tmp_path / "room.exr", world.grid)
    # the floor, straight down, in units of the chart's white (the small frame: within 5 %)
    truth = float(world.environment.luminance([[0.0, 0.0, -1.0]])[0]) / world.chart_white_luminance()
    assert abs(float(env.luminance([[0.0, 0.0, -1.0]])[0]) / truth - 1.0) < 0.05


def test_the_session_report_shows_the_probe(probe_session, tmp_path, capsys):
    import base64
    import io
    import re

    from PIL import Image

    root, world = probe_session
    assert main(["probe", str(root), "--out", str(tmp_path / "room.exr")]) == 0
    manifest = Session.read(root)
    assert manifest["products"]["probe"]["file"] == "products/probe.exr"
    kept, given = read_environment(root / "products" / "probe.exr"), read_environment(tmp_path / "room.exr")
    assert np.array_equal(kept.coefficients, given.coefficients)
    assert main(["report", str(root)]) == 0
    html = (root / "products" / "report.html").read_text()
    assert "<h2>Light probe</h2>" in html and "Not in this session:</b> no light probe" not in html
    # the map's figure: a picture of the room (the lamps and the dim walls both visible), not a blank frame
    uri = re.search(r"<img src='data:image/png;base64,([^']+)' alt='light probe map'>", html)
    img = np.asarray(Image.open(io.BytesIO(base64.b64decode(uri.group(1)))).convert("RGB")).astype(float)
    assert img.std() > 20
    # the report's figures, as the probe's own report states them
    report = json.loads((root / "products" / "probe.json").read_text())
    assert f"{100 * report['map']['observed_fraction']:.0f} %" in html
    assert f"chart RMS reflectance error {report['spectral']['chart_rmse']:.3f}" in html
    assert "<th>brackets</th><td>7</td>" in html


@pytest.fixture(scope="module")
def filtered_session(probe_session):
    """The same room captured through the lens filter (``kogei mock --world probe:20:filtered``), 4 brackets 4 EV
    apart (the merge reads each frame's exposure; fewer frames keep the test short)."""
    from mocks.probe_world import PROBE_FILTER

    root0, _ = probe_session
    base = root0.parent
    world = ProbeWorld.probe(20.0, width=SIZE[0], height=SIZE[1], lens_filter=PROBE_FILTER)
    plan = CapturePlan("probe", sphere_radius_mm=20.0, brackets=("1/4000", "1/250", "1/15", "1"))
    return _capture(world, plan, base / "probe-filtered", base / "station-filtered", seed=4)


def test_two_probe_sessions_make_a_six_channel_probe_and_the_report_says_so(probe_session, filtered_session,
                                                                           tmp_path):
    from mocks.probe_world import write_filter_csv

    root, world = probe_session
    csv = write_filter_csv(tmp_path / "lens-filter.csv")
    assert main(["probe", str(root), "--filter-frames", str(filtered_session), "--filter", str(csv), "--out",
                 str(tmp_path / "room.exr"), "--quiet"]) == 0
    env = read_environment(tmp_path / "room.exr", world.grid)
    assert env.coefficients.shape[2] == 6
    # through the station's fake gphoto2 the filtered frames are darker where the notch is: the second set's
    # chart is the filter's (the floor is still right in units of the chart's white, within 5 %)
    truth = float(world.environment.luminance([[0.0, 0.0, -1.0]])[0]) / world.chart_white_luminance()
    assert abs(float(env.luminance([[0.0, 0.0, -1.0]])[0]) / truth - 1.0) < 0.05
    report = json.loads((root / "products" / "probe.json").read_text())
    assert report["spectral"]["method"] == "twolight" and len(report["spectral"]["filter_frames"]) == 4
    assert main(["report", str(root)]) == 0
    html = (root / "products" / "report.html").read_text()
    assert "4 brackets through the filter" in html and "basis spectra kept</th><td>6: 99 % of directions" in html
