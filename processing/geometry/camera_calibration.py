"""Camera calibration against the turntable: intrinsics and the camera's pose in the room.

:func:`calibrate_camera` takes the ChArUco corners of views of a board lying on
the turntable (one or more *groups*: placements of the board, flat or on a
wedge; the table turns under it between views) and fits, jointly by least
squares on the corner reprojection errors, the intrinsics ``(fx, fy, cx, cy,
k1, k2, p1, p2)`` (``k3 = 0`` unless asked), the camera's pose relative to the
turntable axis and one board -> table pose per group:
``x_cam = A Rz(theta) B_g X``.  The board cannot see a rotation about the axis
or a shift along it, so ``A`` is expressed in a *gauge table frame* with the
camera centre at ``(0, -rho, 0)`` (module
:mod:`~processing.geometry.camera_calibration_fit`).  :func:`link_to_room`
fixes those two gauge parameters with photos of the scanner's reference
sphere, whose centre the scanner calibration knows in the room (table) frame,
and gives ``room_to_camera``.  docs/processing.md, section "Camera
calibration", describes the method and its checks.

References
----------
.. [1] Zhang, Z. (2000). A flexible new technique for camera calibration.
   IEEE TPAMI 22(11), 1330-1334. doi:10.1109/34.888718
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from processing.common.rotation import rotation_z
from processing.errors import InputError
from processing.geometry.camera_calibration_fit import (
    FitProblem,
    angle_span_deg,
    covariance,
    gauge_transform,
    initial_state,
    per_view_rms,
    solve,
    start_intrinsics,
)

__all__ = [
    "INTRINSIC_NAMES",
    "LONG_LENS_HELD",
    "PP_MAX_STD_PX",
    "CAMERA_CALIBRATION_SCHEMA",
    "CAMERA_CALIBRATION_SCHEMA_VERSION",
    "BoardView",
    "CameraCalibration",
    "CameraCalibrationError",
    "RoomLink",
    "SphereObservation",
    "calibrate_camera",
    "link_to_room",
    "project_points",
]

CAMERA_CALIBRATION_SCHEMA = "kogei.camera_calibration"
#: Version of the JSON layout written by :meth:`CameraCalibration.to_dict`.
CAMERA_CALIBRATION_SCHEMA_VERSION = 1
#: Fewest usable views, fewest corners in a usable view.
MIN_VIEWS, MIN_VIEW_CORNERS = 6, 6
#: A view whose RMS exceeds this multiple of the median is dropped (once).
OUTLIER_FACTOR = 5.0
#: Names of the intrinsic parameters in the fit's order.
INTRINSIC_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
#: Held by the long-lens model: the principal point (at the image centre), k2 and the tangential terms.
LONG_LENS_HELD = (2, 3, 5, 6, 7)
#: A principal point less certain than this (px, one sigma) cannot be told from a camera rotation.
PP_MAX_STD_PX = 1.0
#: Largest accepted chi-square per degree of freedom of the room link.
MAX_LINK_CHI2 = 25.0


class CameraCalibrationError(InputError):
    """The views or the sphere photos cannot calibrate the camera; the message names the figure."""


@dataclass(frozen=True)
class BoardView:
    """The board's corners in one calibration frame.

    Parameters
    ----------
    name
        Frame name (for messages).
    table_angle_deg
        Firmware table angle (deg, counter-clockwise from above).
    group
        Placement of the board on the table the frame belongs to.
    corners_px
        ``(N, 2)`` corner pixels.
    ids
        ``(N,)`` corner ids (rows of the board's corner table).
    """

    name: str
    table_angle_deg: float
    group: str
    corners_px: NDArray[np.float64]
    ids: NDArray[np.int64]


@dataclass(frozen=True)
class SphereObservation:
    """The reference sphere's centre measured in the camera frame in one photo.

    Parameters
    ----------
    table_angle_deg
        Table angle of the photo (deg).
    centre_cam_mm
        ``(3,)`` centre in the camera frame (mm).
    cov_cam
        ``(3, 3)`` its covariance (mm^2).
    """

    table_angle_deg: float
    centre_cam_mm: NDArray[np.float64]
    cov_cam: NDArray[np.float64]


@dataclass(frozen=True)
class CameraCalibration:
    """A calibrated camera (OpenCV conventions; docs/processing.md, "Camera calibration").

    Parameters
    ----------
    image_size
        ``(width, height)`` of the calibration frames (px).
    K
        ``(3, 3)`` intrinsic matrix.
    dist
        ``(5,)`` OpenCV distortion ``(k1, k2, p1, p2, k3)``.
    gauge_to_camera
        ``(4, 4)`` gauge table frame (axis = +z, camera centre at ``(0, -rho, 0)``) -> camera.
    room_to_camera
        ``(4, 4)`` room -> camera once linked (:func:`link_to_room`), else None.
    view_rms_px
        RMS reprojection error of each view used (px).
    rms_px
        RMS reprojection error over all corners (px).
    stds
        One-sigma uncertainties: ``fx_px, fy_px, cx_px, cy_px, axis_direction_deg,
        camera_distance_mm`` (and after linking ``gauge_rotation_deg, gauge_height_mm``).
    board
        The board definition (JSON form), or an empty dict.
    dropped_views
        Views dropped as outliers (RMS > 5x the median).
    gauge_cov
        ``(4, 4)`` covariance of ``gauge_to_camera``'s rotation vector (rad) and ``rho`` (mm),
        used by :func:`link_to_room` to weigh the sphere centres; None if unknown.
    held
        Intrinsic parameters held at nominal values rather than fitted (``cx``, ``cy`` at the image
        centre; ``k2``, ``p1``, ``p2`` at 0) by the long-lens model, else empty.
    """

    image_size: tuple[int, int]
    K: NDArray[np.float64]
    dist: NDArray[np.float64]
    gauge_to_camera: NDArray[np.float64]
    room_to_camera: NDArray[np.float64] | None = None
    view_rms_px: dict[str, float] = field(default_factory=dict)
    rms_px: float = 0.0
    stds: dict[str, float] = field(default_factory=dict)
    board: dict[str, Any] = field(default_factory=dict)
    dropped_views: tuple[str, ...] = ()
    gauge_cov: NDArray[np.float64] | None = None
    held: tuple[str, ...] = ()

    def for_image_size(self, width: int, height: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(K, dist)`` for frames binned by an integer factor from the calibrated size.

        Parameters
        ----------
        width, height
            Size of the frames (px): ``(W / b, H / b)`` for an integer ``b``.

        Returns
        -------
        tuple
            ``K`` with ``fx/b, fy/b, (cx + 0.5)/b - 0.5, (cy + 0.5)/b - 0.5``; the same distortion.

        Examples
        --------
        >>> c = CameraCalibration((960, 640), np.array([[2000.0, 0, 479.5], [0, 2000, 319.5], [0, 0, 1]]),
        ...                       np.zeros(5), np.eye(4))
        >>> c.for_image_size(240, 160)[0][0].tolist()
        [500.0, 0.0, 119.5]
        """
        w0, h0 = self.image_size
        b = w0 / width if width > 0 else 0.0
        if not (width > 0 and height > 0 and b >= 1 and b == round(b) and w0 == width * round(b)
                and h0 == height * round(b)):
            raise CameraCalibrationError(f"image size {width} x {height} is not an integer binning of the "
                                         f"calibrated size {w0} x {h0}; calibrate at this size")
        b = float(round(b))
        k = np.array(self.K, dtype=np.float64)
        k[0, 0], k[1, 1] = k[0, 0] / b, k[1, 1] / b
        k[0, 2], k[1, 2] = (k[0, 2] + 0.5) / b - 0.5, (k[1, 2] + 0.5) / b - 0.5
        return k, np.array(self.dist, dtype=np.float64)

    def to_dict(self) -> dict[str, Any]:
        """The JSON form (schema ``"kogei.camera_calibration"``, version 1).

        Returns
        -------
        dict
        """
        return {
            "schema": CAMERA_CALIBRATION_SCHEMA, "version": CAMERA_CALIBRATION_SCHEMA_VERSION,
            "image_size": [int(self.image_size[0]), int(self.image_size[1])],
            "K": np.asarray(self.K, float).tolist(), "dist": np.asarray(self.dist, float).tolist(),
            "gauge_to_camera": np.asarray(self.gauge_to_camera, float).tolist(),
            "room_to_camera": None if self.room_to_camera is None else np.asarray(self.room_to_camera, float).tolist(),
            "view_rms_px": {str(k): float(v) for k, v in self.view_rms_px.items()},
            "rms_px": float(self.rms_px), "stds": {str(k): float(v) for k, v in self.stds.items()},
            "board": dict(self.board), "dropped_views": list(self.dropped_views),
            "gauge_cov": None if self.gauge_cov is None else np.asarray(self.gauge_cov, float).tolist(),
            "held": list(self.held),
        }

    @classmethod
    def from_dict(cls, data: Any) -> CameraCalibration:
        """Read the JSON form, validating it as untrusted input.

        Parameters
        ----------
        data
            What :meth:`to_dict` wrote.

        Returns
        -------
        CameraCalibration

        Raises
        ------
        CameraCalibrationError
            One line naming the bad field.
        """
        from processing.geometry.camera_calibration_io import parse_calibration

        return cls(**parse_calibration(data))


@dataclass(frozen=True)
class RoomLink:
    """The fit of the gauge to the room (:func:`link_to_room`).

    Attributes
    ----------
    rotation_deg, height_mm
        Gauge parameters: the gauge table frame is the room turned by ``rotation_deg`` about
        the axis and raised by ``height_mm`` along it.
    rotation_std_deg, height_std_mm
        Their one-sigma uncertainties (from the observations' covariances).
    residuals_mm
        ``(n, 3)`` measured minus modelled centre in the camera frame.
    chi2_per_dof
        Weighted residual sum of squares per degree of freedom.
    """

    rotation_deg: float
    height_mm: float
    rotation_std_deg: float
    height_std_mm: float
    residuals_mm: NDArray[np.float64]
    chi2_per_dof: float


def _usable(views: list[BoardView], corners_mm: NDArray[np.float64]) -> list[BoardView]:
    """Views with enough valid corners, their inputs checked."""
    out = []
    for v in views:
        c = np.asarray(v.corners_px, dtype=np.float64)
        ids = np.asarray(v.ids)
        if c.ndim != 2 or c.shape[1] != 2 or ids.shape != (len(c),) or not np.isfinite(c).all() \
                or not np.isfinite(float(v.table_angle_deg)):
            raise CameraCalibrationError(f"view {v.name}: corners must be (N, 2) finite pixels with N ids "
                                         "and a finite table angle")
        if ids.size and (ids.min() < 0 or ids.max() >= len(corners_mm)):
            raise CameraCalibrationError(f"view {v.name}: corner ids outside 0..{len(corners_mm) - 1}; "
                                         "use the board definition the frames were detected with")
        if len(c) >= MIN_VIEW_CORNERS:
            out.append(v)
    return out


def _problem(views: list[BoardView], corners_mm: NDArray[np.float64], fit_k3: bool,
             fixed: tuple[int, ...] = ()) -> tuple[FitProblem, list]:
    """Stack the views' observations; the group names in index order."""
    names = sorted({v.group for v in views})
    gi = {g: i for i, g in enumerate(names)}
    obj = np.concatenate([corners_mm[np.asarray(v.ids, int)] for v in views])
    img = np.concatenate([np.asarray(v.corners_px, np.float64) for v in views])
    view = np.concatenate([np.full(len(v.ids), k) for k, v in enumerate(views)]).astype(np.int64)
    ang = np.radians([float(v.table_angle_deg) for v in views])
    grp = np.array([gi[v.group] for v in views], dtype=np.int64)
    return FitProblem(obj, img, view, ang, grp, len(names), fit_k3, tuple(fixed)), names


def _axis_groups(views: list[BoardView], groups: list[str]) -> list[int]:
    """Indices of the groups with >= 3 distinct table angles spanning >= 30 deg."""
    out = []
    for i, g in enumerate(groups):
        a = np.array([v.table_angle_deg for v in views if v.group == g], dtype=np.float64)
        if len(np.unique(np.round(np.mod(a, 360.0), 6))) >= 3 and angle_span_deg(a) >= 30.0:
            out.append(i)
    return out


def _fit(views: list[BoardView], corners_mm: NDArray[np.float64], image_size: tuple[int, int],
         initial_focal_px: float | None, fit_k3: bool, fixed: tuple[int, ...] = ()) -> tuple:
    """Start (or reuse the previous intrinsics) and solve robustly; returns (p, problem, groups)."""
    prob, groups = _problem(views, corners_mm, fit_k3, fixed)
    axis_groups = _axis_groups(views, groups)
    if not axis_groups:
        raise CameraCalibrationError("turntable axis unobservable: no board placement has >= 3 distinct table "
                                     "angles spanning >= 30 deg; turn the table through more angles")
    objs = [corners_mm[np.asarray(v.ids, int)] for v in views]
    imgs = [np.asarray(v.corners_px, np.float64) for v in views]
    k, dist, rots, trans = start_intrinsics(objs, imgs, image_size, initial_focal_px, fit_k3)
    start = initial_state(rots, trans, prob, axis_groups)
    if start is None:
        raise CameraCalibrationError("turntable axis unobservable: the board poses show no rotation; "
                                     "turn the table between views")
    r_a, rho, gp = start
    intr = [k[0, 0], k[1, 1], k[0, 2], k[1, 2], *dist[:4]] + ([dist[4]] if fit_k3 else [])
    for i in prob.fixed:                # held parameters start (and stay) at their nominal values
        if i in (2, 3):
            intr[i] = (image_size[i - 2] - 1) / 2.0
        elif 4 <= i < len(intr):
            intr[i] = 0.0
    p0 = np.concatenate([intr, r_a, [rho], gp.ravel()])
    res = solve(p0, prob, loss="soft_l1")
    return res.x, prob, groups


def _fit_model(use: list[BoardView], corners_mm: NDArray[np.float64], size: tuple[int, int],
               initial_focal_px: float | None, fit_k3: bool, principal_point: str) -> tuple:
    """Fit the full model, or the long-lens model when the views cannot place the principal point.

    With ``principal_point="auto"`` the full model (principal point, k1, k2, p1, p2) is fitted first;
    when either coordinate of the principal point has a standard deviation above
    :data:`PP_MAX_STD_PX`, the views cannot tell it from a rotation of the camera (a long lens seen
    over a small field), and the model is refitted with the principal point held at the image centre
    and only k1 for the distortion.  Returns ``(p, problem, groups, held)``.
    """
    if principal_point not in ("auto", "fit", "centre"):
        raise CameraCalibrationError(f"principal_point must be auto, fit or centre, got {principal_point!r}")
    if principal_point != "centre":
        p, prob, groups = _fit(use, corners_mm, size, initial_focal_px, fit_k3)
        if principal_point == "fit":
            return p, prob, groups, ()
        res = solve(p, prob, loss="linear")
        sd = np.sqrt(np.clip(np.diag(covariance(res, 2 * len(prob.img_px))), 0, None))
        if max(sd[2], sd[3]) <= PP_MAX_STD_PX:
            return p, prob, groups, ()
    p, prob, groups = _fit(use, corners_mm, size, initial_focal_px, fit_k3, LONG_LENS_HELD)
    return p, prob, groups, tuple(INTRINSIC_NAMES[i] for i in LONG_LENS_HELD)


def calibrate_camera(views: list[BoardView], image_size: tuple[int, int], board_corners_mm: ArrayLike, *,
                     board: dict[str, Any] | None = None, initial_focal_px: float | None = None,
                     max_rms_px: float = 1.0, fit_k3: bool = False,
                     principal_point: str = "auto") -> CameraCalibration:
    """Intrinsics and the camera's pose relative to the turntable axis from board views.

    Parameters
    ----------
    views
        The detected boards (views with fewer than 6 corners are ignored).
    image_size
        ``(width, height)`` of the frames (px).
    board_corners_mm
        ``(C, 3)`` board-frame corners indexed by corner id
        (``processing.camera.charuco.board_corners_mm``).
    board
        The board definition (JSON form) to store with the result.
    initial_focal_px
        Start from this focal length (the manual ``focal_mm / sensor_width_mm * width``)
        instead of ``cv2.calibrateCamera``.
    max_rms_px
        Largest accepted overall reprojection RMS (px).
    fit_k3
        Fit the distortion's k3 (else it is fixed at 0).
    principal_point
        ``"fit"``, ``"centre"`` (held at the image centre, with only k1 for the
        distortion: the long-lens model) or ``"auto"`` (the long-lens model when
        the full fit leaves the principal point uncertain by more than
        :data:`PP_MAX_STD_PX`; the result's ``held`` names what was held).

    Returns
    -------
    CameraCalibration
        Not yet linked to the room (``room_to_camera`` is None).

    Raises
    ------
    CameraCalibrationError
        Fewer than 6 usable views, no placement showing the axis, RMS above ``max_rms_px``.
    """
    corners_mm = np.asarray(board_corners_mm, dtype=np.float64).reshape(-1, 3)
    w, h = (int(image_size[0]), int(image_size[1]))
    use = _usable(list(views), corners_mm)
    if len(use) < MIN_VIEWS:
        raise CameraCalibrationError(f"only {len(use)} usable board views (< {MIN_VIEWS}); shoot more table "
                                     "angles with the whole board in view")
    p, prob, groups, held = _fit_model(use, corners_mm, (w, h), initial_focal_px, fit_k3, principal_point)
    rms_v = per_view_rms(p, prob)
    bad = rms_v > OUTLIER_FACTOR * np.median(rms_v)
    dropped = tuple(v.name for v, b in zip(use, bad) if b)
    if dropped:
        use = [v for v, b in zip(use, bad) if not b]
        if len(use) < MIN_VIEWS:
            raise CameraCalibrationError(f"only {len(use)} usable board views after dropping "
                                         f"{', '.join(dropped)} (RMS > {OUTLIER_FACTOR:g}x the median)")
        p, prob, groups, held = _fit_model(use, corners_mm, (w, h), initial_focal_px, fit_k3, principal_point)
    res = solve(p, prob, loss="linear")
    return replace(_result(res, prob, use, (w, h), board, dropped, max_rms_px), held=held)


def _result(res: Any, prob: FitProblem, views: list[BoardView], size: tuple[int, int], board: dict | None,
            dropped: tuple[str, ...], max_rms_px: float) -> CameraCalibration:
    """Package the solution, its figures and uncertainties; refuse a poor fit."""
    p = res.x
    rms_v = per_view_rms(p, prob)
    rms = float(np.sqrt(2.0 * res.cost / len(prob.img_px)))
    if not rms <= max_rms_px:
        worst = views[int(np.argmax(rms_v))].name
        raise CameraCalibrationError(f"reprojection residual {rms:.2f} px is far above the expected corner noise "
                                     f"(limit {max_rms_px:g} px); check the board definition, the table angles "
                                     f"and focus (worst view {worst}: {rms_v.max():.2f} px)")
    cov = covariance(res, 2 * len(prob.img_px))
    n = prob.n_intr
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))

    def axis_of(rv: NDArray[np.float64]) -> NDArray[np.float64]:
        return Rotation.from_rotvec(rv).as_matrix()[:, 2]

    jd = np.column_stack([(axis_of(p[n:n + 3] + e) - axis_of(p[n:n + 3] - e)) / 2e-6 for e in np.eye(3) * 1e-6])
    cov_axis = jd @ cov[n:n + 3, n:n + 3] @ jd.T
    stds = {"fx_px": sd[0], "fy_px": sd[1], "cx_px": sd[2], "cy_px": sd[3],
            "axis_direction_deg": math.degrees(math.sqrt(max(np.trace(cov_axis), 0.0))),
            "camera_distance_mm": sd[n + 3]}
    k = np.array([[p[0], 0, p[2]], [0, p[1], p[3]], [0, 0, 1.0]])
    dist = np.zeros(5)
    dist[:4] = p[4:8]
    if prob.fit_k3:
        dist[4] = p[8]
    return CameraCalibration(
        image_size=size, K=k, dist=dist, gauge_to_camera=gauge_transform(p[n:n + 3], p[n + 3]),
        view_rms_px={v.name: float(r) for v, r in zip(views, rms_v)}, rms_px=rms,
        stds={key: float(val) for key, val in stds.items()}, board=dict(board or {}), dropped_views=dropped,
        gauge_cov=0.5 * (cov[n:n + 4, n:n + 4] + cov[n:n + 4, n:n + 4].T))


def _observations(observations: list) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Angles (rad), centres (n, 3) and covariances (n, 3, 3) of the sphere observations."""
    ang, cen, covs = [], [], []
    for i, o in enumerate(observations):
        a, c, cv = (o.table_angle_deg, o.centre_cam_mm, o.cov_cam) if isinstance(o, SphereObservation) else o
        c, cv = np.asarray(c, dtype=np.float64), np.asarray(cv, dtype=np.float64)
        if c.shape != (3,) or cv.shape != (3, 3) or not np.isfinite(c).all() or not np.isfinite(cv).all() \
                or not np.isfinite(float(a)):
            raise CameraCalibrationError(f"sphere observation {i}: needs a finite angle, a (3,) centre and a (3, 3) "
                                         "covariance")
        if not np.all(np.linalg.eigvalsh(0.5 * (cv + cv.T)) > 0):
            raise CameraCalibrationError(f"sphere observation {i}: covariance is not positive definite; "
                                         "give the measurement's covariance in mm^2")
        ang.append(math.radians(float(a)))
        cen.append(c)
        covs.append(0.5 * (cv + cv.T))
    return np.array(ang), np.array(cen), np.array(covs)


def _gauge_params(calib: CameraCalibration) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
    """``(rotation vector, rho)`` of ``gauge_to_camera`` and the inverse Cholesky factor of its covariance."""
    a = np.asarray(calib.gauge_to_camera, dtype=np.float64)
    q0 = np.concatenate([Rotation.from_matrix(a[:3, :3]).as_rotvec(), [np.linalg.norm(a[:3, 3])]])
    if calib.gauge_cov is None:
        return q0, None
    cov = 0.5 * (np.asarray(calib.gauge_cov) + np.asarray(calib.gauge_cov).T) + np.eye(4) * 1e-18
    try:
        return q0, np.linalg.inv(np.linalg.cholesky(cov))
    except np.linalg.LinAlgError:
        return q0, None


def link_to_room(calib: CameraCalibration, observations: list, sphere_centre_table_mm: ArrayLike, *,
                 update_pose: bool = True) -> tuple[CameraCalibration, RoomLink]:
    """Fix the gauge (rotation about the axis, height along it) with photos of the reference sphere.

    Parameters
    ----------
    calib
        Result of :func:`calibrate_camera`.
    observations
        :class:`SphereObservation` or ``(table_angle_deg, centre_cam_mm (3,), cov_cam (3, 3))``
        tuples: the sphere centre measured in the camera frame.
    sphere_centre_table_mm
        The sphere centre ``c`` in the room at table angle 0 (the scanner calibration's);
        at angle ``theta`` it is at ``Rz(theta) c``.
    update_pose
        Also refine the gauge pose ``A`` (rotation, ``rho``) with the sphere centres, under its
        covariance from the board fit as a prior (``calib.gauge_cov``); False fits only the two
        gauge parameters.

    Returns
    -------
    tuple
        ``(calibration with room_to_camera and the gauge stds, RoomLink)``.

    Raises
    ------
    CameraCalibrationError
        Fewer than 2 observations, a centre on the axis, or residuals inconsistent with the
        covariances (chi-square per dof > 25).
    """
    if len(observations) < 2:
        raise CameraCalibrationError(f"only {len(observations)} sphere observations (< 2); photograph the "
                                     "reference sphere at two or more table angles")
    ang, cen, covs = _observations(list(observations))
    c = np.asarray(sphere_centre_table_mm, dtype=np.float64).reshape(3)
    if not np.isfinite(c).all() or math.hypot(c[0], c[1]) < 1.0:
        raise CameraCalibrationError(f"sphere centre {c.tolist()} mm is on (or within 1 mm of) the axis, so the "
                                     "rotation about it is unobservable; place the sphere off the axis")
    a = np.asarray(calib.gauge_to_camera, dtype=np.float64)
    room_pts = (rotation_z(ang) @ c)
    g_meas = (cen - a[:3, 3]) @ a[:3, :3]
    phi0 = float(np.angle(np.exp(1j * (np.arctan2(room_pts[:, 1], room_pts[:, 0])
                                       - np.arctan2(g_meas[:, 1], g_meas[:, 0]))).mean()))
    h0 = float((c[2] - g_meas[:, 2]).mean())
    white = np.linalg.inv(np.linalg.cholesky(covs))
    q0, prior = _gauge_params(calib)
    prior = prior if update_pose else None
    n_a = 0 if prior is None else 4

    def fun(q: NDArray[np.float64]) -> NDArray[np.float64]:
        aa = gauge_transform(q0[:3] + q[2:5], q0[3] + q[5]) if n_a else a
        g = room_pts @ rotation_z(-q[0]).T - np.array([0.0, 0.0, q[1]])
        r = np.einsum("nij,nj->ni", white, cen - (g @ aa[:3, :3].T + aa[:3, 3])).ravel()
        return np.concatenate([r, prior @ q[2:6]]) if n_a else r

    res = least_squares(fun, np.concatenate([[phi0, h0], np.zeros(n_a)]), method="lm")
    dof = max(3 * len(ang) - 2, 1)
    chi2 = 2.0 * float(res.cost) / dof
    if not chi2 <= MAX_LINK_CHI2:
        raise CameraCalibrationError(f"sphere centres disagree with the camera calibration: chi-square per dof "
                                     f"{chi2:.1f} > {MAX_LINK_CHI2:g}; check the table angles, the sphere centre "
                                     "and the covariances, or recalibrate")
    a_new = gauge_transform(q0[:3] + res.x[2:5], q0[3] + res.x[5]) if n_a else a
    return _linked(calib, a_new, res, room_pts, cen, chi2)


def _linked(calib: CameraCalibration, a: NDArray[np.float64], res: Any, room_pts: NDArray[np.float64],
            cen: NDArray[np.float64], chi2: float) -> tuple[CameraCalibration, RoomLink]:
    """Build the linked calibration (gauge pose updated by the sphere) and the link report."""
    phi, h = float(res.x[0]), float(res.x[1])
    cov = np.linalg.pinv(res.jac.T @ res.jac)
    room_to_gauge = np.eye(4)
    room_to_gauge[:3, :3] = rotation_z(-phi)
    room_to_gauge[2, 3] = -h
    r2c = a @ room_to_gauge
    pred = room_pts @ r2c[:3, :3].T + r2c[:3, 3]
    link = RoomLink(rotation_deg=math.degrees(phi), height_mm=h,
                    rotation_std_deg=math.degrees(math.sqrt(max(cov[0, 0], 0.0))),
                    height_std_mm=math.sqrt(max(cov[1, 1], 0.0)), residuals_mm=cen - pred, chi2_per_dof=chi2)
    stds = dict(calib.stds, gauge_rotation_deg=link.rotation_std_deg, gauge_height_mm=link.height_std_mm)
    gcov = 0.5 * (cov[2:6, 2:6] + cov[2:6, 2:6].T) if len(res.x) == 6 else calib.gauge_cov
    return replace(calib, room_to_camera=r2c, gauge_to_camera=a, gauge_cov=gcov, stds=stds), link


def project_points(points_mm: ArrayLike, K: ArrayLike, dist: ArrayLike,
                   to_camera: ArrayLike | None = None) -> NDArray[np.float64]:
    """Pixels of 3-D points (``cv2.projectPoints``).

    Parameters
    ----------
    points_mm
        ``(N, 3)`` points (mm) in the frame ``to_camera`` maps from (the camera frame if None).
    K, dist
        Intrinsics and distortion (e.g. :meth:`CameraCalibration.for_image_size`).
    to_camera
        ``(4, 4)`` rigid transform to the camera frame, e.g. ``room_to_camera``.

    Returns
    -------
    ndarray
        ``(N, 2)`` pixels (OpenCV convention, centre of pixel (0, 0) at (0, 0)).

    Examples
    --------
    >>> project_points([[0.0, 0.0, 100.0]], np.diag([1000.0, 1000.0, 1.0]) + [[0, 0, 50], [0, 0, 40], [0, 0, 0]],
    ...                np.zeros(5)).tolist()
    [[50.0, 40.0]]
    """
    pts = np.asarray(points_mm, dtype=np.float64).reshape(-1, 3)
    t = np.eye(4) if to_camera is None else np.asarray(to_camera, dtype=np.float64)
    rvec = Rotation.from_matrix(t[:3, :3]).as_rotvec()
    out, _ = cv2.projectPoints(pts, rvec, t[:3, 3].copy(), np.asarray(K, np.float64), np.asarray(dist, np.float64))
    return out.reshape(-1, 2)
