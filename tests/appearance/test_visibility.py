"""Visible vertices against analytic truth: a sphere (convex, so facing = unoccluded by itself) and a box in front.

Truth for a sphere vertex X seen from camera centre C: it faces the camera when
``(X - c) . (C - X) > 0`` and the box hides it when the segment C -> X enters
the box (slab test).  Silhouettes and depth edges come from analytic ray
casting of the sphere and the box through every pixel.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from processing.appearance.frame_poses import AppearanceError, FramePose
from processing.appearance.projection import mesh_arrays
from processing.appearance.visibility import visible_vertices
from tests.appearance.synthetic_scene import (
    HEIGHT,
    SPHERE_CENTRE,
    SPHERE_RADIUS,
    WIDTH,
    analytic_labels,
    intrinsics,
    look_at,
    ray_box_t,
    rigid,
    sphere_and_box,
)

ROOM_TO_CAMERA = look_at([480.0, -60.0, 200.0], [0.0, 0.0, 60.0])
PASS_POSE = rigid(0.0, 0.0, 0.0, [0.0, 0.0, 0.0])


@pytest.fixture(scope="module")
def scene():
    mesh, n_sphere, lo, hi = sphere_and_box(resolution=30)
    v, f, n = mesh_arrays(mesh)
    n[:n_sphere] = (v[:n_sphere] - SPHERE_CENTRE) / SPHERE_RADIUS  # analytic normals on the sphere
    return v, f, n, n_sphere, lo, hi


def _frame(theta: float, dist=None, size=(WIDTH, HEIGHT)) -> FramePose:
    return FramePose.from_chain(f"t{theta:g}", 1, ROOM_TO_CAMERA, theta, PASS_POSE, intrinsics(*size),
                                np.zeros(5) if dist is None else dist, size)


def _truth(v, n_sphere, frame, lo, hi, max_view_deg=90.0):
    x = v[:n_sphere]
    c = frame.camera_centre_mm
    to_cam = c - x
    dist = np.linalg.norm(to_cam, axis=1)
    cos_view = np.einsum("ij,ij->i", (x - SPHERE_CENTRE) / SPHERE_RADIUS, to_cam / dist[:, None])
    dirs = -to_cam / dist[:, None]
    t_box = np.array([ray_box_t(c, d[None], lo, hi)[0] for d in dirs])
    return (cos_view > math.cos(math.radians(max_view_deg))) & (t_box >= dist), cos_view


@pytest.mark.parametrize("theta", [0.0, 70.0, 160.0, 250.0, 330.0])
def test_occlusion_and_facing_agree_with_analytic_truth(scene, theta):
    v, f, n, n_sphere, lo, hi = scene
    frame = _frame(theta)
    truth, cos_view = _truth(v, n_sphere, frame, lo, hi)
    assert truth.sum() > 100 and np.abs(cos_view).min() > 1e-6  # a real test, no ties
    got = visible_vertices(v, f, n, frame, max_view_deg=90.0, edge_margin_px=0)
    assert np.array_equal(got[:n_sphere], truth)  # exact: every sphere vertex


def test_view_angle_limit(scene):
    v, f, n, n_sphere, lo, hi = scene
    frame = _frame(70.0)
    truth, cos_view = _truth(v, n_sphere, frame, lo, hi, max_view_deg=60.0)
    assert np.abs(np.degrees(np.arccos(np.clip(cos_view, -1, 1))) - 60.0).min() > 1e-6
    got = visible_vertices(v, f, n, frame, max_view_deg=60.0, edge_margin_px=0)
    assert np.array_equal(got[:n_sphere], truth)


def _outline_distance_px(frame, lo, hi):
    lab = analytic_labels(frame.mesh_to_camera, frame.K, lo=lo, hi=hi)
    edge = np.zeros(lab.shape, bool)
    dh, dv = lab[:, 1:] != lab[:, :-1], lab[1:] != lab[:-1]
    edge[:, 1:] |= dh
    edge[:, :-1] |= dh
    edge[1:] |= dv
    edge[:-1] |= dv
    return cv2.distanceTransform((~edge).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)


@pytest.mark.parametrize("binning", [1, 2])
@pytest.mark.parametrize("theta", [0.0, 200.0])
def test_edge_margin_drops_exactly_the_vertices_near_outlines(scene, theta, binning):
    v, f, n, n_sphere, lo, hi = scene
    frame = _frame(theta)
    margin = 2.0
    all_seen = visible_vertices(v, f, n, frame, max_view_deg=90.0, edge_margin_px=0)
    kept = visible_vertices(v, f, n, frame, max_view_deg=90.0, edge_margin_px=margin, depth_binning=binning)
    assert not np.any(kept & ~all_seen)
    # distance of each vertex's pixel from the analytic outline (sphere limb, box edges)
    m = frame.mesh_to_camera
    p = v @ m[:3, :3].T + m[:3, 3]
    uv = p[:, :2] / p[:, 2:] * np.diag(frame.K)[:2] + frame.K[:2, 2]
    d = _outline_distance_px(frame, lo, hi)[np.rint(uv[:, 1]).astype(int).clip(0, HEIGHT - 1),
                                            np.rint(uv[:, 0]).astype(int).clip(0, WIDTH - 1)]
    dropped = all_seen & ~kept
    assert dropped.sum() > 10
    # tolerance: the margin plus the depth grid's step plus rounding to a pixel
    assert d[dropped].max() <= margin + binning + 0.7
    assert d[kept].min() >= margin - 0.5


def test_distortion_and_image_bounds(scene):
    v, f, n, n_sphere, lo, hi = scene
    dist = np.array([-0.25, 0.1, 0.0, 0.0, 0.0])
    # the camera looks off to the side: part of the sphere is out of the frame
    rc = look_at([480.0, -60.0, 200.0], [0.0, 140.0, 60.0])
    frame = FramePose.from_chain("off", 1, rc, 0.0, PASS_POSE, intrinsics(), dist, (WIDTH, HEIGHT))
    rvec, _ = cv2.Rodrigues(rc[:3, :3])
    uv = cv2.projectPoints(v, rvec, rc[:3, 3], intrinsics(), dist)[0].reshape(-1, 2)
    inside = (uv[:, 0] >= -0.5) & (uv[:, 0] <= WIDTH - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] <= HEIGHT - 0.5)
    truth, _ = _truth(v, n_sphere, frame, lo, hi)
    assert (truth & ~inside[:n_sphere]).sum() > 20  # some facing vertices are out of the frame
    got = visible_vertices(v, f, n, frame, max_view_deg=90.0, edge_margin_px=0)
    assert np.array_equal(got[:n_sphere], truth & inside[:n_sphere])


def test_bad_arguments_are_refused(scene):
    v, f, n, *_ = scene
    with pytest.raises(AppearanceError, match="vertex_normals"):
        visible_vertices(v, f, n[:5], _frame(0.0))
    with pytest.raises(AppearanceError, match="max_view_deg"):
        visible_vertices(v, f, n, _frame(0.0), max_view_deg=120)


def _shortfall_mm(c, x, tri):
    """Möller-Trumbore over all triangles: how far before x the segment c -> x first crosses the mesh (0 = none)."""
    d = x - c
    length = np.linalg.norm(d)
    d = d / length
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    p = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = c - tri[:, 0]
    u = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    v = (q @ d) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-9)
    return float(max(length - t[hit].min(), 0.0)) if hit.any() else 0.0


@pytest.mark.parametrize("theta", [0.0, 20.0])
def test_torus_self_occlusion_agrees_with_brute_force_intersection(theta):
    # a torus (self-occluding, not convex) tilted toward the camera, plus a box in front of part of it
    import open3d as o3d

    torus = o3d.geometry.TriangleMesh.create_torus(45.0, 15.0, radial_resolution=40, tubular_resolution=16)
    torus.rotate(o3d.geometry.get_rotation_matrix_from_xyz([1.1, 0.0, 0.0]), center=[0, 0, 0]).translate([0, 0, 60.0])
    box = o3d.geometry.TriangleMesh.create_box(10.0, 30.0, 30.0).translate([70.0, -50.0, 50.0])
    v, f, n = mesh_arrays(torus + box)
    frame = _frame(theta)
    got = visible_vertices(v, f, n, frame, max_view_deg=80.0, edge_margin_px=0)
    c = frame.camera_centre_mm
    tri = v[f]
    tol = 1e-3 * np.linalg.norm(v.max(0) - v.min(0))
    to_cam = c - v
    facing = np.einsum("ij,ij->i", n, to_cam / np.linalg.norm(to_cam, axis=1, keepdims=True)) > np.cos(np.radians(80))
    short = np.array([_shortfall_mm(c, v[i], tri) if facing[i] else 0.0 for i in range(len(v))])
    # float64 brute force; ties within 0.5..3 x the tolerance are left undecided
    sure_visible, sure_hidden = facing & (short < 0.5 * tol), ~facing | (short > 3 * tol)
    assert sure_hidden[facing].sum() > 20 and sure_visible.sum() > 100  # the torus really hides itself
    assert not np.any(got & sure_hidden) and np.all(got[sure_visible])
