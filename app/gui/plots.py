"""Plots for the window: figures drawn off the GUI thread, and an interactive canvas for picking.

Drawing a Matplotlib figure takes 60-170 ms on a busy two-core machine
(measured: a 320-point line plot, a 60 x 320 image with a colour bar), more
than the 100 ms the event loop may be held.  :class:`PlotImage` therefore
draws each figure on a worker thread with the Agg canvas
(``matplotlib.backends.backend_agg``; a separate :class:`Figure` per draw,
never pyplot, so no state is shared between threads) and shows the finished
bitmap; requests made while a draw runs are coalesced into the latest one.
:class:`PlotCanvas` (Matplotlib's Qt canvas, ``FigureCanvasQTAgg``) is kept
for the interactive picking dialog, where the technician waits for the plot.
"""

from __future__ import annotations

from typing import Any, Callable

# The canvases are used directly (never pyplot), so the process-wide Matplotlib backend is left alone.
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.backends.backend_qtagg import FigureCanvasQTAgg
from matplotlib.figure import Figure
from PySide6.QtCore import Qt, Signal
from PySide6.QtGui import QImage, QPixmap
from PySide6.QtWidgets import QLabel, QSizePolicy, QWidget

from app.gui.workers import JobContext, Lane

__all__ = ["PlotCanvas", "PlotImage", "style", "draw_figure"]


def style(ax: Any, title: str = "", xlabel: str = "", ylabel: str = "") -> None:
    """Title and labels at sizes that stay readable in a small panel."""
    if title:
        ax.set_title(title, fontsize=10)
    if xlabel:
        ax.set_xlabel(xlabel, fontsize=9)
    if ylabel:
        ax.set_ylabel(ylabel, fontsize=9)
    ax.tick_params(labelsize=8)


def draw_figure(build: Callable[[Figure], Any], width_px: int, height_px: int, dpi: int = 100) -> np.ndarray:
    """``build(fig)`` on a new figure of the given size, drawn with Agg; returns ``(H, W, 4)`` uint8 RGBA."""
    fig = Figure(figsize=(max(width_px, 50) / dpi, max(height_px, 50) / dpi), dpi=dpi, layout="constrained")
    canvas = FigureCanvasAgg(fig)
    build(fig)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba()).copy()


class PlotImage(QLabel):
    """A figure drawn off the GUI thread (see the module docstring).

    ``plot(build)`` asks for a new drawing; ``build(fig)`` runs on the
    worker thread and must only use its arguments and immutable data.
    ``drawn`` is emitted after each drawing is shown.
    """

    drawn = Signal()

    def __init__(self, lane: Lane, parent: QWidget | None = None, min_size: tuple[int, int] = (260, 200)) -> None:
        super().__init__(parent)
        self.lane = lane
        self.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Ignored)
        self.setMinimumSize(*min_size)
        self.setStyleSheet("background:white;")
        self._waiting: Callable[[Figure], Any] | None = None
        self._busy = False
        self._last: Callable[[Figure], Any] | None = None
        self.rgba: np.ndarray | None = None
        self.draws = 0
        self.failure = ""

    def plot(self, build: Callable[[Figure], Any]) -> None:
        self._waiting = build
        self._last = build
        self._next()

    @property
    def busy(self) -> bool:
        return self._busy or self._waiting is not None

    def _next(self) -> None:
        if self._busy or self._waiting is None:
            return
        build, self._waiting = self._waiting, None
        self._busy = True
        w, h = max(self.width(), 320), max(self.height(), 240)

        def work(ctx: JobContext) -> np.ndarray:
            return draw_figure(build, w, h)

        self.lane.run(work, "plot", succeeded=self._show, failed=self._failed, finished=self._done)

    def _show(self, rgba: np.ndarray) -> None:
        self.rgba = rgba
        h, w = rgba.shape[:2]
        img = QImage(rgba.data, w, h, 4 * w, QImage.Format.Format_RGBA8888).copy()
        self.setPixmap(QPixmap.fromImage(img))
        self.draws += 1
        self.drawn.emit()

    def _failed(self, text: str, exc: Any) -> None:
        self.failure = text
        self.setText(f"plot failed: {text}")

    def _done(self) -> None:
        self._busy = False
        self._next()

    def resizeEvent(self, e: Any) -> None:  # noqa: N802 - Qt's name
        super().resizeEvent(e)
        if self._last is not None and self.rgba is not None and abs(self.rgba.shape[1] - self.width()) > 40:
            self.plot(self._last)


class PlotCanvas(FigureCanvasQTAgg):
    """An interactive figure in the window (drawn on the GUI thread)."""

    def __init__(self, parent: QWidget | None = None, width: float = 5.0, height: float = 3.5) -> None:
        self.figure = Figure(figsize=(width, height), dpi=100, layout="constrained")
        super().__init__(self.figure)
        if parent is not None:
            self.setParent(parent)
        self.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Expanding)
        self.setMinimumSize(240, 180)

    def redraw(self) -> None:
        """Draw at the next event-loop turn."""
        self.draw_idle()

    style = staticmethod(style)
