"""The scanner calibration of a session: fitted from a sphere scan, installed, read back.

The calibration (:func:`processing.geometry.calibration.calibrate_sphere`: the
laser plane's pose relative to the table axis) is written into the session as
``calibration.json`` and referenced from its manifest (path, SHA-256,
residuals).  Other sessions install it from the calibrated session (the file
is copied into them and referenced the same way), so each session carries the
exact calibration its geometry was computed with.  ``kogei calibrate``, the
window's processing panel, the batch's geometry step and the demo call these
functions.
"""

from __future__ import annotations

import hashlib
import json
import math
import stat
from pathlib import Path
from typing import Any

from app.errors import UsageError
from app.session_paths import MAX_JSON_BYTES, UnsafeSessionPath, read_confined_bytes
from processing.common.files import JSONFileError, parse_json

__all__ = ["calibrate_session", "install_calibration", "session_calibration", "load_calibration_source",
           "calibration_source_bytes", "CALIBRATION_FILE"]

CALIBRATION_FILE = "calibration.json"


def calibrate_session(session_dir: str | Path, sphere_radius_mm: float, *, sphere_height_mm: float | None = None,
                      pass_no: int = 1) -> dict[str, Any]:
    """Calibrate from pass ``pass_no`` of a sphere-scan session and store the result in it.

    Returns
    -------
    dict
        The manifest's calibration reference (path, sha256, residuals).
    """
    from app.capture.runner import load_pass_profiles
    from app.session import Session
    from processing.geometry.calibration import CalibrationError, calibrate_sphere

    if not (math.isfinite(sphere_radius_mm) and sphere_radius_mm > 0):
        raise UsageError(f"--sphere-radius must be a positive number of millimetres, got {sphere_radius_mm!r}")
    root = Path(session_dir)
    _check_profiles_file(root, pass_no)
    profiles = load_pass_profiles(root, pass_no)
    try:
        cal = calibrate_sphere(profiles["x_mm"], profiles["z_mm"], profiles["angles_deg"], sphere_radius_mm,
                               sphere_height_mm=sphere_height_mm)
    except CalibrationError as exc:
        raise UsageError(f"session {root}, pass {pass_no}: {exc}") from None
    data = cal.to_dict()
    data["source"] = {"session": str(root.resolve()), "pass": pass_no}
    with Session.open(root) as s:
        return install_calibration(s, data)


def _check_profiles_file(root: Path, pass_no: int) -> None:
    """Refuse a pass's profiles record naming a file outside the session, a symlink, a FIFO or a device."""
    from app.session import Session, SessionError
    from app.session_paths import confined_file

    try:
        captures = Session.read(root).get("captures")
    except SessionError as exc:
        raise UsageError(str(exc)) from None
    cid = f"p{int(pass_no):02d}/profiles"
    rec = captures.get(cid) if isinstance(captures, dict) else None
    if isinstance(rec, dict):
        try:
            confined_file(root, rec.get("file"), f"captures.{cid}.file")
        except FileNotFoundError:
            pass            # load_pass_profiles says which pass is missing and what to do


def install_calibration(session: Any, data: dict[str, Any]) -> dict[str, Any]:
    """Write ``data`` (a calibration's JSON form) as the session's ``calibration.json`` and reference it."""
    blob = (json.dumps(data, indent=1) + "\n").encode()
    info = session.write_file(CALIBRATION_FILE, blob)
    ref = {"path": info.path, "sha256": info.sha256, "rms_mm": data.get("rms_mm"), "max_mm": data.get("max_mm"),
           "sphere_radius_mm": data.get("sphere_radius_mm"), "source": data.get("source")}
    session.update("calibration", ref)
    session.event("calibration", f"{info.path} (rms {data.get('rms_mm', float('nan')):.4f} mm)")
    return ref


def session_calibration(session_dir: str | Path, manifest: dict[str, Any]) -> Any:
    """The session's referenced calibration, checked against its checksum."""
    from processing.geometry.calibration import CalibrationError, ScannerCalibration

    ref = manifest.get("calibration")
    if not ref:
        raise UsageError(f"session {session_dir} has no scanner calibration; scan the reference sphere, run "
                         "'kogei calibrate CAL_SESSION --sphere-radius MM', then "
                         f"'kogei process {session_dir} --calibration CAL_SESSION'")
    if not isinstance(ref, dict) or not isinstance(ref.get("sha256"), str):
        raise UsageError(f"session {session_dir}: session.json calibration is not a record with 'path' and "
                         "'sha256'; install the calibration again with --calibration")
    try:
        blob = read_confined_bytes(session_dir, ref.get("path"), "session.json calibration.path", MAX_JSON_BYTES)
    except OSError:
        raise UsageError(f"session {session_dir}: its calibration {ref['path']} is missing; "
                         "run kogei process with --calibration again") from None
    if hashlib.sha256(blob).hexdigest() != ref["sha256"]:
        raise UsageError(f"session {session_dir}: {ref['path']} does not match the checksum in the manifest "
                         "(edited by hand?); install the calibration again with --calibration")
    try:
        data = parse_json(blob, f"session {session_dir}: {ref['path']}", "install the calibration again with "
                                                                         "--calibration")
    except JSONFileError as exc:
        raise UsageError(str(exc)) from None
    try:
        return ScannerCalibration.from_dict(data)
    except (CalibrationError, ValueError, KeyError) as exc:
        raise UsageError(f"session {session_dir}: {ref['path']}: {exc}") from None


def calibration_source_bytes(source: str | Path) -> tuple[Path, bytes]:
    """The file a ``--calibration`` source names and its bytes.

    A calibrated session folder: its ``calibration.json``, which must be a
    regular file inside it (not a symlink, FIFO or device; at most
    :data:`app.session_paths.MAX_JSON_BYTES`).  A file: the file itself
    (the user named it), which must be a regular file of bounded size.
    """
    p = Path(source)
    try:
        if p.is_dir():
            return p / CALIBRATION_FILE, read_confined_bytes(p, CALIBRATION_FILE, f"--calibration {source}",
                                                             MAX_JSON_BYTES)
        st = p.stat()
        if not stat.S_ISREG(st.st_mode) or st.st_size > MAX_JSON_BYTES:
            raise UsageError(f"--calibration {source}: not a regular file of at most {MAX_JSON_BYTES} bytes; give "
                             "a calibration.json or a calibrated session folder")
        return p, p.read_bytes()
    except FileNotFoundError:
        file = p / CALIBRATION_FILE if p.is_dir() else p
        raise UsageError(f"--calibration {source}: {file} not found; give a session calibrated with "
                         "'kogei calibrate' or its calibration.json") from None
    except UnsafeSessionPath:
        raise
    except OSError as exc:
        raise UsageError(f"--calibration {source}: unreadable ({exc.strerror or exc})") from None


def load_calibration_source(source: str | Path) -> dict[str, Any]:
    """A calibration's JSON form from a calibrated session folder or a calibration JSON file."""
    from processing.geometry.calibration import CalibrationError, ScannerCalibration

    file, blob = calibration_source_bytes(source)
    try:
        data = parse_json(blob, f"--calibration {source}: {file}", "give a session calibrated with 'kogei calibrate' "
                                                                   "or its calibration.json")
    except JSONFileError as exc:
        raise UsageError(str(exc)) from None
    try:
        ScannerCalibration.from_dict(data)
    except (CalibrationError, ValueError, KeyError) as exc:
        raise UsageError(f"--calibration {source}: {exc}") from None
    return data
