"""Registration of turned objects of the simulated world against the true placements.

Passes come from :func:`mocks.pass_cloud.simulated_pass` (the station's sensor, placements and
0.05 mm range noise).  A right pose is within 0.5 deg and 0.5 mm (largest displacement of the source
points) of the truth, the limits of the scan-processing benchmark; a verified pose must be right.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from mocks.pass_cloud import simulated_pass
from mocks.world import World
from processing.geometry.registration import pose_difference, register_pair

TOL_DEG, TOL_MM = 0.5, 0.5


@functools.lru_cache(maxsize=2)
def _pair(name: str, seed: int):
    w = World.turned(name)
    a, b = simulated_pass(w, seed, 2), simulated_pass(w, seed, 3)
    return a, b, a.pose @ np.linalg.inv(b.pose)


def _registered(name: str, seed: int):
    """The pair registered automatically at ``standard``, and its rotation (deg) and displacement (mm) errors."""
    a, b, truth = _pair(name, seed)
    res = register_pair(b.points, a.points, source_normals=b.normals, target_normals=a.normals,
                        preset="standard", seed=seed)
    rot, disp = pose_difference(res.transform, truth, b.points)
    return res, rot, disp


def test_bare_bowl_is_ambiguous_in_shape_with_the_evidence_in_the_reason():
    a, b, truth = _pair("plain-bowl:bare", 0)
    res = register_pair(b.points, a.points, source_normals=b.normals, target_normals=a.normals,
                        preset="draft", seed=0)
    assert not res.verified
    assert "ambiguous" in res.reason and "sigma of the range noise" in res.reason, res.reason
    assert np.isfinite(res.evidence_sigma) and res.evidence_sigma < 5.0


@pytest.mark.slow
def test_vase_with_its_boss_in_both_passes_registers_by_evidence():
    # seed 0, placements 2 and 3: the boss is measured in both passes; the margin alone (about 2 %)
    # refused this pair, the evidence where the poses differ accepts it
    res, rot, disp = _registered("vase", 0)
    assert res.verified, res.reason
    assert rot < TOL_DEG and disp < TOL_MM
    assert res.margin < 0.05 and res.evidence_sigma >= 5.0


def test_a_turned_pose_settles_where_one_level_of_icp_stops_short():
    # the vase's basin about its axis is flat: from the truth turned 6 deg, one pyramid level's iterations
    # leave the turn where another round still moves it; settled, a further round does not, and it is closer
    # to the truth
    from processing.geometry.registration.clouds import _as_cloud
    from processing.geometry.registration.photo_consistency import _turned
    from processing.geometry.registration.presets import registration_preset
    from processing.geometry.registration.refinement import _icp_pyramid, _pair_scale, _pyramid, _settle
    from processing.geometry.registration.turn_uncertainty import _about_axis_deg

    a, b, truth = _pair("vase", 28)
    p = registration_preset("standard")
    src, tgt = _as_cloud(b.points, b.normals, "source"), _as_cloud(a.points, a.normals, "target")
    decide = _pyramid(p, _pair_scale(src, tgt), src, tgt)[-2]
    axis = a.pose[:3, 2]
    start = _turned(truth, axis, a.pose[:3, 3], np.radians([6.0]))[0]
    one = _icp_pyramid(src, tgt, p, start, [decide], settled=True)
    settled = _settle(src, tgt, p, start, decide)

    def moved_deg(t):
        return abs(_about_axis_deg(_icp_pyramid(src, tgt, p, t, [decide], settled=True), t, axis))

    assert moved_deg(one) > 0.5
    assert moved_deg(settled) < 0.05
    assert abs(_about_axis_deg(settled, truth, axis)) < abs(_about_axis_deg(one, truth, axis)) - 1.0


@pytest.mark.slow
def test_vase_pair_compared_at_settled_poses_is_decided_with_a_bound_that_holds_its_turn():
    # seed 28: the boss in both passes (0.63 % of the overlap, from the truth).  Weighed before the poses
    # settled, the pose chosen was 3.2 deg from the truth and a rival 9.8 deg away stood at 3.0 sigma:
    # ambiguous.  Compared at settled poses the evidence decides.  At these 72 profiles per revolution the
    # boss is crossed every 5 deg of table angle: the turn chosen is 0.37 deg off and the profile of the
    # cost about the axis states +-0.56 deg (2 sigma), so the pair is reported turn uncertain, not verified
    # (at 200 profiles the same seed is verified 0.06 deg off with +-0.15 deg; docs/BENCHMARKS.md)
    from processing.geometry.registration.turn_uncertainty import _about_axis_deg

    a, _, truth = _pair("vase", 28)
    res, rot, disp = _registered("vase", 28)
    assert res.evidence_sigma >= 5.0, res.reason
    assert rot < TOL_DEG and disp < TOL_MM, (rot, disp)
    assert abs(_about_axis_deg(res.transform, truth, a.pose[:3, 2])) <= res.turn_uncertainty_deg
    assert res.verified == (res.turn_uncertainty_deg <= TOL_DEG), res.reason
    if not res.verified:
        assert "turn about the symmetry axis is uncertain" in res.reason, res.reason


@pytest.mark.slow
def test_colours_that_contradict_a_turn_the_shape_verified_refuse_the_pair():
    # seed 0: the shape alone verifies the turn (the test above).  Paint a crest on each pass where the
    # object's azimuth is 100 +- 15 deg, 20-40 mm up, but on the target 30 deg further round: the colours
    # then decide a turn 30 deg from the shape's, far outside the two turns' joint bound.  Two
    # measurements of one turn that contradict each other verify nothing.
    a, b, truth = _pair("vase", 0)

    def painted(p, centre_deg):
        x = (p.points - p.pose[:3, 3]) @ p.pose[:3, :3]          # the object's frame (+z its axis)
        az = np.degrees(np.arctan2(x[:, 1], x[:, 0]))
        crest = (np.abs((az - centre_deg + 180.0) % 360.0 - 180.0) < 15.0) & (x[:, 2] > 20.0) & (x[:, 2] < 40.0)
        return np.where(crest[:, None], [0.02, 0.02, 0.02], [0.6, 0.08, 0.05])

    res = register_pair(b.points, a.points, source_normals=b.normals, target_normals=a.normals, preset="standard",
                        seed=0, source_colours=painted(b, 100.0), target_colours=painted(a, 130.0))
    rot, disp = pose_difference(res.transform, truth, b.points)
    assert not res.verified and res.decided_by == "shape", res.reason
    assert "shape and colour disagree: colour turns the pair 30." in res.reason and "\n" not in res.reason, res.reason
    assert rot < TOL_DEG and disp < TOL_MM, (rot, disp)          # the shape's turn is kept, and was right
