"""A printed ChArUco board on the turntable, for calibrating the station's camera.

:class:`BoardWorld` is the station world (:class:`mocks.world.World`) with a
flat ChArUco board instead of a scanned object.  The board's printed texture
is OpenCV's own (``cv2.aruco.CharucoBoard(...).generateImage`` at
``px_per_mm``, >= 16 px/mm, on white paper with a ``margin_mm`` border), laid
on the plane ``z = 0`` of the board frame (OpenCV's CharucoBoard object frame:
origin at a corner of the pattern, x along ``squares_x``, y along
``squares_y``, z into the board).  The board's pose on the table
(:attr:`World.pose`, board -> table) is flat on the table or propped on a
wedge at ``tilt_deg`` about its x axis, facing the camera at table angle 0;
placement ``n`` of the station uses the n-th entry of ``tilts_deg`` (cyclic),
each with its own small offset, so a three-pass capture shoots the board flat
and on two wedges.

Frames are rendered analytically: each camera ray meets the board's plane, the
texture is sampled bilinearly at ``supersample x supersample`` points per pixel
and averaged, so the corners are sub-pixel exact.  Paper white reflects 0.85,
print black 0.04 (Lambertian) under the world's lamp (distant or point); rays
missing the board see the backdrop (:data:`mocks.world.BACKDROP_REFLECTANCE`).

Truth for tests: :meth:`BoardWorld.board_to_room`, :attr:`BoardWorld.board`,
:meth:`World.camera_intrinsics`, :meth:`World.room_to_camera`.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocks.world import BACKDROP_REFLECTANCE, Frame, World, WorldError, rotation_z

__all__ = ["BoardWorld", "DEFAULT_BOARD", "WHITE_REFLECTANCE", "BLACK_REFLECTANCE", "board_pose"]

#: The ChArUco board definition the sessions store (see the shared conventions).
DEFAULT_BOARD: dict[str, Any] = {"dictionary": "DICT_5X5_100", "squares_x": 7, "squares_y": 5,
                                 "square_mm": 8.0, "marker_mm": 6.0}
#: Lambertian reflectance of the paper and of the print.
WHITE_REFLECTANCE = 0.85
BLACK_REFLECTANCE = 0.04
#: Reflectance of the board's unprinted back.
_BACK_REFLECTANCE = 0.3
#: Offsets (x, y in mm, table frame) of the board's centre per placement, cycled: behind the axis, where the
#: fixed camera (aimed 37 mm above the table) sees a board lying on the table or on a low wedge.
_OFFSETS_MM = ((0.0, 50.0), (4.0, 30.0), (-5.0, 26.0), (6.0, 40.0), (-4.0, 45.0))


def _board_size_mm(board: dict[str, Any]) -> tuple[float, float]:
    return board["squares_x"] * board["square_mm"], board["squares_y"] * board["square_mm"]


def _check_board(board: Any) -> dict[str, Any]:
    import cv2

    if not isinstance(board, dict) or set(board) != set(DEFAULT_BOARD):
        raise WorldError(f"board must map {', '.join(DEFAULT_BOARD)}, got {board!r}")
    out = {"dictionary": str(board["dictionary"]), "squares_x": int(board["squares_x"]),
           "squares_y": int(board["squares_y"]), "square_mm": float(board["square_mm"]),
           "marker_mm": float(board["marker_mm"])}
    if not hasattr(cv2.aruco, out["dictionary"]):
        raise WorldError(f"board dictionary {out['dictionary']!r} is not an OpenCV ArUco dictionary "
                         "(e.g. DICT_5X5_100)")
    if out["squares_x"] < 3 or out["squares_y"] < 3 or not 0 < out["marker_mm"] < out["square_mm"]:
        raise WorldError(f"board: need squares_x, squares_y >= 3 and 0 < marker_mm < square_mm, got {board!r}")
    return out


def board_pose(board: dict[str, Any], tilt_deg: float, offset_mm: tuple[float, float] = (0.0, 0.0),
               margin_mm: float = 6.0) -> NDArray[np.float64]:
    """Board -> table pose (4 x 4, mm) of a board resting on the table, tilted by ``tilt_deg`` toward -y.

    The printed face's normal is ``(0, -sin t, cos t)``; the board's x axis
    is the table's x; the paper's lower edge rests on the table and the
    board's centre is above ``offset_mm`` (table x, y).

    Examples
    --------
    >>> p = board_pose(DEFAULT_BOARD, 0.0)
    >>> (p[:3, :3] @ [0, 0, -1.0]).round(9).tolist(), (p @ [28.0, 20.0, 0, 1])[:3].round(9).tolist()
    ([0.0, 0.0, 1.0], [0.0, 0.0, 0.0])
    """
    if not (math.isfinite(tilt_deg) and 0.0 <= tilt_deg < 90.0):
        raise WorldError(f"tilt_deg must be in [0, 90) degrees, got {tilt_deg!r}")
    t = math.radians(tilt_deg)
    w, h = _board_size_mm(board)
    rot = np.array([[1.0, 0.0, 0.0], [0.0, -math.cos(t), math.sin(t)], [0.0, -math.sin(t), -math.cos(t)]])
    centre = np.array([offset_mm[0], offset_mm[1], (h / 2 + margin_mm) * math.sin(t)])
    pose = np.eye(4)
    pose[:3, :3] = rot
    pose[:3, 3] = centre - rot @ [w / 2, h / 2, 0.0]
    return pose


@functools.lru_cache(maxsize=4)
def _texture(dictionary: str, sx: int, sy: int, square: float, marker: float, ppmm: float,
             margin_mm: float) -> NDArray[np.float32]:
    """``(H, W, 2)`` float32: reflectance and coverage (1) of the printed sheet, margin included."""
    import cv2

    board = cv2.aruco.CharucoBoard((sx, sy), square, marker,
                                   cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary)))
    margin = int(round(margin_mm * ppmm))
    size = (int(round(sx * square * ppmm)) + 2 * margin, int(round(sy * square * ppmm)) + 2 * margin)
    img = board.generateImage(size, marginSize=margin, borderBits=1).astype(np.float32) / 255.0
    refl = BLACK_REFLECTANCE + (WHITE_REFLECTANCE - BLACK_REFLECTANCE) * img
    return np.dstack([refl, np.ones_like(refl)])


@dataclass
class BoardWorld(World):
    """The station world with a ChArUco board on the table (see the module's description).

    Attributes (besides :class:`mocks.world.World`'s)
    -------------------------------------------------
    board
        The board definition (``dictionary``, ``squares_x``, ``squares_y``,
        ``square_mm``, ``marker_mm``), OpenCV's CharucoBoard.
    tilts_deg
        Wedge angle (degrees, 0 = flat) of placement n = 1, 2, ... (cyclic).
    px_per_mm
        Resolution of the printed texture (>= 16).
    margin_mm
        White paper around the pattern.
    supersample
        Samples per pixel along each axis (>= 3).
    """

    board: dict[str, Any] = field(default_factory=lambda: dict(DEFAULT_BOARD))
    tilts_deg: tuple[float, ...] = (0.0, 40.0, 55.0)
    px_per_mm: float = 16.0
    margin_mm: float = 6.0
    supersample: int = 3

    def __post_init__(self) -> None:
        super().__post_init__()
        self.board = _check_board(self.board)
        self.tilts_deg = tuple(float(t) for t in self.tilts_deg)
        if not self.tilts_deg:
            raise WorldError("tilts_deg must hold at least one wedge angle (degrees, 0 = flat)")
        for t in self.tilts_deg:
            board_pose(self.board, t)                      # validates the angle
        if not (self.px_per_mm >= 16 and self.margin_mm >= 0):
            raise WorldError(f"px_per_mm must be >= 16 and margin_mm >= 0, got {self.px_per_mm!r}, "
                             f"{self.margin_mm!r}")
        if not isinstance(self.supersample, (int, np.integer)) or self.supersample < 3:
            raise WorldError(f"supersample must be an integer >= 3, got {self.supersample!r}")

    @classmethod
    def charuco(cls, board: dict[str, Any] | None = None, tilts_deg: tuple[float, ...] = (0.0, 40.0, 55.0),
                **kwargs: Any) -> BoardWorld:
        """A board world in placement 1 (``tilts_deg[0]``); keyword arguments set :class:`World` fields.

        Defaults: 960 x 640 pixels, 25 degrees field of view.

        Examples
        --------
        >>> w = BoardWorld.charuco(tilts_deg=(55.0,), width=96, height=64)
        >>> w.board["squares_x"], w.frame("object", 0.0).radiance.shape[:2]
        (7, (64, 96))
        """
        b = _check_board(dict(DEFAULT_BOARD) if board is None else board)
        tilts = tuple(float(t) for t in tilts_deg)
        if not tilts:
            raise WorldError("tilts_deg must hold at least one wedge angle (degrees, 0 = flat)")
        margin = float(kwargs.pop("margin_mm", 6.0))
        w, h = _board_size_mm(b)
        vertices = np.array([[-margin, -margin, 0.0], [w + margin, -margin, 0.0], [w + margin, h + margin, 0.0],
                             [-margin, h + margin, 0.0]])
        triangles = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
        kwargs.setdefault("width", 960)
        kwargs.setdefault("height", 640)
        kwargs.setdefault("fov_deg", 25.0)
        kwargs.setdefault("pose", board_pose(b, tilts[0], _OFFSETS_MM[0], margin))
        source = f"board:{b['dictionary']}:{b['squares_x']}x{b['squares_y']}"
        return cls(vertices, triangles, np.zeros(2, np.int64), ("board",), {"board": "paper"},
                   mesh_source=source, board=b, tilts_deg=tilts, margin_mm=margin, **kwargs)

    @property
    def shows_chart(self) -> bool:
        """A calibration target: the station shoots no chart frame."""
        return False

    def fixed_placement_pose(self, placement: int) -> NDArray[np.float64]:
        """Board -> table pose of station placement ``placement`` (>= 1): the n-th tilt, its own offset."""
        i = (int(placement) - 1) % len(self.tilts_deg)
        return board_pose(self.board, self.tilts_deg[i], _OFFSETS_MM[(int(placement) - 1) % len(_OFFSETS_MM)],
                          self.margin_mm)

    def board_to_room(self, table_angle_deg: float | None = None) -> NDArray[np.float64]:
        """True board -> room transform (4 x 4, mm) at a table angle (None: :attr:`table_angle_deg`)."""
        angle = self.table_angle_deg if table_angle_deg is None else float(table_angle_deg)
        return rotation_z(angle) @ self.pose

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> BoardWorld:
        """Rebuild from :meth:`to_dict` (the fake gphoto2's configuration).

        Examples
        --------
        >>> w = BoardWorld.charuco(tilts_deg=(30.0, 50.0), width=96, height=64)
        >>> v = BoardWorld.from_dict(w.to_dict())
        >>> v.tilts_deg, bool(np.allclose(v.pose, w.pose)), v.width
        ((30.0, 50.0), True, 96)
        """
        from mocks.world import world_settings

        data = dict(data)
        spec = data.pop("board")
        if not isinstance(spec, dict) or not {"definition", "tilts_deg"} <= set(spec):
            raise WorldError(f"world 'board' entry must map definition and tilts_deg, got {spec!r}")
        data.pop("mesh", None)
        data.pop("materials", None)
        extra = {k: spec[k] for k in ("px_per_mm", "margin_mm", "supersample") if k in spec}
        return cls.charuco(spec["definition"], tuple(spec["tilts_deg"]), **extra, **world_settings(data))

    def to_dict(self) -> dict[str, Any]:
        """The station world's mapping plus ``"board"``: definition, tilts, texture resolution, supersampling."""
        out = super().to_dict()
        out["board"] = {"definition": dict(self.board), "tilts_deg": list(self.tilts_deg),
                        "px_per_mm": float(self.px_per_mm), "margin_mm": float(self.margin_mm),
                        "supersample": int(self.supersample)}
        return out

    def _object_frame(self, angle: float) -> Frame:
        """The board at table angle ``angle``: rays meet its plane, the texture is supersampled."""
        import cv2

        grid, e = self.grid, self.light_spectrum()
        b = self.board
        tex = _texture(b["dictionary"], b["squares_x"], b["squares_y"], b["square_mm"], b["marker_mm"],
                       float(self.px_per_mm), float(self.margin_mm))
        to_room = self.board_to_room(angle)
        rot, trans = to_room[:3, :3], to_room[:3, 3]
        eye, axes = self._camera_axes()
        k = self.camera_intrinsics()
        s = int(self.supersample)
        sub = (np.arange(s) + 0.5) / s - 0.5
        x = ((np.arange(self.width)[:, None] + sub).ravel() - k[0, 2]) / k[0, 0]
        y = ((np.arange(self.height)[:, None] + sub).ravel() - k[1, 2]) / k[1, 1]
        # everything in the board frame: ray = eye_b + t (a + x bx + y by), plane z_b = 0
        eye_b = rot.T @ (eye - trans)
        a, bx, by = rot.T @ axes[2], rot.T @ axes[0], rot.T @ axes[1]
        dz = a[2] + x[None, :] * bx[2] + y[:, None] * by[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -eye_b[2] / dz
        t = np.where(t > 0, t, np.nan).astype(np.float32)
        ppmm, m = float(self.px_per_mm), float(self.margin_mm)
        map_x = (eye_b[0] + t * (a[0] + x[None, :] * bx[0] + y[:, None] * by[0]).astype(np.float32) + m) * ppmm - 0.5
        map_y = (eye_b[1] + t * (a[1] + x[None, :] * bx[1] + y[:, None] * by[1]).astype(np.float32) + m) * ppmm - 0.5
        map_x = np.nan_to_num(map_x, nan=-1e6).astype(np.float32)
        map_y = np.nan_to_num(map_y, nan=-1e6).astype(np.float32)
        sampled = cv2.remap(tex, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        h, w = self.height, self.width
        sampled = sampled.reshape(h, s, w, s, 2).mean(axis=(1, 3), dtype=np.float64)
        front = eye_b[2] < 0                       # the printed face looks along -z of the board frame
        refl, cover = (sampled[..., 0], sampled[..., 1]) if front else (_BACK_REFLECTANCE * sampled[..., 1],
                                                                         sampled[..., 1])
        normal = rot @ [0.0, 0.0, -1.0 if front else 1.0]
        centre = self._rays(1)[1].reshape(-1, 3)
        tc = -(eye_b[2]) / (centre @ rot[:, 2])
        points = eye + centre * np.where(np.isfinite(tc) & (tc > 0), tc, 0.0)[:, None]
        light, irradiance, _ = self._lamp_at(points)
        shade = (np.clip(light @ normal, 0.0, None) * irradiance).reshape(h, w)
        scalar = refl * shade + (1.0 - cover) * BACKDROP_REFLECTANCE
        labels = np.where(cover > 0.5, 0, -1).astype(np.int16)      # the board (either face) or backdrop
        return Frame(scalar[..., None] * (e / math.pi), grid, e, labels, "object", angle)
