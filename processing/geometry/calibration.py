"""Scanner calibration: the laser plane's pose relative to the turntable axis,
from one revolution of a reference sphere of known radius.

Issue #4 ("Calibration"); DESIGN.md section 2 (``processing.scan``).  The
geometry convention of the scan station: the turntable axis is room ``+Z``
through the origin, the table top is the plane ``z = 0``; a profile point
``(x, z)`` of the laser profiler lies at ``o + x X_s + z Z_s`` in the room,
where ``X_s, Y_s, Z_s`` are the columns of ``sensor_to_room[:3, :3]`` and
``o = sensor_to_room[:3, 3]`` is the sensor origin (the emitter); at table
angle ``a`` (degrees, counter-clockwise from above) a table-frame point ``q``
is at ``Rz(a) q`` in the room.

Method
------
A sphere of radius ``R`` with its centre ``c`` in the table frame is cut by
the laser plane in a circle.  Its centre is the projection of ``Rz(a) c``
onto the plane, with in-plane coordinates ``(u, v)``, and its radius is
``r = sqrt(R^2 - d^2)``, ``d`` the signed distance of the sphere centre from
the plane (``d = Y_s . (Rz(a) c - o)``), known from ``r`` only up to sign.

1. **Segmentation.**  The table top, a plane perpendicular to the axis, cuts
   the laser plane in the same line at every angle: a RANSAC line fit over
   the pooled profile points finds it.  Of the remaining points, the longest
   connected run of each profile is the candidate sphere section.
2. **Circle per profile** (algebraic fit of Kasa 1976, then Gauss-Newton on
   the geometric distance, with trimming), vectorised over all profiles;
   sections that are not circles, or larger than the sphere, are rejected.
3. **Closed-form start.**  In the sensor frame the sphere centre is
   ``s(a) = rho cos(a) f1 + rho sin(a) f2 + k`` with ``f1, f2`` orthonormal
   and ``f1 x f2`` the table axis, so each of ``u(a), d(a), v(a)`` is
   ``A cos a + B sin a + C``.  ``u`` and ``v`` come from a linear least
   squares fit; the ``d`` row follows from the orthonormality of ``f1, f2``
   (two solutions, mirror images of each other in the laser plane) and its
   constant from ``d^2 = R^2 - r^2`` (a cubic).  The mirror ambiguity is
   settled by the table top (the sensor looks down on it) or, without a
   table, by the station's convention that the laser line points up
   (``X_s . Z > 0``).
4. **Refinement.**  Non-linear least squares (SciPy, trust region, soft-L1)
   of the geometric distances of all sphere points to the sphere
   ``|sensor_to_room(p) - Rz(a) c| - R`` and of the table points to
   ``z = 0``, first with the radius free (a wrong ``sphere_radius_mm`` is
   reported, not absorbed), then with it fixed, after reassigning every
   point by its distance to the fitted sphere and table.

Gauge
-----
A rotation of the room about the table axis, with the table frame turning
with it, changes nothing that the scanner observes: it is fixed so that the
sensor origin lies in the room's XZ plane with positive X (the ideal
station's ``(standoff, 0, height)``).  The height of the room frame is fixed
by the table top (``z = 0`` on its points) or, when the table is not in
view, by the sphere centre's known height above it (``sphere_height_mm``,
``R`` for a sphere resting on the table); with neither it is unobservable and
calibration refuses.  The table top is assumed perpendicular to the axis.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from processing.errors import InputError

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

    Examples
    --------
    >>> ideal_sensor_to_room(200.0, 30.0)[:3].tolist()
    [[0.0, 0.0, -1.0, 200.0], [0.0, 1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 30.0]]
    """
    if not (math.isfinite(standoff_mm) and standoff_mm > 0):
        raise ValueError(f"standoff_mm must be a positive distance (mm), got {standoff_mm!r}")
    if not math.isfinite(height_mm):
        raise ValueError(f"height_mm must be finite (mm), got {height_mm!r}")
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

    Examples
    --------
    >>> check_sensor_to_room(np.eye(4)).shape
    (4, 4)
    >>> check_sensor_to_room(np.diag([2.0, 1.0, 1.0, 1.0]))
    Traceback (most recent call last):
    ...
    ValueError: sensor_to_room[:3, :3] must be a rotation (orthonormal, det +1); got max |R^T R - I| = 3 and det = 2
    """
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape != (4, 4):
        raise ValueError(f"{name} must be a (4, 4) rigid transform, got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise ValueError(f"{name} contains NaN or infinite values")
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise ValueError(f"{name} must have last row [0, 0, 0, 1], got {m[3].tolist()}")
    r = m[:3, :3]
    err = float(np.abs(r.T @ r - np.eye(3)).max())
    det = float(np.linalg.det(r))
    if err > 1e-6 or det < 0:
        raise ValueError(f"{name}[:3, :3] must be a rotation (orthonormal, det +1); "
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

    Examples
    --------
    >>> profile_points_room([10.0], [150.0], ideal_sensor_to_room(200.0)).tolist()
    [[50.0, 0.0, 10.0]]
    """
    m = check_sensor_to_room(sensor_to_room)
    x = np.asarray(x_mm, dtype=np.float64)
    z = np.asarray(z_mm, dtype=np.float64)
    if x.shape != z.shape:
        raise ValueError(f"x_mm and z_mm must have the same shape, got {x.shape} and {z.shape}")
    return x[..., None] * m[:3, 0] + z[..., None] * m[:3, 2] + m[:3, 3]


def _rz(a_rad: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation matrices about +Z, shape ``a.shape + (3, 3)``."""
    c, s = np.cos(a_rad), np.sin(a_rad)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


# ---------------------------------------------------------------------------- result
@dataclass(frozen=True)
class ScannerCalibration:
    """A calibrated scan station.

    Attributes
    ----------
    sensor_to_room
        (4, 4) rigid transform from the profiler's sensor frame to the room
        frame (mm), in the gauge of the module docstring.
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
        """Inverse of :meth:`to_dict`; refuses another schema, a newer version or missing fields."""
        if not isinstance(data, dict):
            raise ValueError(f"a scanner calibration must be a JSON object, got {type(data).__name__}")
        if data.get("schema") != cls.SCHEMA:
            raise ValueError(f"not a scanner calibration: schema is {data.get('schema')!r}, expected {cls.SCHEMA!r}")
        version = data.get("version")
        if not isinstance(version, int) or not 1 <= version <= cls.SCHEMA_VERSION:
            raise ValueError(f"scanner calibration version {version!r} is not supported "
                             f"(this program reads versions 1..{cls.SCHEMA_VERSION}); update kogei")
        keys = ("sensor_to_room", "sphere_radius_mm", "sphere_center_mm", "rms_mm", "max_mm", "n_profiles",
                "n_sphere_points", "n_table_points", "table_rms_mm", "fitted_radius_mm", "step_indices",
                "step_rms_mm")
        missing = [k for k in keys if k not in data]
        if missing:
            raise ValueError(f"scanner calibration lacks field(s) {', '.join(missing)}")
        m = check_sensor_to_room(data["sensor_to_room"], "calibration 'sensor_to_room'")
        centre = np.asarray(data["sphere_center_mm"], dtype=np.float64)
        if centre.shape != (3,) or not np.all(np.isfinite(centre)):
            raise ValueError(f"calibration 'sphere_center_mm' must be 3 finite numbers, got {data['sphere_center_mm']!r}")
        steps = np.asarray(data["step_indices"], dtype=np.int64).reshape(-1)
        step_rms = np.asarray(data["step_rms_mm"], dtype=np.float64).reshape(-1)
        if steps.shape != step_rms.shape:
            raise ValueError("calibration 'step_indices' and 'step_rms_mm' must have the same length")
        return cls(sensor_to_room=m, sphere_radius_mm=float(data["sphere_radius_mm"]), sphere_center_mm=centre,
                   rms_mm=float(data["rms_mm"]), max_mm=float(data["max_mm"]), n_profiles=int(data["n_profiles"]),
                   n_sphere_points=int(data["n_sphere_points"]), n_table_points=int(data["n_table_points"]),
                   table_rms_mm=float(data["table_rms_mm"]), fitted_radius_mm=float(data["fitted_radius_mm"]),
                   step_indices=steps, step_rms_mm=step_rms)


# ---------------------------------------------------------------------------- input checks
def _check_profiles(x_mm: ArrayLike, z_mm: ArrayLike, angles_deg: ArrayLike
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    x = np.asarray(x_mm, dtype=np.float64)
    z = np.asarray(z_mm, dtype=np.float64)
    a = np.asarray(angles_deg, dtype=np.float64)
    if x.ndim != 2:
        raise ValueError(f"x_mm must be a (steps, points) array of profiles, got shape {x.shape}")
    if z.shape != x.shape:
        raise ValueError(f"z_mm must have the shape of x_mm {x.shape}, got {z.shape}")
    if a.shape != (x.shape[0],):
        raise ValueError(f"angles_deg must have one angle per profile, shape ({x.shape[0]},), got {a.shape}")
    if not np.all(np.isfinite(a)):
        bad = np.flatnonzero(~np.isfinite(a))
        raise ValueError(f"angles_deg has NaN or infinite values at step(s) {bad[:10].tolist()}")
    for name, arr in (("x_mm", x), ("z_mm", z)):
        if np.isinf(arr).any():
            raise ValueError(f"{name} contains infinite values; mark invalid points with NaN")
    valid = np.isfinite(x) & np.isfinite(z)
    return x, z, a, valid


# ---------------------------------------------------------------------------- segmentation
def _fit_table_line(x: NDArray, z: NDArray, valid: NDArray, tol: float
                    ) -> tuple[NDArray[np.bool_], NDArray[np.float64] | None]:
    """RANSAC line common to all profiles; returns the inlier mask and (nx, nz, c) with nx x + nz z = c."""
    s = x.shape[0]
    rows = np.broadcast_to(np.arange(s)[:, None], x.shape)[valid]
    px, pz = x[valid], z[valid]
    none = np.zeros_like(valid)
    if px.size < 20:
        return none, None
    rng = np.random.default_rng(12345)
    sub = rng.choice(px.size, size=min(px.size, 4000), replace=False)
    sx, sz = px[sub], pz[sub]
    i, j = rng.integers(0, sub.size, (2, 256))
    dx, dz = sx[j] - sx[i], sz[j] - sz[i]
    ln = np.hypot(dx, dz)
    good = ln > 1.0
    if not good.any():
        return none, None
    nx, nz = -dz[good] / ln[good], dx[good] / ln[good]
    c = nx * sx[i][good] + nz * sz[i][good]
    count = (np.abs(np.outer(nx, sx) + np.outer(nz, sz) - c[:, None]) < tol).sum(1)
    k = int(np.argmax(count))
    line = np.array([nx[k], nz[k], c[k]])
    inl = np.abs(line[0] * px + line[1] * pz - line[2]) < tol
    for _ in range(3):  # total least squares on the inliers, then reselect
        if inl.sum() < 3:
            return none, None
        q = np.stack([px[inl], pz[inl]], 1)
        mu = q.mean(0)
        _, _, vt = np.linalg.svd(q - mu, full_matrices=False)
        n = vt[1]
        line = np.array([n[0], n[1], n @ mu])
        inl = np.abs(line[0] * px + line[1] * pz - line[2]) < tol
    per_row = np.bincount(rows[inl], minlength=s)
    if (per_row >= 5).sum() < max(3, 0.3 * s):
        return none, None
    mask = np.zeros_like(valid)
    mask[valid] = inl
    return mask, line


def _longest_runs(x: NDArray, z: NDArray, mask: NDArray, gap_mm: float) -> NDArray[np.bool_]:
    """Per profile, the longest run of consecutive valid points no farther than ``gap_mm`` apart."""
    s, p = x.shape
    idx = np.where(mask, np.arange(p), -1)
    prev = np.maximum.accumulate(idx, axis=1)
    prev = np.concatenate([np.full((s, 1), -1), prev[:, :-1]], axis=1)
    has = prev >= 0
    pc = np.clip(prev, 0, None)
    with np.errstate(invalid="ignore"):
        dist = np.hypot(x - np.take_along_axis(x, pc, 1), z - np.take_along_axis(z, pc, 1))
    brk = mask & (~has | ~(dist <= gap_mm))
    seg = np.cumsum(brk.ravel()).reshape(s, p) - 1
    if not brk.any():
        return np.zeros_like(mask)
    counts = np.bincount(seg[mask], minlength=int(brk.sum()))
    seg_row = np.nonzero(brk)[0]
    order = np.lexsort((-counts, seg_row))
    _, first = np.unique(seg_row[order], return_index=True)
    best = np.zeros(counts.size, dtype=bool)
    best[order[first]] = True
    return mask & best[np.where(mask, seg, 0)]


def _fit_circles(x: NDArray, z: NDArray, mask: NDArray, floor_mm: float, rounds: int = 3
                 ) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray, NDArray]:
    """Circle per profile (Kasa start, Gauss-Newton, trimming), vectorised; returns cx, cz, r, rms, n, mask."""
    s = x.shape[0]
    m = mask.copy()
    cx = np.zeros(s)
    cz = np.zeros(s)
    r = np.zeros(s)
    rms = np.full(s, np.inf)
    for rnd in range(rounds):
        w = m.astype(np.float64)
        n = w.sum(1)
        ok = n >= 5
        nn = np.where(ok, n, 1.0)
        mx = np.where(m, x, 0.0).sum(1) / nn
        mz = np.where(m, z, 0.0).sum(1) / nn
        X = np.where(m, x - mx[:, None], 0.0)
        Z = np.where(m, z - mz[:, None], 0.0)
        if rnd == 0:
            a = np.stack([X, Z, w], -1)                                   # (S, P, 3)
            b = -(X * X + Z * Z)
            ata = np.einsum("spi,spj->sij", a, a)
            atb = np.einsum("spi,sp->si", a, b)
            ata[~ok] = np.eye(3)
            atb[~ok] = 0.0
            sol = np.linalg.solve(ata, atb[..., None])[..., 0]
            ccx, ccz = -sol[:, 0] / 2, -sol[:, 1] / 2
            r = np.sqrt(np.clip(ccx * ccx + ccz * ccz - sol[:, 2], 0.0, None))
        else:
            ccx, ccz = cx - mx, cz - mz
        for _ in range(6):
            ex, ez = X - ccx[:, None], Z - ccz[:, None]
            rho = np.hypot(ex, ez)
            rho_s = np.where(rho > 1e-12, rho, 1.0)
            res = np.where(m, rho - r[:, None], 0.0)
            jac = np.stack([-ex / rho_s, -ez / rho_s, -np.ones_like(ex)], -1) * w[..., None]
            jtj = np.einsum("spi,spj->sij", jac, jac)
            jtr = np.einsum("spi,sp->si", jac, res)
            jtj[~ok] = np.eye(3)
            jtr[~ok] = 0.0
            jtj += 1e-12 * np.eye(3)
            step = np.linalg.solve(jtj, -jtr[..., None])[..., 0]
            ccx, ccz, r = ccx + step[:, 0], ccz + step[:, 1], r + step[:, 2]
        cx, cz = ccx + mx, ccz + mz
        dist = np.abs(np.hypot(x - cx[:, None], z - cz[:, None]) - r[:, None])
        dist = np.where(m, dist, 0.0)
        rms = np.where(ok, np.sqrt((dist * dist).sum(1) / nn), np.inf)
        if rnd < rounds - 1:
            lim = np.maximum(3.0 * rms, floor_mm)
            m = m & (dist <= lim[:, None])
    n = m.sum(1)
    return cx, cz, np.abs(r), rms, n, m


# ---------------------------------------------------------------------------- closed-form start
def _initial_pose(a: NDArray, cu: NDArray, cv: NDArray, r: NDArray, w: NDArray, radius: float,
                  table_pts: NDArray | None, sphere_height: float | None
                  ) -> tuple[NDArray, NDArray, float, float]:
    """Sensor-to-room rotation, origin, trajectory radius rho and centre height h (gauge phi = 0)."""
    basis = np.stack([np.cos(a), np.sin(a), np.ones_like(a)], 1)
    sw = np.sqrt(w)[:, None]
    ku = np.linalg.lstsq(basis * sw, cu * sw[:, 0], rcond=None)[0]
    kv = np.linalg.lstsq(basis * sw, cv * sw[:, 0], rcond=None)[0]
    va, vb = np.array([ku[0], kv[0]]), np.array([ku[1], kv[1]])
    root = np.sqrt(complex(vb @ vb - va @ va, -2.0 * (va @ vb)))
    e = radius * radius - r * r
    candidates = []
    for sign in (1.0, -1.0):
        y1, y2 = sign * root.real, sign * root.imag
        g = y1 * np.cos(a) + y2 * np.sin(a)
        q = g * g - e
        cub = [a.size, 3.0 * g.sum(), 2.0 * (g * g).sum() + q.sum(), (q * g).sum()]
        roots = np.roots(cub)
        roots = roots[np.abs(roots.imag) < 1e-6 * (1.0 + np.abs(roots.real))].real
        cost = [float((((g + c0) ** 2 - e) ** 2).sum()) for c0 in roots]
        cd = float(roots[int(np.argmin(cost))])
        f1 = np.array([ku[0], y1, kv[0]])
        f2 = np.array([ku[1], y2, kv[1]])
        k3 = np.array([ku[2], cd, kv[2]])
        rho = math.sqrt(0.5 * (f1 @ f1 + f2 @ f2))
        mm = np.stack([f1, f2, np.cross(f1, f2) / max(rho * rho, 1e-12)], 1)
        u, _, vt = np.linalg.svd(mm)
        rot_t = u @ vt
        if np.linalg.det(rot_t) < 0:
            u[:, -1] *= -1
            rot_t = u @ vt
        rot = rot_t.T                               # sensor -> room
        e3 = rot_t[:, 2]                            # room +Z in sensor coordinates
        rk = rot @ k3
        if table_pts is not None:
            oz = -float(np.mean(table_pts @ e3))
            h = oz + rk[2] if sphere_height is None else sphere_height
            up = oz > 0
        else:
            h = float(sphere_height)                # checked by the caller
            up = rot[2, 0] > 0
        o = np.array([0.0, 0.0, h]) - rk
        candidates.append((up, rot, o, rho, h))
    # the two candidates are mirror images: exactly one has "up" the right way
    _, rot, o, rho, h = next((c for c in candidates if c[0]), candidates[0])
    return rot, o, rho, h


# ---------------------------------------------------------------------------- refinement
def _refine(rot0: NDArray, o0: NDArray, rho0: float, h0: float, radius: float, free_radius: bool,
            fix_h: bool, sp: NDArray, sa: NDArray, tp: NDArray | None, f_scale: float
            ) -> tuple[NDArray, NDArray, float, float, float, Any]:
    """Least squares over (rotation vector, origin, rho, [h], [R]); sp (N,2) sensor (x, z), sa (N,) angles."""
    ca, sn = np.cos(sa), np.sin(sa)

    def unpack(p: NDArray) -> tuple[NDArray, NDArray, float, float, float]:
        rot = Rotation.from_rotvec(p[:3]).as_matrix() @ rot0
        o = p[3:6]
        rho = p[6]
        k = 7
        h = h0
        if not fix_h:
            h = p[k]
            k += 1
        rr = p[k] if free_radius else radius
        return rot, o, rho, h, rr

    def fun(p: NDArray) -> NDArray:
        rot, o, rho, h, rr = unpack(p)
        pts = sp[:, :1] * rot[:, 0] + sp[:, 1:] * rot[:, 2] + o
        d = np.sqrt((pts[:, 0] - rho * ca) ** 2 + (pts[:, 1] - rho * sn) ** 2 + (pts[:, 2] - h) ** 2) - rr
        if tp is None:
            return d
        tz = tp[:, 0] * rot[2, 0] + tp[:, 1] * rot[2, 2] + o[2]
        return np.concatenate([d, tz])

    p0 = [0.0, 0.0, 0.0, *o0, rho0]
    if not fix_h:
        p0.append(h0)
    if free_radius:
        p0.append(radius)
    res = least_squares(fun, np.array(p0), method="trf", loss="soft_l1", f_scale=f_scale, x_scale="jac",
                        xtol=1e-12, ftol=1e-12, gtol=1e-10, max_nfev=200)
    rot, o, rho, h, rr = unpack(res.x)
    return rot, o, float(rho), float(h), float(rr), res


def _table_sample(x: NDArray, z: NDArray, mask: NDArray, most: int = 4000) -> NDArray[np.float64]:
    """(M, 2) sensor (x, z) of table points, an even subsample of at most ``most`` (the table fixes only
    the height and tilt of the frame; more points cost time, not accuracy).
    """
    pts = np.stack([x[mask], z[mask]], 1)
    step = max(1, -(-len(pts) // most))
    return pts[::step]


def _sphere_distance(x: NDArray, z: NDArray, a: NDArray, rot: NDArray, o: NDArray, centre: NDArray) -> NDArray:
    """Distance of every profile point (S, P) from the sphere centre at each step's angle."""
    pts = x[..., None] * rot[:, 0] + z[..., None] * rot[:, 2] + o
    c = np.einsum("sij,j->si", _rz(a), centre)
    return np.linalg.norm(pts - c[:, None, :], axis=-1)


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
    """Estimate ``sensor_to_room`` from one revolution of a reference sphere (see the module docstring).

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

    Raises
    ------
    ValueError
        Malformed input (shapes, NaN angles, infinite coordinates, bad options).
    CalibrationError
        No valid points; the sphere seen in too few profiles; a radius that
        does not match the data; the table height unobservable; a fit that
        does not converge or leaves too large a residual.

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
    radius = float(sphere_radius_mm)
    if not (math.isfinite(radius) and 0.5 <= radius <= 500.0):
        raise ValueError(f"sphere_radius_mm must be a radius in [0.5, 500] mm, got {sphere_radius_mm!r}")
    if sphere_height_mm is not None and not math.isfinite(float(sphere_height_mm)):
        raise ValueError(f"sphere_height_mm must be finite (mm) or None, got {sphere_height_mm!r}")
    for name, v in (("table_tolerance_mm", table_tolerance_mm), ("gap_mm", gap_mm), ("max_rms_mm", max_rms_mm)):
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be positive (mm), got {v!r}")
    if not isinstance(min_profiles, int) or min_profiles < 4:
        raise ValueError(f"min_profiles must be an integer >= 4, got {min_profiles!r}")
    if not isinstance(min_points_per_profile, int) or min_points_per_profile < 5:
        raise ValueError(f"min_points_per_profile must be an integer >= 5, got {min_points_per_profile!r}")
    rad_tol = max(0.2, 0.01 * radius) if radius_tolerance_mm is None else float(radius_tolerance_mm)
    if not (math.isfinite(rad_tol) and rad_tol > 0):
        raise ValueError(f"radius_tolerance_mm must be positive (mm), got {radius_tolerance_mm!r}")
    if not valid.any():
        raise CalibrationError("the calibration scan has no valid points (every x_mm/z_mm is NaN); "
                               "check that the laser sees the sphere")
    a = np.radians(a_deg)
    xv = np.where(valid, x, 0.0)  # finite everywhere; masks carry validity
    zv = np.where(valid, z, 0.0)

    # 1. the table line
    table_mask = np.zeros_like(valid)
    if use_table is not False:
        table_mask, _ = _fit_table_line(x, z, valid, table_tolerance_mm)
        if use_table and not table_mask.any():
            raise CalibrationError("use_table=True but no table-top line was found in the profiles; "
                                   "check that the laser reaches the table top, or pass use_table=None")
    have_table = bool(table_mask.any())
    if not have_table and sphere_height_mm is None:
        raise CalibrationError("the table top is not in view, so the height of the room frame is unobservable: "
                               "pass sphere_height_mm (the sphere centre's height above the table top, "
                               "sphere_radius_mm for a sphere resting on it) or scan with the table top in view")

    # 2. sphere sections
    cand = _longest_runs(xv, zv, valid & ~table_mask, gap_mm)
    rows = np.flatnonzero(cand.sum(1) >= min_points_per_profile)
    cu, cv, r, rms = (np.zeros(x.shape[0]), np.zeros(x.shape[0]), np.zeros(x.shape[0]),
                      np.full(x.shape[0], np.inf))
    n = np.zeros(x.shape[0], dtype=np.int64)
    sec_mask = np.zeros_like(valid)
    if rows.size:
        fit = _fit_circles(xv[rows], zv[rows], cand[rows], floor_mm=0.05)
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

    # 3. closed-form start
    table_pts = None
    if have_table:
        table_pts = np.stack([x[table_mask], np.zeros(int(table_mask.sum())), z[table_mask]], 1)
    rot, o, rho, h = _initial_pose(a[use], cu[use], cv[use], np.minimum(r[use], radius), n[use].astype(float),
                                   radius, table_pts, sphere_height_mm)
    if not (np.all(np.isfinite(rot)) and np.all(np.isfinite(o)) and math.isfinite(rho)):
        raise CalibrationError("the sphere's trajectory could not be solved; the sections do not trace a circle "
                               "about the table axis")
    if rho < radius:
        raise CalibrationError(f"the sphere centre is only {rho:.1f} mm from the table axis: place the sphere "
                               f"off-axis, at least one radius ({radius:g} mm) away (40-80 mm works well)")

    # 4. refinement: radius free (check), then fixed after reassigning points
    fix_h = sphere_height_mm is not None
    h0 = float(sphere_height_mm) if fix_h else h
    step_of = np.broadcast_to(np.arange(x.shape[0])[:, None], x.shape)
    sel = sec_mask & use[:, None]
    sp = np.stack([x[sel], z[sel]], 1)
    sa = a[step_of[sel]]
    tp = _table_sample(x, z, table_mask) if have_table else None
    f_scale = max(3.0 * sigma, 0.05)
    rot, o, rho, h, fitted_r, res = _refine(rot, o, rho, h0, radius, True, fix_h, sp, sa, tp, f_scale)
    if not res.success or not np.all(np.isfinite(res.x)):
        raise CalibrationError(f"the calibration fit did not converge ({res.message}); check sphere_radius_mm "
                               "and that the scan is one revolution of the sphere")
    if abs(fitted_r - radius) > rad_tol:
        raise CalibrationError(f"sphere_radius_mm={radius:g} is implausible: the scan fits a sphere of radius "
                               f"{fitted_r:.3f} mm (tolerance {rad_tol:g} mm); give the sphere's certified radius")

    centre = np.array([rho, 0.0, h])
    dist = _sphere_distance(xv, zv, a, rot, o, centre) - radius
    inlier_tol = max(5.0 * sigma, 0.25)
    sph = valid & (np.abs(dist) < inlier_tol)
    tab = np.zeros_like(valid)
    if have_table:
        # points near the sphere's contact with the table are within tolerance of both: use neither
        zr = xv * rot[2, 0] + zv * rot[2, 2] + o[2]
        near_table = valid & (np.abs(zr) < max(table_tolerance_mm, inlier_tol))
        tab = near_table & ~sph & (np.abs(zr) < table_tolerance_mm)
        sph &= ~near_table
    sp = np.stack([x[sph], z[sph]], 1)
    sa = a[step_of[sph]]
    tp = _table_sample(x, z, tab) if have_table else None
    rot, o, rho, h, _, res = _refine(rot, o, rho, h0, radius, False, fix_h, sp, sa, tp, f_scale)
    if not res.success or not np.all(np.isfinite(res.x)):
        raise CalibrationError(f"the calibration fit did not converge ({res.message})")

    # 5. gauge: sensor origin in the room's XZ plane, positive X
    theta = -math.atan2(o[1], o[0])
    g = _rz(np.array(theta))
    rot, o = g @ rot, g @ o
    centre = g @ np.array([rho, 0.0, h])
    m = np.eye(4)
    m[:3, :3] = rot
    m[:3, 3] = o
    u_, _, vt_ = np.linalg.svd(rot)  # re-orthonormalise (rounding only)
    m[:3, :3] = u_ @ vt_

    dist = (_sphere_distance(xv, zv, a, m[:3, :3], o, centre) - radius)[sph]
    steps = step_of[sph]
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
