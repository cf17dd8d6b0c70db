"""ChArUco boards: the definition stored in sessions, and their detection in a linear frame.

A board is defined by an ArUco dictionary, its size in squares and the side
of a square and of a marker in millimetres (the session's JSON form is
``{"dictionary": "DICT_5X5_100", "squares_x": 9, "squares_y": 6,
"square_mm": 15.0, "marker_mm": 11.0}``).  The board frame is OpenCV's
``CharucoBoard`` object frame: origin at a board corner, ``x`` along
``squares_x``, ``y`` along ``squares_y``, ``z = 0`` on the printed face
(``z`` points into the board).

:func:`detect_board` finds the inner chessboard corners with
``cv2.aruco.CharucoDetector`` in an 8-bit grey copy of the linear frame (a
0.5-99.5 % percentile stretch), refines them to sub-pixel with
``cv2.cornerSubPix`` and rejects a frame whose board is missing, shows too few
corners, is partly outside, too small or blurred.  Sharpness is the 10-90 %
width of the chessboard edges: for every pair of neighbouring corners the
grey profile across the edge between them is sampled at its middle, and the
width is the board's black-white contrast divided by the profile's steepest
slope (for a Gaussian-blurred step this equals the 10-90 % rise distance,
``2.56 sigma``, within 2 %).  The median over the edges must not exceed
``max_edge_width_px`` (default 4 px: a sharp, supersampled edge measures
about 1-1.5 px, a blur of sigma 1.5 px about 4 px).

References
----------
.. [1] Garrido-Jurado, S., Munoz-Salinas, R., Madrid-Cuevas, F. J.,
   Marin-Jimenez, M. J. (2014). Automatic generation and detection of highly
   reliable fiducial markers under occlusion. Pattern Recognition 47(6),
   2280-2292. doi:10.1016/j.patcog.2014.01.005
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.ndimage import map_coordinates

from processing.errors import InputError

__all__ = [
    "BoardDefinition",
    "BoardDetection",
    "CharucoError",
    "MIN_CORNERS",
    "board_corners_mm",
    "detect_board",
    "make_board",
]

#: Fewest interpolated chessboard corners a usable view shows.
MIN_CORNERS = 8
#: Smallest share of the image the corners' convex hull must cover.
MIN_AREA_FRACTION = 0.02
#: Distance (px) from the image border within which a marker corner counts as touching it.
BORDER_PX = 2.0


class CharucoError(InputError):
    """A board definition or a board frame is unusable; the message names it and says what to do."""


@dataclass(frozen=True)
class BoardDefinition:
    """A ChArUco board as printed.

    Parameters
    ----------
    dictionary
        Name of an OpenCV predefined ArUco dictionary, e.g. ``"DICT_5X5_100"``.
    squares_x, squares_y
        Squares along the board's x and y (each >= 3).
    square_mm
        Side of a chessboard square (mm), > 0.
    marker_mm
        Side of a marker (mm), ``0 < marker_mm < square_mm``.

    Examples
    --------
    >>> d = BoardDefinition.from_dict({"dictionary": "DICT_5X5_100", "squares_x": 9,
    ...                                "squares_y": 6, "square_mm": 15.0, "marker_mm": 11.0})
    >>> d.to_dict()["squares_x"], board_corners_mm(d).shape
    (9, (40, 3))
    """

    dictionary: str = "DICT_5X5_100"
    squares_x: int = 7
    squares_y: int = 5
    square_mm: float = 8.0
    marker_mm: float = 6.0

    def __post_init__(self) -> None:
        """Validate every field; one-line :class:`CharucoError` naming the bad one."""
        if not isinstance(self.dictionary, str) or not self.dictionary.startswith("DICT_") \
                or not isinstance(getattr(cv2.aruco, self.dictionary, None), int):
            raise CharucoError(f"board dictionary {self.dictionary!r} is not an OpenCV ArUco dictionary; "
                               "use a name like 'DICT_5X5_100'")
        for name in ("squares_x", "squares_y"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 3 <= int(v) <= 100:
                raise CharucoError(f"board {name} = {v!r} must be an integer in [3, 100]")
        for name in ("square_mm", "marker_mm"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.number)) or not np.isfinite(v) \
                    or not 0.0 < float(v) <= 1000.0:
                raise CharucoError(f"board {name} = {v!r} must be a length in (0, 1000] mm")
        if not float(self.marker_mm) < float(self.square_mm):
            raise CharucoError(f"board marker_mm = {self.marker_mm} must be smaller than square_mm = {self.square_mm}")
        n_markers = (int(self.squares_x) * int(self.squares_y)) // 2
        dict_size = len(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary)).bytesList)
        if n_markers > dict_size:
            raise CharucoError(f"board dictionary {self.dictionary} holds {dict_size} markers but a "
                               f"{self.squares_x} x {self.squares_y} board needs {n_markers}; use a larger dictionary")

    @classmethod
    def from_dict(cls, data: Any) -> BoardDefinition:
        """Build from the JSON form, validating it as untrusted input.

        Parameters
        ----------
        data
            Mapping with the keys ``dictionary, squares_x, squares_y, square_mm, marker_mm``.

        Returns
        -------
        BoardDefinition
        """
        if not isinstance(data, dict):
            raise CharucoError(f"board definition must be a JSON object, got {type(data).__name__}")
        keys = ("dictionary", "squares_x", "squares_y", "square_mm", "marker_mm")
        missing = [k for k in keys if k not in data]
        if missing:
            raise CharucoError(f"board definition lacks {', '.join(missing)}; give all of {', '.join(keys)}")
        return cls(**{k: data[k] for k in keys})

    def to_dict(self) -> dict[str, Any]:
        """The JSON form.

        Returns
        -------
        dict
        """
        return {"dictionary": self.dictionary, "squares_x": int(self.squares_x), "squares_y": int(self.squares_y),
                "square_mm": float(self.square_mm), "marker_mm": float(self.marker_mm)}


@dataclass(frozen=True)
class BoardDetection:
    """The board's corners found in one frame.

    Attributes
    ----------
    name
        The frame's name (for messages).
    corners_px
        ``(N, 2)`` sub-pixel corner positions (OpenCV pixel convention).
    ids
        ``(N,)`` chessboard corner ids (rows of :func:`board_corners_mm`).
    n_markers
        Markers decoded.
    area_fraction
        Share of the image covered by the corners' convex hull.
    edge_width_px
        Median 10-90 % width of the chessboard edges (px).
    """

    name: str
    corners_px: NDArray[np.float64]
    ids: NDArray[np.int64]
    n_markers: int
    area_fraction: float
    edge_width_px: float


def make_board(defn: BoardDefinition) -> cv2.aruco.CharucoBoard:
    """The OpenCV board object (lengths in mm).

    Parameters
    ----------
    defn
        Board definition.

    Returns
    -------
    cv2.aruco.CharucoBoard
    """
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, defn.dictionary))
    return cv2.aruco.CharucoBoard((int(defn.squares_x), int(defn.squares_y)), float(defn.square_mm),
                                  float(defn.marker_mm), dictionary)


def board_corners_mm(defn: BoardDefinition) -> NDArray[np.float64]:
    """Inner chessboard corners in the board frame, indexed by corner id.

    Parameters
    ----------
    defn
        Board definition.

    Returns
    -------
    ndarray
        ``((squares_x - 1) * (squares_y - 1), 3)`` in mm, ``z = 0``.
    """
    return np.asarray(make_board(defn).getChessboardCorners(), dtype=np.float64).reshape(-1, 3)


def _grey(image: ArrayLike, name: str) -> NDArray[np.float32]:
    """Grey copy of a linear image stretched to [0, 255] by robust percentiles (float)."""
    img = np.asarray(image, dtype=np.float64)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        img = img[..., :3].mean(axis=2)
    if img.ndim != 2 or min(img.shape) < 16:
        raise CharucoError(f"frame {name}: image of shape {img.shape} is not an (H, W) or (H, W, 3) picture")
    finite = np.isfinite(img)
    if not finite.all():
        img = np.where(finite, img, np.nanmedian(np.where(finite, img, np.nan)) if finite.any() else 0.0)
    lo, hi = np.percentile(img, [0.5, 99.5])
    if not hi > lo:
        raise CharucoError(f"frame {name}: board not found (the image is flat); check exposure and the lens cap")
    return np.clip((img - lo) * (255.0 / (hi - lo)), 0.0, 255.0).astype(np.float32)


def _edge_width_px(grey: NDArray[np.uint8], corners: NDArray[np.float64], ids: NDArray[np.int64],
                   nx: int, hull: NDArray[np.float32]) -> float:
    """Median contrast / steepest slope across the edges between neighbouring corners (px)."""
    pos = {int(i): k for k, i in enumerate(ids)}
    pairs = [(pos[i], pos[i + 1]) for i in pos if (i + 1) in pos and (i + 1) % nx != 0]
    pairs += [(pos[i], pos[i + nx]) for i in pos if (i + nx) in pos]
    if not pairs:
        return float("nan")
    a, b = corners[[p[0] for p in pairs]], corners[[p[1] for p in pairs]]
    seg = b - a
    length = np.linalg.norm(seg, axis=1, keepdims=True)
    normal = np.stack([-seg[:, 1], seg[:, 0]], 1) / length
    step = 0.25
    t = np.arange(-0.1, 0.1 + 1e-9, step / length.mean()) if length.mean() > 0 else np.zeros(1)
    offs = t[None, :, None] * length[:, :, None] * normal[:, None, :]
    pts = 0.5 * (a + b)[:, None, :] + offs
    prof = map_coordinates(grey.astype(np.float64), [pts[..., 1].ravel(), pts[..., 0].ravel()], order=1,
                           mode="nearest").reshape(pts.shape[:2])
    spacing = (t[1] - t[0]) * length[:, 0] if t.size > 1 else np.ones(len(pairs))
    lag = 4
    slope = np.abs(prof[:, lag:] - prof[:, :-lag]).max(axis=1) / (lag * spacing)
    mask = np.zeros(grey.shape, np.uint8)
    cv2.fillConvexPoly(mask, hull.reshape(-1, 2).round().astype(np.int32), 1)
    inside = grey[mask.astype(bool)]
    lo, hi = np.percentile(inside, [5, 95])
    return float(np.median((hi - lo) / np.maximum(slope, 1e-9)))


def _refine(grey: NDArray[np.float32], corners: NDArray[np.float64], ids: NDArray[np.int64],
            defn: BoardDefinition) -> NDArray[np.float64]:
    """Sub-pixel corners: ``cv2.cornerSubPix`` in the board plane rectified by the corners' homography.

    Rectifying first keeps the window inside the white margin around the markers even on a
    steeply foreshortened board, and a corner the detector misplaced is predicted from the others
    (RANSAC homography) before it is refined.
    """
    obj = board_corners_mm(defn)[ids, :2]
    hom, _ = cv2.findHomography(obj, corners, cv2.RANSAC, 3.0)
    if hom is None:
        return corners
    ppm = 80.0 / float(defn.square_mm)
    lo = obj.min(axis=0) - defn.square_mm
    size = np.ceil((obj.max(axis=0) + defn.square_mm - lo) * ppm).astype(int)
    rect_to_mm = np.array([[1 / ppm, 0, lo[0]], [0, 1 / ppm, lo[1]], [0, 0, 1.0]])
    rect_to_img = hom @ rect_to_mm
    rect = cv2.warpPerspective(grey, rect_to_img, (int(size[0]), int(size[1])),
                               flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)
    start = ((obj - lo) * ppm).astype(np.float32).reshape(-1, 1, 2)
    half = int(max(2, np.floor(0.5 * (defn.square_mm - defn.marker_mm) * ppm) - 1))
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
    ref = cv2.cornerSubPix(rect, start.copy(), (half, half), (-1, -1), crit).reshape(1, -1, 2)
    return cv2.perspectiveTransform(ref.astype(np.float64), rect_to_img).reshape(-1, 2)


def _check_inside(name: str, grey: NDArray[np.uint8], marker_corners: Any, corners: NDArray[np.float64],
                  ids: NDArray[np.int64], defn: BoardDefinition) -> None:
    """Reject a board whose markers touch the border or whose outline leaves the image."""
    h, w = grey.shape
    mk = np.concatenate([np.asarray(c, dtype=np.float64).reshape(-1, 2) for c in marker_corners])
    near = (mk[:, 0] < BORDER_PX) | (mk[:, 1] < BORDER_PX) | (mk[:, 0] > w - 1 - BORDER_PX) \
        | (mk[:, 1] > h - 1 - BORDER_PX)
    outline_out = False
    if len(ids) >= 4:
        obj = board_corners_mm(defn)[ids, :2]
        hom, _ = cv2.findHomography(obj, corners, 0)
        if hom is not None:
            sx, sy = defn.squares_x * defn.square_mm, defn.squares_y * defn.square_mm
            rect = np.array([[[0.0, 0.0], [sx, 0.0], [sx, sy], [0.0, sy]]])
            out = cv2.perspectiveTransform(rect, hom).reshape(-1, 2)
            outline_out = bool(np.any(out < -0.5) or np.any(out[:, 0] > w - 0.5) or np.any(out[:, 1] > h - 0.5))
    if near.any() or outline_out:
        raise CharucoError(f"frame {name}: the board is partly outside the image; "
                           "move or turn it so the whole board is in view")


def detect_board(image: ArrayLike, defn: BoardDefinition, *, name: str,
                 max_edge_width_px: float = 4.0) -> BoardDetection:
    """Find a ChArUco board's inner corners in a linear frame, or say why the frame is unusable.

    Parameters
    ----------
    image
        Linear image ``(H, W)`` or ``(H, W, 3)``, any scale (NaN is tolerated).
    defn
        The board as printed.
    name
        The frame's name, used in messages.
    max_edge_width_px
        Largest accepted median 10-90 % edge width (px); see the module notes.

    Returns
    -------
    BoardDetection

    Raises
    ------
    CharucoError
        Board not found, fewer than :data:`MIN_CORNERS` corners, partly outside, covering
        less than 2 % of the image, or blurred.
    """
    grey_f = _grey(image, name)
    grey = grey_f.round().astype(np.uint8)
    h, w = grey.shape
    detector = cv2.aruco.CharucoDetector(make_board(defn))
    ch_corners, ch_ids, marker_corners, marker_ids = detector.detectBoard(grey)
    if marker_ids is None or len(marker_ids) == 0:
        raise CharucoError(f"frame {name}: board not found (no markers decoded); check that the board "
                           f"({defn.dictionary}, {defn.squares_x} x {defn.squares_y}) faces the camera, lit and in focus")
    n = 0 if ch_ids is None else len(ch_ids)
    corners = np.zeros((0, 2)) if n == 0 else np.asarray(ch_corners, dtype=np.float64).reshape(-1, 2)
    ids = np.zeros(0, np.int64) if n == 0 else np.asarray(ch_ids, dtype=np.int64).ravel()
    _check_inside(name, grey, marker_corners, corners, ids, defn)
    if n < MIN_CORNERS:
        raise CharucoError(f"frame {name}: too few board corners ({n} < {MIN_CORNERS}); "
                           "show more of the board, less obliquely")
    corners = _refine(grey_f, corners, ids, defn)
    hull = cv2.convexHull(corners.astype(np.float32))
    area = float(cv2.contourArea(hull)) / float(w * h)
    if area < MIN_AREA_FRACTION:
        raise CharucoError(f"frame {name}: the board is too small ({100 * area:.1f} % of the image < "
                           f"{100 * MIN_AREA_FRACTION:.0f} %); bring the camera closer or use a larger board")
    width = _edge_width_px(grey, corners, ids, int(defn.squares_x) - 1, hull)
    if not width <= max_edge_width_px:
        raise CharucoError(f"frame {name}: the board is blurred (edge width {width:.1f} px > "
                           f"{max_edge_width_px:g} px); focus on the board and avoid motion")
    return BoardDetection(name=name, corners_px=corners, ids=ids, n_markers=len(marker_ids),
                          area_fraction=area, edge_width_px=width)
