"""Confidence-weighted voxel fusion, dominated samples, spacing and noise estimates."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.stats import chi2

from processing.geometry.fusion import (
    dominated_samples,
    fuse_points,
    noise_level,
    point_spacing,
    validate_oriented_cloud,
)


def test_weighted_mean_in_one_voxel():
    p = np.array([[0.1, 0.1, 0.1], [0.3, 0.1, 0.1], [0.2, 0.4, 0.1]])
    n = np.tile([0.0, 0.0, 1.0], (3, 1))
    c = np.array([0.5, 1.0, 0.25])
    f = fuse_points(p, n, c, voxel_mm=1.0)
    assert f.points.shape == (1, 3) and f.counts.tolist() == [3]
    np.testing.assert_allclose(f.points[0], (c[:, None] * p).sum(0) / c.sum())
    np.testing.assert_allclose(f.confidence[0], (c * c).sum() / c.sum())


def test_opposite_faces_of_a_thin_wall_stay_apart():
    # two samples 0.1 mm apart on the two faces of a wall, one voxel
    p = np.array([[0.5, 0.5, 0.45], [0.5, 0.5, 0.55]])
    n = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
    f = fuse_points(p, n, voxel_mm=1.0)
    assert f.points.shape[0] == 2
    assert sorted(f.normals[:, 2].tolist()) == [-1.0, 1.0]


def test_low_confidence_points_are_dropped_and_counted():
    p = np.random.default_rng(0).random((100, 3))
    n = np.tile([1.0, 0.0, 0.0], (100, 1))
    c = np.linspace(0.0, 1.0, 100)
    f = fuse_points(p, n, c, voxel_mm=0.01, min_confidence=0.5)
    assert f.n_low_confidence == int(np.count_nonzero(c < 0.5))
    assert f.counts.sum() == 100 - f.n_low_confidence
    with pytest.raises(ValueError, match="all 100 points have confidence below"):
        fuse_points(p, n, np.zeros(100), voxel_mm=0.1)


@pytest.mark.parametrize("voxel", [0.0, -1.0, float("nan"), float("inf")])
def test_bad_voxel_is_rejected(voxel):
    with pytest.raises(ValueError, match="voxel_mm"):
        fuse_points([[0, 0, 0]], [[0, 0, 1]], voxel_mm=voxel)


@settings(max_examples=30, deadline=None)
@given(
    pts=arrays(np.float64, (40, 3), elements=st.floats(-5, 5)),
    conf=arrays(np.float64, 40, elements=st.floats(0.01, 1.0)),
    scale=st.floats(0.1, 10.0),
    voxel=st.floats(0.05, 3.0),
)
def test_fusion_invariants(pts, conf, scale, voxel):
    nrm = np.tile([0.0, 1.0, 0.0], (40, 1))
    f = fuse_points(pts, nrm, conf, voxel_mm=voxel)
    assert f.counts.sum() == 40
    # a weighted mean lies inside the hull of its voxel: within the cloud's box
    assert np.all(f.points >= pts.min(axis=0) - 1e-9) and np.all(f.points <= pts.max(axis=0) + 1e-9)
    # the relative weights matter, not their scale
    g = fuse_points(pts, nrm, conf * min(scale, 1.0 / conf.max()), voxel_mm=voxel)
    np.testing.assert_allclose(np.sort(g.points, axis=0), np.sort(f.points, axis=0), atol=1e-9)
    assert np.all((f.confidence > 0) & (f.confidence <= 1.0 + 1e-12))


def test_dominated_samples_only_where_something_better_is_near():
    p = np.array([[0, 0, 0], [0.2, 0, 0], [3, 0, 0], [3.1, 0, 0], [6, 0, 0]], float)
    n = np.tile([0.0, 0.0, 1.0], (5, 1))
    n[3] = [0.0, 0.0, -1.0]  # the other side of a wall: not the same surface
    c = np.array([1.0, 0.3, 0.9, 0.1, 0.05])
    dom = dominated_samples(p, n, c, radius_mm=0.5, ratio=0.5)
    assert dom.tolist() == [False, True, False, False, False]
    assert not dominated_samples(p, n, c, radius_mm=0.5, ratio=0.0).any()
    with pytest.raises(ValueError, match="ratio"):
        dominated_samples(p, n, c, radius_mm=0.5, ratio=1.5)


def test_spacing_of_a_regular_grid():
    g = np.stack(np.meshgrid(np.arange(50.0), np.arange(50.0), [0.0]), -1).reshape(-1, 3) * 0.3
    assert point_spacing(g) == pytest.approx(0.3)
    assert point_spacing(g, sample=100) == pytest.approx(0.3)
    with pytest.raises(ValueError, match="at least 2"):
        point_spacing(g[:1])


@pytest.mark.parametrize("sigma", [0.0, 0.01, 0.05])
def test_noise_level_of_a_noisy_plane(sigma):
    # spacing about 0.17 mm, noise well below it
    rng = np.random.default_rng(1)
    p = np.c_[rng.random((30_000, 2)) * 30.0, sigma * rng.standard_normal(30_000)]
    # 16 * (smallest eigenvalue) / sigma^2 is chi-square with 16 - 3 degrees of
    # freedom (the plane absorbs 3); its median is 12.34
    expected = sigma * np.sqrt(chi2.median(13) / 16)
    assert noise_level(p) == pytest.approx(expected, rel=0.08, abs=1e-9)


def test_validation_messages_name_the_parameter():
    with pytest.raises(ValueError, match="points: the cloud is empty"):
        validate_oriented_cloud(np.zeros((0, 3)), np.zeros((0, 3)))
    with pytest.raises(ValueError, match="normals: the cloud has no normals"):
        validate_oriented_cloud([[0, 0, 0]], None)
    with pytest.raises(ValueError, match="normals: 1 of 1 normals"):
        validate_oriented_cloud([[0, 0, 0]], [[0, 0, np.inf]])
    with pytest.raises(ValueError, match="confidence"):
        validate_oriented_cloud([[0, 0, 0]], [[0, 0, 1]], [-0.1])
    p, n, c = validate_oriented_cloud([[0, 0, 0]], [[0, 3, 4]], [1.0])
    np.testing.assert_allclose(n, [[0, 0.6, 0.8]])
