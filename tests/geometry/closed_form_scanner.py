"""Closed-form laser-profile scanner for the calibration and scan-point tests: the laser plane of a
deliberately non-ideal station intersected analytically with spheres, cylinders and the table."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation


def rz(a_rad):
    """Rotations about +Z, shape a.shape + (3, 3)."""
    c, s = np.cos(a_rad), np.sin(a_rad)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def tilted_pose(standoff=200.0, height=40.0, tilt_deg=(2.0, -3.0, 1.5), offset=(3.0, -4.0, 2.5)):
    """A deliberately non-ideal station: the ideal pose tilted a few degrees and offset a few mm."""
    m = np.eye(4)
    ideal = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    m[:3, :3] = Rotation.from_euler("xyz", tilt_deg, degrees=True).as_matrix() @ ideal
    m[:3, 3] = np.array([standoff, 0.0, height]) + np.asarray(offset)
    return m


def gauge_fixed(m):
    """``m`` rotated about the table axis so that the sensor origin lies in the XZ plane, x > 0."""
    g = np.eye(4)
    g[:3, :3] = rz(np.array(-np.arctan2(m[1, 3], m[0, 3])))
    return g @ m


@dataclass
class Scan:
    x: np.ndarray        # (S, P) sensor x, NaN invalid
    z: np.ndarray        # (S, P) sensor z (range), NaN invalid
    label: np.ndarray    # (S, P) index of the surface hit (spheres, cylinder sides, cylinder caps, table), -1 none
    point: np.ndarray    # (S, P, 3) exact hit point in the table frame
    normal: np.ndarray   # (S, P, 3) exact outward surface normal in the table frame


def scan(sensor_to_room, angles_deg, *, n_points=400, fov_deg=30.0, spheres=(), cylinders=(), table_radius=None,
         noise=0.0, max_incidence_deg=80.0, range_mm=(100.0, 300.0), seed=0):
    """Laser fan against analytic surfaces fixed in the table frame, in closed form.

    Rays leave the sensor origin along ``sin(t) X_s + cos(t) Z_s``; the surfaces are spheres ``(centre, R)``,
    vertical cylinders ``(cx, cy, radius, height)`` standing on the table (side and top cap) and the
    table disk ``z = 0`` of radius ``table_radius``.  The nearest hit is kept if its incidence is within
    ``max_incidence_deg`` and its range within ``range_mm``; Gaussian noise ``noise`` (mm) is added to the range.
    """
    rot, o = sensor_to_room[:3, :3], sensor_to_room[:3, 3]
    th = np.radians(np.linspace(-fov_deg / 2, fov_deg / 2, n_points))
    d_room = np.stack([np.sin(th), np.zeros_like(th), np.cos(th)], 1) @ rot.T
    to_table = np.swapaxes(rz(np.radians(np.asarray(angles_deg, float))), -1, -2)
    org = np.einsum("sij,j->si", to_table, o)[:, None, :]                         # (S, 1, 3)
    dr = np.einsum("sij,pj->spi", to_table, d_room)                               # (S, P, 3)
    best_t = np.full(dr.shape[:2], np.inf)
    best_n = np.zeros(dr.shape)
    label = np.full(dr.shape[:2], -1)

    def take(t, n, k):
        nonlocal best_t, best_n, label
        better = (t > 1e-9) & (t < best_t)
        best_t = np.where(better, t, best_t)
        best_n = np.where(better[..., None], n, best_n)
        label = np.where(better, k, label)

    def at(t):
        return org + dr * np.where(np.isfinite(t), t, 0.0)[..., None]

    k = 0
    for centre, rad in spheres:
        oc = org - np.asarray(centre)
        b = (dr * oc).sum(-1)
        disc = b * b - (oc * oc).sum(-1) + rad * rad
        t = np.where(disc > 0, -b - np.sqrt(np.abs(disc)), np.inf)
        take(t, (at(t) - np.asarray(centre)) / rad, k)
        k += 1
    for cx, cy, rc, hc in cylinders:
        ox, oy = org[..., 0] - cx, org[..., 1] - cy
        qa = dr[..., 0] ** 2 + dr[..., 1] ** 2
        qb = ox * dr[..., 0] + oy * dr[..., 1]
        disc = qb * qb - qa * (ox * ox + oy * oy - rc * rc)
        t = np.where(disc > 0, (-qb - np.sqrt(np.abs(disc))) / np.where(qa > 0, qa, 1.0), np.inf)
        p = at(t)
        t = np.where((p[..., 2] >= 0) & (p[..., 2] <= hc), t, np.inf)
        take(t, np.stack([(p[..., 0] - cx) / rc, (p[..., 1] - cy) / rc, np.zeros_like(t)], -1), k)
        dz = dr[..., 2]
        t = np.where(dz < -1e-12, (hc - org[..., 2]) / np.where(dz < -1e-12, dz, -1.0), np.inf)
        p = at(t)
        t = np.where((p[..., 0] - cx) ** 2 + (p[..., 1] - cy) ** 2 <= rc * rc, t, np.inf)
        take(t, np.broadcast_to([0.0, 0.0, 1.0], p.shape), k + 1)
        k += 2
    if table_radius is not None:
        dz = dr[..., 2]
        t = np.where(dz < -1e-12, -org[..., 2] / np.where(dz < -1e-12, dz, -1.0), np.inf)
        p = at(t)
        t = np.where(p[..., 0] ** 2 + p[..., 1] ** 2 <= table_radius**2, t, np.inf)
        take(t, np.broadcast_to([0.0, 0.0, 1.0], p.shape), k)
    hit = np.isfinite(best_t)
    cos_i = np.abs((best_n * -dr).sum(-1))
    t = np.where(hit, best_t, 0.0)
    x, z = t * np.sin(th), t * np.cos(th)
    ok = hit & (cos_i >= np.cos(np.radians(max_incidence_deg))) & (z >= range_mm[0]) & (z <= range_mm[1])
    if noise:
        z = z + np.random.default_rng(seed).normal(0.0, noise, z.shape)
    return Scan(np.where(ok, x, np.nan), np.where(ok, z, np.nan), np.where(ok, label, -1), at(t), best_n)



def rotation_error_deg(a, b):
    return float(np.degrees(Rotation.from_matrix(a[:3, :3] @ b[:3, :3].T).magnitude()))
