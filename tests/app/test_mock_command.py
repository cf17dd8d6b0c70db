"""``kogei mock``: the argument parser, the control-folder protocol from other processes, and the
station run as a subprocess, found and driven through its printed ports, stopped by SIGINT/SIGTERM."""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest

from app.cli.mock import add_parser, capture_commands, main, run
from app.errors import UsageError
from drivers.profiler import LaserProfiler
from drivers.transport import SerialTransport
from drivers.turntable import Turntable
from mocks.station import (
    SimulatedStation,
    StationError,
    StationTimeout,
    request_place,
    request_shoot,
)
from mocks.waiting import wait_until
from mocks.world import World

ROOT = Path(__file__).resolve().parents[2]


def parse(*argv):
    parser = argparse.ArgumentParser(prog="kogei")
    add_parser(parser.add_subparsers(dest="command", required=True))
    return parser.parse_args(["mock", *argv])


def box_world():
    m = o3d.geometry.TriangleMesh.create_box(40.0, 30.0, 50.0)
    v = np.asarray(m.vertices) - [20.0, 15.0, 0.0]
    t = np.asarray(m.triangles)
    return World(v, t, np.zeros(len(t), np.int64), ("object",), {"object": "gold"}, width=48, height=32,
                 spectral_step=20.0)


def run_cli(*argv, env=None, timeout=60):
    full_env = {**os.environ, "PYTHONPATH": str(ROOT), **(env or {})}
    return subprocess.run([sys.executable, "-m", "app.cli.mock", *argv], cwd=ROOT, env=full_env,
                          capture_output=True, text=True, timeout=timeout)


@pytest.fixture
def station(tmp_path):
    with SimulatedStation(box_world(), root=tmp_path / "station", hotfolder_interval_s=0.0) as st:
        yield st


# ------------------------------------------------------------------ parser
def test_parser_actions():
    a = parse("--world", "hawk", "--triangles", "2000", "--faults", "camera.busy=1", "--faults",
              "profiler.drop_frames=1", "--time-scale", "0", "--root", "/tmp/x", "--seed", "5")
    assert (a.mock_action, a.world, a.triangles, a.faults, a.time_scale, a.root, a.seed) == \
        (None, "hawk", 2000, ["camera.busy=1", "profiler.drop_frames=1"], 0.0, "/tmp/x", 5)
    p = parse("place", "--control", "/c")
    assert (p.mock_action, p.placement, p.control) == ("place", None, "/c")
    s = parse("shoot", "--control", "/c", "--timeout", "5")
    assert (s.mock_action, s.control, s.timeout) == ("shoot", "/c", 5.0)
    with pytest.raises(SystemExit):
        parse("place", "2")                    # --control is required


def test_capture_command_lines_quote_paths():
    info = {"turntable": "/a b/turntable", "profiler": "/a b/profiler", "gphoto2": "/a b/bin/gphoto2",
            "hotfolder": "/a b/hot", "control": "/a b/control"}
    cmds = capture_commands(info, steps=12, passes=2, session="s")
    assert cmds["gphoto2"] == ("kogei capture --turntable '/a b/turntable' --laser '/a b/profiler' "
                               "--camera 'gphoto2:/a b/bin/gphoto2' --steps 12 --passes 2 --camera-angles 0,90,180,270 --out s "
                               "--unattended "
                               "--before-pass 'kogei mock place --control '\"'\"'/a b/control'\"'\"''")
    assert "--camera 'hotfolder:/a b/hot' --shutter 'kogei mock shoot --control '\"'\"'/a b/control'\"'\"''" \
        in cmds["hotfolder"]


@pytest.mark.parametrize("argv,words", [
    (["--faults", "turntable.garbage=3"], ["--faults", "turntable.garbage=3", "garbage_replies"]),
    (["--faults", "camera.busy=x"], ["camera.busy", "whole number"]),
    (["--world", "/no/such/mesh.ply"], ["/no/such/mesh.ply", "hawk"]),
    (["--material", "unobtainium"], ["--material unobtainium"]),
    (["--time-scale", "-1"], ["--time-scale"]),
    (["--seed", "-2"], ["--seed"]),
    (["--triangles", "10"], ["--triangles"]),
])
def test_bad_options_are_one_line_usage_errors(argv, words, tmp_path):
    with pytest.raises(UsageError) as info:
        run(parse(*argv, "--root", str(tmp_path / "r")))
    for w in words:
        assert w in str(info.value)
    assert "\n" not in str(info.value)
    assert not (tmp_path / "r" / "turntable").exists()


def test_triangles_with_a_mesh_file_is_an_error(tmp_path):
    mesh = tmp_path / "box.ply"
    o3d.io.write_triangle_mesh(str(mesh), o3d.geometry.TriangleMesh.create_box(10, 10, 10))
    with pytest.raises(UsageError, match="--triangles"):
        run(parse("--world", str(mesh), "--triangles", "2000"))


def test_main_prints_one_line_and_exits_2(capsys):
    assert main(["--faults", "lamp.on=1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "kogei mock: error:" in err and "'lamp'" in err


# ------------------------------------------------------------------ control folder
def test_place_and_shoot_from_other_processes(station):
    control = str(station.control_dir)
    r = run_cli("place", "2", "--control", control)
    assert r.returncode == 0, r.stderr
    assert station.placement == 2 and "placement 2" in r.stdout
    r = run_cli("place", "--control", control, env={"KOGEI_PASS": "3"})
    assert r.returncode == 0, r.stderr
    assert station.placement == 3
    r = run_cli("shoot", "--control", control)
    assert r.returncode == 0, r.stderr
    assert "chart frame" in r.stdout
    assert [p.name for p in station.hotfolder.iterdir()] == ["IMG_0001.DNG"]
    assert sorted(os.listdir(control)) == []     # requests and answers are cleaned up


def test_client_functions(station):
    answer = request_place(station.control_dir, 5, timeout_s=10)
    assert answer["ok"] and answer["placement"] == 5
    np.testing.assert_allclose(answer["pose"], station.pose)
    shot = request_shoot(station.control_dir, timeout_s=30)
    assert shot["kind"] == "chart" and Path(shot["file"]).is_file() and shot["placement"] == 5
    assert request_shoot(station.control_dir, timeout_s=30)["kind"] == "object"


def test_request_files_by_hand(station):
    """The protocol as documented: request-<id>.json in, done-<id>.json out."""
    control = station.control_dir
    (control / ".request-a1.json.tmp").write_text(json.dumps({"action": "dance"}))
    os.replace(control / ".request-a1.json.tmp", control / "request-a1.json")
    (control / "request-b2.json").write_text("{not json")
    (control / "request-c3.json").write_text(json.dumps({"action": "place", "placement": 0}))
    done = [control / f"done-{i}.json" for i in ("a1", "b2", "c3")]
    assert wait_until(lambda: all(p.exists() for p in done), 5.0)
    answers = [json.loads(p.read_text()) for p in done]
    assert all(a["ok"] is False for a in answers)
    assert "unknown action 'dance'; known: place, shoot" in answers[0]["error"]
    assert "not valid JSON" in answers[1]["error"]
    assert "placement" in answers[2]["error"]
    assert not any(p.name.startswith("request-") for p in control.iterdir())


def test_station_refusal_reaches_the_client(station):
    station.hotfolder.rmdir()                  # the tethering program's folder vanished
    with pytest.raises(StationError, match="could not shoot: .*hotfolder"):
        request_shoot(station.control_dir, timeout_s=10)
    r = run_cli("shoot", "--control", str(station.control_dir))
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "could not shoot" in r.stderr


def test_no_station_answers(tmp_path):
    empty = tmp_path / "control"
    empty.mkdir()
    start = time.monotonic()
    with pytest.raises(StationTimeout) as info:
        request_place(empty, 1, timeout_s=0.3)
    assert time.monotonic() - start < 2.0
    assert str(empty) in str(info.value) and "kogei mock" in str(info.value)
    assert list(empty.iterdir()) == []           # the unanswered request was taken back
    with pytest.raises(StationError, match="no simulated station control folder"):
        request_shoot(tmp_path / "missing", timeout_s=0.3)
    r = run_cli("place", "1", "--control", str(empty), "--timeout", "0.3")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "kogei mock" in r.stderr
    r = run_cli("place", "--control", str(empty), env={"KOGEI_PASS": ""})
    assert r.returncode == 2 and "KOGEI_PASS" in r.stderr
    r = run_cli("place", "--control", str(empty), env={"KOGEI_PASS": "second"})
    assert r.returncode == 2 and "KOGEI_PASS='second'" in r.stderr


# ------------------------------------------------------------------ the station as a process
def _ignore_sigint():
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _start(argv, root, *, sigint_ignored=False):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-m", "app.cli.mock", *argv, "--root", str(root)], cwd=ROOT,
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_ignore_sigint if sigint_ignored else None)
    lines = []
    for line in proc.stdout:
        lines.append(line.rstrip("\n"))
        if line.startswith("Ctrl-C"):
            break
    else:
        proc.wait(10)
        raise AssertionError(f"kogei mock exited early: {proc.stderr.read()}")
    return proc, lines


def _open_slave(link):
    fd = os.open(link, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    return fd


def _hung_up(fd):
    """True when the other end of the pty is closed (a read fails with EIO or sees end of file)."""
    try:
        data = os.read(fd, 1)
        return data == b""
    except BlockingIOError:
        return False
    except OSError:
        return True
    finally:
        os.close(fd)


def _field(lines, label):
    return next(line.split(label, 1)[1].strip() for line in lines if line.strip().startswith(label))


def test_kogei_mock_process_serves_its_ports_until_sigint(tmp_path):
    root = tmp_path / "station"
    proc, lines = _start(["--triangles", "2000", "--time-scale", "0", "--seed", "1",
                          "--faults", "turntable.garbage_replies=2"], root)
    try:
        turntable, profiler = _field(lines, "turntable port"), _field(lines, "profiler port")
        assert turntable == str(root / "turntable") and profiler == str(root / "profiler")
        assert _field(lines, "gphoto2 shim") == str(root / "bin" / "gphoto2")
        assert _field(lines, "control folder") == str(root / "control")
        assert any(line.strip().startswith("kogei capture --turntable") and "--camera gphoto2:" in line
                   for line in lines)
        assert "faults turntable.garbage_replies=2" in lines[0]
        info = json.loads((root / "station.json").read_text())
        assert info["turntable"] == turntable and info["pid"] == proc.pid and info["world"] == "hawk:2000"
        slaves = [_open_slave(turntable), _open_slave(profiler)]
        tt = Turntable(SerialTransport(turntable), margin_s=0.5)
        lp = LaserProfiler(SerialTransport(profiler), margin_s=0.5)
        tt.connect()
        lp.connect()
        lp.laser(True)
        assert tt.step(90.0, lasers=[1]) == pytest.approx(90.0)   # through the garbage fault
        prof = lp.profile(2.0)
        assert prof.valid.sum() > 100
        lp.close()
        tt.close()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(15) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert "station stopped" in proc.stdout.read()
    assert not os.path.lexists(turntable) and not os.path.lexists(profiler)
    assert all(_hung_up(fd) for fd in slaves)          # the pty pairs are gone, not just the links
    assert not (root / "station.json").exists()


def test_kogei_mock_started_in_the_background_stops_on_sigint(tmp_path):
    """A shell starting `kogei mock &` from a script ignores SIGINT in it; `kill -INT` still stops it."""
    mesh = tmp_path / "box.ply"
    o3d.io.write_triangle_mesh(str(mesh), o3d.geometry.TriangleMesh.create_box(30.0, 30.0, 30.0))
    root = tmp_path / "station"
    proc, lines = _start(["--world", str(mesh), "--material", "gold", "--time-scale", "0"], root,
                         sigint_ignored=True)
    try:
        assert str(mesh) in lines[0]
        answer = request_place(root / "control", 2, timeout_s=10)
        assert answer["placement"] == 2
        proc.send_signal(signal.SIGINT)
        assert proc.wait(15) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert not os.path.lexists(root / "turntable")


def test_run_mock_in_process_stops_on_sigterm_and_restores_handlers(tmp_path, capsys):
    mesh = tmp_path / "box.ply"
    o3d.io.write_triangle_mesh(str(mesh), o3d.geometry.TriangleMesh.create_box(20.0, 20.0, 20.0))
    root = tmp_path / "station"
    before = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)

    def stop_when_up():
        if wait_until(lambda: (root / "station.json").exists(), 30.0):
            os.kill(os.getpid(), signal.SIGTERM)

    killer = threading.Thread(target=stop_when_up, daemon=True)
    killer.start()
    assert run(parse("--world", str(mesh), "--time-scale", "0", "--root", str(root))) == 0
    killer.join(5.0)
    assert (signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)) == before
    out = capsys.readouterr().out
    assert "turntable port" in out and out.rstrip().endswith("station stopped")
    assert not os.path.lexists(root / "turntable") and not (root / "station.json").exists()
