"""Every RAW frame posed on the mesh, checked against the simulated station's truth.

With the true camera (intrinsics and pose in the room frame) and the object's own mesh, the chain
``room_to_camera @ Rz(theta) @ inv(T_p)`` must put the mesh exactly where the simulated camera saw the
object: the projected outline against the rendered labels, and against the outline found in the
decoded RAW photo.  The frames are 480 x 320, a 2x2 binning of the 960 x 640 calibration.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.cli import main
from tests.integration.posed_session import ANGLES_DEG, build_posed_session


@pytest.fixture(scope="module")
def posed(tmp_path_factory):
    from app.workflows.posed_frames import project_session

    root = tmp_path_factory.mktemp("posed") / "session"
    built = build_posed_session(root)
    built["report"] = project_session(root)
    built["root"] = root
    return built


def test_the_projected_mesh_covers_the_rendered_object(posed):
    """The mesh mask of each posed frame against the simulation's own labels: IoU >= 0.99."""
    from processing.appearance.frame_poses import FramePose
    from processing.appearance.silhouette import mesh_mask, silhouette_check

    doc = json.loads((posed["root"] / "products" / "frame-poses.json").read_text())
    assert [f["table_angle_deg"] for f in doc["frames"]] == list(ANGLES_DEG)
    for entry in doc["frames"]:
        pose = FramePose.from_dict(entry)
        labels = posed["world"].frame("object", entry["table_angle_deg"]).labels
        hit = mesh_mask((posed["vertices"], posed["triangles"]), pose)
        assert silhouette_check(hit, labels >= 0)["iou"] >= 0.99, entry["name"]


def test_the_projection_report_matches_the_photos(posed):
    """Against the outline found in the decoded photos (targets: IoU >= 0.98, offset <= 0.5 px)."""
    rep = posed["report"]
    assert len(rep["frames"]) == len(ANGLES_DEG)
    assert rep["iou_min"] >= 0.98 and rep["offset_px_mean"] <= 0.5
    obs = rep["observations"]
    assert obs["vertices_seen"] > 0.5 * obs["vertices"]


def test_observations_carry_the_true_geometry(posed):
    """View directions point at the true camera centre; light directions are the world's lamp."""
    from processing.appearance.observations import read_observations

    obs = read_observations(posed["root"] / "products" / "observations.npz")
    world = posed["world"]
    r2c = world.room_to_camera()
    centre_room = -r2c[:3, :3].T @ r2c[:3, 3]
    lamp = np.asarray(world.light_direction, float)
    lamp /= np.linalg.norm(lamp)
    for k, angle in enumerate(ANGLES_DEG):
        rows = obs.frame == k
        c = np.radians(-angle)      # the mesh frame is the table frame: the room turned back by theta
        rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1.0]])
        cam = rz @ centre_room
        v = posed["vertices"][obs.vertex[rows]]
        want = (cam - v) / np.linalg.norm(cam - v, axis=1, keepdims=True)
        assert np.abs(obs.view_dir[rows] - want).max() < 1e-4
        assert np.abs(obs.light_dir[rows, 0] - rz @ lamp).max() < 1e-5
        # every observed vertex faces the camera
        assert (np.einsum("ij,ij->i", obs.normal[rows], obs.view_dir[rows]) > 0).all()


def test_the_outline_of_one_frame_for_an_overlay(posed):
    from app.workflows.posed_frames import frame_outline, posed_frame_names

    names = posed_frame_names(posed["root"])
    assert names == [f"p01/frame/{k:02d}" for k in range(len(ANGLES_DEG))]
    out = frame_outline(posed["root"], names[1])
    assert out["image_size"] == (480, 320) and out["iou"] >= 0.98
    (line,) = out["outlines"]
    # a sphere's outline: a closed curve around the projected centre, radius within a few pixels of constant
    r = np.linalg.norm(line - line.mean(axis=0), axis=1)
    assert r.std() < 0.05 * r.mean()


def test_kogei_project_reruns_and_prints_every_frame(posed, capsys):
    assert main(["project", str(posed["root"]), "--decode", "bin2x2"]) == 0
    out = capsys.readouterr().out
    assert out.count(", offset ") == len(ANGLES_DEG) and "3 posed on the mesh" in out
    rep = json.loads((posed["root"] / "products" / "projection-report.json").read_text())
    assert rep["decode"] == "bin2x2" and rep["iou_min"] >= 0.97
