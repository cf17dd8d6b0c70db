"""Projection of mesh points into a frame and ray casting of the mesh through a frame's pixels.

Both follow OpenCV's camera model (pinhole plus the 5-coefficient
distortion): :func:`project_points` is the vectorised forward model
(the same numbers as ``cv2.projectPoints``); :func:`pixel_rays` inverts it
with ``cv2.undistortPoints``; :func:`depth_map` casts those rays into an
Open3D ``RaycastingScene``.

References
----------
Brown, D. C. (1966). Decentering distortion of lenses. Photogrammetric
Engineering 32(3), 444-462.

Wald, I., Woop, S., Benthin, C., Johnson, G. S., Ernst, M. (2014). Embree: a
kernel framework for efficient CPU ray tracing. ACM TOG 33(4), 143.
doi:10.1145/2601097.2601199
"""

from __future__ import annotations

import functools
from typing import Any

import cv2
import numpy as np
import open3d as o3d
from numpy.typing import ArrayLike, NDArray

from processing.appearance.frame_poses import AppearanceError, FramePose

__all__ = ["mesh_arrays", "raycasting_scene", "project_points", "binned_intrinsics", "pixel_rays", "depth_map"]


def mesh_arrays(mesh: Any) -> tuple[NDArray[np.float64], NDArray[np.int32], NDArray[np.float64]]:
    """Vertices, triangles and unit vertex normals of a mesh, validated.

    Parameters
    ----------
    mesh
        An Open3D legacy ``TriangleMesh`` (its vertex normals are used when
        present, else computed) or a tuple ``(vertices, triangles[, normals])``.

    Returns
    -------
    vertices, triangles, normals
        ``(N, 3)`` float64, ``(F, 3)`` int32, ``(N, 3)`` float64.
    """
    if isinstance(mesh, o3d.geometry.TriangleMesh):
        if not mesh.has_vertex_normals():
            mesh = o3d.geometry.TriangleMesh(mesh)
            mesh.compute_vertex_normals()
        v, f, n = np.asarray(mesh.vertices), np.asarray(mesh.triangles), np.asarray(mesh.vertex_normals)
    elif isinstance(mesh, (tuple, list)) and len(mesh) in (2, 3):
        v, f = np.asarray(mesh[0], dtype=np.float64), np.asarray(mesh[1])
        n = np.asarray(mesh[2], dtype=np.float64) if len(mesh) == 3 else None
        if n is None:
            m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(f.astype(np.int32)))
            n = np.asarray(m.compute_vertex_normals().vertex_normals)
    else:
        raise AppearanceError("mesh: give an Open3D TriangleMesh or (vertices, triangles[, normals])")
    v, f, n = np.asarray(v, dtype=np.float64), np.asarray(f), np.asarray(n, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0 or not np.all(np.isfinite(v)):
        raise AppearanceError("mesh vertices: give a non-empty finite (N, 3) array")
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0 or f.min() < 0 or f.max() >= len(v):
        raise AppearanceError("mesh triangles: give a non-empty (F, 3) array of vertex indices")
    if n.shape != v.shape or not np.all(np.isfinite(n)):
        raise AppearanceError("mesh normals: give finite (N, 3) vertex normals")
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return v, f.astype(np.int32), n / np.where(norm > 0, norm, 1.0)


def raycasting_scene(vertices: ArrayLike, triangles: ArrayLike) -> o3d.t.geometry.RaycastingScene:
    """An Open3D ray casting scene of one triangle mesh (float32, build once per mesh).

    Parameters
    ----------
    vertices
        ``(N, 3)`` mm.
    triangles
        ``(F, 3)`` vertex indices.

    Returns
    -------
    open3d.t.geometry.RaycastingScene
    """
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(vertices, dtype=np.float32)),
                        o3d.core.Tensor(np.ascontiguousarray(triangles, dtype=np.uint32)))
    return scene


def project_points(points: ArrayLike, frame: FramePose) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Pixel positions and camera depths of points of M in one frame (OpenCV model, vectorised).

    Points behind the camera or so far off-axis that the distortion
    polynomial folds back (normalised radius beyond 1.5 x the image corners')
    get NaN pixel positions.

    Parameters
    ----------
    points
        ``(N, 3)`` points in M, mm.
    frame
        The frame's pose and camera.

    Returns
    -------
    uv_px, depth_mm
        ``(N, 2)`` pixel (column, row) and ``(N,)`` camera z.

    Examples
    --------
    >>> import numpy as np
    >>> f = FramePose("f", 1, 0.0, (4, 4), [[2, 0, 1.5], [0, 2, 1.5], [0, 0, 1]], np.zeros(5), np.eye(4))
    >>> project_points([[0.0, 0.0, 2.0], [1.0, 0.0, 2.0]], f)[0].tolist()
    [[1.5, 1.5], [2.5, 1.5]]
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    m = frame.mesh_to_camera
    x = p @ m[:3, :3].T + m[:3, 3]
    z = x[:, 2]
    k1, k2, p1, p2, k3 = frame.dist
    k = frame.K
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        a, b = x[:, 0] / z, x[:, 1] / z
        r2 = a * a + b * b
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = a * radial + 2.0 * p1 * a * b + p2 * (r2 + 2.0 * a * a)
        yd = b * radial + p1 * (r2 + 2.0 * b * b) + 2.0 * p2 * a * b
        uv = np.stack([k[0, 0] * xd + k[0, 2], k[1, 1] * yd + k[1, 2]], axis=1)
        bad = ~(z > 1e-9) | ~(r2 <= (1.5 ** 2) * _corner_radius2(frame))
    uv[bad] = np.nan
    return uv, z


def _corner_radius2(frame: FramePose) -> float:
    return _corner_radius2_cached(frame.K.tobytes(), frame.dist.tobytes(), frame.image_size)


@functools.lru_cache(maxsize=32)
def _corner_radius2_cached(k_bytes: bytes, dist_bytes: bytes, size: tuple[int, int]) -> float:
    k = np.frombuffer(k_bytes).reshape(3, 3)
    dist = np.frombuffer(dist_bytes)
    w, h = size
    corners = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5]], dtype=np.float64)
    und = cv2.undistortPoints(corners.reshape(-1, 1, 2), k, dist).reshape(-1, 2)
    return float(np.max(np.sum(und ** 2, axis=1)))


def binned_intrinsics(K: ArrayLike, binning: int) -> NDArray[np.float64]:
    """Intrinsics of a frame binned ``binning`` x ``binning`` (the brief's convention).

    Parameters
    ----------
    K
        ``(3, 3)`` intrinsics at full resolution.
    binning
        Whole binning factor >= 1.

    Returns
    -------
    ndarray
        ``(3, 3)``: ``fx/b, fy/b, (cx + 0.5)/b - 0.5, (cy + 0.5)/b - 0.5``.
    """
    k = np.array(K, dtype=np.float64)
    b = float(binning)
    return np.array([[k[0, 0] / b, 0.0, (k[0, 2] + 0.5) / b - 0.5], [0.0, k[1, 1] / b, (k[1, 2] + 0.5) / b - 0.5],
                     [0.0, 0.0, 1.0]])


def pixel_rays(frame: FramePose, binning: int = 1) -> NDArray[np.float32]:
    """Unit ray directions in the camera frame through the pixel centres of a (binned) grid.

    Parameters
    ----------
    frame
        The frame (its K, distortion and image size are used).
    binning
        Grid step in full-resolution pixels; the grid is
        ``(ceil(h/b), ceil(w/b))`` with :func:`binned_intrinsics`.

    Returns
    -------
    ndarray
        ``(rows, cols, 3)`` float32, cached per camera.
    """
    return _pixel_rays_cached(frame.K.tobytes(), frame.dist.tobytes(), frame.image_size, int(binning))


@functools.lru_cache(maxsize=4)
def _pixel_rays_cached(k_bytes: bytes, dist_bytes: bytes, size: tuple[int, int], binning: int) -> NDArray[np.float32]:
    k = binned_intrinsics(np.frombuffer(k_bytes).reshape(3, 3), binning)
    dist = np.frombuffer(dist_bytes)
    cols, rows = -(-size[0] // binning), -(-size[1] // binning)
    uu, vv = np.meshgrid(np.arange(cols, dtype=np.float64), np.arange(rows, dtype=np.float64))
    pts = np.stack([uu.ravel(), vv.ravel()], axis=1)
    if np.any(dist != 0):
        ab = cv2.undistortPoints(pts.reshape(-1, 1, 2), k, dist, None, None, None,
                                 (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 1e-9)).reshape(-1, 2)
    else:
        ab = np.stack([(pts[:, 0] - k[0, 2]) / k[0, 0], (pts[:, 1] - k[1, 2]) / k[1, 1]], axis=1)
    d = np.concatenate([ab, np.ones((len(ab), 1))], axis=1)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    out = d.astype(np.float32).reshape(rows, cols, 3)
    out.setflags(write=False)
    return out


def depth_map(scene: o3d.t.geometry.RaycastingScene, frame: FramePose, binning: int = 1) -> NDArray[np.float32]:
    """Camera depth (z, mm) of the first mesh hit through each pixel of a (binned) grid; inf where none.

    Parameters
    ----------
    scene
        :func:`raycasting_scene` of the mesh in M.
    frame
        The frame.
    binning
        Grid step in full-resolution pixels.

    Returns
    -------
    ndarray
        ``(rows, cols)`` float32.
    """
    d_cam = pixel_rays(frame, binning)
    rows, cols = d_cam.shape[:2]
    cam_to_mesh = np.linalg.inv(frame.mesh_to_camera)
    rot = cam_to_mesh[:3, :3].astype(np.float32)
    rays = np.empty((rows * cols, 6), dtype=np.float32)
    rays[:, :3] = cam_to_mesh[:3, 3].astype(np.float32)
    rays[:, 3:] = d_cam.reshape(-1, 3) @ rot.T
    t_hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    return (t_hit * d_cam[..., 2].reshape(-1)).reshape(rows, cols)
