"""Support of a mesh by data and the holes it reports, on closed-form layouts."""

from __future__ import annotations

import math

import numpy as np
import open3d as o3d
import pytest
from scipy.spatial.distance import cdist

from processing.geometry.mesh_support import mesh_support, triangle_areas

STEP = 0.2  # mm, grid spacing
HOLE_R = 3.0  # mm


def grid_mesh(n: int = 101, step: float = STEP):
    """A flat square mesh on z = 0, centred on the origin."""
    xs = (np.arange(n) - (n - 1) / 2) * step
    x, y = np.meshgrid(xs, xs, indexing="ij")
    v = np.c_[x.ravel(), y.ravel(), np.zeros(n * n)]
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    t = np.r_[np.c_[a, a + n, a + 1], np.c_[a + 1, a + n, a + n + 1]]
    return v, t


@pytest.fixture(scope="module")
def plate():
    v, t = grid_mesh()
    data = v[np.linalg.norm(v[:, :2], axis=1) >= HOLE_R]
    return v, t, data


def test_one_round_hole_with_its_area_and_depth(plate):
    v, t, data = plate
    rep = mesh_support(v, t, data, 4 * STEP, low_threshold_mm=1.5 * STEP)
    assert rep.n_holes == 1
    hole = rep.holes[0]
    # grown to vertices beyond 0.3 mm: a disc of radius between 3 - 0.3 - one
    # grid step (border triangles count in part) and 3
    assert math.pi * (HOLE_R - 0.5) ** 2 < hole.area_mm2 < math.pi * HOLE_R**2
    # the centre vertex is 3 mm from the nearest sample (the grid is symmetric)
    nearest = cdist(v[[np.argmin(np.linalg.norm(v, axis=1))]], data).min()
    assert hole.max_distance_mm == pytest.approx(nearest, abs=1e-12)
    np.testing.assert_allclose(hole.centroid, [0, 0, 0], atol=0.05)
    assert rep.mesh_area_mm2 == pytest.approx((100 * STEP) ** 2)
    assert rep.low_threshold_mm == pytest.approx(0.3)


def test_without_growing_the_region_is_smaller(plate):
    v, t, data = plate
    grown = mesh_support(v, t, data, 4 * STEP, low_threshold_mm=1.5 * STEP)
    plain = mesh_support(v, t, data, 4 * STEP)
    assert plain.holes[0].area_mm2 < grown.holes[0].area_mm2
    assert math.pi * (HOLE_R - 4 * STEP - STEP) ** 2 < plain.holes[0].area_mm2 < math.pi * (HOLE_R - 4 * STEP + STEP) ** 2
    assert plain.unsupported.sum() < grown.unsupported.sum()
    assert np.all(plain.hole_label[~plain.unsupported] == -1)


def test_small_gaps_are_not_reported():
    v, t = grid_mesh(41)
    keep = np.ones(v.shape[0], bool)
    keep[np.argmin(np.linalg.norm(v - [1.0, 1.0, 0.0], axis=1))] = False  # one missing sample
    rep = mesh_support(v, t, v[keep], 4 * STEP, low_threshold_mm=0.1)
    assert rep.n_holes == 0  # never farther than 0.2 mm from a sample: no seed
    d = v.copy()
    d = d[np.linalg.norm(d[:, :2] - [2.0, 0.0], axis=1) >= 1.0]  # a 1 mm gap
    rep = mesh_support(v, t, d, 2 * STEP)
    assert rep.n_holes == 1
    rep = mesh_support(v, t, d, 2 * STEP, min_hole_area_mm2=10.0)
    assert rep.n_holes == 0 and rep.unsupported.any()


def test_far_distances_are_exact_for_the_maximum_and_bounded_elsewhere():
    # a sphere with a wide cap missing: the cap's vertices are far from the data
    s = o3d.geometry.TriangleMesh.create_sphere(20.0, resolution=30)
    v, t = np.asarray(s.vertices), np.asarray(s.triangles)
    k = np.arange(10_000) + 0.5  # a Fibonacci sphere: no random gaps
    z, phi = 1 - 2 * k / k.size, np.pi * (1 + 5**0.5) * k
    d = 20.0 * np.c_[np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z]
    data = d[d[:, 2] < 10.0]
    thr = 1.0
    rep = mesh_support(v, t, data, thr)
    exact = cdist(v, data).min(axis=1)
    assert rep.n_holes == 1
    assert rep.holes[0].max_distance_mm == pytest.approx(exact.max(), abs=1e-9)
    near = exact <= 2 * thr
    np.testing.assert_allclose(rep.vertex_distance[near], exact[near], atol=1e-9)
    far = ~near
    assert np.all(np.abs(rep.vertex_distance[far] - exact[far]) <= 0.5 * thr * math.sqrt(3) + 1e-9)


def test_fully_supported_mesh_has_no_holes(plate):
    v, t, _ = plate
    rep = mesh_support(v, t, v, 0.5)
    assert rep.n_holes == 0 and not rep.unsupported.any() and rep.hole_area_mm2 == 0.0
    assert rep.max_distance_mm == 0.0


def test_bad_input_is_rejected(plate):
    v, t, data = plate
    with pytest.raises(ValueError, match="threshold_mm"):
        mesh_support(v, t, data, 0.0)
    with pytest.raises(ValueError, match="low_threshold_mm"):
        mesh_support(v, t, data, 0.5, low_threshold_mm=1.0)
    with pytest.raises(ValueError, match="data_points"):
        mesh_support(v, t, None, 0.5)
    with pytest.raises(ValueError, match="data_points"):
        mesh_support(v, t, np.zeros((0, 3)), 0.5)


def test_triangle_areas_closed_form():
    np.testing.assert_allclose(triangle_areas([[0, 0, 0], [3, 0, 0], [0, 4, 0], [0, 0, 5]], [[0, 1, 2], [0, 1, 3]]),
                               [6.0, 7.5])
