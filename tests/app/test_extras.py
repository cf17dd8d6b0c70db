"""A headless batch machine needs neither Qt nor Dask: the optional extras ``kogei[gui]`` and ``kogei[cluster]``.

The command line runs in a subprocess whose Python cannot import PySide6, shiboken6, dask or distributed:
a folder first on ``PYTHONPATH`` holds packages of those names whose ``__init__`` records the attempt (with
its stack) and raises ImportError.  ``kogei process``, ``render``, ``report`` and ``batch`` (local workers)
then run and never even try to import them; ``kogei gui`` and ``kogei batch --dask`` end with a one-line
message naming the extra to install, exit code 2.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.app.batch_session import built_sessions, copy_session

ROOT = Path(__file__).resolve().parents[2]
BLOCKED = ("PySide6", "shiboken6", "dask", "distributed")
_BLOCKER = '''import os, traceback
_log = os.environ.get("KOGEI_BLOCKED_LOG")
if _log:
    with open(_log, "a") as fh:
        fh.write("import {name}\\n" + "".join(traceback.format_stack()) + "\\n")
raise ImportError("{name} is not installed (blocked by tests/app/test_extras.py)")
'''


@pytest.fixture(scope="module")
def no_extras(tmp_path_factory) -> Path:
    """A folder to put first on ``PYTHONPATH``: every package of :data:`BLOCKED` fails to import."""
    folder = tmp_path_factory.mktemp("no-extras")
    for name in BLOCKED:
        (folder / name).mkdir()
        (folder / name / "__init__.py").write_text(_BLOCKER.format(name=name))
    return folder


def _run(no_extras: Path, tmp: Path, *args: str) -> tuple[subprocess.CompletedProcess, str]:
    """Run ``python ARGS`` without the extras; returns the process and the blocked imports it attempted."""
    log = tmp / "blocked-imports.log"
    log.unlink(missing_ok=True)
    path = [str(no_extras), str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(path), "KOGEI_BLOCKED_LOG": str(log),
           "QT_QPA_PLATFORM": "offscreen"}
    proc = subprocess.run([sys.executable, *args], env=env, cwd=tmp, capture_output=True, text=True, timeout=600)
    return proc, (log.read_text() if log.exists() else "")


def _kogei(no_extras: Path, tmp: Path, *args: str) -> tuple[subprocess.CompletedProcess, str]:
    return _run(no_extras, tmp, "-m", "app.cli", *(str(a) for a in args))


@pytest.mark.parametrize("name", BLOCKED)
def test_the_blocked_packages_cannot_be_imported(no_extras, tmp_path, name):
    proc, attempts = _run(no_extras, tmp_path, "-c", f"import {name}")
    assert proc.returncode == 1 and "blocked by tests/app/test_extras.py" in proc.stderr, proc.stderr
    assert attempts.startswith(f"import {name}\n")


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    return built_sessions(tmp_path_factory)


def test_headless_commands_run_without_qt_and_dask(no_extras, sessions, tmp_path):
    cal = sessions.cal
    a = copy_session(sessions.raw, tmp_path / "a")
    proc, attempts = _kogei(no_extras, tmp_path, "process", a, "--preset", "draft", "--calibration", cal, "--quiet")
    # a one-pass scan: an open mesh, which kogei process reports as a partial result (exit 1)
    assert proc.returncode == 0 or (proc.returncode == 1 and "INCOMPLETE" in proc.stderr), proc.stderr
    assert (a / "products/mesh.ply").is_file()

    proc, attempts2 = _kogei(no_extras, tmp_path, "render", a / "products/mesh.ply", "--size", "64x48",
                             "--preset", "draft", "--out", tmp_path / "r.png", "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "r.png").read_bytes().startswith(b"\x89PNG")

    proc, attempts3 = _kogei(no_extras, tmp_path, "report", a)
    assert proc.returncode == 0, proc.stderr
    assert (a / "products/report.html").read_bytes().startswith(b"<!DOCTYPE html>")

    # local worker processes (forkserver) inherit the same Python path
    b = copy_session(sessions.raw, tmp_path / "b")
    proc, attempts4 = _kogei(no_extras, tmp_path, "batch", b, "--steps", "geometry,report", "--preset", "draft",
                             "--calibration", cal, "--workers", "1", "--quiet")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert (b / "products/mesh.ply").is_file() and (b / "products/report.html").is_file()

    tried = attempts + attempts2 + attempts3 + attempts4
    assert not tried, f"a headless command tried to import an optional extra:\n{tried}"


def test_gui_without_pyside6_names_the_gui_extra(no_extras, tmp_path):
    proc, _ = _kogei(no_extras, tmp_path, "gui")
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("kogei gui: error:"), proc.stderr
    assert "pip install 'kogei[gui]'" in lines[0]


def test_batch_dask_without_distributed_names_the_cluster_extra(no_extras, sessions, tmp_path):
    proc, _ = _kogei(no_extras, tmp_path, "batch", sessions.raw, "--dask", "tcp://127.0.0.1:1")
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("kogei batch: error:"), proc.stderr
    assert "pip install 'kogei[cluster]'" in lines[0]
