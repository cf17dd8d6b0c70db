"""ChArUco detection against synthetic frames of known geometry (tests/camera/charuco_scene.py)."""

from __future__ import annotations

import numpy as np
import pytest

from processing.camera.charuco import (
    BoardDefinition,
    CharucoError,
    board_corners_mm,
    detect_board,
    make_board,
)
from processing.errors import InputError
from tests.camera.charuco_scene import (
    DEFN,
    HEIGHT,
    WIDTH,
    camera_pose,
    flat_board,
    project,
    render,
    rigid,
    rz,
    wedge_board,
)

SMALL = BoardDefinition("DICT_4X4_50", 5, 4, 20.0, 16.0)


def _front(distance_mm, defn=DEFN, shift_mm=(0.0, 0.0)):
    """Board facing the camera, centred on the optical axis (shifted by shift_mm)."""
    w, h = defn.squares_x * defn.square_mm, defn.squares_y * defn.square_mm
    return rigid(np.eye(3), np.array([-w / 2 + shift_mm[0], -h / 2 + shift_mm[1], distance_mm]))


def _error_px(det, board_to_camera):
    truth = project(board_to_camera, board_corners_mm(DEFN)[det.ids])
    return np.linalg.norm(det.corners_px - truth, axis=1)


def test_definition_round_trip_and_board():
    d = BoardDefinition.from_dict(DEFN.to_dict())
    assert d == DEFN
    assert make_board(d).getChessboardSize() == (9, 6)
    c = board_corners_mm(d)
    # truth: inner corners on a 20 mm grid, id = row * 8 + column, first at (20, 20)
    assert c.shape == (40, 3)
    np.testing.assert_allclose(c[[0, 1, 8, 39]], [[20, 20, 0], [40, 20, 0], [20, 40, 0], [160, 100, 0]])


@pytest.mark.parametrize("patch, field", [
    ({"dictionary": "DICT_FOO"}, "dictionary"),
    ({"squares_x": 2}, "squares_x"),
    ({"squares_y": 4.5}, "squares_y"),
    ({"square_mm": float("nan")}, "square_mm"),
    ({"marker_mm": 25.0}, "marker_mm"),
    ({"marker_mm": True}, "marker_mm"),
    ({"dictionary": "DICT_4X4_50", "squares_x": 20, "squares_y": 20}, "dictionary"),
])
def test_definition_rejects_bad_fields_naming_them(patch, field):
    with pytest.raises(CharucoError) as e:
        BoardDefinition.from_dict({**DEFN.to_dict(), **patch})
    assert field in str(e.value) and "\n" not in str(e.value)
    assert isinstance(e.value, InputError)


def test_definition_rejects_missing_keys_and_non_objects():
    with pytest.raises(CharucoError, match="lacks marker_mm"):
        BoardDefinition.from_dict({k: v for k, v in DEFN.to_dict().items() if k != "marker_mm"})
    with pytest.raises(CharucoError, match="JSON object"):
        BoardDefinition.from_dict([1, 2])


@pytest.mark.parametrize("board", ["wedge", "flat"])
def test_corners_match_the_truth(board):
    # A board tilted 45 deg toward the camera, and a flat one seen at 15 deg elevation
    # (foreshortened 3.9x).  Tolerance: 0.15 px RMS, 0.4 px max against the exact projection.
    b = wedge_board(45.0) if board == "wedge" else flat_board()
    btc = camera_pose() @ rigid(rz(30.0), np.zeros(3)) @ b
    det = detect_board(render(btc), DEFN, name=board)
    err = _error_px(det, btc)
    assert len(det.ids) == 40 and det.n_markers == 27
    assert np.sqrt((err ** 2).mean()) < 0.15 and err.max() < 0.4
    assert det.edge_width_px < 2.5


def test_scale_and_colour_do_not_matter():
    btc = _front(600.0)
    img = render(btc)
    a = detect_board(img, DEFN, name="grey")
    b = detect_board(np.dstack([img, img, img]) * 1000.0, DEFN, name="rgb")
    np.testing.assert_allclose(a.corners_px, b.corners_px, atol=0.02)
    # truth: the inner corners' hull is 140 x 80 mm (corners 20..160 x 20..100 mm); at 600 mm
    # facing the camera it spans 505 x 289 px of 960 x 640
    fx = 480 / np.tan(np.radians(12.5))
    assert a.area_fraction == pytest.approx((140 * fx / 600) * (80 * fx / 600) / (WIDTH * HEIGHT), rel=0.01)


def test_no_board():
    img = render(_front(600.0, shift_mm=(2000.0, 0.0)))
    with pytest.raises(CharucoError, match=r"^frame empty-7: board not found"):
        detect_board(img, DEFN, name="empty-7")


def test_partly_outside():
    with pytest.raises(CharucoError, match=r"frame edge: the board is partly outside"):
        detect_board(render(_front(500.0, shift_mm=(60.0, 0.0))), DEFN, name="edge")


def test_tiny_board():
    # truth: a 80 x 60 mm board at 1600 mm covers 108 x 81 px, 1.4 % of the frame (hull 0.7 %)
    with pytest.raises(CharucoError, match=r"frame far: the board is too small \(0\.\d %"):
        detect_board(render(_front(1600.0, SMALL), defn=SMALL), SMALL, name="far")


def test_blurred_board():
    btc = _front(500.0)
    sharp = detect_board(render(btc), DEFN, name="sharp")
    assert sharp.edge_width_px < 2.0
    with pytest.raises(CharucoError, match=r"frame soft: the board is blurred \(edge width \d+\.\d px > 4 px\)"):
        detect_board(render(btc, blur_sigma=4.0), DEFN, name="soft")


def test_back_of_the_board_is_not_a_board():
    # the wedge board at table angle 180 faces away from the camera
    btc = camera_pose() @ rigid(rz(180.0), np.zeros(3)) @ wedge_board(45.0)
    with pytest.raises(CharucoError, match="board not found"):
        detect_board(render(btc), DEFN, name="away")


def test_not_an_image():
    with pytest.raises(CharucoError, match="frame x: image of shape"):
        detect_board(np.zeros(10), DEFN, name="x")
    with pytest.raises(CharucoError, match="flat"):
        detect_board(np.ones((64, 64)), DEFN, name="x")


def test_too_few_corners():
    # everything but the board's 60 x 40 mm top-left corner (3 x 2 squares) is covered:
    # truth: 2 inner corners ((20, 20) and (40, 20) mm) are left, fewer than 8
    btc = _front(500.0)
    img = render(btc)
    (x0, y0), (x1, y1) = project(btc, np.array([[0.0, 0.0, 0.0], [60.0, 40.0, 0.0]])).astype(int)
    covered = np.ones(img.shape, bool)
    covered[y0:y1, x0:x1] = False
    img[covered] = img.min()
    with pytest.raises(CharucoError, match=r"frame hidden: too few board corners \(2 < 8\)"):
        detect_board(img, DEFN, name="hidden")
