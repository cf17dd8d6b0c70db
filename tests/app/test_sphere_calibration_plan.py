"""The sphere-calibration plan: one pass of profiles of the reference sphere, no chart, photos only when asked;
``kogei capture --plan sphere-calibration`` on the simulated station, then ``kogei calibrate``.

Ground truth: the simulated station's own sensor pose (``SimulatedStation.sensor_to_room``) and the sphere's
placement (60 mm off the axis, radius 25 mm), as in tests/app/test_calibrate_command.py.
"""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from app.capture.runner import CapturePlan, placement_prompt
from app.cli import main
from app.session import Session
from app.workflows.calibration import session_calibration
from mocks.station import SimulatedStation
from mocks.world import World

RAW_SUFFIXES = {".cr2", ".cr3", ".nef", ".arw", ".dng", ".raf", ".orf", ".rw2"}


def test_the_plan_is_one_pass_of_profiles_without_chart_or_camera():
    plan = CapturePlan("sphere-calibration", steps=8)
    assert (plan.passes, plan.chart, plan.camera, plan.camera_angles_deg) == (1, False, False, ())
    assert [a.kind for a in plan.actions()] == ["profile"] * 8
    assert CapturePlan.from_dict(json.loads(json.dumps(plan.to_dict()))) == plan
    assert CapturePlan("sphere-calibration").steps == 200
    assert "reference sphere" in placement_prompt("sphere-calibration", 1)


def test_photos_of_the_sphere_only_at_the_angles_given():
    plan = CapturePlan("sphere-calibration", steps=8, camera_angles_deg=(0.0, 90.0))
    assert plan.camera and [a.kind for a in plan.actions()].count("frame") == 2
    assert not [a for a in plan.actions() if a.kind == "chart"]
    with pytest.raises(ValueError, match="no colour-chart frame"):
        CapturePlan("sphere-calibration", chart=True)


def test_cli_sphere_calibration_takes_no_raw_frame_and_calibrates(tmp_path, capsys):
    out = tmp_path / "sphere"
    with SimulatedStation(World.calibration_sphere(25.0, 60.0), root=tmp_path / "station", seed=5,
                          n_points=400) as st:
        code = main(["capture", "--plan", "sphere-calibration", "--turntable", str(st.turntable_path), "--laser",
                     str(st.profiler_path), "--camera", f"gphoto2:{st.gphoto2_path}", "--steps", "72", "--out",
                     str(out), "--unattended", "--quiet",
                     "--before-pass", f"{sys.executable} -m app.cli mock place --control {st.control_dir}"])
        truth = st.sensor_to_room
    assert code == 0, capsys.readouterr().err
    m = Session.read(out)
    assert m["status"] == "complete" and m["plan"]["kind"] == "sphere-calibration"
    kinds = {r["kind"] for r in m["captures"].values()}
    assert kinds == {"profile", "profiles"}, kinds                 # no chart, no photo
    assert not [p for p in out.rglob("*") if p.suffix.lower() in RAW_SUFFIXES]
    assert main(["calibrate", str(out), "--sphere-radius", "25"]) == 0
    cal = session_calibration(out, Session.read(out))
    rot = cal.sensor_to_room[:3, :3].T @ truth[:3, :3]
    angle = np.degrees(np.arccos(np.clip((np.trace(rot) - 1) / 2, -1, 1)))
    # the same tolerance as the scan-plan calibration (tests/app/test_calibrate_command.py): 0.05 deg, 0.05 mm
    assert angle < 0.05 and np.linalg.norm(cal.sensor_to_room[:3, 3] - truth[:3, 3]) < 0.05
    assert np.hypot(*cal.sphere_center_mm[:2]) == pytest.approx(60.0, abs=0.05)


def test_cli_sphere_photos_need_a_camera(tmp_path, capsys):
    code = main(["capture", "--plan", "sphere-calibration", "--turntable", "x", "--laser", "y", "--camera", "none",
                 "--camera-angles", "0,90", "--out", str(tmp_path / "a"), "--unattended"])
    err = capsys.readouterr().err
    assert code == 2 and "need a camera" in err and "Traceback" not in err
    code = main(["capture", "--plan", "sphere-calibration", "--turntable", "x", "--camera", "none",
                 "--out", str(tmp_path / "b"), "--unattended"])
    assert code == 2 and "--laser PORT is required" in capsys.readouterr().err
