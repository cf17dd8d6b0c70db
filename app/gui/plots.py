"""Plots for the window: figures drawn in a separate process, shown as bitmaps that can be clicked.

Drawing a Matplotlib figure takes 60-170 ms on a busy two-core machine
(measured: a 320-point line plot, a 60 x 320 image with a colour bar, a
3-D scatter), and Matplotlib holds the interpreter lock while it lays out
and rasterises -- so drawing on a thread of the window's process still kept
the event loop waiting past 100 ms (docs/BENCHMARKS.md, "gui").
:class:`FigureDrawer` therefore draws in one long-lived worker process
(``multiprocessing`` spawn context, a :func:`multiprocessing.Pipe`): a
figure is a module-level builder of :mod:`app.gui.figures` and its plain
data, pickled on a drawing thread of the window, drawn with Agg in the
worker, and returned as an RGBA bitmap.  The window's thread only waits on
the pipe, which releases the lock.  :class:`PlotImage` shows the bitmaps;
requests made while a drawing runs are coalesced into the latest one.
:class:`PlotImage` also maps a click on the bitmap back to data
coordinates, which is how the manual registration dialog picks points.

A drawing process that dies (killed, out of memory) fails only the figure
it was drawing, with a readable message; the next figure starts a new one.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import threading
import traceback
from collections.abc import Callable
from typing import Any

import numpy as np
from PySide6.QtCore import QSize, Qt, QTimer, Signal
from PySide6.QtGui import QImage, QPixmap
from PySide6.QtWidgets import QLabel, QSizePolicy, QWidget

from app.gui.figures import axes_pixel, empty_figure, render_figure
from app.gui.workers import JobContext, Lane, WindowClosing, serve_requests

__all__ = ["FigureDrawer", "PlotImage"]

_LOG = logging.getLogger("kogei.gui")

#: Smallest size (w, h) in pixels a figure is drawn at; a smaller widget shows it scaled down.
MIN_DRAW_SIZE = (320, 240)


def _serve(conn: Any) -> None:
    """The drawing process: lay out text once, then draw each ``(build, data, w, h)`` received until ``None``."""
    render_figure(empty_figure, {"title": "warm-up: 0.0 (mm) °", "hint": "x"}, 64, 64)
    serve_requests(conn.recv, lambda request: _draw(conn, *request))


def _draw(conn: Any, build: Any, data: Any, w: int, h: int) -> bool:
    """Draw one figure and send it (or the failure) back; False when the window has gone."""
    try:
        reply = ("drawn", *render_figure(build, data, w, h))
    except BaseException as exc:  # noqa: BLE001 - reported to the window as a failed plot
        reply = ("failed", f"{type(exc).__name__}: {exc}", traceback.format_exc())
    try:
        conn.send(reply)
    except (EOFError, OSError):
        return False
    return True


class FigureDrawer:
    """Draw figures in a worker process, one at a time, from a drawing thread of the window.

    Parameters
    ----------
    timeout_s
        A drawing that takes longer is abandoned: the process is stopped and
        the figure fails with a message (the next one starts a new process).

    :meth:`submit` queues a drawing on the drawer's :class:`Lane`;
    :meth:`draw` is the blocking call the lane runs (usable directly from
    any thread but the GUI's).  :meth:`start` starts the process ahead of
    the first figure; :meth:`shutdown` stops it.
    """

    def __init__(self, timeout_s: float = 60.0) -> None:
        self.lane = Lane(1)
        self.timeout_s = float(timeout_s)
        self._lock = threading.Lock()
        self._proc: Any = None
        self._conn: Any = None
        self._closed = False
        self.processes_started = 0

    @property
    def pid(self) -> int | None:
        """The drawing process's id while it runs."""
        return self._proc.pid if self._proc is not None and self._proc.is_alive() else None

    def start(self) -> None:
        """Start the drawing process now, off the GUI thread (it takes a second or two to import Matplotlib)."""
        self.lane.run(lambda ctx: self._ensure_locked(), "start the drawing process",
                      failed=lambda text, exc: _LOG.error("drawing process: %s", text))

    def _ensure_locked(self) -> None:
        with self._lock:
            if not self._closed:
                self._ensure()

    def _ensure(self) -> None:
        if self._proc is not None and self._proc.is_alive():
            return
        self._stop()
        ctx = mp.get_context("spawn")          # never fork a process that runs Qt threads
        parent, child = ctx.Pipe()
        proc = ctx.Process(target=_serve, args=(child,), daemon=True, name="kogei-figures")
        proc.start()
        child.close()
        self._proc, self._conn = proc, parent
        self.processes_started += 1

    def _stop(self) -> None:
        proc, conn, self._proc, self._conn = self._proc, self._conn, None, None
        if conn is not None:
            try:
                conn.send(None)
            except (OSError, ValueError):
                pass
            conn.close()
        if proc is not None:
            proc.join(2.0)
            if proc.is_alive():
                proc.kill()
                proc.join(2.0)

    def draw(self, build: Callable[..., Any], data: dict[str, Any], width_px: int, height_px: int) -> np.ndarray:
        """``build(fig, **data)`` drawn in the worker process at ``width_px`` x ``height_px``; RGBA uint8.

        ``build`` must be a module-level function and ``data`` picklable.
        Raises :class:`RuntimeError` with a readable message when the
        drawing fails, times out or the process dies.
        """
        return self.draw_with_axes(build, data, width_px, height_px)[0]

    def draw_with_axes(self, build: Callable[..., Any], data: dict[str, Any], width_px: int,
                       height_px: int) -> tuple[np.ndarray, list[dict[str, Any]]]:
        """As :meth:`draw`, with where each axes landed (:func:`app.gui.figures.render_figure`)."""
        with self._lock:
            if self._closed:
                raise WindowClosing("the window is closing; the figure was not drawn")
            self._ensure()
            conn, proc = self._conn, self._proc
            try:
                conn.send((build, data, int(width_px), int(height_px)))
                if not conn.poll(self.timeout_s):
                    self._stop()
                    raise RuntimeError(f"drawing the figure took over {self.timeout_s:.0f} s and was abandoned")
                reply = conn.recv()
            except (EOFError, OSError) as exc:
                if proc is not None:
                    proc.join(2.0)             # reap it, so that its exit code is known
                code = proc.exitcode if proc is not None else None
                self._stop()
                raise RuntimeError(f"the figure-drawing process stopped (exit code {code}: {exc or 'no reply'}); "
                                   "the next figure starts a new one") from exc
        if reply[0] == "failed":
            _LOG.error("drawing a figure failed in the drawing process:\n%s", reply[2])
            raise RuntimeError(f"drawing the figure failed: {reply[1]}")
        return reply[1], reply[2]

    def submit(self, build: Callable[..., Any], data: dict[str, Any], width_px: int, height_px: int, **receivers: Any):
        """Queue :meth:`draw_with_axes` on the drawer's lane; ``receivers`` as for :meth:`Lane.run`."""
        def work(ctx: JobContext) -> tuple[np.ndarray, list[dict[str, Any]]]:
            return self.draw_with_axes(build, data, width_px, height_px)

        return self.lane.run(work, "plot", **receivers)

    def shutdown(self, timeout_ms: int = 30_000) -> None:
        """Let queued drawings finish, then stop the process."""
        self.lane.wait(timeout_ms)
        with self._lock:
            self._closed = True
            self._stop()


class PlotImage(QLabel):
    """A figure drawn by a :class:`FigureDrawer` (see the module docstring).

    ``plot(build, **data)`` asks for a new drawing of ``build(fig, **data)``
    (a module-level builder of :mod:`app.gui.figures` and plain data);
    ``drawn`` is emitted after each drawing is shown.  A click on an axes
    that has a gid emits ``clicked(gid, x, y)`` in that axes' data
    coordinates (linear axes), so a bitmap can still be picked on.

    A figure is drawn at the widget's size (at least :data:`MIN_DRAW_SIZE`).
    When the widget changes size -- in width or height, by any amount: an
    error line appearing, a splitter moved, a smaller window -- the bitmap
    shown is scaled to fit at once (never cropped), and the figure is
    redrawn at the new size once the size has stayed put for
    :attr:`RESIZE_DEBOUNCE_MS` (a dragged splitter redraws once, not per
    pixel).  A widget smaller than :data:`MIN_DRAW_SIZE` shows the drawing
    scaled down, so titles and labels stay whole.
    """

    #: Quiet time after the last size change before the figure is redrawn at the new size (ms).
    RESIZE_DEBOUNCE_MS = 150

    drawn = Signal()
    clicked = Signal(str, float, float)

    def __init__(self, drawer: FigureDrawer, parent: QWidget | None = None,
                 min_size: tuple[int, int] = (260, 200)) -> None:
        super().__init__(parent)
        self.drawer = drawer
        self.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Ignored)
        self.setMinimumSize(*min_size)
        self.setStyleSheet("background:white; color:#777;")      # the colour of a placeholder's text
        self.setWordWrap(True)
        self._waiting: tuple[Callable[..., Any], dict[str, Any]] | None = None
        self._busy = False
        self._last: tuple[Callable[..., Any], dict[str, Any]] | None = None
        self.rgba: np.ndarray | None = None
        self.axes: list[dict[str, Any]] = []
        self.draws = 0
        self.failure = ""
        self.scale = 1.0                   # bitmap pixels -> widget pixels of the bitmap shown
        self._resize_timer = QTimer(self)
        self._resize_timer.setSingleShot(True)
        self._resize_timer.setInterval(self.RESIZE_DEBOUNCE_MS)
        self._resize_timer.timeout.connect(self._redraw_for_size)

    def draw_size(self) -> tuple[int, int]:
        """The size (w, h) in pixels a figure is drawn at for the widget's current size."""
        return max(self.width(), MIN_DRAW_SIZE[0]), max(self.height(), MIN_DRAW_SIZE[1])

    def plot(self, build: Callable[..., Any], **data: Any) -> None:
        """Draw ``build(fig, **data)`` next (replacing any drawing still waiting).

        An empty plot's ``title`` and ``hint`` show as text at once, until its drawing arrives from the
        drawing process (which may still be starting): a pane is never blank.
        """
        self._waiting = self._last = (build, data)
        if self.rgba is None and isinstance(data.get("hint"), str):
            title = str(data.get("title") or "")
            self.setText(f"{title}\n\n{data['hint']}" if title else data["hint"])
        self._next()

    @property
    def busy(self) -> bool:
        return self._busy or self._waiting is not None

    def _next(self) -> None:
        if self._busy or self._waiting is None:
            return
        (build, data), self._waiting = self._waiting, None
        self._busy = True
        w, h = self.draw_size()
        self.drawer.submit(build, data, w, h, succeeded=self._show, failed=self._failed, finished=self._done)

    def _show(self, drawing: tuple[np.ndarray, list[dict[str, Any]]]) -> None:
        rgba, self.axes = drawing
        self.rgba = rgba
        self.failure = ""
        h, w = rgba.shape[:2]
        self._image = QImage(rgba.data, w, h, 4 * w, QImage.Format.Format_RGBA8888).copy()
        self._fit()
        self.draws += 1
        self.drawn.emit()
        if (w, h) != self.draw_size() and not self._resize_timer.isActive():
            self._resize_timer.start()          # the widget changed size while this one was drawn

    def _fit(self) -> None:
        """Show the last bitmap scaled to fit the widget, aspect kept (never cropped)."""
        if self.rgba is None:
            return
        h, w = self.rgba.shape[:2]
        self.scale = min(self.width() / w, self.height() / h) if self.width() > 0 and self.height() > 0 else 1.0
        pix = QPixmap.fromImage(self._image)
        if abs(self.scale - 1.0) > 1e-6:
            pix = pix.scaled(QSize(max(1, round(w * self.scale)), max(1, round(h * self.scale))),
                             Qt.AspectRatioMode.KeepAspectRatio, Qt.TransformationMode.SmoothTransformation)
        self.setPixmap(pix)

    def _redraw_for_size(self) -> None:
        if self._last is None or self.rgba is None:
            return
        if tuple(self.rgba.shape[1::-1]) != self.draw_size():
            self.plot(self._last[0], **self._last[1])

    def _failed(self, text: str, exc: Any) -> None:
        self.failure = text
        self.setText(f"plot failed: {text}")

    def _done(self) -> None:
        self._busy = False
        self._next()

    # ------------------------------------------------------------ clicks
    def _origin(self) -> tuple[float, float]:
        """Widget position of the bitmap's top-left corner (it is shown centred, scaled by :attr:`scale`)."""
        h, w = self.rgba.shape[:2]
        return (self.width() - w * self.scale) / 2.0, (self.height() - h * self.scale) / 2.0

    def axes_named(self, gid: str) -> dict[str, Any]:
        for ax in self.axes:
            if ax["gid"] == gid:
                return ax
        raise KeyError(f"the drawing has no axes {gid!r}")

    def widget_point(self, gid: str, x: float, y: float) -> tuple[float, float]:
        """Where data ``(x, y)`` of axes ``gid`` is shown, in widget pixels."""
        ox, oy = self._origin()
        px, py = axes_pixel(self.axes_named(gid), x, y)
        return ox + px * self.scale, oy + py * self.scale

    def data_per_pixel(self, gid: str) -> float:
        """Data units per widget pixel along x of axes ``gid`` (as the bitmap is shown, scaled)."""
        ax = self.axes_named(gid)
        return abs(ax["xlim"][1] - ax["xlim"][0]) / max(ax["bbox"][2] - ax["bbox"][0], 1e-9) / self.scale

    def mousePressEvent(self, e: Any) -> None:  # noqa: N802 - Qt's name
        super().mousePressEvent(e)
        if self.rgba is None:
            return                       # (the axes are those of the bitmap shown, even while the next one draws)
        ox, oy = self._origin()
        px, py = (e.position().x() - ox) / self.scale, (e.position().y() - oy) / self.scale
        for ax in self.axes:
            x0, y0, x1, y1 = ax["bbox"]
            if ax["gid"] and x0 <= px <= x1 and y0 <= py <= y1:
                self.clicked.emit(str(ax["gid"]), *axes_pixel(ax, px, py, inverse=True))
                return

    def resizeEvent(self, e: Any) -> None:  # noqa: N802 - Qt's name
        super().resizeEvent(e)
        self._fit()
        if self._last is not None:
            self._resize_timer.start()
