"""Validation of a stored camera calibration (JSON form, untrusted input).

Examples
--------
>>> parse_calibration({"schema": "other"})
Traceback (most recent call last):
...
processing.geometry.camera_calibration.CameraCalibrationError: camera calibration: schema 'other' is not 'kogei.camera_calibration'; choose a camera calibration file
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from processing.geometry.camera_calibration import (
    CAMERA_CALIBRATION_SCHEMA,
    CAMERA_CALIBRATION_SCHEMA_VERSION,
    CameraCalibrationError,
)

__all__ = ["parse_calibration"]

_BOARD_KEYS = {"dictionary": str, "squares_x": int, "squares_y": int, "square_mm": float, "marker_mm": float}


def _fail(what: str) -> CameraCalibrationError:
    return CameraCalibrationError(f"camera calibration: {what}")


def _array(data: dict, key: str, shape: tuple[int, ...]) -> NDArray[np.float64]:
    """A finite float array of the given shape from ``data[key]``."""
    try:
        arr = np.asarray(data[key], dtype=np.float64)
    except (KeyError, TypeError, ValueError):
        raise _fail(f"{key} is missing or not numeric; re-run the calibration") from None
    if arr.shape != shape or not np.isfinite(arr).all():
        raise _fail(f"{key} must be a finite array of shape {shape}; re-run the calibration")
    return arr


def _rigid(data: dict, key: str) -> NDArray[np.float64]:
    """A 4x4 rigid transform from ``data[key]``."""
    m = _array(data, key, (4, 4))
    r = m[:3, :3]
    if not (np.allclose(r @ r.T, np.eye(3), atol=1e-6) and np.linalg.det(r) > 0
            and np.allclose(m[3], [0, 0, 0, 1], atol=1e-9) and np.abs(m[:3, 3]).max() < 1e7):
        raise _fail(f"{key} is not a rigid transform (rotation, translation < 1e7 mm); re-run the calibration")
    return m


def _figures(data: dict, key: str) -> dict[str, float]:
    """A mapping of names to finite, non-negative numbers."""
    d = data.get(key, {})
    if not isinstance(d, dict):
        raise _fail(f"{key} must be an object of names to numbers")
    out = {}
    for k, v in d.items():
        if not isinstance(k, str) or isinstance(v, bool) or not isinstance(v, (int, float)) \
                or not math.isfinite(v) or v < 0:
            raise _fail(f"{key}[{k!r}] = {v!r} must be a finite number >= 0")
        out[k] = float(v)
    return out


def _intrinsics(data: dict) -> tuple[tuple[int, int], NDArray[np.float64], NDArray[np.float64]]:
    """Image size, K and distortion, with their bounds."""
    size = data.get("image_size")
    if not (isinstance(size, list) and len(size) == 2 and all(isinstance(s, int) and not isinstance(s, bool)
                                                                and 0 < s <= 100000 for s in size)):
        raise _fail(f"image_size {size!r} must be [width, height] in pixels (1..100000)")
    k = _array(data, "K", (3, 3))
    w, h = size
    if not (0 < k[0, 0] < 1e6 and 0 < k[1, 1] < 1e6 and k[0, 1] == 0 and k[1, 0] == 0
            and np.array_equal(k[2], [0, 0, 1]) and -w <= k[0, 2] <= 2 * w and -h <= k[1, 2] <= 2 * h):
        raise _fail("K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with 0 < f < 1e6 px and the principal point "
                    "near the image; re-run the calibration")
    dist = _array(data, "dist", (5,))
    if np.abs(dist).max() > 100:
        raise _fail("dist coefficients beyond +-100 are not a lens; re-run the calibration")
    return (int(w), int(h)), k, dist


def _board(data: dict) -> dict[str, Any]:
    """The board definition's JSON form (types only; the camera module validates it fully)."""
    b = data.get("board", {})
    if not isinstance(b, dict):
        raise _fail("board must be an object (the ChArUco board definition)")
    for k, v in b.items():
        want = _BOARD_KEYS.get(k)
        if want is None or isinstance(v, bool) or not isinstance(v, (want, int) if want is float else want):
            raise _fail(f"board[{k!r}] = {v!r} is not a board definition field of the right type")
    return dict(b)


def parse_calibration(data: Any) -> dict[str, Any]:
    """The keyword arguments of ``CameraCalibration`` from its JSON form, validated.

    Parameters
    ----------
    data
        What ``CameraCalibration.to_dict`` wrote (untrusted).

    Returns
    -------
    dict

    Raises
    ------
    CameraCalibrationError
        One line naming the bad field.
    """
    if not isinstance(data, dict):
        raise _fail(f"expected a JSON object, got {type(data).__name__}; choose a camera calibration file")
    if data.get("schema") != CAMERA_CALIBRATION_SCHEMA:
        raise _fail(f"schema {data.get('schema')!r} is not {CAMERA_CALIBRATION_SCHEMA!r}; "
                    "choose a camera calibration file")
    if data.get("version") != CAMERA_CALIBRATION_SCHEMA_VERSION:
        raise _fail(f"version {data.get('version')!r} is not {CAMERA_CALIBRATION_SCHEMA_VERSION}; "
                    "update kogei or re-run the calibration")
    size, k, dist = _intrinsics(data)
    room = None if data.get("room_to_camera") is None else _rigid(data, "room_to_camera")
    rms = data.get("rms_px")
    if isinstance(rms, bool) or not isinstance(rms, (int, float)) or not 0 <= rms < 1e6:
        raise _fail(f"rms_px = {rms!r} must be a finite number >= 0")
    dropped = data.get("dropped_views", [])
    if not isinstance(dropped, list) or not all(isinstance(d, str) for d in dropped):
        raise _fail("dropped_views must be a list of view names")
    held = data.get("held", [])
    if not isinstance(held, list) or not all(h in ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
                                             for h in held):
        raise _fail("held must be a list of intrinsic parameter names (cx, cy, k2, p1, p2, ...)")
    gcov = None
    if data.get("gauge_cov") is not None:
        gcov = _array(data, "gauge_cov", (4, 4))
        if not (np.allclose(gcov, gcov.T, rtol=1e-6, atol=1e-9 * float(np.abs(gcov).max())) and np.all(np.diag(gcov) >= 0)):
            raise _fail("gauge_cov must be a symmetric 4 x 4 covariance; re-run the calibration")
    return {"gauge_cov": gcov, "image_size": size, "K": k, "dist": dist, "gauge_to_camera": _rigid(data, "gauge_to_camera"),
            "room_to_camera": room, "view_rms_px": _figures(data, "view_rms_px"), "rms_px": float(rms),
            "stds": _figures(data, "stds"), "board": _board(data), "dropped_views": tuple(dropped),
            "held": tuple(held)}
