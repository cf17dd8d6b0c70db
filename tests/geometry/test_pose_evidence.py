"""Evidence between competing poses (processing.geometry.registration.pose_evidence) against known noise.

The residuals are drawn from a known model, so the null distribution of the statistic is known: with
both poses equally right it must behave like a standard normal (no evidence out of noise, however dense
and correlated the points); with a feature of 10 x the noise over 1 % of the overlap it must be
overwhelming.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from processing.geometry.registration.pose_evidence import pose_evidence

NOISE_MM = 0.05
#: The plane sampled on a 0.25 mm grid, 50 x 50 mm: 40 000 points.
STEP_MM, SIDE_MM = 0.25, 50.0


def _grid() -> tuple[np.ndarray, np.ndarray]:
    g = np.arange(0.0, SIDE_MM, STEP_MM)
    xy = np.stack(np.meshgrid(g, g, indexing="ij"), -1)
    return xy, np.concatenate([xy.reshape(-1, 2), np.zeros((xy.shape[0] * xy.shape[1], 1))], axis=1)


def _correlated(rng: np.random.Generator, shape: tuple[int, int], length_mm: float) -> np.ndarray:
    """Gaussian noise of deviation NOISE_MM correlated over about ``length_mm`` (a smoothed white field)."""
    s = length_mm / STEP_MM
    f = gaussian_filter(rng.normal(size=shape), s)
    # the smoothed field's deviation is 1 / (2 sqrt(pi) s) for a 2-D Gaussian of s steps (not the
    # sample's own, which would fix the sum of squares and with it the statistic)
    return (NOISE_MM * 2.0 * np.sqrt(np.pi) * s * f).ravel()


def test_no_evidence_out_of_dense_correlated_noise():
    # 40 trials of two equally right poses whose residual noise is correlated over 0.5 mm (2 grid steps):
    # per point the log-likelihood ratio would be hugely "significant"; with 3 mm cells it stays a
    # standard normal within the sampling error of 40 trials
    rng = np.random.default_rng(1)
    xy, pos = _grid()
    z, naive = [], []
    for _ in range(40):
        ra, rb = (_correlated(rng, xy.shape[:2], 0.5) for _ in range(2))
        z.append(pose_evidence(ra, rb, pos, cell_mm=3.0).sigma)
        d = rb ** 2 - ra ** 2
        naive.append(d.sum() / (2 * NOISE_MM ** 2 * np.sqrt(len(d))))   # independent points assumed
    z = np.asarray(z)
    assert np.abs(z).max() < 5.0, "no trial may reach the acceptance level"
    assert 0.6 < z.std() < 1.4          # standard normal: std 1 within sampling error and estimator bias
    assert abs(z.mean()) < 0.3
    assert np.std(naive) > 2.0 * z.std(), "ignoring the correlation would inflate the evidence"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_feature_of_ten_times_the_noise_over_one_percent_is_overwhelming(seed):
    rng = np.random.default_rng(seed)
    xy, pos = _grid()
    ra, rb = (_correlated(rng, xy.shape[:2], 0.5) for _ in range(2))
    # a disc of 1 % of the area, 10 x the noise high, where pose B has it and A does not (over 0.5 %
    # the same feature gives 2-3 sigma with this correlated noise: too little to accept)
    radius = np.sqrt(0.01 * SIDE_MM ** 2 / np.pi)
    inside = (np.linalg.norm(xy - 20.0, axis=-1) < radius).ravel()
    rb = rb + 10 * NOISE_MM * inside
    ev = pose_evidence(ra, rb, pos, cell_mm=3.0)
    assert ev.sigma > 5.0
    # the other way round the feature speaks against: negative (its spread, estimated from the cells
    # against, then holds the feature, so the figure is smaller in size -- never evidence for)
    assert pose_evidence(rb, ra, pos, cell_mm=3.0).sigma < 0.0
    assert ev.noise_mm == pytest.approx(NOISE_MM, rel=0.1)


def test_only_the_compared_points_count_and_bad_input_is_refused():
    rng = np.random.default_rng(3)
    _, pos = _grid()
    ra = rng.normal(0, NOISE_MM, len(pos))
    rb = ra + 0.5 * (pos[:, 0] < 5)
    assert pose_evidence(ra, rb, pos, 3.0).sigma > 5
    assert abs(pose_evidence(ra, rb, pos, 3.0, compare=pos[:, 0] >= 5).sigma) < 1e-9   # identical elsewhere
    ev = pose_evidence([0.1], [0.2], [[0, 0, 0]], 3.0)
    assert ev.sigma == 0.0 and ev.cells == 0
    with pytest.raises(ValueError, match="one entry per point"):
        pose_evidence([0.1, 0.2], [0.2], [[0, 0, 0]], 3.0)
    with pytest.raises(ValueError, match="cell_mm"):
        pose_evidence([0.1], [0.2], [[0, 0, 0]], 0.0)


def _gap_noise(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    """The gap a cloud measures against itself where two poses predict the same surface: noise only.

    Each point's gap is the larger of two point-to-plane distances, each the difference of two noisy
    points (deviation sqrt(2) x the noise).
    """
    return np.sqrt(2.0) * np.maximum(*(np.abs(_correlated(rng, shape, 0.5)) for _ in range(2)))


def _disc(xy: np.ndarray, share: float, centre_mm: float = 20.0) -> np.ndarray:
    return (np.linalg.norm(xy - centre_mm, axis=-1) < np.sqrt(share * SIDE_MM ** 2 / np.pi)).ravel()


def test_null_where_the_poses_predict_different_surfaces_equally_well():
    # 40 trials of two equally right poses, tested only where the predicted surfaces differ (a disc of
    # 1 % of the area marked as differing by 10 x the noise, residuals of both poses the same noise
    # there): the few tested cells, calibrated by the others, stay a standard normal within the
    # sampling error of 40 trials (measured: sd 0.74, largest 1.9)
    rng = np.random.default_rng(1)
    xy, pos = _grid()
    z, quiet = [], []
    for _ in range(40):
        ra, rb = (_correlated(rng, xy.shape[:2], 0.5) for _ in range(2))
        gap = _gap_noise(rng, xy.shape[:2])
        quiet.append(pose_evidence(ra, rb, pos, cell_mm=3.0, gap_mm=gap).sigma)
        z.append(pose_evidence(ra, rb, pos, cell_mm=3.0, gap_mm=gap + 10 * NOISE_MM * _disc(xy, 0.01)).sigma)
    z = np.asarray(z)
    assert np.abs(z).max() < 5.0, "no trial may reach the acceptance level"
    assert 0.5 < z.std() < 1.4
    assert abs(z.mean()) < 0.4
    # where the poses predict the same surface everywhere there is nothing to test: no evidence at all
    assert np.abs(quiet).max() < 2.0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_feature_of_ten_times_the_noise_over_half_a_percent_is_decided(seed):
    # the same feature over 0.5 % of the area: diluted over every cell it gave 2-3 sigma; tested where
    # the two poses predict different surfaces (the feature's own disc) against the null the other
    # cells give, it is overwhelming -- and never evidence for the pose without it
    rng = np.random.default_rng(seed)
    xy, pos = _grid()
    ra, rb = (_correlated(rng, xy.shape[:2], 0.5) for _ in range(2))
    feature = 10 * NOISE_MM * _disc(xy, 0.005)
    gap = _gap_noise(rng, xy.shape[:2]) + feature
    ev = pose_evidence(ra, rb + feature, pos, cell_mm=3.0, gap_mm=gap)
    assert ev.sigma > 5.0
    assert ev.cells >= 1 and ev.background_cells > 250
    assert pose_evidence(rb + feature, ra, pos, cell_mm=3.0, gap_mm=gap).sigma < 1.0
    assert pose_evidence(ra, rb + feature, pos, cell_mm=3.0).sigma < 5.0, "diluted over every cell it is not"


def test_self_gap_finds_where_a_motion_moves_a_bump_off_itself():
    # a plane with a 1 mm bump moved 20 mm along itself: the poses differ by that motion, and the
    # predicted surfaces differ by the bump's height where the bump is and where it lands, nowhere else
    from processing.geometry.registration.clouds import _Level
    from processing.geometry.registration.symmetry import _self_gap

    g = np.arange(0.0, 60.0, 0.5)
    xy = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    bump = np.exp(-0.5 * np.sum((xy - 30.0) ** 2, axis=1) / 3.0 ** 2)
    pts = np.column_stack([xy, bump])
    level = _Level(pts, np.tile([0.0, 0.0, 1.0], (len(pts), 1)))
    motion = np.eye(4)
    motion[0, 3] = 20.0
    gap = _self_gap(level, motion, reach=3.0, spacing=0.5)
    bump_there = np.exp(-0.5 * np.sum((xy - [50.0, 30.0]) ** 2, axis=1) / 3.0 ** 2)
    bump_here = np.exp(-0.5 * np.sum((xy - [10.0, 30.0]) ** 2, axis=1) / 3.0 ** 2)
    inside = (xy[:, 0] > 22) & (xy[:, 0] < 38)    # moved either way, these points land on the cloud
    # tolerance 0.15 mm: the tangent plane is the flat plane's, the bump's slope tilts the true one
    expect = np.maximum(np.abs(bump - bump_there), np.abs(bump - bump_here))
    assert np.abs(gap[inside] - expect[inside]).max() < 0.15
    assert gap[inside].max() > 0.9
    flat = np.linalg.norm(xy - 30.0, axis=1) > 15.0
    assert np.abs(gap[flat & inside]).max() < 1e-3     # the Gaussian tail, 15 mm = 5 sd out


# ------------------------------------------------------------------ surface partners on a curved surface
CYL_RADIUS_MM, CYL_SPACING_MM = 30.0, 0.5


def _cylinder_pass(rng: np.random.Generator, az_deg: tuple[float, float], boss_mm: float = 0.0,
                   boss_sigma_mm: float = 1.25) -> tuple[np.ndarray, np.ndarray]:
    """A pass over part of a cylinder (axis z, azimuths ``az_deg``, z 0-40 mm), jittered samples, radial noise.

    An optional Gaussian boss of ``boss_mm`` stands on the surface at azimuth 45 deg, 20 mm up.  Normals
    by PCA of the 12 nearest neighbours, turned outward (as a pass's normals are fitted).
    """
    from scipy.spatial import cKDTree

    arc = np.arange(np.radians(az_deg[0]) * CYL_RADIUS_MM, np.radians(az_deg[1]) * CYL_RADIUS_MM, CYL_SPACING_MM)
    s, z = (a.ravel() for a in np.meshgrid(arc, np.arange(0.0, 40.0, CYL_SPACING_MM)))
    s = s + rng.uniform(-0.2, 0.2, s.shape) * CYL_SPACING_MM
    z = z + rng.uniform(-0.2, 0.2, z.shape) * CYL_SPACING_MM
    d2 = (s - np.radians(45.0) * CYL_RADIUS_MM) ** 2 + (z - 20.0) ** 2
    r = CYL_RADIUS_MM + boss_mm * np.exp(-0.5 * d2 / boss_sigma_mm ** 2) + rng.normal(0.0, NOISE_MM, s.shape)
    phi = s / CYL_RADIUS_MM
    pts = np.column_stack([r * np.cos(phi), r * np.sin(phi), z])
    _, idx = cKDTree(pts).query(pts, k=12)
    nb = pts[idx] - pts[idx].mean(axis=1, keepdims=True)
    nrm = np.linalg.eigh(np.einsum("nki,nkj->nij", nb, nb))[1][:, :, 0]
    out = np.column_stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)])
    return pts, nrm * np.sign(np.sum(nrm * out, axis=1))[:, None]


def _turn_deg(deg: float) -> np.ndarray:
    t = np.eye(4)
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    t[:2, :2] = [[c, -s], [s, c]]
    return t


def _cylinder_evidence(a, b, t_a, t_b) -> tuple[float, float]:
    """The two tests registration uses (every moving cell, focused), on true surface partners of both passes."""
    from processing.geometry.registration.clouds import _Level
    from processing.geometry.registration.pose_evidence import border_points, surface_residuals
    from processing.geometry.registration.symmetry import _self_gap

    sp, tp = CYL_SPACING_MM, CYL_SPACING_MM
    (bp, bn), (ap, an) = b, a
    b_edge, a_edge = border_points(bp, bn, sp), border_points(ap, an, tp)

    def residuals(t):
        return np.concatenate([surface_residuals(bp, bn, ap, an, t, 2 * sp, sp, 30.0, a_edge),
                               surface_residuals(ap, an, bp, bn, np.linalg.inv(t), 2 * sp, sp, 30.0, b_edge)])

    pos = np.concatenate([bp @ t_a[:3, :3].T + t_a[:3, 3], ap])
    gap = np.concatenate([_self_gap(_Level(bp, bn), np.linalg.inv(t_a) @ t_b, 6 * sp, sp),
                          _self_gap(_Level(ap, an), t_a @ np.linalg.inv(t_b), 6 * sp, sp)])
    ra, rb = residuals(t_a), residuals(t_b)
    return (pose_evidence(ra, rb, pos, 3 * sp).sigma, pose_evidence(ra, rb, pos, 3 * sp, gap_mm=gap).sigma)


def test_surface_partners_keep_the_null_on_two_equally_right_poses_of_a_cylinder():
    # two passes over different azimuths of a plain cylinder (their borders apart): the true pose and the
    # pose turned 12 deg about the axis fit equally well; 30 trials, both tests stay a standard normal
    # within the sampling error of 30 trials (and far below the 5 sigma of acceptance)
    rng = np.random.default_rng(7)
    z = np.array([_cylinder_evidence(_cylinder_pass(rng, (0.0, 80.0)), _cylinder_pass(rng, (15.0, 95.0)),
                                     np.eye(4), _turn_deg(12.0)) for _ in range(30)])
    assert np.abs(z).max() < 4.0, "no trial may come near the acceptance level"
    assert z[:, 0].std() < 1.5 and abs(z[:, 0].mean()) < 0.6
    assert z[:, 1].std() < 1.5 and abs(z[:, 1].mean()) < 0.6


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_boss_of_ten_times_the_noise_over_half_a_percent_of_a_cylinder_is_decided(seed):
    # a 1 mm boss (20 x the noise) whose part 10 x the noise high covers about 0.5 % of the two passes'
    # overlap (65 deg x 40 mm): the true pose over the pose turned 12 deg (the boss landing on plain
    # surface) is decided, the other way round it is evidence against
    rng = np.random.default_rng(seed)
    a, b = _cylinder_pass(rng, (0.0, 80.0), 1.0), _cylinder_pass(rng, (15.0, 95.0), 1.0)
    share = np.pi * (1.25 * np.sqrt(2 * np.log(2.0))) ** 2 / (np.radians(65.0) * CYL_RADIUS_MM * 40.0)
    assert 0.004 < share < 0.006
    right = _cylinder_evidence(a, b, np.eye(4), _turn_deg(12.0))
    wrong = _cylinder_evidence(a, b, _turn_deg(12.0), np.eye(4))
    assert max(right) >= 5.0, right
    assert max(wrong) < 1.0, wrong
