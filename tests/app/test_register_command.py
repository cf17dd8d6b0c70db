"""`kogei register` (app.cli.register, app.workflows.cloud_registration) end to end on files, with ground truth.

Two or three passes of the procedural hawk in random placements (the ring scan
of tests/geometry/test_registration.py) are written as PLY / PCD / XYZ files; the poses
in poses.json must map every input into the first one's frame as the
placements say, and the merged cloud must hold the registered inputs.
"""

from __future__ import annotations

import argparse
import json
import math

import numpy as np
import pytest

from app.cli.register import add_parser, run
from app.errors import UsageError
from app.workflows.cloud_registration import POSES_FORMAT, read_cloud, read_picks
from mocks.procedural_hawk import hawk_head
from processing.errors import InputError
from processing.geometry.registration import pose_difference, transform_points
from tests.geometry.test_registration import _placement, _scan

TOL_DEG, TOL_MM = 0.3, 0.3


def _parse(*argv) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="kogei")
    add_parser(parser.add_subparsers(dest="command"))
    return parser.parse_args(["register", *[str(a) for a in argv]])


def _write(path, points, normals=None):
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    if normals is not None:
        pcd.normals = o3d.utility.Vector3dVector(normals)
    assert o3d.io.write_point_cloud(str(path), pcd)
    return path


@pytest.fixture(scope="module")
def passes():
    mesh = hawk_head(8000)
    rng = np.random.default_rng(91)
    placements = [_placement(mesh.vertices, rng) for _ in range(3)]
    scans = [_scan(mesh.vertices, mesh.triangles, m, rng) for m in placements]
    return placements, scans


def test_register_three_files_writes_true_poses_and_the_merged_cloud(tmp_path, passes, capsys):
    placements, scans = passes
    files = [_write(tmp_path / "a.ply", *scans[0]), _write(tmp_path / "b.pcd", *scans[1]),
             _write(tmp_path / "c.xyz", scans[2][0])]  # XYZ: no normals, estimated
    out, poses = tmp_path / "out" / "merged.ply", tmp_path / "out" / "poses.json"
    code = run(_parse(*files, "--out", out, "--poses", poses, "--preset", "draft"))
    err = capsys.readouterr().err
    assert code == 0, err
    doc = json.loads(poses.read_text())
    assert doc["format"] == POSES_FORMAT and doc["frame"] == str(files[0]) and doc["preset"] == "draft"
    assert [e["file"] for e in doc["inputs"]] == [str(f) for f in files]
    assert np.allclose(doc["inputs"][0]["matrix"], np.eye(4))
    for k in (1, 2):
        entry = doc["inputs"][k]
        assert entry["registered"] and entry["points"] == len(scans[k][0])
        truth = placements[0] @ np.linalg.inv(placements[k])
        rot, disp = pose_difference(np.array(entry["matrix"]), truth, scans[k][0])
        assert rot < TOL_DEG and disp < TOL_MM
    assert len(doc["pairs"]) == 3
    for pair in doc["pairs"]:
        assert pair["verified"] is True and pair["reason"] == "ok"
        assert {"overlap", "rmse_mm", "margin", "seconds", "transform"} <= set(pair)
        assert pair["source_file"] == str(files[pair["source"]])
    assert doc["pose_graph"]["max_rotation_deg"] < TOL_DEG
    # the merged cloud is every input mapped into a.ply's frame
    merged, _ = read_cloud(out)
    assert len(merged) == sum(len(p) for p, _ in scans)
    expected = transform_points(np.array(doc["inputs"][1]["matrix"]), scans[1][0])
    start = len(scans[0][0])
    assert np.allclose(merged[start:start + len(expected)], expected, atol=1e-4)
    assert "verified" in err and "wrote" in err
    assert not list((tmp_path / "out").glob(".*"))  # no temporary files left behind


def test_an_input_that_fits_nowhere_is_left_out_and_reported(tmp_path, passes, capsys):
    import open3d as o3d

    _, scans = passes
    box = o3d.geometry.TriangleMesh.create_box(30.0, 20.0, 12.0).subdivide_midpoint(4)
    bv, bt = np.asarray(box.vertices), np.asarray(box.triangles)
    rng = np.random.default_rng(3)
    box_scan = _scan(bv, bt, _placement(bv, rng), rng, n_angles=90, n_points=160)
    files = [_write(tmp_path / "a.ply", *scans[0]), _write(tmp_path / "box.ply", *box_scan)]
    poses = tmp_path / "poses.json"
    code = run(_parse(*files, "--poses", poses, "--preset", "draft", "--quiet"))
    err = capsys.readouterr().err
    assert code == 1
    doc = json.loads(poses.read_text())
    assert doc["inputs"][1]["registered"] is False and doc["inputs"][1]["matrix"] is None
    assert doc["pairs"][0]["verified"] is False and doc["pairs"][0]["reason"] != "ok"
    assert "box.ply" in err and "not connected" in err


def test_picks_file_registers_a_pair(tmp_path, passes):
    placements, scans = passes
    files = [_write(tmp_path / "a.ply", *scans[0]), _write(tmp_path / "b.ply", *scans[1])]
    truth = placements[0] @ np.linalg.inv(placements[1])
    on_b = scans[1][0][[10, 500, 1000, 2000]]
    picks = tmp_path / "picks.json"
    # given as [1, 0]: the points on input 1 first
    picks.write_text(json.dumps([{"pair": [1, 0], "points": [on_b.tolist(), transform_points(truth, on_b).tolist()]}]))
    poses = tmp_path / "poses.json"
    assert run(_parse(*files, "--poses", poses, "--preset", "draft", "--picks", picks, "--quiet")) == 0
    doc = json.loads(poses.read_text())
    assert doc["pairs"][0]["method"] == "picks"
    rot, disp = pose_difference(np.array(doc["inputs"][1]["matrix"]), truth, scans[1][0])
    assert rot < TOL_DEG and disp < TOL_MM


def test_nan_points_are_refused_or_dropped(tmp_path, passes):
    _, scans = passes
    pts = scans[0][0].copy()
    pts[5] = np.nan
    path = tmp_path / "holes.xyz"
    np.savetxt(path, pts)
    with pytest.raises(UsageError, match=r"holes\.xyz: 1 of \d+ points have NaN.*--drop-invalid"):
        read_cloud(path)
    kept, normals = read_cloud(path, drop_invalid=True)
    assert len(kept) == len(pts) - 1 and normals is None and np.isfinite(kept).all()


@pytest.mark.parametrize(
    ("name", "content", "match"),
    [
        ("missing.ply", None, "missing.ply: file not found"),
        ("cloud.obj", "v 0 0 0\n", "cloud.obj: unsupported point-cloud format"),
        ("empty.xyz", "", "empty.xyz: no points could be read"),
        ("broken.ply", "ply\nformat binary_little_endian 1.0\nelement vertex 5\nend_header\n",
         "broken.ply: no points could be read"),
    ],
)
def test_bad_files_name_the_file(tmp_path, name, content, match):
    path = tmp_path / name
    if content is not None:
        path.write_text(content)
    with pytest.raises(UsageError, match=match):
        read_cloud(path)
    good = _write(tmp_path / "good.xyz", np.random.default_rng(0).normal(size=(50, 3)))
    with pytest.raises(UsageError, match=match):
        run(_parse(good, path, "--poses", tmp_path / "p.json"))


def test_degenerate_cloud_file_is_a_usage_error(tmp_path):
    good = _write(tmp_path / "good.xyz", np.random.default_rng(0).normal(size=(50, 3)) * 10)
    flat = np.c_[np.random.default_rng(1).normal(size=(50, 2)), np.zeros(50)]
    bad = _write(tmp_path / "flat.xyz", flat)
    with pytest.raises(InputError, match="flat.xyz: all points lie in one plane"):
        run(_parse(good, bad, "--poses", tmp_path / "p.json"))


def test_bad_arguments(tmp_path):
    good = _write(tmp_path / "good.xyz", np.random.default_rng(0).normal(size=(50, 3)))
    with pytest.raises(UsageError, match="nothing to write"):
        run(_parse(good, good))
    with pytest.raises(UsageError, match="at least two"):
        run(_parse(good, "--poses", tmp_path / "p.json"))
    with pytest.raises(UsageError, match=r"--out: .*merged\.obj must end in one of"):
        run(_parse(good, good, "--out", tmp_path / "merged.obj"))
    with pytest.raises(UsageError, match=r"--poses: .*poses\.txt must end in one of \.json"):
        run(_parse(good, good, "--poses", tmp_path / "poses.txt"))
    with pytest.raises(SystemExit):
        _parse(good, good, "--preset", "fast")


@pytest.mark.parametrize(
    ("content", "match"),
    [
        ("not json", "not valid JSON"),
        ('{"pair": [0, 1]}', "expected a list"),
        ('[{"pair": [0, 1]}]', 'needs "pair"'),
        ('[{"pair": [0, 7], "points": [[], []]}]', r"pair \[0, 7\] must name two different inputs among 0..1"),
        ('[{"pair": [0, 0], "points": [[], []]}]', "two different inputs"),
        ('[{"pair": ["a", 1], "points": [[], []]}]', "two input indices"),
        ('[{"pair": [0, 1], "points": [[[0, 0, 0]]]}]', r"points must be \[points on input 0"),
        ('[{"pair": [0, 1], "points": [[[0, 0, 0]], [[0, 0]]]}]', "two equally long lists"),
        ('[{"pair": [0, 1], "points": [[["x", 0, 0]], [[0, 0, 0]]]}]', "numbers in mm"),
    ],
)
def test_bad_picks_files(tmp_path, content, match):
    path = tmp_path / "picks.json"
    path.write_text(content)
    with pytest.raises(UsageError, match=match):
        read_picks(path, 2)


def test_picks_file_missing_and_too_few_picks(tmp_path):
    with pytest.raises(UsageError, match="--picks: .*nope.json: file not found"):
        read_picks(tmp_path / "nope.json", 2)
    a = _write(tmp_path / "a.xyz", np.random.default_rng(0).normal(size=(50, 3)) * 10)
    b = _write(tmp_path / "b.xyz", np.random.default_rng(1).normal(size=(50, 3)) * 10)
    picks = tmp_path / "picks.json"
    picks.write_text(json.dumps([{"pair": [0, 1], "points": [[[0, 0, 0], [1, 0, 0]], [[0, 0, 0], [1, 0, 0]]]}]))
    with pytest.raises(InputError, match="at least 3 picked point pairs"):
        run(_parse(a, b, "--poses", tmp_path / "p.json", "--picks", picks))


def test_poses_json_has_no_nan(tmp_path, passes):
    # margins of picked pairs are NaN in Python and must become null in JSON
    placements, scans = passes
    files = [_write(tmp_path / "a.ply", *scans[0]), _write(tmp_path / "b.ply", *scans[1])]
    truth = placements[0] @ np.linalg.inv(placements[1])
    on_b = scans[1][0][[3, 300, 900]]
    picks = tmp_path / "picks.json"
    picks.write_text(json.dumps([{"pair": [0, 1], "points": [transform_points(truth, on_b).tolist(), on_b.tolist()]}]))
    poses = tmp_path / "poses.json"
    run(_parse(*files, "--poses", poses, "--preset", "draft", "--picks", picks, "--quiet"))
    text = poses.read_text()
    assert "NaN" not in text and "Infinity" not in text
    doc = json.loads(text)
    assert doc["pairs"][0]["margin"] is None and math.isfinite(doc["seconds"])


def test_units_metres_are_converted_and_written_back(tmp_path, passes, capsys):
    # the same two passes written in metres: registered as in mm, poses and merged cloud in metres
    placements, scans = passes
    files = [_write(tmp_path / "a.ply", scans[0][0] / 1000.0, scans[0][1]),
             _write(tmp_path / "b.ply", scans[1][0] / 1000.0, scans[1][1])]
    out, poses = tmp_path / "merged.ply", tmp_path / "poses.json"
    code = run(_parse(*files, "--out", out, "--poses", poses, "--preset", "draft", "--units", "m"))
    assert code == 0, capsys.readouterr().err
    doc = json.loads(poses.read_text())
    assert doc["units"] == "m"
    truth = placements[0] @ np.linalg.inv(placements[1])
    matrix = np.array(doc["inputs"][1]["matrix"])
    # translations in metres: back in mm they match the truth as the mm run does
    in_mm = matrix.copy()
    in_mm[:3, 3] *= 1000.0
    rot, disp = pose_difference(in_mm, truth, scans[1][0])
    assert rot < TOL_DEG and disp < TOL_MM
    # the pair maps b into a, as the pose does (one edge: the pose graph keeps it), also in metres
    assert np.allclose(doc["pairs"][0]["transform"], matrix, atol=1e-5)
    # metrics stay in mm: the residual is about the hawk scan's noise, not a thousandth of it
    assert 0.001 < doc["pairs"][0]["rmse_mm"] < 0.5
    merged, _ = read_cloud(out)
    assert np.allclose(merged[: len(scans[0][0])], scans[0][0] / 1000.0, atol=1e-9)


def test_unknown_units_are_refused(tmp_path):
    good = _write(tmp_path / "good.xyz", np.random.default_rng(0).normal(size=(50, 3)))
    with pytest.raises(SystemExit) as exc:
        _parse(good, good, "--poses", tmp_path / "p.json", "--units", "furlong")
    assert exc.value.code == 2
    from app.workflows.cloud_registration import poses_document

    with pytest.raises(UsageError, match="--units: unknown unit 'furlong'"):
        poses_document([], [], None, units="furlong")
