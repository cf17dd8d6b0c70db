"""Shading normals smoothed at the reconstruction's scale, against diffusion theory and true surfaces."""

from __future__ import annotations

import numpy as np
import pytest

from processing.appearance._surface_features import adjacency
from processing.appearance.frame_poses import AppearanceError
from processing.appearance.shading_normals import diffusion_steps, smoothed_normals


def _grid(n: int) -> tuple[np.ndarray, np.ndarray]:
    x, y = np.meshgrid(np.arange(float(n)), np.arange(float(n)))
    v = np.stack([x.ravel(), y.ravel(), 0 * x.ravel()], axis=1)
    q = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).ravel()
    t = np.concatenate([np.stack([q, q + 1, q + n + 1], 1), np.stack([q, q + n + 1, q + n], 1)])
    return v, t


def _sphere(radius_mm: float, subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    import open3d as o3d

    m = o3d.geometry.TriangleMesh.create_icosahedron(radius_mm).subdivide_loop(subdivisions)
    v = np.asarray(m.vertices)
    v = radius_mm * v / np.linalg.norm(v, axis=1, keepdims=True)
    return v, np.asarray(m.triangles).astype(np.int64)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    return np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0)))


@pytest.mark.parametrize("sigma", [2.0, 4.0])
def test_the_steps_spread_an_impulse_to_the_stated_gaussian(sigma: float) -> None:
    # Random-walk theory: the variance of a diffused impulse is the sum of the steps' variances.
    v, t = _grid(61)
    steps = diffusion_steps(v, t, sigma)
    a = adjacency(t, len(v))
    deg = np.diff(a.indptr)
    f = np.zeros(len(v))
    f[30 * 61 + 30] = 1.0
    for _ in range(steps):
        f = (f + a @ f) / (1.0 + deg)
    w = f / f.sum()
    var_x = float((w * (v[:, 0] - (w * v[:, 0]).sum()) ** 2).sum())
    assert var_x == pytest.approx(sigma ** 2, rel=0.08)       # rounding to whole steps: <= 0.3 step of 16+


def test_noisy_sphere_normals_come_back_to_the_true_ones() -> None:
    # A 20 mm sphere meshed at ~0.6 mm edges, its normals tilted at random by ~3 deg (facet noise).
    v, t = _sphere(20.0, 5)
    truth = v / np.linalg.norm(v, axis=1, keepdims=True)
    rng = np.random.default_rng(1)
    noisy = truth + rng.normal(0.0, 0.04, truth.shape)
    before = _angle_deg(noisy, truth)
    after = _angle_deg(smoothed_normals(v, t, noisy, 1.2), truth)
    assert np.median(before) > 2.0
    assert np.median(after) < 0.5 * np.median(before)
    # Clean normals stay put: an asymmetric neighbourhood (the valence-5 vertices) can shift them by a
    # fraction of sigma / radius (3.4 deg); a tenth of a degree is far below the noise removed.
    assert _angle_deg(smoothed_normals(v, t, truth, 1.2), truth).max() < 0.25


def test_a_crease_is_kept_beyond_a_few_sigma() -> None:
    # A folded sheet (90 deg crease along x = 20): vertices more than 3 sigma from it keep their normal.
    v, t = _grid(41)
    fold = v[:, 0] > 20
    v = v.copy()
    v[fold, 2] = v[fold, 0] - 20
    v[fold, 0] = 20
    n = np.where(fold[:, None], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0])
    m = smoothed_normals(v, t, n, 1.0)
    far = np.abs(np.where(fold, v[:, 2], 20 - v[:, 0])) > 4.0
    assert _angle_deg(m[far], n[far]).max() < 1.0


def test_zero_scale_returns_unit_normals_unchanged() -> None:
    v, t = _grid(5)
    n = np.tile([0.0, 0.0, 2.0], (len(v), 1))
    assert np.allclose(smoothed_normals(v, t, n, 0.0), [0.0, 0.0, 1.0])


@pytest.mark.parametrize("case, message", [
    ("nan", "NaN"), ("shape", "must both be"), ("zero", "are zero"), ("negative", ">= 0 mm"), ("huge", "steps"),
    ("index", "indices"),
])
def test_bad_input_is_named(case: str, message: str) -> None:
    v, t = _grid(5)
    n = np.tile([0.0, 0.0, 1.0], (len(v), 1))
    sigma = 1.0
    if case == "nan":
        n[3] = np.nan
    elif case == "shape":
        n = n[:-1]
    elif case == "zero":
        n[2] = 0.0
    elif case == "negative":
        sigma = -1.0
    elif case == "huge":
        sigma = 1e4
    elif case == "index":
        t = t.copy()
        t[0, 0] = len(v)
    with pytest.raises(AppearanceError, match=message):
        smoothed_normals(v, t, n, sigma)
