"""The station-calibration part of ``kogei demo``: camera and lamp calibrated on the simulated station.

Before the hawk is scanned, the demo does what a technician does once per
station set-up, through the same capture and calibration code as ``kogei
capture`` and ``kogei calibrate``:

1. a ``camera-calibration`` capture of a ChArUco board (flat on the table, then
   on two wedges), 12 table angles per placement, at the camera's full
   960 x 640 photosites;
2. a ``lamp-calibration`` capture of a chrome sphere at 12 table angles;
3. the camera calibration (tied to the turntable by the photos the reference
   sphere session took while the scanner was calibrated) and the lamp
   calibration, each compared with the simulation's truth.
"""

from __future__ import annotations

import math
import shutil
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["calibrate_station", "capture_station_sessions", "CAMERA_SIZE", "FRAME_BINNING", "MIRROR_RADIUS_MM"]

#: The simulated camera's full frame (photosites); the object frames are binned by :data:`FRAME_BINNING`.
CAMERA_SIZE = (960, 640)
FRAME_BINNING = 2
MIRROR_RADIUS_MM = 20.0
MIRROR_OFFSET_MM = 25.0


def _camera_only_session(world: Any, out: Path, name: str, plan: Any, seed: int, label: str) -> Path:
    """Capture a camera-only plan of ``world`` on a fresh simulated station into ``out / name``."""
    from app.capture.devices import build_devices
    from app.capture.runner import CaptureHooks, run_capture
    from app.session import Session
    from mocks.station import SimulatedStation

    root = out / name
    if root.exists():
        shutil.rmtree(root)
    with SimulatedStation(world, root=out / f"station-{name}", seed=seed) as st:
        config = {"turntable": {"port": str(st.turntable_path)},
                  "camera": {"kind": "gphoto2", "executable": str(st.gphoto2_path)}}
        session = Session.create(root, plan=plan.to_dict(), object_info={"name": label},
                                 settings={"unattended": True, "device_config": config})
        try:
            run_capture(session, plan, build_devices(config, session.root),
                        CaptureHooks(before_pass=lambda p, n: st.place(p)))
        finally:
            session.close()
    return root


def _camera_truth_errors(calib: Any, world: Any) -> dict[str, float]:
    """The calibrated camera against the simulation's: focal (%), principal point (px), pose (deg, mm)."""
    from processing.geometry.registration import pose_difference

    k_true = world.camera_intrinsics()
    cam_to_room = np.linalg.inv(calib.room_to_camera)
    rot, shift = pose_difference(cam_to_room, np.linalg.inv(world.room_to_camera()))
    return {"focal_pct": round(100.0 * (calib.K[0, 0] / k_true[0, 0] - 1.0), 4),
            "principal_point_px": round(float(np.hypot(*(calib.K[:2, 2] - k_true[:2, 2]))), 3),
            "rotation_deg": round(rot, 4), "translation_mm": round(shift, 4)}


def _lamp_truth_errors(lamps: Any, world: Any) -> list[dict[str, Any]]:
    """Each located lamp against the simulation's lamp (direction in deg or position in mm)."""
    truth = world.lamp_truth()
    out = []
    for lamp in lamps.lamps:
        if lamp.kind == "distant" and truth.get("kind") == "distant":
            d = np.asarray(truth["direction"], dtype=float)
            d /= np.linalg.norm(d)
            err = math.degrees(math.acos(float(np.clip(np.dot(d, lamp.direction), -1.0, 1.0))))
            out.append({"lamp": lamp.name, "kind": lamp.kind, "direction_error_deg": round(err, 4)})
        elif lamp.kind == "point" and truth.get("kind") == "point":
            err = float(np.linalg.norm(np.asarray(truth["position_mm"]) - lamp.position_mm))
            out.append({"lamp": lamp.name, "kind": lamp.kind, "position_error_mm": round(err, 3)})
        else:
            out.append({"lamp": lamp.name, "kind": lamp.kind, "truth_kind": truth.get("kind")})
    return out


def _station_worlds() -> tuple[Any, Any]:
    """The ChArUco board's and the chrome sphere's simulated worlds at the camera's full frame."""
    from mocks.board_world import BoardWorld
    from mocks.mirror_world import MirrorWorld

    w, h = CAMERA_SIZE
    return (BoardWorld.charuco(width=w, height=h),
            MirrorWorld.mirror_sphere(MIRROR_RADIUS_MM, MIRROR_OFFSET_MM, width=w, height=h))


def capture_station_sessions(out: Path, *, seed: int = 1,
                             kinds: tuple[str, ...] = ("camera", "lamp")) -> dict[str, Any]:
    """Capture the board and mirror-sphere sessions on the simulated station (no calibration yet).

    They need nothing from the scanner's calibration, so the demo captures the board's in a second
    process while the first captures the hawk, and the mirror sphere's in the first after the hawk.

    Parameters
    ----------
    out
        Folder for the sessions (``camera-calibration``, ``lamp-calibration``).
    seed
        The simulated station's seed.
    kinds
        Which to capture: ``"camera"`` (the board), ``"lamp"`` (the mirror sphere).

    Returns
    -------
    dict
        ``camera_session`` and/or ``lamp_session`` (paths as text) and ``capture_s`` (seconds).
    """
    from app.capture.runner import CapturePlan

    t0 = time.perf_counter()
    board_world, mirror_world = _station_worlds()
    result: dict[str, Any] = {}
    if "camera" in kinds:
        result["camera_session"] = str(_camera_only_session(
            board_world, out, "camera-calibration", CapturePlan("camera-calibration"), seed,
            "ChArUco board, 7 x 5 squares of 8 mm"))
    if "lamp" in kinds:
        result["lamp_session"] = str(_camera_only_session(
            mirror_world, out, "lamp-calibration", CapturePlan("lamp-calibration", sphere_radius_mm=MIRROR_RADIUS_MM),
            seed, f"chrome sphere, r = {MIRROR_RADIUS_MM:g} mm"))
    return {**result, "capture_s": time.perf_counter() - t0}


def calibrate_station(out: Path, sphere_session: Path, *, seed: int = 1,
                      sessions: dict[str, Any] | None = None) -> dict[str, Any]:
    """Capture the board and mirror-sphere sessions, calibrate camera and lamps, compare with the truth.

    Parameters
    ----------
    out
        Folder for the calibration sessions (``camera-calibration``, ``lamp-calibration``).
    sphere_session
        The scanner-calibrated reference sphere session with RAW frames of the sphere.
    seed
        The simulated station's seed.
    sessions
        The board and mirror-sphere sessions already captured (:func:`capture_station_sessions`'s
        answer); None: capture them here.

    Returns
    -------
    dict
        Session paths, figures, errors against the simulation's truth, seconds.
    """
    from app.session import Session
    from app.workflows.station_calibration import (
        calibrate_camera_session,
        calibrate_lamp_session,
        session_camera_calibration,
        session_lamp_calibration,
    )

    def say(text: str) -> None:
        print(f"station: {text}", file=sys.stderr)

    if sessions is None:
        sessions = capture_station_sessions(out, seed=seed)
    board, lamp = Path(sessions["camera_session"]), Path(sessions["lamp_session"])
    board_world, mirror_world = _station_worlds()
    capture_s = float(sessions["capture_s"])
    t1 = time.perf_counter()
    cam_ref = calibrate_camera_session(board, sphere_session, message=say)
    camera_s = time.perf_counter() - t1
    t2 = time.perf_counter()
    lamp_ref = calibrate_lamp_session(lamp, board, spectrum=board_world.light, message=say)
    lamp_s = time.perf_counter() - t2
    calib = session_camera_calibration(board, Session.read(board))
    lamps = session_lamp_calibration(lamp, Session.read(lamp))
    return {
        "camera_session": str(board), "lamp_session": str(lamp),
        "camera": {"rms_px": cam_ref["rms_px"], "frames_used": (cam_ref.get("source") or {}).get("frames_used"),
                   "frames_rejected": len((cam_ref.get("source") or {}).get("frames_rejected") or []),
                   "error_vs_truth": _camera_truth_errors(calib, board_world)},
        "lamps": {"count": lamp_ref["lamps"], "error_vs_truth": _lamp_truth_errors(lamps, mirror_world)},
        "seconds": {"capture": round(capture_s, 2), "camera_calibration": round(camera_s, 2),
                    "lamp_calibration": round(lamp_s, 2)},
    }
