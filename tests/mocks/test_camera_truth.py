"""The station camera is fixed in the room and its truth accessors (K, room -> camera) match the renders."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from mocks.world import World, WorldError, rotation_z


@pytest.fixture(scope="module")
def hawk():
    return World.hawk(2_000, width=240, height=160, spectral_step=50.0)


def _project(world, points_room):
    k, t = world.camera_intrinsics(), world.room_to_camera()
    cam = points_room @ t[:3, :3].T + t[:3, 3]
    uv = cam @ k.T
    return uv[:, :2] / uv[:, 2:], cam[:, 2]


def test_pixel_centres_are_the_rays_the_renderer_casts(hawk):
    eye, dirs = hawk._view()
    t = hawk.room_to_camera()
    assert np.allclose(t[:3, :3] @ t[:3, :3].T, np.eye(3), atol=1e-12)
    assert np.allclose(t[:3, :3] @ eye + t[:3, 3], 0.0, atol=1e-9)       # the camera centre
    uv, depth = _project(hawk, (eye + 100.0 * dirs).reshape(-1, 3))
    rows, cols = np.mgrid[0:hawk.height, 0:hawk.width]
    assert np.all(depth > 0)
    assert np.abs(uv[:, 0] - cols.ravel()).max() < 1e-9
    assert np.abs(uv[:, 1] - rows.ravel()).max() < 1e-9


def test_camera_does_not_follow_the_object(hawk):
    moved = World.hawk(2_000, width=240, height=160, spectral_step=50.0,
                       pose=np.array([[1, 0, 0, 30.0], [0, 1, 0, -20.0], [0, 0, 1, 5.0], [0, 0, 0, 1]]))
    assert np.array_equal(moved.room_to_camera(), hawk.room_to_camera())
    assert np.array_equal(moved._view()[1], hawk._view()[1])
    # the default target is about the standing hawk's centre: it projects to the image centre
    k = hawk.camera_intrinsics()
    uv, _ = _project(hawk, np.array([hawk.camera_target_mm]))
    assert np.allclose(uv[0], [k[0, 2], k[1, 2]], atol=1e-9)


@pytest.mark.parametrize("angle", [0.0, 73.0, 200.0])
def test_projected_mesh_covers_the_rendered_object(hawk, angle):
    """The posed, turned mesh projected with the true K and pose is the render's silhouette (IoU > 0.97)."""
    pose = rotation_z(angle) @ hawk.pose
    verts = hawk.vertices @ pose[:3, :3].T + pose[:3, 3]
    uv, depth = _project(hawk, verts)
    assert np.all(depth > 0)
    mask = np.zeros((hawk.height, hawk.width), np.uint8)
    shift = 6
    polys = np.round(uv[hawk.triangles] * (1 << shift)).astype(np.int32)
    for tri in polys:                 # the union of the projected triangles (fillPoly would fill even-odd)
        cv2.fillConvexPoly(mask, tri, 1, lineType=cv2.LINE_8, shift=shift)
    labels = hawk.frame("object", angle).labels >= 0
    inter = np.logical_and(mask > 0, labels).sum()
    union = np.logical_or(mask > 0, labels).sum()
    assert labels.sum() > 500
    assert inter / union > 0.97


def test_intrinsics_follow_the_convention():
    w = World.hawk(2_000, width=960, height=640, fov_deg=25.0)
    k = w.camera_intrinsics()
    f = 480.0 / math.tan(math.radians(12.5))
    assert np.allclose(k, [[f, 0, 479.5], [0, f, 319.5], [0, 0, 1]], rtol=1e-12)


def test_point_lamp_at_the_target_distance_matches_a_distant_lamp():
    """On a plate through the target, the point lamp's irradiance there equals a distant lamp's (d0 / d = 1)."""
    v = np.array([[-100, 0, -100], [100, 0, -100], [100, 0, 100], [-100, 0, 100]], float)
    v[:, 2] += 37.0
    t = np.array([[0, 2, 1], [0, 3, 2]])
    common = dict(camera_elevation_deg=0.0, width=24, height=24, fov_deg=10.0, spectral_step=50.0)
    lamp = np.array([80.0, -200.0, 90.0])
    point = World(v, t, np.zeros(2, int), ("plate",), {"plate": "urushi-black"}, light_position_mm=tuple(lamp),
                  mesh_source="plate", **common)
    distant = World(v, t, np.zeros(2, int), ("plate",), {"plate": "urushi-black"},
                    light_direction=tuple(lamp - [0, 0, 37.0]), **common)
    a, b = point.frame("object").radiance, distant.frame("object").radiance
    centre = (slice(11, 13), slice(11, 13))
    assert np.allclose(a[centre].mean(axis=(0, 1)), b[centre].mean(axis=(0, 1)), rtol=0.02)
    # a pixel on the plate's left, farther from the lamp (on the +x side): darker than under the distant lamp
    assert a[12, 0].sum() < 0.97 * b[12, 0].sum()
    truth = point.lamp_truth()
    assert truth["kind"] == "point" and truth["position_mm"] == lamp.tolist()
    assert distant.lamp_truth()["kind"] == "distant"
    again = World.from_dict({**point.to_dict(), "mesh": "hawk:2000", "materials": {}, "width": 96, "height": 64})
    assert again.light_position_mm == tuple(lamp) and again.camera_target_mm == (0.0, 0.0, 37.0)


def test_bad_camera_target_and_lamp():
    with pytest.raises(WorldError, match="camera_target_mm"):
        World.hawk(2_000, camera_target_mm=(0.0, 1.0))
    with pytest.raises(WorldError, match="light_position_mm"):
        World.hawk(2_000, light_position_mm=(0.0, math.nan, 1.0))
    with pytest.raises(WorldError, match="lamp_radius_mm"):
        World.hawk(2_000, lamp_radius_mm=0.0)
