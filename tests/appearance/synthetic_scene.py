"""A synthetic posed scene with known truth: a sphere and a box occluder, a camera, table angles, pass poses.

The physical construction is written independently of processing.appearance:
an object point ``o`` placed for pass ``p`` sits at ``P_p @ o`` in that pass's
table frame and at ``Rz(theta) @ P_p @ o`` in the room at table angle
``theta``; M is pass 1's table frame, so ``X_M = P_1 @ o`` and the registered
pose of pass p is ``T_p = P_1 @ inv(P_p)``.
"""

from __future__ import annotations

import math

import numpy as np
import open3d as o3d

WIDTH, HEIGHT, FOV_DEG = 240, 160, 25.0
SPHERE_CENTRE = np.array([0.0, 0.0, 60.0])
SPHERE_RADIUS = 40.0


def rz(deg: float) -> np.ndarray:
    a = math.radians(deg)
    out = np.eye(4)
    out[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    return out


def rigid(rx_deg: float, ry_deg: float, rz_deg: float, t) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = o3d.geometry.get_rotation_matrix_from_xyz(np.radians([rx_deg, ry_deg, rz_deg]))
    out[:3, 3] = t
    return out


def intrinsics(width: int = WIDTH, height: int = HEIGHT, fov_deg: float = FOV_DEG) -> np.ndarray:
    f = (width / 2) / math.tan(math.radians(fov_deg) / 2)
    return np.array([[f, 0, width / 2 - 0.5], [0, f, height / 2 - 0.5], [0, 0, 1.0]])


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """room -> camera (OpenCV: x right, y down, z forward)."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    out = np.eye(4)
    out[:3, :3] = np.stack([x, y, z])
    out[:3, 3] = -out[:3, :3] @ eye
    return out


def sphere_and_box(resolution: int = 30):
    """Sphere (centre SPHERE_CENTRE, radius SPHERE_RADIUS) plus an axis-aligned box, in M; returns mesh, box lo/hi."""
    sphere = o3d.geometry.TriangleMesh.create_sphere(SPHERE_RADIUS, resolution=resolution)
    sphere.translate(SPHERE_CENTRE)
    lo, hi = np.array([60.0, -45.0, 20.0]), np.array([75.0, -5.0, 110.0])
    box = o3d.geometry.TriangleMesh.create_box(*(hi - lo))
    box.translate(lo)
    mesh = sphere + box
    n_sphere = len(sphere.vertices)
    return mesh, n_sphere, lo, hi


def ray_box_t(origin, dirs, lo, hi):
    """Entry parameter t of rays ``origin + t * dirs`` into an axis-aligned box (inf when missed or t <= 0)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - origin) / dirs, (hi - origin) / dirs
    tmin = np.nanmax(np.minimum(t1, t2), axis=-1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=-1)
    hit = (tmax >= tmin) & (tmax > 0)
    return np.where(hit, np.maximum(tmin, 0.0), np.inf)


def ray_sphere_t(origin, dirs, centre, radius):
    """First positive t of unit rays into a sphere (inf when missed)."""
    oc = origin - centre
    b = dirs @ oc
    disc = b * b - (oc @ oc - radius * radius)
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    return np.where((disc >= 0) & (t > 0), t, np.inf)


def analytic_labels(room_to_camera, k, width=WIDTH, height=HEIGHT, mesh_pose=None, lo=None, hi=None):
    """Per pixel: 0 background, 1 sphere, 2 box, by analytic ray casting (zero distortion), M = room here."""
    uu, vv = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
    d_cam = np.stack([(uu - k[0, 2]) / k[0, 0], (vv - k[1, 2]) / k[1, 1], np.ones_like(uu)], -1).reshape(-1, 3)
    cam_to_room = np.linalg.inv(room_to_camera)
    dirs = d_cam @ cam_to_room[:3, :3].T
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    origin = cam_to_room[:3, 3]
    ts = ray_sphere_t(origin, dirs, SPHERE_CENTRE, SPHERE_RADIUS)
    tb = ray_box_t(origin, dirs, lo, hi)
    label = np.where(np.isinf(ts) & np.isinf(tb), 0, np.where(ts < tb, 1, 2))
    return label.reshape(height, width)
