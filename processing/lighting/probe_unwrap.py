"""A mirror sphere's HDR photo unwrapped into an equirectangular map of the light around it.

For a direction ``d`` (room frame, pointing away from the sphere) the point of the sphere that
mirrors it into the camera is the one whose normal ``n`` halves the angle between ``d`` and the
direction ``v`` from that point to the camera centre: ``n = (v + d) / |v + d|``.  ``v`` depends on
the point ``p = c + R n``, so the three are solved by a fixed-point iteration started from the
direction to the sphere's centre (it contracts by about ``R / |camera - c|`` per step; 6 steps
reach 1e-6 rad for a sphere 10 radii away, a thousandth of a pixel of a 1000-pixel ball).  ``p`` is projected with the calibrated camera
(OpenCV's pinhole and distortion model, ``room_to_camera``) and the HDR image is sampled there
(bilinear), divided by the sphere's reflectance; each map pixel averages ``3 x 3`` directions
across it, so a map coarser than the photo does not alias.

Two caps of directions are not seen, or not seen reliably, and are marked unobserved
(:attr:`ProbeUnwrap.observed`) and filled with the mean radiance of a ring around them:

* around the direction **toward the camera** (``camera_mask_deg``): the ball shows the camera,
  its stand and the photographer there;
* around the direction **away from the camera** (``back_mask_deg``): those directions map to the
  ball's outline at grazing angles, where one pixel spans tens of degrees and the backdrop behind
  the ball shows (a second view from the side would fill them).

The sphere's centre comes from its outline in the photo (the station's sphere finding,
:mod:`processing.geometry.sphere_image`, used by the light-probe workflow) and the camera's
intrinsics and pose from the station's camera calibration.

References
----------
Debevec, P. (1998). Rendering synthetic objects into real scenes. Proceedings of SIGGRAPH 98,
189-198. doi:10.1145/280814.280864

Reinhard, E., Heidrich, W., Debevec, P., Pattanaik, S., Ward, G., & Myszkowski, K. (2010). High
Dynamic Range Imaging, 2nd ed., chapter 11 (light probes).  Morgan Kaufmann, ISBN 978-0-12-374914-7.

Examples
--------
>>> import numpy as np
>>> v = np.array([0.0, -1.0, 0.0]); d = np.array([0.0, 0.0, 1.0])      # camera at -y, direction up
>>> n = (v + d) / np.linalg.norm(v + d)
>>> np.allclose(-v - 2 * np.dot(-v, n) * n, d)                          # the camera ray mirrored is d
True
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.errors import InputError
from processing.lighting.environment_map import pixel_directions

__all__ = ["ProbeUnwrapError", "ProbeUnwrap", "mirror_points", "project", "unwrap_probe", "default_map_height",
           "MIN_REFLECTANCE"]

#: The lowest mirror reflectance accepted: black glass reflects about 0.04; below this it is not a mirror,
#: and dividing by it would amplify the noise more than 50 times.
MIN_REFLECTANCE = 0.02

_ITERATIONS = 6
_SUPERSAMPLE = 3
_RING_DEG = 5.0
_CHUNK_DIRECTIONS = 1 << 20


class ProbeUnwrapError(InputError):
    """A probe that cannot be unwrapped; the one-line message says what and how to fix it."""


@dataclass
class ProbeUnwrap:
    """The light around the sphere as camera RGB on an equirectangular grid (room frame).

    Attributes
    ----------
    rgb
        ``(H, 2H, 3)`` float32 camera RGB of the radiance arriving from each direction (the HDR
        image's units divided by the sphere's reflectance); unobserved pixels filled.
    observed
        ``(H, 2H)`` bool: seen on the sphere (False: inside a masked cap, or off the image).
    toward_camera
        ``(3,)`` room-frame unit direction from the sphere's centre to the camera.
    sphere_centre_mm
        ``(3,)`` the sphere's centre in the room frame.
    radius_px
        The sphere's radius in the photo (px, about).
    notes
        What the caller should report.
    """

    rgb: NDArray[np.float32] = field(repr=False)
    observed: NDArray[np.bool_] = field(repr=False)
    toward_camera: NDArray[np.float64]
    sphere_centre_mm: NDArray[np.float64]
    radius_px: float
    notes: list[str] = field(default_factory=list)


def default_map_height(radius_px: float) -> int:
    """Rows of the map for a sphere of ``radius_px`` in the photo: the power of 2 nearest it, in [16, 1024].

    Around the sphere's centre one pixel of the photo spans about ``90 / radius_px`` degrees of
    direction, and a map of H rows has ``180 / H`` degrees per row: H = radius keeps both near 2 px/row.

    Parameters
    ----------
    radius_px
        The sphere's radius in the photo (px).

    Returns
    -------
    int
        Rows of the map.

    Examples
    --------
    >>> default_map_height(300.0), default_map_height(3.0)
    (256, 16)
    """
    return int(min(1024, max(16, 2 ** round(math.log2(max(radius_px, 1.0))))))


def mirror_points(directions: ArrayLike, centre_mm: ArrayLike, radius_mm: float, eye_mm: ArrayLike
                  ) -> NDArray[np.float64]:
    """Points ``(..., 3)`` of the sphere that mirror the camera's rays into ``directions``.

    Parameters
    ----------
    directions
        ``(..., 3)`` unit directions (room frame) the reflected rays leave along.
    centre_mm, radius_mm
        The sphere.
    eye_mm
        The camera's centre (room frame, mm).

    Returns
    -------
    ndarray
        ``(..., 3)`` points on the sphere (room frame, mm).

    Examples
    --------
    >>> p = mirror_points([[0.0, 0.0, 1.0]], [0, 0, 0], 10.0, [0, -1000.0, 0])
    >>> v = np.array([0, -1000.0, 0]) - p[0]; v /= np.linalg.norm(v); n = p[0] / 10.0
    >>> bool(np.allclose(-v + 2 * np.dot(v, n) * n, [0, 0, 1], atol=1e-9))
    True
    """
    d = np.asarray(directions, dtype=np.float64)
    c = np.asarray(centre_mm, dtype=np.float64)
    eye = np.asarray(eye_mm, dtype=np.float64)
    shape = d.shape
    d = d.reshape(-1, 3)
    v = np.broadcast_to((eye - c) / np.linalg.norm(eye - c), d.shape)
    p = c + 0.0 * d
    for _ in range(_ITERATIONS):
        n = v + d
        n /= np.maximum(np.sqrt(np.einsum("ij,ij->i", n, n)), 1e-12)[:, None]
        p = c + radius_mm * n
        v = eye - p
        v /= np.sqrt(np.einsum("ij,ij->i", v, v))[:, None]
    p = p.reshape(shape)
    return p


def project(points: ArrayLike, rotation: ArrayLike, translation: ArrayLike, K: ArrayLike,
            dist: ArrayLike) -> NDArray[np.float64]:
    """Pixels ``(N, 2)`` of points ``(N, 3)``: OpenCV's pinhole with ``(k1, k2, p1, p2[, k3])`` distortion.

    The same numbers as ``cv2.projectPoints`` (which also computes derivatives, several times slower).

    Parameters
    ----------
    points
        ``(N, 3)`` points in the frame ``rotation`` / ``translation`` map into the camera frame.
    rotation, translation
        ``(3, 3)`` and ``(3,)``: ``x_cam = rotation @ x + translation``.
    K, dist
        Intrinsics and distortion coefficients (4 or 5, or empty).

    Returns
    -------
    ndarray
        ``(N, 2)`` pixels (centre of pixel (0, 0) at (0, 0)).

    Examples
    --------
    >>> project([[10.0, 0, 100]], np.eye(3), np.zeros(3), np.array([[1000.0, 0, 50], [0, 1000, 40], [0, 0, 1]]),
    ...         np.zeros(5)).tolist()
    [[150.0, 40.0]]
    """
    x = np.asarray(points, dtype=np.float64) @ np.asarray(rotation, dtype=np.float64).T \
        + np.asarray(translation, dtype=np.float64)
    xn, yn = x[:, 0] / x[:, 2], x[:, 1] / x[:, 2]
    d = np.zeros(5)
    dd = np.asarray(dist, dtype=np.float64).ravel()[:5]
    d[:dd.size] = dd
    r2 = xn * xn + yn * yn
    radial = 1.0 + r2 * (d[0] + r2 * (d[1] + r2 * d[4]))
    xd = xn * radial + 2 * d[2] * xn * yn + d[3] * (r2 + 2 * xn * xn)
    yd = yn * radial + d[2] * (r2 + 2 * yn * yn) + 2 * d[3] * xn * yn
    k = np.asarray(K, dtype=np.float64)
    return np.stack([k[0, 0] * xd + k[0, 1] * yd + k[0, 2], k[1, 1] * yd + k[1, 2]], axis=1)


def _checked(hdr_rgb: ArrayLike, room_to_camera: ArrayLike, radius_mm: float, reflectance: float,
             camera_mask_deg: float, back_mask_deg: float) -> tuple[NDArray[np.float32], NDArray[np.float64]]:
    img = np.asarray(hdr_rgb, dtype=np.float32)
    if img.ndim != 3 or img.shape[2] != 3 or not np.isfinite(img).all():
        raise ProbeUnwrapError(f"the HDR image must be finite (H, W, 3) camera RGB, got shape {img.shape}")
    t = np.asarray(room_to_camera, dtype=np.float64)
    if t.shape != (4, 4) or not np.isfinite(t).all():
        raise ProbeUnwrapError("room_to_camera must be a finite 4 x 4 transform (the camera calibration's)")
    if not (isinstance(reflectance, (int, float)) and MIN_REFLECTANCE <= reflectance <= 1.0):
        raise ProbeUnwrapError(f"reflectance must be in [{MIN_REFLECTANCE:g}, 1] (a mirror), got {reflectance!r}")
    checks = (("radius_mm", radius_mm, 0.0, math.inf), ("reflectance", reflectance, 0.0, 1.0),
              ("camera_mask_deg", camera_mask_deg, 0.0, 90.0), ("back_mask_deg", back_mask_deg, 0.0, 90.0))
    for name, v, lo, hi in checks:
        if not (isinstance(v, (int, float)) and math.isfinite(v) and lo < v <= hi) and not (
                name.endswith("_deg") and v == 0):
            raise ProbeUnwrapError(f"{name} must be in ({lo:g}, {hi:g}], got {v!r}")
    return img, t


def unwrap_probe(hdr_rgb: ArrayLike, sphere_centre_camera_mm: ArrayLike, radius_mm: float, K: ArrayLike,
                 dist: ArrayLike, room_to_camera: ArrayLike, *, height: int | None = None,
                 reflectance: float = 0.6, camera_mask_deg: float = 12.0,
                 back_mask_deg: float = 45.0) -> ProbeUnwrap:
    """Unwrap a mirror sphere's HDR photo into an equirectangular map of camera RGB (see the module).

    Parameters
    ----------
    hdr_rgb
        ``(H, W, 3)`` linear camera RGB (:class:`processing.lighting.hdr_merge.HdrImage` ``.rgb``).
    sphere_centre_camera_mm
        The sphere's centre in the camera frame (mm), e.g. from its outline.
    radius_mm
        The sphere's radius (mm).
    K, dist
        The camera's intrinsics and OpenCV distortion for this image size.
    room_to_camera
        ``(4, 4)`` room -> camera transform of the calibration (the map is in the room frame).
    height
        Rows of the map (None: :func:`default_map_height` of the sphere's size in the photo).
    reflectance
        The sphere's (grey) mirror reflectance, :data:`MIN_REFLECTANCE` to 1.
    camera_mask_deg, back_mask_deg
        Half-angles of the unobserved caps toward and away from the camera (degrees).

    Returns
    -------
    ProbeUnwrap

    Raises
    ------
    ProbeUnwrapError
        Bad arguments; the sphere outside the photo or behind the camera.
    """
    img, t = _checked(hdr_rgb, room_to_camera, radius_mm, reflectance, camera_mask_deg, back_mask_deg)
    k = np.asarray(K, dtype=np.float64)
    c_cam = np.asarray(sphere_centre_camera_mm, dtype=np.float64)
    if c_cam.shape != (3,) or not np.isfinite(c_cam).all() or c_cam[2] <= radius_mm:
        raise ProbeUnwrapError(f"the sphere's centre {c_cam.tolist()} mm is not in front of the camera")
    rot, trans = t[:3, :3], t[:3, 3]
    eye = -rot.T @ trans
    centre = rot.T @ (c_cam - trans)
    radius_px = float(k[0, 0] * radius_mm / np.linalg.norm(c_cam))
    h = default_map_height(radius_px) if height is None else int(height)
    if not 4 <= h <= 4096:
        raise ProbeUnwrapError(f"height must be 4..4096 rows, got {height!r}")
    toward = (eye - centre) / np.linalg.norm(eye - centre)
    rgb = np.empty((h, 2 * h, 3), np.float32)
    inside = np.empty((h, 2 * h), bool)
    rows = max(1, _CHUNK_DIRECTIONS // (2 * h * _SUPERSAMPLE ** 2))
    for r0 in range(0, h, rows):
        r1 = min(h, r0 + rows)
        dirs = _subpixel_directions(h, r0, r1)                         # (S, r1 - r0, W, 3)
        p = mirror_points(dirs.reshape(-1, 3), centre, radius_mm, eye)
        px = project(p, rot, trans, k, dist).reshape(-1, 2 * h, 2).astype(np.float32)
        samples = cv2.remap(img, px[..., 0], px[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                            borderValue=(-1.0, -1.0, -1.0)).reshape(_SUPERSAMPLE ** 2, r1 - r0, 2 * h, 3)
        inside[r0:r1] = (samples >= 0).all(axis=3).all(axis=0)
        rgb[r0:r1] = np.maximum(samples, 0.0).mean(axis=0) / np.float32(reflectance)
    centre_dirs = pixel_directions(h, 2 * h)
    cos_cam = centre_dirs @ toward
    observed = inside & (cos_cam < math.cos(math.radians(camera_mask_deg))) \
        & (cos_cam > -math.cos(math.radians(back_mask_deg)))
    notes = []
    lost = int((~inside).sum())
    if lost:
        notes.append(f"{lost} map pixels fall outside the photo")
    if not observed.any():
        raise ProbeUnwrapError("no direction of the map is seen on the sphere; check the camera calibration and "
                               "the sphere's position")
    _fill_caps(rgb, observed, cos_cam, camera_mask_deg, back_mask_deg)
    return ProbeUnwrap(rgb, observed, toward, centre, radius_px, notes)


def _subpixel_directions(h: int, r0: int = 0, r1: int | None = None) -> NDArray[np.float64]:
    """``(S * S, r1 - r0, 2H, 3)`` unit directions at ``S x S`` points across the map pixels of rows r0..r1."""
    s = _SUPERSAMPLE
    r1 = h if r1 is None else r1
    theta = np.pi * (np.arange(r0 * s, r1 * s) + 0.5) / (h * s)
    phi = 2.0 * np.pi * (np.arange(2 * h * s) + 0.5) / (2 * h * s)
    st = np.sin(theta)[:, None]
    fine = np.stack(np.broadcast_arrays(st * np.cos(phi)[None, :], st * np.sin(phi)[None, :],
                                        np.cos(theta)[:, None] + 0.0 * phi[None, :]), axis=-1)
    n = r1 - r0
    return fine.reshape(n, s, 2 * h, s, 3).transpose(1, 3, 0, 2, 4).reshape(s * s, n, 2 * h, 3)


def _fill_caps(rgb: NDArray[np.float32], observed: NDArray[np.bool_], cos_cam: NDArray[np.float64],
               camera_mask_deg: float, back_mask_deg: float) -> None:
    """Unobserved pixels take the solid-angle mean of the observed ring (5 degrees) around their cap."""
    h = rgb.shape[0]
    edges = np.pi * np.arange(h + 1) / h
    omega = np.broadcast_to((np.cos(edges[:-1]) - np.cos(edges[1:]))[:, None], observed.shape)
    ang = np.degrees(np.arccos(np.clip(cos_cam, -1.0, 1.0)))            # angle from the camera direction
    caps = ((ang < camera_mask_deg, (ang >= camera_mask_deg) & (ang < camera_mask_deg + _RING_DEG)),
            (ang > 180.0 - back_mask_deg, (ang <= 180.0 - back_mask_deg) & (ang > 180.0 - back_mask_deg - _RING_DEG)))
    rest = ~observed
    for cap, ring in caps:
        ring = ring & observed
        if ring.any():
            mean = (rgb[ring] * omega[ring][:, None]).sum(axis=0) / omega[ring].sum()
            rgb[cap & rest] = mean
    left = ~observed & ~(caps[0][0] | caps[1][0])                      # off the photo: the mean of what is seen
    if left.any():
        rgb[left] = (rgb[observed] * omega[observed][:, None]).sum(axis=0) / omega[observed].sum()
