"""A session folder is untrusted input, as ``kogei capture --resume`` sees it: leftover files are kept
without overwriting each other, symbolic links are never followed, stored commands do not run
silently, junk frames and laser-less passes are not "complete", grandchildren cannot defeat a
timeout, and bad options leave no folder behind."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from app.capture.devices import build_devices
from app.capture.runner import CaptureHooks, CapturePlan, CaptureSettings, keep_orphans, run_capture
from app.session import Session, SessionError
from mocks.station import SimulatedStation
from mocks.world import World

PLAN = CapturePlan("scan", steps=2, passes=1, camera=False)


def _station(tmp_path: Path, name: str = "station") -> SimulatedStation:
    return SimulatedStation(World.hawk(2000, width=48, height=32), root=tmp_path / name, seed=3, n_points=96)


def _config(st: SimulatedStation) -> dict:
    return {"turntable": {"port": str(st.turntable_path)},
            "profiler": {"port": str(st.profiler_path), "baudrate": 115200}}


def _sentinel(tmp_path: Path) -> tuple[Path, bytes, int]:
    outside = tmp_path / "outside"
    outside.mkdir(exist_ok=True)
    f = outside / "precious.dng"
    f.write_bytes(b"precious bytes")
    return f, f.read_bytes(), f.stat().st_mtime_ns


def _untouched(sentinel: tuple[Path, bytes, int]) -> None:
    f, data, mtime = sentinel
    assert f.read_bytes() == data and f.stat().st_mtime_ns == mtime


def _interrupted_session(root: Path, plan: CapturePlan = PLAN, config: dict | None = None) -> None:
    s = Session.create(root, plan=plan.to_dict(), settings={"device_config": config or {}})
    s.set_status("interrupted")
    s.close()


# ------------------------------------------------------------------ item 3: orphans
def _leftovers(root: Path) -> None:
    for work, data in ((".gphoto2-a", b"first"), (".gphoto2-b", b"second")):
        (root / ".incoming" / work).mkdir(parents=True, exist_ok=True)
        (root / ".incoming" / work / "capt0000.dng").write_bytes(data)


def test_orphans_keep_their_relative_paths_and_never_share_a_folder(tmp_path):
    root = tmp_path / "s"
    _interrupted_session(root)
    _leftovers(root)
    kept, links, folder = keep_orphans(root)
    assert kept == [".gphoto2-a/capt0000.dng", ".gphoto2-b/capt0000.dng"] and links == []
    assert (root / folder / ".gphoto2-a" / "capt0000.dng").read_bytes() == b"first"
    assert (root / folder / ".gphoto2-b" / "capt0000.dng").read_bytes() == b"second"
    _leftovers(root)                                   # a second resume within the same second
    kept2, _, folder2 = keep_orphans(root)
    assert len(kept2) == 2 and folder2 != folder
    assert len(list((root / "orphans").iterdir())) == 2


def test_resume_lists_every_kept_orphan_in_the_history(tmp_path):
    root = tmp_path / "s"
    with _station(tmp_path) as st:
        _interrupted_session(root, config=_config(st))
        _leftovers(root)
        s = Session.open(root)
        try:
            run_capture(s, PLAN, build_devices(_config(st), root), CaptureHooks(before_pass=lambda p, n: st.place(p)),
                        CaptureSettings(reconnect_timeout_s=2.0))
        finally:
            s.close()
    notes = " ".join(h["detail"] for h in Session.read(root)["history"] if h["event"] == "note")
    assert "kept 2 unrecorded file(s)" in notes
    assert ".gphoto2-a/capt0000.dng" in notes and ".gphoto2-b/capt0000.dng" in notes
    assert sorted(p.read_bytes() for p in (root / "orphans").rglob("*.dng")) == [b"first", b"second"]


def test_symlinked_incoming_is_refused_and_its_target_not_moved(tmp_path):
    root = tmp_path / "s"
    _interrupted_session(root)
    sentinel = _sentinel(tmp_path)
    (root / ".incoming").symlink_to(sentinel[0].parent)
    with pytest.raises(SessionError, match=r"\.incoming is a symbolic link"):
        keep_orphans(root)
    _untouched(sentinel)
    assert not (root / "orphans").exists()


def test_symlinked_orphans_folder_is_refused(tmp_path):
    root = tmp_path / "s"
    _interrupted_session(root)
    _leftovers(root)
    sentinel = _sentinel(tmp_path)
    (root / "orphans").symlink_to(sentinel[0].parent)
    with pytest.raises(SessionError, match="orphans is a symbolic link"):
        keep_orphans(root)
    _untouched(sentinel)
    assert sorted(p.name for p in sentinel[0].parent.iterdir()) == ["precious.dng"]


def test_symlinks_inside_incoming_are_not_followed(tmp_path):
    root = tmp_path / "s"
    _interrupted_session(root)
    sentinel = _sentinel(tmp_path)
    (root / ".incoming" / ".gphoto2-a").mkdir(parents=True)
    (root / ".incoming" / ".gphoto2-a" / "capt0000.dng").symlink_to(sentinel[0])
    (root / ".incoming" / "dir").symlink_to(sentinel[0].parent, target_is_directory=True)
    kept, links, _ = keep_orphans(root)
    assert kept == [] and links == [".gphoto2-a/capt0000.dng", "dir"]
    _untouched(sentinel)


def test_cli_resume_with_a_symlinked_incoming_exits_2(tmp_path, capsys):
    from app.cli import main

    root = tmp_path / "s"
    sentinel = _sentinel(tmp_path)
    with _station(tmp_path) as st:
        _interrupted_session(root, config=_config(st))
        (root / ".incoming").symlink_to(sentinel[0].parent)
        code = main(["capture", "--resume", str(root), "--unattended", "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "symbolic link" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    _untouched(sentinel)



# ------------------------------------------------------------------ item 4: stored commands
def _foreign_session(root: Path, config: dict, marker: Path, origin: dict | None) -> None:
    settings = {"device_config": config, "unattended": True, "before_pass": f"touch {marker}"}
    if origin is not None:
        settings["created_by"] = origin
    s = Session.create(root, plan=PLAN.to_dict(), settings=settings)
    s.set_status("interrupted")
    s.close()


@pytest.mark.parametrize("origin", [{"user": "mallory", "uid": 12345, "host": "elsewhere.example"}, None])
def test_stored_hook_of_a_foreign_session_is_shown_not_run(origin, tmp_path, capsys):
    from app.cli import main

    root, marker = tmp_path / "s", tmp_path / "ran"
    _foreign_session(root, {"turntable": {"port": str(tmp_path / "tt")}}, marker, origin)
    code = main(["capture", "--resume", str(root), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and not marker.exists()
    assert f"touch {marker}" in err and "--trust-hooks" in err and "Traceback" not in err
    assert err.strip().splitlines()[-1].startswith("kogei")
    assert Session.read(root)["status"] == "interrupted"        # not touched: no capture was started


def test_stored_camera_executable_of_a_foreign_session_is_shown_not_run(tmp_path, capsys):
    from app.cli import main

    root = tmp_path / "s"
    plan = CapturePlan("scan", steps=2, passes=1, camera_angles_deg=(0.0,))
    config = {"turntable": {"port": "x"}, "profiler": {"port": "y"},
              "camera": {"kind": "gphoto2", "executable": str(tmp_path / "evil.sh")}}
    s = Session.create(root, plan=plan.to_dict(), settings={"device_config": config, "unattended": True,
                                                            "created_by": {"uid": -1, "host": "elsewhere"}})
    s.close()
    code = main(["capture", "--resume", str(root), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and str(tmp_path / "evil.sh") in err and "--trust-hooks" in err


@pytest.mark.parametrize("how", ["--trust-hooks", "re-entered", "own session"])
def test_stored_hook_runs_when_trusted(how, tmp_path, capsys):
    import socket

    from app.cli import main

    root, marker = tmp_path / "s", tmp_path / "ran"
    with _station(tmp_path) as st:
        origin = {"user": "mallory", "uid": 12345, "host": "elsewhere.example"}
        if how == "own session":
            origin = {"user": "me", "uid": os.getuid(), "host": socket.gethostname()}
        _foreign_session(root, _config(st), marker, origin)
        extra = {"--trust-hooks": ["--trust-hooks"], "re-entered": ["--before-pass", f"touch {marker}"],
                 "own session": []}[how]
        code = main(["capture", "--resume", str(root), "--quiet", *extra])
    assert code == 0, capsys.readouterr().err
    assert marker.exists()


def test_new_session_records_who_created_it(tmp_path):
    import socket

    from app.cli import main

    with _station(tmp_path) as st:
        code = main(["capture", "--turntable", str(st.turntable_path), "--laser", str(st.profiler_path),
                     "--camera", "none", "--steps", "2", "--passes", "1", "--out", str(tmp_path / "s"),
                     "--unattended", "--quiet"])
    assert code == 0
    origin = Session.read(tmp_path / "s")["settings"]["created_by"]
    assert origin["uid"] == os.getuid() and origin["host"] == socket.gethostname() and origin["user"]


# ------------------------------------------------------------------ item 5: junk frames, passes without a laser
def _junk_camera(tmp_path: Path, payload: bytes = b"8 bytes!") -> Path:
    exe = tmp_path / "junk-gphoto2"
    exe.write_text(f"#!{sys.executable}\nopen('capt0000.dng', 'wb').write({payload!r})\n")
    exe.chmod(0o755)
    return exe


def test_raw_format_problem_sniffs_the_header(tmp_path):
    import numpy as np

    from drivers.camera_hotfolder import raw_format_problem
    from mocks.dng_writer import dng_bytes

    good = tmp_path / "a.dng"
    good.write_bytes(dng_bytes(np.full((32, 48), 700, np.uint16), black_level=600, white_level=16383))
    assert raw_format_problem(good) is None
    for name, data, match in (("b.dng", b"8 bytes!", "not a DNG file"), ("c.nef", b"", "empty"),
                              ("d.cr2", b"II*\x00\xff\xff\x00\x00", "truncated or damaged CR2"),
                              ("e.cr3", b"\x00\x00\x00\x18junk", "not a CR3")):
        (tmp_path / name).write_bytes(data)
        assert match in raw_format_problem(tmp_path / name)


def test_junk_camera_download_is_a_failed_capture_not_complete(tmp_path):
    from app.capture.runner import CaptureInterrupted

    plan = CapturePlan("scan", steps=2, passes=1, camera_angles_deg=(0.0,), chart=False)
    root = tmp_path / "s"
    with _station(tmp_path) as st:
        config = {**_config(st), "camera": {"kind": "gphoto2", "executable": str(_junk_camera(tmp_path))}}
        s = Session.create(root, plan=plan.to_dict(), settings={"device_config": config})
        try:
            with pytest.raises(CaptureInterrupted, match=r"(?s)not a DNG file.*tried 2 times.*--resume"):
                run_capture(s, plan, build_devices(config, root), CaptureHooks(before_pass=lambda p, n: st.place(p)),
                            CaptureSettings(reconnect_timeout_s=2.0, camera_retries=1, camera_retry_wait_s=0.01))
        finally:
            s.close()
    m = Session.read(root)
    assert m["status"] == "interrupted" and "p01/frame/00" not in m["captures"]
    assert len(list((root / "orphans").rglob("*.dng"))) == 2            # the junk is kept, out of the way


def test_pass_without_laser_returns_is_warned_and_recorded(tmp_path, monkeypatch):
    monkeypatch.setattr(SimulatedStation, "laser_powered", property(lambda self: False))
    asked = []
    root = tmp_path / "s"
    with _station(tmp_path) as st:
        s = Session.create(root, plan=PLAN.to_dict(), settings={"device_config": _config(st)})
        try:
            report = run_capture(s, PLAN, build_devices(_config(st), root),
                                 CaptureHooks(low_return=lambda p, share, text: asked.append((p, share))),
                                 CaptureSettings(reconnect_timeout_s=2.0))
        finally:
            s.close()
    m = Session.read(root)
    assert asked == [(1, 0.0)] and m["passes"]["1"]["valid_share"] == 0.0
    assert report.warnings and "check the laser" in report.warnings[0]
    assert any(h["event"] == "warning" and "laser" in h["detail"] for h in m["history"])


def test_unattended_cli_ends_non_zero_when_the_laser_never_came_on(tmp_path, capsys, monkeypatch):
    from app.cli import main

    monkeypatch.setattr(SimulatedStation, "laser_powered", property(lambda self: False))
    with _station(tmp_path) as st:
        code = main(["capture", "--turntable", str(st.turntable_path), "--laser", str(st.profiler_path),
                     "--camera", "none", "--steps", "2", "--passes", "1", "--out", str(tmp_path / "s"),
                     "--unattended", "--quiet"])
    err = capsys.readouterr().err
    assert code == 1 and "check the laser" in err and "Traceback" not in err
    assert Session.read(tmp_path / "s")["passes"]["1"]["valid_share"] == 0.0


def test_normal_pass_records_its_valid_share(tmp_path):
    root = tmp_path / "s"
    with _station(tmp_path) as st:
        s = Session.create(root, plan=PLAN.to_dict(), settings={"device_config": _config(st)})
        try:
            report = run_capture(s, PLAN, build_devices(_config(st), root),
                                 CaptureHooks(before_pass=lambda p, n: st.place(p)), CaptureSettings())
        finally:
            s.close()
    assert report.warnings == [] and Session.read(root)["passes"]["1"]["valid_share"] == 1.0


# ------------------------------------------------------------------ item 8: timeouts and grandchildren
def _hanging_camera(tmp_path: Path, pids: Path, hang: bool = True) -> Path:
    """A gphoto2 stand-in that leaves a detached ``sleep 100`` holding its stdout (and hangs itself)."""
    exe = tmp_path / "hanging-gphoto2"
    exe.write_text(f"#!/bin/sh\nsetsid sleep 100 &\necho $! >> {pids}\nsleep 100 &\necho $! >> {pids}\n"
                   + ("sleep 100\n" if hang else "exit 3\n"))
    exe.chmod(0o755)
    return exe


@pytest.fixture
def pids(tmp_path):
    """A file the fake programs write their children's pids to; they are all killed afterwards."""
    import signal

    path = tmp_path / "pids"
    yield path
    if path.exists():
        for pid in path.read_text().split():
            try:
                os.kill(int(pid), signal.SIGKILL)
            except (ProcessLookupError, ValueError):
                pass


def test_gphoto2_timeout_is_not_defeated_by_a_detached_grandchild(tmp_path, pids):
    import time

    from drivers.camera_errors import CameraTimeoutError
    from drivers.camera_gphoto2 import Gphoto2Camera

    cam = Gphoto2Camera(tmp_path / "dest", executable=_hanging_camera(tmp_path, pids), timeout_s=1.0)
    t = time.monotonic()
    with pytest.raises(CameraTimeoutError, match="within 1 s"):
        cam.capture("x")
    assert time.monotonic() - t < 4.0


def test_gphoto2_exit_is_not_held_up_by_a_grandchild_holding_stdout(tmp_path, pids):
    import time

    from drivers.camera_errors import CameraCommandError
    from drivers.camera_gphoto2 import Gphoto2Camera

    cam = Gphoto2Camera(tmp_path / "dest", executable=_hanging_camera(tmp_path, pids, hang=False), timeout_s=30)
    t = time.monotonic()
    with pytest.raises(CameraCommandError, match="status 3"):
        cam.capture("x")
    assert time.monotonic() - t < 4.0


def test_hook_that_backgrounds_a_process_does_not_block(tmp_path, pids):
    import time

    from app.capture.devices import run_hook_command

    t = time.monotonic()
    run_hook_command(f"sh -c 'sleep 100 & echo $! >> {pids}; echo placed'", "--before-pass", {})
    assert time.monotonic() - t < 4.0
    t = time.monotonic()
    with pytest.raises(RuntimeError, match="did not finish within 1 s"):
        run_hook_command(f"sh -c 'setsid sleep 100 & echo $! >> {pids}; sleep 100'", "--before-pass", {},
                         timeout_s=1.0)
    assert time.monotonic() - t < 4.0


def test_cli_camera_timeout_3_ends_within_four_tries(tmp_path, pids, capsys):
    import time

    from app.cli import main

    exe = _hanging_camera(tmp_path, pids)
    with _station(tmp_path) as st:
        t = time.monotonic()
        code = main(["capture", "--turntable", str(st.turntable_path), "--laser", str(st.profiler_path),
                     "--camera", f"gphoto2:{exe}", "--camera-timeout", "3", "--steps", "2", "--passes", "1",
                     "--camera-angles", "0", "--no-chart", "--out", str(tmp_path / "s"), "--unattended", "--quiet"])
        elapsed = time.monotonic() - t
    err = capsys.readouterr().err
    assert code == 1 and "tried 4 times" in err and "--resume" in err
    assert elapsed < 30, elapsed        # 4 tries of 3 s and 3 waits of 1 s, not 4 x 100 s


# ------------------------------------------------------------------ item 9: options checked before the folder exists
@pytest.mark.parametrize("extra,match", [
    (["--exposure-us", "0"], "exposure_us must be"),
    (["--exposure-us", "-5"], "--exposure-us"),
    (["--steps", "0"], "steps must be"),
    (["--passes", "1000"], "passes must be"),
    (["--turntable", " "], "not a device path"),
    (["--camera-timeout", "nan"], "--camera-timeout must be"),
    (["--before-pass", "'unclosed"], "--before-pass"),
    (["--shutter", " "], "--shutter"),
    (["--camera-angles", "0,x"], "--camera-angles"),
])
def test_bad_option_leaves_no_session_folder(extra, match, tmp_path, capsys):
    from app.cli import main

    out = tmp_path / "s"
    code = main(["capture", "--turntable", "x", "--laser", "y", "--camera", "none", "--out", str(out),
                 "--unattended", "--quiet", *extra])
    err = capsys.readouterr().err
    assert code == 2 and match in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


@pytest.mark.parametrize("config", [
    {"turntable": {"port": 42}},
    {"turntable": {"port": "x", "speed_deg_s": "fast"}},
    {"turntable": {"port": "x"}, "profiler": {"port": "y", "exposure_us": 10 ** 9}},
    {"turntable": {"port": "x"}, "profiler": {"port": "y"}, "camera": {"kind": "webcam"}},
    {"turntable": {"port": "x"}, "profiler": {"port": "y"}, "camera": {"executable": "gphoto2"}},
    {"turntable": ["x"]},
    "everything",
])
def test_resume_with_a_wrong_typed_device_config_exits_2(config, tmp_path, capsys):
    from app.cli import main

    root = tmp_path / "s"
    s = Session.create(root, plan=PLAN.to_dict(), settings={"device_config": config, "unattended": True})
    s.close()
    code = main(["capture", "--resume", str(root), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert Session.read(root)["status"] == "new"


# ------------------------------------------------------------------ wire logs
def test_cli_resume_with_a_symlinked_wire_log_exits_2(tmp_path, capsys):
    from app.cli import main

    root = tmp_path / "s"
    sentinel = _sentinel(tmp_path)
    with _station(tmp_path) as st:
        _interrupted_session(root, config=_config(st))
        (root / "wire").mkdir()
        (root / "wire" / "turntable.log").symlink_to(sentinel[0])
        code = main(["capture", "--resume", str(root), "--unattended", "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "symbolic link" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    _untouched(sentinel)


# ------------------------------------------------------------------ gathered profiles read back (report, GUI)
@pytest.mark.parametrize("how", ["absolute", "dotdot", "symlink", "linked folder", "fifo", "not a dict"])
def test_load_pass_profiles_stays_inside_the_session(how, tmp_path):
    from app.capture.runner import load_pass_profiles

    root = tmp_path / "s"
    sentinel = _sentinel(tmp_path)
    s = Session.create(root, plan=PLAN.to_dict(), settings={})
    rel = {"absolute": str(sentinel[0]), "dotdot": "../outside/precious.dng"}.get(how, "passes/p01/profiles.npz")
    (root / "passes" / "p01").mkdir(parents=True)
    if how == "symlink":
        (root / rel).symlink_to(sentinel[0])
    elif how == "linked folder":
        os.rmdir(root / "passes" / "p01")
        (root / "passes" / "p01").symlink_to(sentinel[0].parent, target_is_directory=True)
        rel = "passes/p01/precious.dng"
    elif how == "fifo":
        os.mkfifo(root / rel)
    s.add_capture("p01/profiles", kind="profiles", file=rel, sha256="0" * 64, bytes=1)
    s.close()
    if how == "not a dict":
        import json

        m = json.loads((root / "session.json").read_text())
        m["captures"]["p01/profiles"] = "x"
        (root / "session.json").write_text(json.dumps(m))
    match = ".*" if how == "not a dict" else r"relative path|symbolic link|not a regular file|not a plain file"
    with pytest.raises(SessionError, match=match):       # a schema check on load may find the damage first
        load_pass_profiles(root, 1)
    _untouched(sentinel)


def test_stored_hot_folder_of_a_foreign_session_needs_trust(tmp_path, capsys):
    from app.cli import main

    root = tmp_path / "s"
    plan = CapturePlan("scan", steps=2, passes=1, camera_angles_deg=(0.0,))
    photos = tmp_path / "someone's photos"
    photos.mkdir()
    config = {"turntable": {"port": "x"}, "profiler": {"port": "y"}, "camera": {"kind": "hotfolder",
                                                                               "folder": str(photos)}}
    s = Session.create(root, plan=plan.to_dict(), settings={"device_config": config, "unattended": True})
    s.close()
    code = main(["capture", "--resume", str(root), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and f"hotfolder:{photos}" in err and "--trust-hooks" in err


def test_interactive_cli_asks_when_the_laser_never_came_on(tmp_path, capsys, monkeypatch):
    import builtins
    import io

    from app.cli import main

    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    prompts: list[str] = []

    def answer(prompt: str = "") -> str:
        prompts.append(prompt)
        return "q" if "laser line" in prompt else ""

    monkeypatch.setattr(SimulatedStation, "laser_powered", property(lambda self: False))
    monkeypatch.setattr(sys, "stdin", Tty())
    monkeypatch.setattr(builtins, "input", answer)
    with _station(tmp_path) as st:
        code = main(["capture", "--turntable", str(st.turntable_path), "--laser", str(st.profiler_path),
                     "--camera", "none", "--steps", "2", "--passes", "1", "--out", str(tmp_path / "s"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 130 and "no laser line" in err and "--resume" in err
    assert any("saw the laser line" in p for p in prompts)


# ------------------------------------------------------------------ a full disk during capture
def test_full_disk_mid_capture_is_a_message_not_a_traceback(tmp_path, capsys, monkeypatch):
    import errno

    from app.cli import main

    real_add = Session.add_capture
    calls = []

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    def add_capture(self, *args, **kwargs):
        calls.append(args[0])
        if len(calls) == 2:
            for name in ("checkpoint", "event", "set_status", "close", "sync"):
                monkeypatch.setattr(Session, name, full)
            full()
        return real_add(self, *args, **kwargs)

    monkeypatch.setattr(Session, "add_capture", add_capture)
    with _station(tmp_path) as st:
        code = main(["capture", "--turntable", str(st.turntable_path), "--laser", str(st.profiler_path),
                     "--camera", "none", "--steps", "4", "--passes", "1", "--out", str(tmp_path / "s"),
                     "--unattended", "--quiet"])
    err = capsys.readouterr().err
    assert code == 1 and "No space left" in err and "--resume" in err and "Traceback" not in err
