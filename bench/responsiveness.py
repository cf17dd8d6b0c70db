"""How long the GUI thread's event loop is kept from running: the largest delay of a short periodic timer.

A :class:`QTimer` of ``interval_ms`` fires on the GUI thread; whatever keeps
the event loop busy (a slow slot, a long redraw, the interpreter lock held
by another thread, the operating system running other processes) delays the
next firing.  The *stall* of one firing is the wall-clock time since the
previous one minus the interval.  Two parts of a stall are told apart:

* the GUI thread's own CPU time between two firings (:func:`time.thread_time`,
  ``busy``): the window's own work;
* the time the machine did not run the process (``excused``): the run-queue
  wait of the GUI thread (runnable, no CPU free) plus the longest run-queue
  wait of any other thread of the process over the same interval (a thread
  that holds the interpreter lock and waits for a CPU keeps the GUI thread
  waiting as long), plus the hypervisor's steal time per CPU.  Linux reports
  the run-queue waits per thread in ``/proc/self/task/TID/schedstat`` (second
  field, ns; kernel documentation "sched-stats") and steal in ``/proc/stat``.

The *own stall* is the stall minus the excused time (never below zero): the
time the event loop waited while the machine was running this process, that
is for the window's work or for another thread of the window holding the
interpreter lock.  The window's requirement "event loop never blocked > 100 ms"
is asserted on it in the tests; the plain wall-clock stalls (99th percentile, maximum)
are what a technician feels on a loaded machine and are reported by
``bench/gui_bench.py``.  Without ``schedstat`` (not Linux) nothing is
excused and the own stall equals the stall.

Examples
--------
>>> stalls_ms([0.0, 0.010, 0.020, 0.150, 0.160], 10)
[0.0, 0.0, 120.0, 0.0]
>>> own_stalls_ms([0.0, 120.0, 40.0], [0.0, 90.0, 50.0])
[0.0, 30.0, 0.0]
"""

from __future__ import annotations

import os
import threading
import time

import numpy as np
from PySide6.QtCore import QObject, QTimer

__all__ = ["EventLoopMonitor", "stalls_ms", "own_stalls_ms", "run_queue_waits_ns", "steal_ns"]

_TASKS = "/proc/self/task"


def stalls_ms(stamps_s: list[float], interval_ms: float) -> list[float]:
    """Stall of each firing (ms, >= 0) from the firing times (s)."""
    d = np.diff(np.asarray(stamps_s, float)) * 1000.0 - interval_ms
    return [float(round(x, 6)) + 0.0 for x in np.maximum(d, 0.0)]


def own_stalls_ms(stalls: list[float], excused: list[float]) -> list[float]:
    """Each stall minus the time the machine did not run the process (ms, >= 0)."""
    s, e = np.asarray(stalls, float), np.asarray(excused, float)
    if s.shape != e.shape:
        raise ValueError(f"stalls ({s.shape}) and excused times ({e.shape}) must have one value per firing")
    return [float(round(x, 6)) + 0.0 for x in np.maximum(s - e, 0.0)]


def run_queue_waits_ns() -> dict[int, int]:
    """Run-queue wait so far (ns) of every thread of this process, by native thread id ({} without schedstat)."""
    out: dict[int, int] = {}
    try:
        tids = os.listdir(_TASKS)
    except OSError:
        return out
    for tid in tids:
        try:
            with open(f"{_TASKS}/{tid}/schedstat", "rb") as fh:
                out[int(tid)] = int(fh.read().split()[1])
        except (OSError, IndexError, ValueError):
            continue            # the thread ended meanwhile, or no schedstat
    return out


def steal_ns() -> int:
    """Hypervisor steal time so far, summed over the CPUs (ns; 0 where ``/proc/stat`` has none)."""
    try:
        with open("/proc/stat", "rb") as fh:
            fields = fh.readline().split()
        return int(fields[8]) * 10_000_000 if len(fields) > 8 else 0     # USER_HZ = 100
    except (OSError, ValueError):
        return 0


class EventLoopMonitor(QObject):
    """Record the firing times of a periodic timer (start / stop around the work to watch)."""

    def __init__(self, interval_ms: int = 10, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self.interval_ms = interval_ms
        self.stamps: list[float] = []
        self.cpu: list[float] = []
        self.excused: list[float] = []
        self._ncpu = os.cpu_count() or 1
        self._gui_tid = 0
        self._waits: dict[int, int] = {}
        self._steal = 0
        self._timer = QTimer(self)
        self._timer.setInterval(interval_ms)
        self._timer.timeout.connect(self._fired)

    def _fired(self) -> None:
        self.stamps.append(time.perf_counter())
        self.cpu.append(time.thread_time())
        waits, steal = run_queue_waits_ns(), steal_ns()
        gui = waits.get(self._gui_tid, 0) - self._waits.get(self._gui_tid, 0)
        # a thread that appeared since the last firing counts from its start
        other = max((w - self._waits.get(t, 0) for t, w in waits.items() if t != self._gui_tid), default=0)
        self.excused.append((gui + max(other, 0) + (steal - self._steal) / self._ncpu) / 1e6)
        self._waits, self._steal = waits, steal

    def start(self) -> None:
        self._gui_tid = threading.get_native_id()
        self._waits, self._steal = run_queue_waits_ns(), steal_ns()
        self.stamps = [time.perf_counter()]
        self.cpu = [time.thread_time()]
        self.excused = []
        self._timer.start()

    def stop(self) -> None:
        self._timer.stop()

    def stalls(self) -> list[float]:
        return stalls_ms(self.stamps, self.interval_ms)

    def own_stalls(self) -> list[float]:
        """The stalls minus the time the machine did not run the process (see the module docstring)."""
        return own_stalls_ms(self.stalls(), self.excused[: max(len(self.stamps) - 1, 0)])

    def busy_ms(self) -> list[float]:
        """CPU time of the GUI thread between consecutive firings (ms)."""
        return [float(x) for x in np.diff(np.asarray(self.cpu, float)) * 1000.0]

    def summary(self) -> dict[str, float]:
        """Stalls (``max_ms``, ``p99_ms``, ``p999_ms``, ``median_ms``), own stalls (``own_max_ms``, ``own_p999_ms``), ``busy_max_ms``."""
        s = np.asarray(self.stalls()) if len(self.stamps) > 1 else np.zeros(1)
        o = np.asarray(self.own_stalls()) if len(self.stamps) > 1 else np.zeros(1)
        b = np.asarray(self.busy_ms()) if len(self.cpu) > 1 else np.zeros(1)
        e = np.asarray(self.excused) if self.excused else np.zeros(1)
        return {"max_ms": float(s.max()), "p99_ms": float(np.percentile(s, 99)),
                "p999_ms": float(np.percentile(s, 99.9)), "median_ms": float(np.median(s)),
                "own_max_ms": float(o.max()), "own_p999_ms": float(np.percentile(o, 99.9)), "excused_max_ms": float(e.max()), "busy_max_ms": float(b.max()),
                "firings": len(self.stamps), "seconds": self.stamps[-1] - self.stamps[0] if self.stamps else 0.0}
