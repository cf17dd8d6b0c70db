"""The room -> table -> pass -> mesh chain against a physically placed synthetic object."""

from __future__ import annotations

import json

import cv2
import numpy as np
import open3d as o3d
import pytest

from processing.appearance.frame_poses import (
    AppearanceError,
    FramePose,
    camera_centre_mesh,
    lamp_in_mesh,
    mesh_to_camera,
)
from processing.appearance.projection import binned_intrinsics, project_points
from tests.appearance.synthetic_scene import intrinsics, look_at, rigid, rz

# object placements: object frame -> table frame of pass p (pass 1 defines M)
P1 = rigid(3.0, -2.0, 40.0, [4.0, -3.0, 1.0])
P2 = rigid(88.0, 5.0, -30.0, [-2.0, 6.0, 35.0])
ROOM_TO_CAMERA = look_at([420.0, -150.0, 260.0], [0.0, 0.0, 50.0])
DIST = np.array([-0.12, 0.05, 0.001, -0.0008, 0.01])


def _object_points() -> np.ndarray:
    box = o3d.geometry.TriangleMesh.create_box(60.0, 40.0, 80.0).translate([-30.0, -20.0, 0.0])
    return np.asarray(box.subdivide_midpoint(2).vertices)


@pytest.mark.parametrize("theta", [0.0, 37.5, 181.0, -95.0])
@pytest.mark.parametrize("placement", [P1, P2])
def test_mesh_to_camera_matches_the_physical_placement(theta, placement):
    o = _object_points()
    x_mesh = o @ P1[:3, :3].T + P1[:3, 3]
    pass_pose = P1 @ np.linalg.inv(placement)  # T_p: pass table frame -> M
    room = (rz(theta) @ placement @ np.c_[o, np.ones(len(o))].T).T
    direct = (ROOM_TO_CAMERA @ room.T).T[:, :3]
    m = mesh_to_camera(ROOM_TO_CAMERA, theta, pass_pose)
    assert np.allclose(x_mesh @ m[:3, :3].T + m[:3, 3], direct, atol=1e-9)  # mm
    # projection with distortion against OpenCV on the room points (tolerance 1e-6 px)
    k = intrinsics(960, 640)
    frame = FramePose.from_chain("f", 2, ROOM_TO_CAMERA, theta, pass_pose, k, DIST, (960, 640))
    rvec, _ = cv2.Rodrigues(ROOM_TO_CAMERA[:3, :3])
    ref = cv2.projectPoints(room[:, :3], rvec, ROOM_TO_CAMERA[:3, 3], k, DIST)[0].reshape(-1, 2)
    uv, depth = project_points(x_mesh, frame)
    assert np.allclose(uv, ref, atol=1e-6) and np.allclose(depth, direct[:, 2], atol=1e-9)


@pytest.mark.parametrize("theta", [0.0, 72.0, 250.0])
def test_camera_centre_and_lamps_match_the_physical_placement(theta):
    pass_pose = P1 @ np.linalg.inv(P2)
    room_to_object = np.linalg.inv(rz(theta) @ P2)  # room -> object coordinates for this frame
    centre_room = -ROOM_TO_CAMERA[:3, :3].T @ ROOM_TO_CAMERA[:3, 3]
    expect = (P1 @ room_to_object @ np.r_[centre_room, 1.0])[:3]
    assert np.allclose(camera_centre_mesh(ROOM_TO_CAMERA, theta, pass_pose), expect, atol=1e-9)
    lamp_pos = np.array([100.0, 300.0, 400.0])
    point = lamp_in_mesh({"name": "key", "position_mm": lamp_pos}, theta, pass_pose)
    assert point.kind == "point" and np.allclose(point.vector, (P1 @ room_to_object @ np.r_[lamp_pos, 1.0])[:3])
    d = np.array([0.0, -0.6, 0.8])
    distant = lamp_in_mesh({"name": "sun", "direction": d}, theta, pass_pose)
    assert distant.kind == "distant" and np.allclose(distant.vector, (P1 @ room_to_object)[:3, :3] @ d)
    frame = FramePose.from_chain("f", 2, ROOM_TO_CAMERA, theta, pass_pose, intrinsics(), np.zeros(5), (240, 160))
    assert np.allclose(frame.camera_centre_mm, expect, atol=1e-9)


def test_binned_intrinsics_project_like_binned_pixels():
    # a point at full-resolution pixel (u, v) lands at ((u + 0.5)/b - 0.5, (v + 0.5)/b - 0.5) when binned
    k = intrinsics(960, 640)
    full = FramePose("f", 1, 0.0, (960, 640), k, np.zeros(5), np.eye(4))
    binned = FramePose("b", 1, 0.0, (240, 160), binned_intrinsics(k, 4), np.zeros(5), np.eye(4))
    pts = np.array([[10.0, -20.0, 500.0], [-40.0, 15.0, 300.0]])
    assert np.allclose(project_points(pts, binned)[0], (project_points(pts, full)[0] + 0.5) / 4 - 0.5, atol=1e-9)


def test_round_trip_through_json():
    lamps = [{"name": "key", "position_mm": [100.0, 300.0, 400.0]}, {"name": "sun", "direction": [0.0, 0.6, 0.8]}]
    frame = FramePose.from_chain("IMG_0001", 2, ROOM_TO_CAMERA, 33.0, P1 @ np.linalg.inv(P2), intrinsics(), DIST,
                                 (240, 160), lamps)
    back = FramePose.from_dict(json.loads(json.dumps(frame.to_dict())))
    assert back.name == "IMG_0001" and back.pass_index == 2 and back.image_size == (240, 160)
    for a in ("K", "dist", "mesh_to_camera"):
        assert np.array_equal(getattr(back, a), getattr(frame, a))
    assert [(lp.name, lp.kind) for lp in back.lamps] == [("key", "point"), ("sun", "distant")]
    assert np.array_equal(back.lamps[1].vector, frame.lamps[1].vector)


def _good() -> dict:
    return FramePose("f", 1, 10.0, (240, 160), intrinsics(), np.zeros(5), np.eye(4)).to_dict()


@pytest.mark.parametrize(("change", "needle"), [
    (lambda d: d.update(schema="other"), "schema"),
    (lambda d: d.pop("K"), "missing field"),
    (lambda d: d["K"][0].__setitem__(0, float("nan")), "K"),
    (lambda d: d["K"][2].__setitem__(2, 2.0), "K"),
    (lambda d: d["mesh_to_camera"][0].__setitem__(0, 2.0), "mesh_to_camera"),
    (lambda d: d["mesh_to_camera"][3].__setitem__(0, 1.0), "mesh_to_camera"),
    (lambda d: d.update(image_size=[240.5, 160]), "image_size"),
    (lambda d: d.update(image_size="big"), "image_size"),
    (lambda d: d.update(dist=[0, 0, 0]), "dist"),
    (lambda d: d.update(table_angle_deg="north"), "table_angle_deg"),
    (lambda d: d.update(pass_index=-1), "pass_index"),
    (lambda d: d.update(lamps=[{"name": "x", "kind": "spot", "vector": [0, 0, 1]}]), "kind"),
    (lambda d: d.update(lamps=[{"name": "x", "kind": "distant", "vector": [0, 0, 3]}]), "unit"),
    (lambda d: d.update(lamps="none"), "lamps"),
])
def test_hostile_frame_pose_is_refused_with_one_line(change, needle):
    data = _good()
    change(data)
    with pytest.raises(AppearanceError) as err:
        FramePose.from_dict(data)
    assert needle in str(err.value) and "\n" not in str(err.value)


def test_lamp_needs_exactly_one_of_position_or_direction():
    with pytest.raises(AppearanceError, match="exactly one"):
        lamp_in_mesh({"name": "x", "position_mm": [0, 0, 1], "direction": [0, 0, 1]}, 0.0, np.eye(4))
    with pytest.raises(AppearanceError, match="pass_pose"):
        mesh_to_camera(np.eye(4), 0.0, np.diag([1.0, 1.0, -1.0, 1.0]))
