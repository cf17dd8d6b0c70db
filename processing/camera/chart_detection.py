"""Colour-chart detection: where each patch of a ColorChecker Classic / Digital SG / vinyl chart lies.

:func:`detect_chart` runs OpenCV's ``cv2.mcc`` on the sRGB preview of
:func:`processing.camera.raw_decode.preview_srgb8` and refines the patch
centres by segmenting each patch and fitting a homography (RANSAC) to their
centroids; :func:`chart_from_corners` is the manual fallback from the chart's
four outer corners.  Coordinates are full-resolution sensor pixels with pixel
centres at integers.  docs/colour-pipeline.md, "Detection", describes the
steps and the failures.

References
----------
Marrero Fernandez, P. D., Guerrero-Pena, F. A., Ren, T. I., et al. (2019).
Fast and robust multiple ColorChecker detection using deep convolutional
neural networks. Image and Vision Computing 81 (arXiv:1810.08639).

Hartley, R., Zisserman, A. (2004). Multiple View Geometry in Computer Vision,
2nd ed., Cambridge University Press, algorithm 4.6.
doi:10.1017/CBO9780511811685
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.camera.chart_layout import ChartLayout, chart_layout, chart_type_hint
from processing.camera.raw_decode import RawImage, preview_srgb8
from processing.errors import InputError

__all__ = [
    "ChartDetection",
    "ChartDetectionError",
    "ChartNotFoundError",
    "ChartOutsideError",
    "detect_chart",
    "chart_from_corners",
    "parse_corners",
]

_CORNERS_HINT = "pass the chart's four outer corners as --chart-corners x1,y1,x2,y2,x3,y3,x4,y4"


class ChartDetectionError(InputError):
    """The chart cannot be located; the message says what to check."""


class ChartNotFoundError(ChartDetectionError):
    """No chart of the requested type was found in the image."""


class ChartOutsideError(ChartDetectionError):
    """The chart is partly outside the frame."""


@dataclass
class ChartDetection:
    """A located chart.

    Parameters
    ----------
    chart, corners, homography, quads, centres, confidence, method, seconds, image_size, mcc_cost
        The attributes below, in this order.

    Attributes
    ----------
    chart
        ``"classic24"``, ``"sg140"`` or ``"vinyl18"``.
    corners
        ``(4, 2)`` outer corners of the chart's frame (x, y), sensor pixels,
        in the chart's own order (top-left, top-right, bottom-right,
        bottom-left as printed).
    homography
        ``(3, 3)`` model units -> sensor pixels.
    quads
        ``(N, 4, 2)`` patch corners in reading order, sensor pixels.
    centres
        ``(N, 2)`` patch centres, sensor pixels.
    confidence
        Fraction of patches confirmed in the image (1.0 for manual corners).
    method
        ``"mcc"`` or ``"manual"``.
    seconds
        Time taken.
    image_size
        ``(width, height)`` of the sensor image, or None when unknown.
    mcc_cost
        ``cv2.mcc``'s colour-matching cost (None for manual corners).
    """

    chart: str
    corners: NDArray[np.float64]
    homography: NDArray[np.float64] = field(repr=False)
    quads: NDArray[np.float64] = field(repr=False)
    centres: NDArray[np.float64] = field(repr=False)
    confidence: float
    method: str
    seconds: float
    image_size: tuple[int, int] | None = None
    mcc_cost: float | None = None

    @property
    def layout(self) -> ChartLayout:
        """The chart's layout (:func:`processing.camera.chart_layout.chart_layout`)."""
        return chart_layout(self.chart)


def _apply(h: NDArray[np.float64], pts: NDArray[np.float64]) -> NDArray[np.float64]:
    """Points ``(..., 2)`` mapped by the homography ``h``."""
    p = np.asarray(pts, dtype=np.float64)
    flat = p.reshape(-1, 2)
    m = np.column_stack([flat, np.ones(len(flat))]) @ h.T
    return (m[:, :2] / m[:, 2:3]).reshape(p.shape)


def _homography(src: NDArray[np.float64], dst: NDArray[np.float64]) -> NDArray[np.float64]:
    """The homography taking four points ``src`` to ``dst``."""
    import cv2

    return cv2.getPerspectiveTransform(np.asarray(src, np.float32), np.asarray(dst, np.float32)).astype(np.float64)


def _build(chart: str, h: NDArray[np.float64], confidence: float, method: str, seconds: float,
           image_size: tuple[int, int] | None, cost: float | None) -> ChartDetection:
    """The detection of homography ``h`` (model units -> sensor pixels), refused if partly outside the image."""
    layout = chart_layout(chart)
    quads = _apply(h, layout.quads())
    centres = _apply(h, layout.centres())
    det = ChartDetection(chart, _apply(h, layout.corners), h, quads, centres, float(confidence), method,
                         float(seconds), image_size, cost)
    _check_inside(det)
    return det


def _check_inside(det: ChartDetection) -> None:
    """Raise :class:`ChartOutsideError` naming the patches beyond the image, if any."""
    if det.image_size is None:
        return
    w, h = det.image_size
    pts = det.quads.reshape(-1, 2)
    outside = (pts[:, 0] < -0.5) | (pts[:, 0] > w - 0.5) | (pts[:, 1] < -0.5) | (pts[:, 1] > h - 0.5)
    if outside.any():
        patches = sorted({int(i) // 4 + 1 for i in np.flatnonzero(outside)})
        listed = ", ".join(str(p) for p in patches[:8]) + (" ..." if len(patches) > 8 else "")
        raise ChartOutsideError(
            f"the {det.chart} chart is partly outside the frame (patches {listed} fall beyond the "
            f"{w} x {h} image); reframe so the whole chart is in view"
        )


def parse_corners(text: str) -> NDArray[np.float64]:
    """``"x1,y1,x2,y2,x3,y3,x4,y4"`` -> ``(4, 2)`` float array.

    Parameters
    ----------
    text
        Eight numbers separated by commas or semicolons (sensor pixels).

    Returns
    -------
    ndarray
        ``(4, 2)`` float64 (x, y) corners.

    Raises
    ------
    ChartDetectionError
        Not numbers, or not eight of them.

    Examples
    --------
    >>> parse_corners("10,20, 110,20, 110,90, 10,90")[2].tolist()
    [110.0, 90.0]
    """
    try:
        vals = [float(v) for v in str(text).replace(";", ",").split(",") if v.strip()]
    except ValueError:
        raise ChartDetectionError(f"chart corners {text!r}: not numbers; {_CORNERS_HINT}") from None
    if len(vals) != 8:
        raise ChartDetectionError(f"chart corners {text!r}: need 8 numbers (4 x, y pairs), got {len(vals)}; "
                                  f"{_CORNERS_HINT}")
    return np.array(vals, dtype=np.float64).reshape(4, 2)


def chart_from_corners(corners: ArrayLike, chart: str = "classic24", *,
                       image_size: tuple[int, int] | None = None) -> ChartDetection:
    """Patch positions from the four outer corners of the chart's frame (manual fallback).

    Parameters
    ----------
    corners
        ``(4, 2)`` sensor pixels: top-left, top-right, bottom-right,
        bottom-left of the chart as printed (patch 1 is at the top-left).
    chart
        Chart type.
    image_size
        ``(width, height)`` of the sensor image, to reject a chart partly
        outside it.

    Returns
    -------
    ChartDetection
        Method ``"manual"``, confidence 1.

    Raises
    ------
    ChartDetectionError
        Not four finite points, or not a convex quadrilateral in order.
    ChartOutsideError
        A patch falls beyond ``image_size``.
    ChartLayoutError
        Unknown chart.

    Examples
    --------
    >>> d = chart_from_corners([[0, 0], [167.5, 0], [167.5, 112.5], [0, 112.5]])
    >>> np.round(d.centres[0], 2).tolist()          # 10 px per model unit
    [15.0, 15.0]
    """
    t0 = time.perf_counter()
    layout = chart_layout(chart)
    c = np.asarray(corners, dtype=np.float64)
    if c.shape != (4, 2) or not np.all(np.isfinite(c)):
        raise ChartDetectionError(f"chart corners must be 4 finite (x, y) points, got shape {c.shape}; {_CORNERS_HINT}")
    # a valid quadrilateral: convex, one winding, non-degenerate
    edges = np.roll(c, -1, axis=0) - c
    cross = edges[:, 0] * np.roll(edges, -1, axis=0)[:, 1] - edges[:, 1] * np.roll(edges, -1, axis=0)[:, 0]
    area = 0.5 * abs(np.sum(c[:, 0] * np.roll(c[:, 1], -1) - np.roll(c[:, 0], -1) * c[:, 1]))
    if not (np.all(cross > 0) or np.all(cross < 0)) or area < 16.0:
        raise ChartDetectionError(
            f"chart corners {c.tolist()} do not form a convex quadrilateral (give them in order around the chart: "
            "top-left, top-right, bottom-right, bottom-left)"
        )
    h = _homography(layout.corners, c)
    return _build(chart, h, 1.0, "manual", time.perf_counter() - t0, image_size, None)


# ---------------------------------------------------------------------------------------------- mcc

_MCC_TYPE = {"classic24": "MCC24", "sg140": "SG140", "vinyl18": "VINYL18"}

#: Patch side (pixels of the shrunk image) from which the refinement runs on the shrunk image.
_REFINE_SIDE = 40.0


def _refine(preview: NDArray[np.uint8], h_prev: NDArray[np.float64], layout: ChartLayout
            ) -> tuple[NDArray[np.float64], float]:
    """Refit the model -> preview homography on segmented patch centroids; returns it and the inlier fraction."""
    import cv2

    quads = _apply(h_prev, layout.quads())
    centres = layout.centres()
    found_model, found_image = [], []
    for k in range(layout.size):
        centroid = _patch_centroid(preview, quads[k])
        if centroid is not None:
            found_model.append(centres[k])
            found_image.append(centroid)
    if len(found_model) < 6:
        return h_prev, len(found_model) / layout.size
    src = np.asarray(found_model, np.float64)
    dst = np.asarray(found_image, np.float64)
    pitch = float(np.median(np.linalg.norm(_apply(h_prev, centres[1:2]) - _apply(h_prev, centres[0:1]), axis=1)))
    h_new, inl = cv2.findHomography(src, dst, cv2.RANSAC, max(1.0, 0.05 * pitch))
    if h_new is None:
        return h_prev, len(found_model) / layout.size
    return h_new / h_new[2, 2], float(inl.sum()) / layout.size


def _patch_centroid(preview: NDArray[np.uint8], q: NDArray[np.float64]) -> NDArray[np.float64] | None:
    """Centroid (x, y) of the region of the patch's own colour around the predicted patch ``q``, or None."""
    import cv2

    ph, pw = preview.shape[:2]
    c = q.mean(axis=0)
    area = 0.5 * abs(np.sum(q[:, 0] * np.roll(q[:, 1], -1) - np.roll(q[:, 0], -1) * q[:, 1]))
    side = math.sqrt(area)
    if side < 6:
        return None
    pad = 0.4 * side
    x0, y0 = np.floor(q.min(axis=0) - pad).astype(int)
    x1, y1 = np.ceil(q.max(axis=0) + pad).astype(int) + 1
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, pw), min(y1, ph)
    cx, cy = int(round(c[0])) - x0, int(round(c[1])) - y0
    if not (0 <= cx < x1 - x0 and 0 <= cy < y1 - y0):
        return None
    # Lab per window only: converting a whole 24-megapixel preview would cost more than mcc itself
    win = cv2.cvtColor(np.ascontiguousarray(preview[y0:y1, x0:x1]), cv2.COLOR_RGB2Lab).astype(np.float32)
    r = max(1, int(0.15 * side))
    core = win[max(cy - r, 0):cy + r + 1, max(cx - r, 0):cx + r + 1].reshape(-1, 3)
    ref = np.median(core, axis=0)
    dist = np.linalg.norm(win - ref, axis=2)
    tol = max(10.0, 4.0 * float(np.median(np.linalg.norm(core - ref, axis=1))))
    mask = (dist < tol).astype(np.uint8)
    n, cc, stats, cent = cv2.connectedComponentsWithStats(mask, connectivity=4)
    lbl = cc[cy, cx]
    if lbl == 0:
        return None
    ratio = stats[lbl, cv2.CC_STAT_AREA] / area
    touches = (stats[lbl, cv2.CC_STAT_LEFT] == 0 or stats[lbl, cv2.CC_STAT_TOP] == 0
               or stats[lbl, cv2.CC_STAT_LEFT] + stats[lbl, cv2.CC_STAT_WIDTH] == x1 - x0
               or stats[lbl, cv2.CC_STAT_TOP] + stats[lbl, cv2.CC_STAT_HEIGHT] == y1 - y0)
    if 0.7 < ratio < 1.3 and not touches:    # a patch-sized island: not merged with the frame or a neighbour
        return cent[lbl] + [x0, y0]
    return None


def detect_chart(image: RawImage | NDArray[np.uint8], chart: str = "classic24", *, scale: int = 1,
                 max_side: int = 1600) -> ChartDetection:
    """Find a colour chart with ``cv2.mcc`` and refine its patch positions.

    Parameters
    ----------
    image
        A decoded :class:`~processing.camera.raw_decode.RawImage` (its preview is
        made here) or a display-referred uint8 ``(H, W, 3)`` RGB preview.
    chart
        ``"classic24"``, ``"sg140"`` or ``"vinyl18"``.
    scale
        Sensor photosites per preview pixel when ``image`` is an array
        (2 for a preview of a binned image); ignored for a RawImage.
    max_side
        ``mcc`` runs on the preview shrunk to at most this many pixels.

    Returns
    -------
    ChartDetection
        Method ``"mcc"``; ``confidence`` is the fraction of patches that agree
        with the refined homography.

    Raises
    ------
    ChartNotFoundError
        No chart found.
    ChartOutsideError
        The chart is partly outside the frame.
    ChartDetectionError
        An array that is not a uint8 ``(H, W, 3)`` preview of at least 16 px,
        or a bad ``scale``.

    References
    ----------
    Marrero Fernandez, P. D., Guerrero-Pena, F. A., Ren, T. I., et al.
    (2019). Fast and robust multiple ColorChecker detection using deep
    convolutional neural networks. Image and Vision Computing 81
    (arXiv:1810.08639).

    Hartley, R., Zisserman, A. (2004). Multiple View Geometry in Computer
    Vision, 2nd ed., algorithm 4.6. doi:10.1017/CBO9780511811685
    """
    import cv2

    t0 = time.perf_counter()
    layout = chart_layout(chart)
    preview, scale = _preview_of(image, scale)
    ph, pw = preview.shape[:2]
    shrink = min(1.0, max_side / max(ph, pw))
    small = preview if shrink == 1.0 else cv2.resize(preview, (round(pw * shrink), round(ph * shrink)),
                                                     interpolation=cv2.INTER_AREA)
    best = _best_checker(small, chart, (pw * scale, ph * scale))
    box_small = np.asarray(best.getBox(), dtype=np.float64).reshape(4, 2)
    h_prev, confidence = _refined_homography(preview, small, box_small, layout, shrink)
    to_sensor = np.array([[scale, 0, (scale - 1) / 2.0], [0, scale, (scale - 1) / 2.0], [0, 0, 1]])
    h = to_sensor @ h_prev
    return _build(chart, h / h[2, 2], confidence, "mcc", time.perf_counter() - t0, (pw * scale, ph * scale),
                  float(best.getCost()))


def _preview_of(image: RawImage | NDArray[np.uint8], scale: int) -> tuple[NDArray[np.uint8], int]:
    """The uint8 RGB preview to search and its photosites per pixel (a RawImage's own preview and scale)."""
    if isinstance(image, RawImage):
        preview = preview_srgb8(image)
        scale = image.scale
    else:
        preview = np.asarray(image)
        if preview.ndim != 3 or preview.shape[2] != 3 or preview.dtype != np.uint8 or min(preview.shape[:2]) < 16:
            raise ChartDetectionError(
                f"image must be a RawImage or a uint8 (H, W, 3) RGB preview at least 16 px, got "
                f"{preview.dtype} {preview.shape}"
            )
        if not (isinstance(scale, (int, np.integer)) and scale >= 1):
            raise ChartDetectionError(f"scale must be a whole number of photosites per pixel >= 1, got {scale!r}")
    return preview, scale


def _best_checker(small: NDArray[np.uint8], chart: str, sensor_size: tuple[int, int]):
    """``cv2.mcc``'s lowest-cost chart of type ``chart`` in ``small``; :class:`ChartNotFoundError` if none."""
    import cv2

    det = cv2.mcc.CCheckerDetector_create()
    det.setColorChartType(getattr(cv2.mcc, _MCC_TYPE[chart]))
    found = det.process(np.ascontiguousarray(small[..., ::-1]), 1)
    checkers = det.getListColorChecker() if found else []
    if not checkers:
        raise ChartNotFoundError(
            f"no {chart} chart found in the {sensor_size[0]} x {sensor_size[1]} image; check that the whole chart is in "
            f"view, lit evenly and not over- or under-exposed, and that it is {chart_type_hint(chart)}, or "
            f"{_CORNERS_HINT}"
        )
    return min(checkers, key=lambda ch: ch.getCost())


def _refined_homography(preview: NDArray[np.uint8], small: NDArray[np.uint8], box_small: NDArray[np.float64],
                        layout: ChartLayout, shrink: float) -> tuple[NDArray[np.float64], float]:
    """Model -> preview homography from ``mcc``'s box, refined on the shrunk or the full preview, and its confidence."""
    ph, pw = preview.shape[:2]
    h_small = _homography(layout.corners, box_small)
    # resize maps pixel centres by x_small = (x + 0.5) * f - 0.5, f the rounded size's own ratio per axis
    fx, fy = small.shape[1] / pw, small.shape[0] / ph
    small_to_prev = np.array([[1 / fx, 0, 0.5 / fx - 0.5], [0, 1 / fy, 0.5 / fy - 0.5], [0, 0, 1]])
    quad = _apply(h_small, layout.quads()[0])
    side_small = math.sqrt(0.5 * abs(np.sum(quad[:, 0] * np.roll(quad[:, 1], -1) - np.roll(quad[:, 0], -1) * quad[:, 1])))
    if shrink == 1.0 or side_small >= _REFINE_SIDE:
        # patches big enough in the shrunk image: centroids there are precise and cost far less
        h_small, confidence = _refine(small, h_small, layout)
        h_prev = small_to_prev @ h_small
    else:
        h_prev, confidence = _refine(preview, small_to_prev @ h_small, layout)
    return h_prev, confidence
