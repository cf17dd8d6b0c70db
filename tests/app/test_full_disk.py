"""A full disk and a read-only filesystem under every command that writes a session: ``kogei report``,
``batch``, ``process``, ``calibrate`` and ``capture --resume`` end with a one-line message (no
traceback), lose no capture, and complete when run again once the fault is gone.

The fault is injected where kogei writes: every ``os.open`` / ``open`` for writing of a path inside
the session root fails with the given errno once ``after`` such opens have succeeded (``after=0``:
the disk is full or read-only from the start; ``after=3``: the lock, the journal and the first
checkpoint were written, the next write fails, as when the disk fills up mid-command).
"""

from __future__ import annotations

import builtins
import errno
import io
import multiprocessing
import os
from pathlib import Path

import pytest

from app.capture.runner import CapturePlan
from app.cli import main
from app.session import Session
from tests.app.batch_session import built_sessions, copy_session
from tests.app.test_untrusted_session_capture import PLAN, _config, _interrupted_session, _station

_WRITE_FLAGS = os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_APPEND | os.O_TRUNC


class _Fault:
    """Fail writes below ``root`` with ``code`` once ``after`` of them have succeeded."""

    def __init__(self, root: Path, code: int, after: int) -> None:
        self.root, self.code = os.path.realpath(root), code
        # shared memory: a batch worker forked from this process counts in the same place
        self._left, self._failed = multiprocessing.RawValue("i", after), multiprocessing.RawValue("i", 0)

    @property
    def failed(self) -> int:
        return self._failed.value

    def _hit(self, path) -> None:
        if isinstance(path, int):
            return
        p = os.path.realpath(os.fsdecode(os.fspath(path)))
        if p != self.root and not p.startswith(self.root + os.sep):
            return
        if self._left.value > 0:
            self._left.value -= 1
            return
        self._failed.value += 1
        raise OSError(self.code, os.strerror(self.code), str(path))

    def install(self, monkeypatch) -> None:
        real_os_open, real_open = os.open, builtins.open

        def os_open(path, flags, *args, **kwargs):
            if flags & _WRITE_FLAGS:
                self._hit(path)
            return real_os_open(path, flags, *args, **kwargs)

        def open_(file, mode="r", *args, **kwargs):
            if any(c in mode for c in "wax+"):
                self._hit(file)
            return real_open(file, mode, *args, **kwargs)

        monkeypatch.setattr(os, "open", os_open)
        monkeypatch.setattr(builtins, "open", open_)
        monkeypatch.setattr(io, "open", open_)


def _captures(root: Path) -> dict:
    return {k: (r.get("file"), r.get("sha256")) for k, r in Session.read(root)["captures"].items()}


def _under_fault(monkeypatch, capsys, root: Path, argv: list[str], code: int, after: int, *,
                 one_line: bool = True, exit_code: int = 2, lines: int = 1) -> None:
    """Run ``argv`` with the fault: one-line message, no traceback, every capture still listed."""
    before = _captures(root)
    capsys.readouterr()
    fault = _Fault(root, code, after)
    fault.install(monkeypatch)
    try:
        result = main(argv)
    finally:
        monkeypatch.undo()
    out, err = capsys.readouterr()
    assert fault.failed > 0, f"the fault was never hit: {argv}"
    assert "Traceback" not in out + err
    assert result == exit_code, err
    if one_line:
        assert len(err.strip().splitlines()) == lines, err
        assert "free space" in err or "writable" in err or "read-only" in err, err
    after_fault = _captures(root)
    assert all(after_fault.get(k) == v for k, v in before.items()), "a capture was lost"


def _completes(capsys, root: Path, argv: list[str]) -> None:
    from app.cli.process import EXIT_PARTIAL

    capsys.readouterr()
    result = main(argv)
    out, err = capsys.readouterr()
    # the fixture's one-pass scan meshes to an open surface: kogei process says so and exits EXIT_PARTIAL
    assert result == 0 or (result == EXIT_PARTIAL and "INCOMPLETE" in err and argv[0] == "process"), err
    assert "Traceback" not in out + err


FAULTS = [(errno.ENOSPC, 0), (errno.ENOSPC, 3), (errno.EROFS, 0), (errno.EROFS, 3), (errno.EACCES, 3)]
HEAVY_FAULTS = [(errno.ENOSPC, 3), (errno.EROFS, 0)]


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    return built_sessions(tmp_path_factory)


@pytest.mark.parametrize("code,after", FAULTS)
def test_report(sessions, tmp_path, monkeypatch, capsys, code, after):
    root = copy_session(sessions.raw, tmp_path / "s")
    argv = ["report", str(root)]
    _under_fault(monkeypatch, capsys, root, argv, code, after)
    _completes(capsys, root, argv)


@pytest.mark.parametrize("code,after", FAULTS)
def test_calibrate(sessions, tmp_path, monkeypatch, capsys, code, after):
    root = copy_session(sessions.cal, tmp_path / "cal")
    argv = ["calibrate", str(root), "--sphere-radius", "25"]
    _under_fault(monkeypatch, capsys, root, argv, code, after)
    _completes(capsys, root, argv)
    assert Session.read(root)["calibration"]["path"] == "calibration.json"


@pytest.mark.parametrize("code,after", HEAVY_FAULTS)
def test_process(sessions, tmp_path, monkeypatch, capsys, code, after):
    root = copy_session(sessions.raw, tmp_path / "s")
    argv = ["process", str(root), "--preset", "draft", "--calibration", str(sessions.cal), "--quiet"]
    _under_fault(monkeypatch, capsys, root, argv, code, after)
    _completes(capsys, root, argv)


@pytest.mark.parametrize("code,after", HEAVY_FAULTS)
def test_batch(sessions, tmp_path, monkeypatch, capsys, code, after):
    root = copy_session(sessions.raw, tmp_path / "s")
    argv = ["batch", str(root), "--steps", "geometry,colour,report", "--preset", "draft",
            "--calibration", str(sessions.cal), "--quiet"]
    # the workers are forked from this process (not started by a fork server) so that they inherit the fault
    real_context = multiprocessing.get_context
    monkeypatch.setattr("app.batch.runner.multiprocessing.get_context", lambda method=None: real_context("fork"))
    # the batch reports a failed session in its summary and exits 1 by its own rule
    _under_fault(monkeypatch, capsys, root, argv, code, after, one_line=False, exit_code=1)
    _completes(capsys, root, argv)


@pytest.mark.parametrize("code,after", [(errno.ENOSPC, 0), (errno.ENOSPC, 3), (errno.EROFS, 0),
                                        (errno.EACCES, 3)])
def test_capture_resume(tmp_path, monkeypatch, capsys, code, after):
    root = tmp_path / "s"
    with _station(tmp_path) as st:
        _interrupted_session(root, config=_config(st))
        argv = ["capture", "--resume", str(root), "--unattended", "--quiet"]
        _under_fault(monkeypatch, capsys, root, argv, code, after)
        _completes(capsys, root, argv)
    m = Session.read(root)
    assert m["status"] == "complete"
    assert sum(r["kind"] == "profile" for r in m["captures"].values()) == PLAN.steps * PLAN.passes


@pytest.mark.parametrize("code,after", [(errno.ENOSPC, 8), (errno.ENOSPC, 16), (errno.EROFS, 12)])
def test_capture_resume_when_the_disk_fills_mid_pass(tmp_path, monkeypatch, capsys, code, after):
    # a profile of an 8-step pass fails: the capture's "interrupted" message (the cause, then the resume
    # command; exit 1 by its own rule) and no further line about closing the session; or every profile is
    # taken and only the last checkpoint fails: one line saying so, exit 2, and the next command saves it
    plan = CapturePlan("scan", steps=8, passes=1, camera=False)
    root = tmp_path / "s"
    with _station(tmp_path) as st:
        _interrupted_session(root, plan=plan, config=_config(st))
        argv = ["capture", "--resume", str(root), "--unattended", "--quiet"]
        interrupted = after != 16       # the capture's own message: what happened, then how to resume
        _under_fault(monkeypatch, capsys, root, argv, code, after, exit_code=1 if interrupted else 2,
                     lines=2 if interrupted else 1)
        held = _captures(root)
        if after == 16:                             # every profile taken; only the last checkpoint failed
            argv = ["report", str(root)]
        _completes(capsys, root, argv)
    m = Session.read(root)
    assert m["status"] == "complete" and sum(r["kind"] == "profile" for r in m["captures"].values()) == 8
    assert all(_captures(root)[k] == v for k, v in held.items())


@pytest.mark.parametrize("after", [4, 5])
def test_process_when_fsync_reports_the_full_disk(sessions, tmp_path, monkeypatch, capsys, after):
    # a network or delayed-allocation filesystem says ENOSPC only at fsync: the mesh's, then the manifest's
    root = copy_session(sessions.raw, tmp_path / "s")
    argv = ["process", str(root), "--preset", "draft", "--calibration", str(sessions.cal), "--quiet"]
    before = _captures(root)
    left, real_fsync = [after], os.fsync

    def fsync(fd):
        if left[0] <= 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        left[0] -= 1
        return real_fsync(fd)

    capsys.readouterr()
    monkeypatch.setattr(os, "fsync", fsync)
    try:
        code = main(argv)
    finally:
        monkeypatch.undo()
    out, err = capsys.readouterr()
    assert code == 2 and "Traceback" not in out + err and len(err.strip().splitlines()) == 1, err
    assert "free space" in err
    assert all(_captures(root).get(k) == v for k, v in before.items())
    _completes(capsys, root, argv)
