"""Scanner calibration: the laser plane's pose relative to the turntable axis, from a reference sphere.

The geometry convention of the scan station: the turntable axis is room
``+Z`` through the origin, the table top is the plane ``z = 0``; a profile
point ``(x, z)`` of the laser profiler lies at ``o + x X_s + z Z_s`` in the
room, where ``X_s, Y_s, Z_s`` are the columns of ``sensor_to_room[:3, :3]``
and ``o = sensor_to_room[:3, 3]`` is the sensor origin (the emitter); at
table angle ``a`` (degrees, counter-clockwise from above) a table-frame
point ``q`` is at ``Rz(a) q`` in the room.  :func:`calibrate_sphere` finds
``sensor_to_room`` from one revolution of a sphere of known radius; the fit
(segmentation, a circle per profile, a closed-form start, least squares) and
its gauge are described in docs/processing.md, section "Calibration fit".

References
----------
.. [1] Kasa, I. (1976). A circle fitting procedure and its error analysis.
   IEEE Trans. Instrum. Meas. 25(1), 8-14.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.common.rotation import rotation_z
from processing.errors import InputError
from processing.geometry.calibration_fit import (
    _fit_circles,
    _fit_table_line,
    _initial_pose,
    _longest_runs,
    _refine,
    _sphere_distance,
    _table_sample,
)

__all__ = [
    "CALIBRATION_SCHEMA",
    "CALIBRATION_SCHEMA_VERSION",
    "CalibrationError",
    "ScannerCalibration",
    "calibrate_sphere",
    "check_sensor_to_room",
    "ideal_sensor_to_room",
    "profile_points_room",
]

CALIBRATION_SCHEMA = "kogei.scanner_calibration"
#: Version of the JSON layout written by :meth:`ScannerCalibration.to_dict`.
CALIBRATION_SCHEMA_VERSION = 1


class CalibrationError(InputError):
    """The scan cannot be calibrated (sphere not seen, wrong radius, no convergence); the message says why."""


# ---------------------------------------------------------------------------- frames
def ideal_sensor_to_room(standoff_mm: float = 200.0, height_mm: float = 0.0) -> NDArray[np.float64]:
    """The nominal station: ``X_s = +Z``, ``Y_s = +Y``, ``Z_s = -X``, origin ``(standoff, 0, height)``.

    Parameters
    ----------
    standoff_mm
        Distance of the sensor origin from the table axis (mm), > 0.
    height_mm
        Height of the sensor origin above the table top (mm).

    Returns
    -------
    ndarray
        (4, 4) rigid transform from the sensor frame to the room frame.

    Raises
    ------
    ValueError
        A standoff that is not a positive finite distance, a height that is
        not finite.

    Examples
    --------
    >>> ideal_sensor_to_room(200.0, 30.0)[:3].tolist()
    [[0.0, 0.0, -1.0, 200.0], [0.0, 1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 30.0]]
    """
    if not (math.isfinite(standoff_mm) and standoff_mm > 0):
        raise InputError(f"standoff_mm must be a positive distance (mm), got {standoff_mm!r}")
    if not math.isfinite(height_mm):
        raise InputError(f"height_mm must be finite (mm), got {height_mm!r}")
    m = np.eye(4)
    m[:3, :3] = [[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]
    m[:3, 3] = [standoff_mm, 0.0, height_mm]
    return m


def check_sensor_to_room(matrix: ArrayLike, name: str = "sensor_to_room") -> NDArray[np.float64]:
    """Validate a sensor-to-room transform and return it as a float64 (4, 4) array.

    Parameters
    ----------
    matrix
        (4, 4) rigid transform: a proper rotation (orthonormal within 1e-6,
        determinant +1) and a finite translation in mm, last row ``0 0 0 1``.
    name
        Name used in error messages.

    Returns
    -------
    ndarray
        The transform as float64 (4, 4).

    Raises
    ------
    ValueError
        Not (4, 4), NaN or infinite values, a last row other than
        ``0 0 0 1``, a block that is not a proper rotation.

    Examples
    --------
    >>> check_sensor_to_room(np.eye(4)).shape
    (4, 4)
    >>> check_sensor_to_room(np.diag([2.0, 1.0, 1.0, 1.0]))
    Traceback (most recent call last):
    ...
    processing.errors.InputError: sensor_to_room[:3, :3] must be a rotation (orthonormal, det +1); got max |R^T R - I| = 3 and det = 2
    """
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape != (4, 4):
        raise InputError(f"{name} must be a (4, 4) rigid transform, got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise InputError(f"{name} contains NaN or infinite values")
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise InputError(f"{name} must have last row [0, 0, 0, 1], got {m[3].tolist()}")
    r = m[:3, :3]
    err = float(np.abs(r.T @ r - np.eye(3)).max())
    det = float(np.linalg.det(r))
    if err > 1e-6 or det < 0:
        raise InputError(f"{name}[:3, :3] must be a rotation (orthonormal, det +1); "
                         f"got max |R^T R - I| = {err:.3g} and det = {det:.3g}")
    return m


def profile_points_room(x_mm: ArrayLike, z_mm: ArrayLike, sensor_to_room: ArrayLike) -> NDArray[np.float64]:
    """Room coordinates ``o + x X_s + z Z_s`` of sensor-frame profile points.

    Parameters
    ----------
    x_mm, z_mm
        Profile coordinates (mm), any equal shapes; NaN stays NaN.
    sensor_to_room
        (4, 4) sensor-to-room transform (see :func:`check_sensor_to_room`).

    Returns
    -------
    ndarray
        Shape ``x_mm.shape + (3,)``, mm, room frame.

    Raises
    ------
    ValueError
        A bad transform (see :func:`check_sensor_to_room`), ``x_mm`` and
        ``z_mm`` of different shapes.

    Examples
    --------
    >>> profile_points_room([10.0], [150.0], ideal_sensor_to_room(200.0)).tolist()
    [[50.0, 0.0, 10.0]]
    """
    m = check_sensor_to_room(sensor_to_room)
    x = np.asarray(x_mm, dtype=np.float64)
    z = np.asarray(z_mm, dtype=np.float64)
    if x.shape != z.shape:
        raise InputError(f"x_mm and z_mm must have the same shape, got {x.shape} and {z.shape}")
    return x[..., None] * m[:3, 0] + z[..., None] * m[:3, 2] + m[:3, 3]


# ---------------------------------------------------------------------------- result
@dataclass(frozen=True)
class ScannerCalibration:
    """A calibrated scan station.

    Attributes
    ----------
    sensor_to_room
        (4, 4) rigid transform from the profiler's sensor frame to the room
        frame (mm), in the gauge of docs/processing.md, section
        "Calibration fit" (sensor origin in the room's XZ plane, positive X).
    sphere_radius_mm
        Radius of the reference sphere (as given).
    sphere_center_mm
        (3,) centre of the sphere in the table frame (the room at angle 0), mm.
    rms_mm, max_mm
        RMS and largest absolute distance of the sphere points to the fitted
        sphere (mm).
    n_profiles
        Number of profiles in which the sphere was used.
    n_sphere_points, n_table_points
        Points used on the sphere and on the table top.
    table_rms_mm
        RMS height of the table points above ``z = 0`` (mm); NaN-free: 0.0
        when no table point was used (see ``n_table_points``).
    fitted_radius_mm
        The sphere radius estimated with the radius free (a check of the
        given radius), mm.
    step_indices
        (M,) indices of the profiles used.
    step_rms_mm
        (M,) RMS distance to the sphere of each used profile's points (mm).
    """

    sensor_to_room: NDArray[np.float64]
    sphere_radius_mm: float
    sphere_center_mm: NDArray[np.float64]
    rms_mm: float
    max_mm: float
    n_profiles: int
    n_sphere_points: int
    n_table_points: int
    table_rms_mm: float
    fitted_radius_mm: float
    step_indices: NDArray[np.int64] = field(repr=False)
    step_rms_mm: NDArray[np.float64] = field(repr=False)

    SCHEMA: ClassVar[str] = CALIBRATION_SCHEMA
    SCHEMA_VERSION: ClassVar[int] = CALIBRATION_SCHEMA_VERSION

    @property
    def sensor_origin_mm(self) -> NDArray[np.float64]:
        """(3,) sensor origin (the emitter) in the room frame, mm."""
        return self.sensor_to_room[:3, 3].copy()

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (plain lists and numbers) with schema name and version.

        Returns
        -------
        dict
            ``schema``, ``version`` and one entry per attribute (lengths in mm).

        Examples
        --------
        >>> c = ScannerCalibration(ideal_sensor_to_room(), 10.0, np.array([50.0, 0, 10]), 0.05, 0.2,
        ...                        40, 4000, 9000, 0.04, 10.001, np.arange(2), np.array([0.05, 0.06]))
        >>> d = c.to_dict(); d["schema"], d["version"], d["sphere_radius_mm"]
        ('kogei.scanner_calibration', 1, 10.0)
        >>> ScannerCalibration.from_dict(d).n_profiles
        40
        """
        return {
            "schema": self.SCHEMA,
            "version": self.SCHEMA_VERSION,
            "sensor_to_room": np.asarray(self.sensor_to_room, dtype=float).tolist(),
            "sphere_radius_mm": float(self.sphere_radius_mm),
            "sphere_center_mm": np.asarray(self.sphere_center_mm, dtype=float).tolist(),
            "rms_mm": float(self.rms_mm),
            "max_mm": float(self.max_mm),
            "n_profiles": int(self.n_profiles),
            "n_sphere_points": int(self.n_sphere_points),
            "n_table_points": int(self.n_table_points),
            "table_rms_mm": float(self.table_rms_mm),
            "fitted_radius_mm": float(self.fitted_radius_mm),
            "step_indices": np.asarray(self.step_indices, dtype=np.int64).tolist(),
            "step_rms_mm": np.asarray(self.step_rms_mm, dtype=float).tolist(),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ScannerCalibration:
        """Inverse of :meth:`to_dict`; refuses another schema, a newer version or missing fields.

        Parameters
        ----------
        data
            The dictionary read from ``calibration.json``.

        Returns
        -------
        ScannerCalibration
            The calibration.

        Raises
        ------
        ValueError
            Not a dictionary, another schema, an unsupported version, missing
            fields, a bad ``sensor_to_room``, a sphere centre that is not 3
            finite numbers, step arrays of different lengths.
        """
        if not isinstance(data, dict):
            raise InputError(f"a scanner calibration must be a JSON object, got {type(data).__name__}")
        if data.get("schema") != cls.SCHEMA:
            raise InputError(f"not a scanner calibration: schema is {data.get('schema')!r}, expected {cls.SCHEMA!r}")
        version = data.get("version")
        if not isinstance(version, int) or not 1 <= version <= cls.SCHEMA_VERSION:
            raise InputError(f"scanner calibration version {version!r} is not supported "
                             f"(this program reads versions 1..{cls.SCHEMA_VERSION}); update kogei")
        keys = ("sensor_to_room", "sphere_radius_mm", "sphere_center_mm", "rms_mm", "max_mm", "n_profiles",
                "n_sphere_points", "n_table_points", "table_rms_mm", "fitted_radius_mm", "step_indices",
                "step_rms_mm")
        missing = [k for k in keys if k not in data]
        if missing:
            raise InputError(f"scanner calibration lacks field(s) {', '.join(missing)}")
        m = check_sensor_to_room(data["sensor_to_room"], "calibration 'sensor_to_room'")
        centre = np.asarray(data["sphere_center_mm"], dtype=np.float64)
        if centre.shape != (3,) or not np.all(np.isfinite(centre)):
            raise InputError(f"calibration 'sphere_center_mm' must be 3 finite numbers, got {data['sphere_center_mm']!r}")
        steps = np.asarray(data["step_indices"], dtype=np.int64).reshape(-1)
        step_rms = np.asarray(data["step_rms_mm"], dtype=np.float64).reshape(-1)
        if steps.shape != step_rms.shape:
            raise InputError("calibration 'step_indices' and 'step_rms_mm' must have the same length")
        return cls(sensor_to_room=m, sphere_radius_mm=float(data["sphere_radius_mm"]), sphere_center_mm=centre,
                   rms_mm=float(data["rms_mm"]), max_mm=float(data["max_mm"]), n_profiles=int(data["n_profiles"]),
                   n_sphere_points=int(data["n_sphere_points"]), n_table_points=int(data["n_table_points"]),
                   table_rms_mm=float(data["table_rms_mm"]), fitted_radius_mm=float(data["fitted_radius_mm"]),
                   step_indices=steps, step_rms_mm=step_rms)


# ---------------------------------------------------------------------------- input checks
def _check_profiles(x_mm: ArrayLike, z_mm: ArrayLike, angles_deg: ArrayLike
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """The profiles and angles as float arrays of matching shapes, and the mask of valid points."""
    x = np.asarray(x_mm, dtype=np.float64)
    z = np.asarray(z_mm, dtype=np.float64)
    a = np.asarray(angles_deg, dtype=np.float64)
    if x.ndim != 2:
        raise InputError(f"x_mm must be a (steps, points) array of profiles, got shape {x.shape}")
    if z.shape != x.shape:
        raise InputError(f"z_mm must have the shape of x_mm {x.shape}, got {z.shape}")
    if a.shape != (x.shape[0],):
        raise InputError(f"angles_deg must have one angle per profile, shape ({x.shape[0]},), got {a.shape}")
    if not np.all(np.isfinite(a)):
        bad = np.flatnonzero(~np.isfinite(a))
        raise InputError(f"angles_deg has NaN or infinite values at step(s) {bad[:10].tolist()}")
    for name, arr in (("x_mm", x), ("z_mm", z)):
        if np.isinf(arr).any():
            raise InputError(f"{name} contains infinite values; mark invalid points with NaN")
    valid = np.isfinite(x) & np.isfinite(z)
    return x, z, a, valid


# ---------------------------------------------------------------------------- main entry
def calibrate_sphere(
    x_mm: ArrayLike,
    z_mm: ArrayLike,
    angles_deg: ArrayLike,
    sphere_radius_mm: float,
    *,
    sphere_height_mm: float | None = None,
    use_table: bool | None = None,
    table_tolerance_mm: float = 0.5,
    gap_mm: float = 2.0,
    min_profiles: int = 8,
    min_points_per_profile: int = 10,
    max_rms_mm: float = 0.5,
    radius_tolerance_mm: float | None = None,
) -> ScannerCalibration:
    """Estimate ``sensor_to_room`` from one revolution of a reference sphere.

    The steps are: the table line (RANSAC over the pooled profiles), the
    sphere's circle in each profile, a closed-form start, least squares with
    the radius free (a check) and then fixed, and the gauge (the sensor
    origin in the room's XZ plane); see docs/processing.md, section
    "Calibration fit".

    Parameters
    ----------
    x_mm, z_mm
        (S, P) profiles in the sensor frame (mm), NaN where invalid.
    angles_deg
        (S,) table angle of each profile (degrees, counter-clockwise from above).
    sphere_radius_mm
        Certified radius of the reference sphere (mm), > 0.
    sphere_height_mm
        Height of the sphere centre above the table top (mm) when known
        (``sphere_radius_mm`` for a sphere resting on the table).  Needed when
        the table top is not in view; with the table in view it is held fixed.
    use_table
        Use the table-top points: ``None`` when found (automatic), ``True``
        requires them, ``False`` ignores them.
    table_tolerance_mm
        Distance (mm) within which a point belongs to the table-top line.
    gap_mm
        Largest gap (mm) between consecutive points of one sphere section.
    min_profiles
        Fewest profiles with an accepted sphere section.
    min_points_per_profile
        Fewest points for a section to be accepted.
    max_rms_mm
        Largest acceptable RMS distance of the sphere points to the fitted
        sphere (mm); a larger one means the fit did not converge or the data
        is not a sphere of that radius.
    radius_tolerance_mm
        Largest acceptable difference between the given radius and the
        radius fitted freely (mm); default ``max(0.2, 1% of the radius)``.

    Returns
    -------
    ScannerCalibration
        The sensor-to-room transform, the sphere centre and the residuals.

    Raises
    ------
    ValueError
        Malformed input (shapes, NaN angles, infinite coordinates, bad options).
    CalibrationError
        No valid points; the sphere seen in too few profiles; a radius that
        does not match the data; the table height unobservable; a fit that
        does not converge or leaves too large a residual.

    References
    ----------
    .. [1] Kasa, I. (1976). A circle fitting procedure and its error analysis.
       IEEE Trans. Instrum. Meas. 25(1), 8-14.

    Examples
    --------
    A sphere of radius 10 mm, its centre 50 mm off-axis and 10 mm up, seen
    by the ideal station with the sensor 30 mm above the table (closed-form
    ray-sphere intersections, no table in view):

    >>> R, a = 10.0, np.arange(120) * 3.0                     # table angles, degrees
    >>> th = np.radians(np.linspace(-15.0, 15.0, 200))          # the laser fan
    >>> d = np.stack([-np.cos(th), 0 * th, np.sin(th)], -1)     # ray directions in the room
    >>> ar = np.radians(a)[:, None, None]
    >>> oc = np.array([200.0, 0, 30]) - np.concatenate([50 * np.cos(ar), 50 * np.sin(ar), 10 + 0 * ar], -1)
    >>> b = (d * oc).sum(-1); disc = b * b - (oc * oc).sum(-1) + R * R
    >>> t = np.where(disc > 0, -b - np.sqrt(np.abs(disc)), np.nan)   # ray lengths to the sphere
    >>> cal = calibrate_sphere(t * np.sin(th), t * np.cos(th), a, R, sphere_height_mm=10.0)
    >>> (np.round(cal.sensor_to_room[:3], 6) + 0.0).tolist()
    [[0.0, 0.0, -1.0, 200.0], [0.0, 1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 30.0]]
    >>> cal.rms_mm < 1e-6, (np.round(cal.sphere_center_mm, 6) + 0.0).tolist()
    (True, [50.0, 0.0, 10.0])
    """
    x, z, a_deg, valid = _check_profiles(x_mm, z_mm, angles_deg)
    radius, rad_tol = _check_options(sphere_radius_mm, sphere_height_mm, table_tolerance_mm, gap_mm, max_rms_mm,
                                     min_profiles, min_points_per_profile, radius_tolerance_mm)
    if not valid.any():
        raise CalibrationError("the calibration scan has no valid points (every x_mm/z_mm is NaN); "
                               "check that the laser sees the sphere")
    a = np.radians(a_deg)
    scan = _Scan(x=x, z=z, xv=np.where(valid, x, 0.0), zv=np.where(valid, z, 0.0), a=a, valid=valid)
    table_mask = _table_mask(scan, use_table, table_tolerance_mm, sphere_height_mm)
    sections = _sphere_sections(scan, table_mask, gap_mm, min_points_per_profile, min_profiles, radius)
    start = _closed_form_start(scan, table_mask, sections, radius, sphere_height_mm)
    rot, o, rho, h, fitted_r, sph, tab = _refine_pose(scan, table_mask, sections, start, radius, sphere_height_mm,
                                                      table_tolerance_mm, rad_tol)
    m, o, centre = _fix_gauge(rot, o, rho, h)
    return _calibration_result(scan, m, o, centre, radius, fitted_r, sph, tab, bool(table_mask.any()), max_rms_mm)


@dataclass(frozen=True)
class _Scan:
    """The checked profiles: (S, P) ``x``, ``z`` (NaN where invalid), the same with 0 there, angles (rad), validity."""

    x: NDArray[np.float64]
    z: NDArray[np.float64]
    xv: NDArray[np.float64]
    zv: NDArray[np.float64]
    a: NDArray[np.float64]
    valid: NDArray[np.bool_]

    @property
    def step_of(self) -> NDArray[np.int64]:
        """(S, P) step index of every profile slot."""
        return np.broadcast_to(np.arange(self.x.shape[0])[:, None], self.x.shape)


@dataclass(frozen=True)
class _Sections:
    """Circle fitted per profile: centre ``(cu, cv)``, radius ``r``, points ``n``, their mask; profiles used, noise."""

    cu: NDArray[np.float64]
    cv: NDArray[np.float64]
    r: NDArray[np.float64]
    n: NDArray[np.int64]
    mask: NDArray[np.bool_]
    use: NDArray[np.bool_]
    sigma: float


def _check_options(sphere_radius_mm: float, sphere_height_mm: float | None, table_tolerance_mm: float,
                   gap_mm: float, max_rms_mm: float, min_profiles: int, min_points_per_profile: int,
                   radius_tolerance_mm: float | None) -> tuple[float, float]:
    """The sphere radius and the radius tolerance (mm), after checking every option of :func:`calibrate_sphere`."""
    radius = float(sphere_radius_mm)
    if not (math.isfinite(radius) and 0.5 <= radius <= 500.0):
        raise InputError(f"sphere_radius_mm must be a radius in [0.5, 500] mm, got {sphere_radius_mm!r}")
    if sphere_height_mm is not None and not math.isfinite(float(sphere_height_mm)):
        raise InputError(f"sphere_height_mm must be finite (mm) or None, got {sphere_height_mm!r}")
    for name, v in (("table_tolerance_mm", table_tolerance_mm), ("gap_mm", gap_mm), ("max_rms_mm", max_rms_mm)):
        if not (math.isfinite(v) and v > 0):
            raise InputError(f"{name} must be positive (mm), got {v!r}")
    if not isinstance(min_profiles, int) or min_profiles < 4:
        raise InputError(f"min_profiles must be an integer >= 4, got {min_profiles!r}")
    if not isinstance(min_points_per_profile, int) or min_points_per_profile < 5:
        raise InputError(f"min_points_per_profile must be an integer >= 5, got {min_points_per_profile!r}")
    rad_tol = max(0.2, 0.01 * radius) if radius_tolerance_mm is None else float(radius_tolerance_mm)
    if not (math.isfinite(rad_tol) and rad_tol > 0):
        raise InputError(f"radius_tolerance_mm must be positive (mm), got {radius_tolerance_mm!r}")
    return radius, rad_tol


def _table_mask(scan: _Scan, use_table: bool | None, table_tolerance_mm: float,
                sphere_height_mm: float | None) -> NDArray[np.bool_]:
    """The table-top points (step 1); refuses a scan whose frame height is unobservable."""
    table_mask = np.zeros_like(scan.valid)
    if use_table is not False:
        table_mask, _ = _fit_table_line(scan.x, scan.z, scan.valid, table_tolerance_mm)
        if use_table and not table_mask.any():
            raise CalibrationError("use_table=True but no table-top line was found in the profiles; "
                                   "check that the laser reaches the table top, or pass use_table=None")
    have_table = bool(table_mask.any())
    if not have_table and sphere_height_mm is None:
        raise CalibrationError("the table top is not in view, so the height of the room frame is unobservable: "
                               "pass sphere_height_mm (the sphere centre's height above the table top, "
                               "sphere_radius_mm for a sphere resting on it) or scan with the table top in view")
    return table_mask


def _sphere_sections(scan: _Scan, table_mask: NDArray[np.bool_], gap_mm: float, min_points_per_profile: int,
                     min_profiles: int, radius: float) -> _Sections:
    """The sphere's circle in every profile (step 2); refuses a wrong radius or too few profiles."""
    x, valid = scan.x, scan.valid
    cand = _longest_runs(scan.xv, scan.zv, valid & ~table_mask, gap_mm)
    rows = np.flatnonzero(cand.sum(1) >= min_points_per_profile)
    cu, cv, r, rms = (np.zeros(x.shape[0]), np.zeros(x.shape[0]), np.zeros(x.shape[0]),
                      np.full(x.shape[0], np.inf))
    n = np.zeros(x.shape[0], dtype=np.int64)
    sec_mask = np.zeros_like(valid)
    if rows.size:
        fit = _fit_circles(scan.xv[rows], scan.zv[rows], cand[rows], floor_mm=0.05)
        cu[rows], cv[rows], r[rows], rms[rows], n[rows], sec_mask[rows] = fit
    circ = (n >= min_points_per_profile) & np.isfinite(rms)
    sigma = float(np.median(rms[circ])) if circ.any() else 0.05
    circ &= rms <= max(4.0 * sigma, 0.15)
    too_big = circ & (r > radius + max(0.02 * radius, 0.3)) & (r < 4.0 * radius)
    use = circ & (r <= radius + max(0.02 * radius, 0.3)) & (r >= min(0.5, 0.1 * radius))
    if too_big.sum() >= 3 and too_big.sum() > 0.25 * use.sum():
        raise CalibrationError(f"sphere_radius_mm={radius:g} is implausible: {int(too_big.sum())} profiles show "
                               f"circular sections of radius up to {float(r[too_big].max()):.2f} mm; "
                               "give the sphere's radius (not its diameter)")
    if use.sum() < min_profiles:
        raise CalibrationError(f"the sphere was found in only {int(use.sum())} profile(s), fewer than "
                               f"min_profiles={min_profiles}: check that the sphere (radius {radius:g} mm) is in "
                               "the laser's field and range over the revolution, or lower min_profiles")
    return _Sections(cu=cu, cv=cv, r=r, n=n, mask=sec_mask, use=use, sigma=sigma)


def _closed_form_start(scan: _Scan, table_mask: NDArray[np.bool_], sec: _Sections, radius: float,
                       sphere_height_mm: float | None) -> tuple[NDArray, NDArray, float, float]:
    """Rotation, origin, trajectory radius and centre height in closed form (step 3), checked."""
    x, z, a, use = scan.x, scan.z, scan.a, sec.use
    table_pts = None
    if table_mask.any():
        table_pts = np.stack([x[table_mask], np.zeros(int(table_mask.sum())), z[table_mask]], 1)
    rot, o, rho, h = _initial_pose(a[use], sec.cu[use], sec.cv[use], np.minimum(sec.r[use], radius),
                                   sec.n[use].astype(float), radius, table_pts, sphere_height_mm)
    if not (np.all(np.isfinite(rot)) and np.all(np.isfinite(o)) and math.isfinite(rho)):
        raise CalibrationError("the sphere's trajectory could not be solved; the sections do not trace a circle "
                               "about the table axis")
    if rho < radius:
        raise CalibrationError(f"the sphere centre is only {rho:.1f} mm from the table axis: place the sphere "
                               f"off-axis, at least one radius ({radius:g} mm) away (40-80 mm works well)")
    return rot, o, rho, h


def _refine_pose(scan: _Scan, table_mask: NDArray[np.bool_], sec: _Sections,
                 start: tuple[NDArray, NDArray, float, float], radius: float, sphere_height_mm: float | None,
                 table_tolerance_mm: float, rad_tol: float
                 ) -> tuple[NDArray, NDArray, float, float, float, NDArray[np.bool_], NDArray[np.bool_]]:
    """Least squares with the radius free (a check), then fixed after reassigning the points (step 4).

    Returns the rotation, origin, trajectory radius, centre height, the
    freely fitted radius and the sphere and table points finally used.
    """
    x, z, a = scan.x, scan.z, scan.a
    have_table = bool(table_mask.any())
    rot, o, rho, h = start
    fix_h = sphere_height_mm is not None
    h0 = float(sphere_height_mm) if fix_h else h
    step_of = scan.step_of
    sel = sec.mask & sec.use[:, None]
    sp = np.stack([x[sel], z[sel]], 1)
    sa = a[step_of[sel]]
    tp = _table_sample(x, z, table_mask) if have_table else None
    f_scale = max(3.0 * sec.sigma, 0.05)
    rot, o, rho, h, fitted_r, res = _refine(rot, o, rho, h0, radius, True, fix_h, sp, sa, tp, f_scale)
    if not res.success or not np.all(np.isfinite(res.x)):
        raise CalibrationError(f"the calibration fit did not converge ({res.message}); check sphere_radius_mm "
                               "and that the scan is one revolution of the sphere")
    if abs(fitted_r - radius) > rad_tol:
        raise CalibrationError(f"sphere_radius_mm={radius:g} is implausible: the scan fits a sphere of radius "
                               f"{fitted_r:.3f} mm (tolerance {rad_tol:g} mm); give the sphere's certified radius")
    sph, tab = _reassign(scan, rot, o, np.array([rho, 0.0, h]), radius, sec.sigma, have_table, table_tolerance_mm)
    sp = np.stack([x[sph], z[sph]], 1)
    sa = a[step_of[sph]]
    tp = _table_sample(x, z, tab) if have_table else None
    rot, o, rho, h, _, res = _refine(rot, o, rho, h0, radius, False, fix_h, sp, sa, tp, f_scale)
    if not res.success or not np.all(np.isfinite(res.x)):
        raise CalibrationError(f"the calibration fit did not converge ({res.message})")
    return rot, o, rho, h, fitted_r, sph, tab


def _reassign(scan: _Scan, rot: NDArray, o: NDArray, centre: NDArray, radius: float, sigma: float,
              have_table: bool, table_tolerance_mm: float) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Every point assigned to the sphere or the table by its distance to the fitted sphere and table top."""
    xv, zv, valid = scan.xv, scan.zv, scan.valid
    dist = _sphere_distance(xv, zv, scan.a, rot, o, centre) - radius
    inlier_tol = max(5.0 * sigma, 0.25)
    sph = valid & (np.abs(dist) < inlier_tol)
    tab = np.zeros_like(valid)
    if have_table:
        # points near the sphere's contact with the table are within tolerance of both: use neither
        zr = xv * rot[2, 0] + zv * rot[2, 2] + o[2]
        near_table = valid & (np.abs(zr) < max(table_tolerance_mm, inlier_tol))
        tab = near_table & ~sph & (np.abs(zr) < table_tolerance_mm)
        sph &= ~near_table
    return sph, tab


def _fix_gauge(rot: NDArray, o: NDArray, rho: float, h: float) -> tuple[NDArray, NDArray, NDArray]:
    """Turn the room about the table axis so the sensor origin lies in its XZ plane at positive X (step 5).

    Returns the (4, 4) sensor-to-room transform (re-orthonormalised), the
    sensor origin and the sphere centre in the table frame (mm).
    """
    theta = -math.atan2(o[1], o[0])
    g = rotation_z(np.array(theta))
    rot, o = g @ rot, g @ o
    centre = g @ np.array([rho, 0.0, h])
    m = np.eye(4)
    m[:3, :3] = rot
    m[:3, 3] = o
    u_, _, vt_ = np.linalg.svd(rot)  # re-orthonormalise (rounding only)
    m[:3, :3] = u_ @ vt_
    return m, o, centre


def _calibration_result(scan: _Scan, m: NDArray, o: NDArray, centre: NDArray, radius: float, fitted_r: float,
                        sph: NDArray[np.bool_], tab: NDArray[np.bool_], have_table: bool,
                        max_rms_mm: float) -> ScannerCalibration:
    """The residuals of the final fit, checked against ``max_rms_mm``, as a :class:`ScannerCalibration`."""
    xv, zv = scan.xv, scan.zv
    dist = (_sphere_distance(xv, zv, scan.a, m[:3, :3], o, centre) - radius)[sph]
    steps = scan.step_of[sph]
    rms_all = float(np.sqrt(np.mean(dist * dist)))
    if not rms_all <= max_rms_mm:
        raise CalibrationError(f"the calibration fit leaves an RMS distance of {rms_all:.3f} mm to the sphere "
                               f"(limit max_rms_mm={max_rms_mm:g}): the fit did not converge or the scan is not "
                               "one revolution of a sphere of that radius")
    used_steps, inv = np.unique(steps, return_inverse=True)
    step_rms = np.sqrt(np.bincount(inv, weights=dist * dist) / np.bincount(inv))
    table_rms = 0.0
    if have_table and tab.any():
        zr = (xv * m[2, 0] + zv * m[2, 2] + o[2])[tab]
        table_rms = float(np.sqrt(np.mean(zr * zr)))
    return ScannerCalibration(
        sensor_to_room=m,
        sphere_radius_mm=radius,
        sphere_center_mm=centre,
        rms_mm=rms_all,
        max_mm=float(np.abs(dist).max()),
        n_profiles=int(used_steps.size),
        n_sphere_points=int(sph.sum()),
        n_table_points=int(tab.sum()),
        table_rms_mm=table_rms,
        fitted_radius_mm=fitted_r,
        step_indices=used_steps.astype(np.int64),
        step_rms_mm=step_rms,
    )
