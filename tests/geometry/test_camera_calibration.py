"""Camera calibration against the turntable, on synthetic frames of a known camera and table.

The scene (tests/camera/charuco_scene.py): a 960 x 640 pinhole camera, fov 25 deg (fx = 2165.1 px),
600 mm from a point 45 mm above the table on the axis, 15 deg elevation, azimuth -70 deg, roll 1.5
deg.  A 9 x 6 board of 20 mm squares in three placements (flat; on wedges tilted 45 and 55 deg) is
shot at 12 table angles each; the views where the board faces away or leaves the frame are rejected
by detection (13 of 36), and the calibration works with the rest.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time

import numpy as np
import pytest

from processing.camera.charuco import CharucoError, board_corners_mm, detect_board
from processing.errors import InputError
from processing.geometry.camera_calibration import (
    BoardView,
    CameraCalibration,
    CameraCalibrationError,
    SphereObservation,
    calibrate_camera,
    link_to_room,
    project_points,
)
from tests.camera.charuco_scene import (
    DEFN,
    FX,
    HEIGHT,
    K_TRUE,
    WIDTH,
    camera_pose,
    flat_board,
    render,
    rigid,
    rz,
    wedge_board,
)

CAM = camera_pose()
GROUPS = {"flat": flat_board(), "w45": wedge_board(45.0), "w55": wedge_board(55.0, 20.0, along_mm=-70.0)}
CORNERS = board_corners_mm(DEFN)
SPHERE_MM = np.array([95.0, 20.0, 30.0])


@pytest.fixture(scope="module")
def views():
    rng = np.random.default_rng(1)
    out, rejected = [], []
    for g, b in GROUPS.items():
        for a in range(0, 360, 30):
            img = render(CAM @ rigid(rz(a), np.zeros(3)) @ b, rng=rng)
            try:
                d = detect_board(img, DEFN, name=f"{g}-{a:03d}")
            except CharucoError:
                rejected.append(f"{g}-{a:03d}")
                continue
            out.append(BoardView(d.name, float(a), g, d.corners_px, d.ids))
    assert len(rejected) >= 6 and len(out) >= 20  # the away-facing wedge views are rejected
    return out


@pytest.fixture(scope="module")
def calibrated(views):
    t0 = time.perf_counter()
    calib = calibrate_camera(views, (WIDTH, HEIGHT), CORNERS, board=DEFN.to_dict())
    return calib, time.perf_counter() - t0


def _sphere_observations(seed=3, sigma_mm=0.05, angles=range(0, 360, 30), centre=SPHERE_MM):
    rng = np.random.default_rng(seed)
    return [SphereObservation(float(a), CAM[:3, :3] @ (rz(a) @ centre) + CAM[:3, 3] + rng.normal(0, sigma_mm, 3),
                              np.eye(3) * sigma_mm ** 2) for a in angles]


def _pose_errors(room_to_camera):
    d = room_to_camera[:3, :3] @ CAM[:3, :3].T
    rot_deg = math.degrees(math.acos(np.clip((np.trace(d) - 1) / 2, -1, 1)))
    centre = -room_to_camera[:3, :3].T @ room_to_camera[:3, 3]
    return rot_deg, float(np.linalg.norm(centre - (-CAM[:3, :3].T @ CAM[:3, 3])))


def test_intrinsics_against_truth(calibrated):
    calib, _ = calibrated
    # targets: RMS <= 0.3 px, focal within 0.2 %, principal point within 3 px (its time: bench, "Posed photos")
    assert calib.rms_px <= 0.3
    assert calib.K[0, 0] == pytest.approx(FX, rel=0.002) and calib.K[1, 1] == pytest.approx(FX, rel=0.002)
    assert np.abs(calib.K[:2, 2] - K_TRUE[:2, 2]).max() < 3.0
    assert calib.dropped_views == () and calib.room_to_camera is None
    assert max(calib.view_rms_px.values()) < 0.3


@pytest.fixture(scope="module")
def calibrated_full(views):
    """The full model (principal point and k1, k2, p1, p2 fitted), as ``principal_point="fit"`` forces."""
    return calibrate_camera(views, (WIDTH, HEIGHT), CORNERS, board=DEFN.to_dict(), principal_point="fit")


def test_a_long_lens_holds_the_principal_point_when_the_views_cannot_place_it(calibrated, calibrated_full):
    """The full fit leaves the principal point uncertain by more than 1 px here; auto holds it at the centre."""
    calib, _ = calibrated
    assert max(calibrated_full.stds["cx_px"], calibrated_full.stds["cy_px"]) > 1.0
    assert calibrated_full.held == ()
    assert calib.held == ("cx", "cy", "k2", "p1", "p2")
    assert calib.K[0, 2] == (WIDTH - 1) / 2 and calib.K[1, 2] == (HEIGHT - 1) / 2
    assert calib.dist[1:].tolist() == [0.0, 0.0, 0.0, 0.0]
    # held, and stored so: the JSON round trip keeps it
    assert CameraCalibration.from_dict(calib.to_dict()).held == calib.held


def test_reported_uncertainties_cover_the_errors(calibrated_full):
    calib = calibrated_full
    s = calib.stds
    assert set(s) >= {"fx_px", "fy_px", "cx_px", "cy_px", "axis_direction_deg", "camera_distance_mm"}
    for key, err in (("fx_px", calib.K[0, 0] - FX), ("cx_px", calib.K[0, 2] - K_TRUE[0, 2]),
                     ("cy_px", calib.K[1, 2] - K_TRUE[1, 2])):
        assert 0 < s[key] and abs(err) < 4 * s[key], key
    # truth: the camera centre is 600 cos(15 deg) = 579.6 mm from the axis; gauge_to_camera puts it at (0, -rho, 0)
    rho = np.linalg.norm(calib.gauge_to_camera[:3, 3])
    assert abs(rho - 600 * math.cos(math.radians(15))) < max(1.0, 4 * s["camera_distance_mm"])
    # truth: the axis (room +z) in the camera frame
    axis = calib.gauge_to_camera[:3, 2]
    err_deg = math.degrees(math.acos(np.clip(axis @ CAM[:3, 2], -1, 1)))
    assert err_deg < max(0.1, 4 * s["axis_direction_deg"])


def test_link_to_room_against_truth(calibrated):
    calib, _ = calibrated
    linked, link = link_to_room(calib, _sphere_observations(), SPHERE_MM)
    rot_deg, centre_mm = _pose_errors(linked.room_to_camera)
    # targets: camera pose within 0.05 deg and 0.2 mm of the truth
    assert rot_deg <= 0.05 and centre_mm <= 0.2
    assert link.chi2_per_dof < 3.0 and link.residuals_mm.shape == (12, 3)
    assert 0 < link.rotation_std_deg < 0.1 and 0 < link.height_std_mm < 0.5
    # projection of room points by the linked calibration vs the truth (px)
    pts = np.random.default_rng(0).uniform([-80, -80, 0], [80, 80, 150], (200, 3))
    err = project_points(pts, linked.K, linked.dist, linked.room_to_camera) - project_points(pts, K_TRUE, np.zeros(5),
                                                                                             CAM)
    assert np.abs(err).max() < 4.0


def test_link_with_two_gauge_parameters_only(calibrated):
    # without refining the gauge pose the board fit's own pose error remains (measured 0.03 deg, 0.4 mm)
    calib, _ = calibrated
    linked, link = link_to_room(calib, _sphere_observations(), SPHERE_MM, update_pose=False)
    rot_deg, centre_mm = _pose_errors(linked.room_to_camera)
    assert rot_deg <= 0.1 and centre_mm <= 1.0
    np.testing.assert_array_equal(linked.gauge_to_camera, calib.gauge_to_camera)
    assert link.chi2_per_dof < 25


def test_link_refuses_inconsistent_or_too_few(calibrated):
    calib, _ = calibrated
    obs = _sphere_observations()
    with pytest.raises(CameraCalibrationError, match=r"only 1 sphere observations \(< 2\)"):
        link_to_room(calib, obs[:1], SPHERE_MM)
    with pytest.raises(CameraCalibrationError, match=r"chi-square per dof \d+\.\d > 25"):
        link_to_room(calib, obs, SPHERE_MM + [5.0, 0.0, 0.0])
    with pytest.raises(CameraCalibrationError, match="on .*the axis"):
        link_to_room(calib, obs, [0.0, 0.0, 30.0])
    tuples = [(o.table_angle_deg, o.centre_cam_mm, o.cov_cam) for o in obs]
    assert np.allclose(link_to_room(calib, tuples, SPHERE_MM)[0].room_to_camera,
                       link_to_room(calib, obs, SPHERE_MM)[0].room_to_camera)


def test_manual_focal_start(views):
    # start from a focal 3 % off (the manual fallback) instead of cv2.calibrateCamera
    calib = calibrate_camera(views, (WIDTH, HEIGHT), CORNERS, initial_focal_px=1.03 * FX)
    assert calib.K[0, 0] == pytest.approx(FX, rel=0.002)


def test_a_grossly_wrong_view_is_dropped(views, calibrated):
    bad = dataclasses.replace(views[3], table_angle_deg=views[3].table_angle_deg + 40.0)
    calib = calibrate_camera([*views[:3], bad, *views[4:]], (WIDTH, HEIGHT), CORNERS)
    assert calib.dropped_views == (bad.name,) and bad.name not in calib.view_rms_px
    assert calib.K[0, 0] == pytest.approx(FX, rel=0.002) and calib.rms_px <= 0.3


def test_refuses_unobservable_axis_and_few_views(views):
    by_group = {g: [v for v in views if v.group == g] for g in GROUPS}
    two_angles = [v for g in GROUPS for v in by_group[g][:2]]
    assert len(two_angles) == 6
    with pytest.raises(CameraCalibrationError, match="axis unobservable"):
        calibrate_camera(two_angles, (WIDTH, HEIGHT), CORNERS)
    narrow = [dataclasses.replace(v, table_angle_deg=10.0 * (k % 3)) for k, v in enumerate(views)]
    with pytest.raises(CameraCalibrationError, match="spanning >= 30 deg"):
        calibrate_camera(narrow, (WIDTH, HEIGHT), CORNERS)
    with pytest.raises(CameraCalibrationError, match=r"only 5 usable board views \(< 6\)"):
        calibrate_camera(views[:5], (WIDTH, HEIGHT), CORNERS)


def test_refuses_a_poor_fit(views):
    rng = np.random.default_rng(0)
    noisy = [dataclasses.replace(v, corners_px=v.corners_px + rng.normal(0, 2.0, v.corners_px.shape)) for v in views]
    with pytest.raises(CameraCalibrationError, match=r"residual \d\.\d\d px is far above the expected corner noise"):
        calibrate_camera(noisy, (WIDTH, HEIGHT), CORNERS)


def test_binning_rule(calibrated):
    calib, _ = calibrated
    k4, d4 = calib.for_image_size(240, 160)
    k = calib.K
    np.testing.assert_allclose(k4, [[k[0, 0] / 4, 0, (k[0, 2] + 0.5) / 4 - 0.5],
                                    [0, k[1, 1] / 4, (k[1, 2] + 0.5) / 4 - 0.5], [0, 0, 1]])
    np.testing.assert_array_equal(d4, calib.dist)
    with pytest.raises(CameraCalibrationError, match="250 x 160 is not an integer binning of the calibrated size 960 x 640"):
        calib.for_image_size(250, 160)
    with pytest.raises(CameraCalibrationError, match="binning"):
        calib.for_image_size(1920, 1280)


def test_json_round_trip(calibrated):
    calib, _ = calibrated
    linked, _ = link_to_room(calib, _sphere_observations(), SPHERE_MM)
    back = CameraCalibration.from_dict(json.loads(json.dumps(linked.to_dict())))
    for f in ("K", "dist", "gauge_to_camera", "room_to_camera", "gauge_cov"):
        np.testing.assert_array_equal(getattr(back, f), getattr(linked, f))
    assert back.view_rms_px == linked.view_rms_px and back.board == DEFN.to_dict()
    assert back.image_size == (WIDTH, HEIGHT) and back.stds == linked.stds


@pytest.mark.parametrize("patch, field", [
    ({"schema": "kogei.scanner_calibration"}, "schema"),
    ({"version": 2}, "version"),
    ({"image_size": [960, -640]}, "image_size"),
    ({"K": [[1.0, 0, 0], [0, 1.0, 0]]}, "K"),
    ({"K": [[float("nan"), 0, 479.5], [0, 2000.0, 319.5], [0, 0, 1]]}, "K"),
    ({"K": [[-2000.0, 0, 479.5], [0, 2000.0, 319.5], [0, 0, 1]]}, "K"),
    ({"dist": [0, 0, 0, 0]}, "dist"),
    ({"dist": [1e9, 0, 0, 0, 0]}, "dist"),
    ({"gauge_to_camera": np.diag([2.0, 1, 1, 1]).tolist()}, "gauge_to_camera"),
    ({"room_to_camera": "identity"}, "room_to_camera"),
    ({"rms_px": -1}, "rms_px"),
    ({"stds": {"fx_px": float("inf")}}, "stds"),
    ({"view_rms_px": []}, "view_rms_px"),
    ({"board": {"squares_x": "nine"}}, "board"),
    ({"dropped_views": "flat-000"}, "dropped_views"),
    ({"gauge_cov": [[1.0]]}, "gauge_cov"),
])
def test_from_dict_rejects_garbage(calibrated, patch, field):
    data = {**calibrated[0].to_dict(), **patch}
    with pytest.raises(CameraCalibrationError) as e:
        CameraCalibration.from_dict(data)
    msg = str(e.value)
    assert field in msg and "\n" not in msg and isinstance(e.value, InputError)


def test_from_dict_rejects_non_objects():
    with pytest.raises(CameraCalibrationError, match="JSON object"):
        CameraCalibration.from_dict([1, 2, 3])
