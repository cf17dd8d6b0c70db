"""A calibrated camera: OpenCV intrinsics, lens distortion and a pose on the mesh.

:class:`CalibratedCamera` is the camera of a posed photo (a
:class:`processing.appearance.frame_poses.FramePose`): the camera matrix
``K``, the distortion ``(k1, k2, p1, p2, k3)``, ``mesh_to_camera`` (4 x 4,
OpenCV axes: x right, y down, z forward) and the image size.  It offers the
interface the renderer uses of :class:`render.camera.Camera` (``eye``,
``basis``, ``width``, ``height``, ``sample_offsets``, ``rays``,
``pixel_rays``, ``project``), so :func:`render.renderer.render` draws the
scene exactly as that photo saw it.

Pixel conventions: OpenCV puts the centre of pixel (0, 0) at (0, 0); the
renderer's sample offsets lie in [0, 1)^2 of a pixel (0.5 = centre), so a
sample ``(x + ox, y + oy)`` is the OpenCV image point ``(x + ox - 0.5,
y + oy - 0.5)``.  Ray directions through distorted image points come from
inverting the distortion with ``cv2.undistortPoints`` (iterated to 1e-9);
:meth:`CalibratedCamera.project` returns the renderer's convention (pixel
centres at half-integers), :meth:`CalibratedCamera.project_px` OpenCV's.

References
----------
Brown, D. C. (1966). Decentering distortion of lenses. Photogrammetric
Engineering 32(3), 444-462 (no DOI).

Zhang, Z. (2000). A flexible new technique for camera calibration. IEEE
TPAMI 22(11), 1330-1334. doi:10.1109/34.888718

Examples
--------
>>> import numpy as np
>>> cam = CalibratedCamera([[100, 0, 31.5], [0, 100, 23.5], [0, 0, 1]], np.zeros(5), np.eye(4), 64, 48)
>>> rays = cam.rays(0, 64, 0, 48)
>>> rays.shape, np.round(cam.project_px([[0.0, 0.0, 10.0]]), 6).tolist()
((3072, 6), [[31.5, 23.5]])
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from render.camera import Camera
from render.errors import RenderInputError

__all__ = ["CalibratedCamera"]

_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 1e-10)


def _matrix(value: ArrayLike, shape: tuple[int, ...], name: str) -> NDArray[np.float64]:
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        arr = np.array([np.nan])
    if arr.size == int(np.prod(shape)):
        arr = arr.reshape(shape)
    if arr.shape != shape or not np.all(np.isfinite(arr)):
        raise RenderInputError(f"calibrated camera {name}: give finite numbers of shape {shape}, got {value!r}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class CalibratedCamera:
    """A calibrated (OpenCV) camera posed in the scene's frame.

    Parameters
    ----------
    K
        ``(3, 3)`` camera matrix (pixels; centre of pixel (0, 0) at (0, 0)); a skew
        ``K[0, 1]`` is ignored, as OpenCV's projection does.
    dist
        ``(5,)`` distortion ``(k1, k2, p1, p2, k3)``.
    mesh_to_camera
        ``(4, 4)`` rigid transform from the scene (mesh) frame to the camera
        frame (x right, y down, z forward), millimetres.
    width, height
        Image size in pixels.

    Raises
    ------
    RenderInputError
        Non-finite or misshapen matrices, a non-rigid pose, a bad focal
        length, a non-positive image size.
    """

    K: NDArray[np.float64] = field(repr=False)
    dist: NDArray[np.float64] = field(repr=False)
    mesh_to_camera: NDArray[np.float64] = field(repr=False)
    width: int
    height: int

    def __post_init__(self) -> None:
        k = _matrix(self.K, (3, 3), "K")
        if not (k[0, 0] > 0 and k[1, 1] > 0) or not np.allclose(k[2], [0, 0, 1]):
            raise RenderInputError("calibrated camera K: focal lengths must be > 0 and the last row (0, 0, 1)")
        m = _matrix(self.mesh_to_camera, (4, 4), "mesh_to_camera")
        if not np.allclose(m[3], [0, 0, 0, 1]) or not np.allclose(m[:3, :3] @ m[:3, :3].T, np.eye(3), atol=1e-6):
            raise RenderInputError("calibrated camera mesh_to_camera: give a rigid 4 x 4 transform (rotation, "
                                   "translation, last row 0 0 0 1)")
        for name in ("width", "height"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise RenderInputError(f"calibrated camera {name} must be a positive whole number of pixels, got {v!r}")
            object.__setattr__(self, name, int(v))
        object.__setattr__(self, "K", k)
        object.__setattr__(self, "dist", _matrix(self.dist, (5,), "dist"))
        object.__setattr__(self, "mesh_to_camera", m)

    @classmethod
    def from_frame(cls, frame_pose: Any) -> CalibratedCamera:
        """The camera of a posed frame (``K``, ``dist``, ``mesh_to_camera``, ``image_size``).

        Parameters
        ----------
        frame_pose
            A :class:`processing.appearance.frame_poses.FramePose`.

        Returns
        -------
        CalibratedCamera
        """
        w, h = frame_pose.image_size
        return cls(frame_pose.K, frame_pose.dist, frame_pose.mesh_to_camera, int(w), int(h))

    # ------------------------------------------------------------------ geometry
    @property
    def eye(self) -> tuple[float, float, float]:
        """The camera centre in the scene frame (mm)."""
        r, t = self.mesh_to_camera[:3, :3], self.mesh_to_camera[:3, 3]
        return tuple((-r.T @ t).tolist())

    def basis(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Unit ``(right, up, forward)`` of the camera in the scene frame (as :meth:`render.camera.Camera.basis`).

        Returns
        -------
        tuple of ndarray
            Three ``(3,)`` vectors.
        """
        r = self.mesh_to_camera[:3, :3]
        return r[0].copy(), -r[1], r[2].copy()

    @property
    def aspect(self) -> float:
        """Width over height."""
        return self.width / self.height

    def project_px(self, points: ArrayLike) -> NDArray[np.float64]:
        """OpenCV pixel positions (centre of pixel (0, 0) at (0, 0)) of scene points; NaN behind the camera.

        Parameters
        ----------
        points
            ``(..., 3)`` positions in the scene frame (mm).

        Returns
        -------
        ndarray
            ``(..., 2)`` column and row, the numbers ``cv2.projectPoints`` gives.
        """
        p = np.asarray(points, dtype=np.float64)
        x = p.reshape(-1, 3) @ self.mesh_to_camera[:3, :3].T + self.mesh_to_camera[:3, 3]
        k1, k2, p1, p2, k3 = self.dist
        z = np.where(x[:, 2] > 1e-12, x[:, 2], np.nan)
        a, b = x[:, 0] / z, x[:, 1] / z
        r2 = a * a + b * b
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = a * radial + 2.0 * p1 * a * b + p2 * (r2 + 2.0 * a * a)
        yd = b * radial + p1 * (r2 + 2.0 * b * b) + 2.0 * p2 * a * b
        uv = np.stack([self.K[0, 0] * xd + self.K[0, 2], self.K[1, 1] * yd + self.K[1, 2]], axis=1)
        return uv.reshape(p.shape[:-1] + (2,))

    def project(self, points: ArrayLike) -> NDArray[np.float64]:
        """Image coordinates in the renderer's convention (pixel centres at half-integers); NaN behind.

        Parameters
        ----------
        points
            ``(..., 3)`` positions in the scene frame (mm).

        Returns
        -------
        ndarray
            ``(..., 2)``: :meth:`project_px` + 0.5.
        """
        return self.project_px(points) + 0.5

    def directions(self, u_px: ArrayLike, v_px: ArrayLike) -> NDArray[np.float64]:
        """Unit ray directions in the camera frame through OpenCV image points (distortion inverted).

        Parameters
        ----------
        u_px, v_px
            Columns and rows (centre of pixel (0, 0) at (0, 0)), same shape.

        Returns
        -------
        ndarray
            ``(N, 3)`` float64 unit vectors (z > 0), flattened in input order.
        """
        pts = np.stack([np.asarray(u_px, dtype=np.float64).ravel(), np.asarray(v_px, dtype=np.float64).ravel()], 1)
        if np.any(self.dist != 0):
            ab = cv2.undistortPoints(pts.reshape(-1, 1, 2), self.K, self.dist, None, None, None,
                                     _UNDISTORT_CRITERIA).reshape(-1, 2)
        else:
            ab = np.stack([(pts[:, 0] - self.K[0, 2]) / self.K[0, 0], (pts[:, 1] - self.K[1, 2]) / self.K[1, 1]], 1)
        d = np.concatenate([ab, np.ones((len(ab), 1))], axis=1)
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    # ------------------------------------------------------------------ rays
    def sample_offsets(self, n_pixels: int, samples: int, rng: np.random.Generator | None,
                       jitter: bool = True) -> NDArray[np.float32]:
        """Sub-pixel sample positions in [0, 1)^2, exactly as :meth:`render.camera.Camera.sample_offsets`.

        Parameters
        ----------
        n_pixels, samples, rng, jitter
            As :meth:`render.camera.Camera.sample_offsets`.

        Returns
        -------
        ndarray
            float32 ``(n_pixels, samples, 2)``.
        """
        return Camera.sample_offsets(self, n_pixels, samples, rng, jitter)  # type: ignore[arg-type]

    def rays(self, x0: int, x1: int, y0: int, y1: int, samples: int = 1, rng: np.random.Generator | None = None,
             jitter: bool = True) -> NDArray[np.float32]:
        """Primary rays of the pixel block ``[x0, x1) x [y0, y1)`` (as :meth:`render.camera.Camera.rays`).

        Parameters
        ----------
        x0, x1, y0, y1
            The block's columns and rows.
        samples, rng, jitter
            As :meth:`sample_offsets`.

        Returns
        -------
        ndarray
            float32 ``(n, 6)`` rows ``(ox, oy, oz, dx, dy, dz)`` in the scene
            frame, unit directions, ordered by row, column, sample.
        """
        if not (0 <= x0 < x1 <= self.width and 0 <= y0 < y1 <= self.height):
            raise RenderInputError(f"pixel block x[{x0}, {x1}) y[{y0}, {y1}) is outside the "
                                   f"{self.width}x{self.height} image")
        yy, xx = np.meshgrid(np.arange(y0, y1), np.arange(x0, x1), indexing="ij")
        return self.pixel_rays(xx.ravel(), yy.ravel(), samples, rng, jitter)

    def pixel_rays(self, xs: NDArray[np.integer], ys: NDArray[np.integer], samples: int = 1,
                   rng: np.random.Generator | None = None, jitter: bool = True) -> NDArray[np.float32]:
        """Primary rays of the pixels ``(xs[i], ys[i])`` (as :meth:`render.camera.Camera.pixel_rays`).

        Parameters
        ----------
        xs, ys
            Columns and rows of the pixels (same length).
        samples, rng, jitter
            As :meth:`sample_offsets`.

        Returns
        -------
        ndarray
            float32 ``(len(xs) * samples, 6)``, ordered by pixel, then sample.
        """
        xs, ys = np.asarray(xs).ravel(), np.asarray(ys).ravel()
        if xs.shape != ys.shape:
            raise RenderInputError(f"pixel_rays: xs and ys must have the same length, got {xs.size} and {ys.size}")
        if xs.size and (xs.min() < 0 or xs.max() >= self.width or ys.min() < 0 or ys.max() >= self.height):
            raise RenderInputError(f"pixel_rays: pixels outside the {self.width}x{self.height} image")
        off = self.sample_offsets(xs.size, samples, rng, jitter).astype(np.float64)
        u = xs[:, None] + off[:, :, 0] - 0.5
        v = ys[:, None] + off[:, :, 1] - 0.5
        d = self.directions(u, v) @ self.mesh_to_camera[:3, :3]
        out = np.empty((len(d), 6), dtype=np.float32)
        out[:, :3] = np.asarray(self.eye, dtype=np.float32)
        out[:, 3:] = d
        return out
