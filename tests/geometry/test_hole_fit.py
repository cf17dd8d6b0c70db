"""Hole completion by smooth height fields: direction, ring fits, border plane, polygon test."""

from __future__ import annotations

import math

import numpy as np
import open3d as o3d
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from matplotlib.path import Path

from processing.geometry.holes import _fit, hole_guide_points, inside_polygon
from processing.geometry.mesh_support import mesh_support

NOISE = 0.05


def fib(n):
    k = np.arange(n) + 0.5
    z, phi = 1 - 2 * k / n, np.pi * (1 + 5**0.5) * k
    return np.c_[np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z]


@settings(max_examples=40, deadline=None)
@given(
    radii=st.lists(st.floats(0.3, 2.0), min_size=3, max_size=12),
    turn=st.floats(0, 2 * math.pi),
    seed=st.integers(0, 10_000),
)
def test_inside_polygon_matches_matplotlib(radii, turn, seed):
    a = turn + np.linspace(0, 2 * np.pi, len(radii), endpoint=False)
    poly = np.c_[np.cos(a) * radii, np.sin(a) * radii]
    edges = np.stack([poly, np.roll(poly, -1, axis=0)], axis=1)
    rng = np.random.default_rng(seed)
    q = rng.uniform(-2.2, 2.2, (300, 2))
    expected = Path(poly).contains_points(q)
    # points within 1e-9 of an edge are ambiguous for either rule
    seg = edges[None, :, 1] - edges[None, :, 0]
    rel = q[:, None] - edges[None, :, 0]
    s = np.clip(np.einsum("qek,qek->qe", rel, seg) / np.einsum("qek,qek->qe", seg, seg), 0, 1)
    gap = np.linalg.norm(rel - s[..., None] * seg, axis=2).min(axis=1)
    clear = gap > 1e-9
    shuffled = edges[rng.permutation(len(edges))][:, ::-1]  # order and direction do not matter
    assert np.array_equal(inside_polygon(q, shuffled)[clear], expected[clear])


def test_inside_polygon_with_two_loops_is_even_odd():
    square = lambda r: np.array([[[-r, -r], [r, -r]], [[r, -r], [r, r]], [[r, r], [-r, r]], [[-r, r], [-r, -r]]])
    edges = np.concatenate([square(2.0), square(1.0)])  # an annulus
    got = inside_polygon([[0.0, 0.0], [1.5, 0.0], [3.0, 0.0]], edges)
    assert got.tolist() == [False, True, False]
    assert inside_polygon(np.zeros((0, 2)), edges).shape == (0,)


def sphere_with_cap(cap_deg, radius=20.0, n=60_000, seed=0):
    d = fib(n)
    d = d[d[:, 2] < math.cos(math.radians(cap_deg))]
    rng = np.random.default_rng(seed)
    return radius * d + NOISE * rng.standard_normal(d.shape[0])[:, None] * d, d


@pytest.fixture(scope="module")
def coarse_sphere():
    s = o3d.geometry.TriangleMesh.create_sphere(20.0, resolution=50)
    return np.asarray(s.vertices), np.asarray(s.triangles).astype(np.int64)


def test_wide_cap_is_filled_along_the_sphere(coarse_sphere):
    v, t = coarse_sphere
    p, n = sphere_with_cap(40.0)
    spacing = 0.15
    rep = mesh_support(v, t, p, 4 * spacing)
    assert rep.n_holes == 1
    g = hole_guide_points(v, t, rep, p, n, spacing_mm=spacing, noise_mm=NOISE)
    fit = g.fits[0]
    assert fit.fitted and fit.reason in ("sphere", "spline")
    np.testing.assert_allclose(fit.direction, [0, 0, 1], atol=0.02)
    err = np.abs(np.linalg.norm(g.points, axis=1) - 20.0)
    assert err.mean() < 0.1  # the cap's sagitta is 4.7 mm
    radial = g.points / np.linalg.norm(g.points, axis=1, keepdims=True)
    assert np.einsum("ij,ij->i", g.normals, radial).min() > 0.98
    # guide points cover the cap and keep off the data
    assert g.points[:, 2].max() > 19.5 and (g.hole == 0).all()
    assert g.points.shape[0] == fit.n_guide_points


def test_sphere_plus_spline_beats_a_spline_on_a_wide_cap():
    """The module's claim: a spline alone flattens a wide dome."""
    p, _ = sphere_with_cap(40.0)
    ring = p[(p[:, 2] < 20 * math.cos(math.radians(40))) & (p[:, 2] > 20 * math.cos(math.radians(58)))]
    ring = ring[np.random.default_rng(1).choice(ring.shape[0], 800, replace=False)]
    inner = 20.0 * fib(20_000)
    inner = inner[inner[:, 2] > 20 * math.cos(math.radians(40))]
    origin = np.array([0.0, 0.0, ring[:, 2].mean()])
    samples, query = ring - origin, inner - origin
    errs = {}
    for kind in ("sphere", "spline"):
        model = _fit(kind, samples)
        errs[kind] = np.abs(model(query[:, :2]) - query[:, 2]).mean()
    assert errs["sphere"] < 0.1 < 0.2 < errs["spline"]


def test_flat_cut_between_walls_is_closed_by_the_border_plane():
    # a cylinder standing on the table: the flat bottom is missing, the walls
    # around it are no height field over the hole's plane
    cyl = o3d.geometry.TriangleMesh.create_cylinder(radius=10.0, height=20.0, resolution=80, split=20)
    cyl.translate([0, 0, 10.0])
    v, t = np.asarray(cyl.vertices), np.asarray(cyl.triangles).astype(np.int64)
    rng = np.random.default_rng(4)
    m = 50_000
    a, z = rng.uniform(0, 2 * np.pi, m), rng.uniform(0.3, 20, m)
    wall = np.c_[10 * np.cos(a), 10 * np.sin(a), z]
    wall_n = np.c_[np.cos(a), np.sin(a), np.zeros(m)]
    r, b = 10 * np.sqrt(rng.random(15_000)), rng.uniform(0, 2 * np.pi, 15_000)
    lid = np.c_[r * np.cos(b), r * np.sin(b), np.full(15_000, 20.0)]
    p = np.r_[wall, lid] + NOISE * rng.standard_normal((m + 15_000, 1)) * np.r_[wall_n, np.tile([0, 0, 1.0], (15_000, 1))]
    n = np.r_[wall_n, np.tile([0, 0, 1.0], (15_000, 1))]
    rep = mesh_support(v, t, p, 1.0)
    assert rep.n_holes == 1
    g = hole_guide_points(v, t, rep, p, n, spacing_mm=0.25, noise_mm=NOISE)
    fit = g.fits[0]
    assert fit.fitted and fit.reason.startswith("border")
    np.testing.assert_allclose(fit.direction, [0, 0, -1], atol=0.02)
    # the plane through the lowest data (z = 0.3): flat, inside the wall
    assert np.abs(g.points[:, 2] - 0.3).max() < 0.3
    assert np.linalg.norm(g.points[:, :2], axis=1).max() < 10.0
    np.testing.assert_allclose(g.normals.mean(axis=0), [0, 0, -1], atol=0.02)


def test_flat_cut_on_the_table_is_closed_on_the_table():
    cyl = o3d.geometry.TriangleMesh.create_cylinder(radius=10.0, height=20.0, resolution=80, split=20)
    cyl.translate([0, 0, 10.0])
    v, t = np.asarray(cyl.vertices), np.asarray(cyl.triangles).astype(np.int64)
    rng = np.random.default_rng(5)
    a, z = rng.uniform(0, 2 * np.pi, 40_000), rng.uniform(0.5, 20, 40_000)  # cropped 0.5 mm above the table
    p = np.c_[10 * np.cos(a), 10 * np.sin(a), z]
    n = np.c_[np.cos(a), np.sin(a), np.zeros(a.size)]
    r, b = 10 * np.sqrt(rng.random(12_000)), rng.uniform(0, 2 * np.pi, 12_000)
    p = np.r_[p, np.c_[r * np.cos(b), r * np.sin(b), np.full(12_000, 20.0)]]
    n = np.r_[n, np.tile([0, 0, 1.0], (12_000, 1))]
    rep = mesh_support(v, t, p, 1.0)
    g = hole_guide_points(v, t, rep, p, n, spacing_mm=0.25, noise_mm=NOISE, floor_z_mm=0.0)
    fit = g.fits[0]
    assert fit.reason == "table plane" and fit.fit_rms_mm == pytest.approx(0.5, abs=0.1)
    np.testing.assert_allclose(g.points[:, 2], 0.0, atol=1e-9)
    np.testing.assert_allclose(g.normals, np.tile([0, 0, -1.0], (g.points.shape[0], 1)), atol=1e-9)
    with pytest.raises(ValueError, match="floor_z_mm"):
        hole_guide_points(v, t, rep, p, n, spacing_mm=0.25, noise_mm=NOISE, floor_z_mm=float("inf"))


def test_no_fill_passes_below_the_floor(coarse_sphere):
    v, t = coarse_sphere
    p, n = sphere_with_cap(40.0, n=15_000)
    rep = mesh_support(v, t, p, 1.2)
    floor = 19.0  # a plane through the upper cap: the fit's top must be cut there
    g = hole_guide_points(v, t, rep, p, n, spacing_mm=0.3, noise_mm=NOISE, floor_z_mm=floor)
    free = hole_guide_points(v, t, rep, p, n, spacing_mm=0.3, noise_mm=NOISE)
    assert g.points[:, 2].min() >= floor - 1e-9
    assert free.points[:, 2].min() < floor
    assert g.fits[0].reason == free.fits[0].reason != "table plane"  # it faces up, not onto the floor


def test_no_holes_no_guides(coarse_sphere):
    v, t = coarse_sphere
    p = 20.0 * fib(40_000)
    rep = mesh_support(v, t, p, 1.0)
    g = hole_guide_points(v, t, rep, p, p / 20.0, spacing_mm=0.2, noise_mm=0.0)
    assert g.points.shape == (0, 3) and g.fits == ()


def test_bad_parameters_are_rejected(coarse_sphere):
    v, t = coarse_sphere
    p = 20.0 * fib(2000)
    rep = mesh_support(v, t, p, 2.0)
    with pytest.raises(ValueError, match="spacing_mm"):
        hole_guide_points(v, t, rep, p, p / 20, spacing_mm=0.0, noise_mm=0.0)
    with pytest.raises(ValueError, match="noise_mm"):
        hole_guide_points(v, t, rep, p, p / 20, spacing_mm=0.5, noise_mm=float("nan"))
