"""Registration of passes (processing.geometry.registration) against ground truth.

Partial views come from a small ring scan of a known mesh placed at random on
the table (as the station sees one pass: the sensor turns about the table
axis, the underside against the table and self-occluded parts are missing),
with 0.05 mm range noise.  The true relative pose of two passes is known from
the placements, so every recovered pose is checked in degrees and millimetres.
The clouds are small (a few thousand points) to keep the file fast; with a
sample spacing of about a millimetre the pose error is bounded by a fraction
of that spacing (the tolerances below), not by the noise.

Several passes (the pose graph, merging) are tested in tests/geometry/test_registration_passes.py.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from mocks.procedural_hawk import hawk_head
from processing.geometry.registration import (
    MIN_POINTS,
    PRESETS,
    RegistrationError,
    RegistrationPreset,
    pose_difference,
    register_from_picks,
    register_pair,
    register_passes,
    registration_preset,
    rigid_from_picks,
    rotation_samples,
    transform_points,
)

NOISE_MM = 0.05
#: Pose tolerance for clouds with ~1 mm sample spacing (see the module docstring).
TOL_DEG, TOL_MM = 0.3, 0.3


# ---------------------------------------------------------------------------
# Simulated passes
# ---------------------------------------------------------------------------


def _placement(vertices: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A random rigid placement (object -> table) resting on z = 0, centred on the axis."""
    m = np.eye(4)
    m[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    v = vertices @ m[:3, :3].T
    lo, hi = v.min(axis=0), v.max(axis=0)
    m[:3, 3] = [-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]]
    return m


def _scan(vertices, triangles, placement, rng, *, n_angles=120, n_points=200, noise_mm=NOISE_MM):
    """One revolution of a laser line scanner (table frame points and outward normals).

    The emitter stands off on +x at mid height and fans its rays in the vertical
    plane; at table angle a the table frame sees the emitter turned by -a.
    Points are kept where the ray meets the surface within 75 degrees of its
    normal, the camera 60 mm beside the emitter sees the point, and the point is
    above the table (z > 0.3 mm); range noise is Gaussian along the ray.
    """
    import open3d as o3d

    v = vertices @ placement[:3, :3].T + placement[:3, 3]
    radius = float(np.max(np.linalg.norm(v[:, :2], axis=1)))
    height = float(v[:, 2].max())
    standoff = max(200.0, 2.5 * max(radius, height))
    h = height / 2
    half = math.atan2(0.6 * height, standoff - radius) + 0.05
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(np.asarray(triangles, np.uint32)))
    a = -np.radians(np.arange(n_angles) * 360.0 / n_angles)
    c, s = np.cos(a), np.sin(a)
    theta = np.linspace(-half, half, n_points)
    emit = np.stack([standoff * c, standoff * s, np.full_like(c, h)], axis=1)
    cam = np.stack([standoff * c - 60.0 * s, standoff * s + 60.0 * c, np.full_like(c, h)], axis=1)
    dx, dz = -np.cos(theta), np.sin(theta)
    d = np.stack([c[:, None] * dx, s[:, None] * dx, np.broadcast_to(dz, (n_angles, n_points))], axis=-1).reshape(-1, 3)
    o = np.repeat(emit, n_points, axis=0)
    ans = scene.cast_rays(o3d.core.Tensor(np.concatenate([o, d], axis=1).astype(np.float32)))
    t_hit = ans["t_hit"].numpy().astype(np.float64)
    nrm = ans["primitive_normals"].numpy().astype(np.float64)
    hit = np.isfinite(t_hit)
    t_hit = np.where(hit, t_hit, 0.0)
    p = o + d * t_hit[:, None]
    cos_i = np.sum(nrm * -d, axis=1)
    ok = hit & (np.abs(cos_i) >= math.cos(math.radians(75.0))) & (p[:, 2] > 0.3)
    to_cam = np.repeat(cam, n_points, axis=0) - p
    dist = np.linalg.norm(to_cam, axis=1)
    u = to_cam / np.maximum(dist, 1e-12)[:, None]
    occ = scene.cast_rays(o3d.core.Tensor(np.concatenate([p + 1e-3 * u, u], axis=1).astype(np.float32)))
    ok &= ~(occ["t_hit"].numpy() < dist - 2e-3)
    p = o + d * (t_hit + rng.normal(0.0, noise_mm, t_hit.shape))[:, None]
    n = np.where((cos_i < 0)[:, None], -nrm, nrm)
    return p[ok], n[ok]


def _pair(vertices, triangles, seed, **scan):
    """Two passes in random placements: (source, source normals, target, target normals,
    true transform source -> target)."""
    rng = np.random.default_rng(seed)
    m0, m1 = _placement(vertices, rng), _placement(vertices, rng)
    p0, n0 = _scan(vertices, triangles, m0, rng, **scan)
    p1, n1 = _scan(vertices, triangles, m1, rng, **scan)
    return p1, n1, p0, n0, m0 @ np.linalg.inv(m1)


def _egg(bump_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """An egg (surface of revolution about z, 70 mm long, 44-51 mm wide) with one
    Gaussian bump of ``bump_mm`` on its side (none: exactly symmetric)."""
    import open3d as o3d

    sphere = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=60)
    d = np.asarray(sphere.vertices)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    f = 1.0 + 0.15 * d[:, 2]
    p = np.stack([22.0 * d[:, 0] * f, 22.0 * d[:, 1] * f, 35.0 * d[:, 2]], axis=1)
    centre = np.array([1.0, 0.0, 0.3]) / np.linalg.norm([1.0, 0.0, 0.3])
    p += d * (bump_mm * np.exp(-0.5 * (np.arccos(np.clip(d @ centre, -1, 1)) / 0.18) ** 2))[:, None]
    return p, np.asarray(sphere.triangles)


@pytest.fixture(scope="module")
def hawk():
    mesh = hawk_head(8000)
    return mesh.vertices, mesh.triangles


def _error(result_t, truth, points):
    return pose_difference(result_t, truth, points)


# ---------------------------------------------------------------------------
# Building blocks
# ---------------------------------------------------------------------------


def test_rotation_samples_are_proper_rotations_covering_so3():
    assert rotation_samples(1).shape == (1, 3, 3)
    r = rotation_samples(1024)
    assert r.shape == (1024, 3, 3)
    assert np.allclose(r @ r.transpose(0, 2, 1), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(r), 1.0)
    # Covering radius: every rotation is close to a sample.  n balls of angular radius
    # t cover SO(3) only if n (t - sin t) / pi >= 1 (Haar measure), so t >= (6 pi / n)^(1/3)
    # at best; an even sampling stays within 1.5 times that.
    probes = Rotation.random(3000, random_state=7).as_matrix()
    trace = np.einsum("aij,bij->ab", probes, r).max(axis=1)
    worst = np.degrees(np.arccos(np.clip((trace - 1) / 2, -1, 1))).max()
    bound = np.degrees((6 * np.pi / 1024) ** (1 / 3))
    assert worst <= 1.5 * bound


@pytest.mark.parametrize("n", [0, -3, 2.5, True])
def test_rotation_samples_rejects_bad_counts(n):
    with pytest.raises(RegistrationError, match="positive integer"):
        rotation_samples(n)


def test_pose_difference_closed_form():
    a = np.eye(4)
    b = np.eye(4)
    b[:3, :3] = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    rot, disp = pose_difference(a, b)
    assert rot == pytest.approx(30.0, abs=1e-9) and disp == pytest.approx(0.0, abs=1e-12)
    # a point 10 mm from the axis moves along a 30 degree chord: 2 * 10 * sin(15 deg)
    rot, disp = pose_difference(a, b, [[10.0, 0.0, 5.0], [0.0, 0.0, 1.0]])
    assert disp == pytest.approx(20 * math.sin(math.radians(15)), rel=1e-12)


@settings(max_examples=80, deadline=None)
@given(q=st.lists(st.floats(-1, 1, allow_nan=False), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1),
       tiny=st.sampled_from([0.0, 1e-10, 1e-7, 1e-4]), half=st.booleans())
def test_pose_difference_angle_matches_scipy_near_zero_and_half_turn(q, tiny, half):
    # the angle between R and R composed with a tiny turn (or a half turn plus a tiny turn)
    a = Rotation.from_quat(q)
    axis = np.array([0.36, -0.48, 0.8])
    delta = Rotation.from_rotvec(axis * (math.pi - tiny if half else tiny))
    b = a * delta
    ta, tb = np.eye(4), np.eye(4)
    ta[:3, :3], tb[:3, :3] = a.as_matrix(), b.as_matrix()
    rot, _ = pose_difference(ta, tb)
    assert rot == pytest.approx(math.degrees((a.inv() * b).magnitude()), abs=1e-6)


def test_transform_points_matches_homogeneous_product():
    rng = np.random.default_rng(0)
    t = np.eye(4)
    t[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    t[:3, 3] = rng.normal(size=3) * 100
    p = rng.normal(size=(20, 3))
    expected = (t @ np.c_[p, np.ones(20)].T).T[:, :3]
    assert np.allclose(transform_points(t, p), expected, atol=1e-12)


quaternions = st.lists(st.floats(-1, 1, allow_nan=False), min_size=4, max_size=4).filter(
    lambda q: np.linalg.norm(q) > 0.1
)


@settings(max_examples=60, deadline=None)
@given(q=quaternions, shift=st.lists(st.floats(-1e4, 1e4), min_size=3, max_size=3),
       size=st.floats(1e-2, 1e4), n=st.integers(3, 12))
def test_rigid_from_picks_recovers_any_motion(q, shift, size, n):
    # any rotation (including half turns), any offset and object size from 10 um to 10 m
    rng = np.random.default_rng(n)
    src = rng.normal(size=(n, 3)) * size
    src[:3] = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]]) * size  # never collinear
    r = Rotation.from_quat(q).as_matrix()
    tgt = src @ r.T + np.asarray(shift)
    t, rms = rigid_from_picks(src, tgt)
    assert np.allclose(t[:3, :3], r, atol=1e-9)
    assert np.linalg.det(t[:3, :3]) == pytest.approx(1.0)
    scale = size + np.abs(shift).max()
    assert np.allclose(t[:3, 3], shift, atol=1e-9 * scale)
    assert rms <= 1e-9 * scale


def test_rigid_from_picks_never_returns_a_reflection():
    rng = np.random.default_rng(3)
    src = rng.normal(size=(6, 3)) * 10
    mirrored = src * [-1, 1, 1]  # no rotation maps a shape onto its mirror image
    t, rms = rigid_from_picks(src, mirrored)
    assert np.linalg.det(t[:3, :3]) == pytest.approx(1.0)
    assert rms > 1.0


@pytest.mark.parametrize(
    ("src", "tgt", "match"),
    [
        ([[0, 0, 0], [1, 0, 0]], [[0, 0, 0], [1, 0, 0]], "at least 3"),
        ([[0, 0, 0], [1, 1, 1], [2, 2, 2]], [[0, 0, 0], [1, 0, 0], [0, 1, 0]], "collinear"),
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0, 0], [2, 0, 0], [4, 0, 0]], "collinear"),
        ([[0, 0, 0], [0, 0, 0], [0, 0, 0]], [[0, 0, 0], [1, 0, 0], [0, 1, 0]], "collinear"),
        ([[0, 0, 0], [1, 0, 0], [0, np.nan, 0]], [[0, 0, 0], [1, 0, 0], [0, 1, 0]], "NaN"),
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], "one to one"),
        ([[0, 0], [1, 0], [0, 1]], [[0, 0], [1, 0], [0, 1]], r"\(M, 3\)"),
    ],
)
def test_rigid_from_picks_rejects_bad_picks(src, tgt, match):
    with pytest.raises(RegistrationError, match=match):
        rigid_from_picks(np.asarray(src, float), np.asarray(tgt, float))


def test_presets_trade_samples_and_voxels():
    d, s, r = PRESETS["draft"], PRESETS["standard"], PRESETS["reference"]
    assert d.rotation_samples < s.rotation_samples < r.rotation_samples
    assert d.icp_voxels[-1] > s.icp_voxels[-1] > r.icp_voxels[-1]
    assert registration_preset("standard") is s and registration_preset(s) is s
    with pytest.raises(RegistrationError, match="draft, standard, reference"):
        registration_preset("fast")
    with pytest.raises(RegistrationError, match="coarse to fine"):
        RegistrationPreset(name="x", rotation_samples=10, search_voxel=0.1, search_points=100,
                           search_keep=0.5, hypotheses=2, icp_voxels=(0.01, 0.02),
                           icp_iterations=10, icp_points=1000, icp_distance=2.0, fpfh=False)
    with pytest.raises(RegistrationError, match="rotation_samples"):
        RegistrationPreset(name="x", rotation_samples=0, search_voxel=0.1, search_points=100,
                           search_keep=0.5, hypotheses=2, icp_voxels=(0.02,),
                           icp_iterations=10, icp_points=1000, icp_distance=2.0, fpfh=False)


# ---------------------------------------------------------------------------
# Pairs with ground truth
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [11, 12])
def test_hawk_passes_register_without_a_guess(hawk, seed):
    src, sn, tgt, tn, truth = _pair(*hawk, seed)
    res = register_pair(src, tgt, source_normals=sn, target_normals=tn, preset="standard", seed=seed)
    rot, disp = _error(res.transform, truth, src)
    assert res.verified, res.reason
    assert res.reason == "ok"
    assert rot < TOL_DEG and disp < TOL_MM
    assert 0.5 < res.overlap <= 1.0
    assert res.rmse_mm <= 4 * res.expected_rmse_mm
    assert res.margin >= PRESETS["standard"].min_margin
    assert res.seconds > 0 and res.method == "global"


def test_estimated_normals_and_a_far_offset_do_not_matter(hawk):
    # no normals given (fitted and oriented away from the centroid), clouds 10 m from the origin
    src, _, tgt, _, truth = _pair(*hawk, 13)
    shift = np.eye(4)
    shift[:3, 3] = [1e4, -1e4, 5e3]
    res = register_pair(transform_points(shift, src), tgt, preset="draft", seed=1)
    assert res.verified, res.reason
    rot, disp = _error(res.transform, truth @ np.linalg.inv(shift), transform_points(shift, src))
    assert rot < TOL_DEG and disp < TOL_MM


@pytest.mark.parametrize("seed", [21, 22, 23])
def test_nearly_symmetric_egg_is_resolved_or_reported(seed):
    # a surface of revolution with a 3 mm bump: the bump alone fixes the turn about the axis
    egg = _egg(3.0)
    src, sn, tgt, tn, truth = _pair(*egg, seed, n_angles=90, n_points=160)
    res = register_pair(src, tgt, source_normals=sn, target_normals=tn, preset="draft", seed=seed)
    rot, disp = _error(res.transform, truth, src)
    if res.verified:
        assert rot < TOL_DEG and disp < TOL_MM, "a verified pose must be right"
    else:
        assert "ambiguous" in res.reason or "undetermined" in res.reason
    # with this bump the pose is in fact found
    assert res.verified


@pytest.mark.parametrize("seed", [31, 32])
def test_exactly_symmetric_shapes_are_reported_unverified(seed):
    import open3d as o3d

    box = o3d.geometry.TriangleMesh.create_box(40.0, 25.0, 15.0).subdivide_midpoint(4)
    shapes = {"egg": _egg(0.0), "box": (np.asarray(box.vertices), np.asarray(box.triangles))}
    for name, (v, t) in shapes.items():
        src, sn, tgt, tn, _ = _pair(v, t, seed, n_angles=90, n_points=160)
        res = register_pair(src, tgt, source_normals=sn, target_normals=tn, preset="draft", seed=seed)
        assert not res.verified, f"{name}: a symmetric shape has no single right pose"
        assert "ambiguous" in res.reason or "undetermined" in res.reason, res.reason


@pytest.mark.parametrize("bump_mm", [3.0, 0.0])
def test_picks_then_icp(bump_mm):
    egg = _egg(bump_mm)
    src, sn, tgt, tn, truth = _pair(*egg, 41, n_angles=90, n_points=160)
    rng = np.random.default_rng(5)
    picked = src[rng.choice(len(src), 4, replace=False)]
    # the user clicks within half a millimetre of the right spots
    on_target = transform_points(truth, picked) + rng.uniform(-0.5, 0.5, (4, 3))
    res = register_from_picks(picked, on_target, src, tgt, source_normals=sn, target_normals=tn,
                              preset="draft")
    assert res.method == "picks" and res.verified, res.reason
    assert math.isnan(res.margin)
    rot, disp = _error(res.transform, truth, src)
    kabsch_rot, _ = _error(rigid_from_picks(picked, on_target)[0], truth, src)
    assert kabsch_rot > 0.5  # the picks alone are off by about a degree
    if bump_mm:
        # the bump fixes the turn about the axis: the ICP removes the picking error
        assert rot < TOL_DEG and disp < TOL_MM
    else:
        # nothing fixes the turn about the axis of an exact surface of revolution: the
        # result keeps the picks' own error there, and the ICP makes it no worse
        assert rot < kabsch_rot + TOL_DEG


def test_picks_without_clouds_give_the_kabsch_fit_unverified():
    src = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0]], float)
    t = np.eye(4)
    t[:3, 3] = [1, 2, 3]
    res = register_from_picks(src, src + [1, 2, 3])
    assert not res.verified and "no clouds" in res.reason
    assert np.allclose(res.transform, t, atol=1e-12)
    with pytest.raises(RegistrationError, match="both clouds"):
        register_from_picks(src, src, src)


def test_clouds_without_overlap_are_reported(hawk):
    # the front (beak) and the back (neck) of one pass share no surface
    src, sn, _, _, _ = _pair(*hawk, 51)
    c = src.mean(axis=0)
    axis = np.linalg.svd(src - c)[2][0]
    along = (src - c) @ axis
    front, back = along > 8.0, along < -8.0
    res = register_pair(src[front], src[back], source_normals=sn[front], target_normals=sn[back],
                        preset="draft")
    assert not res.verified
    assert res.reason != "ok"


# ---------------------------------------------------------------------------
# Bad input
# ---------------------------------------------------------------------------


GOOD = np.random.default_rng(1).normal(size=(100, 3)) * [20, 10, 5]


@pytest.mark.parametrize(
    ("cloud", "match"),
    [
        (np.zeros((0, 3)), "is empty"),
        (np.array([[1.0, 2.0, 3.0]]), "only 1 point"),
        (GOOD[: MIN_POINTS - 1], f"only {MIN_POINTS - 1} point"),
        (np.outer(np.arange(50.0), [1, 2, 3]), "on a line"),
        (np.c_[GOOD[:, :2], np.zeros(100)] @ Rotation.from_euler("xy", [30, 40], degrees=True).as_matrix().T,
         "in one plane"),
        (np.tile([1.0, 2.0, 3.0], (30, 1)), "coincide"),
        (np.vstack([GOOD, [[np.nan, 0, 0]]]), "1 NaN or infinite"),
        (np.vstack([GOOD, [[np.inf, 0, 0]]]), "1 NaN or infinite"),
        (GOOD[:, :2], r"\(N, 3\)"),
        ("points", r"\(N, 3\)"),
    ],
)
def test_bad_clouds_get_clear_errors(cloud, match):
    with pytest.raises(RegistrationError, match=match) as err:
        register_pair(cloud, GOOD, preset="draft")
    assert "source" in str(err.value)
    with pytest.raises(RegistrationError, match=match) as err:
        register_passes([GOOD, cloud], names=["a.ply", "b.ply"], preset="draft")
    assert "b.ply" in str(err.value)


def test_bad_normals_and_arguments_get_clear_errors():
    with pytest.raises(RegistrationError, match="normals must have the shape"):
        register_pair(GOOD, GOOD, source_normals=np.ones((3, 3)))
    with pytest.raises(RegistrationError, match="normals contain NaN"):
        register_pair(GOOD, GOOD, target_normals=np.full(GOOD.shape, np.nan))
    with pytest.raises(RegistrationError, match="not a rigid transform"):
        register_pair(GOOD, GOOD, initial=np.diag([2.0, 1, 1, 1]))
    with pytest.raises(RegistrationError, match="no clouds"):
        register_passes([])
    with pytest.raises(RegistrationError, match="'all' or 'sequential'"):
        register_passes([GOOD, GOOD], pairs="every")
    with pytest.raises(RegistrationError, match="1 names for 2 clouds"):
        register_passes([GOOD, GOOD], names=["a"])
    with pytest.raises(RegistrationError, match=r"give the pair pass 1 - pass 2 in that order, with the points on pass 1"):
        register_passes([GOOD, GOOD], picks={(1, 0): (GOOD[:3], GOOD[:3])})
    with pytest.raises(RegistrationError, match=r"pair of indices \(0, 5\) is not one of the registered pairs "
                                                r"\(pass 1 - pass 2, pass 2 - pass 3, pass 1 - pass 3\)"):
        register_passes([GOOD, GOOD, GOOD], pairs="sequential", picks={(0, 5): (GOOD[:3], GOOD[:3])})


def test_messages_number_passes_from_1_throughout():
    """A pass no verified pair reaches is reported with 1-based pass numbers only, as its pairs are."""
    rng = np.random.default_rng(2)
    d = rng.normal(size=(1500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    bump = 1 + 0.3 * np.exp(-8 * np.sum((d - [0.5, 0.7, 0.5]) ** 2, axis=1))
    blob = d * [30, 20, 12] * ((1 + 0.2 * d[:, 0]) * bump)[:, None]
    turn = np.eye(4)
    turn[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    sphere = d * 25.0                                  # no pose of a sphere is better than another
    res = register_passes([blob, transform_points(turn, blob), sphere], preset="draft")
    assert [p.registered for p in res.poses] == [True, True, False]
    reason = res.poses[2].reason
    assert reason.startswith("pass 3 is not connected to pass 1 by verified pairs (pass 1 - pass 3: "), reason
    assert "pass 2 - pass 3: " in reason and "pass 0" not in reason and not re.search(r"pair \d", reason), reason


# ---------------------------------------------------------------------------
# Thin walls: partners on the other face


def _thin_shell(rng: np.random.Generator, wall_mm: float, view: np.ndarray, n: int = 9000):
    """Both faces of an egg-shaped bowl's wall ``wall_mm`` thick, as seen from ``view`` (outward normals).

    The outer face is the lower part of an ellipsoid (semi-axes 40, 30, 25 mm, a bump that fixes every
    turn); the inner face lies ``wall_mm`` inside it along the normal, its normals into the cavity.  A
    face point is kept when its normal is within 80 deg of ``view`` (a partial view), with 0.05 mm noise
    along the normal.
    """
    theta = np.arccos(rng.uniform(np.cos(np.radians(100.0)), 1.0, n))
    phi = rng.uniform(-np.pi, np.pi, n)
    d = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), -np.cos(theta)], 1)
    bump = 1.0 + 0.15 * np.exp(-30.0 * np.sum((d - [0.6, 0.5, -0.6]) ** 2, axis=1))
    outer = d * [40.0, 30.0, 25.0] * bump[:, None]
    normal = outer / np.array([40.0, 30.0, 25.0]) ** 2
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    inner = outer - wall_mm * normal
    pts = np.concatenate([outer, inner])
    nrm = np.concatenate([normal, -normal])
    keep = nrm @ view > np.cos(np.radians(80.0))
    pts = pts[keep] + rng.normal(0.0, NOISE_MM, (int(keep.sum()), 1)) * nrm[keep]
    return pts, nrm[keep]


@pytest.mark.parametrize("wall_mm", [1.0, 2.0])
def test_thin_wall_stays_at_the_true_pose(wall_mm):
    # Started at the truth, the ICP and the checks must keep it: partners across the wall (the other
    # face, its normal reversed, a wall's thickness away) once pulled the pose toward the middle of the
    # wall and inflated the residual past the RMS check.  Tolerance 0.1 deg / 0.1 mm: a tenth of the
    # ~1 mm sample spacing, and well under the wall's thickness.
    rng = np.random.default_rng(3)
    view_a = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])
    view_b = np.array([-0.4, 0.3, 1.0]) / np.linalg.norm([-0.4, 0.3, 1.0])
    a, na = _thin_shell(rng, wall_mm, view_a)
    b, nb = _thin_shell(rng, wall_mm, view_b)
    truth = np.eye(4)
    truth[:3, :3] = Rotation.from_euler("xyz", [20.0, -10.0, 35.0], degrees=True).as_matrix()
    truth[:3, 3] = [4.0, -3.0, 2.0]
    res = register_pair(b, transform_points(truth, a), source_normals=nb, target_normals=na @ truth[:3, :3].T,
                        preset="draft", initial=truth)
    rot, disp = pose_difference(res.transform, truth, b)
    assert res.verified, res.reason
    assert rot < 0.1 and disp < 0.1, (rot, disp)
    assert res.normal_agreement > 0.9
