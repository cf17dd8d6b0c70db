"""Sphere outline and centre against a ray-traced synthetic booth (truth: the scene's own sphere)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from processing.geometry.sphere_image import SphereImageError, fit_sphere_centre, sphere_radius_px, sphere_silhouette
from tests.geometry.sphere_scene import CX, CY, DIST, FX, FY, K, Scene


def _project(c):
    return np.array([FX * c[0] / c[2] + CX, FY * c[1] / c[2] + CY])


@pytest.mark.parametrize("matte", [False, True], ids=["chrome", "matte"])
def test_centre_within_a_tenth_of_a_millimetre_and_beats_the_ellipse(matte):
    scene = Scene(point_lamps=[((-200.0, -300.0, 350.0), 15.0, 1.3)], matte=matte)
    for angle in (0.0, 150.0, 240.0, 330.0):            # on-axis-ish and far off-axis positions
        centre_room = scene.sphere_centre_room(angle)
        truth = scene.centre_cam(centre_room)
        edge = sphere_silhouette(scene.render(centre_room, seed=int(angle)), name=f"a{angle}", clip_level=1.0)
        centre, cov, rms = fit_sphere_centre(edge, K, DIST, 20.0)
        assert np.linalg.norm(centre - truth) < 0.1          # mm, the target
        assert rms < 0.15                                    # px: the outline is sub-pixel
        assert np.all(np.linalg.eigvalsh(cov) > 0)
        (eu, ev), _, _ = cv2.fitEllipse(edge.astype(np.float32))
        ellipse_err = np.linalg.norm([eu, ev] - _project(truth))
        fit_err = np.linalg.norm(_project(centre) - _project(truth))
        assert fit_err < 0.1 and ellipse_err > 3 * fit_err   # the ellipse centre is biased off-axis


def test_chrome_centre_error_is_within_its_covariance_scale():
    scene = Scene()
    centre_room = scene.sphere_centre_room(60.0)
    edge = sphere_silhouette(scene.render(centre_room, seed=3), name="f")
    centre, cov, _ = fit_sphere_centre(edge, K, DIST, 20.0)
    err = centre - scene.centre_cam(centre_room)
    # the edge points are correlated over ~2 px, so allow 5x the independent-point sigma (plus 5 um)
    assert np.all(np.abs(err) < 5 * np.sqrt(np.diag(cov)) + 0.005)


def test_no_sphere_is_refused():
    img = np.full((640, 960), 0.25) + np.random.default_rng(0).normal(0, 0.002, (640, 960))
    with pytest.raises(SphereImageError, match="empty.png: no sphere found"):
        sphere_silhouette(img, name="empty.png")


def test_sphere_at_the_border_is_refused():
    scene = Scene()
    img = scene.render(scene.sphere_centre_room(0.0) + np.array([0.0, 0.0, -40.0]))  # pushed down out of frame
    with pytest.raises(SphereImageError, match="b.png: the sphere is partly outside the frame"):
        sphere_silhouette(img, name="b.png")


def test_saturated_sphere_is_refused():
    scene = Scene(matte=True, albedo=3.0)
    img = np.minimum(scene.render(scene.sphere_centre_room(90.0)), 1.0)
    with pytest.raises(SphereImageError, match="s.png: the sphere is saturated"):
        sphere_silhouette(img, name="s.png", clip_level=1.0)


def test_fit_refuses_too_few_points():
    with pytest.raises(SphereImageError, match="needs >= 5 outline points"):
        fit_sphere_centre(np.zeros((3, 2)), K, DIST, 20.0)


def test_fit_removes_lens_distortion():
    # outline of a known sphere projected through a distorting lens with OpenCV's own model
    dist = np.array([-0.25, 0.12, 0.001, -0.0015, 0.0])
    truth = np.array([-45.0, 30.0, 250.0])
    axis = truth / np.linalg.norm(truth)
    half = np.arcsin(20.0 / np.linalg.norm(truth))
    e1 = np.cross(axis, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    phi = np.linspace(0, 2 * np.pi, 400, endpoint=False)[:, None]
    rays = np.cos(half) * axis + np.sin(half) * (np.cos(phi) * e1 + np.sin(phi) * e2)
    px, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, dist)
    centre, _, rms = fit_sphere_centre(px.reshape(-1, 2), K, dist, 20.0)
    assert np.linalg.norm(centre - truth) < 1e-4 and rms < 1e-4
    wrong, _, rms_wrong = fit_sphere_centre(px.reshape(-1, 2), K, DIST, 20.0)   # ignoring the distortion
    assert np.linalg.norm(wrong - truth) > 0.5 and rms_wrong > 0.1


def test_a_radius_wrong_by_orders_of_magnitude_is_one_error_not_a_traceback():
    """1e-300 mm made the cone fit's first residuals non-finite (scipy's ValueError and divide warnings)."""
    scene = Scene()
    edge = sphere_silhouette(scene.render(scene.sphere_centre_room(0.0), seed=1), name="f")
    for radius in (1e-300, float("nan"), float("inf")):
        with pytest.raises(SphereImageError, match=r"(no sphere of radius .* fits the outline|positive radius)"):
            fit_sphere_centre(edge, K, DIST, radius)


def test_a_fitted_sphere_must_lie_in_the_frame_and_span_a_few_pixels():
    k = np.array([[1000.0, 0, 320], [0, 1000.0, 240], [0, 0, 1]])
    assert sphere_radius_px([0.0, 0.0, 500.0], 20.0, k, (640, 480)) == pytest.approx(40.0, abs=0.1)
    with pytest.raises(SphereImageError, match=r"^f: the sphere is 0.02 px in radius, under 4 px; check the sphere's "
                                               r"radius \(mm\)"):
        sphere_radius_px([0.0, 0.0, 1e6], 20.0, k, (640, 480), "f")
    with pytest.raises(SphereImageError, match="not inside the 640 x 480 frame; check the sphere's radius"):
        sphere_radius_px([0.0, 0.0, 500.0], 200.0, k, (640, 480), "f")
    with pytest.raises(SphereImageError, match="does not fit the outline in front of the camera"):
        sphere_radius_px([0.0, 0.0, 10.0], 20.0, k, (640, 480), "f")
