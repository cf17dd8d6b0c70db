"""A sphere of known radius in a linear photo: its outline and its centre in the camera frame.

The booth's backdrop is uniform, so the sphere is what differs from it: a matte reference sphere is
brighter, a chrome sphere mirrors the darker backdrop (about 40 % darker) and shows the lamps as small,
much brighter highlights.  :func:`sphere_silhouette` finds the outline to a fraction of a pixel;
:func:`fit_sphere_centre` turns it into the sphere's centre with the exact perspective model: every
ray that grazes a sphere of radius R centred at c makes the angle ``asin(R / |c|)`` with the direction
of c, so the silhouette is a cone of rays.  The centre of the ellipse the outline forms is *not* the
projection of the centre off the optical axis (the ellipse is the conic section of that cone), which is
why the cone, not the ellipse, is fitted.

Examples
--------
>>> import numpy as np
>>> K = np.array([[1000.0, 0, 320], [0, 1000.0, 240], [0, 0, 1]])
>>> c = np.array([30.0, -10.0, 300.0])                       # the true centre, mm
>>> axis = c / np.linalg.norm(c); a = np.arcsin(20.0 / np.linalg.norm(c))
>>> e1 = np.cross(axis, [0, 0, 1.0]); e1 /= np.linalg.norm(e1); e2 = np.cross(axis, e1)
>>> phi = np.linspace(0, 2 * np.pi, 90, endpoint=False)[:, None]
>>> rays = np.cos(a) * axis + np.sin(a) * (np.cos(phi) * e1 + np.sin(phi) * e2)
>>> px = (rays[:, :2] / rays[:, 2:]) * 1000.0 + [320, 240]
>>> centre, cov, rms = fit_sphere_centre(px, K, np.zeros(5), 20.0)
>>> np.allclose(centre, c, atol=1e-6), rms < 1e-6
(True, True)
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.ndimage import map_coordinates
from scipy.optimize import least_squares

from processing.errors import InputError

__all__ = ["SphereImageError", "sphere_silhouette", "fit_sphere_centre", "pixel_rays", "sphere_radius_px",
           "MIN_RADIUS_PX"]

#: A sphere whose image is smaller than this in radius (px) is too small to find or unwrap.
MIN_RADIUS_PX = 4.0

_BORDER_PX = 4          # width of the frame border that samples the backdrop
_MIN_AREA_PX = 200      # a smaller blob is not a sphere
_PROFILE_PX = 3.0       # half-length of the profile sampled across the edge


class SphereImageError(InputError):
    """No usable sphere in a frame; the one-line message names the frame and what to do."""


def _channels(image: ArrayLike, name: str) -> NDArray[np.float64]:
    """The image as ``(H, W, C)`` float64 (C = 1 for a grey image), checked."""
    img = np.asarray(image, dtype=np.float64)
    if img.ndim == 2:
        img = img[..., None]
    if img.ndim != 3 or min(img.shape[:2]) < 4 * _BORDER_PX:
        raise SphereImageError(f"{name}: expected a 2-D (or H x W x C) image, got shape {np.shape(image)}")
    if not np.all(np.isfinite(img)):
        raise SphereImageError(f"{name}: the image has NaN or infinite pixels")
    return img


def _backdrop(img: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Robust level and noise (median, 1.4826 MAD) of the image border, per channel."""
    b = _BORDER_PX
    c = img.shape[2]
    border = np.concatenate([img[:b].reshape(-1, c), img[-b:].reshape(-1, c), img[b:-b, :b].reshape(-1, c),
                             img[b:-b, -b:].reshape(-1, c)])
    level = np.median(border, axis=0)
    return level, 1.4826 * np.median(np.abs(border - level), axis=0)


def _difference(smooth: NDArray[np.float64], level: NDArray[np.float64], noise: NDArray[np.float64]
                ) -> NDArray[np.float64]:
    """How far each pixel's colour is from the backdrop's, in units of the threshold scale (per channel).

    The scale of a channel is its border noise, but at least 5/8 % of its level (so the default
    threshold of 8 also asks for 5 % of the level).  The largest channel difference counts: a red
    sphere whose brightness equals the grey backdrop's at its terminator still differs in colour.
    """
    scale = np.maximum(np.maximum(noise, 0.05 / 8.0 * np.abs(level)), 1e-12)
    return np.max(np.abs(smooth - level) / scale, axis=2)


def _sphere_blob(diff: NDArray[np.float64], threshold_sigma: float, name: str) -> NDArray[np.uint8]:
    """The largest region differing from the backdrop, made convex (a sphere's outline is), as uint8 0/1."""
    mask = (diff > threshold_sigma).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n < 2 or stats[1:, cv2.CC_STAT_AREA].max() < _MIN_AREA_PX:
        raise SphereImageError(f"{name}: no sphere found (nothing differs from the backdrop by more than "
                               f"{threshold_sigma:g} noise units); check the exposure and that the sphere is in view")
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    pts = cv2.findNonZero((labels == k).astype(np.uint8))
    blob = np.zeros_like(mask)
    cv2.fillConvexPoly(blob, cv2.convexHull(pts), 1)     # fills the highlights and a terminator's gap
    x, y, w, h = cv2.boundingRect(blob)
    if x <= 1 or y <= 1 or x + w >= blob.shape[1] - 1 or y + h >= blob.shape[0] - 1:
        raise SphereImageError(f"{name}: the sphere is partly outside the frame; move it or the camera "
                               "so the whole sphere is in view")
    return blob


def _edge_points(smooth: NDArray[np.float64], blob: NDArray[np.uint8]) -> NDArray[np.float64]:
    """Sub-pixel edge points: the gradient maximum along each contour point's normal.

    ``smooth`` is the colour-difference image; points where the outline is invisible (the sphere's
    colour equals the backdrop's there: a weak gradient) are dropped.
    """
    contours, _ = cv2.findContours(blob, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    pts = max(contours, key=len)[:, 0, :].astype(np.float64)
    m = cv2.moments(blob, binaryImage=True)
    centre = np.array([m["m10"], m["m01"]]) / m["m00"]
    normal = pts - centre
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    t = np.arange(-_PROFILE_PX, _PROFILE_PX + 1e-9, 0.25)
    xy = pts[:, None, :] + t[None, :, None] * normal[:, None, :]
    prof = map_coordinates(smooth, [xy[..., 1].ravel(), xy[..., 0].ravel()], order=3, mode="nearest")
    grad = np.abs(np.gradient(prof.reshape(len(pts), len(t)), axis=1))
    i = np.clip(np.argmax(grad, axis=1), 1, len(t) - 2)
    g0, g1, g2 = (grad[np.arange(len(pts)), i + k] for k in (-1, 0, 1))
    den = g0 - 2 * g1 + g2
    frac = np.where(den < 0, 0.5 * (g0 - g2) / np.where(den < 0, den, -1.0), 0.0)
    peak = grad[np.arange(len(pts)), i]
    keep = (np.argmax(grad, axis=1) > 0) & (np.argmax(grad, axis=1) < len(t) - 1) & (np.abs(frac) <= 1) \
        & (peak > 0.3 * np.median(peak))
    s = t[i] + 0.25 * frac
    return (pts + s[:, None] * normal)[keep]


def sphere_silhouette(image: ArrayLike, *, name: str = "image", clip_level: float | None = None,
                      threshold_sigma: float = 8.0, smooth_px: float = 0.6) -> NDArray[np.float64]:
    """Sub-pixel points of a sphere's outline in a linear photo against a uniform backdrop.

    Parameters
    ----------
    image
        (H, W) or (H, W, C) linear image; a pixel differs from the backdrop by its largest channel
        difference (in noise units), so a coloured sphere is found where its brightness equals the
        backdrop's.
    name
        The frame's name, for the error messages.
    clip_level
        Pixel value at which the sensor clips; a clipped pixel on the outline is refused.
        ``None``: not checked.
    threshold_sigma
        A pixel belongs to the sphere when the (smoothed) image differs from the backdrop by more
        than this many times the border's noise (and by at least 5 % of the backdrop level).
    smooth_px
        Standard deviation of the Gaussian smoothing, px.

    Returns
    -------
    ndarray
        (N, 2) edge points ``(u, v)`` in px (OpenCV convention: the centre of pixel (0, 0) is (0, 0)).

    Raises
    ------
    SphereImageError
        No sphere found; the sphere touches the frame border; the outline is clipped.
    """
    img = _channels(image, name)
    smooth = np.stack([cv2.GaussianBlur(img[..., c], (0, 0), smooth_px) for c in range(img.shape[2])], axis=2) \
        if smooth_px > 0 else img
    level, noise = _backdrop(smooth)
    diff = _difference(smooth, level, noise)
    blob = _sphere_blob(diff, threshold_sigma, name)
    if clip_level is not None:
        ring = cv2.dilate(blob, np.ones((7, 7), np.uint8)) - cv2.erode(blob, np.ones((7, 7), np.uint8))
        top = img.max(axis=2)
        if np.any(top[ring > 0] >= clip_level) or np.mean(top[blob > 0] >= clip_level) > 0.5:
            raise SphereImageError(f"{name}: the sphere is saturated (pixels at the clip level {clip_level:g}); "
                                   "shoot at a shorter exposure")
    edge = _edge_points(diff, blob)
    if len(edge) < 20:
        raise SphereImageError(f"{name}: no sharp sphere outline found ({len(edge)} edge points); check the focus")
    return edge


def pixel_rays(px: ArrayLike, K: ArrayLike, dist: ArrayLike) -> NDArray[np.float64]:
    """Unit camera-frame rays through pixels, with the lens distortion removed.

    Parameters
    ----------
    px
        (N, 2) pixel positions ``(u, v)``.
    K
        (3, 3) intrinsic matrix.
    dist
        OpenCV distortion coefficients (k1, k2, p1, p2, k3) or empty / ``None``.

    Returns
    -------
    ndarray
        (N, 3) unit vectors in the camera frame (z forward).
    """
    p = np.asarray(px, dtype=np.float64).reshape(-1, 1, 2)
    d = None if dist is None else np.asarray(dist, dtype=np.float64)
    k = np.asarray(K, dtype=np.float64)
    if d is None or not np.any(d):
        xy = cv2.undistortPoints(p, k, None).reshape(-1, 2)
    else:       # iterate to convergence rather than OpenCV's default 5 steps (strong distortion)
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
        xy = cv2.undistortPoints(p, k, d, R=None, P=None, criteria=crit).reshape(-1, 2)
    rays = np.column_stack([xy, np.ones(len(xy))])
    return rays / np.linalg.norm(rays, axis=1, keepdims=True)


def _cone_residual(c: NDArray[np.float64], rays: NDArray[np.float64], radius_mm: float,
                   f_px: float) -> NDArray[np.float64]:
    """Angular miss of each ray from the grazing cone of the sphere at c, in px."""
    dist = np.linalg.norm(c)
    axis = c / dist
    ang = np.arctan2(np.linalg.norm(np.cross(rays, axis), axis=1), rays @ axis)
    return (ang - np.arcsin(min(radius_mm / dist, 1.0))) * f_px


def fit_sphere_centre(edge_px: ArrayLike, K: ArrayLike, dist: ArrayLike, radius_mm: float
                      ) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """Centre of a sphere of known radius from its outline, with the exact perspective (cone) model.

    Parameters
    ----------
    edge_px
        (N, 2) outline points in px (see :func:`sphere_silhouette`), N >= 5.
    K
        (3, 3) intrinsic matrix, px.
    dist
        OpenCV distortion coefficients.
    radius_mm
        The sphere's radius, mm.

    Returns
    -------
    centre_cam_mm : ndarray
        (3,) centre in the camera frame, mm.
    cov : ndarray
        (3, 3) covariance of the centre, mm^2, from the Jacobian and the residual variance (the outline
        points are treated as independent, so it is optimistic by the smoothing's correlation length).
    rms_px : float
        RMS distance of the outline points from the fitted cone, px.

    Raises
    ------
    SphereImageError
        Fewer than 5 points, a non-positive radius, or no sphere of that radius fits the outline (the
        radius is wrong by orders of magnitude).
    """
    pts = np.asarray(edge_px, dtype=np.float64).reshape(-1, 2)
    if len(pts) < 5 or not (np.isfinite(radius_mm) and radius_mm > 0):
        raise SphereImageError(f"sphere fit: needs >= 5 outline points and a positive radius, got {len(pts)} "
                               f"points and {radius_mm!r} mm")
    k = np.asarray(K, dtype=np.float64)
    f_px = 0.5 * (k[0, 0] + k[1, 1])
    rays = pixel_rays(pts, k, dist)
    axis = rays.mean(axis=0)
    axis /= np.linalg.norm(axis)
    half = float(np.mean(np.arccos(np.clip(rays @ axis, -1, 1))))
    x0 = axis * radius_mm / np.sin(max(half, 1e-6))
    with np.errstate(all="ignore"):     # a radius wrong by orders of magnitude: non-finite, refused below
        try:
            res = least_squares(_cone_residual, x0, args=(rays, float(radius_mm), f_px), method="lm", x_scale="jac")
        except ValueError:
            res = None
    if res is None or not (np.isfinite(res.x).all() and np.isfinite(res.fun).all()):
        raise SphereImageError(f"sphere fit: no sphere of radius {radius_mm:g} mm fits the outline; check the "
                               "sphere's radius (mm)")
    r = res.fun
    dof = max(len(r) - 3, 1)
    cov = np.linalg.pinv(res.jac.T @ res.jac) * float(r @ r) / dof
    return res.x, cov, float(np.sqrt(np.mean(r ** 2)))


def sphere_radius_px(centre_mm: ArrayLike, radius_mm: float, K: ArrayLike, image_size: tuple[int, int],
                     name: str = "image") -> float:
    """The radius in px of a fitted sphere's image, checked to lie whole in the frame and to be a few px at least.

    A sphere radius wrong by orders of magnitude still gives a centre (far away or nearly at the camera);
    this refuses it instead of unwrapping garbage.

    Parameters
    ----------
    centre_mm
        (3,) the sphere's centre in the camera frame, mm (:func:`fit_sphere_centre`).
    radius_mm
        The sphere's radius, mm.
    K
        (3, 3) intrinsic matrix of the image, px.
    image_size
        ``(width, height)`` of the image, px.
    name
        The image as the message names it.

    Returns
    -------
    float
        ``f * tan(asin(R / |c|))``: the radius of the sphere's image near the optical axis, px.

    Raises
    ------
    SphereImageError
        The sphere is behind the camera, under :data:`MIN_RADIUS_PX` in radius, or not inside the frame.

    Examples
    --------
    >>> K = np.array([[1000.0, 0, 320], [0, 1000.0, 240], [0, 0, 1]])
    >>> round(sphere_radius_px([0.0, 0.0, 500.0], 20.0, K, (640, 480)), 1)
    40.0
    """
    c = np.asarray(centre_mm, dtype=np.float64).reshape(3)
    k = np.asarray(K, dtype=np.float64)
    dist = float(np.linalg.norm(c))
    if not (np.isfinite(dist) and c[2] > radius_mm > 0 and dist > radius_mm):
        raise SphereImageError(f"{name}: a sphere of radius {radius_mm:g} mm does not fit the outline in front of the "
                               "camera; check the sphere's radius (mm)")
    r_px = 0.5 * (k[0, 0] + k[1, 1]) * float(np.tan(np.arcsin(radius_mm / dist)))
    if not r_px >= MIN_RADIUS_PX:
        raise SphereImageError(f"{name}: the sphere is {r_px:.2g} px in radius, under {MIN_RADIUS_PX:g} px; check the "
                               "sphere's radius (mm), or bring the camera closer")
    u, v = k[0, 0] * c[0] / c[2] + k[0, 2], k[1, 1] * c[1] / c[2] + k[1, 2]
    w, h = image_size
    if min(u - r_px, v - r_px) < -1.0 or u + r_px > w + 1.0 or v + r_px > h + 1.0:
        raise SphereImageError(f"{name}: a sphere of radius {radius_mm:g} mm fitted to the outline would be "
                               f"{r_px:.0f} px in radius at ({u:.0f}, {v:.0f}), not inside the {w} x {h} frame; "
                               "check the sphere's radius (mm)")
    return r_px
