"""The station's camera and lamp calibration: fitted from calibration sessions, installed into scans.

Three calibrations place the station's instruments in one frame, the room
frame of the scanner calibration (turntable axis +Z, table top z = 0):

* the **scanner** (``kogei calibrate SPHERE_SESSION --sphere-radius MM``,
  :mod:`app.workflows.calibration`): the laser plane, from a sphere scan;
* the **camera** (``kogei calibrate --camera BOARD_SESSION --scanner
  SPHERE_SESSION``, :func:`calibrate_camera_session`): intrinsics and the
  camera's pose relative to the turntable axis from a ChArUco board photographed
  at many table angles (a ``camera-calibration`` capture), tied to the
  scanner's frame by the photos of the reference sphere the sphere session
  took while it was scanned (their centres against the sphere centre the
  scanner calibration found);
* the **lamps** (``kogei calibrate --lamp LAMP_SESSION --camera-calibration
  BOARD_SESSION``, :func:`calibrate_lamp_session`): each lamp's position (a
  point lamp) or direction (a distant lamp) from a mirror sphere's highlights
  (a ``lamp-calibration`` capture).

Each result is written into the session it was fitted from
(``camera_calibration.json``, ``lamp_calibration.json``) and referenced from
its manifest with its SHA-256; ``kogei process SCAN --camera-calibration
BOARD_SESSION --lamp-calibration LAMP_SESSION`` copies them into a scan
session the same way, so every session carries the exact calibrations its
posed frames were computed with.
"""

from __future__ import annotations

import hashlib
import json
import math
import stat
from collections.abc import Callable
from pathlib import Path
from typing import Any

from app.errors import UsageError
from app.session_paths import MAX_JSON_BYTES, confined_file, read_confined_bytes
from processing.common.files import JSONFileError, parse_json

__all__ = [
    "CAMERA_FILE",
    "LAMP_FILE",
    "calibrate_camera_session",
    "calibrate_lamp_session",
    "install_station_calibration",
    "load_station_source",
    "session_camera_calibration",
    "session_lamp_calibration",
    "frame_records",
    "decode_frame",
    "board_coverage",
    "parse_station_calibration",
]

CAMERA_FILE = "camera_calibration.json"
LAMP_FILE = "lamp_calibration.json"
_FILES = {"camera_calibration": CAMERA_FILE, "lamp_calibration": LAMP_FILE}
_FLAGS = {"camera_calibration": "--camera-calibration", "lamp_calibration": "--lamp-calibration"}
#: A decoded pixel at or above this (1.0 = the white level) counts as clipped.
CLIP_LEVEL = 0.98
#: A sphere photo whose outline misses the fitted sphere's by more than this (px RMS) is not used.
MAX_OUTLINE_RMS_PX = 0.5
#: Most lamps ``--lamps`` may ask for.
MAX_LAMPS = 16


# ---------------------------------------------------------------------------- frames of a session
def frame_records(root: Path, manifest: dict[str, Any], *, passes: set[int] | None = None
                  ) -> list[tuple[str, dict[str, Any]]]:
    """The session's RAW object frames (``kind == "frame"``, done), in pass and frame order.

    Raises :class:`UsageError` naming a frame whose table angle is missing.
    """
    out = []
    for cid, rec in (manifest.get("captures") or {}).items():
        if not isinstance(rec, dict) or rec.get("kind") != "frame" or rec.get("status") != "done":
            continue
        p = rec.get("pass")
        if not _is_count(p) or not _is_count(rec.get("index", 0)):
            raise UsageError(f"session {root}: frame {cid} has no valid pass and index (pass {p!r}, index "
                             f"{rec.get('index')!r}); session.json is damaged: restore it from a copy")
        if passes is not None and p not in passes:
            continue
        angle = rec.get("angle_deg")
        if isinstance(angle, bool) or not isinstance(angle, (int, float)) or not math.isfinite(angle):
            raise UsageError(f"session {root}: frame {cid} has no table angle (angle_deg {angle!r}); it cannot be "
                             "posed: take it again with kogei capture")
        out.append((cid, rec))
    out.sort(key=lambda item: (int(item[1].get("pass") or 0), int(item[1].get("index") or 0)))
    return out


def _is_count(value: Any) -> bool:
    """An integer >= 0 (not a bool)."""
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def decode_frame(root: Path, cid: str, rec: dict[str, Any], mode: str = "demosaic") -> Any:
    """Decode one recorded frame (confined to the session, checked against its SHA-256)."""
    from processing.camera.raw_decode import RawDecodeError, decode_raw
    from processing.common.files import sha256_file

    try:
        path = confined_file(root, rec.get("file"), f"captures.{cid}.file")
    except FileNotFoundError:
        raise UsageError(f"session {root}: {rec.get('file')} ({cid}) is missing; restore it from a copy of the "
                         "session, or take the frames again with kogei capture") from None
    if isinstance(rec.get("sha256"), str) and sha256_file(path) != rec["sha256"]:
        raise UsageError(f"session {root}: {rec['file']} ({cid}) does not match its checksum; take the frame "
                         "again (kogei capture --resume re-takes damaged frames)")
    try:
        return decode_raw(path, mode=mode)
    except RawDecodeError as exc:
        raise UsageError(f"session {root}: {cid}: {exc}") from None


def _sensor_size(img: Any) -> tuple[int, int]:
    """``(width, height)`` of a decoded frame in its own pixels."""
    h, w = img.rgb.shape[:2]
    return int(w), int(h)


# ---------------------------------------------------------------------------- camera
def _board_views(root: Path, manifest: dict[str, Any], mode: str, note: Callable[[str], None]
                 ) -> tuple[list[Any], list[str], tuple[int, int], dict[str, Any]]:
    """Detect the board in every frame of a camera-calibration session; rejected frames are listed, not fatal."""
    from processing.camera.charuco import BoardDefinition, CharucoError, detect_board
    from processing.geometry.camera_calibration import BoardView

    plan = manifest.get("plan") or {}
    if plan.get("kind") != "camera-calibration":
        raise UsageError(f"session {root} is a {plan.get('kind')!r} capture, not a camera-calibration one; capture "
                         "the board with 'kogei capture --plan camera-calibration'")
    try:
        defn = BoardDefinition.from_dict(plan.get("board"))
    except CharucoError as exc:
        raise UsageError(f"session {root}: plan.board: {exc}") from None
    views, rejected, size = [], [], None
    for cid, rec in frame_records(root, manifest):
        img = decode_frame(root, cid, rec, mode)
        if size is None:
            size = _sensor_size(img)
        elif _sensor_size(img) != size:
            raise UsageError(f"session {root}: {cid} is {_sensor_size(img)} px, the first frame {size}; calibrate "
                             "from frames of one size")
        try:
            det = detect_board(img.rgb, defn, name=cid)
        except CharucoError as exc:
            rejected.append(str(exc))
            note(f"rejected: {exc}")
            continue
        views.append(BoardView(cid, float(rec["angle_deg"]), f"pass {rec.get('pass')}", det.corners_px, det.ids))
    if size is None:
        raise UsageError(f"session {root} has no RAW frames; capture the board with "
                         "'kogei capture --plan camera-calibration'")
    return views, rejected, size, defn.to_dict()


def _sphere_frames(sphere_root: Path, manifest: dict[str, Any]) -> list[tuple[str, dict[str, Any]]]:
    """The sphere session's RAW frames of the calibrated pass; a one-line error when there are none."""
    ref = manifest.get("calibration")
    source = ref.get("source") if isinstance(ref, dict) else None
    p = source.get("pass") if isinstance(source, dict) else None     # session.json is untrusted
    pass_no = p if isinstance(p, int) and not isinstance(p, bool) and p >= 1 else 1
    frames = frame_records(sphere_root, manifest, passes={pass_no})
    if not frames:
        raise UsageError(f"--scanner {sphere_root}: the sphere session has no RAW frames of the sphere; capture it "
                         "with photos (kogei capture --plan sphere-calibration --camera gphoto2 --camera-angles "
                         "0,30,...,330), then calibrate again")
    return frames


def _sphere_observations(sphere_root: Path, calib: Any, scanner: Any, mode: str, note: Callable[[str], None]
                         ) -> list[Any]:
    """The reference sphere's centre in the camera frame, from the sphere session's photos."""
    from app.session import Session, SessionError
    from processing.geometry.camera_calibration import CameraCalibrationError, SphereObservation
    from processing.geometry.sphere_image import SphereImageError, fit_sphere_centre, sphere_silhouette

    try:
        manifest = Session.read(sphere_root)
    except SessionError as exc:
        raise UsageError(str(exc)) from None
    frames = _sphere_frames(sphere_root, manifest)
    out = []
    for cid, rec in frames:
        img = decode_frame(sphere_root, cid, rec, mode)
        try:
            k, dist = calib.for_image_size(*_sensor_size(img))
        except CameraCalibrationError as exc:
            raise UsageError(f"--scanner {sphere_root}: {cid}: {exc}") from None
        try:
            edge = sphere_silhouette(img.rgb, name=cid, clip_level=CLIP_LEVEL)
            centre, cov, rms_px = fit_sphere_centre(edge, k, dist, scanner.sphere_radius_mm)
        except SphereImageError as exc:
            note(f"sphere photo left out: {exc}")
            continue
        if rms_px > MAX_OUTLINE_RMS_PX:
            note(f"sphere photo left out: {cid}: its outline is not a sphere of radius "
                 f"{scanner.sphere_radius_mm:g} mm (fit rms {rms_px:.2f} px > {MAX_OUTLINE_RMS_PX:g} px)")
            continue
        out.append(SphereObservation(float(rec["angle_deg"]), centre, cov))
    return out


def calibrate_camera_session(board_session: str | Path, scanner_session: str | Path, *,
                             focal_mm: float | None = None, sensor_mm: float | None = None,
                             max_rms_px: float = 1.0, decode: str = "demosaic",
                             message: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Calibrate the camera from a board session, tie it to the scanner's frame, store it in the board session.

    Parameters
    ----------
    board_session
        A ``camera-calibration`` capture (the ChArUco board at many table angles).
    scanner_session
        The sphere session ``kogei calibrate`` calibrated the scanner from, with
        RAW frames of the sphere (its scanner calibration gives the sphere's centre).
    focal_mm, sensor_mm
        Manual intrinsics to start from (the lens's focal length and the sensor's
        width, mm), both or neither.
    max_rms_px
        Largest accepted reprojection RMS (px).
    decode
        ``demosaic`` (full resolution) or ``bin2x2``.
    message
        Called with progress, rejected frames and warnings.

    Returns
    -------
    dict
        The manifest's reference to the stored calibration (path, sha256, figures).
    """
    from app.session import Session, SessionError
    from app.workflows.calibration import session_calibration
    from processing.camera.charuco import board_corners_mm
    from processing.geometry.camera_calibration import MIN_VIEWS, CameraCalibrationError, calibrate_camera, link_to_room

    note = message or (lambda text: None)
    _manual_focal(focal_mm, sensor_mm, 1)          # argument errors before any frame is read
    if not (isinstance(max_rms_px, (int, float)) and math.isfinite(max_rms_px) and max_rms_px > 0):
        raise UsageError(f"--max-rms must be a positive number of pixels, got {max_rms_px!r}")
    root, sphere_root = Path(board_session), Path(scanner_session)
    try:
        manifest = Session.read(root)
        sphere_manifest = Session.read(sphere_root)
    except SessionError as exc:
        raise UsageError(str(exc)) from None
    scanner = session_calibration(sphere_root, sphere_manifest)
    _sphere_frames(sphere_root, sphere_manifest)     # said at once, not after the board is detected
    views, rejected, size, board = _board_views(root, manifest, decode, note)
    if len(views) < MIN_VIEWS:
        raise UsageError(f"session {root}: {len(rejected)} of {len(rejected) + len(views)} frames rejected (first: "
                         f"{rejected[0] if rejected else 'none'}), {len(views)} usable; at least "
                         f"{MIN_VIEWS} frames must show the board {board.get('squares_x')} x "
                         f"{board.get('squares_y')} squares ({board.get('dictionary')}): check the plan's board and "
                         "the lighting, then capture again")
    focal = _manual_focal(focal_mm, sensor_mm, size[0])
    from processing.camera.charuco import BoardDefinition

    try:
        calib = calibrate_camera(views, size, board_corners_mm(BoardDefinition.from_dict(board)), board=board,
                                 initial_focal_px=focal, max_rms_px=max_rms_px)
        observations = _sphere_observations(sphere_root, calib, scanner, decode, note)
        calib, link = link_to_room(calib, observations, scanner.sphere_center_mm)
    except CameraCalibrationError as exc:
        raise UsageError(f"session {root}: camera calibration: {exc}") from None
    data = calib.to_dict()
    data["source"] = {"board_session": str(root.resolve()), "scanner_session": str(sphere_root.resolve()),
                      "frames_used": len(views), "frames_rejected": rejected,
                      "sphere_photos": len(observations), "link": _jsonable(link),
                      "coverage": board_coverage([v.corners_px for v in views], size)}
    with Session.open(root) as s:
        return install_station_calibration(s, "camera_calibration", data)


def board_coverage(corners_px: list[Any], image_size: tuple[int, int], cells: tuple[int, int] = (12, 8)
                   ) -> dict[str, Any]:
    """How much of the image the board's corners covered over all frames used (a 12 x 8 grid of cells).

    Returns ``{"cells": [cols, rows], "counts": rows x cols corner counts, "fraction": share of cells
    with at least one corner}``: a calibration from corners in one corner of the image extrapolates
    the distortion elsewhere.

    Examples
    --------
    >>> import numpy as np
    >>> board_coverage([np.array([[10.0, 10.0], [950.0, 630.0]])], (960, 640))["fraction"]
    0.020833333333333332
    """
    import numpy as np

    cols, rows = cells
    counts = np.zeros((rows, cols), dtype=np.int64)
    for c in corners_px:
        c = np.asarray(c, dtype=np.float64).reshape(-1, 2)
        i = np.clip((c[:, 1] / image_size[1] * rows).astype(int), 0, rows - 1)
        j = np.clip((c[:, 0] / image_size[0] * cols).astype(int), 0, cols - 1)
        np.add.at(counts, (i, j), 1)
    return {"cells": [cols, rows], "counts": counts.tolist(), "fraction": float(np.mean(counts > 0))}


def _manual_focal(focal_mm: float | None, sensor_mm: float | None, width_px: int) -> float | None:
    """``focal_mm / sensor_mm * width`` (px) from the manual intrinsics, checked."""
    if focal_mm is None and sensor_mm is None:
        return None
    if focal_mm is None or sensor_mm is None:
        raise UsageError("--focal-mm and --sensor-mm go together (the lens's focal length and the sensor's width)")
    for name, v in (("--focal-mm", focal_mm), ("--sensor-mm", sensor_mm)):
        if not (math.isfinite(v) and 0 < v < 1000):
            raise UsageError(f"{name} must be a length in (0, 1000) mm, got {v!r}")
    return float(focal_mm) / float(sensor_mm) * width_px


def _jsonable(obj: Any) -> Any:
    """A dataclass / array / number as JSON data."""
    import dataclasses

    import numpy as np

    if dataclasses.is_dataclass(obj):
        return {f.name: _jsonable(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


# ---------------------------------------------------------------------------- lamps
def calibrate_lamp_session(lamp_session: str | Path, camera_source: str | Path, *,
                           sphere_radius_mm: float | None = None, model: str = "auto", n_lamps: int | None = None,
                           spectrum: str | None = None, decode: str = "demosaic",
                           message: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Locate the lamps from a mirror-sphere session and store the result in it.

    Parameters
    ----------
    lamp_session
        A ``lamp-calibration`` capture (the mirror sphere at many table angles).
    camera_source
        A camera-calibrated board session or its ``camera_calibration.json``.
    sphere_radius_mm
        The mirror sphere's radius (mm); default the plan's ``sphere_radius_mm``.
    model
        ``auto``, ``point`` or ``distant``.
    n_lamps
        Number of lamps (default: the most highlights seen in one frame).
    spectrum
        The lamps' spectrum (a name such as ``D65`` or ``A``, or a CCT in K).
    decode, message
        As :func:`calibrate_camera_session`.

    Returns
    -------
    dict
        The manifest's reference to the stored lamp calibration.
    """
    from app.session import Session, SessionError
    from processing.geometry.camera_calibration import CameraCalibrationError
    from processing.geometry.lamp_calibration import LampCalibrationError, calibrate_lamps

    note = message or (lambda text: None)
    root = Path(lamp_session)
    if model not in ("auto", "point", "distant"):
        raise UsageError(f"--lamp-model must be auto, point or distant, got {model!r}")
    if n_lamps is not None and not (isinstance(n_lamps, int) and not isinstance(n_lamps, bool)
                                    and 1 <= n_lamps <= MAX_LAMPS):
        raise UsageError(f"--lamps must be a number of lamps in 1..{MAX_LAMPS}, got {n_lamps!r}")
    try:
        manifest = Session.read(root)
    except SessionError as exc:
        raise UsageError(str(exc)) from None
    plan = manifest.get("plan") or {}
    if plan.get("kind") != "lamp-calibration":
        raise UsageError(f"session {root} is a {plan.get('kind')!r} capture, not a lamp-calibration one; capture the "
                         "mirror sphere with 'kogei capture --plan lamp-calibration'")
    radius = sphere_radius_mm if sphere_radius_mm is not None else plan.get("sphere_radius_mm")
    if radius is None:
        raise UsageError(f"session {root}: give the mirror sphere's radius with --sphere-radius MM (the plan does not "
                         "record it)")
    if isinstance(radius, bool) or not isinstance(radius, (int, float)) or not (math.isfinite(radius) and radius > 0):
        raise UsageError(f"--sphere-radius must be the mirror sphere's radius in mm (> 0), got {radius!r}")
    spec = _lamp_spectrum(spectrum)
    calib = parse_station_calibration("camera_calibration", load_station_source(camera_source, "camera_calibration"),
                                      f"--camera-calibration {camera_source}")
    if calib.room_to_camera is None:
        raise UsageError(f"--camera-calibration {camera_source}: the camera is not tied to the scanner's frame; "
                         "calibrate it with --scanner SPHERE_SESSION")
    views, size = _mirror_views(root, manifest, decode, note)
    try:
        k, dist = calib.for_image_size(*size)
        lamps = calibrate_lamps(views, k, dist, calib.room_to_camera, float(radius), model=model, n_lamps=n_lamps,
                                clip_level=CLIP_LEVEL)
    except (CameraCalibrationError, LampCalibrationError) as exc:
        raise UsageError(f"session {root}: lamp calibration: {exc}") from None
    for lamp in lamps.lamps:
        lamp.spectrum = spec
        note(f"{lamp.name}: {_describe_lamp(lamp)}")
    data = lamps.to_dict()
    data["source"] = {"lamp_session": str(root.resolve()), "camera_calibration": str(Path(camera_source).resolve())}
    with Session.open(root) as s:
        return install_station_calibration(s, "lamp_calibration", data)


def _mirror_views(root: Path, manifest: dict[str, Any], decode: str, note: Callable[[str], None]
                  ) -> tuple[list[tuple[str, float, Any]], tuple[int, int]]:
    """The lamp session's frames whose mirror sphere is whole in view; the others are listed and left out."""
    from processing.geometry.sphere_image import SphereImageError, sphere_silhouette

    views, size = [], None
    for cid, rec in frame_records(root, manifest):
        img = decode_frame(root, cid, rec, decode)
        size = _sensor_size(img)
        try:
            sphere_silhouette(img.rgb, name=cid)
        except SphereImageError as exc:
            note(f"left out: {exc}")
            continue
        views.append((cid, float(rec["angle_deg"]), img.rgb))
    if size is None:
        raise UsageError(f"session {root} has no RAW frames of the mirror sphere; capture it with "
                         "'kogei capture --plan lamp-calibration'")
    return views, size


def _lamp_spectrum(spectrum: str | None) -> str | float | None:
    """A lamp spectrum name the spectral tables know, or a CCT (K), checked."""
    if spectrum is None:
        return None
    from processing.spectral.spectra import SpectralGrid, light_spectrum

    value: str | float = spectrum
    try:
        value = float(spectrum)
    except ValueError:
        pass
    try:
        light_spectrum(value, SpectralGrid(400.0, 700.0, 10.0))
    except (ValueError, KeyError) as exc:
        raise UsageError(f"--lamp-spectrum {spectrum!r}: {exc}") from None
    return value


def _describe_lamp(lamp: Any) -> str:
    """One line: where a lamp is and how well that is known."""
    import numpy as np

    sd = np.sqrt(np.maximum(np.diag(np.asarray(lamp.covariance, dtype=float)), 0.0))
    if lamp.kind == "point":
        p = lamp.position_mm
        return (f"point lamp at ({p[0]:.1f}, {p[1]:.1f}, {p[2]:.1f}) mm +- ({sd[0]:.1f}, {sd[1]:.1f}, {sd[2]:.1f}) mm, "
                f"ray rms {lamp.rms_deg:.3f} deg")
    d = lamp.direction
    return (f"distant lamp toward ({d[0]:.4f}, {d[1]:.4f}, {d[2]:.4f}) +- {math.degrees(float(sd.max())):.3f} deg, "
            f"ray rms {lamp.rms_deg:.3f} deg")


# ---------------------------------------------------------------------------- installing and reading back
def install_station_calibration(session: Any, key: str, data: dict[str, Any]) -> dict[str, Any]:
    """Write ``data`` as the session's camera or lamp calibration file and reference it from the manifest."""
    if key == "camera_calibration" and data.get("room_to_camera") is None:
        raise UsageError(f"--camera-calibration {data.get('installed_from') or ''}: the camera is not tied to the "
                         "scanner's frame (room_to_camera is null); calibrate it with 'kogei calibrate --camera "
                         "BOARD_SESSION --scanner SPHERE_SESSION'")
    blob = (json.dumps(data, indent=1, allow_nan=False) + "\n").encode()
    info = session.write_file(_FILES[key], blob)
    ref: dict[str, Any] = {"path": info.path, "sha256": info.sha256, "source": data.get("source")}
    if key == "camera_calibration":
        ref["rms_px"] = data.get("rms_px")
        ref["image_size"] = data.get("image_size")
    else:
        ref["lamps"] = len(data.get("lamps") or [])
    session.update(key, ref)
    session.event(key, info.path)
    return ref


def load_station_source(source: str | Path, key: str) -> dict[str, Any]:
    """A camera or lamp calibration's JSON form from a calibrated session folder or the JSON file itself."""
    flag, name = _FLAGS[key], _FILES[key]
    p = Path(source)
    if p.is_dir():
        return _calibrated_session_file(p, key)
    try:
        st = p.stat()
        if not stat.S_ISREG(st.st_mode) or st.st_size > MAX_JSON_BYTES:
            raise UsageError(f"{flag} {source}: not a regular file of at most {MAX_JSON_BYTES} bytes; give "
                             f"a {name} or a calibrated session folder")
        blob = p.read_bytes()
    except FileNotFoundError:
        raise UsageError(f"{flag} {source}: {name} not found; give the session calibrated with 'kogei calibrate' "
                         f"or its {name}") from None
    except OSError as exc:
        raise UsageError(f"{flag} {source}: unreadable ({exc.strerror or exc})") from None
    try:
        data = parse_json(blob, f"{flag} {source}", f"give a {name} or a calibrated session folder")
    except JSONFileError as exc:
        raise UsageError(str(exc)) from None
    if not isinstance(data, dict):
        raise UsageError(f"{flag} {source}: not a {name}")
    return data


def _calibrated_session_file(root: Path, key: str) -> dict[str, Any]:
    """The calibration a session folder references from its manifest, checked against its SHA-256."""
    from app.session import Session, SessionError

    flag, name = _FLAGS[key], _FILES[key]
    try:
        manifest = Session.read(root)
    except SessionError as exc:
        raise UsageError(f"{flag} {root}: not a kogei session ({exc}); give a calibrated session folder or its "
                         f"{name}") from None
    data = _session_file(root, manifest, key)
    if data is None:
        what = "--camera BOARD_SESSION --scanner SPHERE_SESSION" if key == "camera_calibration" else \
            "--lamp LAMP_SESSION --camera-calibration BOARD_SESSION"
        raise UsageError(f"{flag} {root}: the session has no {name} (not found); calibrate it with "
                         f"'kogei calibrate {what}' or give a {name}")
    if not isinstance(data, dict):
        raise UsageError(f"{flag} {root}: {name} is not a {name}")
    return data


def _session_file(root: Path, manifest: dict[str, Any], key: str) -> dict[str, Any] | None:
    """The JSON of the session's referenced camera or lamp calibration (checksum checked), or None."""
    ref = manifest.get(key)
    if not ref:
        return None
    if not isinstance(ref, dict) or not isinstance(ref.get("sha256"), str):
        raise UsageError(f"session {root}: session.json {key} is not a record with 'path' and 'sha256'; install "
                         f"the calibration again with {_FLAGS[key]}")
    try:
        blob = read_confined_bytes(root, ref.get("path"), f"session.json {key}.path", MAX_JSON_BYTES)
    except OSError:
        raise UsageError(f"session {root}: its {key.replace('_', ' ')} {ref.get('path')} is missing; install it "
                         f"again with {_FLAGS[key]}") from None
    if hashlib.sha256(blob).hexdigest() != ref["sha256"]:
        raise UsageError(f"session {root}: {ref['path']} does not match the checksum in the manifest (edited by "
                         f"hand?); install it again with {_FLAGS[key]}")
    try:
        return parse_json(blob, f"session {root}: {ref['path']}", f"install it again with {_FLAGS[key]}")
    except JSONFileError as exc:
        raise UsageError(str(exc)) from None


def parse_station_calibration(key: str, data: dict[str, Any], where: str) -> Any:
    """A camera or lamp calibration's JSON form as its object, checked; errors are one line starting ``where``."""
    if key == "camera_calibration":
        from processing.geometry.camera_calibration import CameraCalibration as parsed
        from processing.geometry.camera_calibration import CameraCalibrationError as error
    else:
        from processing.geometry.lamp_calibration import LampCalibration as parsed
        from processing.geometry.lamp_calibration import LampCalibrationError as error
    try:
        return parsed.from_dict(data)
    except error as exc:
        raise UsageError(f"{where}: {exc}") from None


def session_camera_calibration(root: str | Path, manifest: dict[str, Any]) -> Any:
    """The session's camera calibration (:class:`~processing.geometry.camera_calibration.CameraCalibration`) or None."""
    data = _session_file(Path(root), manifest, "camera_calibration")
    return None if data is None else parse_station_calibration("camera_calibration", data,
                                                               f"session {root}: {CAMERA_FILE}")


def session_lamp_calibration(root: str | Path, manifest: dict[str, Any]) -> Any:
    """The session's lamp calibration (:class:`~processing.geometry.lamp_calibration.LampCalibration`) or None."""
    data = _session_file(Path(root), manifest, "lamp_calibration")
    return None if data is None else parse_station_calibration("lamp_calibration", data, f"session {root}: {LAMP_FILE}")
