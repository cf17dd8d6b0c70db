"""How long the GUI thread's event loop is kept from running: the largest delay of a short periodic timer.

A :class:`QTimer` of ``interval_ms`` fires on the GUI thread; whatever keeps
the event loop busy (a slow slot, a long redraw, the interpreter lock held
by another thread, the operating system running other processes) delays the
next firing.  The *stall* of one firing is the wall-clock time since the
previous one minus the interval.  The GUI thread's own CPU time between two
firings (:func:`time.thread_time`) is recorded too: it is the part of a
stall that the window's own work caused, whatever else runs on the machine,
so "the event loop is never blocked more than 100 ms by the window's work"
(issue #7) is testable on a busy machine, while the wall-clock stalls (their
99th percentile and maximum) are what a technician feels and are reported
by ``bench/gui_bench.py``.

Examples
--------
>>> stalls_ms([0.0, 0.010, 0.020, 0.150, 0.160], 10)
[0.0, 0.0, 120.0, 0.0]
"""

from __future__ import annotations

import time

import numpy as np
from PySide6.QtCore import QObject, QTimer

__all__ = ["EventLoopMonitor", "stalls_ms"]


def stalls_ms(stamps_s: list[float], interval_ms: float) -> list[float]:
    """Stall of each firing (ms, >= 0) from the firing times (s)."""
    d = np.diff(np.asarray(stamps_s, float)) * 1000.0 - interval_ms
    return [float(round(x, 6)) + 0.0 for x in np.maximum(d, 0.0)]


class EventLoopMonitor(QObject):
    """Record the firing times of a periodic timer (start / stop around the work to watch)."""

    def __init__(self, interval_ms: int = 10, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self.interval_ms = interval_ms
        self.stamps: list[float] = []
        self.cpu: list[float] = []
        self._timer = QTimer(self)
        self._timer.setInterval(interval_ms)
        self._timer.timeout.connect(self._fired)

    def _fired(self) -> None:
        self.stamps.append(time.perf_counter())
        self.cpu.append(time.thread_time())

    def start(self) -> None:
        self.stamps = [time.perf_counter()]
        self.cpu = [time.thread_time()]
        self._timer.start()

    def stop(self) -> None:
        self._timer.stop()

    def stalls(self) -> list[float]:
        return stalls_ms(self.stamps, self.interval_ms)

    def busy_ms(self) -> list[float]:
        """CPU time of the GUI thread between consecutive firings (ms)."""
        return [float(x) for x in np.diff(np.asarray(self.cpu, float)) * 1000.0]

    def summary(self) -> dict[str, float]:
        """Stalls (``max_ms``, ``p99_ms``, ``median_ms``), the GUI thread's ``busy_max_ms``, ``seconds`` watched."""
        s = np.asarray(self.stalls()) if len(self.stamps) > 1 else np.zeros(1)
        b = np.asarray(self.busy_ms()) if len(self.cpu) > 1 else np.zeros(1)
        return {"max_ms": float(s.max()), "p99_ms": float(np.percentile(s, 99)), "median_ms": float(np.median(s)),
                "busy_max_ms": float(b.max()), "firings": len(self.stamps),
                "seconds": self.stamps[-1] - self.stamps[0] if self.stamps else 0.0}
