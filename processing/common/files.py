r"""Atomic file writes: a reader (or a crash) sees the old file or the new one, never a part; JSON read safely.

The data go to a temporary file in the target's folder, are flushed and
(``durable=True``) ``fsync``-ed, and the temporary file is renamed over the
target; the folder is then ``fsync``-ed so the rename itself survives a power
cut.  A failure at any point removes the temporary file and leaves the target
as it was.

The written file gets the permissions of any new file (``0o666`` less the
process umask, e.g. ``0o644`` under umask ``022``), like a file written with
:func:`open`: the temporary file is created with mode ``0o666`` and the
kernel applies the umask (and a folder's default ACL), so the umask is never
read or changed (``os.umask`` would change it for every thread).
``tempfile.mkstemp`` would leave ``0o600``, unreadable for the lab's other
users and its web server.

A JSON file kogei reads (a session's manifest, journal and products, a
calibration, a user's file) is untrusted: :func:`parse_json` reads it and
turns every way it can fail -- not UTF-8, not JSON, arrays or objects nested
so deeply that the parser runs out of stack (``RecursionError``) -- into one
:class:`JSONFileError` whose one-line message names the file and the remedy.

Examples
--------
>>> import tempfile, pathlib
>>> p = atomic_write_json(pathlib.Path(tempfile.mkdtemp()) / "a" / "b.json", {"x": 1})
>>> p.read_text()
'{\n  "x": 1\n}\n'
"""

from __future__ import annotations

import hashlib
import json
import os
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from processing.errors import InputError

__all__ = ["fsync_dir", "atomic_path", "atomic_write_bytes", "atomic_write_text", "atomic_write_json", "sha256_file",
           "JSONFileError", "parse_json"]


def fsync_dir(folder: str | os.PathLike[str]) -> None:
    """``fsync`` a folder so a rename inside it is durable.

    Parameters
    ----------
    folder
        The folder.  Filesystems that refuse ``fsync`` on a folder are
        tolerated: the rename is atomic all the same.
    """
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _create_temp(parent: Path, prefix: str, suffix: str) -> tuple[int, Path]:
    """Create a new, empty temporary file in ``parent`` (mode ``0o666`` less the umask); its fd and path."""
    flags = os.O_RDWR | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    for _ in range(100):
        name = parent / f"{prefix}{secrets.token_hex(4)}{suffix}"
        try:
            return os.open(name, flags, 0o666), name
        except FileExistsError:
            continue
    raise FileExistsError(f"no free temporary file name in {parent}")


def _parent(target: Path, make_parents: bool) -> Path:
    """The folder of ``target`` (``.`` for a bare name), created first if ``make_parents``."""
    parent = target.parent if str(target.parent) else Path(".")
    if make_parents:
        parent.mkdir(parents=True, exist_ok=True)
    return parent


@contextmanager
def atomic_path(path: str | os.PathLike[str], *, durable: bool = True, make_parents: bool = True) -> Iterator[Path]:
    """A temporary path beside ``path`` to write by name; renamed over ``path`` when the block ends.

    For writers that take a file name (Open3D, tifffile, Pillow).  If the
    block raises, the temporary file is removed and ``path`` is untouched.

    Parameters
    ----------
    path
        The target file.
    durable
        ``fsync`` the written file and its folder.
    make_parents
        Create the target's folder if it is missing.

    Yields
    ------
    Path
        The temporary file's path (same folder and suffix as ``path``).

    Examples
    --------
    >>> import tempfile, pathlib
    >>> target = pathlib.Path(tempfile.mkdtemp()) / "x.txt"
    >>> with atomic_path(target) as tmp:
    ...     _ = tmp.write_text("done")
    >>> target.read_text()
    'done'
    """
    target = Path(path)
    parent = _parent(target, make_parents)
    fd, tmp = _create_temp(parent, f".{target.name}.", f".tmp{target.suffix}")
    os.close(fd)
    try:
        yield tmp
        if durable:
            with open(tmp, "rb+") as fh:
                os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    if durable:
        fsync_dir(parent)


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes, *, durable: bool = True,
                       make_parents: bool = True) -> Path:
    """Write ``data`` to ``path`` atomically.

    Parameters
    ----------
    path
        The target file.
    data
        The bytes.
    durable
        ``fsync`` the file and its folder (survives a power cut, not only a
        crash).
    make_parents
        Create the target's folder if it is missing.

    Returns
    -------
    Path
        The written file.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = atomic_write_bytes(pathlib.Path(tempfile.mkdtemp()) / "a" / "b.bin", b"xyz")
    >>> p.read_bytes()
    b'xyz'
    """
    target = Path(path)
    parent = _parent(target, make_parents)
    fd, tmp = _create_temp(parent, f".{target.name}.", ".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            if durable:
                os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    if durable:
        fsync_dir(parent)
    return target


def atomic_write_text(path: str | os.PathLike[str], text: str, *, durable: bool = True,
                      make_parents: bool = True) -> Path:
    """Write UTF-8 ``text`` to ``path`` atomically (see :func:`atomic_write_bytes`).

    Parameters
    ----------
    path
        The target file.
    text
        The text.
    durable
        ``fsync`` the file and its folder.
    make_parents
        Create the target's folder if it is missing.

    Returns
    -------
    Path
        The written file.
    """
    return atomic_write_bytes(path, text.encode("utf-8"), durable=durable, make_parents=make_parents)


def atomic_write_json(path: str | os.PathLike[str], obj: Any, *, durable: bool = True,
                      make_parents: bool = True, indent: int | None = 2, sort_keys: bool = False) -> Path:
    """Write ``obj`` as JSON (UTF-8, a final newline) to ``path`` atomically.

    Parameters
    ----------
    path
        The target file.
    obj
        A JSON-serialisable object; NaN and infinity are refused (they are
        not JSON).
    durable
        ``fsync`` the file and its folder.
    make_parents
        Create the target's folder if it is missing.
    indent, sort_keys
        As for :func:`json.dumps`.

    Returns
    -------
    Path
        The written file.
    """
    text = json.dumps(obj, indent=indent, sort_keys=sort_keys, allow_nan=False, ensure_ascii=False) + "\n"
    return atomic_write_text(path, text, durable=durable, make_parents=make_parents)


def sha256_file(path: str | os.PathLike[str]) -> str:
    """Hex SHA-256 of a file's contents, read in 1 MiB blocks.

    Parameters
    ----------
    path
        The file.

    Returns
    -------
    str
        64 hexadecimal digits.
    """
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


class JSONFileError(InputError):
    """A file that should hold JSON and does not (not UTF-8, not JSON, nested too deeply); one line naming it.

    Parameters
    ----------
    message
        The whole one-line message: the file, what is wrong, what to do.
    reason
        What the parser found wrong, alone (``"Expecting value: line 1 column 1 (char 0)"``), for a
        caller that words its own message.
    """

    def __init__(self, message: str, reason: str = "") -> None:
        super().__init__(message)
        self.reason = reason or message

    def __reduce__(self) -> tuple[type[JSONFileError], tuple[str, str]]:
        return type(self), (str(self), self.reason)     # survives pickling (a worker process's error)


def _json_fault(exc: Exception) -> str:
    """What is wrong with a text that did not parse as JSON, in a few words."""
    if isinstance(exc, UnicodeDecodeError):
        return f"not UTF-8 text: {exc.reason} at byte {exc.start}"
    if isinstance(exc, json.JSONDecodeError):
        return str(exc)
    return "arrays or objects nested too deeply to read"


def parse_json(data: bytes | str, what: str | os.PathLike[str], remedy: str) -> Any:
    """The JSON value in ``data`` (a file's bytes, UTF-8, or its text), or a one-line error naming the file.

    Every JSON read from a file goes through here: :func:`json.loads` alone lets a
    document nested 100 000 deep escape as a ``RecursionError`` traceback.

    Parameters
    ----------
    data
        The file's bytes (decoded as UTF-8) or text.
    what
        The file as the message names it (its path, or ``"--board FILE"``).
    remedy
        What the user should do, e.g. ``"restore it from a backup"``.

    Returns
    -------
    Any
        The parsed value (an object, list, text, number, bool or None).

    Raises
    ------
    JSONFileError
        ``"{what} is not JSON kogei can read ({reason}); {remedy}"``, with ``reason`` also as its attribute.

    Examples
    --------
    >>> parse_json(b'{"a": [1, 2]}', "a.json", "write it again")
    {'a': [1, 2]}
    >>> parse_json("[" * 100000 + "]" * 100000, "deep.json", "write it again")
    Traceback (most recent call last):
    ...
    processing.common.files.JSONFileError: deep.json is not JSON kogei can read (arrays or objects nested too deeply to read); write it again
    """
    try:
        return json.loads(data.decode("utf-8") if isinstance(data, (bytes, bytearray)) else data)
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        reason = _json_fault(exc)
    raise JSONFileError(f"{os.fspath(what)} is not JSON kogei can read ({reason}); {remedy}", reason)
