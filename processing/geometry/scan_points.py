"""Point cloud of one scan pass: laser profiles, table angles and calibration -> oriented, weighted points.

Conventions of :mod:`processing.geometry.calibration`: a profile point
``(x, z)`` is at ``p = o + x X_s + z Z_s`` in the room, and a room point
measured at table angle ``a`` is at ``Rz(-a) p`` in the table frame (the
frame that turns with the object, equal to the room at angle 0).  The table
top is cropped, normals come from principal component analysis over a patch
of the scan grid, turned toward the sensor, and each point gets a confidence
from its incidence angle and its place in the sensor's range; see
docs/processing.md, section "Points per pass".

References
----------
.. [1] Hoppe, H., DeRose, T., Duchamp, T., McDonald, J., Stuetzle, W.
   (1992). Surface reconstruction from unorganized points. SIGGRAPH 1992.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.errors import InputError
from processing.geometry.calibration import ScannerCalibration, _check_profiles, check_sensor_to_room

__all__ = ["ScanPoints", "profiles_to_points"]

#: Index pairs ``(i, j)``, ``i <= j``, of the six distinct entries of a 3 x 3 covariance.
_PAIRS = ([0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2])


@dataclass(frozen=True)
class ScanPoints:
    """The point cloud of one pass in the table frame.

    Attributes
    ----------
    points
        (N, 3) positions in the table frame (mm).
    normals
        (N, 3) unit normals, turned toward the sensor.
    confidence
        (N,) weights in [0, 1] (incidence x range; 0 for points without an
        estimated normal).
    step
        (N,) index of the profile (step) each point comes from.
    column
        (N,) index of the point within its profile.
    normal_estimated
        (N,) False where the neighbourhood was degenerate and the normal is
        just the direction to the sensor.
    sensor_origins
        (S, 3) the sensor origin seen from the table frame at each step (mm).
    n_total
        ``S * P``, every profile slot.
    n_invalid
        Slots without a measurement (NaN in ``x_mm`` or ``z_mm``).
    n_cropped_table
        Valid points dropped as table top (or below it).
    n_cropped_radius
        Valid points above the table dropped for lying outside ``max_radius_mm``.
    n_kept
        Points returned (``n_total = n_invalid + n_cropped_table + n_cropped_radius + n_kept``).
    """

    points: NDArray[np.float64] = field(repr=False)
    normals: NDArray[np.float64] = field(repr=False)
    confidence: NDArray[np.float64] = field(repr=False)
    step: NDArray[np.int64] = field(repr=False)
    column: NDArray[np.int64] = field(repr=False)
    normal_estimated: NDArray[np.bool_] = field(repr=False)
    sensor_origins: NDArray[np.float64] = field(repr=False)
    n_total: int
    n_invalid: int
    n_cropped_table: int
    n_cropped_radius: int
    n_kept: int

    def as_open3d(self) -> Any:
        """An ``open3d.geometry.PointCloud`` with the points and normals (confidence is not carried).

        Returns
        -------
        open3d.geometry.PointCloud
            The points (mm) with their normals.

        Examples
        --------
        >>> sp = ScanPoints(np.zeros((1, 3)), np.array([[0.0, 0, 1]]), np.ones(1), np.zeros(1, int),
        ...                 np.zeros(1, int), np.ones(1, bool), np.zeros((1, 3)), 1, 0, 0, 0, 1)
        >>> sp.as_open3d().has_normals()
        True
        """
        import open3d as o3d

        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(self.points))
        pc.normals = o3d.utility.Vector3dVector(self.normals)
        return pc


def _runs(pts: NDArray, keep: NDArray, jump: float) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """First and last column of the run holding each kept point; (S, P) arrays, meaningful where ``keep``.

    Runs break where consecutive kept points of a profile are more than
    ``jump`` apart.
    """
    s, p = keep.shape
    cols = np.arange(p)
    prev = np.maximum.accumulate(np.where(keep, cols, -1), axis=1)
    prev = np.concatenate([np.full((s, 1), -1), prev[:, :-1]], axis=1)
    gap = np.linalg.norm(pts - np.take_along_axis(pts, np.clip(prev, 0, None)[..., None], 1), axis=-1)
    brk = keep & ((prev < 0) | (gap > jump))
    start = np.maximum.accumulate(np.where(brk, cols, -1), axis=1)
    seg = np.cumsum(brk.ravel()).reshape(s, p) - 1
    last = np.zeros(max(int(brk.sum()), 1), dtype=np.int64)
    np.maximum.at(last, seg[keep], np.broadcast_to(cols, (s, p))[keep])
    end = last[np.clip(seg, 0, None)]
    return np.clip(start, 0, None), end


def _median_spacing(pts: NDArray, ok: NDArray, axis: int) -> float:
    """Median distance between valid neighbours along ``axis`` of the (S, P, 3) grid (nan-free; 0 if none)."""
    if pts.shape[axis] < 2:
        return 0.0
    a = np.take(pts, np.arange(pts.shape[axis] - 1), axis=axis)
    b = np.take(pts, np.arange(1, pts.shape[axis]), axis=axis)
    both = np.take(ok, np.arange(pts.shape[axis] - 1), axis=axis) & np.take(ok, np.arange(1, pts.shape[axis]),
                                                                          axis=axis)
    if not both.any():
        return 0.0
    return float(np.median(np.linalg.norm((a - b)[both], axis=-1)))


def profiles_to_points(
    x_mm: ArrayLike,
    z_mm: ArrayLike,
    angles_deg: ArrayLike,
    calibration: ScannerCalibration | ArrayLike,
    *,
    table_tolerance_mm: float = 0.5,
    max_radius_mm: float | None = None,
    range_mm: tuple[float, float] = (100.0, 300.0),
    normal_span_mm: float = 1.5,
    normal_window: tuple[int, int] | None = None,
    max_jump_mm: float | None = None,
) -> ScanPoints:
    """Turn one pass's profiles into an oriented, weighted point cloud in the table frame.

    Parameters
    ----------
    x_mm, z_mm
        (S, P) profiles in the sensor frame (mm), NaN where invalid (float32
        or float64).
    angles_deg
        (S,) table angle of each profile (degrees, counter-clockwise from above).
    calibration
        A :class:`~processing.geometry.calibration.ScannerCalibration` or its (4, 4)
        ``sensor_to_room`` matrix.
    table_tolerance_mm
        Points with room ``z < table_tolerance_mm`` are the table top (or
        below it) and are dropped (mm, >= 0).
    max_radius_mm
        Points farther than this from the table axis are dropped (mm); None
        keeps every distance.
    range_mm
        The sensor's working range ``(near, far)`` along ``Z_s`` (mm), for the
        confidence; the default is the KP-200 profiler's.
    normal_span_mm
        Half-span of the neighbourhood for the normals (mm) in both
        directions; larger averages the range noise more and smooths more
        detail (about 0.5 deg median normal error at 1.5 mm with 0.05 mm
        noise).
    normal_window
        Half-widths ``(k_s, k_p)`` of the neighbourhood in steps and in points,
        overriding ``normal_span_mm``.
    max_jump_mm
        Consecutive points farther apart than this are on different surfaces
        (mm); default ``max(1, 4 * spacing)`` with ``spacing`` the larger median
        distance between neighbours across and along the profiles.

    Returns
    -------
    ScanPoints
        Points, normals and confidences in the table frame (mm), with their
        step and column and the counts of cropped points.

    Raises
    ------
    ValueError
        Wrong shapes, NaN/infinite angles, infinite coordinates, a bad
        calibration or option, no valid point, or every point cropped.

    Examples
    --------
    A plane 50 mm in front of the axis (normal +X in the table frame), seen
    by the ideal sensor (standoff 200 mm, 30 mm above the table) at the table
    angles -0.5 and +0.5 deg; along the ray at elevation ``theta`` the range
    to it is ``200 - 50 / cos(a)``:

    >>> from processing.geometry.calibration import ideal_sensor_to_room
    >>> a = np.array([-0.5, 0.5]); th = np.radians(np.linspace(-10.0, 10.0, 21))
    >>> z = np.repeat(200.0 - 50.0 / np.cos(np.radians(a))[:, None], 21, axis=1)
    >>> sp = profiles_to_points(z * np.tan(th), z, a, ideal_sensor_to_room(200.0, 30.0))
    >>> sp.n_kept, sp.n_cropped_table, bool(np.allclose(sp.normals, [1.0, 0.0, 0.0]))
    (42, 0, True)
    >>> round(float(sp.confidence[10]), 4)     # centre ray: cos(0.5 deg) * (1 - 0.5^2) at range 150 of (100, 300)
    0.75
    """
    x, z, a, m, (near, far) = _check_inputs(x_mm, z_mm, angles_deg, calibration, table_tolerance_mm, max_radius_mm,
                                            range_mm, normal_span_mm, normal_window, max_jump_mm)
    s, p = x.shape
    valid = np.isfinite(x) & np.isfinite(z)
    n_total, n_invalid = s * p, int((~valid).sum())
    if not valid.any():
        raise InputError(f"the profiles have no valid point (all {n_total} x_mm/z_mm values are NaN); "
                         "check that the laser saw the object")
    xv, zv = np.where(valid, x, 0.0), np.where(valid, z, 0.0)
    pts, origins = _table_frame(xv, zv, a, m)
    keep, n_table, n_radius, n_kept = _crop(pts, valid, table_tolerance_mm, max_radius_mm)
    ks, kp, jump, wrap = _neighbourhood(pts, keep, a, normal_window, normal_span_mm, max_jump_mm)
    normals, estimated = _grid_normals(pts, keep, ks, kp, jump, wrap)
    normals, conf = _orient_and_weigh(normals, estimated, pts, origins, zv, near, far)
    rows, cols = np.nonzero(keep)
    return ScanPoints(
        points=pts[keep],
        normals=normals[keep],
        confidence=conf[keep],
        step=rows.astype(np.int64),
        column=cols.astype(np.int64),
        normal_estimated=estimated[keep],
        sensor_origins=origins,
        n_total=n_total,
        n_invalid=n_invalid,
        n_cropped_table=n_table,
        n_cropped_radius=n_radius,
        n_kept=n_kept,
    )


def _check_inputs(x_mm: ArrayLike, z_mm: ArrayLike, angles_deg: ArrayLike,
                  calibration: ScannerCalibration | ArrayLike, table_tolerance_mm: float,
                  max_radius_mm: float | None, range_mm: tuple[float, float], normal_span_mm: float,
                  normal_window: tuple[int, int] | None, max_jump_mm: float | None
                  ) -> tuple[NDArray, NDArray, NDArray, NDArray, tuple[float, float]]:
    """The profiles, angles and ``sensor_to_room`` as float arrays and the range, after checking every option."""
    x, z, a, _ = _check_profiles(x_mm, z_mm, angles_deg)
    m = check_sensor_to_room(calibration.sensor_to_room if isinstance(calibration, ScannerCalibration)
                             else calibration, "calibration")
    if not (math.isfinite(table_tolerance_mm) and table_tolerance_mm >= 0):
        raise InputError(f"table_tolerance_mm must be a distance >= 0 (mm), got {table_tolerance_mm!r}")
    if max_radius_mm is not None and not (math.isfinite(max_radius_mm) and max_radius_mm > 0):
        raise InputError(f"max_radius_mm must be a positive distance (mm) or None, got {max_radius_mm!r}")
    near, far = (float(v) for v in range_mm)
    if not (math.isfinite(near) and math.isfinite(far) and 0 <= near < far):
        raise InputError(f"range_mm must be (near, far) with 0 <= near < far (mm), got {range_mm!r}")
    if not (math.isfinite(normal_span_mm) and normal_span_mm > 0):
        raise InputError(f"normal_span_mm must be a positive distance (mm), got {normal_span_mm!r}")
    if normal_window is not None:
        ks, kp = normal_window
        if not (isinstance(ks, (int, np.integer)) and isinstance(kp, (int, np.integer)) and ks >= 0 and kp >= 0
                and ks + kp >= 1 and ks <= 20 and kp <= 200):
            raise InputError(f"normal_window must be (k_steps, k_points), integers with 0 <= k_steps <= 20, "
                             f"0 <= k_points <= 200, not both 0; got {normal_window!r}")
    if max_jump_mm is not None and not (math.isfinite(max_jump_mm) and max_jump_mm > 0):
        raise InputError(f"max_jump_mm must be a positive distance (mm) or None, got {max_jump_mm!r}")
    return x, z, a, m, (near, far)


def _table_frame(xv: NDArray, zv: NDArray, a: NDArray, m: NDArray) -> tuple[NDArray, NDArray]:
    """(S, P, 3) profile points and (S, 3) sensor origins in the table frame: room -> table is ``Rz(-a)``."""
    s = xv.shape[0]
    ar = np.radians(a)
    c, sn = np.cos(ar), np.sin(ar)
    room = xv[..., None] * m[:3, 0] + zv[..., None] * m[:3, 2] + m[:3, 3]          # (S, P, 3)
    pts = np.stack([c[:, None] * room[..., 0] + sn[:, None] * room[..., 1],
                    -sn[:, None] * room[..., 0] + c[:, None] * room[..., 1], room[..., 2]], -1)
    o = m[:3, 3]
    origins = np.stack([c * o[0] + sn * o[1], -sn * o[0] + c * o[1], np.full(s, o[2])], -1)  # (S, 3)
    return pts, origins


def _crop(pts: NDArray, valid: NDArray, table_tolerance_mm: float, max_radius_mm: float | None
          ) -> tuple[NDArray[np.bool_], int, int, int]:
    """The points kept above the table top and within ``max_radius_mm`` of the axis, and the counts cropped."""
    table = valid & (pts[..., 2] < table_tolerance_mm)
    outside = np.zeros_like(valid)
    if max_radius_mm is not None:
        outside = valid & ~table & (np.hypot(pts[..., 0], pts[..., 1]) > max_radius_mm)
    keep = valid & ~table & ~outside
    n_table, n_radius, n_kept = int(table.sum()), int(outside.sum()), int(keep.sum())
    if n_kept == 0:
        raise InputError(f"all {int(valid.sum())} valid points were cropped ({n_table} as table top within "
                         f"table_tolerance_mm={table_tolerance_mm:g} of z = 0 or below it, {n_radius} outside "
                         f"max_radius_mm={max_radius_mm}); check the calibration and the crop settings")
    return keep, n_table, n_radius, n_kept


def _neighbourhood(pts: NDArray, keep: NDArray, a: NDArray, normal_window: tuple[int, int] | None,
                   normal_span_mm: float, max_jump_mm: float | None) -> tuple[int, int, float, bool]:
    """Half-widths ``(k_s, k_p)`` of the normal window, the jump that breaks runs (mm), and whether steps wrap."""
    s = pts.shape[0]
    d_s = _median_spacing(pts, keep, 0)
    d_p = _median_spacing(pts, keep, 1)
    if normal_window is None:
        ks = 0 if d_s <= 0 else int(np.clip(round(normal_span_mm / d_s), 1, 10))
        kp = 0 if d_p <= 0 else int(np.clip(round(normal_span_mm / d_p), 1, 100))
        if ks + kp == 0:
            ks = kp = 1
    else:
        ks, kp = normal_window
    jump = max(1.0, 4.0 * max(d_s, d_p)) if max_jump_mm is None else float(max_jump_mm)
    wrap = False
    if s >= 3:
        steps = np.abs((np.diff(a) + 180.0) % 360.0 - 180.0)
        closing = abs((a[0] - a[-1] + 180.0) % 360.0 - 180.0)
        med = float(np.median(steps))
        wrap = med > 0 and closing <= 1.5 * med and 2 * ks < s
    return ks, kp, jump, wrap


def _grid_normals(pts: NDArray, keep: NDArray, ks: int, kp: int, jump: float, wrap: bool
                  ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """(S, P, 3) unoriented PCA normals over the scan-grid windows, and where the window spans a surface."""
    return _pca_normals(_window_moments(pts, keep, ks, kp, jump, wrap), keep)


def _window_moments(pts: NDArray, keep: NDArray, ks: int, kp: int, jump: float, wrap: bool) -> NDArray[np.float64]:
    """(S, P, 10) count, first and second moments of every window, from cumulative sums along the profiles."""
    s, p = keep.shape
    # coordinates relative to the centroid
    centroid = pts[keep].mean(axis=0)
    q = np.where(keep[..., None], pts - centroid, 0.0)
    iu = _PAIRS
    f = np.concatenate([keep[..., None].astype(np.float64), q, q[..., iu[0]] * q[..., iu[1]]], axis=-1)  # (S, P, 10)
    csum = np.concatenate([np.zeros((s, 1, 10)), np.cumsum(f, axis=1)], axis=1)                          # (S, P+1, 10)
    start, end = _runs(pts, keep, jump)
    cols = np.arange(p)
    mom = np.zeros((s, p, 10))
    rows_i = np.arange(s)[:, None]
    for di in range(-ks, ks + 1):
        r = rows_i + di
        if wrap:
            r = r % s
        inside = (r >= 0) & (r < s)
        rc = np.clip(r, 0, s - 1)
        rr = np.broadcast_to(rc, (s, p))
        other = keep[rr, cols] & inside & keep
        if di != 0:
            other &= np.linalg.norm(pts[rr, cols] - pts, axis=-1) <= abs(di) * jump
        lo = np.maximum(cols - kp, start[rr, cols])
        hi = np.minimum(cols + kp, end[rr, cols]) + 1
        mom += np.where(other[..., None], csum[rr, hi] - csum[rr, lo], 0.0)
    return mom


def _pca_normals(mom: NDArray[np.float64], keep: NDArray) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Normals (eigenvector of the smallest eigenvalue of each window's covariance) and where they are defined."""
    s, p = keep.shape
    iu = _PAIRS
    cnt = mom[..., 0]
    kk = keep & (cnt >= 3)
    n_nb = cnt[kk][:, None]
    mean = mom[kk][:, 1:4] / n_nb
    sec = mom[kk][:, 4:] / n_nb
    cov = np.empty((mean.shape[0], 3, 3))
    for k, (i, j) in enumerate(zip(*iu)):
        cov[:, i, j] = cov[:, j, i] = sec[:, k] - mean[:, i] * mean[:, j]
    w, v = np.linalg.eigh(cov)
    flat = w[:, 1] > 1e-6 * np.maximum(w[:, 2], 1e-300)     # the neighbourhood spans a surface
    normals = np.zeros((s, p, 3))
    estimated = np.zeros((s, p), dtype=bool)
    normals[kk] = v[:, :, 0]
    estimated[kk] = flat
    return normals, estimated


def _orient_and_weigh(normals: NDArray, estimated: NDArray, pts: NDArray, origins: NDArray, zv: NDArray,
                      near: float, far: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Normals turned toward the sensor (its direction where none was estimated) and the confidences."""
    to_sensor = origins[:, None, :] - pts
    dist = np.linalg.norm(to_sensor, axis=-1)
    to_sensor = to_sensor / np.where(dist > 0, dist, 1.0)[..., None]
    cos_i = (normals * to_sensor).sum(-1)
    normals = np.where((cos_i < 0)[..., None], -normals, normals)
    normals = np.where(estimated[..., None], normals, to_sensor)
    cos_i = np.clip(np.abs(cos_i), 0.0, 1.0)
    half, mid = (far - near) / 2.0, (far + near) / 2.0
    u = (zv - mid) / half
    conf = np.where(estimated, cos_i * np.clip(1.0 - u * u, 0.0, 1.0), 0.0)
    return normals, conf
