"""Synthetic ChArUco frames of a known camera and turntable, for the detection and calibration tests.

The board texture (``CharucoBoard.generateImage`` on a white plate) is mapped into the frame by the
plane homography ``K [r1 r2 t]``, rendered at 4x and averaged down (``INTER_AREA``), then scaled to a
linear range and given Gaussian noise.  A board whose printed face turns away from the camera is
drawn as a blank grey plate (its back).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from processing.camera.charuco import BoardDefinition, make_board

DEFN = BoardDefinition("DICT_5X5_100", 9, 6, 20.0, 15.0)  # 180 x 120 mm
WIDTH, HEIGHT = 960, 640
FX = (WIDTH / 2) / math.tan(math.radians(12.5))  # 2165.1 px, fov 25 deg
K_TRUE = np.array([[FX, 0.0, WIDTH / 2 - 0.5], [0.0, FX, HEIGHT / 2 - 0.5], [0.0, 0.0, 1.0]])
PPM = 10.0  # texture pixels per mm
MARGIN_MM = 8.0


def rz(deg):
    a = math.radians(deg)
    return np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1.0]])


def rx(deg):
    a = math.radians(deg)
    return np.array([[1.0, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])


def rigid(r, t):
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = r, t
    return m


def look_at(centre, target, roll_deg=0.0):
    """room_to_camera of a camera at ``centre`` looking at ``target`` (x right, y down, z forward)."""
    centre, target = np.asarray(centre, float), np.asarray(target, float)
    z = (target - centre) / np.linalg.norm(target - centre)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    r = np.stack([x, y, z])
    c, s = math.cos(math.radians(roll_deg)), math.sin(math.radians(roll_deg))
    r = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]) @ r
    return rigid(r, -r @ centre)


def camera_pose(distance_mm=600.0, elevation_deg=15.0, azimuth_deg=-70.0, target_z_mm=45.0, roll_deg=1.5):
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    centre = np.array([distance_mm * math.cos(el) * math.cos(az), distance_mm * math.cos(el) * math.sin(az),
                       target_z_mm + distance_mm * math.sin(el)])
    return look_at(centre, [0.0, 0.0, target_z_mm], roll_deg)


def flat_board(yaw_deg=10.0, offset=(-90.0, -60.0)):
    """Board lying face up on the table: board x -> table x, board y -> -table y, board z -> -table z."""
    r = rz(yaw_deg) @ rx(180.0)
    return rigid(r, rz(yaw_deg) @ np.array([offset[0], -offset[1], 0.0]))


def wedge_board(tilt_deg=45.0, yaw_deg=0.0, along_mm=-90.0, base_mm=(10.0, 0.0), height_mm=120.0):
    """Board on a wedge tilted ``tilt_deg`` from the table (0 = flat); its bottom edge is its y = height row.

    At table angle 0 and yaw 0 the printed face looks toward -Y (toward the camera's side).
    """
    # Start upright facing -Y: board x -> +X, board y -> -Z (rows go down), board z -> +Y (into the board).
    upright = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])
    r = rz(yaw_deg) @ rx(-(90.0 - tilt_deg)) @ upright
    bottom = np.array([along_mm, -base_mm[0], base_mm[1]])
    t = rz(yaw_deg) @ bottom - r @ np.array([0.0, height_mm, 0.0])
    return rigid(r, t)


@dataclass
class Shot:
    name: str
    angle_deg: float
    group: str
    board_to_camera: np.ndarray
    image: np.ndarray


def _texture(defn, ppm, margin_mm):
    sx, sy = defn.squares_x * defn.square_mm, defn.squares_y * defn.square_mm
    size = (int(round(sx * ppm)), int(round(sy * ppm)))
    board = make_board(defn).generateImage(size, marginSize=0, borderBits=1)
    m = int(round(margin_mm * ppm))
    plate = np.full((size[1] + 2 * m, size[0] + 2 * m), 255, np.uint8)
    plate[m:m + size[1], m:m + size[0]] = board
    tex_to_mm = np.array([[1 / ppm, 0, 0.5 / ppm - margin_mm], [0, 1 / ppm, 0.5 / ppm - margin_mm], [0, 0, 1.0]])
    return plate, tex_to_mm


def render(board_to_camera, k=K_TRUE, size=(WIDTH, HEIGHT), defn=DEFN, noise=0.004, blur_sigma=0.0, rng=None,
           scale=0.37, ss=4, background=0.25):
    """Linear float frame of the board at ``board_to_camera`` (4x4) through the pinhole ``k``."""
    rng = np.random.default_rng(0) if rng is None else rng
    plate, tex_to_mm = _texture(defn, PPM, MARGIN_MM)
    r, t = board_to_camera[:3, :3], board_to_camera[:3, 3]
    if (r[:, 2] @ (-t)) > 0:  # camera on the +z (back) side of the board
        plate = np.full_like(plate, 140)
    sup = np.array([[ss, 0, (ss - 1) / 2], [0, ss, (ss - 1) / 2], [0, 0, 1.0]])
    hom = sup @ k @ np.column_stack([r[:, 0], r[:, 1], t]) @ tex_to_mm
    w, h = size
    big = cv2.warpPerspective(plate.astype(np.float32) / 255.0, hom, (w * ss, h * ss), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=background)
    img = cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA).astype(np.float64)
    img = 0.03 + 0.9 * img
    if blur_sigma > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_sigma)
    img = img + rng.normal(0.0, noise, img.shape)
    return scale * img


def project(board_to_camera, points_board, k=K_TRUE):
    pc = points_board @ board_to_camera[:3, :3].T + board_to_camera[:3, 3]
    uv = pc @ k.T
    return uv[:, :2] / uv[:, 2:]


def turntable_shots(groups, angles_deg, room_to_camera, seed=1, noise=0.004):
    """Frames of every group (name -> board_to_table) at every table angle."""
    rng = np.random.default_rng(seed)
    out = []
    for g, b in groups.items():
        for a in angles_deg:
            btc = room_to_camera @ rigid(rz(a), np.zeros(3)) @ b
            out.append(Shot(f"{g}-{a:03.0f}", float(a), g, btc, render(btc, rng=rng, noise=noise)))
    return out
