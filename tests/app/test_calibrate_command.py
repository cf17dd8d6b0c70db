"""`kogei calibrate` end to end: the simulated station scans a reference sphere through the real
drivers, the calibration recovers the station's true sensor pose, and is stored and referenced
with its checksum; bad input gets one-line errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.capture.devices import build_devices
from app.capture.runner import CaptureHooks, CapturePlan, run_capture
from app.cli import main
from app.errors import UsageError
from app.session import Session
from app.workflows.calibration import session_calibration
from mocks.station import SimulatedStation
from mocks.world import World


@pytest.fixture(scope="module")
def sphere_session(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("cal")
    with SimulatedStation(World.calibration_sphere(25.0, 60.0), root=tmp / "station", seed=5, n_points=400) as st:
        plan = CapturePlan("scan", steps=72, passes=1, camera=False)
        config = {"turntable": {"port": str(st.turntable_path)}, "profiler": {"port": str(st.profiler_path)}}
        s = Session.create(tmp / "cal", plan=plan.to_dict())
        run_capture(s, plan, build_devices(config, s.root), CaptureHooks(before_pass=lambda p, n: st.place(p)))
        s.close()
        truth = st.sensor_to_room
    return tmp / "cal", truth


def test_calibration_recovers_the_station_pose(sphere_session, capsys):
    root, truth = sphere_session
    assert main(["calibrate", str(root), "--sphere-radius", "25"]) == 0
    assert "residual rms" in capsys.readouterr().out
    manifest = Session.read(root)
    cal = session_calibration(root, manifest)
    rot = cal.sensor_to_room[:3, :3].T @ truth[:3, :3]
    angle = np.degrees(np.arccos(np.clip((np.trace(rot) - 1) / 2, -1, 1)))
    assert angle < 0.05 and np.linalg.norm(cal.sensor_to_room[:3, 3] - truth[:3, 3]) < 0.05
    # the sphere sits 60 mm off the axis, resting on the table: its centre is at height 25 mm
    assert np.hypot(*cal.sphere_center_mm[:2]) == pytest.approx(60.0, abs=0.05)
    assert cal.sphere_center_mm[2] == pytest.approx(25.0, abs=0.05)
    assert manifest["calibration"]["path"] == "calibration.json" and manifest["calibration"]["rms_mm"] < 0.1
    assert any(h["event"] == "calibration" for h in manifest["history"])


def test_wrong_radius_is_reported(sphere_session, capsys):
    root, _ = sphere_session
    code = main(["calibrate", str(root), "--sphere-radius", "30"])
    err = capsys.readouterr().err
    assert code == 2 and "radius" in err and "Traceback" not in err


def test_tampered_calibration_is_refused(sphere_session, tmp_path):
    root, _ = sphere_session
    main(["calibrate", str(root), "--sphere-radius", "25"])
    manifest = Session.read(root)
    data = json.loads((root / "calibration.json").read_text())
    data["rms_mm"] = 0.0
    copy = tmp_path / "copy"
    copy.mkdir()
    (copy / "calibration.json").write_text(json.dumps(data))
    with pytest.raises(UsageError, match="checksum"):
        session_calibration(copy, manifest)
    with pytest.raises(UsageError, match="no scanner calibration"):
        session_calibration(copy, {"calibration": None})


@pytest.mark.parametrize("args,match", [
    (["{tmp}", "--sphere-radius", "25"], "not a kogei session"),
    (["{tmp}", "--sphere-radius", "-1"], "positive number"),
])
def test_bad_input(args, match, tmp_path, capsys):
    code = main(["calibrate", *[a.format(tmp=tmp_path) for a in args]])
    err = capsys.readouterr().err
    assert code == 2 and match in err


def test_incomplete_pass_is_refused(tmp_path, capsys):
    plan = CapturePlan("scan", steps=4, passes=1, camera=False)
    Session.create(tmp_path / "s", plan=plan.to_dict()).close()
    code = main(["calibrate", str(tmp_path / "s"), "--sphere-radius", "25"])
    assert code == 2 and "not complete" in capsys.readouterr().err
