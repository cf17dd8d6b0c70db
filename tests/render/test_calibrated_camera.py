"""CalibratedCamera against OpenCV's projection and against the mesh mask of the same pose.

Truth: ``cv2.projectPoints`` (a point must lie on the ray of the image point it
projects to, angle < 1e-4 rad, with and without distortion) and
``processing.appearance.silhouette.mesh_mask`` (the renderer's coverage of a
sphere seen by the calibrated camera matches it, IoU > 0.99).
"""

from __future__ import annotations

import cv2
import numpy as np
import open3d as o3d
import pytest

from processing.appearance.frame_poses import FramePose
from processing.appearance.silhouette import mesh_mask
from processing.materials.lobes import Lobe, Material
from render.calibrated_camera import CalibratedCamera
from render.camera import Camera
from render.errors import RenderInputError
from render.meshio import make_mesh
from render.presets import RenderSettings
from render.renderer import render
from render.scene import Light, Scene, SceneObject

W, H = 160, 120
K = np.array([[150.0, 0.0, 81.3], [0.0, 152.0, 58.7], [0.0, 0.0, 1.0]])
DIST = np.array([-0.21, 0.08, 0.0015, -0.0012, -0.01])


def _pose() -> np.ndarray:
    rvec = np.array([0.3, -0.5, 0.2])
    m = np.eye(4)
    m[:3, :3] = cv2.Rodrigues(rvec)[0]
    m[:3, 3] = [5.0, -3.0, 120.0]
    return m


@pytest.mark.parametrize("dist", [np.zeros(5), DIST], ids=["pinhole", "distorted"])
def test_projected_points_lie_on_their_pixel_rays(dist):
    cam = CalibratedCamera(K, dist, _pose(), W, H)
    rng = np.random.default_rng(1)
    m = _pose()
    # points in front of the camera, spread over the image (camera frame), mapped back to the mesh frame
    p_cam = np.column_stack([rng.uniform(-0.45, 0.45, 300), rng.uniform(-0.35, 0.35, 300), np.ones(300)])
    p_cam *= rng.uniform(80, 200, 300)[:, None]
    p_mesh = (p_cam - m[:3, 3]) @ m[:3, :3]
    uv = cv2.projectPoints(p_mesh, cv2.Rodrigues(m[:3, :3])[0], m[:3, 3], K, dist)[0].reshape(-1, 2)
    np.testing.assert_allclose(cam.project_px(p_mesh), uv, atol=1e-6)
    np.testing.assert_allclose(cam.project(p_mesh), uv + 0.5, atol=1e-6)
    d_mesh = cam.directions(uv[:, 0], uv[:, 1]) @ m[:3, :3]
    to_point = p_mesh - np.asarray(cam.eye)
    to_point /= np.linalg.norm(to_point, axis=1, keepdims=True)
    angle = np.arccos(np.clip(np.sum(d_mesh * to_point, axis=1), -1, 1))
    assert angle.max() < 1e-4


def test_pixel_rays_go_through_the_pixel_centres_in_opencv_convention():
    cam = CalibratedCamera(K, DIST, _pose(), W, H)
    xs, ys = np.array([0, 37, 159]), np.array([0, 80, 119])
    rays = cam.pixel_rays(xs, ys).astype(np.float64)
    # a point far along each ray projects back onto the pixel's integer position (centre of pixel (0, 0) = (0, 0))
    pts = rays[:, :3] + 150.0 * rays[:, 3:]
    np.testing.assert_allclose(cam.project_px(pts), np.column_stack([xs, ys]), atol=2e-3)
    block = cam.rays(0, W, 0, H, 4, jitter=False)
    some = cam.pixel_rays(xs, ys, 4, jitter=False)
    np.testing.assert_array_equal(block.reshape(H, W, 4, 6)[ys, xs].reshape(-1, 6), some)
    np.testing.assert_allclose(np.linalg.norm(block[:, 3:], axis=1), 1.0, atol=1e-6)


def test_basis_and_eye_follow_the_pose():
    m = _pose()
    cam = CalibratedCamera(K, np.zeros(5), m, W, H)
    right, up, forward = cam.basis()
    np.testing.assert_allclose(m[:3, :3] @ forward, [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(m[:3, :3] @ up, [0, -1, 0], atol=1e-12)
    np.testing.assert_allclose(np.cross(right, forward), up, atol=1e-12)    # as render.camera.Camera
    np.testing.assert_allclose(m @ [*cam.eye, 1.0], [0, 0, 0, 1], atol=1e-9)


def test_rendered_sphere_silhouette_matches_the_mesh_mask():
    sphere = o3d.geometry.TriangleMesh.create_sphere(30.0, resolution=60)
    v, t = np.asarray(sphere.vertices) + [4.0, -6.0, 2.0], np.asarray(sphere.triangles)
    pose = np.eye(4)
    pose[:3, :3] = cv2.Rodrigues(np.array([0.2, 0.1, -0.3]))[0]
    pose[:3, 3] = [0.0, 0.0, 140.0]
    frame = FramePose("f", 1, 0.0, (W, H), K, DIST, pose)
    cam = CalibratedCamera.from_frame(frame)
    grey = Material("grey", (Lobe("lambert", 1.0, _Grey()),))
    scene = Scene([SceneObject(make_mesh(v, t), [grey])], [Light("directional", (0.0, 0.0, -1.0))])
    settings = RenderSettings(spectral_step=10.0, samples_per_pixel=1, mirror_bounces=0, mirror_rays=0,
                              use_tables=True, table_size=64, shadows=False, tile_size=64)
    result = render(scene, cam, settings)
    got = result.mask > 0.5
    truth = mesh_mask((v, t), frame)
    iou = (got & truth).sum() / (got | truth).sum()
    assert truth.sum() > 2000 and iou > 0.99


class _Grey:
    angle_dependent = False

    def reflectance(self, cos_d, wavelengths):
        return np.full(np.shape(cos_d) + (len(wavelengths),), 0.5)


def test_bad_parameters_are_refused_in_one_line():
    with pytest.raises(RenderInputError, match="K"):
        CalibratedCamera(np.eye(3) * 0, np.zeros(5), np.eye(4), W, H)
    with pytest.raises(RenderInputError, match="mesh_to_camera"):
        CalibratedCamera(K, np.zeros(5), np.eye(4) * 2, W, H)
    with pytest.raises(RenderInputError, match="dist"):
        CalibratedCamera(K, np.zeros(4), np.eye(4), W, H)
    with pytest.raises(RenderInputError, match="width"):
        CalibratedCamera(K, np.zeros(5), np.eye(4), 0, H)
    with pytest.raises(RenderInputError, match="outside"):
        CalibratedCamera(K, np.zeros(5), np.eye(4), W, H).rays(0, W + 1, 0, H)
    with pytest.raises(RenderInputError, match="CalibratedCamera"):
        render(Scene([SceneObject(make_mesh(np.eye(3), [[0, 1, 2]]), ["urushi-black"])], [Light("directional", (0.0, 0.0, 1.0))]), "camera")
    assert isinstance(Camera((0, -5, 0), (0, 0, 0), (0, 0, 1), 40, 4, 3).rays(0, 4, 0, 3), np.ndarray)
