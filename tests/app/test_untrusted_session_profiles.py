"""A pass's ``passes/pNN/profiles.npz`` is untrusted: a sender can rewrite it and its checksum in session.json.

Every way it can fail to be a pass's profiles (not a zip, pickled objects, a missing array, a header
claiming hundreds of gigabytes, a wrong dtype, shapes that do not match) is one line naming the file and
saying what to do, from :func:`app.capture.runner.load_pass_profiles` and from the commands that read it
(``kogei calibrate``, ``kogei process``, ``kogei batch --steps geometry``)."""

from __future__ import annotations

import hashlib
import io
import json
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.batch.runner import process_one
from app.batch.steps import BatchOptions
from app.capture.runner import ProfilesFileError, load_pass_profiles
from app.cli import main
from processing.geometry.calibration import ScannerCalibration, ideal_sensor_to_room

FILE = "passes/p01/profiles.npz"
REMEDY = "restore the file from a copy of the session"


def _arrays(**change: Any) -> dict[str, Any]:
    arrays = {"angles_deg": np.linspace(0.0, 270.0, 4), "x_mm": np.zeros((4, 5), np.float32),
              "z_mm": np.full((4, 5), 50.0, np.float32)}
    arrays.update(change)
    return {k: v for k, v in arrays.items() if v is not None}


def _npz(**change: Any) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **_arrays(**change))
    return buf.getvalue()


def _huge_x() -> bytes:
    """A good archive whose x_mm header claims (100000000000, 5) float32 in a member of 192 bytes."""
    with zipfile.ZipFile(io.BytesIO(_npz())) as zf:
        members = {n: zf.read(n) for n in zf.namelist()}
    head = io.BytesIO()
    np.lib.format.write_array_header_1_0(head, {"descr": "<f4", "fortran_order": False,
                                                "shape": (100_000_000_000, 5)})
    members["x_mm.npy"] = head.getvalue() + bytes(64)
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    return out.getvalue()


#: Hostile contents of profiles.npz -> words the message must hold.
HOSTILE: dict[str, tuple[Callable[[], bytes], tuple[str, ...]]] = {
    "random-bytes": (lambda: bytes(range(256)) * 12, ("not a zip archive",)),
    "no-x_mm": (lambda: _npz(x_mm=None), ("missing x_mm",)),
    "pickled": (lambda: _npz(z_mm=np.array([{"a": 1}], dtype=object)), ("'z_mm'", "Python objects")),
    "huge-header": (_huge_x, ("'x_mm'", "(100000000000, 5)", "member holds")),
    "int-x_mm": (lambda: _npz(x_mm=np.zeros((4, 5), np.int32)), ("'x_mm'", "floating-point")),
    "shapes-differ": (lambda: _npz(z_mm=np.zeros((4, 3), np.float32)), ("do not match", "z_mm (4, 3)")),
    "few-angles": (lambda: _npz(angles_deg=np.zeros(2)), ("do not match", "angles_deg (2,)")),
}


def _session(root: Path, data: bytes, *, kind: str = "scan") -> Path:
    """A hand-written session holding an ideal calibration and pass 1's profiles ``data`` (checksummed)."""
    cal = ScannerCalibration(ideal_sensor_to_room(), 10.0, np.array([50.0, 0, 10]), 0.05, 0.2, 40, 4000, 9000,
                             0.04, 10.001, np.arange(2), np.array([0.05, 0.06]))
    blob = json.dumps(cal.to_dict()).encode()
    (root / "passes" / "p01").mkdir(parents=True)
    (root / "calibration.json").write_bytes(blob)
    (root / FILE).write_bytes(data)
    manifest = {"schema": "kogei.session", "version": 1, "created_utc": "2026-01-01T00:00:00.000000Z",
                "updated_utc": "2026-01-01T00:00:00.000000Z", "status": "complete", "object": {"name": "hostile"},
                "devices": {}, "settings": {}, "plan": {"kind": kind, "steps": 4, "passes": 1},
                "calibration": {"path": "calibration.json", "sha256": hashlib.sha256(blob).hexdigest()},
                "passes": {"1": {"status": "complete"}}, "state": {}, "history": [],
                "captures": {"p01/profiles": {"kind": "profiles", "status": "done", "pass": 1, "steps": 4,
                                              "points": 5, "file": FILE, "sha256": hashlib.sha256(data).hexdigest(),
                                              "bytes": len(data)}}}
    (root / "session.json").write_text(json.dumps(manifest))
    return root


def _names_the_file(msg: str, root: Path, *needles: str) -> None:
    assert "\n" not in msg.strip() and "Traceback" not in msg, msg
    assert str(root / FILE) in msg and REMEDY in msg and "kogei capture --resume" in msg, msg
    assert "allow_pickle" not in msg and "is not a file in the archive" not in msg, msg
    for needle in needles:
        assert needle in msg, msg


@pytest.mark.parametrize("name", sorted(HOSTILE))
def test_load_pass_profiles_names_the_file_and_what_to_do(tmp_path, name):
    make, needles = HOSTILE[name]
    root = _session(tmp_path / "s", make())
    with pytest.raises(ProfilesFileError) as err:
        load_pass_profiles(root, 1)
    _names_the_file(str(err.value), root, *needles)


@pytest.mark.parametrize("name", ["random-bytes", "pickled", "huge-header", "shapes-differ"])
def test_calibrate_of_hostile_profiles_is_one_line(tmp_path, capsys, name):
    make, needles = HOSTILE[name]
    root = _session(tmp_path / "s", make(), kind="sphere-calibration")
    assert main(["calibrate", str(root), "--sphere-radius", "25"]) == 2
    _names_the_file(capsys.readouterr().err, root, *needles)


@pytest.mark.parametrize("name", ["random-bytes", "no-x_mm", "huge-header"])
def test_batch_geometry_step_names_the_file(tmp_path, name):
    make, needles = HOSTILE[name]
    root = _session(tmp_path / "s", make())
    r = process_one(str(root), ("geometry",), BatchOptions(preset="draft", render_size=(32, 24)))
    assert r.status == "failed", r
    _names_the_file(r.reason, root, *needles)


def test_process_leaves_out_the_pass_and_names_the_file(tmp_path, capsys):
    make, needles = HOSTILE["pickled"]
    root = _session(tmp_path / "s", make())
    assert main(["process", str(root), "--preset", "draft", "--no-project"]) == 2
    note, error = capsys.readouterr().err.strip().splitlines()
    _names_the_file(note, root, *needles)
    assert note.startswith("pass 1: ") and error.startswith("kogei process: error: ") and str(root / FILE) in error
