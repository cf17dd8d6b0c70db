"""The newcomer's path, literally: the shell lines of docs/simulator.md's "A first session, step by step".

Every line of that block runs as written, in an empty folder, through a ``kogei`` on ``PATH`` that runs
this checkout: the two simulated stations started in the background, each capture line (which must be
exactly the command its station printed), the scanner calibration, ``kogei process``, ``kogei batch``
and ``kogei report``.  Every step must exit 0, and the results are judged against the simulation's
truth (the station file's ``sensor_to_room`` and region materials), not against the code's own output:
the calibrated sensor pose, a registered and watertight mesh (its edges counted here),
the chart found on every pass, and the hawk's gold beak identified as gold.

This is the whole product path (about a minute on 2 cores; marked ``slow``, which ``make test`` runs).
"""

from __future__ import annotations

import json
import os
import re
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
DOC = REPO / "docs" / "simulator.md"
SECTION = "## A first session, step by step"

pytestmark = pytest.mark.slow


def walkthrough_lines(text: str) -> list[str]:
    """The lines of the first fenced block after :data:`SECTION` (comments and blank lines dropped)."""
    start = text.index(SECTION)
    block = re.search(r"^```[a-z]*\n(.*?)^```", text[start:], re.S | re.M)
    assert block, f"{DOC}: no fenced block under {SECTION!r}"
    return [ln.split("  #")[0].strip() for ln in block.group(1).splitlines()
            if ln.strip() and not ln.strip().startswith("#")]


def _kogei_shim(bin_dir: Path) -> None:
    """A ``kogei`` program that runs this checkout with this interpreter (what ``pip install -e .`` gives)."""
    bin_dir.mkdir()
    shim = bin_dir / "kogei"
    shim.write_text(f"#!{sys.executable}\nimport sys\nsys.path.insert(0, {str(REPO)!r})\n"
                    "from app.cli import main\nif __name__ == '__main__':\n    sys.exit(main())\n")
    shim.chmod(0o755)


def _wait_for_station(proc: subprocess.Popen, station_file: Path, timeout_s: float = 120.0) -> dict:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if station_file.is_file():
            try:
                return json.loads(station_file.read_text())
            except json.JSONDecodeError:       # written atomically, but be patient with a slow disk
                pass
        if proc.poll() is not None:
            raise AssertionError(f"kogei mock exited with {proc.returncode}: {proc.stdout.read()}")
        time.sleep(0.1)
    raise AssertionError(f"{station_file} did not appear within {timeout_s} s")


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def test_the_documented_first_session_runs_and_measures_the_simulated_truth(tmp_path):
    lines = walkthrough_lines(DOC.read_text(encoding="utf-8"))
    assert [ln.split()[:2] for ln in lines if ln.startswith("kogei")] == [
        ["kogei", "mock"], ["kogei", "capture"], ["kogei", "calibrate"], ["kogei", "mock"], ["kogei", "capture"],
        ["kogei", "process"], ["kogei", "batch"], ["kogei", "report"]], lines
    work = tmp_path / "work"
    work.mkdir()
    _kogei_shim(tmp_path / "bin")
    env = {**os.environ, "PATH": f"{tmp_path / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}", "PWD": str(work),
           "PYTHONPATH": str(REPO)}
    station: subprocess.Popen | None = None
    stations: dict[str, dict] = {}
    info: dict = {}
    log: list[str] = []
    try:
        for line in lines:
            if line.endswith("&"):
                assert station is None, "the walkthrough starts a station while another runs"
                command = line[:-1].strip()
                station = subprocess.Popen(["bash", "-c", f"exec {command}"], cwd=work, env=env, text=True,
                                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
                root = work / shlex.split(command)[shlex.split(command).index("--root") + 1]
                info = _wait_for_station(station, root / "station.json")
                stations[info["world"]] = info
                continue
            if line == "kill %1":
                assert station is not None
                _stop(station)
                station = None
                continue
            if line.startswith("kogei capture"):
                printed = info["capture"]["gphoto2"]
                documented = shlex.split(line.replace("$PWD", str(work)))
                assert documented == shlex.split(printed), f"docs: {line}\nprinted: {printed}"
            t = time.perf_counter()
            done = subprocess.run(["bash", "-c", line], cwd=work, env=env, text=True, capture_output=True,
                                  timeout=600)
            log.append(f"{time.perf_counter() - t:6.1f} s  {line[:60]}")
            print(log[-1], flush=True)
            assert done.returncode == 0, f"{line}\nexit {done.returncode}\n{done.stdout}\n{done.stderr}"
    finally:
        if station is not None:
            _stop(station)

    # the scanner calibration found the simulated sensor's pose
    cal = json.loads((work / "calibration-session" / "calibration.json").read_text())
    truth = np.array(stations["sphere:25:60"]["sensor_to_room"])
    fitted = np.array(cal["sensor_to_room"])
    angle_deg = np.degrees(np.arccos(np.clip((np.trace(fitted[:3, :3].T @ truth[:3, :3]) - 1) / 2, -1, 1)))
    assert angle_deg < 0.05 and np.linalg.norm(fitted[:3, 3] - truth[:3, 3]) < 0.05

    # every pass registered, and the mesh closed and consistently oriented: every directed edge once, its
    # reverse once (counted here from the triangles, not by the code that made the mesh)
    from render.meshio import load_mesh

    session = work / "kogei-session"
    report = json.loads((session / "products" / "process-report.json").read_text())
    assert [p.get("registered") for p in report["passes"]] == [True, True, True]
    assert report["complete"] is True and report["warnings"] == []
    tri = np.asarray(load_mesh(session / "products" / "mesh.ply").triangles, dtype=np.int64)
    directed = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    keys = directed[:, 0] * (tri.max() + 1) + directed[:, 1]
    reverse = directed[:, 1] * (tri.max() + 1) + directed[:, 0]
    assert len(tri) > 10_000 and np.unique(keys).size == keys.size and np.isin(reverse, keys).all()

    # the chart was found on the chart frame of every pass
    for p in (1, 2, 3):
        chart = json.loads((session / "products" / "colour" / f"p{p:02d}-chart.json").read_text())
        assert chart["method"] == "mcc" and len(chart["patches"]) == 24, f"pass {p}: {chart.get('warnings')}"

    # the hawk's gold beak (the world's truth) is identified as gold
    hawk = stations["hawk:4000"]
    assert hawk["materials"]["beak"] == "gold"
    materials = json.loads((session / "products" / "materials.json").read_text())
    golds = [r for r in materials["regions"] if r["material"] == "gold"]
    # named gold at the confidence the report calls reliable (0.8: calibrated, about one in five wrong there)
    assert golds and max(r["confidence"] for r in golds) >= 0.8, materials["regions"]
    assert (session / "products" / "report.html").stat().st_size > 10_000
