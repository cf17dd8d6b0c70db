"""Which vertices of the mesh one frame sees well enough to sample.

A vertex is visible in a frame when it is in front of the camera and
projects inside the image (with the distortion model), faces the camera
with a view angle to its normal below ``max_view_deg``, is not hidden by
another part of the mesh (a ray cast from the camera centre toward it hits
nothing closer than its own distance minus a tolerance relative to the mesh
size) and does not project within ``edge_margin_px`` of the mesh's
silhouette or of a depth discontinuity in that frame (a depth map of the
mesh cast at the frame's resolution or a coarser grid, discontinuities
marked and dilated), where a pixel mixes two surfaces.

References
----------
Callieri, M., Cignoni, P., Corsini, M., Scopigno, R. (2008). Masked
photo blending: mapping dense photographic data set on high-resolution
sampled 3D models. Computers & Graphics 32(4), 464-473.
doi:10.1016/j.cag.2008.05.004
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import open3d as o3d
from numpy.typing import ArrayLike, NDArray

from processing.appearance.frame_poses import AppearanceError, FramePose
from processing.appearance.projection import depth_map, project_points, raycasting_scene

__all__ = ["visible_vertices", "edge_mask", "occlusion_tolerance_mm"]


def occlusion_tolerance_mm(vertices: NDArray[np.float64], relative: float = 1e-3) -> float:
    """The occlusion test's distance tolerance: ``relative`` x the mesh's bounding-box diagonal.

    Parameters
    ----------
    vertices
        ``(N, 3)`` mm.
    relative
        Fraction of the diagonal.

    Returns
    -------
    float
        mm.
    """
    return float(relative * np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))


def edge_mask(depth_mm: NDArray[np.float32], frame: FramePose, binning: int, margin_px: float,
              jump_px: float = 10.0) -> NDArray[np.bool_]:
    """Pixels of a depth map within ``margin_px`` of the silhouette or of a depth discontinuity.

    Two neighbouring grid pixels are discontinuous when exactly one hits the
    mesh, or when their depths differ by more than ``jump_px`` pixel
    footprints (``depth / fx`` per full-resolution pixel x ``binning``): a
    surface seen at up to ~84 deg from its normal changes depth by less than
    that.  Both pixels of a pair are marked, then the marks are dilated by
    ``ceil(margin_px / binning)`` grid pixels.

    Parameters
    ----------
    depth_mm
        :func:`~processing.appearance.projection.depth_map` (inf = no hit).
    frame
        The frame (its fx gives the footprint).
    binning
        The depth map's grid step.
    margin_px
        Margin in full-resolution pixels.
    jump_px
        Depth jump threshold in pixel footprints.

    Returns
    -------
    ndarray
        Bool, the depth map's shape.
    """
    hit = np.isfinite(depth_mm)
    d = np.where(hit, depth_mm, 0.0).astype(np.float32)
    step = jump_px * binning / float(frame.K[0, 0])
    marks = np.zeros(depth_mm.shape, dtype=np.uint8)
    for axis in (0, 1):
        a = [slice(None), slice(None)]
        b = [slice(None), slice(None)]
        a[axis], b[axis] = slice(None, -1), slice(1, None)
        ha, hb, da, db = hit[tuple(a)], hit[tuple(b)], d[tuple(a)], d[tuple(b)]
        jump = (ha != hb) | (ha & hb & (np.abs(da - db) > step * np.minimum(da, db)))
        marks[tuple(a)] |= jump
        marks[tuple(b)] |= jump
    radius = math.ceil(margin_px / binning)
    if radius > 0:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        marks = cv2.dilate(marks, kernel)
    return marks.astype(bool)


def _candidates(vertices, normals, frame, max_view_deg):
    uv, z = project_points(vertices, frame)
    w, h = frame.image_size
    with np.errstate(invalid="ignore"):
        inside = (uv[:, 0] >= -0.5) & (uv[:, 0] <= w - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] <= h - 0.5)
    to_cam = frame.camera_centre_mm - vertices
    dist = np.linalg.norm(to_cam, axis=1)
    cos_view = np.einsum("ij,ij->i", normals, to_cam) / np.where(dist > 0, dist, 1.0)
    ok = inside & (z > 0) & (cos_view > math.cos(math.radians(max_view_deg)))
    return ok, uv, to_cam, dist


def _unoccluded(scene, centre, to_cam, dist, tol_mm, idx, triangles):
    """First hit no closer than the vertex (minus ``tol_mm``), or on a triangle of the vertex itself.

    The second case catches grazing rays whose float32 hit on the vertex's own
    triangle falls short of the vertex by more than the tolerance.
    """
    rays = np.empty((len(dist), 6), dtype=np.float32)
    rays[:, :3] = centre.astype(np.float32)
    rays[:, 3:] = -to_cam / dist[:, None]
    hit = scene.cast_rays(o3d.core.Tensor(rays))
    t_hit, prim = hit["t_hit"].numpy(), hit["primitive_ids"].numpy()
    own = np.zeros(len(dist), dtype=bool)
    finite = np.isfinite(t_hit)
    own[finite] = np.any(triangles[prim[finite].astype(np.intp)] == idx[finite, None], axis=1)
    return (t_hit >= dist - tol_mm) | own


def visible_vertices(vertices: ArrayLike, triangles: ArrayLike, vertex_normals: ArrayLike, frame_pose: FramePose, *,
                     max_view_deg: float = 75.0, edge_margin_px: float = 2.0, occlusion_tol_rel: float = 1e-3,
                     depth_binning: int = 2, jump_px: float = 10.0,
                     scene: o3d.t.geometry.RaycastingScene | None = None) -> NDArray[np.bool_]:
    """Which vertices a frame sees (in view, facing, unoccluded, away from edges).

    Parameters
    ----------
    vertices
        ``(N, 3)`` mesh vertices in M, mm.
    triangles
        ``(F, 3)`` vertex indices.
    vertex_normals
        ``(N, 3)`` unit outward normals.
    frame_pose
        The frame.
    max_view_deg
        Largest angle between the normal and the direction to the camera.
    edge_margin_px
        Vertices projecting within this many full-resolution pixels of the
        silhouette or a depth discontinuity are dropped; 0 skips the test.
    occlusion_tol_rel
        Occlusion tolerance as a fraction of the mesh's bounding-box diagonal.
    depth_binning
        Grid step of the depth map used for the edge test (1 = every pixel).
    jump_px
        Depth discontinuity threshold, in pixel footprints (:func:`edge_mask`).
    scene
        A prebuilt :func:`~processing.appearance.projection.raycasting_scene`
        of the same mesh (build it once for many frames).

    Returns
    -------
    ndarray
        ``(N,)`` bool.
    """
    v = np.asarray(vertices, dtype=np.float64)
    n = np.asarray(vertex_normals, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or n.shape != v.shape:
        raise AppearanceError(f"frame {frame_pose.name!r}: vertices and vertex_normals must both be (N, 3)")
    if int(depth_binning) < 1 or not 0 < max_view_deg <= 90 or edge_margin_px < 0:
        raise AppearanceError("visible_vertices: give depth_binning >= 1, 0 < max_view_deg <= 90, edge_margin_px >= 0")
    if scene is None:
        scene = raycasting_scene(v, triangles)
    ok, uv, to_cam, dist = _candidates(v, n, frame_pose, max_view_deg)
    idx = np.flatnonzero(ok)
    tol_mm = occlusion_tolerance_mm(v, occlusion_tol_rel)
    keep = _unoccluded(scene, frame_pose.camera_centre_mm, to_cam[idx], dist[idx], tol_mm, idx,
                       np.asarray(triangles))
    idx = idx[keep]
    if edge_margin_px > 0 and len(idx):
        b = int(depth_binning)
        marks = edge_mask(depth_map(scene, frame_pose, b), frame_pose, b, edge_margin_px, jump_px)
        col = np.clip(np.rint((uv[idx, 0] + 0.5) / b - 0.5), 0, marks.shape[1] - 1).astype(np.intp)
        row = np.clip(np.rint((uv[idx, 1] + 0.5) / b - 0.5), 0, marks.shape[0] - 1).astype(np.intp)
        idx = idx[~marks[row, col]]
    out = np.zeros(len(v), dtype=bool)
    out[idx] = True
    return out
