"""A tiny ray-traced booth for the sphere and lamp tests: pinhole camera, one sphere, a uniform backdrop, lamps.

Everything not the sphere is the backdrop (radiance ``b``).  A chrome sphere reflects what its mirror ray
sees (the backdrop or a lamp) times ``reflectance``; a matte sphere is Lambertian, lit by a distant light
plus an ambient term, so it is brighter than the backdrop everywhere.  Each pixel is the mean of
``ss x ss`` sub-pixel rays (box filter); Gaussian noise is added.  Only a box around the sphere is traced,
the rest of the frame is the backdrop.  The truth is the scene's own parameters, never the code under test.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

W, H = 960, 640
FX = FY = 2165.0
CX, CY = 479.5, 319.5
K = np.array([[FX, 0, CX], [0, FY, CY], [0, 0, 1.0]])
DIST = np.zeros(5)


def rz(theta_deg):
    a = np.radians(theta_deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def look_at(eye, target, up=(0, 0, 1.0)):
    """room_to_camera (4x4) of a camera at ``eye`` looking at ``target`` (OpenCV axes: x right, y down)."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    r = np.stack([x, y, z])
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = r, -r @ eye
    return m


def booth_camera(distance_mm=260.0, elevation_deg=15.0, azimuth_deg=250.0, target=(0, 0, 20.0)):
    e, a = np.radians(elevation_deg), np.radians(azimuth_deg)
    eye = np.asarray(target) + distance_mm * np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
    return look_at(eye, target)


def _rays(u, v):
    d = np.stack([(u - CX) / FX, (v - CY) / FY, np.ones_like(u)], -1)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


@dataclass
class Scene:
    room_to_camera: np.ndarray = field(default_factory=booth_camera)
    radius_mm: float = 20.0
    backdrop: float = 0.25
    reflectance: float = 0.6
    point_lamps: list = field(default_factory=list)     # (position (3,), radius_mm, radiance)
    distant_lamps: list = field(default_factory=list)   # (unit direction (3,), angular radius deg, radiance)
    matte: bool = False
    albedo: float = 0.8
    noise: float = 0.002
    ss: int = 4

    def sphere_centre_room(self, theta_deg, offset_mm=35.0):
        return rz(theta_deg) @ np.array([offset_mm, 0.0, self.radius_mm])

    def render(self, centre_room, seed=0):
        """(H, W) float image of the sphere centred at ``centre_room`` (mm)."""
        m = self.room_to_camera
        c_cam = m[:3, :3] @ centre_room + m[:3, 3]
        u0, v0 = FX * c_cam[0] / c_cam[2] + CX, FY * c_cam[1] / c_cam[2] + CY
        half = FX * self.radius_mm / np.sqrt(c_cam[2] ** 2 - self.radius_mm ** 2) * 1.15 + 6
        img = np.full((H, W), self.backdrop)
        c0, c1 = int(max(0, np.floor(u0 - half))), int(min(W, np.ceil(u0 + half) + 1))
        r0, r1 = int(max(0, np.floor(v0 - half))), int(min(H, np.ceil(v0 + half) + 1))
        # trace pixel centres, then re-trace with ss x ss sub-pixel rays where the neighbourhood changes
        uu, vv = np.meshgrid(np.arange(c0, c1, dtype=float), np.arange(r0, r1, dtype=float))
        coarse = self._trace(_rays(uu, vv), c_cam)
        pad = np.pad(coarse, 1, mode="edge")
        win = np.stack([pad[i:i + coarse.shape[0], j:j + coarse.shape[1]] for i in range(3) for j in range(3)])
        busy = np.argwhere(win.max(0) - win.min(0) > 0.01)
        s = self.ss
        sub = (np.arange(s) + 0.5) / s - 0.5
        su, sv = np.meshgrid(sub, sub)
        fu = (busy[:, 1, None] + c0 + su.ravel()[None, :])
        fv = (busy[:, 0, None] + r0 + sv.ravel()[None, :])
        coarse[busy[:, 0], busy[:, 1]] = self._trace(_rays(fu, fv), c_cam).mean(axis=1)
        img[r0:r1, c0:c1] = coarse
        return img + np.random.default_rng(seed).normal(0, self.noise, img.shape)

    def _trace(self, d, c):
        b = d @ c
        disc = b * b - (c @ c - self.radius_mm ** 2)
        hit = disc > 0
        out = np.full(d.shape[:-1], self.backdrop)
        dh = d[hit]
        t = b[hit] - np.sqrt(disc[hit])
        p = t[:, None] * dh
        n = (p - c) / self.radius_mm
        rot = self.room_to_camera[:3, :3]
        if self.matte:
            light = rot @ np.array([-0.3, -0.8, 0.6])
            light /= np.linalg.norm(light)
            out[hit] = self.albedo * (0.45 + 0.4 * np.clip(n @ light, 0, None))
            return out
        r = dh - 2 * np.sum(dh * n, -1, keepdims=True) * n
        val = np.full(len(dh), self.backdrop)
        p_room = (p - self.room_to_camera[:3, 3]) @ rot       # rot.T @ (p - t)
        r_room = r @ rot
        for pos, rad_mm, radiance in self.point_lamps:
            w = np.asarray(pos) - p_room
            along = np.sum(w * r_room, -1)
            miss = np.linalg.norm(w - along[:, None] * r_room, axis=-1)
            val[(along > 0) & (miss < rad_mm)] = radiance
        for direction, ang_deg, radiance in self.distant_lamps:
            u = np.asarray(direction, float) / np.linalg.norm(direction)
            val[r_room @ u > np.cos(np.radians(ang_deg))] = radiance
        out[hit] = self.reflectance * val
        return out

    def views(self, angles_deg, offset_mm=35.0, seed=0):
        return [(f"frame{i:02d}", float(a), self.render(self.sphere_centre_room(a, offset_mm), seed + i))
                for i, a in enumerate(angles_deg)]

    def centre_cam(self, centre_room):
        m = self.room_to_camera
        return m[:3, :3] @ centre_room + m[:3, 3]
