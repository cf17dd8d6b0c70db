"""Pixel rays invert the projection through the distortion model; depth maps match an analytic sphere."""

from __future__ import annotations

import numpy as np
import pytest

from processing.appearance.frame_poses import FramePose
from processing.appearance.projection import depth_map, pixel_rays, project_points, raycasting_scene
from tests.appearance.synthetic_scene import (
    SPHERE_CENTRE,
    SPHERE_RADIUS,
    intrinsics,
    look_at,
    ray_sphere_t,
    sphere_and_box,
)


@pytest.mark.parametrize("binning", [1, 3])
def test_pixel_rays_project_back_to_their_pixels(binning):
    dist = np.array([-0.2, 0.08, 0.001, -0.002, -0.01])
    frame = FramePose("f", 1, 0.0, (240, 160), intrinsics(), dist, np.eye(4))
    rays = pixel_rays(frame, binning)
    assert rays.shape == (-(-160 // binning), -(-240 // binning), 3)
    uv, _ = project_points(rays.reshape(-1, 3).astype(np.float64) * 100.0, frame)
    rows, cols = np.mgrid[0:rays.shape[0], 0:rays.shape[1]]
    expect = np.stack([(cols.ravel() + 0.5) * binning - 0.5, (rows.ravel() + 0.5) * binning - 0.5], 1)
    assert np.abs(uv - expect).max() < 1e-3  # px (float32 rays)


def test_depth_map_matches_an_analytic_sphere():
    mesh, n_sphere, lo, hi = sphere_and_box(resolution=60)
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    rc = look_at([0.0, -480.0, 150.0], [0.0, 0.0, 60.0])  # the box is beside the sphere from here
    frame = FramePose("f", 1, 0.0, (240, 160), intrinsics(), np.zeros(5), rc)
    depth = depth_map(raycasting_scene(v, f), frame)
    d_cam = pixel_rays(frame).reshape(-1, 3).astype(np.float64)
    origin = -rc[:3, :3].T @ rc[:3, 3]
    t = ray_sphere_t(origin, d_cam @ rc[:3, :3], SPHERE_CENTRE, SPHERE_RADIUS).reshape(depth.shape)
    dirs = d_cam @ rc[:3, :3]
    hit = origin + np.where(np.isfinite(t.ravel()), t.ravel(), 0)[:, None] * dirs
    cos_inc = -np.sum((hit - SPHERE_CENTRE) / SPHERE_RADIUS * dirs, axis=1).reshape(depth.shape)
    assert np.all(np.isfinite(depth)[np.isfinite(t) & (cos_inc > 0.2)])
    both = np.isfinite(t) & np.isfinite(depth) & (cos_inc > 0.5)
    # inscribed facets of a 60-segment sphere lie at most R (1 - cos(3 deg)) = 0.055 mm inside it,
    # so at most 0.055 / cos(incidence) = 0.11 mm along the ray
    assert both.sum() > 3000 and np.abs(depth[both] - (t * d_cam[:, 2].reshape(depth.shape))[both]).max() < 0.12


def test_points_behind_or_on_the_camera_plane_get_nan_without_warnings():
    frame = FramePose("f", 1, 0.0, (240, 160), intrinsics(), np.array([-0.2, 0.05, 0.0, 0.0, 0.0]), np.eye(4))
    pts = np.array([[0.0, 0.0, 100.0], [1.0, 1.0, 0.0], [0.0, 0.0, 0.0], [5.0, 0.0, -10.0], [1e3, 0.0, 1.0]])
    uv, depth = project_points(pts, frame)  # RuntimeWarnings are errors under pytest here
    assert np.all(np.isfinite(uv[0])) and np.all(np.isnan(uv[1:])) and depth.tolist()[3] == -10.0
