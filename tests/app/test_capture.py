"""Capture sessions against the simulated station over real ptys: a clean scan, RAW frames through the
fake gphoto2 and the hot folder, the fault matrix (every fault recovered with the same data as a
fault-free run, or reported with the session intact and resumable), Ctrl-C, and kill -9 + --resume."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from app.capture.devices import build_devices
from app.capture.runner import (
    CaptureHooks,
    CaptureInterrupted,
    CapturePlan,
    CaptureSettings,
    load_pass_profiles,
    run_capture,
)
from app.session import Session
from mocks.station import SimulatedStation
from mocks.waiting import wait_until
from mocks.world import World

ROOT = Path(__file__).resolve().parents[2]
N_POINTS = 96


def _world() -> World:
    return World.hawk(2000, width=48, height=32)


def _station(tmp_path: Path, name: str = "station", **kw) -> SimulatedStation:
    return SimulatedStation(_world(), root=tmp_path / name, seed=3, n_points=N_POINTS, **kw)


def _config(st: SimulatedStation, camera: str = "none", **cam) -> dict:
    config = {"turntable": {"port": str(st.turntable_path)},
              "profiler": {"port": str(st.profiler_path), "baudrate": 115200}}
    if camera == "gphoto2":
        config["camera"] = {"kind": "gphoto2", "executable": str(st.gphoto2_path), **cam}
    elif camera == "hotfolder":
        config["camera"] = {"kind": "hotfolder", "folder": str(st.hotfolder), "stable_s": 0.15, **cam}
    return config


def _capture(st: SimulatedStation, root: Path, plan: CapturePlan, camera: str = "none", *, progress=None,
             settings: CaptureSettings | None = None, session: Session | None = None, **cam):
    config = _config(st, camera, **cam)
    s = session or Session.create(root, plan=plan.to_dict(), settings={"device_config": config})
    devices = build_devices(config, s.root, shutter=st.shoot if camera == "hotfolder" else None)
    hooks = CaptureHooks(before_pass=lambda p, n: st.place(p), progress=progress)
    try:
        return run_capture(s, plan, devices, hooks, settings or CaptureSettings(reconnect_timeout_s=5.0))
    finally:
        s.close()


def _profiles(root: Path, passes: int) -> list[dict]:
    return [load_pass_profiles(root, p) for p in range(1, passes + 1)]


def _same(a: list[dict], b: list[dict]) -> None:
    for pa, pb in zip(a, b, strict=True):
        np.testing.assert_allclose(pa["angles_deg"], pb["angles_deg"], rtol=0, atol=1e-9)
        np.testing.assert_array_equal(pa["x_mm"], pb["x_mm"])
        np.testing.assert_array_equal(pa["z_mm"], pb["z_mm"])


PLAN = CapturePlan("scan", steps=12, passes=2, camera=False)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """A fault-free run of PLAN: the data every recovered run must reproduce exactly."""
    tmp = tmp_path_factory.mktemp("reference")
    with _station(tmp) as st:
        report = _capture(st, tmp / "session", PLAN)
    return report, _profiles(tmp / "session", PLAN.passes), tmp / "session"


def test_clean_scan(reference, tmp_path):
    report, profiles, root = reference
    m = Session.read(root)
    assert m["status"] == "complete" and report.taken == 24 and report.skipped == 0
    for p, prof in enumerate(profiles, start=1):
        assert prof["x_mm"].shape == (12, N_POINTS)
        # confirmed angles: the planned ones rounded to a whole motor step (3200 per revolution)
        np.testing.assert_allclose(prof["angles_deg"], np.arange(12) * 30.0, atol=0.5 * 360 / 3200 + 1e-9)
        np.testing.assert_allclose(prof["angles_deg"] * 3200 / 360, np.round(prof["angles_deg"] * 3200 / 360),
                                   atol=1e-9)
        valid = np.isfinite(prof["z_mm"])
        assert valid.any(axis=1).all()          # every profile sees the object or the table
        assert m["passes"][str(p)]["status"] == "complete"
    # the two placements differ (the object was re-placed), so their profiles do too
    assert not np.array_equal(np.isfinite(profiles[0]["z_mm"]), np.isfinite(profiles[1]["z_mm"]))
    for rec in m["captures"].values():
        assert hashlib_ok(root, rec)
    dev = m["devices"]
    assert dev["turntable"]["firmware"] == "Horus 0.2" and dev["profiler"]["model"]
    log = (root / "wire" / "turntable.log").read_text()
    sent = [line.split(" > ", 1)[1] for line in log.splitlines() if " > " in line]
    assert " < ok" in log and any(c.startswith("G1 X") for c in sent)
    assert sent[-3:] == ["M70 T1\\n", "M70 T2\\n", "M18\\n"]      # lasers off, motor released at the end


def hashlib_ok(root: Path, rec: dict) -> bool:
    import hashlib

    return hashlib.sha256((root / rec["file"]).read_bytes()).hexdigest() == rec["sha256"]


def test_lasers_off_and_motor_released_after_the_capture(tmp_path):
    with _station(tmp_path) as st:
        _capture(st, tmp_path / "s", CapturePlan("scan", steps=4, passes=1, camera=False))
        time.sleep(0.1)
        assert not any(st.turntable.lasers) and not st.turntable.motor_enabled


def _at_step(k: int, action, stop_after: int | None = None, stop=None):
    """A progress hook that runs ``action`` once after ``k`` actions (and ``stop`` ``stop_after`` later)."""
    fired = []

    def hook(p):
        if p.done == k and not fired:
            fired.append(True)
            action()
        if stop is not None and p.done == k + stop_after:
            stop()
    return hook


def _set(faults, **values):
    return lambda: [setattr(faults, k, v) for k, v in values.items()]


def _log(root: Path, device: str) -> str:
    return (root / "wire" / f"{device}.log").read_text()


def _noted(report, *words: str) -> bool:
    return any(w in r for r in report.recoveries for w in words)


def _slow_reply_seen(root: Path) -> bool:
    """Some turntable reply came >= 0.2 s after the command before it (the fault's delay)."""
    import datetime as dt

    last_sent = None
    for line in _log(root, "turntable").splitlines():
        stamp, _, direction = line.split(" ", 3)[:3]
        t = dt.datetime.strptime(stamp, "%Y-%m-%dT%H:%M:%S.%fZ").timestamp()
        if direction == ">":
            last_sent = t
        elif direction == "<" and last_sent is not None and t - last_sent >= 0.2:
            return True
    return False


# fault -> (switch it on, evidence that it really happened and was dealt with)
RECOVERED = {
    "turntable garbage": (lambda st: _set(st.turntable_faults, garbage_replies=3),
                          lambda rep, root: "\\xf0" in _log(root, "turntable")),
    "turntable lost replies": (lambda st: _set(st.turntable_faults, drop_replies=2),
                               lambda rep, root: _noted(rep, "reply lost", "ok lost")),
    "turntable slow replies": (lambda st: (_set(st.turntable_faults, reply_delay_s=0.2),
                                           _set(st.turntable_faults, reply_delay_s=0.0)),
                               lambda rep, root: _slow_reply_seen(root)),
    "turntable reset": (lambda st: _set(st.turntable_faults, reset_on_command=1),
                        lambda rep, root: _noted(rep, "device reset")),
    "turntable unplug + replug": (lambda st: _set(st.turntable_faults, unplug_on_command=1, replug_after_s=0.5),
                                  lambda rep, root: _noted(rep, "port vanished") and _noted(rep, "reconnected")),
    "laser watchdog": (lambda st: st.turntable.fire_laser_watchdog,
                       lambda rep, root: "watchdog" in _log(root, "turntable")),
    "profiler corrupted frames": (lambda st: _set(st.profiler_faults, corrupt_frames=2),
                                  lambda rep, root: _noted(rep, "re-requested")),
    "profiler dropped frames": (lambda st: _set(st.profiler_faults, drop_frames=2),
                                lambda rep, root: _noted(rep, "re-requested")),
    "profiler garbage": (lambda st: _set(st.profiler_faults, garbage_frames=2, garbage_replies=2),
                         lambda rep, root: "\\xf0" in _log(root, "profiler")),
    "profiler reset": (lambda st: _set(st.profiler_faults, reset_on_command=1),
                       lambda rep, root: _noted(rep, "device reset")),
    "profiler unplug + replug": (lambda st: _set(st.profiler_faults, unplug_on_command=1, replug_after_s=0.5),
                                 lambda rep, root: _noted(rep, "port vanished") and _noted(rep, "reconnected")),
}


@pytest.mark.parametrize("fault", list(RECOVERED))
def test_fault_is_recovered_with_the_same_data(fault, reference, tmp_path):
    _, expected, _ = reference
    switch, evidence = RECOVERED[fault]
    with _station(tmp_path) as st:
        on = switch(st)
        on, off = on if isinstance(on, tuple) else (on, None)   # a fault switched off 3 actions later
        report = _capture(st, tmp_path / "s", PLAN, progress=_at_step(5, on, 3, off))
    assert report.status == "complete" and report.taken == 24
    _same(_profiles(tmp_path / "s", PLAN.passes), expected)
    assert evidence(report, tmp_path / "s"), f"no trace of the {fault} fault: {report.recoveries}"
    notes = [h["detail"] for h in Session.read(tmp_path / "s")["history"] if h["event"] == "note"]
    assert notes == report.recoveries            # what was recovered is in the session's history


def test_laser_watchdog_without_reassertion_would_lose_data(tmp_path):
    """Guard for the test above: with the laser off the station really returns nothing."""
    with _station(tmp_path) as st:
        from drivers.profiler import LaserProfiler
        from drivers.transport import SerialTransport

        lp = LaserProfiler(SerialTransport(str(st.profiler_path)), max_points=4096)
        lp.connect()
        lp.laser(True)
        assert not lp.profile(2.0).valid.any()       # T1 never switched on
        lp.close()


def test_unplugged_device_is_reported_and_the_session_resumes(reference, tmp_path):
    _, expected, _ = reference
    with _station(tmp_path) as st:
        quick = CaptureSettings(reconnect_timeout_s=0.5)
        with pytest.raises(CaptureInterrupted, match=r"(?s)profiler.*did not come back.*--resume"):
            _capture(st, tmp_path / "s", PLAN, settings=quick,
                     progress=_at_step(16, _set(st.profiler_faults, unplug_on_command=1)))
        m = Session.read(tmp_path / "s")
        assert m["status"] == "interrupted" and m["history"][-1]["event"] == "interrupted"
        done = [k for k, r in m["captures"].items() if r["kind"] == "profile"]
        assert 14 <= len(done) < 24
        st.profiler.replug()
        s = Session.open(tmp_path / "s")
        report = _capture(st, tmp_path / "s", PLAN, session=s)
    assert report.status == "complete" and report.skipped == len(done) and report.taken == 24 - len(done)
    _same(_profiles(tmp_path / "s", PLAN.passes), expected)


def test_a_move_whose_end_is_lost_retakes_the_pass_in_one_table_frame(tmp_path):
    """The host hears nothing from the board during a move (the move runs to its end): after the reset
    the table's angle is known only to within that move, so the profiles taken before it are taken again
    in the table's new frame -- every profile of the pass one revolution seen from one zero."""
    plan = CapturePlan("scan", steps=12, passes=1, camera=False)
    with _station(tmp_path) as st:
        report = _capture(st, tmp_path / "s", plan, progress=_at_step(5, _set(st.turntable_faults,
                                                                                silent_after_move=1)))
        got = _profiles(tmp_path / "s", 1)[0]
        # the lost move (120 -> 150 deg) ran to its end: the table's new zero is the old one turned by
        # that move, and the last capture (a profile taken again) says by how much
        offset_deg = st.table_angle_deg - got["angles_deg"][4]
        truth = [st.profile_at(a + offset_deg) for a in got["angles_deg"]]
    assert report.status == "complete"
    assert _noted(report, "stopped answering") and _noted(report, "taken again")
    assert offset_deg == pytest.approx(30.0, abs=0.1)
    for i, (x_um, z_um, _) in enumerate(truth):          # every profile, before the loss and after it
        np.testing.assert_allclose(got["z_mm"][i], z_um / 1000.0, rtol=0, atol=1e-3,
                                   err_msg=f"profile {i}")
        np.testing.assert_allclose(got["x_mm"][i], x_um / 1000.0, rtol=0, atol=1e-3)   # the wire: whole um
    np.testing.assert_allclose(got["angles_deg"], np.arange(12) * 30.0, atol=0.5 * 360 / 3200 + 1e-9)
    m = Session.read(tmp_path / "s")
    assert m["passes"]["1"]["table_frame"] == 1 and not m["passes"]["1"].get("angle_uncertain_deg")
    assert report.taken == 12 + 5                          # the five profiles before the loss, again


def test_the_progress_bar_follows_a_growing_total():
    """Captures taken again add to the plan's total: the terminal's bar must not run past its end."""
    import io

    from rich.console import Console
    from rich.progress import Progress

    from app.capture.runner import CaptureProgress
    from app.cli.capture import _progress

    pr = _progress(quiet=False)
    pr._bar = Progress(console=Console(file=io.StringIO()))
    pr.update(CaptureProgress(5, 12, 1, "p01/profile/0004", 1.0, 2.0))
    pr.update(CaptureProgress(13, 17, 1, "p01/profile/0000", 3.0, 1.0))      # five taken again
    task = pr._bar.tasks[0]
    assert (task.completed, task.total) == (13, 17)


def test_resume_after_a_crash_mid_move_retakes_the_pass_in_one_table_frame(tmp_path):
    """A crash while a move was in flight, the board reset since: on --resume the angle is known only to
    within that move, so the pass's profiles are all taken (again) in one new table frame."""
    plan = CapturePlan("scan", steps=12, passes=1, camera=False)
    with _station(tmp_path) as st:
        with pytest.raises(CaptureInterrupted):
            _capture(st, tmp_path / "s", plan, settings=CaptureSettings(reconnect_timeout_s=0.5),
                     progress=_at_step(7, _set(st.profiler_faults, unplug_on_command=1)))
        st.profiler.replug()
        s = Session.open(tmp_path / "s")
        held = sum(r["kind"] == "profile" for r in s.manifest["captures"].values())
        last = float(s.manifest["state"]["table_deg"])
        s.set_state(moving_to=last + 30.0)           # the crash came during the next move, which went on ...
        import serial

        with serial.serial_for_url(str(st.turntable_path), baudrate=115200, timeout=5.0) as port:
            port.write(f"M17\nG1 X{last + 30.0:.4f}\n".encode())
            assert wait_until(lambda: st.table_angle_deg == pytest.approx(last + 30.0, abs=0.1), timeout=5.0)
        st.turntable.unplug()                        # ... and the board lost power since
        st.turntable.replug()
        report = _capture(st, tmp_path / "s", plan, session=s)
        got = _profiles(tmp_path / "s", 1)[0]
        offset_deg = st.table_angle_deg - got["angles_deg"][-1]      # the last profile taken
        truth = [st.profile_at(a + offset_deg) for a in got["angles_deg"]]
    assert report.status == "complete" and _noted(report, "lost its position")
    assert offset_deg == pytest.approx(30.0, abs=0.1)
    assert report.taken == 12 and report.skipped == 0 and held >= 5   # every profile of the pass, in frame 1
    for i, (_, z_um, _) in enumerate(truth):
        np.testing.assert_allclose(got["z_mm"][i], z_um / 1000.0, rtol=0, atol=1e-3, err_msg=f"profile {i}")
    assert Session.read(tmp_path / "s")["passes"]["1"]["table_frame"] == 1


def test_tampered_capture_is_taken_again(reference, tmp_path):
    _, expected, _ = reference
    with _station(tmp_path) as st:
        _capture(st, tmp_path / "s", CapturePlan("scan", steps=12, passes=1, camera=False))
    (tmp_path / "s" / "passes" / "p01" / "profiles" / "0003.npz").write_bytes(b"damaged")
    s = Session.open(tmp_path / "s")
    s.set_status("interrupted")
    with _station(tmp_path, "station2") as st:
        report = _capture(st, tmp_path / "s", CapturePlan("scan", steps=12, passes=1, camera=False), session=s)
    assert report.redone == ["p01/profile/0003", "p01/profiles"] or report.redone[0] == "p01/profile/0003"
    assert report.taken == 1
    _same(_profiles(tmp_path / "s", 1), expected[:1])


def test_gphoto2_frames_chart_first_and_busy_camera(tmp_path):
    plan = CapturePlan("scan", steps=4, passes=1, camera_angles_deg=(0.0, 180.0))
    with _station(tmp_path) as st:
        st.apply_faults({"camera": {"busy": 1}})
        report = _capture(st, tmp_path / "s", plan, "gphoto2",
                          settings=CaptureSettings(camera_retry_wait_s=0.05))
    import rawpy

    m = Session.read(tmp_path / "s")
    frames = {k: r for k, r in m["captures"].items() if r["kind"] in ("chart", "frame")}
    assert list(frames) == ["p01/chart", "p01/frame/00", "p01/frame/01"]
    assert [frames[k]["angle_deg"] for k in frames] == [0.0, 0.0, 180.0]
    levels = []
    for rec in frames.values():
        with rawpy.imread(str(tmp_path / "s" / rec["file"])) as raw:
            levels.append(raw.raw_image_visible.astype(float))
    # the chart frame is a different scene from the object frames; the two object angles differ too
    assert np.abs(levels[0] - levels[1]).mean() > 5 * np.abs(levels[1] - levels[1][::-1, ::-1]).std() / 100
    assert not np.array_equal(levels[1], levels[2])
    assert any("busy" in r for r in report.recoveries)


def test_no_camera_is_reported_then_resumed(tmp_path):
    plan = CapturePlan("scan", steps=4, passes=1, camera_angles_deg=(90.0,))
    with _station(tmp_path) as st:
        st.apply_faults({"camera": {"no_camera": True}})
        with pytest.raises(CaptureInterrupted, match="(?i)no camera found"):
            _capture(st, tmp_path / "s", plan, "gphoto2")
        assert Session.read(tmp_path / "s")["status"] == "interrupted"
        st.apply_faults({"camera": {"no_camera": False}})
        report = _capture(st, tmp_path / "s", plan, "gphoto2", session=Session.open(tmp_path / "s"))
    m = Session.read(tmp_path / "s")
    assert report.status == "complete" and "p01/chart" in m["captures"] and "p01/frame/00" in m["captures"]


def test_hot_folder_partial_file_is_never_taken(tmp_path):
    plan = CapturePlan("scan", steps=4, passes=1, camera_angles_deg=(0.0,))
    with _station(tmp_path) as st:
        st.hotfolder_faults.partial = 1
        report = _capture(st, tmp_path / "s", plan, "hotfolder", timeout_s=1.5,
                          settings=CaptureSettings(camera_retry_wait_s=0.05))
        leftover = sorted(p.name for p in st.hotfolder.iterdir())
    import rawpy

    m = Session.read(tmp_path / "s")
    assert report.status == "complete"
    for key in ("p01/chart", "p01/frame/00"):
        with rawpy.imread(str(tmp_path / "s" / m["captures"][key]["file"])) as raw:
            assert raw.raw_image_visible.size > 0
    assert len(leftover) == 1                     # the truncated file stays where it was, untouched
    assert any("did not reach" in r or "incomplete" in r or "no new RAW" in r for r in report.recoveries)


def test_swatch_plan_takes_frames_at_every_angle(tmp_path):
    plan = CapturePlan("swatch", steps=3, passes=1)
    with _station(tmp_path) as st:
        _capture(st, tmp_path / "s", plan, "hotfolder")
    m = Session.read(tmp_path / "s")
    angles = [r["angle_deg"] for k, r in m["captures"].items() if r["kind"] == "frame"]
    np.testing.assert_allclose(angles, [0.0, 120.0, 240.0], atol=0.5 * 360 / 3200)
    assert not any(r["kind"] == "profile" for r in m["captures"].values())


def test_an_angle_lost_between_passes_leaves_the_finished_pass_alone(tmp_path):
    """A swatch's turn back to pass 1's zero comes after pass 1 is complete: losing the angle there must not
    make pass 1's frames stale (nor be taken again on a resume); the next pass is zeroed anew."""
    plan = CapturePlan("swatch", steps=3, passes=2)
    n_pass1 = len(plan.pass_actions(1))
    with _station(tmp_path) as st:
        report = _capture(st, tmp_path / "s", plan, "hotfolder",
                          progress=_at_step(n_pass1, _set(st.turntable_faults, silent_after_move=1)))
    m = Session.read(tmp_path / "s")
    assert report.status == "complete" and _noted(report, "before the next pass is zeroed")
    assert report.taken == len(plan.actions()) and "table_frame" not in m["passes"]["1"]
    assert not _noted(report, "taken again")


# ------------------------------------------------------------------ the command line in a subprocess
def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "app.cli", *args]


def _wait_for_profiles(root: Path, n: int, proc: subprocess.Popen, timeout_s: float = 60.0) -> None:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        assert proc.poll() is None, proc.communicate()
        try:
            m = Session.read(root)
        except Exception:  # noqa: BLE001 - not created yet
            time.sleep(0.05)
            continue
        if sum(r["kind"] == "profile" for r in m["captures"].values()) >= n:
            return
        time.sleep(0.02)
    raise AssertionError(f"fewer than {n} profiles after {timeout_s} s")


def _capture_args(st: SimulatedStation, out: Path, steps: int, passes: int) -> list[str]:
    return ["capture", "--turntable", str(st.turntable_path), "--laser", str(st.profiler_path), "--camera", "none",
            "--steps", str(steps), "--passes", str(passes), "--out", str(out), "--unattended",
            "--before-pass", f"{sys.executable} -m app.cli mock place --control {st.control_dir}", "--quiet"]


def test_kill_9_mid_pass_then_resume_completes_with_the_same_data(reference, tmp_path):
    _, expected, _ = reference
    out = tmp_path / "s"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    with _station(tmp_path, time_scale=0.02) as st:    # slow motion, so the kill lands mid-pass
        proc = subprocess.Popen(_cli(*_capture_args(st, out, 12, 2)), cwd=ROOT, env=env,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        _wait_for_profiles(out, 17, proc)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        m = Session.read(out)
        assert m["status"] == "capturing"                  # it never got to say anything
        held = sum(r["kind"] == "profile" for r in m["captures"].values())
        assert 17 <= held < 24
        done = subprocess.run(_cli("capture", "--resume", str(out), "--quiet"), cwd=ROOT, env=env,
                              capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert f"{24 - held} captures taken, {held} already held" in done.stdout
    m = Session.read(out)
    assert m["status"] == "complete"
    assert sorted(k for k, r in m["captures"].items() if r["kind"] == "profile") == \
        [f"p{p:02d}/profile/{i:04d}" for p in (1, 2) for i in range(12)]
    _same(_profiles(out, 2), expected)
    assert [h["event"] for h in m["history"]].count("resumed") == 1


def test_ctrl_c_leaves_a_resumable_session(reference, tmp_path):
    _, expected, _ = reference
    out = tmp_path / "s"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    with _station(tmp_path, time_scale=0.02) as st:    # slow motion, so Ctrl-C lands mid-pass
        proc = subprocess.Popen(_cli(*_capture_args(st, out, 12, 2)), cwd=ROOT, env=env,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        _wait_for_profiles(out, 3, proc)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 130, err
        assert "--resume" in err
        m = Session.read(out)
        assert m["status"] == "interrupted"
        done = subprocess.run(_cli("capture", "--resume", str(out), "--quiet"), cwd=ROOT, env=env,
                              capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    _same(_profiles(out, 2), expected)


@pytest.mark.parametrize("args,match", [
    (["--camera", "none", "--laser", "x", "--steps", "4", "--out", "{tmp}/a"], "--turntable PORT is required"),
    (["--turntable", "x", "--camera", "none", "--out", "{tmp}/a"], "--laser PORT is required"),
    (["--turntable", "x", "--laser", "y", "--out", "{tmp}/a"], "--camera is required"),
    (["--turntable", "x", "--laser", "y", "--camera", "webcam", "--out", "{tmp}/a"], "gphoto2, gphoto2:PATH"),
    (["--turntable", "x", "--laser", "y", "--camera", "hotfolder:{tmp}/nope", "--out", "{tmp}/a"],
     "does not exist"),
    (["--turntable", "x", "--laser", "y", "--camera", "none", "--steps", "0", "--out", "{tmp}/a"], "steps must be"),
    (["--turntable", "x", "--laser", "y", "--camera", "none", "--speed", "-1", "--out", "{tmp}/a"],
     "--speed must be"),
    (["--turntable", "x", "--camera", "none", "--plan", "swatch", "--out", "{tmp}/a"], "swatch capture"),
    (["--turntable", "x", "--laser", "y", "--camera", "gphoto2", "--holdout-burst", "0", "--out", "{tmp}/a"],
     "--holdout-burst must be"),
    (["--turntable", "x", "--camera", "gphoto2", "--plan", "swatch", "--holdout-burst", "4", "--out", "{tmp}/a"],
     "--holdout-burst is for --plan scan"),
    (["--resume", "{tmp}"], "not a kogei session"),
    (["--turntable", "x", "--laser", "y", "--camera", "none", "--out", "{tmp}/a", "--resume", "{tmp}/a"],
     "either --out"),
])
def test_cli_usage_errors(args, match, tmp_path, capsys):
    from app.cli import main

    code = main(["capture", "--unattended", *[a.format(tmp=tmp_path) for a in args]])
    assert code == 2
    err = capsys.readouterr().err
    assert match in err and "Traceback" not in err


def test_cli_refuses_prompts_without_a_terminal(tmp_path, capsys, monkeypatch):
    from app.cli import main

    monkeypatch.setattr(sys, "stdin", open(os.devnull))
    code = main(["capture", "--turntable", "x", "--laser", "y", "--camera", "none", "--out", str(tmp_path / "a")])
    assert code == 2 and "--unattended" in capsys.readouterr().err


def test_cli_device_missing_is_reported_not_a_traceback(tmp_path, capsys):
    from app.cli import main

    code = main(["capture", "--turntable", str(tmp_path / "no-such-port"), "--laser", str(tmp_path / "nor-this"),
                 "--camera", "none", "--steps", "4", "--passes", "1", "--out", str(tmp_path / "s"), "--unattended"])
    err = capsys.readouterr().err
    assert code == 1 and "turntable" in err and "--resume" in err and "Traceback" not in err
    m = json.loads((tmp_path / "s" / "session.json").read_text())
    assert m["status"] == "interrupted"
