"""A :class:`app.gui.workers.WorkerProcess` runs its jobs in one process, and a cancelled job leaves none behind.

Ground truth: the operating system's process ids (the job reports the id of the process it ran in) and the
process's own liveness after a cancel.
"""

from __future__ import annotations

import os
import time

import pytest

pytest.importorskip("PySide6.QtWidgets", reason="the GUI tests need PySide6 (pip install 'kogei[gui]')")


def _pid(tag: str, message) -> tuple[str, int]:
    message(f"running {tag}")
    return tag, os.getpid()


def _forever(message) -> None:
    message("started")
    while True:
        time.sleep(0.05)


def _run(qtbot, job) -> dict:
    seen: dict = {"messages": []}
    job.message.connect(seen["messages"].append)
    job.succeeded.connect(lambda out: seen.setdefault("result", out))
    job.failed.connect(lambda text, exc: seen.setdefault("failed", text))
    with qtbot.waitSignal(job.finished, timeout=120_000):
        job.start()
    return seen


def test_jobs_share_the_worker_process_until_one_is_cancelled(qtbot):
    from app.gui.workers import ProcessJob, WorkerProcess

    worker = WorkerProcess()
    try:
        first = _run(qtbot, ProcessJob(_pid, "a", worker=worker))
        second = _run(qtbot, ProcessJob(_pid, "b", worker=worker))
        assert first["result"][0] == "a" and second["result"][0] == "b"
        assert first["messages"] == ["running a"] and second["messages"] == ["running b"]
        assert first["result"][1] == second["result"][1] != os.getpid()        # one process, not the window's
        assert worker.processes_started == 1
        # a cancelled job stops its process; the next job runs in a new one
        stuck = ProcessJob(_forever, worker=worker)
        started: list[str] = []
        stuck.message.connect(started.append)
        stuck.start()
        qtbot.waitUntil(lambda: started == ["started"], timeout=120_000)
        proc = stuck._proc
        stuck.cancel()
        assert stuck.done and stuck.cancelled and not proc.is_alive()
        third = _run(qtbot, ProcessJob(_pid, "c", worker=worker))
        assert third["result"][0] == "c" and third["result"][1] not in (first["result"][1], proc.pid)
        assert worker.processes_started == 2
    finally:
        worker.stop()
