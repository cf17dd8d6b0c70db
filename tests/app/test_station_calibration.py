"""`kogei calibrate --camera` / `--lamp` on bad input: one-line errors (exit code 2) that say what to do,
and nothing written.  The positive path (real board and mirror-sphere sessions against the
simulation's truth) is `tests/app/test_demo.py`'s."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from app.capture.devices import build_devices
from app.capture.runner import CaptureHooks, CapturePlan, run_capture
from app.cli import main
from app.errors import UsageError
from app.session import MANIFEST, Session
from app.workflows.calibration import install_calibration
from app.workflows.station_calibration import calibrate_lamp_session, install_station_calibration
from mocks.station import SimulatedStation
from mocks.world import World
from processing.geometry.calibration import ScannerCalibration, ideal_sensor_to_room
from processing.geometry.camera_calibration import CameraCalibration
from tests.app.cli_checks import fails_with_one_line


def _camera_only(world: World, root: Path, plan: CapturePlan, station: Path) -> Path:
    """Capture a camera-only plan of ``world`` (as ``app/demo/station.py`` does)."""
    with SimulatedStation(world, root=station, seed=2) as st:
        config = {"turntable": {"port": str(st.turntable_path)},
                  "camera": {"kind": "gphoto2", "executable": str(st.gphoto2_path)}}
        s = Session.create(root, plan=plan.to_dict())
        try:
            run_capture(s, plan, build_devices(config, s.root), CaptureHooks(before_pass=lambda p, n: st.place(p)))
        finally:
            s.close()
    return root


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    """Small sessions: scanner-calibrated (no frames), uncalibrated scan, empty board/lamp, board without a board."""
    base = tmp_path_factory.mktemp("station")
    scan = CapturePlan("scan", steps=8, passes=1, camera=True).to_dict()
    with Session.create(base / "scanner", plan=scan) as s:
        # a plausible scanner calibration (the doctest's); no RAW frames of the sphere
        cal = ScannerCalibration(ideal_sensor_to_room(), 20.0, np.array([40.0, 0, 20]), 0.05, 0.2, 40, 4000, 9000,
                                 0.04, 20.001, np.arange(2), np.array([0.05, 0.06]))
        install_calibration(s, cal.to_dict())
    Session.create(base / "uncalibrated", plan=scan).close()
    Session.create(base / "board-empty", plan=CapturePlan("camera-calibration").to_dict()).close()
    Session.create(base / "lamp-no-radius", plan=CapturePlan("lamp-calibration").to_dict()).close()
    Session.create(base / "lamp", plan=CapturePlan("lamp-calibration", sphere_radius_mm=20.0).to_dict()).close()
    # the camera-calibration plan shot at a reference sphere: frames without a board
    _camera_only(World.calibration_sphere(20.0, 40.0, width=240, height=160, chart_first=False), base / "no-board",
                 CapturePlan("camera-calibration", steps=3, passes=1), base / "station-no-board")
    # a scanner-calibrated session with RAW frames of the sphere (the same frames, calibration installed)
    shutil.copytree(base / "no-board", base / "sphere-photos")
    with Session.open(base / "sphere-photos") as s:
        install_calibration(s, cal.to_dict())
    k = World.calibration_sphere(20.0, 40.0, width=960, height=640)
    untied = CameraCalibration((960, 640), k.camera_intrinsics(), np.zeros(5), np.eye(4), room_to_camera=None)
    (base / "untied.json").write_text(json.dumps(untied.to_dict()))
    tied = CameraCalibration((960, 640), k.camera_intrinsics(), np.zeros(5), np.eye(4),
                             room_to_camera=k.room_to_camera())
    (base / "tied.json").write_text(json.dumps(tied.to_dict()))
    # a camera-calibrated board session, and a copy whose camera_calibration.json was edited by hand
    with Session.create(base / "board-calibrated", plan=CapturePlan("camera-calibration").to_dict()) as s:
        install_station_calibration(s, "camera_calibration", tied.to_dict())
    shutil.copytree(base / "board-calibrated", base / "board-edited")
    edited = json.loads((base / "board-edited" / "camera_calibration.json").read_text())
    edited["K"][0][0] *= 1.01
    (base / "board-edited" / "camera_calibration.json").write_text(json.dumps(edited))
    (base / "not-a-session").mkdir()
    (base / "not-a-session" / "camera_calibration.json").write_text(json.dumps(tied.to_dict()))
    (base / "garbage.json").write_text("{not json")
    (base / "wrong-schema.json").write_text(json.dumps({"schema": "kogei.scanner_calibration", "version": 1}))
    return base



# ---------------------------------------------------------------------------- argument combinations
@pytest.mark.parametrize("args, needles", [
    (["--camera", "B"], ["--scanner"]),
    (["--camera", "B", "--scanner", "S", "--lamp", "L"], ["not both"]),
    (["--camera", "B", "--lamp", "L"], ["not both"]),
    (["--lamp", "L"], ["--camera-calibration"]),
    ([], ["--camera BOARD_SESSION", "--lamp LAMP_SESSION", "--sphere-radius"]),
    # options of one mode given to another are refused, not silently ignored
    (["SPHERE", "--camera", "B", "--scanner", "S"], ["SESSION", "--camera"]),
    (["SPHERE", "--lamp", "L", "--camera-calibration", "C"], ["SESSION", "--lamp"]),
    (["SPHERE", "--sphere-radius", "20", "--scanner", "S"], ["--scanner", "--camera"]),
    (["SPHERE", "--sphere-radius", "20", "--camera-calibration", "C"], ["--camera-calibration", "--lamp"]),
    (["--camera", "B", "--scanner", "S", "--camera-calibration", "C"], ["--camera-calibration", "--lamp"]),
    (["--lamp", "L", "--camera-calibration", "C", "--scanner", "S"], ["--scanner", "--camera"]),
    (["--lamp", "L", "--camera-calibration", "C", "--focal-mm", "50", "--sensor-mm", "36"], ["--focal-mm"]),
])
def test_calibrate_mode_arguments_are_checked(args, needles, sessions, capsys):
    _fails(["calibrate", *args], capsys, sessions, *needles)


@pytest.mark.parametrize("extra", [["--focal-mm", "50"], ["--sensor-mm", "36"], ["--focal-mm", "-5", "--sensor-mm", "36"]])
def test_manual_focal_is_checked_before_any_frame_is_read(extra, sessions, capsys):
    # the board session has no frames: the argument error must come first, not "no RAW frames"
    err = _fails(["calibrate", "--camera", str(sessions / "board-empty"), "--scanner", str(sessions / "scanner"),
                  *extra], capsys, sessions, "--focal-mm")
    assert "RAW" not in err


@pytest.mark.parametrize("rms", ["-1", "0", "nan"])
def test_a_bad_max_rms_is_refused_before_any_frame(rms, sessions, capsys):
    _fails(["calibrate", "--camera", str(sessions / "board-empty"), "--scanner", str(sessions / "sphere-photos"),
            f"--max-rms={rms}"], capsys, sessions, "--max-rms")


# ---------------------------------------------------------------------------- camera: the sessions
def test_a_scan_session_is_not_a_board_session(sessions, capsys):
    _fails(["calibrate", "--camera", str(sessions / "scanner"), "--scanner", str(sessions / "sphere-photos")], capsys,
           sessions, "'scan'", "not a camera-calibration", "--plan camera-calibration")


def test_a_board_session_without_frames(sessions, capsys):
    _fails(["calibrate", "--camera", str(sessions / "board-empty"), "--scanner", str(sessions / "sphere-photos")],
           capsys, sessions, "no RAW frames", "--plan camera-calibration")


def test_frames_without_a_board_say_how_many_were_rejected(sessions, capsys):
    # the scanner session has RAW frames (of the sphere), so only the board can fail
    err = _fails(["calibrate", "--camera", str(sessions / "no-board"), "--scanner", str(sessions / "sphere-photos")],
                 capsys, sessions, "no-board", "board")
    assert "3 of 3 frames rejected" in err and "0 usable" in err, err


def test_a_scanner_session_without_a_scanner_calibration(sessions, capsys):
    _fails(["calibrate", "--camera", str(sessions / "no-board"), "--scanner", str(sessions / "uncalibrated")],
           capsys, sessions, "no scanner calibration", "kogei calibrate")


def test_a_scanner_session_without_raw_frames_is_refused_before_the_board_is_read(sessions, capsys):
    # the scanner session has no RAW frames: said at once (not after minutes of board detection)
    _fails(["calibrate", "--camera", str(sessions / "no-board"), "--scanner", str(sessions / "scanner")],
           capsys, sessions, "--scanner", "no RAW frames of the sphere", "--plan sphere-calibration", "--camera-angles")


def test_missing_sessions_are_named(sessions, capsys):
    _fails(["calibrate", "--camera", str(sessions / "nowhere"), "--scanner", str(sessions / "scanner")], capsys,
           sessions, "nowhere")
    _fails(["calibrate", "--camera", str(sessions / "no-board"), "--scanner", str(sessions / "nowhere")], capsys,
           sessions, "nowhere")


# ---------------------------------------------------------------------------- lamps
def test_a_lamp_session_without_a_radius(sessions, capsys):
    _fails(["calibrate", "--lamp", str(sessions / "lamp-no-radius"), "--camera-calibration",
            str(sessions / "untied.json")], capsys, sessions, "--sphere-radius")


@pytest.mark.parametrize("radius", ["-5", "0", "nan", "inf"])
def test_a_bad_mirror_sphere_radius_is_refused_before_any_frame(radius, sessions, capsys):
    _fails(["calibrate", "--lamp", str(sessions / "lamp"), "--camera-calibration", str(sessions / "tied.json"),
            f"--sphere-radius={radius}"], capsys, sessions, "--sphere-radius", radius)


@pytest.mark.parametrize("n", ["0", "-1", "99"])
def test_a_bad_number_of_lamps_is_refused_before_any_frame(n, sessions, capsys):
    _fails(["calibrate", "--lamp", str(sessions / "lamp"), "--camera-calibration", str(sessions / "tied.json"),
            f"--lamps={n}"], capsys, sessions, "--lamps", n)


def test_a_lamp_session_without_frames(sessions, capsys):
    _fails(["calibrate", "--lamp", str(sessions / "lamp"), "--camera-calibration", str(sessions / "tied.json")],
           capsys, sessions, "no RAW frames of the mirror sphere", "--plan lamp-calibration")


def test_a_board_session_is_not_a_lamp_session(sessions, capsys):
    _fails(["calibrate", "--lamp", str(sessions / "no-board"), "--camera-calibration", str(sessions / "untied.json")],
           capsys, sessions, "not a lamp-calibration", "--plan lamp-calibration")


def test_an_unknown_lamp_model(sessions, capsys):
    with pytest.raises(SystemExit) as exc:        # argparse's choices
        main(["calibrate", "--lamp", str(sessions / "lamp"), "--camera-calibration", str(sessions / "untied.json"),
              "--lamp-model", "bogus"])
    assert exc.value.code == 2 and "--lamp-model" in capsys.readouterr().err
    with pytest.raises(UsageError, match="--lamp-model must be auto, point or distant"):
        calibrate_lamp_session(sessions / "lamp", sessions / "untied.json", model="bogus")


@pytest.mark.parametrize("spectrum", ["bogus", "-3000", "nan"])
def test_an_unknown_lamp_spectrum(spectrum, sessions, capsys):
    _fails(["calibrate", "--lamp", str(sessions / "lamp"), "--camera-calibration", str(sessions / "untied.json"),
            "--lamp-spectrum", spectrum], capsys, sessions, "--lamp-spectrum")


@pytest.mark.parametrize("source, needles", [
    ("garbage.json", ["not JSON"]),
    ("wrong-schema.json", ["--camera-calibration"]),
    ("untied.json", ["not tied to the scanner", "--scanner"]),
    ("nowhere.json", ["not found"]),
    ("board-empty", ["camera_calibration.json", "not found", "kogei calibrate --camera"]),
    ("board-edited", ["camera_calibration.json", "checksum"]),
    ("not-a-session", ["session.json"]),
])
def test_a_bad_camera_calibration_for_the_lamps(source, needles, sessions, capsys):
    _fails(["calibrate", "--lamp", str(sessions / "lamp"), "--camera-calibration", str(sessions / source)], capsys,
           sessions, "--camera-calibration", *needles)


# ---------------------------------------------------------------------------- kogei process --camera-calibration
def test_process_refuses_a_camera_calibration_not_tied_to_the_scanner(sessions, capsys):
    # refused when installed, not after the session is meshed
    _fails(["process", str(sessions / "scanner"), "--camera-calibration", str(sessions / "untied.json")], capsys,
           sessions, "--camera-calibration", "not tied to the scanner", "--scanner")


@pytest.mark.parametrize("source, needles", [
    ("nowhere.json", ["not found"]),
    ("wrong-schema.json", []),
    ("garbage.json", ["not JSON"]),
    ("board-edited", ["checksum"]),
    ("board-empty", ["not found"]),
])
def test_process_refuses_a_bad_camera_calibration(source, needles, sessions, capsys):
    _fails(["process", str(sessions / "scanner"), "--camera-calibration", str(sessions / source)], capsys, sessions,
           "--camera-calibration", source, *needles)


def test_the_lamps_use_a_calibrated_board_session(sessions, capsys):
    # the good board session passes every check up to the lamp session's (missing) frames
    _fails(["calibrate", "--lamp", str(sessions / "lamp"), "--camera-calibration", str(sessions / "board-calibrated")],
           capsys, sessions, "no RAW frames of the mirror sphere")


@pytest.mark.parametrize("source, needles", [("garbage.json", ["not JSON"]), ("nowhere", ["not found"])])
def test_process_refuses_a_bad_lamp_calibration(source, needles, sessions, capsys):
    _fails(["process", str(sessions / "scanner"), "--lamp-calibration", str(sessions / source)], capsys, sessions,
           "--lamp-calibration", source, *needles)


@pytest.mark.parametrize("source", ["bench", 7, {"pass": "one"}, {"pass": True}])
def test_a_scanner_calibration_with_an_odd_source_record(source, sessions, capsys, tmp_path):
    # session.json is untrusted: an odd calibration.source is read as pass 1, not a traceback
    root = tmp_path / "sphere"
    shutil.copytree(sessions / "sphere-photos", root)
    manifest = json.loads((root / MANIFEST).read_text())
    manifest["calibration"]["source"] = source
    (root / MANIFEST).write_text(json.dumps(manifest))
    _fails(["calibrate", "--camera", str(sessions / "no-board"), "--scanner", str(root)], capsys, sessions,
           "3 of 3 frames rejected")


def _fails(argv: list[str], capsys, base: Path, *needles: str) -> str:
    return fails_with_one_line(argv, capsys, base, *needles)
