"""A colour chart lying on the booth's backdrop, seen in perspective: radiance and ground-truth labels.

The chart is a flat card: a matte black frame (reflectance
:data:`FRAME_REFLECTANCE`) holding square patches with gaps, laid out as in
:mod:`processing.camera.chart_layout` (ColorChecker Classic: 16.75 x 11.25 model
units, about 276 x 186 mm).  Its placement is a pinhole view of the card
(Hartley & Zisserman, *Multiple View Geometry*, 2nd ed., section 8.1: a plane
maps to the image by a homography): the card is tilted about its horizontal
and vertical axes by ``tilt_deg``, seen from ``VIEW_DISTANCE`` card widths,
turned in the image by ``rotation_deg``, scaled so its long side spans
``size`` of the image width and centred at ``center`` (fractions of the
image).  Pixel ``(x, y)`` has its centre at coordinate ``(x, y)`` (OpenCV's
convention); a pixel takes the patch its centre falls in, so labels are exact
for the ground truth of detection tests.

Reflectances: the ColorChecker Classic uses colour-science's measured
spectra (``SDS_COLOURCHECKERS``).  The Digital SG and the vinyl chart have no
published spectra in colour-science; their patches get spectra recovered from
``cv2.mcc``'s reference colours by Otsu et al. (2018), "Reproducing spectral
reflectances from tristimulus colours" (``colour.XYZ_to_sd(...,
method="Otsu 2018")``), clipped to [0.005, 1] -- plausible smooth spectra with
the right colours under D65, not measurements.

Faults: a chart partly outside the frame is a placement whose ``center`` and
``size`` put part of the card beyond the image (:func:`outside_placement`;
the station's ``world.chart_outside`` switch); an over-exposed chart is
:func:`mocks.camera_sim.simulate_raw` with ``exposure_boost > 1`` (the
station's ``camera.saturate`` switch).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from processing.camera.chart_layout import ChartLayout, chart_layout, reference_srgb8
from processing.errors import InputError
from processing.spectral.spectra import SpectralGrid, resample

__all__ = [
    "FRAME_REFLECTANCE",
    "VIEW_DISTANCE",
    "ChartPlacement",
    "ChartSceneError",
    "chart_corners",
    "chart_homography",
    "chart_patch_reflectances",
    "outside_placement",
    "render_chart",
]

#: Reflectance of the chart's black frame (matte black card).
FRAME_REFLECTANCE = 0.03

#: Viewing distance in card widths (sets the strength of the perspective of a tilted card).
VIEW_DISTANCE = 2.5


class ChartSceneError(InputError):
    """A chart placement or layout input is not valid; the message names it."""


@dataclass(frozen=True)
class ChartPlacement:
    """Where the chart lies in the image.

    Attributes
    ----------
    center
        Centre of the card as fractions of the image width and height.
    size
        Long side of the (untilted) card as a fraction of the image width.
    rotation_deg
        Turn in the image plane (counter-clockwise as seen, y down).
    tilt_deg
        Tilt of the card about its horizontal and vertical axes (perspective).
    """

    center: tuple[float, float] = (0.5, 0.5)
    size: float = 0.7
    rotation_deg: float = 0.0
    tilt_deg: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        # lists from JSON become tuples, so placements compare and hash by value
        for name in ("center", "tilt_deg"):
            value = getattr(self, name)
            if isinstance(value, (list, np.ndarray)):
                object.__setattr__(self, name, tuple(float(v) for v in value))
        c = np.asarray(self.center, dtype=np.float64)
        t = np.asarray(self.tilt_deg, dtype=np.float64)
        if c.shape != (2,) or not np.all(np.isfinite(c)):
            raise ChartSceneError(f"chart center must be two finite fractions (x, y), got {self.center!r}")
        if not (math.isfinite(self.size) and 0 < self.size <= 4):
            raise ChartSceneError(f"chart size must be in (0, 4] image widths, got {self.size!r}")
        if not math.isfinite(self.rotation_deg):
            raise ChartSceneError(f"chart rotation_deg must be finite, got {self.rotation_deg!r}")
        if t.shape != (2,) or not np.all(np.abs(t) < 70):
            raise ChartSceneError(f"chart tilt_deg must be two angles within +-70 degrees, got {self.tilt_deg!r}")


def outside_placement(placement: ChartPlacement) -> ChartPlacement:
    """The "chart partly outside the frame" fault: the card moved right until a third of it is past the edge.

    Examples
    --------
    >>> outside_placement(ChartPlacement(size=0.6)).center
    (0.8, 0.5)
    """
    return ChartPlacement((1.0 - placement.size / 3.0, placement.center[1]), placement.size,
                          placement.rotation_deg, placement.tilt_deg)


def chart_corners(layout: ChartLayout, width: int, height: int, placement: ChartPlacement) -> NDArray[np.float64]:
    """Image positions ``(4, 2)`` of the card's outer corners (TL, TR, BR, BL of the chart's own frame).

    Examples
    --------
    >>> lay = chart_layout("classic24")
    >>> c = chart_corners(lay, 200, 100, ChartPlacement(size=0.5))
    >>> np.round(c[0], 2).tolist(), np.round(c[2] - c[0], 2).tolist()
    ([49.5, 15.92], [100.0, 67.16])
    """
    half = np.array([layout.width, layout.height]) / (2 * layout.width)       # card width 1
    card = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=np.float64) * half
    pts = np.column_stack([card, np.zeros(4)])
    ax, ay = (math.radians(v) for v in placement.tilt_deg)
    rx = np.array([[1, 0, 0], [0, math.cos(ax), -math.sin(ax)], [0, math.sin(ax), math.cos(ax)]])
    ry = np.array([[math.cos(ay), 0, math.sin(ay)], [0, 1, 0], [-math.sin(ay), 0, math.cos(ay)]])
    pts = pts @ (ry @ rx).T
    d = VIEW_DISTANCE
    proj = pts[:, :2] * (d / (d + pts[:, 2:3]))
    a = math.radians(placement.rotation_deg)
    rot = np.array([[math.cos(a), math.sin(a)], [-math.sin(a), math.cos(a)]])     # counter-clockwise with y down
    proj = proj @ rot.T
    scale = placement.size * width
    centre = np.array([placement.center[0] * width, placement.center[1] * height]) - 0.5
    return proj * scale + centre


def chart_homography(layout: ChartLayout, corners: NDArray[np.float64]) -> NDArray[np.float64]:
    """3 x 3 homography from model units to image pixels through the four outer corners."""
    import cv2

    return cv2.getPerspectiveTransform(layout.corners.astype(np.float32), np.asarray(corners, np.float32)).astype(
        np.float64)


@functools.lru_cache(maxsize=16)
def _reflectances_cached(name: str, start: float, stop: float, step: float) -> NDArray[np.float64]:
    import colour

    grid = SpectralGrid(start, stop, step)
    if name == "classic24":
        sds = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
        out = np.stack([resample(sd.wavelengths, sd.values, grid) for sd in sds.values()])
    else:
        xyz = colour.sRGB_to_XYZ(reference_srgb8(name).astype(np.float64) / 255.0)
        rows = []
        with colour.utilities.suppress_warnings(colour_runtime_warnings=True):   # its shape/interpolation notices
            for v in xyz:
                sd = colour.XYZ_to_sd(np.maximum(v, 1e-4), method="Otsu 2018")
                rows.append(resample(sd.wavelengths, sd.values, grid))
        out = np.clip(np.stack(rows), 0.005, 1.0)
    out.setflags(write=False)
    return out


def chart_patch_reflectances(name: str, grid: SpectralGrid) -> NDArray[np.float64]:
    """Reflectances ``(N, L)`` of chart ``name``'s patches in reading order.

    Examples
    --------
    >>> r = chart_patch_reflectances("vinyl18", SpectralGrid(400, 700, 20))
    >>> r.shape, bool(r[0].mean() > 0.8 and r[5].mean() < 0.05)       # white and black
    ((18, 16), True)
    """
    return _reflectances_cached(name, grid.start, grid.stop, grid.step)


def render_chart(
    name: str,
    width: int,
    height: int,
    placement: ChartPlacement,
    grid: SpectralGrid,
    light: NDArray[np.float64],
    backdrop_reflectance: float,
    reflectances: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.int16], NDArray[np.float64]]:
    """Spectral radiance ``(H, W, L)``, labels ``(H, W)`` and outer corners ``(4, 2)`` of a chart frame.

    Lambertian at normal incidence: ``L = R(lambda) E(lambda) / pi`` for the
    patches, the frame and the backdrop.  Labels: patch index, -1 elsewhere.
    ``reflectances`` ``(N, L)`` replaces :func:`chart_patch_reflectances`.

    Examples
    --------
    >>> g = SpectralGrid(400, 700, 20)
    >>> rad, lab, corners = render_chart("classic24", 120, 80, ChartPlacement(), g, np.ones(g.size), 0.05)
    >>> rad.shape, sorted(set(np.unique(lab).tolist()))[:3]
    ((80, 120, 16), [-1, 0, 1])
    """
    layout = chart_layout(name)
    corners = chart_corners(layout, width, height, placement)
    h_img = chart_homography(layout, corners)
    inv = np.linalg.inv(h_img)
    ys, xs = np.mgrid[0:height, 0:width]
    x, y = xs.ravel().astype(np.float64), ys.ravel().astype(np.float64)
    den = inv[2, 0] * x + inv[2, 1] * y + inv[2, 2]
    u = (inv[0, 0] * x + inv[0, 1] * y + inv[0, 2]) / den
    v = (inv[1, 0] * x + inv[1, 1] * y + inv[1, 2]) / den
    in_card = (den > 0) & (u >= 0) & (u < layout.width) & (v >= 0) & (v < layout.height)
    col = np.full(u.shape, -1)
    row = np.full(u.shape, -1)
    for c, (x0, x1) in enumerate(layout.col_edges):
        col[(u >= x0) & (u < x1)] = c
    for r, (y0, y1) in enumerate(layout.row_edges):
        row[(v >= y0) & (v < y1)] = r
    on_patch = in_card & (col >= 0) & (row >= 0)
    labels = np.full(u.shape, -1, dtype=np.int16)
    labels[on_patch] = (row * layout.cols + col)[on_patch]
    refl = chart_patch_reflectances(name, grid) if reflectances is None else np.asarray(reflectances, np.float64)
    if refl.shape != (layout.size, grid.size):
        raise ChartSceneError(f"reflectances must be ({layout.size}, {grid.size}) for {name}, got {refl.shape}")
    table = np.vstack([refl, np.full((1, grid.size), FRAME_REFLECTANCE), np.full((1, grid.size), backdrop_reflectance)])
    index = np.where(on_patch, labels, np.where(in_card, layout.size, layout.size + 1))
    radiance = table[index.reshape(height, width)] * (np.asarray(light, dtype=np.float64) / math.pi)
    return radiance, labels.reshape(height, width), corners
