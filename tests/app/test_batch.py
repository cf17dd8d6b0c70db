"""`kogei batch`: incremental steps with fingerprints, failure isolation, consistency after Ctrl-C and
kill -9, the Dask engine.  Sessions are tiny simulated captures (tests/app/batch_session.py).

What is checked against what:
* every product a step lists is compared with an independent SHA-256 of the file on disk;
* "up to date" is decided by the recorded inputs (the manifest's capture/product checksums), the
  parameters and the code version: each is changed in turn and the step must run again, and only it
  (and the steps reading its products);
* after an interruption the session opens (its lock was released), its journal replays, every product
  it records is intact, the interrupted step has no record, and a rerun completes it without redoing
  the steps that had finished.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from app.batch.code_version import code_version, module_imports
from app.batch.runner import LOG_FILE, process_one, run_batch
from app.batch.steps import STEPS, BatchOptions, fingerprint, parse_steps, step_inputs, up_to_date
from app.cli import main
from app.errors import UsageError
from app.session import Session
from tests.app.batch_session import built_sessions, copy_session

ROOT = Path(__file__).resolve().parents[2]
ALL = ("geometry", "colour", "materials", "render", "report")


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    return built_sessions(tmp_path_factory)


@pytest.fixture(scope="module")
def done(base, tmp_path_factory):
    """A session on which every step has run once (in this process), with the result of that run."""
    root = copy_session(base.raw, tmp_path_factory.mktemp("done") / "s")
    options = BatchOptions(preset="draft", calibration=str(base.cal), render_size=(96, 72))
    result = process_one(str(root), ALL, options)
    return root, options, result


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _assert_consistent(root: Path) -> dict:
    """The session opens, and every product and every step record points at intact files."""
    with Session.open(root) as s:        # the lock is free and the journal replays
        manifest = json.loads(json.dumps(s.manifest))
    for key, rec in (manifest.get("products") or {}).items():
        for f in _files(rec):
            assert _sha(root / f["file"]) == f["sha256"], (key, f["file"])
    for name, rec in ((manifest.get("batch") or {}).get("steps") or {}).items():
        for files in rec["outputs"].values():
            for f in files:
                assert _sha(root / f["file"]) == f["sha256"], (name, f["file"])
    return manifest


def _files(rec) -> list[dict]:
    """Every file record (``file`` + ``sha256``) inside a product entry."""
    if not isinstance(rec, dict):
        return []
    if "file" in rec:
        return [rec]
    return [f for v in rec.values() for f in _files(v)]


def _statuses(result) -> dict[str, str]:
    return {s.name: s.status for s in result.steps}


def test_every_step_runs_once_then_is_skipped(done):
    root, options, first = done
    assert first.status == "ok", first
    assert _statuses(first) == {"geometry": "ran", "colour": "ran", "materials": "ran", "render": "ran",
                                 "report": "ran"}
    manifest = _assert_consistent(root)
    steps = manifest["batch"]["steps"]
    assert set(steps) == set(ALL)
    # the geometry step read exactly the gathered profiles of the one pass
    assert set(steps["geometry"]["inputs"]) == {"p01/profiles"}
    assert steps["geometry"]["inputs"]["p01/profiles"] == manifest["captures"]["p01/profiles"]["sha256"]
    # no posed photos in this session: no materials on the mesh, so the render used the identified ones
    assert steps["render"]["inputs"] == {"mesh": manifest["products"]["mesh"]["sha256"],
                                         "materials": manifest["products"]["materials"]["report"]["sha256"],
                                         "object_materials": "none"}
    for ill in ("D65", "A"):
        img = Image.open(root / manifest["products"]["renders"]["images"][ill]["file"])
        assert img.size == (96, 72)
        assert np.asarray(img)[..., :3].std() > 5      # the object is in view, not an empty frame
    assert (root / "products/report.html").read_bytes().startswith(b"<!DOCTYPE html>")
    # the chart of the simulated frame: found by mcc, every patch usable, and a 3x3 fit of the simulated
    # camera (linear, known sensitivities) to the chart's reference colours within a few dE00
    chart = json.loads((root / manifest["products"]["colour"]["passes"]["p01"]["chart"]["file"]).read_text())
    assert chart["method"] == "mcc" and all(p["usable"] for p in chart["patches"])
    assert chart["patch_errors"]["mean"] < 3.0 and chart["patch_errors"]["max"] < 6.0
    log = (root / LOG_FILE).read_text()
    assert "geometry: started (never run)" in log and "report: done" in log

    again = process_one(str(root), ALL, options)
    assert again.status == "skipped"
    assert _statuses(again) == {"geometry": "skipped", "colour": "skipped", "materials": "skipped",
                                 "render": "skipped", "report": "skipped"}
    assert _assert_consistent(root)["batch"] == manifest["batch"]


def test_a_changed_parameter_or_product_reruns_only_what_depends_on_it(done, tmp_path):
    src, options, _ = done
    root = copy_session(src, tmp_path / "s")
    before = Session.read(root)
    # a parameter of the render step: render and the report (which shows the renders) run again
    bigger = BatchOptions(preset=options.preset, calibration=options.calibration, render_size=(112, 84))
    r = process_one(str(root), ALL, bigger)
    assert _statuses(r) == {"geometry": "skipped", "colour": "skipped", "materials": "skipped", "render": "ran",
                            "report": "ran"}
    assert r.steps[3].reason == "params changed"
    after = _assert_consistent(root)
    assert after["batch"]["steps"]["geometry"] == before["batch"]["steps"]["geometry"]
    assert Image.open(root / "products/renders/A.png").size == (112, 84)
    # a product altered on disk: the step that wrote it runs again
    png = root / "products/renders/D65.png"
    png.write_bytes(png.read_bytes() + b"x")
    r = process_one(str(root), ("render",), bigger)
    assert _statuses(r) == {"render": "ran"}
    assert "products/renders/D65.png was changed" in r.steps[0].reason
    _assert_consistent(root)


def test_fingerprint_follows_inputs_parameters_and_code(done, tmp_path, monkeypatch):
    root, options, _ = done
    manifest = Session.read(root)
    geometry = STEPS["geometry"]
    assert up_to_date(geometry, root, manifest, options)[:2] == (True, "up to date")
    # another calibration file (same fit, other bytes): a parameter of the geometry step
    other = tmp_path / "cal.json"
    other.write_text(json.dumps({**json.loads((Path(options.calibration) / "calibration.json").read_text()),
                                 "note": "re-issued"}))
    moved = BatchOptions(preset="draft", calibration=str(other), render_size=options.render_size)
    assert up_to_date(geometry, root, manifest, moved)[:2] == (False, "params changed")
    # other input data: a different checksum of the gathered profiles
    edited = json.loads(json.dumps(manifest))
    edited["captures"]["p01/profiles"]["sha256"] = "0" * 64
    assert up_to_date(geometry, root, edited, options)[:2] == (False, "inputs changed")
    # other code: the modules' hash
    monkeypatch.setattr("app.batch.steps.code_version", lambda modules: type("V", (), {"sha256": "x"})())
    assert up_to_date(geometry, root, manifest, options)[:2] == (False, "code changed")


def test_code_version_hashes_the_modules_a_step_imports():
    v = code_version(("app.workflows.process_session",))
    # process_session imports these (directly or through processing.geometry.surface); no driver, no GUI
    for f in ("app/workflows/process_session.py", "processing/geometry/registration/__init__.py", "processing/geometry/surface.py",
              "processing/geometry/scan_points.py", "processing/geometry/holes.py"):
        assert f in v.files
    assert not any(f.startswith(("drivers/", "mocks/")) for f in v.files)
    digest = hashlib.sha256()
    for f in v.files:
        digest.update(f.encode() + b"\0" + (ROOT / f).read_bytes() + b"\0")
    assert v.sha256 == digest.hexdigest()
    assert module_imports("from .spectra import x\nfrom . import fresnel\n", "processing") == \
        {"processing.spectra", "processing.spectra.x", "processing", "processing.fresnel"}
    with pytest.raises(ValueError, match="no source file"):
        code_version(("app.no_such_module",))


def test_patch_errors_see_a_misordered_chart():
    from app.batch.colour import patch_errors
    from processing.camera.chart_layout import reference_lab

    lab = np.asarray(reference_lab("classic24"))
    import colour

    xyz = colour.Lab_to_XYZ(lab, colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"])
    rgb = xyz @ np.linalg.inv(np.array([[0.6, 0.3, 0.1], [0.2, 0.7, 0.1], [0.0, 0.1, 0.9]]))
    assert patch_errors(rgb, lab, np.ones(24, bool))["max"] < 1e-6      # a linear camera: no error
    assert patch_errors(rgb[::-1], lab, np.ones(24, bool))["mean"] > 10  # patches read in the wrong order
    with pytest.raises(ValueError, match="3 or more"):
        patch_errors(rgb, lab, np.arange(24) < 2)


@settings(max_examples=40, deadline=None)
@given(exponent=st.floats(-30, 30), seed=st.integers(0, 2**16))
def test_patch_errors_do_not_depend_on_the_exposure_scale(exponent, seed):
    from app.batch.colour import patch_errors
    from processing.camera.chart_layout import reference_lab

    lab = np.asarray(reference_lab("classic24"))
    rng = np.random.default_rng(seed)
    rgb = rng.uniform(0.02, 0.9, size=(24, 3))          # any camera response: the fit absorbs a 3x3 map
    base = patch_errors(rgb, lab, np.ones(24, bool))
    scaled = patch_errors(rgb * 10.0 ** exponent, lab, np.ones(24, bool))
    assert np.all(np.isfinite(scaled["delta_e00"]))
    np.testing.assert_allclose(scaled["delta_e00"], base["delta_e00"], rtol=1e-6, atol=1e-6)
    bad = rgb.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match=r"usable patch\(es\) \[4\] have no finite camera RGB"):
        patch_errors(bad, lab, np.ones(24, bool))


def test_fingerprint_is_canonical():
    parts = {"inputs": {"a": "1", "b": "2"}, "params": {"preset": "draft"}, "code": "c"}
    same = {"code": "c", "params": {"preset": "draft"}, "inputs": {"b": "2", "a": "1"}}
    assert fingerprint(parts) == fingerprint(same)
    expected = hashlib.sha256(b'{"code":"c","inputs":{"a":"1","b":"2"},"params":{"preset":"draft"}}').hexdigest()
    assert fingerprint(parts) == expected


def test_worker_pool_isolates_failed_sessions(base, done, tmp_path):
    from rich.console import Console

    from app.cli.batch import summary_table

    src, options, _ = done
    ok = copy_session(src, tmp_path / "ok")
    broken = copy_session(base.raw, tmp_path / "broken")
    (broken / "passes/p01/profiles.npz").unlink()       # the pass's gathered profiles are lost
    not_a_session = tmp_path / "empty"
    not_a_session.mkdir()
    progress = Console(file=io.StringIO(), width=160, height=20)   # not a terminal: the final frame is written once
    summary = run_batch([ok, broken, not_a_session], None, options=options, workers=2, progress=True, console=progress)
    by = {Path(r.session).name: r for r in summary.results}
    assert by["ok"].status == "skipped"                # the other sessions' failures did not stop it
    assert by["broken"].status == "failed"
    assert "no pass has usable points" in by["broken"].reason and "profiles.npz" in by["broken"].reason
    assert _statuses(by["broken"]) == {"geometry": "failed", "colour": "ran", "materials": "ran",
                                         "render": "not run", "report": "ran"}
    assert "needs geometry, which failed" in by["broken"].steps[3].reason
    assert by["empty"].status == "failed" and "not a kogei session" in by["empty"].reason
    assert summary.exit_code == 1 and summary.count("failed") == 2 and summary.count("skipped") == 1
    console = Console(record=True, width=200)
    console.print(summary_table(summary))
    text = console.export_text()
    assert "skipped (up to date)" in text and "no pass has usable points" in text and "not a kogei session" in text
    # the report of the failed session says what is missing and which command makes it
    html = (broken / "products/report.html").read_text()
    assert "Not in this session:</b> no mesh" in html and f"kogei process {broken}" in html
    _assert_consistent(broken)
    assert "geometry: FAILED" in (broken / LOG_FILE).read_text()
    # the progress display: a bar per step with what happened to the three sessions, and one overall
    bars = progress.file.getvalue()
    assert re.search(r"all steps .* 15/15", bars)
    assert re.search(r"geometry .* 3/3 +2 failed, 1 skipped", bars)
    assert re.search(r"colour .* 3/3 +1 failed, 1 ran, 1 skipped", bars)
    assert re.search(r"render .* 3/3 +2 failed, 1 skipped", bars)
    assert re.search(r"report .* 3/3 +1 failed, 1 ran, 1 skipped", bars)


#: Run argv[1:] with Ctrl-C at its default disposition, as a terminal's shell starts a foreground command: an
#: ignored SIGINT is inherited through exec, and a test run started in the background by a non-interactive shell
#: ignores it (the Ctrl-C then reached nobody and the batch ran to the end).
_FROM_A_TERMINAL = ("import os, signal, sys; signal.signal(signal.SIGINT, signal.SIG_DFL); "
                    "signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT}); os.execv(sys.argv[1], sys.argv[1:])")


def _run_until(cmd: list[str], log: Path, marker: str, sig: int, delay_s: float) -> int:
    """Start ``cmd`` in its own process group, wait for ``marker`` in ``log``, signal the group, wait."""
    proc = subprocess.Popen([sys.executable, "-c", _FROM_A_TERMINAL, *cmd], cwd=ROOT, start_new_session=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        while not (log.is_file() and marker in log.read_text()):
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "the step never started"
            time.sleep(0.02)
        time.sleep(delay_s)
        os.killpg(proc.pid, sig)
        proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    return proc.returncode


def test_a_ctrl_c_wrapped_by_a_module_import_interrupts_the_step(base, tmp_path, monkeypatch):
    # a Ctrl-C during Open3D's first import surfaces as "ImportError: initialization failed" caused by the
    # KeyboardInterrupt (pybind11 wraps it); the step is interrupted, not failed
    import app.batch.runner as runner

    def ctrl_c_in_an_import(*_args, **_kwargs):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise ImportError("initialization failed") from exc

    monkeypatch.setattr(runner, "run_step", ctrl_c_in_an_import)
    root = copy_session(base.raw, tmp_path / "s")
    result = process_one(str(root), ("geometry",), BatchOptions(preset="draft", calibration=str(base.cal)))
    assert result.status == "interrupted", result
    assert [(s.name, s.status) for s in result.steps] == [("geometry", "interrupted")]
    log = (root / LOG_FILE).read_text()
    assert "batch: interrupted" in log and "FAILED" not in log


def test_ctrl_c_and_a_killed_worker_leave_sessions_consistent(base, done, tmp_path):
    root = copy_session(base.raw, tmp_path / "s")
    other = copy_session(done[0], tmp_path / "other")
    cmd = [sys.executable, "-m", "app.cli", "batch", str(root), "--preset", "draft", "--calibration", str(base.cal),
           "--quiet"]
    # Ctrl-C (SIGINT to the whole process group, as a terminal sends it) while the mesh is being computed
    code = _run_until(cmd, root / LOG_FILE, "geometry: started", signal.SIGINT, 0.3)
    assert code == 130
    manifest = _assert_consistent(root)
    assert "geometry" not in (manifest.get("batch") or {}).get("steps", {})
    assert "batch: interrupted" in (root / LOG_FILE).read_text()
    # kill -9 of the worker alone while it renders (out of memory, a crash in a native library), with
    # another session waiting for the same worker: the pool breaks, each session runs again in a pool of
    # its own, and both complete
    cmd[4:5] = [str(root), str(other)]
    proc = subprocess.Popen(cmd + ["--workers", "1"], cwd=ROOT, start_new_session=True, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        while not ((root / LOG_FILE).is_file() and "render: started" in (root / LOG_FILE).read_text()):
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.02)
        time.sleep(0.1)
        worker = int(re.findall(r"pid (\d+)", (root / LOG_FILE).read_text())[-1])
        os.kill(worker, signal.SIGKILL)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 0, err.decode()[-2000:]
    log = (root / LOG_FILE).read_text()
    pids = [int(p) for p in re.findall(r"pid (\d+)", log)]
    assert len(pids) == 3 and pids[1] == worker and pids[2] != worker
    # the run after the kill redid exactly what was missing
    last = log[log.rindex("batch: steps"):]
    assert "geometry: skipped (up to date)" in last and "colour: skipped (up to date)" in last
    assert "render: started (never run)" in last and "report: done" in last
    for s in (root, other):
        assert set(_assert_consistent(s)["batch"]["steps"]) == set(ALL)


def test_dask_local_cluster_runs_the_same_tasks(done, tmp_path):
    distributed = pytest.importorskip("distributed")
    src, options, _ = done
    a = copy_session(src, tmp_path / "a")
    b = copy_session(src, tmp_path / "b")
    (b / "products/report.html").unlink()                 # b's report must be written again
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cl:
        summary = run_batch([a, b], "report", options=options, dask=cl.scheduler_address)
    assert summary.engine.startswith("dask ") and summary.workers == 1
    by = {Path(r.session).name: r for r in summary.results}
    assert by["a"].status == "skipped"
    assert by["b"].status == "ok" and _statuses(by["b"]) == {"report": "ran"}
    _assert_consistent(b)


@pytest.mark.parametrize("argv, message", [
    (["--steps", "materialz"], "unknown step 'materialz'"),
    (["--steps", "geometry,shading"], "unknown step 'shading'"),
    (["--workers", "0"], "--workers must be"),
    (["--dask", "bogus://scheduler:8786"], "cannot reach the Dask scheduler"),
])
def test_bad_batch_arguments_are_one_line_errors(done, argv, message, capsys):
    code = main(["batch", str(done[0]), *argv, "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and message in err
    assert err.count("\n") == 1


def test_a_session_given_twice_is_refused(done):
    with pytest.raises(UsageError, match="more than once"):
        run_batch([done[0], done[0]])
    assert parse_steps("report, geometry") == ("geometry", "report")
    parts = step_inputs(STEPS["report"], done[0], Session.read(done[0]), done[1])
    assert set(parts) == {"inputs", "params", "code"}


def test_a_pass_with_several_chart_frames_is_calibrated_by_its_first(tmp_path):
    """Swatch passes open with several chart frames (pNN/chart/00 ...): the colour step decodes the first
    one only, names it in the product and says so in the log; the others leave the step up to date."""
    from app.capture.runner import CapturePlan
    from mocks.world import World
    from tests.app.batch_session import _capture

    root = tmp_path / "s"
    _capture(World.hawk(2_000, width=240, height=160, chart_layout="classic24"), root,
             CapturePlan("scan", steps=4, passes=1, camera_angles_deg=(0.0,), chart_frames=3), True, 3)
    caps = Session.read(root)["captures"]
    assert sorted(c for c in caps if "/chart" in c) == ["p01/chart/00", "p01/chart/01", "p01/chart/02"]
    options = BatchOptions()
    result = process_one(str(root), ("colour",), options)
    assert [(s.name, s.status) for s in result.steps] == [("colour", "ran")], result
    product = Session.read(root)["products"]["colour"]["passes"]
    assert list(product) == ["p01"]
    report = json.loads((root / product["p01"]["chart"]["file"]).read_text())
    assert report["raw"] == caps["p01/chart/00"]["file"]
    assert "p01: 3 chart frames; the first (p01/chart/00) calibrates the pass" in (root / LOG_FILE).read_text()
    # the step's inputs are the first frame's checksum only
    inputs = step_inputs(STEPS["colour"], root, Session.read(root), options)["inputs"]
    assert inputs == {"p01/chart/00": caps["p01/chart/00"]["sha256"]}
