"""Probe unwrap geometry: the mirror points obey the law of reflection; the projection is OpenCV's."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from processing.lighting.environment_map import pixel_directions
from processing.lighting.probe_unwrap import ProbeUnwrapError, mirror_points, project, unwrap_probe


def test_mirror_points_reflect_the_camera_ray_into_each_direction():
    # a camera 12 radii away (near: the distant-camera approximation would be off by degrees)
    eye, c, r = np.array([0.0, -240.0, 60.0]), np.array([5.0, 3.0, 20.0]), 20.0
    d = pixel_directions(16, 32).reshape(-1, 3)
    toward = (eye - c) / np.linalg.norm(eye - c)
    d = d[d @ toward > -0.8]                              # away from the singular direction behind the ball
    p = mirror_points(d, c, r, eye)
    n = (p - c) / r
    incoming = p - eye
    incoming /= np.linalg.norm(incoming, axis=1, keepdims=True)
    out = incoming - 2 * np.einsum("ij,ij->i", incoming, n)[:, None] * n
    assert np.allclose(np.linalg.norm(p - c, axis=1), r)
    assert np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", out, d), -1, 1))).max() < 1e-4


def test_projection_matches_opencv_with_distortion():
    rng = np.random.default_rng(0)
    pts = rng.uniform([-30, -20, 200], [30, 20, 300], (200, 3))
    k = np.array([[2100.0, 0.0, 480.0], [0.0, 2090.0, 320.0], [0.0, 0.0, 1.0]])
    dist = np.array([-0.12, 0.05, 0.001, -0.002, 0.01])
    rot = cv2.Rodrigues(np.array([0.1, -0.2, 0.05]))[0]
    t = np.array([1.0, -2.0, 5.0])
    ref, _ = cv2.projectPoints(pts, cv2.Rodrigues(rot)[0], t, k, dist)
    assert np.abs(project(pts, rot, t, k, dist) - ref.reshape(-1, 2)).max() < 1e-6


def test_bad_arguments_are_refused():
    img = np.ones((64, 96, 3), np.float32)
    k = np.array([[500.0, 0, 48], [0, 500, 32], [0, 0, 1]])
    with pytest.raises(ProbeUnwrapError, match="in front of the camera"):
        unwrap_probe(img, [0, 0, -100.0], 20.0, k, np.zeros(5), np.eye(4))
    with pytest.raises(ProbeUnwrapError, match="reflectance"):
        unwrap_probe(img, [0, 0, 300.0], 20.0, k, np.zeros(5), np.eye(4), reflectance=0.0)
    for tiny in (1e-300, 0.019):       # not a mirror: 1e-300 divided the map to infinity
        with pytest.raises(ProbeUnwrapError, match=r"reflectance must be in \[0.02, 1\] \(a mirror\)"):
            unwrap_probe(img, [0, 0, 300.0], 20.0, k, np.zeros(5), np.eye(4), reflectance=tiny)
    with pytest.raises(ProbeUnwrapError, match="finite"):
        unwrap_probe(np.full((64, 96, 3), np.nan, np.float32), [0, 0, 300.0], 20.0, k, np.zeros(5), np.eye(4))
