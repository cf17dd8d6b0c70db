"""Expensive test inputs built once per test run and shared by the pytest-xdist workers.

A simulated capture or a projected session takes tens of seconds; several test files start from the same
one.  :func:`built_once` builds it in a folder shared by the workers of this run (the parent of their base
temporary folders; under ``-n 0`` the base temporary folder itself): a file lock lets the first process that
needs it build it while the others wait, and a marker file records that the build finished, so a build that
raised is started again by the next caller.  Callers change only their own copy (:func:`copy_tree`).
"""

from __future__ import annotations

import fcntl
import os
import shutil
from collections.abc import Callable
from pathlib import Path

__all__ = ["built_once", "copy_tree"]


def _shared_folder(tmp_path_factory, name: str) -> Path:
    """``name`` in the folder shared by the xdist workers of this run (created if missing)."""
    base = tmp_path_factory.getbasetemp()
    shared = (base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / name
    shared.mkdir(parents=True, exist_ok=True)
    return shared


def built_once(tmp_path_factory, name: str, build: Callable[[Path], None]) -> Path:
    """The folder that ``build(folder)`` filled, run once per test run whichever process asks first.

    Parameters
    ----------
    tmp_path_factory
        pytest's ``tmp_path_factory`` of the calling process.
    name
        Name of the shared folder; one per distinct build.
    build
        Fills the empty folder it is given.  Runs under the lock: it may itself call :func:`built_once`
        with another ``name``.

    Returns
    -------
    Path
        The built folder, shared: copy it (:func:`copy_tree`) before changing anything in it.
    """
    shared = _shared_folder(tmp_path_factory, name)
    built, done = shared / "built", shared / "done"
    with open(shared / "lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            if not done.exists():
                if built.exists():
                    shutil.rmtree(built)
                built.mkdir()
                build(built)
                done.write_text("ok\n")
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
    return built


def copy_tree(src: Path, dst: Path) -> Path:
    """A copy at ``dst`` of the folder ``src`` without its ``*.lock`` files (a session's locks are its own)."""
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("*.lock"))
    return dst
