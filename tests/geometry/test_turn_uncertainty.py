"""Uncertainty of a refined turn (processing.geometry.registration.turn_uncertainty) against the truth.

The sandwich covariance is checked against the scatter of the fit itself over independent noise draws
(a cylinder with a boss, the vase's proportions); the stated bound of the registration's gate against the
simulated world's truth on vase passes (mocks.pass_cloud.simulated_pass); the colour turn's bootstrap
against the scatter of the colour turn over ragged borders.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from processing.geometry.registration.clouds import _as_cloud, _Level
from processing.geometry.registration.photo_consistency import _turned, turn_by_colour
from processing.geometry.registration.presets import registration_preset
from processing.geometry.registration.refinement import _icp, _icp_pyramid, _pair_scale, _pyramid
from processing.geometry.registration.transforms import transform_points
from processing.geometry.registration.turn_uncertainty import (
    _about_axis_deg,
    _profiled,
    _turn_spread,
    profile_turn,
    rotation_covariance,
    turn_sigma_deg,
)

RADIUS_MM, BOSS_MM, BOSS_SIGMA_MM, NOISE_MM = 26.0, 1.0, 3.0, 0.05
Z_AXIS = np.array([0.0, 0.0, 1.0])


def _boss_cylinder(phi: np.ndarray, z: np.ndarray, boss_mm: float = BOSS_MM) -> tuple[np.ndarray, np.ndarray]:
    """Points and outward normals of a cylinder with a Gaussian boss (``boss_mm`` high) at azimuth 0, 30 mm up."""
    def at(ph: np.ndarray, zz: np.ndarray) -> np.ndarray:
        r = RADIUS_MM + boss_mm * np.exp(-((RADIUS_MM * ph) ** 2 + (zz - 30.0) ** 2) / (2 * BOSS_SIGMA_MM ** 2))
        return np.stack([r * np.cos(ph), r * np.sin(ph), zz], 1)

    e = 1e-4
    n = np.cross(at(phi + e, z) - at(phi - e, z), at(phi, z + e) - at(phi, z - e))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    p = at(phi, z)
    n *= np.sign(np.sum(n[:, :2] * p[:, :2], axis=1))[:, None]
    return p, n


def test_sandwich_matches_the_scatter_of_the_fit_over_noise_draws():
    # 20 independent draws of 6000 noisy points fitted (the registration's ICP) to a densely sampled
    # surface: the turn about the axis rests on the boss alone.  The standard deviation of 20 draws is
    # known to about 16 % (1 / sqrt(2 x 19)); the sandwich must agree within a factor of 1.5
    rng = np.random.default_rng(0)
    g, zz = np.meshgrid(np.arange(-0.8, 0.8, 0.5 / RADIUS_MM), np.arange(5.0, 55.0, 0.5))
    tp, tn = _boss_cylinder(g.ravel(), zz.ravel())
    target = _Level(tp, tn)
    turns, sigmas = [], []
    for _ in range(20):
        p, n = _boss_cylinder(rng.uniform(-0.7, 0.7, 6000), rng.uniform(8.0, 52.0, 6000))
        p = p + rng.normal(0.0, NOISE_MM, (6000, 1)) * n
        t = _icp(p, n, target, np.eye(4), 1.0, 0.25, 0.5, True, 40)
        turns.append(_about_axis_deg(t, np.eye(4), Z_AXIS))
        cov = rotation_covariance(p, n, tp, tn, t, reach_mm=1.0, kernel_mm=0.25, cell_mm=1.5)
        sigmas.append(turn_sigma_deg(cov, Z_AXIS)[0])
    ratio = float(np.mean(sigmas)) / float(np.std(turns))
    assert abs(math.log(ratio)) < math.log(1.5), (ratio, np.std(turns), np.mean(sigmas))


def test_profile_matches_the_scatter_of_its_vertex_over_noise_draws():
    # the boss cylinder, both clouds noisy (each point's partner is itself a noisy point), 12 independent
    # draws: the cost profiled over turns about the axis at the truth.  The standard deviation of 12
    # vertices is known to about 21 % (1 / sqrt(2 x 11)); the stated one must agree within a factor of 1.6,
    # and every vertex lie within 3 of them
    rng = np.random.default_rng(3)
    vertices, sigmas = [], []
    for _ in range(12):
        clouds = []
        for n_pts in (6000, 6000):
            p, n = _boss_cylinder(rng.uniform(-0.7, 0.7, n_pts), rng.uniform(8.0, 52.0, n_pts))
            clouds.append(_Level(p + rng.normal(0.0, NOISE_MM, (n_pts, 1)) * n, n))
        v, sd = _profiled(clouds[0], clouds[1], np.eye(4), Z_AXIS, np.zeros(3), 0.5)
        vertices.append(v)
        sigmas.append(sd)
    scatter, stated = float(np.std(vertices, ddof=1)), float(np.mean(sigmas))
    assert abs(math.log(stated / scatter)) < math.log(1.6), (scatter, stated)
    assert all(abs(v) <= 3.0 * s for v, s in zip(vertices, sigmas)), (vertices, sigmas)


@pytest.mark.parametrize("scale", [1e-200, 1e-30, 1.0, 1e30, 1e200])
def test_profile_states_one_turn_whatever_the_scale_of_its_cost(scale):
    # 300 cells, parabolas whose minima scatter 1 deg about 0.2 deg: the vertex is their mean and its
    # deviation their standard deviation over sqrt(300), from the draws themselves; multiplying every cost
    # by a constant (a noise variance 1e200 too small or too large) changes neither, nor makes them NaN
    rng = np.random.default_rng(7)
    d = np.arange(-3.0, 3.0 + 1e-9, 0.2)
    mu = rng.normal(0.2, 1.0, 300)
    v, sd = profile_turn(d, scale * (d[:, None] - mu) ** 2, np.arange(300))
    assert v == pytest.approx(mu.mean(), abs=1e-9)
    assert sd == pytest.approx(mu.std() / math.sqrt(300), rel=1e-9)


def test_profile_refuses_costs_it_cannot_fit():
    d = np.array([-1.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="3 or more distinct turns"):
        profile_turn([0.0, 0.0, 1.0], np.ones((3, 4)), np.arange(4))
    with pytest.raises(ValueError, match="a cell per point"):
        profile_turn(d, np.ones((3, 4)), np.arange(5))
    # a profile curving down (a maximum, not a minimum) holds no turn
    v, sd = profile_turn(d, -(d[:, None] ** 2) * np.ones((3, 4)), np.arange(4))
    assert math.isnan(v) and math.isinf(sd)


def test_profile_of_a_surface_of_revolution_holds_no_turn():
    phi, z = np.meshgrid(np.linspace(-1.0, 1.0, 80), np.linspace(5.0, 55.0, 80))
    p = np.stack([RADIUS_MM * np.cos(phi.ravel()), RADIUS_MM * np.sin(phi.ravel()), z.ravel()], 1)
    n = p * [1.0, 1.0, 0.0] / RADIUS_MM
    rng = np.random.default_rng(0)
    noisy = _Level(p + rng.normal(0.0, NOISE_MM, (len(p), 1)) * n, n)
    v, sd = _profiled(noisy, _Level(p, n), np.eye(4), Z_AXIS, np.zeros(3), 0.5)
    # no curvature over the span: free, or so flat that the turn is known to no better than the span
    assert math.isinf(sd) or sd > 3.0, (v, sd)


def test_a_surface_of_revolution_leaves_the_turn_free():
    phi, z = np.meshgrid(np.linspace(-1.0, 1.0, 80), np.linspace(5.0, 55.0, 80))
    p = np.stack([RADIUS_MM * np.cos(phi.ravel()), RADIUS_MM * np.sin(phi.ravel()), z.ravel()], 1)
    n = p * [1.0, 1.0, 0.0] / RADIUS_MM
    cov = rotation_covariance(p, n, p, n, np.eye(4), reach_mm=2.0, kernel_mm=0.5, cell_mm=3.0)
    assert math.isinf(turn_sigma_deg(cov, Z_AXIS)[0])


def _vase_fit(seed: int, name: str = "vase", steps: int = 72, turn_deg: float = 1.0):
    """A vase pair's passes, the fit's last two levels run from the truth turned ``turn_deg`` about the axis."""
    from mocks.pass_cloud import simulated_pass
    from mocks.world import World

    w = World.turned(name)
    a, b = simulated_pass(w, seed, 2, steps=steps), simulated_pass(w, seed, 3, steps=steps)
    p = registration_preset("standard")
    src, tgt = _as_cloud(b.points, b.normals, "source"), _as_cloud(a.points, a.normals, "target")
    levels = _pyramid(p, _pair_scale(src, tgt), src, tgt)
    truth = a.pose @ np.linalg.inv(b.pose)
    axis = a.pose[:3, 2]
    start = _turned(truth, axis, a.pose[:3, 3], np.radians([turn_deg]))[0]
    t = _icp_pyramid(src, tgt, p, start, levels[-2:], settled=True)
    sd = _turn_spread(src, tgt, t, axis, levels[-1], p, a.pose[:3, 3])[0]
    return p, p.turn_sigmas * sd, abs(_about_axis_deg(t, truth, axis))


@pytest.mark.parametrize(("seed", "pinned", "steps"), [(0, True, 200), (4, False, 72)])
def test_vase_turn_bound_covers_the_true_error_and_gates(seed, pinned, steps):
    # seed 0: the boss in both passes' overlap (0.56 % of it, from the truth), scanned as the station
    # does (200 profiles): the stated bound (2 sigma) is within the 0.5 deg tolerance; seed 4: the boss in
    # neither overlap, the turn rests on the vase's faint asymmetries only: the bound exceeds the
    # tolerance even at 72 profiles.  In both the true error lies within it
    preset, bound_deg, error_deg = _vase_fit(seed, steps=steps)
    assert error_deg <= bound_deg, (error_deg, bound_deg)
    assert (bound_deg <= preset.max_turn_deg) == pinned, bound_deg


@pytest.mark.parametrize(("seed", "turn_deg"), [(3, -1.0), (15, 0.0), (13, -1.45)])
def test_a_turn_a_shallow_relief_cannot_hold_is_not_pinned(seed, turn_deg):
    # the inlaid bowl (a motif sunk 0.1 mm, twice the range noise), scanned at 200 profiles, fitted from the
    # truth turned by ``turn_deg``; each case is one the registration once pinned or under-bounded:
    # seed 3: the fit settles 0.98 deg from the truth, and the sandwich (0.06 deg) and the refits from that
    #   pose (within 0.16 deg of it) alone would state a bound of 0.17 deg, pinning a wrong turn;
    # seed 15: the fit settles 0.93 deg off and every refit lands within 0.41 deg of it, so the sandwich
    #   (0.05 deg), the refits and the basin stated 0.50 deg: the registration verified the turn 0.94 deg
    #   off; the cost profiled over +-3 deg does not credit the partners' jumps as information;
    # seed 13: registered, the fit settled 1.45 deg off, a shallow minimum among others about a degree
    #   apart; refits from +-0.5 deg fell back to it and the bound was 1.02 deg (1.16 from this start).
    # Refitted from the profile's ends (+-3 deg) on the offset grid, the fit does not come back: the bound
    # must cover the true error and exceed the tolerance
    preset, bound_deg, error_deg = _vase_fit(seed, "inlaid-bowl", steps=200, turn_deg=turn_deg)
    assert error_deg > preset.max_turn_deg, error_deg                      # the case is the one above
    assert error_deg <= bound_deg and bound_deg > preset.max_turn_deg, (error_deg, bound_deg)


def _painted(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """A cylinder's points and their classes: painted within 0.5 rad of azimuth 0, the border ragged."""
    phi, z = rng.uniform(-np.pi, np.pi, n), rng.uniform(0.0, 40.0, n)
    edge = 0.5 + rng.normal(0.0, 0.03, n)
    return np.stack([30 * np.cos(phi), 30 * np.sin(phi), z], 1), (np.abs(phi) < edge).astype(np.int8)


def test_colour_turn_bootstrap_matches_the_scatter_over_ragged_borders():
    # a cylinder painted on one side, its border ragged by about 1 mm (label noise), turned by 70 deg;
    # 10 draws: the RMS error of the turn must be within a factor of 1.6 of the stated standard deviation
    # (the RMS of 10 draws is known to about 25 %), and every error within 3 of them
    errors, sds = [], []
    for k in range(10):
        rng = np.random.default_rng(k)
        (ps, ls), (pt, lt) = _painted(rng, 8000), _painted(rng, 8000)
        turn = _turned(np.eye(4), Z_AXIS, np.zeros(3), np.radians([70.0]))[0]
        res = turn_by_colour(ps, ls, transform_points(turn, pt), lt, np.eye(4), Z_AXIS, np.zeros(3),
                             max_distance_mm=1.5, cell_mm=3.0, seed=k)
        errors.append(res.angle_deg - 70.0)
        sds.append(res.sigma_deg)
    rms, sd = math.sqrt(float(np.mean(np.square(errors)))), float(np.mean(sds))
    assert abs(math.log(sd / rms)) < math.log(1.6), (rms, sd)
    assert all(abs(e) <= 3.0 * s for e, s in zip(errors, sds)), (errors, sds)
