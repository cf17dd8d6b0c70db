"""Geometry and reference colours of the colour charts the pipeline knows.

The layouts (``classic24``, ``sg140``, ``vinyl18``) are those of OpenCV's
``mcc`` module, so a chart found by ``cv2.mcc`` and a chart given by its four
outer corners map to the same patch polygons; model units are 1/11 of a patch
(a patch is 2.5 units, gaps and margins 0.25).  The reference colours are
``cv2.mcc``'s own 8-bit sRGB, used only for camera-independent orderings.
docs/colour-pipeline.md, "Chart layouts", tabulates the charts.

References
----------
Marrero Fernandez, P. D., Guerrero-Pena, F. A., Ren, T. I., et al.
(2019). Fast and robust multiple ColorChecker detection using deep
convolutional neural networks. Image and Vision Computing 81 (arXiv:1810.08639).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from processing.errors import InputError

__all__ = ["CHARTS", "chart_type_hint", "ChartLayout", "ChartLayoutError", "chart_layout", "reference_srgb8", "reference_lab"]

#: Names of the charts :func:`chart_layout` knows.
CHARTS = ("classic24", "sg140", "vinyl18")

_CLASSIC_NAMES = (
    "dark skin", "light skin", "blue sky", "foliage", "blue flower", "bluish green",
    "orange", "purplish blue", "moderate red", "purple", "yellow green", "orange yellow",
    "blue", "green", "red", "yellow", "magenta", "cyan",
    "white 9.5", "neutral 8", "neutral 6.5", "neutral 5", "neutral 3.5", "black 2",
)

_VINYL_NAMES = (
    "white", "grey 73", "grey 62", "grey 50", "grey 38", "black",
    "red", "yellow", "green", "cyan", "navy", "magenta",
    "dark red", "orange", "teal", "purple", "light skin", "skin",
)


class ChartLayoutError(InputError):
    """An unknown chart name or bad layout input; the message names the choices."""


@dataclass(frozen=True)
class ChartLayout:
    """A chart's patch grid in model units (x to the right along the long side, y down).

    Parameters
    ----------
    name, rows, cols, width, height, col_edges, row_edges, names, mm_per_unit
        The attributes below, in this order.

    Attributes
    ----------
    name
        ``"classic24"``, ``"sg140"`` or ``"vinyl18"``.
    rows, cols
        Patch grid.
    width, height
        Outer size of the chart's frame (model units).
    col_edges, row_edges
        ``(start, end)`` of each column / row of patches.
    names
        Patch names in reading order (row-major).
    mm_per_unit
        Physical size of one model unit (for simulation).
    """

    name: str
    rows: int
    cols: int
    width: float
    height: float
    col_edges: tuple[tuple[float, float], ...]
    row_edges: tuple[tuple[float, float], ...]
    names: tuple[str, ...]
    mm_per_unit: float = 16.5

    @property
    def size(self) -> int:
        """Number of patches."""
        return self.rows * self.cols

    @property
    def corners(self) -> NDArray[np.float64]:
        """The frame's outer corners ``(4, 2)``: top-left, top-right, bottom-right, bottom-left."""
        return np.array([[0.0, 0.0], [self.width, 0.0], [self.width, self.height], [0.0, self.height]])

    def quads(self) -> NDArray[np.float64]:
        """Patch corners ``(N, 4, 2)`` (TL, TR, BR, BL) in reading order, model units.

        Returns
        -------
        ndarray
            ``(N, 4, 2)`` float64 (x, y) corners, N = :attr:`size`.

        Examples
        --------
        >>> chart_layout("classic24").quads()[0].tolist()
        [[0.25, 0.25], [2.75, 0.25], [2.75, 2.75], [0.25, 2.75]]
        """
        out = np.empty((self.rows, self.cols, 4, 2))
        for r, (y0, y1) in enumerate(self.row_edges):
            for c, (x0, x1) in enumerate(self.col_edges):
                out[r, c] = [[x0, y0], [x1, y0], [x1, y1], [x0, y1]]
        return out.reshape(-1, 4, 2)

    def centres(self) -> NDArray[np.float64]:
        """Patch centres ``(N, 2)`` in model units.

        Returns
        -------
        ndarray
            ``(N, 2)`` float64 (x, y), reading order.
        """
        return self.quads().mean(axis=1)

    def label(self, index: int) -> str:
        """``"patch 19 (white 9.5)"``: the 1-based number printed on charts, and the name.

        Parameters
        ----------
        index
            0-based patch index in reading order.

        Returns
        -------
        str
            The patch as messages name it.
        """
        return f"patch {index + 1} ({self.names[index]})"


def _uniform(n: int) -> tuple[tuple[float, float], ...]:
    """Edges of ``n`` patches of 2.5 units with 0.25-unit gaps and margins."""
    return tuple((0.25 + 2.75 * i, 2.75 + 2.75 * i) for i in range(n))


@functools.cache
def chart_type_hint(name: str) -> str:
    """The chart type named with the other types, for messages that suspect the wrong type was given.

    Parameters
    ----------
    name
        The chart type given (one of :data:`CHARTS`).

    Returns
    -------
    str
        ``"a <name> chart (other types: ...)"``.

    Examples
    --------
    >>> chart_type_hint("sg140")
    'an sg140 chart (other types: classic24, vinyl18)'
    """
    article = "an" if name[:1] in "aeiosx" else "a"
    return f"{article} {name} chart (other types: {', '.join(c for c in CHARTS if c != name)})"


def chart_layout(name: str) -> ChartLayout:
    """The layout of chart ``name`` (one of :data:`CHARTS`).

    Parameters
    ----------
    name
        ``"classic24"`` (X-Rite ColorChecker Classic, 4 x 6), ``"sg140"``
        (ColorChecker Digital SG, 10 x 14) or ``"vinyl18"`` (the 18-patch
        vinyl chart of ``cv2.mcc``).

    Returns
    -------
    ChartLayout
        The patch grid in model units.

    Raises
    ------
    ChartLayoutError
        Unknown chart.

    Examples
    --------
    >>> lay = chart_layout("classic24")
    >>> lay.size, lay.width, lay.height, lay.label(18)
    (24, 16.75, 11.25, 'patch 19 (white 9.5)')
    """
    if name == "classic24":
        return ChartLayout(name, 4, 6, 16.75, 11.25, _uniform(6), _uniform(4), _CLASSIC_NAMES)
    if name == "sg140":
        letters = "ABCDEFGHIJKLMN"
        names = tuple(f"{letters[c]}{r + 1}" for r in range(10) for c in range(14))
        return ChartLayout(name, 10, 14, 38.75, 27.75, _uniform(14), _uniform(10), names, mm_per_unit=8.0)
    if name == "vinyl18":
        cols = tuple((0.25 + 3.0 * i, 3.0 + 3.0 * i) for i in range(6))
        rows = ((0.25, 6.25), (6.5, 9.25), (9.5, 12.25))
        return ChartLayout(name, 3, 6, 18.25, 12.5, cols, rows, _VINYL_NAMES, mm_per_unit=10.0)
    raise ChartLayoutError(f"unknown chart {name!r}; choose one of {', '.join(CHARTS)}")


_MCC_TYPE = {"classic24": "MCC24", "sg140": "SG140", "vinyl18": "VINYL18"}


@functools.cache
def reference_srgb8(name: str) -> NDArray[np.uint8]:
    """``cv2.mcc``'s reference colours of chart ``name``: ``(N, 3)`` 8-bit sRGB (R, G, B), reading order.

    The colours are ``getRefColors`` of ``cv2.mcc``: 8-bit sRGB derived from
    the charts' CIE L*a*b* D50 values.

    Parameters
    ----------
    name
        One of :data:`CHARTS`.

    Returns
    -------
    ndarray
        ``(N, 3)`` read-only uint8.

    Raises
    ------
    ChartLayoutError
        Unknown chart.

    Examples
    --------
    >>> ref = reference_srgb8("classic24")
    >>> ref.shape, bool(ref[18].min() > 230 and ref[23].max() < 70)     # white 9.5 and black 2
    ((24, 3), True)
    """
    import cv2

    chart_layout(name)
    det = cv2.mcc.CCheckerDetector_create()
    det.setColorChartType(getattr(cv2.mcc, _MCC_TYPE[name]))
    bgr = np.asarray(det.getRefColors(), dtype=np.uint8).reshape(-1, 3)
    out = np.ascontiguousarray(bgr[:, ::-1])
    out.setflags(write=False)
    return out


@functools.cache
def reference_lab(name: str) -> NDArray[np.float64]:
    """CIE L*a*b* (D65) of :func:`reference_srgb8`, ``(N, 3)``.

    Parameters
    ----------
    name
        One of :data:`CHARTS`.

    Returns
    -------
    ndarray
        ``(N, 3)`` read-only float64 L*, a*, b* (CIE 1931 2 degree observer,
        D65 white).

    Raises
    ------
    ChartLayoutError
        Unknown chart.

    References
    ----------
    CIE 015:2018 Colorimetry, 4th edition. doi:10.25039/TR.015.2018

    Examples
    --------
    >>> lab = reference_lab("classic24")
    >>> bool(lab[18, 0] > 90 and abs(lab[18, 1]) < 3)
    True
    """
    import colour

    rgb = reference_srgb8(name).astype(np.float64) / 255.0
    xyz = colour.sRGB_to_XYZ(rgb)
    out = np.asarray(colour.XYZ_to_Lab(xyz, colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]))
    out.setflags(write=False)
    return out
