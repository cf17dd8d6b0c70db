"""The session store: a directory of captures with a versioned, crash-safe manifest.

See ``docs/session-format.md``.  A session directory holds ``session.json``
(schema ``kogei.session``, version :data:`SCHEMA_VERSION`) and the captured
files.  Every file is written atomically (temporary file in the same folder,
``fsync``, rename, ``fsync`` of the folder; :mod:`processing.common.files`)
and checksummed (SHA-256) before it is recorded.

Recording a capture appends one line to ``session.journal`` (a write-ahead
log), so a capture costs one small append however large the session is;
:meth:`Session.checkpoint` folds the journal into ``session.json``
(atomically) and empties it.  :meth:`Session.open` replays the journal, so a
crash or ``kill -9`` at any point loses at most the capture in flight:

* a file written but not yet recorded is simply written again on resume;
* a torn last journal line (the process died mid-append) is ignored;
* a record whose file is missing or fails its checksum is not "done".

Durability against a power cut is a group commit: files and journal lines
reach the operating system at once (so a process crash loses nothing) and
are ``fsync``-ed together at most every ``sync_interval_s`` seconds, at every
checkpoint and for every adopted RAW frame.  A power cut therefore costs at
most the last ``sync_interval_s`` of profiles, which the checksums reveal and
a resumed capture takes again; ``sync_interval_s=0`` syncs every record (at
the price of several ``fsync`` per profile step, see docs/BENCHMARKS.md).

One process at a time may write a session (an ``flock`` on
``session.lock``, released by the kernel even after ``kill -9``).

A session folder is untrusted input (``docs/session-format.md``, "Trust
model"): the session's own files are opened without following links and
must be plain files; the manifest and every journal operation are checked
against a bounded schema on load; file names stored in a session are joined
to its root only through :func:`session_path` and read through
:func:`check_regular_file` / :func:`read_session_file`.  A full or
read-only disk ends in a one-line :class:`SessionError`, never a traceback.

Examples
--------
>>> import tempfile, pathlib
>>> root = pathlib.Path(tempfile.mkdtemp()) / "s1"
>>> s = Session.create(root, plan={"kind": "scan", "steps": 4, "passes": 1})
>>> info = s.write_file("passes/p01/note.txt", b"hello")
>>> s.add_capture("p01/note", kind="note", file=info.path, sha256=info.sha256, bytes=info.bytes)
>>> s.close()
>>> t = Session.open(root)
>>> t.is_done("p01/note"), t.manifest["schema"]
(True, 'kogei.session')
>>> t.close()
"""

from __future__ import annotations

import datetime as _dt
import errno
import fcntl
import hashlib
import io
import json
import math
import os
import shutil
import stat
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from processing.common.files import JSONFileError, atomic_path, atomic_write_bytes, fsync_dir, parse_json, sha256_file
from processing.errors import InputError

__all__ = [
    "SCHEMA",
    "SCHEMA_VERSION",
    "MANIFEST",
    "JOURNAL",
    "SessionError",
    "SessionLockedError",
    "disk_error",
    "FileInfo",
    "Session",
    "session_path",
    "check_regular_file",
    "read_session_file",
    "atomic_write_bytes",   # re-exported from processing.common.files
    "sha256_file",          # re-exported from processing.common.files
    "utc_now",
]

SCHEMA = "kogei.session"
#: Version of the manifest layout; :meth:`Session.open` refuses newer versions and migrates older ones
#: (version 2 adds ``camera_calibration``, ``lamp_calibration``, ``plan.board``, ``plan.sphere_radius_mm``
#: and the products ``frame_poses``, ``observations``, ``projection_report``; a version 1 session simply
#: has no camera poses).
SCHEMA_VERSION = 2
MANIFEST = "session.json"
JOURNAL = "session.journal"
LOCK = "session.lock"
#: Largest ``session.json`` read (bytes); a manifest of 100 000 captures is about 40 MB.
MAX_MANIFEST_BYTES = 256 << 20
#: Largest ``session.journal`` replayed (bytes).
MAX_JOURNAL_BYTES = 1 << 30

_STATUSES = ("new", "capturing", "interrupted", "complete", "failed")


class SessionError(InputError):
    """A session directory that cannot be created, opened or written; the message names it."""


class SessionLockedError(SessionError):
    """Another process is writing the session."""


@dataclass(frozen=True)
class FileInfo:
    """A file written into a session: path relative to the session root, SHA-256, size in bytes."""

    path: str
    sha256: str
    bytes: int


def utc_now() -> str:
    """The current UTC time as ISO 8601 with microseconds and a ``Z``."""
    return _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def _check_rel(rel: str) -> str:
    p = Path(rel)
    if not rel or p.is_absolute() or ".." in p.parts or rel.startswith("."):
        raise SessionError(f"session file name {rel!r} must be a relative path inside the session "
                           "(no '..', not absolute, no leading dot)")
    return p.as_posix()


_SYMLINK_FIX = "a session folder holds plain files and folders only; replace it with the real file or folder"


def _symlink_error(what: str, rel: str) -> SessionError:
    return SessionError(f"{what}: {rel} is a symbolic link; {_SYMLINK_FIX} (kogei never follows links "
                        "inside a session)")


def session_path(root: str | os.PathLike[str], rel: Any, what: str) -> Path:
    """``root / rel`` after checking that ``rel`` stays inside the session without following a link.

    Every file name a session stores (a capture's ``file``, a product, the
    calibration, ...) is untrusted input; join it to the session root only
    through this function.  ``root`` itself may be a symbolic link (the
    folder the user names); only the entries below it are checked, each
    with ``lstat``, so nothing outside the session is read or written
    through a link planted inside it.  Missing components are accepted (a
    file about to be written); the caller checks the file itself, e.g. with
    :func:`check_regular_file`.

    Parameters
    ----------
    root
        The session folder.
    rel
        A session-relative file name from the manifest (``/`` separated).
    what
        What the name is, for the message (``"products.mesh.file"``).

    Returns
    -------
    Path
        ``Path(root) / rel``.

    Raises
    ------
    SessionError
        ``rel`` is not a non-empty string, contains a NUL byte, is absolute,
        has a ``..`` component, or a component below ``root`` is a symbolic
        link.  The message names ``what`` and ``rel``.

    Examples
    --------
    >>> import tempfile
    >>> session_path(tempfile.mkdtemp(), "passes/p01/a.npz", "capture p01/a").name
    'a.npz'
    >>> session_path("/tmp", "../etc/passwd", "products.mesh.file")
    Traceback (most recent call last):
    ...
    app.session.SessionError: products.mesh.file: '../etc/passwd' must be a relative path inside the session (no '..', not absolute); fix or remove that entry in session.json
    """
    if not isinstance(rel, str) or not rel:
        raise SessionError(f"{what}: the file name must be a non-empty text, got {rel!r}; fix or remove "
                           "that entry in session.json")
    if "\0" in rel:
        raise SessionError(f"{what}: the file name {rel!r} contains a NUL byte; fix or remove that entry "
                           "in session.json")
    parts = Path(rel).parts
    if Path(rel).is_absolute() or ".." in parts:
        raise SessionError(f"{what}: {rel!r} must be a relative path inside the session (no '..', not "
                           "absolute); fix or remove that entry in session.json")
    base = Path(root)
    current = base
    for part in parts:
        current = current / part
        try:
            mode = os.lstat(current).st_mode
        except FileNotFoundError:
            break
        except OSError as exc:
            raise SessionError(f"{what}: cannot look at {current}: {exc.strerror or exc}") from None
        if stat.S_ISLNK(mode):
            raise _symlink_error(what, current.relative_to(base).as_posix())
    return base / rel


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISFIFO(mode):
        return "a named pipe (FIFO)"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device file"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISLNK(mode):
        return "a symbolic link"
    return "not a plain file"


def _check_stat(st: os.stat_result, path: Path, what: str, max_bytes: int | None) -> None:
    if not stat.S_ISREG(st.st_mode):
        if stat.S_ISLNK(st.st_mode):
            raise _symlink_error(what, path.name)
        raise SessionError(f"{what}: {path} is {_kind(st.st_mode)}, not a plain file; a session holds plain "
                           "files only: replace or remove it")
    if max_bytes is not None and st.st_size > max_bytes:
        raise SessionError(f"{what}: {path} has {st.st_size} bytes, more than the {max_bytes} this file may "
                           "have; it is not what kogei wrote: replace or remove it")


def check_regular_file(path: str | os.PathLike[str], what: str, max_bytes: int | None = None) -> Path:
    """Refuse anything but a plain file of at most ``max_bytes`` at ``path`` (not followed if a link).

    Call it on a path from :func:`session_path` before reading: a FIFO
    would block the reader for ever, a device file (``/dev/zero``) would
    exhaust memory, a folder or a huge file is not what kogei wrote.  For a
    read that cannot be raced (the file swapped between the check and the
    read) use :func:`read_session_file`.

    Parameters
    ----------
    path
        The file (a symbolic link is refused, not followed).
    what
        What the file is, for the message.
    max_bytes
        Largest accepted size; None for no bound.

    Returns
    -------
    Path
        ``path``, for chaining.

    Raises
    ------
    SessionError
        Missing, a symbolic link, a folder, FIFO, device or socket, or larger
        than ``max_bytes``; the message names ``what`` and the file.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "a.bin"
    >>> _ = p.write_bytes(b"12345")
    >>> check_regular_file(p, "test file", max_bytes=10).name
    'a.bin'
    >>> check_regular_file(p.parent, "test file")
    Traceback (most recent call last):
    ...
    app.session.SessionError: test file: ... is a folder, not a plain file; a session holds plain files only: replace or remove it
    """
    p = Path(path)
    try:
        st = os.lstat(p)
    except FileNotFoundError:
        raise SessionError(f"{what}: {p} is missing") from None
    except OSError as exc:
        raise SessionError(f"{what}: cannot look at {p}: {exc.strerror or exc}") from None
    _check_stat(st, p, what, max_bytes)
    return p


def read_session_file(root: str | os.PathLike[str], rel: Any, what: str, max_bytes: int) -> bytes:
    """The bytes of the session file ``rel``, checked by :func:`session_path` and as a plain file.

    The file is opened without following a link and without blocking (a
    FIFO cannot hang the reader), then checked on the open descriptor, so it
    cannot be swapped between the check and the read.

    Parameters
    ----------
    root
        The session folder.
    rel
        The session-relative name (from the manifest: untrusted).
    what
        What the file is, for the message.
    max_bytes
        Largest accepted size.

    Returns
    -------
    bytes
        The contents.

    Raises
    ------
    SessionError
        As :func:`session_path` and :func:`check_regular_file`, or unreadable.
    """
    path = session_path(root, rel, what)
    return _read_plain(path, what, max_bytes)


def _read_plain(path: Path, what: str, max_bytes: int) -> bytes:
    flags = os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        raise SessionError(f"{what}: {path} is missing") from None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise _symlink_error(what, path.name) from None
        raise SessionError(f"{what}: cannot read {path}: {exc.strerror or exc}") from None
    try:
        _check_stat(os.fstat(fd), path, what, max_bytes)
        with os.fdopen(fd, "rb", closefd=False) as fh:
            data = fh.read(max_bytes + 1)
    except OSError as exc:
        raise SessionError(f"{what}: cannot read {path}: {exc.strerror or exc}") from None
    finally:
        os.close(fd)
    if len(data) > max_bytes:
        raise SessionError(f"{what}: {path} grew beyond {max_bytes} bytes while being read; replace it")
    return data


class Session:
    """An open session directory (see the module docstring).

    Use :meth:`create` or :meth:`open`; :meth:`close` (or the context
    manager) checkpoints the journal and releases the lock.

    Attributes
    ----------
    root
        The session directory.
    manifest
        The manifest as a dict (``captures`` maps capture ids to records).
    """

    #: Default seconds between group ``fsync`` of files and journal (see the module docstring).
    SYNC_INTERVAL_S = 1.0

    def __init__(self, root: Path, manifest: dict[str, Any], lock_fd: int, sync_interval_s: float | None = None) -> None:
        self.root = root
        self.manifest = manifest
        self._lock_fd = lock_fd
        try:
            self._journal = _open_journal(root)
        except OSError as exc:
            raise disk_error(root, f"open {JOURNAL} for writing", exc) from None
        self._journal_ops = 0
        self.sync_interval_s = _interval(sync_interval_s, self.SYNC_INTERVAL_S)
        self._unsynced: set[Path] = set()
        self._last_sync = time.monotonic()

    # ------------------------------------------------------------------ life cycle
    @staticmethod
    def _lock(root: Path) -> int:
        try:
            fd = _open_own(root, LOCK, os.O_RDWR | os.O_CREAT)
        except OSError as exc:
            raise disk_error(root, f"open {LOCK} for writing", exc) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise SessionLockedError(
                f"session {root} is in use by another process (a kogei capture, batch, report or the GUI "
                "still running?); wait for it to finish or close it, then run the command again "
                f"('kogei report {root} --out FILE.html' reads the session without locking it)") from None
        return fd

    @classmethod
    def create(cls, root: str | os.PathLike[str], *, plan: dict[str, Any], object_info: dict[str, Any] | None = None,
               devices: dict[str, Any] | None = None, settings: dict[str, Any] | None = None,
               sync_interval_s: float | None = None) -> Session:
        """Create a new session directory (it must not exist, or be empty).

        Parameters
        ----------
        root
            The session directory.
        plan
            What will be captured (JSON-serialisable; ``docs/session-format.md``).
        object_info
            Object metadata (name, collection number, notes, ...).
        devices
            Device configuration (ports, camera, settings) for ``--resume``.
        settings
            Other capture settings to keep (JSON-serialisable).
        sync_interval_s
            Group-commit interval (see the module docstring); default
            :attr:`SYNC_INTERVAL_S`.
        """
        _interval(sync_interval_s, cls.SYNC_INTERVAL_S)
        path = Path(root)
        if path.exists() and (not path.is_dir() or any(path.iterdir())):
            raise SessionError(f"{path} already exists and is not an empty folder; choose a new session folder, "
                               f"or continue that session with 'kogei capture --resume {path}'")
        try:
            path.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise SessionError(f"cannot create session folder {path}: {exc.strerror or exc}") from None
        now = utc_now()
        manifest: dict[str, Any] = {
            "schema": SCHEMA,
            "version": SCHEMA_VERSION,
            "created_utc": now,
            "updated_utc": now,
            "status": "new",
            "object": dict(object_info or {}),
            "devices": dict(devices or {}),
            "settings": dict(settings or {}),
            "calibration": None,
            "camera_calibration": None,
            "lamp_calibration": None,
            "plan": dict(plan),
            "passes": {},
            "state": {},
            "captures": {},
            "history": [{"utc": now, "event": "created", "detail": ""}],
        }
        try:
            json.dumps(manifest)
        except (TypeError, ValueError) as exc:
            raise SessionError(f"session {path}: plan, object, devices and settings must be JSON data: {exc}") from None
        fd = cls._lock(path)
        try:
            atomic_write_bytes(path / MANIFEST, _dump(manifest))
            return cls(path, manifest, fd, sync_interval_s)
        except OSError as exc:
            os.close(fd)
            raise disk_error(path, f"write {MANIFEST}", exc) from None
        except BaseException:
            os.close(fd)
            raise

    @classmethod
    def read(cls, root: str | os.PathLike[str]) -> dict[str, Any]:
        """The manifest with the journal replayed, without locking or changing anything (for viewers)."""
        return cls.read_checked(root)[0]

    @classmethod
    def read_checked(cls, root: str | os.PathLike[str]) -> tuple[dict[str, Any], list[str]]:
        """As :meth:`read`, with the problems found on the way (corrupt journal lines that were skipped).

        Returns
        -------
        tuple
            The manifest, and a list of one-line problem descriptions (empty
            when the journal is sound) for a report's "problems found".
        """
        path = Path(root)
        manifest = _load_manifest(path)
        problems = _replay(manifest, path / JOURNAL, strict=False)
        return manifest, problems

    @classmethod
    def problems(cls, root: str | os.PathLike[str]) -> list[str]:
        """The problems :meth:`read` skips over (corrupt journal lines), one line each; empty if none."""
        return cls.read_checked(root)[1]

    @classmethod
    def open(cls, root: str | os.PathLike[str], *, sync_interval_s: float | None = None) -> Session:
        """Open an existing session for writing: lock it, replay its journal, checkpoint.

        Raises
        ------
        SessionError
            Not a session, an unreadable or newer manifest, a corrupt journal.
        SessionLockedError
            Another process holds the session.
        """
        _interval(sync_interval_s, cls.SYNC_INTERVAL_S)
        path = Path(root)
        manifest = _load_manifest(path)
        fd = cls._lock(path)
        try:
            _replay(manifest, path / JOURNAL, strict=True)
            session = cls(path, manifest, fd, sync_interval_s)
        except BaseException:
            os.close(fd)
            raise
        try:
            session.checkpoint()
        except BaseException:
            session._release()
            raise
        return session

    def close(self) -> None:
        """Checkpoint and release the session (idempotent)."""
        if self._lock_fd < 0:
            return
        try:
            self.checkpoint()
        finally:
            self._release()

    def _release(self) -> None:
        """Close the journal and release the lock without checkpointing (the journal keeps every record)."""
        try:
            self._journal.close()
        except OSError:
            pass            # a buffered append that failed (disk full) was reported already; the line is torn
        os.close(self._lock_fd)
        self._lock_fd = -1

    def __enter__(self) -> Session:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        if exc_type is None:
            self.close()
            return
        try:
            self.close()
        except SessionError:
            pass            # keep the error in flight (e.g. "disk full"): it is the one the user must see

    # ------------------------------------------------------------------ files
    def path(self, rel: str) -> Path:
        """Absolute path of a session-relative file name (checked by :func:`session_path`)."""
        return session_path(self.root, _check_rel(rel), "session file")

    def write_file(self, rel: str, data: bytes) -> FileInfo:
        """Write ``data`` atomically and durably at ``rel``; returns its checksum (not yet recorded)."""
        self._require_open()
        rel = _check_rel(rel)
        session_path(self.root, rel, "session file")
        durable = self.sync_interval_s == 0
        try:
            atomic_write_bytes(self.root / rel, data, durable=durable)
        except OSError as exc:
            raise SessionError(f"session {self.root}: cannot write {rel}: {exc.strerror or exc} "
                               "(disk full or read-only? free space and resume)") from None
        if not durable:
            self._unsynced.add(self.root / rel)
        return FileInfo(rel, hashlib.sha256(data).hexdigest(), len(data))

    def write_arrays(self, rel: str, **arrays: Any) -> FileInfo:
        """Write NumPy arrays as an uncompressed ``.npz`` at ``rel`` (atomic, checksummed)."""
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        return self.write_file(rel, buf.getvalue())

    def adopt_file(self, src: str | os.PathLike[str], rel: str) -> FileInfo:
        """Move an existing file (e.g. a downloaded RAW frame) to ``rel`` atomically, replacing any old one."""
        self._require_open()
        rel = _check_rel(rel)
        target = session_path(self.root, rel, "session file")
        source = Path(src)
        digest = sha256_file(source)
        size = source.stat().st_size
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            try:
                os.replace(source, target)
            except OSError:
                # another filesystem: copy to a temporary file beside the target, then rename (fsync-ed)
                with atomic_path(target) as tmp:
                    shutil.copyfile(source, tmp)
                source.unlink()
            else:
                fsync_dir(target.parent)
        except OSError as exc:
            raise disk_error(self.root, f"store {rel}", exc) from None
        return FileInfo(rel, digest, size)

    def verify_file(self, record: dict[str, Any]) -> str | None:
        """Why a capture record's file is not intact, or None if it is (exists, size and SHA-256 match)."""
        rel = record.get("file")
        if not rel:
            return None
        try:
            p = session_path(self.root, rel, "capture file")
            st = os.lstat(p)
        except SessionError as exc:
            return str(exc)
        except OSError:
            return f"{rel} is missing"
        if not stat.S_ISREG(st.st_mode):
            return f"{rel} is {_kind(st.st_mode)}, not a plain file"
        if "bytes" in record and p.stat().st_size != record["bytes"]:
            return f"{rel} has {p.stat().st_size} bytes, the manifest says {record['bytes']}"
        if "sha256" in record and sha256_file(p) != record["sha256"]:
            return f"{rel} fails its SHA-256 checksum"
        return None

    # ------------------------------------------------------------------ records
    def add_capture(self, capture_id: str, *, state: dict[str, Any] | None = None, **record: Any) -> None:
        """Record a finished capture (journaled immediately; its file must already be written).

        ``state`` also merges into the running state in the same journal write.
        """
        rec = {"status": "done", "utc": utc_now(), **record}
        ops = [{"op": "capture", "id": capture_id, "record": rec}]
        if state:
            ops.append({"op": "state", "fields": state})
        self._apply(*ops)

    def capture(self, capture_id: str) -> dict[str, Any] | None:
        """The record of ``capture_id``, or None."""
        return self.manifest["captures"].get(capture_id)

    def is_done(self, capture_id: str, *, verify: bool = True) -> bool:
        """True if ``capture_id`` is recorded as done (and its file is intact, with ``verify``)."""
        rec = self.capture(capture_id)
        if rec is None or rec.get("status") != "done":
            return False
        return not verify or self.verify_file(rec) is None

    def update_pass(self, number: int, **fields: Any) -> None:
        """Merge ``fields`` into the record of pass ``number``."""
        self._apply({"op": "pass", "pass": int(number), "fields": fields})

    def pass_record(self, number: int) -> dict[str, Any]:
        """The record of pass ``number`` (empty if none)."""
        return dict(self.manifest["passes"].get(str(int(number)), {}))

    def set_state(self, **fields: Any) -> None:
        """Merge ``fields`` into the session's running state (e.g. the table angle)."""
        self._apply({"op": "state", "fields": fields})

    def event(self, event: str, detail: str = "") -> None:
        """Append an entry to the session's history (start, resume, recovered fault, interruption...)."""
        self._apply({"op": "event", "entry": {"utc": utc_now(), "event": event, "detail": detail}})

    def set_status(self, status: str) -> None:
        """Set the session status (``new``, ``capturing``, ``interrupted``, ``complete``, ``failed``)."""
        if status not in _STATUSES:
            raise SessionError(f"status must be one of {', '.join(_STATUSES)}, got {status!r}")
        self._apply({"op": "status", "status": status})

    def update(self, key: str, value: Any) -> None:
        """Replace a top-level manifest entry (``object``, ``devices``, ``calibration``, ``settings``...)."""
        if key in ("schema", "version", "captures", "passes", "history", "state", "status"):
            raise SessionError(f"manifest key {key!r} is managed by the session; use its own method")
        try:
            _check_field(key, value)
        except _SchemaError as exc:
            raise SessionError(f"session {self.root}: {exc}") from None
        self._apply({"op": "set", "key": key, "value": value})

    def sync(self) -> None:
        """Make every file written and every record journaled so far durable (``fsync``)."""
        self._require_open()
        try:
            self._sync()
        except OSError as exc:
            raise disk_error(self.root, "write its files to disk (fsync)", exc) from None

    def _sync(self) -> None:
        folders = set()
        for path in self._unsynced:
            try:
                fd = os.open(path, os.O_RDONLY)
            except FileNotFoundError:
                continue            # replaced or removed since; its successor is in the set too
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
            folders.add(path.parent)
        for folder in folders:
            fsync_dir(folder)
        self._unsynced.clear()
        self._journal.flush()
        os.fsync(self._journal.fileno())
        self._last_sync = time.monotonic()

    def checkpoint(self) -> None:
        """Fold the journal into ``session.json`` (atomic) and empty the journal."""
        self._require_open()
        self.sync()
        self.manifest["updated_utc"] = utc_now()
        try:
            atomic_write_bytes(self.root / MANIFEST, _dump(self.manifest))
            self._journal.truncate(0)
            self._journal.seek(0)
            os.fsync(self._journal.fileno())
        except OSError as exc:
            raise disk_error(self.root, f"save {MANIFEST}", exc) from None
        self._journal_ops = 0

    # ------------------------------------------------------------------ internals
    def _require_open(self) -> None:
        if self._lock_fd < 0:
            raise SessionError(f"session {self.root} is closed; open it again with Session.open")

    def _apply(self, *ops: dict[str, Any]) -> None:
        self._require_open()
        try:
            line = b"".join(json.dumps(op, separators=(",", ":"), allow_nan=False).encode() + b"\n" for op in ops)
        except (TypeError, ValueError) as exc:
            raise SessionError(f"session {self.root}: a record is not JSON data (NaN or an object?): {exc}") from None
        try:
            self._journal.write(line)
            self._journal.flush()
            if time.monotonic() - self._last_sync >= self.sync_interval_s:
                self._sync()
        except OSError as exc:
            raise SessionError(f"session {self.root}: cannot append to {JOURNAL}: {exc.strerror or exc} "
                               "(disk full? free space and resume)") from None
        for op in ops:
            _apply_op(self.manifest, op)
        self._journal_ops += len(ops)


_READ_ONLY = (errno.EROFS, errno.EACCES, errno.EPERM)
_FULL = (errno.ENOSPC, errno.EDQUOT)


def disk_error(root: Path, action: str, exc: OSError) -> SessionError:
    """The one-line message for an ``OSError`` while writing the session: what failed and what to do."""
    reason = exc.strerror or str(exc)
    if exc.errno in _FULL:
        todo = "the disk is full: free space"
    elif exc.errno in _READ_ONLY:
        todo = "the session is read-only here: make it writable or copy it to a writable disk"
    else:
        todo = "fix the disk"
    return SessionError(f"session {root}: cannot {action}: {reason}; nothing recorded is lost: {todo} and run "
                        f"the command again (a capture continues with 'kogei capture --resume {root}')")


def _open_own(root: Path, name: str, flags: int) -> int:
    """``os.open`` one of the session's own files (journal, lock) without following a link."""
    flags |= os.O_NOFOLLOW | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(root / name, flags, 0o666)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise _symlink_error(f"session {root}", name) from None
        raise
    try:
        _check_stat(os.fstat(fd), root / name, f"session {root}", None)
    except BaseException:
        os.close(fd)
        raise
    return fd


def _open_journal(root: Path) -> io.BufferedWriter:
    fd = _open_own(root, JOURNAL, os.O_WRONLY | os.O_APPEND | os.O_CREAT)
    os.set_blocking(fd, True)
    return os.fdopen(fd, "ab")


def _interval(value: float | None, default: float) -> float:
    interval = default if value is None else value
    if not (isinstance(interval, (int, float)) and 0 <= interval < float("inf")):
        raise SessionError(f"sync_interval_s must be a number of seconds >= 0, got {value!r}")
    return float(interval)


def _dump(manifest: dict[str, Any]) -> bytes:
    return json.dumps(manifest, indent=1, allow_nan=False).encode() + b"\n"


def _load_manifest(path: Path) -> dict[str, Any]:
    file = path / MANIFEST
    if not os.path.lexists(file):
        raise SessionError(f"{path} is not a kogei session ({MANIFEST} not found); give the folder "
                           "'kogei capture --out' created")
    data = _read_plain(file, f"session {path}", MAX_MANIFEST_BYTES)
    try:
        manifest = parse_json(data, file, f"restore {MANIFEST} from a backup")
    except JSONFileError as exc:
        raise SessionError(f"{file} is unreadable ({exc.reason}); restore it from a backup") from None
    if not isinstance(manifest, dict) or manifest.get("schema") != SCHEMA:
        raise SessionError(f"{file} is not a kogei session manifest (schema {manifest.get('schema')!r})"
                           if isinstance(manifest, dict) else f"{file} is not a kogei session manifest")
    version = manifest.get("version")
    if _is_int(version, SCHEMA_VERSION + 1, 1 << 62):
        raise SessionError(f"{file} has manifest version {version!r}; this kogei reads versions up to "
                           f"{SCHEMA_VERSION}: update kogei")
    try:
        _check_manifest(manifest)
    except _SchemaError as exc:
        raise SessionError(f"{file}: {exc}; fix that field or restore {MANIFEST} from a backup") from None
    _migrate(manifest)
    return manifest


def _migrate(manifest: dict[str, Any]) -> None:
    """Bring an older manifest to :data:`SCHEMA_VERSION` in memory (written back at the next checkpoint).

    Version 1 -> 2: the session has no camera or lamp calibration and no
    posed frames (``camera_calibration`` and ``lamp_calibration`` are null).
    """
    version = manifest["version"]
    if version >= SCHEMA_VERSION:
        return
    manifest.setdefault("camera_calibration", None)
    manifest.setdefault("lamp_calibration", None)
    manifest["version"] = SCHEMA_VERSION
    manifest["history"].append({"utc": utc_now(), "event": "migrated",
                                "detail": f"manifest version {version} -> {SCHEMA_VERSION} "
                                          "(no camera or lamp calibration: frames are not posed)"})


def _replay(manifest: dict[str, Any], journal: Path, *, strict: bool) -> list[str]:
    """Apply the journal's operations to ``manifest``.

    A torn last line (not JSON) is ignored.  Any other bad line raises
    :class:`SessionError` when ``strict``; otherwise it is skipped and
    described in the returned list of problems (one line each).
    """
    problems: list[str] = []
    if not os.path.lexists(journal):
        return problems
    lines = _read_plain(journal, f"session {journal.parent}", MAX_JOURNAL_BYTES).split(b"\n")
    for i, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            op = parse_json(line, f"{journal} line {i + 1}", "move the journal aside")
        except JSONFileError as exc:
            if all(not rest.strip() for rest in lines[i + 1:]):
                break  # torn final line: the process died while appending it
            why = f"not JSON ({exc.reason}), and not a torn last line"
        else:
            try:
                _check_op(op)
            except _SchemaError as exc:
                why = str(exc)
            else:
                _apply_op(manifest, op)
                continue
        if strict:
            raise SessionError(f"{journal}: line {i + 1} is corrupt ({why}); the session needs attention: move "
                               "the journal aside and resume (captures after the last checkpoint will be taken "
                               "again)")
        problems.append(f"{JOURNAL} line {i + 1} is corrupt ({why}); it was skipped")
    return problems


# ---------------------------------------------------------------------------- schema of manifest and journal
#: Bounds a manifest must respect (a session outside them is refused, not processed for ever).
MAX_PASSES = 1000
MAX_STEPS = 100_000
MAX_CAPTURES = 2_000_000
MAX_HISTORY = 1_000_000
_MANAGED = ("schema", "version", "captures", "passes", "history", "state", "status")
_DICT_FIELDS = ("object", "devices", "settings", "state", "products", "batch")
_OPS = ("capture", "pass", "state", "event", "status", "set")


class _SchemaError(ValueError):
    """A manifest field or journal operation of the wrong type or out of bounds (message names it)."""


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _need(ok: bool, field: str, expected: str, value: Any) -> None:
    if not ok:
        raise _SchemaError(f"{field} must be {expected}, got {_short(value)}")


def _is_int(value: Any, low: int, high: int) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and low <= value <= high


def _check_record(field: str, rec: Any) -> None:
    _need(isinstance(rec, dict), field, "an object (a capture record)", rec)
    _need(rec.get("file") is None or isinstance(rec["file"], str), f"{field}.file", "a file name or null",
          rec.get("file"))
    if "bytes" in rec:
        _need(_is_int(rec["bytes"], 0, 1 << 50), f"{field}.bytes", "a size in bytes", rec["bytes"])
    if "sha256" in rec:
        _need(isinstance(rec["sha256"], str), f"{field}.sha256", "a hex digest", rec["sha256"])
    if "status" in rec:
        _need(isinstance(rec["status"], str), f"{field}.status", "a text", rec["status"])
    if "table_frame" in rec:
        _need(_is_int(rec["table_frame"], 0, 1 << 20), f"{field}.table_frame", "a table frame number",
              rec["table_frame"])
    if "pass" in rec:
        _need(_is_int(rec["pass"], 1, MAX_PASSES), f"{field}.pass", f"a pass number in 1..{MAX_PASSES}", rec["pass"])
    if "index" in rec:
        _need(_is_int(rec["index"], 0, MAX_STEPS), f"{field}.index", f"an index in 0..{MAX_STEPS}", rec["index"])
    if rec.get("angle_deg") is not None:
        _need(_is_number(rec["angle_deg"]), f"{field}.angle_deg", "an angle in degrees", rec["angle_deg"])
    if "kind" in rec:
        _need(isinstance(rec["kind"], str), f"{field}.kind", "a text", rec["kind"])


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _check_pass(field: str, rec: Any) -> None:
    """A pass record (or a journal operation's fields for one): the numbers capture and processing compute with.

    ``table_frame`` counts the pass's table frames, ``valid_share`` is the share of its profiles that saw
    the object, and ``angle_uncertain_deg`` (older sessions) how far its profiles may be turned.
    """
    _need(isinstance(rec, dict), field, "an object", rec)
    if "table_frame" in rec:
        _need(_is_int(rec["table_frame"], 0, 1 << 20), f"{field}.table_frame", "a table frame number",
              rec["table_frame"])
    if rec.get("valid_share") is not None:
        share = rec["valid_share"]
        _need(_is_number(share) and 0 <= share <= 1, f"{field}.valid_share", "a share between 0 and 1", share)
    if rec.get("angle_uncertain_deg") is not None:
        angle = rec["angle_uncertain_deg"]
        _need(_is_number(angle) and 0 <= angle <= 360, f"{field}.angle_uncertain_deg",
              "an angle in degrees between 0 and 360, or null", angle)


def _check_calibration_ref(key: str, ref: Any) -> None:
    """A calibration's record in the manifest: an object or null, and the fields the window and report show."""
    _need(ref is None or isinstance(ref, dict), key, "an object or null", ref)
    if not isinstance(ref, dict):
        return
    if key == "camera_calibration" and ref.get("source") is not None:   # the scanner's may name a pass: read leniently
        _need(isinstance(ref["source"], dict), f"{key}.source", "an object or null", ref["source"])
        rejected = ref["source"].get("frames_rejected") or []
        _need(isinstance(rejected, list), f"{key}.source.frames_rejected", "a list of frames", rejected)
    if ref.get("image_size") is not None:
        size = ref["image_size"]
        _need(isinstance(size, list) and len(size) == 2 and all(_is_int(n, 1, 1 << 20) for n in size),
              f"{key}.image_size", "[width, height] in pixels", size)
    for name in ("rms_px", "rms_mm", "max_mm"):
        if ref.get(name) is not None:
            _need(_is_number(ref[name]), f"{key}.{name}", "a finite number", ref[name])


def _check_plan(plan: Any) -> None:
    _need(isinstance(plan, dict), "plan", "an object", plan)
    bounds = {"steps": (1, MAX_STEPS), "passes": (1, MAX_PASSES), "chart_frames": (1, 99)}
    for key, (low, high) in bounds.items():
        if plan.get(key) is not None or (key in plan and key != "chart_frames"):   # steps and passes: never null
            _need(_is_int(plan[key], low, high), f"plan.{key}", f"an integer in {low}..{high}", plan[key])
    if "kind" in plan:
        _need(isinstance(plan["kind"], str), "plan.kind", "a text", plan["kind"])
    for key in ("chart", "camera"):
        if key in plan:
            _need(isinstance(plan[key], bool), f"plan.{key}", "true or false", plan[key])
    angles = plan.get("camera_angles_deg", [])
    _need(isinstance(angles, list) and len(angles) <= 1000 and all(
        isinstance(a, (int, float)) and not isinstance(a, bool) for a in angles),
        "plan.camera_angles_deg", "a list of at most 1000 angles in degrees", angles)
    if plan.get("board") is not None:
        board = plan["board"]
        _need(isinstance(board, dict) and len(board) <= 16, "plan.board", "an object (the ChArUco board)", board)
    if plan.get("sphere_radius_mm") is not None:
        r = plan["sphere_radius_mm"]
        _need(isinstance(r, (int, float)) and not isinstance(r, bool) and 0 < r <= 500, "plan.sphere_radius_mm",
              "a radius in (0, 500] mm", r)
    lasers = plan.get("lasers", [])
    _need(isinstance(lasers, list) and len(lasers) <= 16 and all(_is_int(i, 0, 255) for i in lasers),
          "plan.lasers", "a list of at most 16 laser numbers", lasers)


def _check_field(key: str, value: Any) -> None:
    """Check one top-level manifest field; raises :class:`_SchemaError` naming it."""
    if key == "status":
        _need(value in _STATUSES, key, f"one of {', '.join(_STATUSES)}", value)
    elif key in ("created_utc", "updated_utc"):
        _need(isinstance(value, str), key, "a UTC time as text", value)
    elif key in _DICT_FIELDS:
        _need(isinstance(value, dict), key, "an object", value)
        if key == "object":                 # the object's description: texts the window shows and edits
            for name, text in value.items():
                _need(isinstance(text, str), f"object.{name}", "a text", text)
    elif key in ("calibration", "camera_calibration", "lamp_calibration"):
        _check_calibration_ref(key, value)
    elif key == "plan":
        _check_plan(value)
    elif key == "passes":
        _need(isinstance(value, dict) and len(value) <= MAX_PASSES, key,
              f"an object of at most {MAX_PASSES} pass records", value)
        for number, rec in value.items():
            _check_pass(f"passes.{number}", rec)
    elif key == "captures":
        _need(isinstance(value, dict) and len(value) <= MAX_CAPTURES, key,
              f"an object of at most {MAX_CAPTURES} capture records", value)
        for cid, rec in value.items():
            _check_record(f"captures.{cid}", rec)
    elif key == "history":
        _need(isinstance(value, list) and len(value) <= MAX_HISTORY, key,
              f"a list of at most {MAX_HISTORY} entries", value)
        for i, entry in enumerate(value):
            _need(isinstance(entry, dict), f"history[{i}]", "an object", entry)


def _check_manifest(manifest: dict[str, Any]) -> None:
    version = manifest.get("version")
    _need(_is_int(version, 1, 1 << 31), "version", f"an integer in 1..{SCHEMA_VERSION}", version)
    for key in ("passes", "state", "captures"):
        manifest.setdefault(key, {})
    manifest.setdefault("history", [])
    for key, value in manifest.items():
        _check_field(key, value)


def _check_op(op: Any) -> None:
    """Check one journal operation; raises :class:`_SchemaError` naming the faulty field."""
    _need(isinstance(op, dict), "the operation", "an object", op)
    kind = op.get("op")
    _need(kind in _OPS, "op", f"one of {', '.join(_OPS)}", kind)
    if kind == "capture":
        _need(isinstance(op.get("id"), str) and 0 < len(op["id"]) <= 200, "capture id", "a text", op.get("id"))
        _check_record(f"record of capture {op['id']}", op.get("record"))
    elif kind == "pass":
        _need(_is_int(op.get("pass"), 1, MAX_PASSES), "pass", f"an integer in 1..{MAX_PASSES}", op.get("pass"))
        _need(isinstance(op.get("fields"), dict), "pass fields", "an object", op.get("fields"))
        _check_pass(f"passes.{op['pass']}", op["fields"])
    elif kind == "state":
        _need(isinstance(op.get("fields"), dict), "state fields", "an object", op.get("fields"))
    elif kind == "event":
        _need(isinstance(op.get("entry"), dict), "history entry", "an object", op.get("entry"))
    elif kind == "status":
        _check_field("status", op.get("status"))
    else:
        key = op.get("key")
        _need(isinstance(key, str) and key not in _MANAGED, "set key",
              f"a manifest key other than {', '.join(_MANAGED)}", key)
        _need("value" in op, f"set {key}", "given a value", None)
        _check_field(key, op["value"])


def _apply_op(manifest: dict[str, Any], op: dict[str, Any]) -> None:
    kind = op["op"]
    if kind == "capture":
        manifest["captures"][op["id"]] = op["record"]
    elif kind == "pass":
        manifest["passes"].setdefault(str(op["pass"]), {}).update(op["fields"])
    elif kind == "state":
        manifest["state"].update(op["fields"])
    elif kind == "event":
        manifest["history"].append(op["entry"])
    elif kind == "status":
        manifest["status"] = op["status"]
    elif kind == "set":
        manifest[op["key"]] = op["value"]
    else:
        raise KeyError(kind)
