"""``kogei batch``: reprocess many sessions, each in its own worker process, incrementally.

docs/batch.md.  One task per session (:func:`process_one`) runs the chosen
steps of :mod:`app.batch.steps` in order, skipping every step whose
fingerprint (inputs, parameters, code version) is unchanged, and writes a log
into the session (``batch.log``).  The tasks run

* on this machine in a :class:`concurrent.futures.ProcessPoolExecutor` with
  the ``forkserver`` start method (``--workers N``), or
* on a Dask distributed cluster (``--dask tcp://SCHEDULER:8786``): the same
  function submitted to a :class:`distributed.Client`.

Progress events travel from the workers through a queue (a
:class:`multiprocessing.Manager` queue, or a :class:`distributed.Queue`) to
a ``rich`` display with one bar per step and one overall.  A failed session
never stops the others; a worker process that dies takes only its own
session down (the sessions it shared a pool with are run again, alone).
Ctrl-C stops every worker; each session is left consistent because a step's
record is its last write (:mod:`app.batch.steps`).
"""

from __future__ import annotations

import fcntl
import multiprocessing
import os
import time
import traceback
import uuid
from collections.abc import Iterable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from app.batch.steps import STEPS, BatchOptions, parse_steps, run_step, up_to_date
from app.errors import UsageError, caused_by_ctrl_c

__all__ = ["StepResult", "SessionResult", "BatchSummary", "run_batch", "process_one", "partial_mesh_reason", "LOG_FILE",
           "EXIT_OK", "EXIT_FAILED", "EXIT_INTERRUPTED"]

LOG_FILE = "batch.log"
BATCH_LOCK = "batch.lock"
EXIT_OK, EXIT_FAILED, EXIT_INTERRUPTED = 0, 1, 130


class _Queue(Protocol):
    def put(self, item: Any) -> Any: ...


@dataclass
class StepResult:
    """What one step did: ``ran``, ``skipped`` (up to date), ``failed``, ``interrupted`` or ``not run``."""

    name: str
    status: str
    reason: str = ""
    seconds: float = 0.0


@dataclass
class SessionResult:
    """What the batch did to one session.

    ``status``: ``ok`` (at least one step ran, none failed), ``skipped``
    (every step up to date), ``failed`` (``reason`` says why) or
    ``interrupted``.
    """

    session: str
    status: str
    reason: str = ""
    steps: list[StepResult] = field(default_factory=list)
    seconds: float = 0.0
    log: str = ""


@dataclass
class BatchSummary:
    """Every session's result, the engine, the worker count and the wall time (s)."""

    results: list[SessionResult]
    engine: str
    workers: int
    seconds: float
    interrupted: bool = False

    def count(self, status: str) -> int:
        """Number of sessions with ``status``."""
        return sum(1 for r in self.results if r.status == status)

    @property
    def exit_code(self) -> int:
        """130 after Ctrl-C, 1 if a session failed, else 0."""
        if self.interrupted or self.count("interrupted"):
            return EXIT_INTERRUPTED
        return EXIT_FAILED if self.count("failed") else EXIT_OK


# ---------------------------------------------------------------------------- the task (runs in a worker)
class _SessionLog:
    """``SESSION/batch.log``: one timestamped line per event, appended and flushed at once."""

    def __init__(self, root: Path) -> None:
        from app.session_paths import open_log_append

        self.path = root / LOG_FILE
        self._fh = open_log_append(root, LOG_FILE, LOG_FILE)

    def __call__(self, text: str) -> None:
        from app.session import utc_now

        self._fh.write(f"{utc_now()} {text}\n")

    def close(self) -> None:
        self._fh.close()


def _emit(queue: _Queue | None, *event: Any) -> None:
    if queue is not None:
        try:
            queue.put(event)
        except Exception:  # progress is best effort: a lost event must not fail the session
            pass


#: Top-level manifest fields the steps read, and their types.
_MANIFEST_TYPES = {"plan": dict, "captures": dict, "passes": dict, "products": dict, "batch": dict, "history": list}


def _check_manifest_types(root: Path, manifest: dict[str, Any]) -> None:
    """A :class:`app.session.SessionError` naming the first top-level field of the wrong type.

    >>> _check_manifest_types(Path("S"), {"plan": {}, "captures": "x"})
    Traceback (most recent call last):
    ...
    app.session.SessionError: session S: session.json captures is a str, not a dict; the manifest is damaged
    """
    from app.session import SessionError

    for key, kind in _MANIFEST_TYPES.items():
        value = manifest.get(key)
        if value is not None and not isinstance(value, kind):
            raise SessionError(f"session {root}: session.json {key} is a {type(value).__name__}, not a "
                               f"{kind.__name__}; the manifest is damaged")
    bad = [cid for cid, rec in (manifest.get("captures") or {}).items() if not isinstance(rec, dict)]
    if bad:
        raise SessionError(f"session {root}: session.json captures {bad[0]!r} is not a record; the manifest "
                           "is damaged")


def _lock_and_log(root: Path) -> tuple[int, _SessionLog]:
    """Take the session's batch lock and open its ``batch.log`` (neither may be a symlink).

    ``BlockingIOError`` when another batch holds the lock; ``UnsafeSessionPath`` (a ``ValueError``)
    for a symlink or a non-regular file.
    """
    import errno

    from app.session_paths import UnsafeSessionPath

    try:
        lock_fd = os.open(root / BATCH_LOCK, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK, 0o644)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise UnsafeSessionPath(f"{BATCH_LOCK} is a symlink; a session may not contain symlinks (remove it)") \
                from None
        raise
    try:
        fcntl.flock(lock_fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return lock_fd, _SessionLog(root)
    except BaseException:
        os.close(lock_fd)
        raise


def _reraise_ctrl_c(exc: BaseException) -> None:
    """Raise :class:`KeyboardInterrupt` when a step's error was a Ctrl-C in disguise (:func:`caused_by_ctrl_c`)."""
    if caused_by_ctrl_c(exc):
        raise KeyboardInterrupt from exc


def process_one(session: str, steps: tuple[str, ...], options: BatchOptions,
                queue: _Queue | None = None) -> SessionResult:
    """Run ``steps`` on one session; never raises for a bad session (the result says why it failed).

    Parameters
    ----------
    session
        The session folder.
    steps
        Step names in pipeline order (:func:`app.batch.steps.parse_steps`).
    options
        The batch parameters.
    queue
        Optional: receives progress events ``(kind, session, step, status, detail)``.
    """
    from app.session import Session, SessionError

    t0 = time.perf_counter()
    root = Path(session)
    result = SessionResult(session=session, status="ok")
    _emit(queue, "session", session, "", "started", "")
    try:
        _check_manifest_types(root, Session.read(root))
    except (SessionError, OSError) as exc:
        result.status, result.reason = "failed", str(exc)
        result.steps = [StepResult(n, "not run", "not a readable session") for n in steps]
        for n in steps:
            _emit(queue, "step", session, n, "failed", result.reason)
        _emit(queue, "session", session, "", "failed", result.reason)
        return result
    try:
        lock_fd, log = _lock_and_log(root)
    except (BlockingIOError, ValueError, OSError) as exc:
        reason = (f"session {root} is being processed by another kogei batch; wait for it to finish"
                  if isinstance(exc, BlockingIOError) else f"session {root}: {exc}")
        result.status, result.reason = "failed", reason
        result.steps = [StepResult(n, "not run", reason) for n in steps]
        for n in steps:
            _emit(queue, "step", session, n, "failed", reason)
        _emit(queue, "session", session, "", "failed", reason)
        return result
    result.log = str(log.path)
    log(f"batch: steps {','.join(steps)}, preset {options.preset}, pid {os.getpid()}")
    failed: set[str] = set()
    try:
        for name in steps:
            step = STEPS[name]
            t = time.perf_counter()
            _emit(queue, "step", session, name, "running", "")
            blocked = [n for n in step.needs if n in failed]
            if blocked:
                reason = f"needs {', '.join(blocked)}, which failed"
                result.steps.append(StepResult(name, "not run", reason))
                failed.add(name)
                log(f"{name}: not run: {reason}")
                _emit(queue, "step", session, name, "failed", reason)
                continue
            try:
                skip, why, _ = up_to_date(step, root, Session.read(root), options)
                if skip:
                    result.steps.append(StepResult(name, "skipped", why))
                    log(f"{name}: skipped ({why})")
                    _emit(queue, "step", session, name, "skipped", why)
                    continue
                log(f"{name}: started ({why})")
                run_step(step, root, options, lambda text, n=name: log(f"{n}: {text}"))
                secs = time.perf_counter() - t
                result.steps.append(StepResult(name, "ran", why, round(secs, 3)))
                log(f"{name}: done in {secs:.2f} s")
                _emit(queue, "step", session, name, "ran", f"{secs:.1f} s")
            except (ValueError, OSError) as exc:     # UsageError, SessionError and the library's input errors
                _reraise_ctrl_c(exc)
                failed.add(name)
                result.steps.append(StepResult(name, "failed", str(exc), round(time.perf_counter() - t, 3)))
                log(f"{name}: FAILED: {exc}")
                _emit(queue, "step", session, name, "failed", str(exc))
            except Exception as exc:  # a bug in a step must not stop the other sessions: logged with its traceback
                _reraise_ctrl_c(exc)
                failed.add(name)
                reason = f"{type(exc).__name__}: {exc} (traceback in {log.path})"
                result.steps.append(StepResult(name, "failed", reason, round(time.perf_counter() - t, 3)))
                log(f"{name}: FAILED: {type(exc).__name__}: {exc}\n{traceback.format_exc()}")
                _emit(queue, "step", session, name, "failed", reason)
    except KeyboardInterrupt:
        done = {s.name for s in result.steps}
        result.steps += [StepResult(n, "interrupted", "Ctrl-C") for n in steps if n not in done]
        result.status, result.reason = "interrupted", "Ctrl-C; the interrupted step runs again next time"
        log("batch: interrupted (Ctrl-C); the session is consistent, the interrupted step runs again next time")
    finally:
        log.close()
        fcntl.flock(lock_fd, fcntl.LOCK_UN)
        os.close(lock_fd)
    if result.status != "interrupted":
        bad = [s for s in result.steps if s.status in ("failed", "not run")]
        if bad:
            result.status, result.reason = "failed", f"{bad[0].name}: {bad[0].reason}"
        elif all(s.status == "skipped" for s in result.steps):
            result.status = "skipped"
    if result.status in ("ok", "skipped") and not result.reason:
        result.reason = partial_mesh_reason(root)
    result.seconds = round(time.perf_counter() - t0, 3)
    _emit(queue, "session", session, "", result.status, result.reason)
    return result


def partial_mesh_reason(root: Path) -> str:
    """``"partial mesh: ..."`` when the session's mesh is a partial result (a pass left out, not watertight), else ``""``."""
    from app.session import Session

    try:
        mesh = (Session.read(root).get("products") or {}).get("mesh") or {}
    except (ValueError, OSError):
        return ""
    warnings = mesh.get("warnings") if isinstance(mesh, dict) else None
    if not isinstance(warnings, list) or not warnings:
        return ""
    return "partial mesh: " + "; ".join(str(w).split(";")[0] for w in warnings)


def _dask_task(session: str, steps: tuple[str, ...], options: BatchOptions, queue_name: str) -> SessionResult:
    """:func:`process_one` on a Dask worker; the progress queue is named, not passed (the scheduler would
    have to unpickle a live queue object)."""
    from distributed import Queue

    return process_one(session, steps, options, Queue(queue_name))


# ---------------------------------------------------------------------------- progress
class _Display:
    """A ``rich`` progress display: one bar per step (sessions through it) and one overall."""

    def __init__(self, sessions: int, steps: tuple[str, ...], enabled: bool, console: Any = None) -> None:
        self.enabled = enabled
        self.steps = steps
        if not enabled:
            return
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        self.console = console or Console(stderr=True)
        self.progress = Progress(TextColumn("{task.description:<22}"), BarColumn(), MofNCompleteColumn(),
                                 TextColumn("{task.fields[note]}"), TimeElapsedColumn(), console=self.console,
                                 redirect_stdout=False, redirect_stderr=False)
        self.overall = self.progress.add_task("all steps", total=sessions * len(steps), note="")
        self.bars = {s: self.progress.add_task(f"  {s}", total=sessions, note="") for s in steps}
        self.running: dict[str, set[str]] = {s: set() for s in steps}
        self.counts: dict[str, dict[str, int]] = {s: {} for s in steps}

    def __enter__(self) -> _Display:
        if self.enabled:
            self.progress.start()
        return self

    def __exit__(self, *exc: object) -> None:
        if self.enabled:
            self.progress.stop()

    def event(self, event: tuple) -> None:
        if not self.enabled or event[0] != "step":
            return
        _, session, step, status, _detail = event
        if step not in self.bars:
            return
        if status == "running":
            self.running[step].add(session)
        else:
            self.running[step].discard(session)
            self.counts[step][status] = self.counts[step].get(status, 0) + 1
            self.progress.advance(self.bars[step])
            self.progress.advance(self.overall)
        c = self.counts[step]
        note = ", ".join(f"{v} {k}" for k, v in sorted(c.items()))
        if self.running[step]:
            note = f"{len(self.running[step])} running" + (f", {note}" if note else "")
        self.progress.update(self.bars[step], note=note)


def _drain(queue: Any, display: _Display) -> None:
    import queue as _q

    while True:
        try:
            display.event(queue.get_nowait())
        except (_q.Empty, EOFError, OSError):
            return


# ---------------------------------------------------------------------------- engines
def _local(sessions: list[str], steps: tuple[str, ...], options: BatchOptions, workers: int,
           display: _Display) -> tuple[dict[str, SessionResult], bool]:
    ctx = multiprocessing.get_context("forkserver")
    results: dict[str, SessionResult] = {}
    interrupted = False
    with ctx.Manager() as manager:
        queue = manager.Queue()
        batches = [(sessions, workers)]
        while batches and not interrupted:
            waiting, n = batches.pop(0)
            broken: list[str] = []
            pool = ProcessPoolExecutor(max_workers=max(1, min(n, len(waiting))), mp_context=ctx)
            futures: dict[Future, str] = {pool.submit(process_one, s, steps, options, queue): s for s in waiting}
            try:
                pending = set(futures)
                while pending:
                    done, pending = wait(pending, timeout=0.1, return_when=FIRST_COMPLETED)
                    _drain(queue, display)
                    for fut in done:
                        s = futures[fut]
                        try:
                            results[s] = fut.result()
                        except BrokenProcessPool:
                            broken.append(s)
                        except KeyboardInterrupt:
                            results[s] = SessionResult(s, "interrupted", "Ctrl-C")
                        except Exception as exc:
                            results[s] = SessionResult(s, "failed", f"worker: {type(exc).__name__}: {exc}")
                pool.shutdown(wait=True)
            except KeyboardInterrupt:
                interrupted = True
                pool.shutdown(wait=True, cancel_futures=True)   # the workers got the same Ctrl-C
                for fut, s in futures.items():
                    if s not in results:
                        try:
                            results[s] = fut.result(timeout=0) if fut.done() and not fut.cancelled() else \
                                SessionResult(s, "interrupted", "Ctrl-C before it started" if fut.cancelled()
                                              else "Ctrl-C")
                        except BaseException:
                            results[s] = SessionResult(s, "interrupted", "Ctrl-C")
            _drain(queue, display)
            if broken:
                if len(broken) == 1 and len(waiting) == 1:
                    results[broken[0]] = SessionResult(broken[0], "failed", "its worker process died (killed, out "
                                                       f"of memory or crashed); see {Path(broken[0]) / LOG_FILE}")
                else:   # run each again alone, so only the session that kills its worker fails
                    batches.extend(([s], 1) for s in broken)
    return results, interrupted


def _require_distributed() -> None:
    """A :class:`UsageError` naming the extra to install when Dask's ``distributed`` cannot be imported."""
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise UsageError("--dask needs Dask's 'distributed' package: pip install 'kogei[cluster]'") from None


def _dask(sessions: list[str], steps: tuple[str, ...], options: BatchOptions, address: str,
          display: _Display) -> tuple[dict[str, SessionResult], bool, int]:
    from distributed import Client, Queue, as_completed  # run_batch checked it is importable

    try:
        client = Client(address, timeout="10s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise UsageError(f"--dask {address}: cannot reach the Dask scheduler ({exc}); start one with "
                         "'dask scheduler' and workers with 'dask worker ADDRESS'") from None
    results: dict[str, SessionResult] = {}
    interrupted = False
    with client:
        workers = len(client.scheduler_info().get("workers", {}))
        name = f"kogei-batch-{uuid.uuid4().hex}"
        queue = Queue(name, client=client)
        futures = {client.submit(_dask_task, s, steps, options, name, pure=False,
                                 key=f"kogei-batch-{i}-{uuid.uuid4().hex[:8]}"): s for i, s in enumerate(sessions)}
        try:
            ac = as_completed(futures)
            while not ac.is_empty() or ac.has_ready():
                for item in queue.get(batch=True):
                    display.event(tuple(item))
                for fut in ac.next_batch(block=False):
                    s = futures[fut]
                    try:
                        results[s] = fut.result()
                    except Exception as exc:       # KilledWorker, a lost connection...
                        results[s] = SessionResult(s, "failed", f"dask: {type(exc).__name__}: {exc}")
                time.sleep(0.1)
            for item in queue.get(batch=True):
                display.event(tuple(item))
        except KeyboardInterrupt:
            interrupted = True
            client.cancel(list(futures))
            for s in sessions:
                results.setdefault(s, SessionResult(s, "interrupted", "Ctrl-C (cancelled on the cluster)"))
    return results, interrupted, workers


def _refuse_duplicates(names: list[str]) -> None:
    """A :class:`UsageError` naming two arguments that are the same session folder (compared resolved).

    >>> _refuse_duplicates(["a", "b"])
    >>> _refuse_duplicates(["/tmp", "/tmp/"])
    Traceback (most recent call last):
    ...
    app.errors.UsageError: session given more than once: '/tmp' and '/tmp/' are the same folder (one worker per session)
    """
    seen: dict[str, str] = {}
    for name in names:
        try:
            key = str(Path(name).resolve())
        except (OSError, RuntimeError):
            key = os.path.abspath(name)
        if key in seen:
            raise UsageError(f"session given more than once: {seen[key]!r} and {name!r} are the same folder "
                             "(one worker per session)")
        seen[key] = name


def run_batch(sessions: Iterable[str | os.PathLike[str]], steps: str | Iterable[str] | None = None, *,
              options: BatchOptions | None = None, workers: int = 1, dask: str | None = None,
              progress: bool = False, console: Any = None) -> BatchSummary:
    """Process ``sessions`` (see the module docstring); returns every session's result.

    Parameters
    ----------
    sessions
        Session folders (each appears once).
    steps
        Step names (a comma-separated string or a list); default every step.
    options
        :class:`app.batch.steps.BatchOptions` (preset, calibration, render size).
    workers
        Worker processes on this machine (ignored with ``dask``).
    dask
        Address of a Dask scheduler, e.g. ``tcp://10.0.0.5:8786``.
    progress
        Show the ``rich`` progress bars (on ``console``, default stderr).

    Raises
    ------
    UsageError
        No session, a session given twice, a bad step name or worker count, an unreachable scheduler.
    """
    names = [str(s) for s in sessions]
    if not names:
        raise UsageError("give one or more session folders")
    _refuse_duplicates(names)
    if not isinstance(workers, int) or isinstance(workers, bool) or workers < 1:
        raise UsageError(f"--workers must be a whole number >= 1, got {workers!r}")
    step_names = parse_steps(steps if steps is None or isinstance(steps, str) else ",".join(steps))
    options = options or BatchOptions()
    if dask:
        _require_distributed()      # before the progress display starts: the message stays one line
    t0 = time.perf_counter()
    display = _Display(len(names), step_names, progress, console)
    with display:
        if dask:
            results, interrupted, n = _dask(names, step_names, options, dask, display)
            engine = f"dask {dask}"
        else:
            results, interrupted = _local(names, step_names, options, workers, display)
            engine, n = "local", workers
    ordered = [results.get(s) or SessionResult(s, "interrupted" if interrupted else "failed", "no result")
               for s in names]
    return BatchSummary(ordered, engine, n, round(time.perf_counter() - t0, 3), interrupted)
