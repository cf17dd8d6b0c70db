"""The real-scan benchmark's alignment reader (``bun.conf``), its pose comparison and its section, on synthetic data.

The published alignment's convention (a scan point p maps to R(q)^-1 p + t, q = qx qy qz qw) is
checked against SciPy's independent quaternion code and on synthetic scans cut from one known
cloud; no real scan is read here.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bench.real_scans_bench import (
    SCANS,
    ConfError,
    agreement,
    conf_pose,
    quaternion_matrix,
    read_conf,
    relative_poses,
    section,
)


def _random_poses(rng, n):
    rots = Rotation.random(n, random_state=rng)
    trans = rng.uniform(-0.1, 0.1, (n, 3))  # metres, as in the repository's files
    return rots, trans


def test_quaternion_matrix_matches_scipy():
    rng = np.random.default_rng(0)
    for q in Rotation.random(20, random_state=rng).as_quat():  # SciPy's order is (x, y, z, w) as in bun.conf
        assert np.allclose(quaternion_matrix(q), Rotation.from_quat(q).as_matrix(), atol=1e-12)
    # not normalised: the same rotation
    assert np.allclose(quaternion_matrix(3.0 * np.array([0, 0, 1, 1])), quaternion_matrix([0, 0, 1, 1]))


def test_quarter_turn_by_hand():
    # q = (0, 0, sin 45, cos 45) turns x onto y; the conf maps p to R(q)^-1 p, so x goes to -y
    s = math.sqrt(0.5)
    pose = conf_pose([0.0, 0.0, 0.002], [0.0, 0.0, s, s], scale=1000.0)
    assert np.allclose(pose @ [1.0, 0.0, 0.0, 1.0], [0.0, -1.0, 2.0, 1.0], atol=1e-12)


def test_synthetic_conf_brings_scans_back_into_one_frame(tmp_path):
    rng = np.random.default_rng(1)
    world = rng.normal(size=(500, 3)) * 0.05  # metres
    rots, trans = _random_poses(rng, 4)
    names = ["a", "b", "c", "d"]
    lines = ["camera 0 0 0 0 0 0 1"]
    scans = {}
    for k, name in enumerate(names):
        r = rots[k].as_matrix()
        # the file stores q with pose p -> R(q)^-1 p + t: R(q) = r^T, i.e. q is the conjugate of r's quaternion
        q = rots[k].inv().as_quat()
        lines.append(f"bmesh {name}.ply " + " ".join(f"{v:.17g}" for v in [*trans[k], *q]))
        scans[name] = (world - trans[k]) @ r  # r^T (world - t): the scan in its own frame
    conf = tmp_path / "x.conf"
    conf.write_text("\n".join(lines) + "\n")
    poses = read_conf(conf, scale=1000.0)
    assert sorted(poses) == names
    for name in names:
        back = scans[name] * 1000.0 @ poses[name][:3, :3].T + poses[name][:3, 3]
        # float64 round trip through 17 significant digits: far below a micrometre
        assert np.max(np.abs(back - world * 1000.0)) < 1e-9
    # relative to "a": scan d mapped into a's frame is a's view of the same points
    rel = relative_poses(poses, "a")
    d_in_a = scans["d"] * 1000.0 @ rel["d"][:3, :3].T + rel["d"][:3, 3]
    assert np.max(np.abs(d_in_a - scans["a"] * 1000.0)) < 1e-9
    assert np.allclose(rel["a"], np.eye(4), atol=1e-12)


def test_literal_reading_would_not_align(tmp_path):
    # the same synthetic set read with R(q) instead of R(q)^-1 misses by centimetres: the test can fail
    rng = np.random.default_rng(2)
    world = rng.normal(size=(200, 3)) * 0.05
    rot = Rotation.from_rotvec([0.0, 0.8, 0.0])
    conf = tmp_path / "y.conf"
    conf.write_text("bmesh s.ply 0 0 0 " + " ".join(f"{v:.17g}" for v in rot.inv().as_quat()) + "\n")
    scan = world @ rot.as_matrix()
    pose = read_conf(conf)["s"]
    assert np.max(np.abs(scan @ pose[:3, :3].T - world)) < 1e-12
    literal = scan @ rot.inv().as_matrix().T
    assert np.max(np.abs(literal - world)) > 0.01


@pytest.mark.parametrize(("text", "match"), [
    ("bmesh a.ply 0 0 0 0 0 1\n", r"x\.conf:1: expected 'bmesh FILE"),
    ("camera 1 2 3 0 0 0 1\nbmesh a.ply 0 0 x 0 0 0 1\n", r"x\.conf:2: expected"),
    ("bmesh a.ply 0 0 0 0 0 0 0\n", "quaternion of a.ply is zero"),
    ("bmesh a.ply 0 0 nan 0 0 0 1\n", "expected"),
    ("camera 0 0 0 0 0 0 1\n", "no 'bmesh' line"),
])
def test_bad_conf_names_file_and_line(tmp_path, text, match):
    conf = tmp_path / "x.conf"
    conf.write_text(text)
    with pytest.raises(ConfError, match=match):
        read_conf(conf)


def test_agreement_measures_an_offset_along_the_normal():
    # two samplings of a plane, one 0.3 mm above the other: point-to-plane distance 0.3 mm everywhere
    rng = np.random.default_rng(3)
    a = np.column_stack([rng.uniform(0, 20, (4000, 2)), np.zeros(4000)])
    b = np.column_stack([rng.uniform(0, 20, (4000, 2)), np.full(4000, 0.3)])
    clouds = {SCANS[0]: a, SCANS[1]: b}
    ident = {SCANS[0]: np.eye(4), SCANS[1]: np.eye(4)}
    ag = agreement(ident, clouds, every=1)
    assert ag["scans"] == 2 and ag["overlap"] > 0.95
    assert ag["rms_mm"] == pytest.approx(0.3, abs=1e-6) and ag["median_mm"] == pytest.approx(0.3, abs=1e-6)
    # moved 2 mm apart: beyond the 1.5 mm reach, no partners
    far = dict(ident)
    far[SCANS[1]] = np.eye(4)
    far[SCANS[1]][2, 3] = 1.7
    ag = agreement(far, clouds, every=1)
    assert ag["overlap"] == 0.0 and ag["rms_mm"] is None and ag["median_mm"] is None


def _result(rows_k, rows_o):
    ag = {"rms_mm": 0.16, "median_mm": 0.09, "overlap": 0.96, "scans": 10}
    return {
        "machine": "test machine", "points": {n: 1000 for n in SCANS},
        "convention": {"conjugate_median_mm": 0.33, "literal_median_mm": 28.8},
        "published_agreement": ag,
        "kogei": {"rows": rows_k, "agreement": ag, "seconds": 500.0, "exit_status": 1, "pairs": 45,
                  "verified_pairs": 20, "pair_seconds_median": 6.0, "graph_max_rotation_deg": 0.4,
                  "graph_max_displacement_mm": 0.7, "verified_wrong": [],
                  "refused": [{"scan": "top3", "reason": "top3 is not connected to bun000 by verified pairs"}],
                  "unverified": [{"pair": ["bun000", "top3"], "reason": "overlap 10% is below 25% (...)"}]},
        "open3d": {"rows": rows_o, "agreement": ag, "seconds": 370.0, "voxel_mm": 2.0, "edges": 14, "pairs": 45,
                   "pairs_outside_limits": 25},
    }


def test_section_reports_refused_scans_and_the_count_within_limits():
    ok = {"registered": True, "rotation_deg": 0.1, "displacement_mm": 0.2, "within": True}
    bad = {"registered": True, "rotation_deg": 178.0, "displacement_mm": 260.0, "within": False}
    refused = {"registered": False, "rotation_deg": None, "displacement_mm": None, "within": False}
    rows_k = [dict(ok, scan=n) for n in SCANS[1:-1]] + [dict(refused, scan=SCANS[-1])]
    rows_o = [dict(ok, scan=n) for n in SCANS[1:-1]] + [dict(bad, scan=SCANS[-1])]
    r = _result(rows_k, rows_o)
    r["kogei_seeds"] = [{"seed": 0, "within": 8, "scans": 9, "refused": 1, "max_rotation_deg": 0.1,
                         "max_displacement_mm": 0.2, "verified_wrong": 0, "seconds": 500.0}]
    text = "\n".join(section(r))
    assert "| kogei | 0 | 8/9 | 1 | 0.100 | 0.200 | 0 | 500 |" in text
    assert "| top3 | refused | refused | no | 178.000 | 260.000 | **no** |" in text
    assert text.count("**8/9**") == 2
    assert "Target: **not met**." in text
    assert "* top3: top3 is not connected" in text
    assert "Stanford 3D Scanning Repository" in text


def test_section_without_the_data_is_one_line():
    lines = section({"missing": "no real scans at /nowhere"})
    assert lines[0].startswith("## Real scans") and lines[2] == "Skipped: no real scans at /nowhere."
