"""Lamps located from a chrome sphere's highlights, in the room frame.

A chrome sphere of known radius is photographed on the turntable at several table angles.  In each
frame the sphere's centre is measured from its outline (:mod:`processing.geometry.sphere_image`), and
each lamp shows as a small bright highlight.  The camera ray d through a highlight meets the sphere at
p with normal n; by the law of reflection the ray ``r = d - 2 (d.n) n`` leaves p toward the lamp.  The
lamps are fixed in the room while the table moves the sphere, so the reflected rays of one lamp from
all frames meet at a point lamp (the least-squares point nearest all rays) or are parallel for a
distant lamp (their mean direction).  Several lamps give several highlights per frame; they are
assigned to lamps by clustering the reflected directions.

Point or distant (``model="auto"``): the distant model (2 parameters, a direction) is the point
model (3 parameters) with the point pushed to infinity, so the two are nested.  With the angular
residuals of the rays about each model, SS_d and SS_p over n rays, ``F = (SS_d - SS_p) / (SS_p /
(2 n - 3))`` follows Fisher's F(1, 2n - 3) when the lamp is distant; the lamp is a point when the
F-test rejects that at the 0.1 % level and the point lies in front of every ray, otherwise distant.

References
----------
M. W. Powell, S. Sarkar, D. Goldgof, "A simple strategy for calibrating the geometry of light
sources", IEEE Trans. Pattern Anal. Mach. Intell. 23(9), 2001 (highlights on spheres, rays
intersected).  J. Ackermann, S. Fuhrmann, M. Goesele, "Geometric point light source calibration",
Vision, Modeling and Visualization 2013 (the ray intersection compared with image-space fits).
(DOIs not verified here, so not given.)

Examples
--------
>>> lamp = Lamp("key", "distant", direction=np.array([0, 0, 1.0]), covariance=np.eye(3) * 1e-6)
>>> cal = LampCalibration([lamp], 20.0)
>>> LampCalibration.from_dict(cal.to_dict()).lamps[0].kind
'distant'
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import fdtrc

from processing.errors import InputError
from processing.geometry.sphere_image import SphereImageError, fit_sphere_centre, pixel_rays, sphere_silhouette

__all__ = ["LampCalibrationError", "Lamp", "LampCalibration", "find_highlights", "calibrate_lamps",
           "LAMP_CALIBRATION_SCHEMA", "LAMP_CALIBRATION_SCHEMA_VERSION"]

LAMP_CALIBRATION_SCHEMA = "kogei.lamp_calibration"
LAMP_CALIBRATION_SCHEMA_VERSION = 1
_EXPECTED_HIGHLIGHT_PX = 0.1    # the highlight centroid's expected error, px (sets the expected ray scatter)
_INCONSISTENT_FACTOR = 10.0     # refuse when the rays' RMS miss exceeds this many times the expected one


class LampCalibrationError(InputError):
    """The lamp calibration cannot be made; the one-line message names the frame or lamp and what to do."""


@dataclass
class Lamp:
    """One lamp, fixed in the room frame.

    Parameters
    ----------
    name
        Its name (``"lamp1"``, ...).
    kind
        ``"point"`` (``position_mm`` set) or ``"distant"`` (``direction`` set).
    position_mm
        (3,) room-frame position, mm, for a point lamp; else ``None``.
    direction
        (3,) room-frame unit vector toward the lamp, for a distant lamp; else ``None``.
    covariance
        (3, 3) covariance of the position (mm^2) or of the direction in its tangent plane (rad^2).
    spectrum
        A name :func:`processing.spectral.spectra.light_spectrum` knows, a CCT in K, or ``None`` (unknown).
    n_observations
        Number of reflected rays (highlights) used.
    rms_deg
        RMS angle between the rays and the fitted lamp, degrees.
    """

    name: str
    kind: str
    position_mm: NDArray[np.float64] | None = None
    direction: NDArray[np.float64] | None = None
    covariance: NDArray[np.float64] = field(default_factory=lambda: np.zeros((3, 3)))
    spectrum: str | float | None = None
    n_observations: int = 0
    rms_deg: float = 0.0


@dataclass
class LampCalibration:
    """The lamps of a booth and the per-frame residuals of the calibration that found them.

    Parameters
    ----------
    lamps
        The lamps (one or more).
    sphere_radius_mm
        Radius of the chrome sphere used, mm.
    frame_names
        Names of the frames used.
    sphere_rms_px
        (F,) RMS of each frame's sphere outline fit, px.
    ray_miss_deg
        (F,) largest angle between a frame's reflected rays and their lamp, degrees.
    circle_miss_mm
        (F,) distance of each frame's sphere centre from the circle the table angles predict, mm.
    """

    lamps: list[Lamp]
    sphere_radius_mm: float
    frame_names: list[str] = field(default_factory=list)
    sphere_rms_px: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    ray_miss_deg: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    circle_miss_mm: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))

    SCHEMA: ClassVar[str] = LAMP_CALIBRATION_SCHEMA
    SCHEMA_VERSION: ClassVar[int] = LAMP_CALIBRATION_SCHEMA_VERSION

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form with schema name and version.

        Returns
        -------
        dict
            ``schema``, ``version``, ``lamps`` (list of dicts), ``sphere_radius_mm`` and ``frames``.
        """
        def vec(v: NDArray[np.float64] | None) -> list[float] | None:
            return None if v is None else np.asarray(v, dtype=float).tolist()
        lamps = [{"name": lp.name, "kind": lp.kind, "position_mm": vec(lp.position_mm),
                  "direction": vec(lp.direction), "covariance": vec(lp.covariance), "spectrum": lp.spectrum,
                  "n_observations": int(lp.n_observations), "rms_deg": float(lp.rms_deg)} for lp in self.lamps]
        frames = {"names": list(self.frame_names), "sphere_rms_px": vec(self.sphere_rms_px),
                  "ray_miss_deg": vec(self.ray_miss_deg), "circle_miss_mm": vec(self.circle_miss_mm)}
        return {"schema": self.SCHEMA, "version": self.SCHEMA_VERSION, "lamps": lamps,
                "sphere_radius_mm": float(self.sphere_radius_mm), "frames": frames}

    @classmethod
    def from_dict(cls, data: Any) -> LampCalibration:
        """Inverse of :meth:`to_dict`, validating untrusted input.

        Parameters
        ----------
        data
            The dictionary read from the session's JSON.

        Returns
        -------
        LampCalibration
            The calibration.

        Raises
        ------
        LampCalibrationError
            Not an object, another schema, an unsupported version, missing or malformed fields.
        """
        if not isinstance(data, dict):
            raise LampCalibrationError(f"a lamp calibration must be a JSON object, got {type(data).__name__}")
        if data.get("schema") != cls.SCHEMA:
            raise LampCalibrationError(f"not a lamp calibration: schema is {data.get('schema')!r}, "
                                       f"expected {cls.SCHEMA!r}")
        version = data.get("version")
        if not isinstance(version, int) or isinstance(version, bool) or not 1 <= version <= cls.SCHEMA_VERSION:
            raise LampCalibrationError(f"lamp calibration version {version!r} is not supported (this program "
                                       f"reads versions 1..{cls.SCHEMA_VERSION}); update kogei")
        lamps = data.get("lamps")
        if not isinstance(lamps, list) or not lamps:
            raise LampCalibrationError("lamp calibration 'lamps' must be a non-empty list")
        radius = _number(data.get("sphere_radius_mm"), "sphere_radius_mm")
        if radius <= 0:
            raise LampCalibrationError(f"lamp calibration 'sphere_radius_mm' must be positive, got {radius}")
        frames = data.get("frames", {})
        if not isinstance(frames, dict):
            raise LampCalibrationError("lamp calibration 'frames' must be an object")
        names = frames.get("names", [])
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise LampCalibrationError("lamp calibration 'frames.names' must be a list of strings")
        arrays = [_array(frames.get(k, []), (len(names),), f"frames.{k}")
                  for k in ("sphere_rms_px", "ray_miss_deg", "circle_miss_mm")]
        parsed = [_lamp_from_dict(d, i) for i, d in enumerate(lamps)]
        if len({lp.name for lp in parsed}) != len(parsed):
            raise LampCalibrationError("lamp calibration: two lamps have the same name; name each lamp once")
        return cls(parsed, radius, names, *arrays)


def _number(v: Any, what: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
        raise LampCalibrationError(f"lamp calibration '{what}' must be a finite number, got {v!r}")
    return float(v)


def _array(v: Any, shape: tuple[int, ...], what: str) -> NDArray[np.float64]:
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise LampCalibrationError(f"lamp calibration '{what}' must be numbers, got {v!r}") from None
    if a.shape != shape or not np.all(np.isfinite(a)):
        raise LampCalibrationError(f"lamp calibration '{what}' must be {shape} finite numbers, got shape {a.shape}")
    return a


def _lamp_from_dict(d: Any, i: int) -> Lamp:
    if not isinstance(d, dict) or d.get("kind") not in ("point", "distant"):
        raise LampCalibrationError(f"lamp calibration lamp #{i + 1}: must be an object with kind 'point' or 'distant'")
    name = d.get("name")
    if not isinstance(name, str) or not name:
        raise LampCalibrationError(f"lamp calibration lamp #{i + 1}: 'name' must be a non-empty string")
    spectrum = d.get("spectrum")
    if spectrum is not None and (isinstance(spectrum, bool) or not isinstance(spectrum, (str, int, float))):
        raise LampCalibrationError(f"lamp {name!r}: 'spectrum' must be a name, a CCT in K or null")
    pos = _array(d.get("position_mm"), (3,), f"{name}.position_mm") if d["kind"] == "point" else None
    direction = None
    if d["kind"] == "distant":
        direction = _array(d.get("direction"), (3,), f"{name}.direction")
        if abs(np.linalg.norm(direction) - 1) > 1e-6:
            raise LampCalibrationError(f"lamp {name!r}: 'direction' must be a unit vector")
    n_obs = d.get("n_observations", 0)
    if isinstance(n_obs, bool) or not isinstance(n_obs, int) or n_obs < 0:
        raise LampCalibrationError(f"lamp {name!r}: 'n_observations' must be a non-negative integer")
    cov = _array(d.get("covariance"), (3, 3), f"{name}.covariance")
    if not np.allclose(cov, cov.T, rtol=1e-9, atol=1e-12 * max(1.0, float(np.abs(cov).max()))) \
            or np.linalg.eigvalsh(0.5 * (cov + cov.T)).min() < -1e-9 * max(1.0, float(np.abs(cov).max())):
        raise LampCalibrationError(f"lamp {name!r}: 'covariance' must be symmetric positive semi-definite")
    return Lamp(name, d["kind"], pos, direction, cov, spectrum, n_obs, _number(d.get("rms_deg", 0.0), f"{name}.rms_deg"))


# ---------------------------------------------------------------------------- highlights
def _region(shape: tuple[int, int], sphere: Any, name: str) -> NDArray[np.bool_]:
    arr = np.asarray(sphere)
    if arr.shape == shape:
        return arr.astype(bool)
    if arr.shape != (3,):
        raise LampCalibrationError(f"{name}: the sphere must be a mask of the image's shape or (u, v, r_px)")
    vv, uu = np.mgrid[0:shape[0], 0:shape[1]]
    return (uu - arr[0]) ** 2 + (vv - arr[1]) ** 2 <= arr[2] ** 2


def find_highlights(image: ArrayLike, sphere_mask_or_circle: Any, *, clip_level: float | None = None,
                    name: str = "image", threshold_sigma: float = 10.0) -> NDArray[np.float64]:
    """Intensity-weighted centroids of the lamps' highlights on a chrome sphere.

    Parameters
    ----------
    image
        (H, W) or (H, W, C) linear image.
    sphere_mask_or_circle
        (H, W) boolean mask of the sphere, or its circle ``(u, v, r_px)``.
    clip_level
        Pixel value at which the sensor clips; a clipped highlight is refused.  ``None``: not checked.
    name
        The frame's name, for the error messages.
    threshold_sigma
        A highlight pixel exceeds the sphere's median by this many times its noise and by half the median.

    Returns
    -------
    ndarray
        (M, 2) centroids ``(u, v)`` in px, brightest first; separate blobs are separate lamps.

    Raises
    ------
    LampCalibrationError
        No highlight; a clipped highlight.
    """
    img = np.asarray(image, dtype=np.float64)
    img = img.mean(axis=2) if img.ndim == 3 else img
    region = _region(img.shape, sphere_mask_or_circle, name)
    inside = img[region]
    if inside.size < 10:
        raise LampCalibrationError(f"{name}: the sphere region is empty")
    med = float(np.median(inside))
    noise = float(1.4826 * np.median(np.abs(inside - med)))
    bright = region & (img > med + max(threshold_sigma * noise, 0.5 * abs(med)))
    if not bright.any():
        raise LampCalibrationError(f"{name}: no highlight on the sphere; is the lamp on and its reflection in view?")
    grown = cv2.dilate(bright.astype(np.uint8), np.ones((5, 5), np.uint8)) & region
    n, labels = cv2.connectedComponents(grown.astype(np.uint8), connectivity=8)
    if clip_level is not None and np.any(img[grown > 0] >= clip_level):
        raise LampCalibrationError(f"{name}: saturated highlight: shoot the lamp calibration at a shorter exposure")
    w = np.clip(img - med, 0, None) * (labels > 0)
    idx = np.arange(1, n)
    vv, uu = np.mgrid[0:img.shape[0], 0:img.shape[1]]
    s = np.bincount(labels.ravel(), w.ravel(), n)[1:]
    su = np.bincount(labels.ravel(), (w * uu).ravel(), n)[1:]
    sv = np.bincount(labels.ravel(), (w * vv).ravel(), n)[1:]
    order = np.argsort(-s)
    return np.column_stack([su / s, sv / s])[order][s[order] > 0] if len(idx) else np.zeros((0, 2))


# ---------------------------------------------------------------------------- reflected rays
def _reflected_rays(px: NDArray[np.float64], centre: NDArray[np.float64], radius_mm: float, K: ArrayLike,
                    dist: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Camera-frame points on the sphere and unit mirror directions for highlight pixels."""
    d = pixel_rays(px, K, dist)
    b = d @ centre
    disc = np.clip(b * b - (centre @ centre - radius_mm ** 2), 0, None)   # a grazing ray touches the limb
    p = (b - np.sqrt(disc))[:, None] * d
    n = (p - centre) / radius_mm
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    r = d - 2 * np.sum(d * n, axis=1, keepdims=True) * n
    return p, r / np.linalg.norm(r, axis=1, keepdims=True)


def _fit_point(p: NDArray[np.float64], r: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Least-squares point nearest all rays (p + t r) and its covariance (mm^2)."""
    proj = np.eye(3)[None] - r[:, :, None] * r[:, None, :]
    a = proj.sum(axis=0)
    x = np.linalg.solve(a, np.einsum("nij,nj->i", proj, p))
    miss = np.einsum("nij,nj->ni", proj, x - p)
    s2 = float(np.sum(miss ** 2)) / max(2 * len(p) - 3, 1)
    return x, s2 * np.linalg.inv(a)


def _angles(r: NDArray[np.float64], toward: NDArray[np.float64]) -> NDArray[np.float64]:
    u = toward / np.linalg.norm(toward, axis=-1, keepdims=True)
    return np.arctan2(np.linalg.norm(np.cross(r, u), axis=-1), np.sum(r * u, axis=-1))


def _fit_lamp(p: NDArray[np.float64], r: NDArray[np.float64], model: str, name: str) -> tuple[Lamp, NDArray]:
    """A point or distant lamp from its reflected rays (room frame), and each ray's miss angle (rad)."""
    m = r.sum(axis=0)
    m /= np.linalg.norm(m)
    miss_d = _angles(r, m[None])
    e = r - (r @ m)[:, None] * m
    cov_d = e.T @ e / max(len(r) * (len(r) - 1), 1)
    x, cov_p = _fit_point(p, r)
    miss_p = _angles(r, x - p)
    ahead = bool(np.all(np.sum((x - p) * r, axis=1) > 0))
    ss_d, ss_p, dof = float(miss_d @ miss_d), float(miss_p @ miss_p), 2 * len(r) - 3
    f_stat = (ss_d - ss_p) / max(ss_p / dof, 1e-300)
    point = model == "point" or (model == "auto" and ahead and fdtrc(1, dof, f_stat) < 1e-3)
    if point:
        return Lamp(name, "point", position_mm=x, covariance=cov_p, n_observations=len(r),
                    rms_deg=float(np.degrees(np.sqrt(np.mean(miss_p ** 2))))), miss_p
    return Lamp(name, "distant", direction=m, covariance=cov_d, n_observations=len(r),
                rms_deg=float(np.degrees(np.sqrt(np.mean(miss_d ** 2))))), miss_d


def _cluster(r: NDArray[np.float64], view: NDArray[np.int64], n_lamps: int) -> NDArray[np.int64]:
    """Lamp index of each reflected direction: k-means on the unit sphere seeded by a frame with all lamps."""
    counts = np.bincount(view)
    if counts.max() < n_lamps:
        raise LampCalibrationError(f"no frame shows {n_lamps} highlights (at most {counts.max()}); "
                                   "give the number of lamps the frames show")
    seed_view = int(np.flatnonzero(counts >= n_lamps)[0])
    centres = r[view == seed_view][:n_lamps]
    label = np.zeros(len(r), dtype=np.int64)
    for _ in range(10):
        label = np.argmax(r @ centres.T, axis=1)
        new = np.array([r[label == k].sum(axis=0) if np.any(label == k) else centres[k] for k in range(n_lamps)])
        centres = new / np.linalg.norm(new, axis=1, keepdims=True)
    return label


def _measure_view(name: str, image: ArrayLike, K: ArrayLike, dist: ArrayLike, radius_mm: float,
                  clip_level: float | None) -> tuple[NDArray, float, NDArray, NDArray]:
    """Sphere centre (camera, mm), outline RMS (px), highlight points on the sphere and mirror rays (camera)."""
    try:
        edge = sphere_silhouette(image, name=name, clip_level=None)
        centre, _, rms = fit_sphere_centre(edge, K, dist, radius_mm)
    except SphereImageError as exc:
        raise LampCalibrationError(f"sphere not found in frame {name}: {exc}") from None
    middle = edge.mean(axis=0)
    r_px = float(np.mean(np.linalg.norm(edge - middle, axis=1)))
    hl = find_highlights(image, (middle[0], middle[1], r_px - 2.0), clip_level=clip_level, name=name)
    p, r = _reflected_rays(hl, centre, radius_mm, K, dist)
    return centre, rms, p, r


def calibrate_lamps(views: list[tuple[str, float, ArrayLike]], K: ArrayLike, dist: ArrayLike,
                    room_to_camera: ArrayLike, sphere_radius_mm: float, *, model: str = "auto",
                    n_lamps: int | None = None, clip_level: float | None = None) -> LampCalibration:
    """Locate the booth's lamps from a chrome sphere photographed at several table angles.

    Parameters
    ----------
    views
        ``(name, table_angle_deg, image)`` per frame, at least 3, linear images.
    K
        (3, 3) intrinsics, px.
    dist
        OpenCV distortion coefficients.
    room_to_camera
        (4, 4) rigid transform, ``X_cam = R @ X_room + t``.
    sphere_radius_mm
        The chrome sphere's radius, mm.
    model
        ``"point"``, ``"distant"`` or ``"auto"`` (the F-test of the module's description).
    n_lamps
        Number of lamps; ``None``: the largest number of highlights in a frame.
    clip_level
        Pixel value at which the sensor clips; clipped highlights are refused.

    Returns
    -------
    LampCalibration
        The lamps (room frame; ``spectrum`` left ``None`` for the caller) and per-frame residuals.

    Raises
    ------
    LampCalibrationError
        Fewer than 3 frames; the sphere not found in a frame; no or clipped highlight; a lamp seen in
        fewer than 3 frames; rays that miss their lamp far more than their expected scatter.
    """
    if len(views) < 3:
        raise LampCalibrationError(f"lamp calibration needs at least 3 frames of the chrome sphere, got {len(views)}")
    if model not in ("auto", "point", "distant"):
        raise LampCalibrationError(f"lamp model must be 'auto', 'point' or 'distant', got {model!r}")
    m = np.asarray(room_to_camera, dtype=np.float64)
    rot, tr = m[:3, :3], m[:3, 3]
    names, rms, centres, ps, rs, view = [], [], [], [], [], []
    for i, (name, _angle, image) in enumerate(views):
        c, s, p, r = _measure_view(str(name), image, K, dist, float(sphere_radius_mm), clip_level)
        names.append(str(name))
        rms.append(s)
        centres.append(rot.T @ (c - tr))
        ps.append((p - tr) @ rot)
        rs.append(r @ rot)
        view += [i] * len(p)
    p, r, view = np.concatenate(ps), np.concatenate(rs), np.asarray(view)
    k = int(n_lamps) if n_lamps else int(np.bincount(view).max())
    label = _cluster(r, view, k) if k > 1 else np.zeros(len(r), dtype=np.int64)
    lamps, miss = [], np.zeros(len(r))
    depth = float(np.mean([np.linalg.norm(rot @ c + tr) for c in centres]))
    expected = 2 * _EXPECTED_HIGHLIGHT_PX * depth / float(np.asarray(K)[0, 0]) / float(sphere_radius_mm)
    for j in range(k):
        sel = label == j
        if len(np.unique(view[sel])) < 3:
            raise LampCalibrationError(f"lamp{j + 1} is seen in only {len(np.unique(view[sel]))} frame(s); "
                                       "need 3: shoot more table angles")
        lamp, miss[sel] = _fit_lamp(p[sel], r[sel], model, f"lamp{j + 1}")
        if np.radians(lamp.rms_deg) > _INCONSISTENT_FACTOR * expected:
            raise LampCalibrationError(f"lamp calibration: the rays of {lamp.name} miss it by {lamp.rms_deg:.3g} deg "
                                       f"RMS, expected about {np.degrees(expected):.2g} deg; did a lamp, the camera "
                                       "or the sphere move during the series?")
        lamps.append(lamp)
    ray_miss = np.degrees(np.array([miss[view == i].max() for i in range(len(views))]))
    return LampCalibration(lamps, float(sphere_radius_mm), names, np.asarray(rms), ray_miss,
                           _circle_miss(np.asarray(centres), [float(v[1]) for v in views]))


def _circle_miss(centres: NDArray[np.float64], angles_deg: list[float]) -> NDArray[np.float64]:
    """Distance of each room-frame sphere centre from ``Rz(theta) c0`` with c0 fitted (mm)."""
    a = np.radians(np.asarray(angles_deg))
    c, s = np.cos(a), np.sin(a)
    back = np.column_stack([c * centres[:, 0] + s * centres[:, 1], -s * centres[:, 0] + c * centres[:, 1],
                            centres[:, 2]])
    c0 = back.mean(axis=0)
    return np.linalg.norm(back - c0, axis=1)
