"""Run an external program (gphoto2, a user's hook) with a deadline that its children cannot defeat.

The program runs in its own process group (``start_new_session=True``),
its output goes to anonymous temporary files rather than pipes, and only
the program itself is waited for: a child it leaves behind (``sleep 100 &``,
even a detached ``setsid`` one) that keeps the output open cannot hold the
caller up.  On timeout the whole group is killed and the wait after the
kill is bounded too.

Examples
--------
>>> import sys
>>> done = run_bounded([sys.executable, "-c", "print('hi')"], timeout_s=10)
>>> done.returncode, done.stdout, done.timed_out
(0, 'hi\\n', False)
"""

from __future__ import annotations

import os
import signal
import subprocess
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import IO

__all__ = ["Finished", "run_bounded", "OUTPUT_LIMIT_BYTES"]

#: At most this much of each output stream is kept (the end of it).
OUTPUT_LIMIT_BYTES = 1 << 20


@dataclass(frozen=True)
class Finished:
    """How a program ended: its status (None if it was killed at the deadline) and its output."""

    returncode: int | None
    stdout: str
    stderr: str
    timed_out: bool


def _kill_group(pid: int) -> None:
    try:
        os.killpg(pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass


def _tail(fh: IO[bytes]) -> str:
    size = fh.seek(0, os.SEEK_END)
    fh.seek(max(0, size - OUTPUT_LIMIT_BYTES))
    return fh.read(OUTPUT_LIMIT_BYTES).decode("utf-8", "replace")


def run_bounded(argv: Sequence[str], *, timeout_s: float, cwd: str | os.PathLike[str] | None = None,
                env: Mapping[str, str] | None = None, kill_leftovers: bool = False,
                grace_s: float = 2.0) -> Finished:
    """Run ``argv`` (no shell) for at most ``timeout_s`` seconds plus ``grace_s`` after a kill.

    Parameters
    ----------
    argv
        The program and its arguments.
    timeout_s
        Deadline of the program itself (> 0).
    cwd, env
        Working folder and environment (None: the caller's).
    kill_leftovers
        Also kill what the program left running in its process group when it
        ends in time (a camera command's helpers).
    grace_s
        Bound on the wait for the killed program to be reaped.

    Returns
    -------
    Finished
        Its status and output (the last :data:`OUTPUT_LIMIT_BYTES` of each stream).

    Raises
    ------
    OSError
        The program cannot be started (``FileNotFoundError`` when it does not exist).
    """
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        proc = subprocess.Popen(list(argv), cwd=cwd, env=None if env is None else dict(env),
                                stdin=subprocess.DEVNULL, stdout=out, stderr=err, start_new_session=True)
        timed_out = False
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            timed_out = True
        if timed_out or kill_leftovers:
            _kill_group(proc.pid)
        if timed_out:
            try:
                proc.wait(timeout=grace_s)
            except subprocess.TimeoutExpired:
                proc.kill()
        return Finished(None if timed_out else proc.returncode, _tail(out), _tail(err), timed_out)
