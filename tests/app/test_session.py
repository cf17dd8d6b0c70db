"""The session store: manifest round trip, atomic checksummed files, journal replay after a crash
(including a real kill -9), torn journal lines, locking, and every bad-input message."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from app.session import (
    JOURNAL,
    MANIFEST,
    SCHEMA_VERSION,
    Session,
    SessionError,
    SessionLockedError,
    atomic_write_bytes,
)

ROOT = Path(__file__).resolve().parents[2]


def _new(tmp_path: Path, name: str = "s") -> Session:
    return Session.create(tmp_path / name, plan={"kind": "scan", "steps": 4, "passes": 1},
                          object_info={"name": "tsuba"}, devices={"turntable": {"port": "/dev/null"}})


def test_create_open_round_trip(tmp_path):
    s = _new(tmp_path)
    info = s.write_file("passes/p01/a.bin", b"abc")
    assert info.sha256 == hashlib.sha256(b"abc").hexdigest() and info.bytes == 3
    s.add_capture("p01/a", kind="profile", file=info.path, sha256=info.sha256, bytes=info.bytes, angle_deg=1.5)
    s.update_pass(1, placed="now")
    s.set_state(table_deg=1.5)
    s.update("calibration", {"path": "cal.json", "sha256": "0" * 64})
    s.close()
    m = json.loads((tmp_path / "s" / MANIFEST).read_text())
    assert m["schema"] == "kogei.session" and m["version"] == SCHEMA_VERSION
    assert m["object"] == {"name": "tsuba"} and m["devices"]["turntable"]["port"] == "/dev/null"
    assert m["captures"]["p01/a"]["angle_deg"] == 1.5 and m["captures"]["p01/a"]["status"] == "done"
    assert m["passes"]["1"]["placed"] == "now" and m["state"]["table_deg"] == 1.5
    assert m["calibration"]["path"] == "cal.json"
    assert (tmp_path / "s" / JOURNAL).read_bytes() == b""  # folded into the manifest
    with Session.open(tmp_path / "s") as t:
        assert t.is_done("p01/a")
        assert t.manifest["captures"] == m["captures"]


def test_no_temporary_files_are_left(tmp_path):
    s = _new(tmp_path)
    for i in range(5):
        s.write_file(f"x/{i}.bin", bytes([i]) * 100)
    s.close()
    leftovers = [p for p in (tmp_path / "s").rglob("*") if p.name.endswith(".tmp")]
    assert leftovers == []


def test_write_arrays_is_a_readable_npz(tmp_path):
    s = _new(tmp_path)
    info = s.write_arrays("a.npz", x=np.arange(4.0), y=np.array([np.nan, 1.0]))
    s.close()
    with np.load(tmp_path / "s" / info.path) as z:
        assert z["x"].tolist() == [0, 1, 2, 3] and np.isnan(z["y"][0])
    assert hashlib.sha256((tmp_path / "s" / info.path).read_bytes()).hexdigest() == info.sha256


def test_verify_detects_missing_resized_and_altered_files(tmp_path):
    s = _new(tmp_path)
    for name in ("a", "b", "c"):
        info = s.write_file(f"{name}.bin", b"0123456789")
        s.add_capture(name, file=info.path, sha256=info.sha256, bytes=info.bytes)
    (tmp_path / "s" / "a.bin").unlink()
    (tmp_path / "s" / "b.bin").write_bytes(b"0123")
    (tmp_path / "s" / "c.bin").write_bytes(b"0123456780")   # same size, other content
    assert "missing" in s.verify_file(s.capture("a"))
    assert "bytes" in s.verify_file(s.capture("b"))
    assert "checksum" in s.verify_file(s.capture("c"))
    assert not any(s.is_done(n) for n in "abc")
    assert s.is_done("c", verify=False)
    s.close()


def test_adopt_file_moves_and_replaces(tmp_path):
    s = _new(tmp_path)
    src = tmp_path / "download.dng"
    src.write_bytes(b"raw1")
    info = s.adopt_file(src, "passes/p01/raw/chart.dng")
    assert not src.exists() and (tmp_path / "s" / info.path).read_bytes() == b"raw1"
    src.write_bytes(b"raw22")       # a retaken frame replaces an unrecorded one
    info = s.adopt_file(src, "passes/p01/raw/chart.dng")
    assert info.bytes == 5 and info.sha256 == hashlib.sha256(b"raw22").hexdigest()
    s.close()


_CRASHER = textwrap.dedent("""
    import os, sys
    sys.path.insert(0, {root!r})
    from app.session import Session
    s = Session.open({path!r})
    n = int(sys.argv[1])
    for i in range(n):
        info = s.write_file(f"f/{{i:05d}}.bin", os.urandom(64))
        s.add_capture(f"c{{i:05d}}", file=info.path, sha256=info.sha256, bytes=info.bytes)
        if i == n - 1:
            print("ready", flush=True)
    if sys.argv[2] == "exit":
        os._exit(0)           # a crash: no checkpoint, no close
    import time
    while True:
        info = s.write_file("f/busy.bin", os.urandom(4096))
        s.add_capture("busy", file=info.path, sha256=info.sha256, bytes=info.bytes)
""")


def _crasher(tmp_path: Path) -> Path:
    script = tmp_path / "crash.py"
    script.write_text(_CRASHER.format(root=str(ROOT), path=str(tmp_path / "s")))
    return script


def test_journal_is_replayed_after_a_crash(tmp_path):
    _new(tmp_path).close()
    subprocess.run([sys.executable, str(_crasher(tmp_path)), "7", "exit"], check=True, capture_output=True)
    manifest = json.loads((tmp_path / "s" / MANIFEST).read_text())
    assert manifest["captures"] == {}                         # never checkpointed...
    assert Session.read(tmp_path / "s")["captures"].keys() >= {f"c{i:05d}" for i in range(7)}
    with Session.open(tmp_path / "s") as s:                    # ...but nothing is lost
        assert all(s.is_done(f"c{i:05d}") for i in range(7))


def test_kill_9_mid_write_leaves_a_consistent_session(tmp_path):
    _new(tmp_path).close()
    proc = subprocess.Popen([sys.executable, str(_crasher(tmp_path)), "20", "loop"], stdout=subprocess.PIPE,
                            text=True)
    assert proc.stdout.readline().strip() == "ready"
    time.sleep(0.3)                                   # let it rewrite and re-record "busy" many times
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    with Session.open(tmp_path / "s") as s:           # the kernel released the lock
        assert all(s.is_done(f"c{i:05d}") for i in range(20))
        busy = s.capture("busy")
        # the last record names a file that is intact, or the next rewrite was in flight: then the
        # checksum tells (never a record silently pointing at other content)
        assert busy is not None
        problem = s.verify_file(busy)
        assert problem is None or "checksum" in problem or "bytes" in problem


def test_torn_last_journal_line_is_ignored(tmp_path):
    s = _new(tmp_path)
    info = s.write_file("a.bin", b"a")
    s.add_capture("a", file=info.path, sha256=info.sha256, bytes=info.bytes)
    s._journal.write(b'{"op":"capture","id":"b","rec')     # the process died mid-append
    s._journal.flush()
    os.close(s._lock_fd)
    s._lock_fd = -1
    with Session.open(tmp_path / "s") as t:
        assert t.is_done("a") and t.capture("b") is None


def test_corrupt_journal_line_in_the_middle_is_an_error(tmp_path):
    s = _new(tmp_path)
    s._journal.write(b"garbage\n")
    s._journal.flush()
    s.add_capture("a", file=None)
    os.close(s._lock_fd)
    s._lock_fd = -1
    with pytest.raises(SessionError, match="line 1 is corrupt"):
        Session.open(tmp_path / "s")


def test_second_writer_is_refused(tmp_path):
    s = _new(tmp_path)
    with pytest.raises(SessionLockedError, match="another process"):
        Session.open(tmp_path / "s")
    assert Session.read(tmp_path / "s")["object"]["name"] == "tsuba"   # readers are fine
    s.close()
    Session.open(tmp_path / "s").close()


def test_create_refuses_an_existing_session(tmp_path):
    _new(tmp_path).close()
    with pytest.raises(SessionError, match="--resume"):
        _new(tmp_path)


@pytest.mark.parametrize("content,match", [
    (None, "not a kogei session"),
    ("{not json", "unreadable"),
    (json.dumps({"schema": "other"}), "not a kogei session manifest"),
    (json.dumps({"schema": "kogei.session", "version": 99}), "update kogei"),
])
def test_open_bad_sessions(tmp_path, content, match):
    d = tmp_path / "bad"
    d.mkdir()
    if content is not None:
        (d / MANIFEST).write_text(content)
    with pytest.raises(SessionError, match=match):
        Session.open(d)


def test_bad_records_and_names(tmp_path):
    s = _new(tmp_path)
    with pytest.raises(SessionError, match="not JSON"):
        s.add_capture("x", angle_deg=float("nan"))
    with pytest.raises(SessionError, match="relative path"):
        s.write_file("../escape.bin", b"")
    with pytest.raises(SessionError, match="managed by the session"):
        s.update("captures", {})
    with pytest.raises(SessionError, match="status must be"):
        s.set_status("done")
    assert s.capture("x") is None                  # a refused record changes nothing
    s.close()
    with pytest.raises(SessionError, match="closed"):
        s.add_capture("y")


def test_atomic_write_replaces_whole(tmp_path):
    p = atomic_write_bytes(tmp_path / "f.bin", b"old")
    atomic_write_bytes(p, b"new content")
    assert p.read_bytes() == b"new content"


def test_group_commit_syncs_files_at_the_interval_and_at_checkpoints(tmp_path, monkeypatch):
    synced: list[int] = []
    real_fsync = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: (synced.append(fd), real_fsync(fd)))
    lazy = Session.create(tmp_path / "lazy", plan={}, sync_interval_s=3600.0)
    synced.clear()
    for i in range(20):
        info = lazy.write_file(f"f/{i}.bin", b"x")
        lazy.add_capture(str(i), file=info.path, sha256=info.sha256, bytes=info.bytes)
    assert synced == []                      # nothing forced to disk yet: the OS has it (crash-safe)...
    lazy.checkpoint()
    assert len(synced) >= 20 + 1             # ...and a checkpoint makes every file and the journal durable
    lazy.close()
    eager = Session.create(tmp_path / "eager", plan={}, sync_interval_s=0)
    synced.clear()
    info = eager.write_file("a.bin", b"x")
    eager.add_capture("a", file=info.path, sha256=info.sha256, bytes=info.bytes)
    assert len(synced) >= 2                  # the file and the journal line, at once
    eager.close()
    with pytest.raises(SessionError, match="sync_interval_s"):
        Session.create(tmp_path / "bad", plan={}, sync_interval_s=-1)
