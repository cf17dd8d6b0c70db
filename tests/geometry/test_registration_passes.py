"""Registration of several passes (processing.geometry.registration.register_passes, merge_passes) against
ground truth: the pose graph of three hawk passes, a pass that fits nowhere, picks for a symmetric pair.

The passes are simulated as in tests/geometry/test_registration.py (a small ring scan of a known mesh in a
random placement, 0.05 mm range noise; its helpers and tolerances are used here), which tests the pairs.
The two files are apart so that the two halves of the registration's tests, each a few minutes of CPU, can
run on two test workers at once.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocks.procedural_hawk import hawk_head
from processing.geometry.registration import (
    PRESETS,
    PairResult,
    PassPose,
    RegistrationError,
    RegistrationResult,
    merge_passes,
    register_passes,
    transform_points,
)
from tests.geometry.test_registration import TOL_DEG, TOL_MM, _egg, _error, _pair, _placement, _scan


@pytest.fixture(scope="module")
def hawk():
    mesh = hawk_head(8000)
    return mesh.vertices, mesh.triangles



def test_three_hawk_passes_pose_graph(hawk):
    rng = np.random.default_rng(61)
    placements = [_placement(hawk[0], rng) for _ in range(3)]
    scans = [_scan(*hawk, m, rng) for m in placements]
    res = register_passes([p for p, _ in scans], [n for _, n in scans], preset="draft", seed=2)
    assert isinstance(res, RegistrationResult) and res.all_registered
    assert len(res.pairs) == 3 and {(p.source, p.target) for p in res.pairs} == {(1, 0), (2, 0), (2, 1)}
    assert all(p.verified for p in res.pairs), [p.reason for p in res.pairs]
    assert np.array_equal(res.poses[0].transform, np.eye(4))
    for k in (1, 2):
        truth = placements[0] @ np.linalg.inv(placements[k])
        rot, disp = _error(res.poses[k].transform, truth, scans[k][0])
        assert rot < TOL_DEG and disp < TOL_MM
    # the three pairwise results agree with the optimised poses
    c = res.consistency
    assert c is not None and len(c.edges) == 3
    assert c.max_rotation_deg < TOL_DEG and c.max_displacement_mm < TOL_MM
    assert all(e[4] > 0.5 for e in c.edges)  # no loop closure rejected


def test_unconnected_pass_has_no_pose_and_says_why(hawk):
    rng = np.random.default_rng(71)
    m0, m1 = _placement(hawk[0], rng), _placement(hawk[0], rng)
    p0, n0 = _scan(*hawk, m0, rng, n_angles=90, n_points=160)
    p1, n1 = _scan(*hawk, m1, rng, n_angles=90, n_points=160)
    # the third "pass" is a scan of a box: it shares no surface with the hawk
    import open3d as o3d

    box = o3d.geometry.TriangleMesh.create_box(30.0, 20.0, 12.0).subdivide_midpoint(4)
    bv, bt = np.asarray(box.vertices), np.asarray(box.triangles)
    p2, n2 = _scan(bv, bt, _placement(bv, rng), rng, n_angles=90, n_points=160)
    res = register_passes([p0, p1, p2], [n0, n1, n2], preset="draft", names=["a.ply", "b.ply", "box.ply"])
    assert res.poses[1].registered and not res.poses[2].registered
    assert res.poses[2].transform is None
    assert "box.ply" in res.poses[2].reason and "a.ply" in res.poses[2].reason
    assert [p.verified for p in res.pairs] == [True, False, False]
    assert not res.all_registered
    truth = m0 @ np.linalg.inv(m1)
    rot, disp = _error(res.poses[1].transform, truth, p1)
    assert rot < TOL_DEG and disp < TOL_MM


def test_register_passes_with_picks_for_a_symmetric_pair():
    egg = _egg(0.0)
    src, sn, tgt, tn, truth = _pair(*egg, 81, n_angles=90, n_points=160)
    rng = np.random.default_rng(8)
    on_1 = src[rng.choice(len(src), 3, replace=False)]
    on_0 = transform_points(truth, on_1)
    res = register_passes([tgt, src], [tn, sn], preset="draft", picks={(0, 1): (on_0, on_1)})
    assert res.pairs[0].method == "picks" and res.pairs[0].verified
    rot, disp = _error(res.poses[1].transform, truth, src)
    assert rot < TOL_DEG and disp < TOL_MM


def test_a_single_pass_is_its_own_frame():
    pts = np.random.default_rng(0).normal(size=(200, 3)) * 10
    res = register_passes([pts])
    assert res.all_registered and np.array_equal(res.poses[0].transform, np.eye(4))
    assert res.pairs == () and res.consistency is None


def test_merge_passes_applies_poses_and_leaves_out_unregistered():
    t = np.eye(4)
    t[:3, :3] = Rotation.from_euler("x", 90, degrees=True).as_matrix()
    t[:3, 3] = [0, 0, 7]
    res = RegistrationResult(
        poses=(PassPose(0, np.eye(4), True, "ok"), PassPose(1, t, True, "ok"), PassPose(2, None, False, "no")),
        pairs=(), consistency=None, preset=PRESETS["draft"], seconds=0.0,
    )
    a, b, c = np.zeros((2, 3)), np.array([[0.0, 1.0, 0.0]]), np.ones((5, 3))
    pts, nrm, idx = merge_passes([a, b, c], res, [np.tile([0, 0, 1.0], (2, 1)), np.array([[0, 1.0, 0]]), None])
    assert pts.shape == (3, 3) and idx.tolist() == [0, 0, 1]
    assert np.allclose(pts[2], [0, 0, 8])  # (0, 1, 0) turned about x onto +z, lifted 7 mm
    assert np.allclose(nrm[2], [0, 0, 1])
    with pytest.raises(RegistrationError, match="2 clouds for 3 poses"):
        merge_passes([a, b], res)


def test_pair_result_as_dict_is_json_ready():
    import json

    r = PairResult(1, 0, np.eye(4), 0.9, 0.9, 0.8, 0.05, 0.04, 0.99, 0.8, math.nan, math.nan, False, "x", 0.1, "picks")
    d = r.as_dict()
    assert d["margin"] is None and d["transform"] == np.eye(4).tolist()
    json.dumps(d, allow_nan=False)

