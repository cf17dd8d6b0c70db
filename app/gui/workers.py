"""Work off the GUI thread: thread-pool jobs with progress, messages and cancel, and process jobs.

Qt's threading guide ("Multithreading Technologies in Qt": QThreadPool and
QRunnable for one-off tasks; signals emitted in a worker thread are queued to
receivers living in the GUI thread).  Three kinds of lane:

* :class:`Lane` -- a private :class:`QThreadPool`.  A lane of one thread
  serialises access to instruments (the serial drivers are not thread-safe),
  a wider lane runs independent work such as preview renders.
* :class:`Job` -- a :class:`QRunnable` running ``fn(ctx)``; ``ctx`` is a
  :class:`JobContext` carrying the cancel event and the progress / message
  callbacks, which arrive in the GUI thread as signals.
* :class:`ProcessJob` -- ``fn(*args, message=...)`` in a separate process
  (``multiprocessing`` spawn context) for heavy computation that holds the
  interpreter lock for long stretches (registration, meshing) or cannot be
  interrupted; cancel terminates the process.  Files the library writes are
  atomic, so a terminated job leaves the session as it was.
* :class:`WorkerProcess` -- one long-lived spawned process that runs the
  :class:`ProcessJob` s given it, one after another, for work asked for
  again and again (the preview's full-size renders): a fresh process
  imports Python, Qt's bindings, NumPy, Open3D and colour-science again,
  seconds each time on a busy machine, and loses what the previous job
  kept in memory.  Cancelling its job terminates it; the next job starts
  a new one.

Errors never escape as tracebacks: :func:`describe_error` turns an exception
into the one readable line the window shows (the full traceback goes to the
log).

Examples
--------
>>> describe_error(ValueError("steps must be an integer"))
'steps must be an integer'
>>> describe_error(ZeroDivisionError("division by zero"))
'unexpected error (ZeroDivisionError): division by zero'
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import queue
import threading
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from PySide6.QtCore import QObject, QRunnable, QThreadPool, QTimer, Signal

__all__ = ["describe_error", "JobContext", "JobSignals", "Job", "Lane", "ProcessJob", "WorkerProcess", "WindowClosing",
           "serve_requests"]

_LOG = logging.getLogger("kogei.gui")

#: Exception types whose message is written for the user (the rest get their type named).
_USER_ERRORS: tuple[type[BaseException], ...] = (ValueError, RuntimeError, OSError, TimeoutError)


def describe_error(exc: BaseException) -> str:
    """The readable message of ``exc`` for the window (see the module docstring)."""
    text = str(exc).strip() or type(exc).__name__
    if isinstance(exc, _USER_ERRORS) and not isinstance(exc, (RecursionError, NotImplementedError)):
        return text
    return f"unexpected error ({type(exc).__name__}): {text}"


class WindowClosing(RuntimeError):
    """A job given up because the window is closing: expected, so it is not logged as a failure."""


@dataclass
class JobContext:
    """What a job's function gets: ``cancel`` (set it or test it), ``progress(obj)``, ``message(text)``."""

    cancel: threading.Event
    progress: Callable[[Any], None]
    message: Callable[[str], None]

    def cancelled(self) -> bool:
        """True once cancel was requested."""
        return self.cancel.is_set()


class JobSignals(QObject):
    """Signals of one job; connected receivers in the GUI thread get them queued."""

    progress = Signal(object)
    message = Signal(str)
    succeeded = Signal(object)
    failed = Signal(str, object)      # readable message, the exception
    finished = Signal()


class Job(QRunnable):
    """``fn(ctx)`` on a pool thread; its result or error arrives as :class:`JobSignals`.

    Parameters
    ----------
    fn
        Called with a :class:`JobContext`; its return value is emitted by
        ``succeeded``; an exception by ``failed`` with a readable message.
    name
        For the log.
    """

    def __init__(self, fn: Callable[[JobContext], Any], name: str = "job") -> None:
        super().__init__()
        self.setAutoDelete(False)       # the window keeps a reference while it runs
        self.fn = fn
        self.name = name
        self.signals = JobSignals()
        self.cancel_event = threading.Event()
        self.running = False
        self.done = False
        self.delivered = False          # its signals have reached the window's thread (set there)

    def cancel(self) -> None:
        """Ask the job to stop at its next cancel check."""
        self.cancel_event.set()

    def run(self) -> None:  # runs on a pool thread
        self.running = True
        ctx = JobContext(self.cancel_event, self.signals.progress.emit, self.signals.message.emit)
        try:
            result = self.fn(ctx)
        except WindowClosing as exc:
            _LOG.debug("%s given up: %s", self.name, exc)
            self.signals.failed.emit(describe_error(exc), exc)
        except BaseException as exc:  # noqa: BLE001 - every failure is reported in the window, never lost
            _LOG.error("%s failed: %s\n%s", self.name, describe_error(exc), traceback.format_exc())
            self.signals.failed.emit(describe_error(exc), exc)
        else:
            self.signals.succeeded.emit(result)
        finally:
            self.running = False
            self.done = True
            self.signals.finished.emit()


class Lane:
    """A private thread pool (``threads=1``: jobs run one after another, in order)."""

    def __init__(self, threads: int = 1) -> None:
        self.pool = QThreadPool()
        self.pool.setMaxThreadCount(max(1, int(threads)))
        self.jobs: list[Job] = []

    def submit(self, job: Job) -> Job:
        """Queue ``job``; it is kept referenced until its signals have reached the window's thread.

        A job's results are signals queued from the pool thread to the window's
        thread; dropping the job when it is ``done`` (before the window has
        handled them) let its signals object be collected with a result still
        queued, and that result was lost.  ``finished`` is emitted last, so once
        its receiver here has run, every other receiver has.
        """
        self.jobs = [j for j in self.jobs if not j.delivered]
        job.signals.finished.connect(lambda j=job: setattr(j, "delivered", True))
        self.jobs.append(job)
        self.pool.start(job)
        return job

    def run(self, fn: Callable[[JobContext], Any], name: str = "job", *,
            succeeded: Callable[[Any], None] | None = None, failed: Callable[[str, Any], None] | None = None,
            progress: Callable[[Any], None] | None = None, message: Callable[[str], None] | None = None,
            finished: Callable[[], None] | None = None) -> Job:
        """Build a :class:`Job` for ``fn``, connect the given receivers and submit it."""
        job = Job(fn, name)
        for sig, slot in ((job.signals.succeeded, succeeded), (job.signals.failed, failed),
                          (job.signals.progress, progress), (job.signals.message, message),
                          (job.signals.finished, finished)):
            if slot is not None:
                sig.connect(slot)
        return self.submit(job)

    @property
    def busy(self) -> bool:
        """True while a job of this lane is queued or running, or its results are not handled yet."""
        return any(not j.delivered for j in self.jobs)

    def wait(self, timeout_ms: int = 30_000) -> bool:
        """Block until every job has finished (for shutdown and tests)."""
        return self.pool.waitForDone(timeout_ms)


def _process_main(fn: Callable[..., Any], args: tuple[Any, ...], out: Any) -> None:
    def message(text: str) -> None:
        out.put(("message", str(text)))

    try:
        result = fn(*args, message=message)
    except BaseException as exc:  # noqa: BLE001 - sent to the window as a readable line
        out.put(("failed", describe_error(exc), traceback.format_exc()))
    else:
        out.put(("succeeded", result))


def serve_requests(receive: Callable[[], Any], handle: Callable[[Any], bool]) -> None:
    """A worker process's loop: ``handle`` each request ``receive`` gives until ``None``, a closed pipe or False.

    ``handle`` returns False when the window can no longer be answered.
    """
    while True:
        try:
            request = receive()
        except (EOFError, OSError):
            return                                   # the window has gone
        if request is None or not handle(request):
            return


def _serve_jobs(requests: Any, out: Any) -> None:
    """A :class:`WorkerProcess`: run each ``(fn, args)`` received as :func:`_process_main` would, until ``None``."""
    serve_requests(requests.get, lambda request: _process_main(*request, out) or True)


class WorkerProcess:
    """One spawned process that runs the :class:`ProcessJob` s given it, one at a time (module docstring).

    The process starts with its first job and is kept for the next; a job
    cancelled, or a process that died, leaves none, and the next job starts a
    new one (new queues too: a terminated process can leave a queue broken).
    Whoever owns it runs one job at a time and calls :meth:`stop` when done.
    """

    def __init__(self) -> None:
        self._proc: Any = None
        self.requests: Any = None
        self.replies: Any = None
        self.processes_started = 0

    def ensure(self) -> tuple[Any, Any]:
        """The running process and its reply queue, started now if there is none."""
        if self._proc is None or not self._proc.is_alive():
            self.stop()
            ctx = mp.get_context("spawn")       # never fork a process that runs Qt threads
            self.requests, self.replies = ctx.Queue(), ctx.Queue()
            self._proc = ctx.Process(target=_serve_jobs, args=(self.requests, self.replies), daemon=True,
                                     name="kogei-worker")
            self._proc.start()
            self.processes_started += 1
        return self._proc, self.replies

    def submit(self, fn: Callable[..., Any], args: tuple[Any, ...], *, last: bool = False) -> tuple[Any, Any]:
        """Send ``fn(*args)`` to the process (started if needed); returns the process and its reply queue.

        ``last``: the process ends on its own after this job (a one-off job's process).
        """
        proc, replies = self.ensure()
        self.requests.put((fn, args))
        if last:
            self.requests.put(None)
        return proc, replies

    def terminate(self) -> None:
        """Stop the process now (its job's partial results are not recorded)."""
        proc, self._proc = self._proc, None
        if proc is not None:
            proc.terminate()
            proc.join(5.0)

    def stop(self, timeout_s: float = 2.0) -> None:
        """Ask the process to end after its job, then stop it if it has not within ``timeout_s``."""
        proc, self._proc = self._proc, None
        if proc is not None and proc.is_alive():
            try:
                self.requests.put(None)
            except (OSError, ValueError):
                pass
            proc.join(timeout_s)
            if proc.is_alive():
                proc.terminate()
                proc.join(5.0)


class ProcessJob(QObject):
    """``fn(*args, message=callback)`` in a spawned process; messages and the result arrive as signals.

    ``fn`` and its arguments and result must be picklable (a module-level
    function and plain data).  :meth:`cancel` terminates the process.  With
    ``worker`` (a :class:`WorkerProcess`), the job runs in that process;
    without, in a process of its own that ends after it.
    """

    message = Signal(str)
    succeeded = Signal(object)
    failed = Signal(str, object)
    finished = Signal()

    def __init__(self, fn: Callable[..., Any], *args: Any, poll_ms: int = 50, parent: QObject | None = None,
                 worker: WorkerProcess | None = None) -> None:
        super().__init__(parent)
        self._fn, self._args = fn, args
        self._one_off = worker is None
        self._worker = WorkerProcess() if worker is None else worker
        self._queue: Any = None
        self._proc: Any = None
        self._timer = QTimer(self)
        self._timer.setInterval(poll_ms)
        self._timer.timeout.connect(self._poll)
        self.done = False
        self.cancelled = False

    def start(self) -> ProcessJob:
        self._proc, self._queue = self._worker.submit(self._fn, self._args, last=self._one_off)
        self._timer.start()
        return self

    @property
    def running(self) -> bool:
        return not self.done

    def cancel(self) -> None:
        """Stop the process now (its partial results are not recorded)."""
        if self.done:
            return
        self.cancelled = True
        self._worker.terminate()
        self._finish()
        self.failed.emit("cancelled by the user; the session is unchanged", None)
        self.finished.emit()

    def _finish(self) -> None:
        self.done = True
        self._timer.stop()

    def _poll(self) -> None:
        # a few items per tick keeps every tick short
        for _ in range(20):
            try:
                item = self._queue.get_nowait()
            except queue.Empty:
                break
            kind = item[0]
            if kind == "message":
                self.message.emit(item[1])
                continue
            # the process exits on its own (tearing down its libraries takes a while): never wait for it here
            self._finish()
            if kind == "succeeded":
                self.succeeded.emit(item[1])
            else:
                _LOG.error("process job failed: %s\n%s", item[1], item[2])
                self.failed.emit(item[1], item[2])
            self.finished.emit()
            return
        if not self.done and not self._proc.is_alive() and self._queue.empty():
            self._finish()
            code = self._proc.exitcode
            self.failed.emit(f"the worker process ended without a result (exit code {code})", None)
            self.finished.emit()
