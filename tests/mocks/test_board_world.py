"""The ChArUco board world: OpenCV finds the board, and PnP with the true K recovers the true pose."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from mocks.board_world import DEFAULT_BOARD, BoardWorld
from mocks.world import World, WorldError
from processing.spectral.display import spectra_to_xyz


@pytest.fixture(scope="module")
def world():
    return BoardWorld.charuco(spectral_step=50.0)


@pytest.fixture(scope="module")
def detector():
    d = DEFAULT_BOARD
    board = cv2.aruco.CharucoBoard((d["squares_x"], d["squares_y"]), d["square_mm"], d["marker_mm"],
                                   cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, d["dictionary"])))
    return board, cv2.aruco.CharucoDetector(board)


def _grey(frame):
    y = spectra_to_xyz(frame.radiance.reshape(-1, frame.radiance.shape[-1]), frame.grid)[:, 1]
    y = y.reshape(frame.labels.shape)
    return np.clip(np.round(255 * y / y.max()), 0, 255).astype(np.uint8)


def _detect(world, detector, placement, angle):
    world.pose = world.fixed_placement_pose(placement)
    frame = world.frame("object", angle)
    corners, ids, _, _ = detector[1].detectBoard(_grey(frame))
    return frame, corners, ids


@pytest.mark.parametrize("placement, angles", [(1, (0.0, 20.0, -30.0)), (2, (0.0, 20.0, -30.0)),
                                               (3, (0.0, 20.0, -30.0))])
def test_board_is_detected_at_several_table_angles(world, detector, placement, angles):
    for angle in angles:
        frame, corners, ids = _detect(world, detector, placement, angle)
        assert frame.radiance.shape[:2] == (640, 960)
        assert ids is not None and len(ids) >= 15, (placement, angle)
        # detected corners lie where the true pose projects them (OpenCV's own refinement, no sub-pixel step:
        # 10 mm squares on a wedge 0.4 px, the flat board seen at grazing incidence 1.5 px)
        obj = detector[0].getChessboardCorners()[ids.ravel()]
        cam = world.room_to_camera() @ world.board_to_room(angle)
        p = (obj @ cam[:3, :3].T + cam[:3, 3]) @ world.camera_intrinsics().T
        err = np.abs(p[:, :2] / p[:, 2:] - corners.reshape(-1, 2)).max()
        assert err < (1.5 if world.tilts_deg[placement - 1] == 0 else 0.4), (placement, angle, err)


def test_pnp_with_the_true_intrinsics_gives_the_true_pose(world, detector):
    """Board on the 55 degree wedge, nearly facing the camera: PnP within 0.05 deg and 0.1 mm.

    The corners are the calibration's own (``processing.camera.charuco.detect_board``, refined to
    sub-pixel on the rectified board); OpenCV's raw corners of the 8 mm squares leave 0.055 deg.
    """
    from processing.camera.charuco import BoardDefinition, detect_board

    world.pose = world.fixed_placement_pose(3)
    frame = world.frame("object", 20.0)
    det = detect_board(_grey(frame).astype(float), BoardDefinition.from_dict(DEFAULT_BOARD), name="wedge 55")
    corners, ids = det.corners_px.astype(np.float64), det.ids
    obj = detector[0].getChessboardCorners()[ids.ravel()].astype(np.float64)
    ok, rvec, tvec = cv2.solvePnP(obj, corners, world.camera_intrinsics(), np.zeros(5))
    assert ok
    truth = world.room_to_camera() @ world.board_to_room(20.0)
    r = cv2.Rodrigues(rvec)[0]
    angle = np.degrees(np.arccos(np.clip((np.trace(r.T @ truth[:3, :3]) - 1) / 2, -1.0, 1.0)))
    assert angle < 0.05
    assert np.linalg.norm(tvec.ravel() - truth[:3, 3]) < 0.1


def test_placements_cycle_through_the_tilts(world):
    for n, tilt in ((1, 0.0), (2, 40.0), (3, 55.0), (4, 0.0)):
        normal = world.fixed_placement_pose(n)[:3, :3] @ [0.0, 0.0, -1.0]
        assert np.degrees(np.arccos(normal[2])) == pytest.approx(tilt, abs=1e-9)
        assert normal[1] <= 0.0                          # facing the camera's side at table angle 0


def test_round_trip_and_radiometry(world):
    again = World.from_dict(world.to_dict())
    assert isinstance(again, BoardWorld) and again.board == world.board
    assert np.allclose(again.pose, world.pose) and again.tilts_deg == world.tilts_deg
    world.pose = world.fixed_placement_pose(3)
    f = world.frame("object", 0.0)
    e = world.light_spectrum()
    light = np.asarray(world.light_direction) / np.linalg.norm(world.light_direction)
    cos_i = light @ (world.board_to_room(0.0)[:3, :3] @ [0.0, 0.0, -1.0])
    brightest = f.radiance[..., 3].max()            # a pixel fully on the white paper
    assert brightest == pytest.approx(0.85 * cos_i * e[3] / np.pi, rel=1e-6)
    side = world.frame("object", 90.0)                   # turned edge-on: the backdrop shows
    assert (side.labels == -1).sum() > 1000
    assert np.allclose(side.radiance[side.labels == -1][:, 3].min(), 0.05 * e[3] / np.pi, rtol=1e-6)


def test_bad_board():
    with pytest.raises(WorldError, match="board"):
        BoardWorld.charuco({"dictionary": "DICT_5X5_100"})
    with pytest.raises(WorldError, match="tilt_deg"):
        BoardWorld.charuco(tilts_deg=(95.0,))
