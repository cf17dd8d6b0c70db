"""Paths read from a session's manifest, confined to the session folder.

A session folder is untrusted input (docs/session-format.md): a manifest may
name ``/etc/passwd``, ``../../secret`` or a symlink, and a file in the
session may be a FIFO or a device.  Every consumer that turns a path from
``session.json`` into a file it reads goes through :func:`confined` (the
path) or :func:`read_confined_bytes` (the bytes), which refuse, with one
line naming the manifest field and the file:

* an absolute path, a ``..`` component, a NUL character, an empty name;
* a symlink at any component below the session root (checked with
  ``lstat``, so the link is never followed);
* for reading: a FIFO, a device, a folder, or a file above ``max_bytes``
  (the file is opened with ``O_NOFOLLOW | O_NONBLOCK`` and checked with
  ``fstat``, so a swap between check and open is caught too).

The session root itself may be reached through a symlink (the user chose
it); only what lies below it is checked.

Examples
--------
>>> import tempfile, pathlib
>>> root = pathlib.Path(tempfile.mkdtemp())
>>> _ = (root / "products").mkdir(), (root / "products" / "a.txt").write_bytes(b"hi")
>>> read_confined_bytes(root, "products/a.txt", "products.x.file", 10)
b'hi'
>>> confined(root, "../etc/passwd", "products.x.file")
Traceback (most recent call last):
...
app.session_paths.UnsafeSessionPath: products.x.file: '../etc/passwd' must be a relative path inside the session (no '..', not absolute)
>>> (root / "link").symlink_to(root / "products")
>>> confined(root, "link/a.txt", "products.x.file")   # doctest: +ELLIPSIS
Traceback (most recent call last):
...
app.session_paths.UnsafeSessionPath: products.x.file: 'link/a.txt': ...link is a symlink; a session may not contain symlinks...
"""

from __future__ import annotations

import errno
import os
import stat
from collections.abc import Sequence
from pathlib import Path, PurePosixPath

from processing.errors import InputError

__all__ = ["UnsafeSessionPath", "confined", "confined_file", "read_confined_bytes", "check_not_symlink", "check_destinations",
           "open_log_append", "MAX_PRODUCT_BYTES", "MAX_JSON_BYTES"]

#: Largest product file (an image, a mesh, a report) a consumer reads into memory.
MAX_PRODUCT_BYTES = 512 * 1024 * 1024
#: Largest JSON document (a calibration, a process report, a chart report) a consumer reads.
MAX_JSON_BYTES = 64 * 1024 * 1024


class UnsafeSessionPath(InputError):
    """A manifest path that leaves the session, crosses a symlink, or names something that is not a plain file."""


def _shown(path: Path) -> str:
    """A path as text that cannot fail on non-UTF-8 names."""
    return os.fsdecode(path).encode("utf-8", "backslashreplace").decode("utf-8")


def _relative(rel: object, what: str) -> PurePosixPath:
    if not isinstance(rel, str) or not rel:
        raise UnsafeSessionPath(f"{what}: {rel!r} is not a file name; the manifest is damaged")
    if "\0" in rel:
        raise UnsafeSessionPath(f"{what}: {rel!r} contains a NUL character; the manifest is damaged")
    p = PurePosixPath(rel)
    if p.is_absolute() or rel.startswith("\\") or ".." in p.parts or ".." in rel.split("\\"):
        raise UnsafeSessionPath(f"{what}: {rel!r} must be a relative path inside the session (no '..', not absolute)")
    return p


def confined(root: str | os.PathLike[str], rel: object, what: str) -> Path:
    """``root / rel`` after checking ``rel`` stays inside ``root`` and crosses no symlink.

    Parameters
    ----------
    root
        The session folder.
    rel
        A path read from the manifest (must be a relative POSIX path).
    what
        The manifest field it came from, named in the message (e.g. ``products.mesh.file``).

    Returns
    -------
    Path
        The joined path (it may not exist).

    Raises
    ------
    UnsafeSessionPath
        Absolute, ``..``, NUL, not a string, or a symlink below ``root``.
    """
    base = Path(root)
    parts = _relative(rel, what).parts
    cur = base
    for part in parts:
        if part == ".":
            continue
        cur = cur / part
        try:
            st = os.lstat(cur)
        except FileNotFoundError:
            return base.joinpath(*parts)
        except OSError as exc:
            raise UnsafeSessionPath(f"{what}: {rel!r}: cannot inspect {_shown(cur)}: {exc.strerror or exc}") from None
        if stat.S_ISLNK(st.st_mode):
            raise UnsafeSessionPath(f"{what}: {rel!r}: {_shown(cur)} is a symlink; a session may not contain "
                                    "symlinks (replace it with the file itself)")
    return base.joinpath(*parts)


def _check_regular(st: os.stat_result, path: Path, rel: object, what: str, max_bytes: int) -> None:
    if stat.S_ISDIR(st.st_mode):
        raise UnsafeSessionPath(f"{what}: {rel!r}: {_shown(path)} is a folder, not a file")
    if not stat.S_ISREG(st.st_mode):
        kind = ("a FIFO" if stat.S_ISFIFO(st.st_mode) else "a device" if stat.S_ISCHR(st.st_mode) or
                stat.S_ISBLK(st.st_mode) else "a socket" if stat.S_ISSOCK(st.st_mode) else "not a regular file")
        raise UnsafeSessionPath(f"{what}: {rel!r}: {_shown(path)} is {kind}; a session holds only regular files")
    if st.st_size > max_bytes:
        raise UnsafeSessionPath(f"{what}: {rel!r}: {_shown(path)} has {st.st_size} bytes, more than the "
                                f"{max_bytes} this file may have; the session is damaged")


def confined_file(root: str | os.PathLike[str], rel: object, what: str, max_bytes: int = MAX_PRODUCT_BYTES) -> Path:
    """:func:`confined`, and the path must be an existing regular file of at most ``max_bytes``.

    For consumers that hand the path to a library (a RAW decoder, a mesh
    loader).  ``FileNotFoundError`` (an ``OSError``) if it does not exist.
    """
    path = confined(root, rel, what)
    _check_regular(os.lstat(path), path, rel, what, max_bytes)
    return path


def read_confined_bytes(root: str | os.PathLike[str], rel: object, what: str, max_bytes: int = MAX_PRODUCT_BYTES) -> bytes:
    """The bytes of the session file ``rel`` (see :func:`confined`), refusing anything but a bounded regular file.

    Raises
    ------
    UnsafeSessionPath
        See :func:`confined`; a FIFO, device, socket, folder, or a file above ``max_bytes``.
    OSError
        The file is missing or unreadable (``FileNotFoundError`` if missing).
    """
    path = confined(root, rel, what)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise UnsafeSessionPath(f"{what}: {rel!r}: {_shown(path)} is a symlink; a session may not contain "
                                    "symlinks") from None
        raise
    try:
        _check_regular(os.fstat(fd), path, rel, what, max_bytes)
        chunks = []
        total = 0
        while True:
            chunk = os.read(fd, min(1 << 20, max_bytes + 1 - total))
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
            if total > max_bytes:
                raise UnsafeSessionPath(f"{what}: {rel!r}: {_shown(path)} grew beyond {max_bytes} bytes while read")
        return b"".join(chunks)
    finally:
        os.close(fd)


def check_not_symlink(root: str | os.PathLike[str], rel: str, what: str) -> Path:
    """``root / rel`` for writing: refuse if it (or a folder on the way) is a symlink, a FIFO or a device.

    A missing path is fine (it will be created).
    """
    path = confined(root, rel, what)
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return path
    if not (stat.S_ISREG(st.st_mode) or stat.S_ISDIR(st.st_mode)):
        raise UnsafeSessionPath(f"{what}: {_shown(path)} is not a regular file or folder; remove it")
    return path


def check_destinations(root: str | os.PathLike[str], rels: Sequence[str]) -> None:
    """Refuse, before a job writes anything, any of its destinations that :func:`check_not_symlink` would refuse.

    A job that writes several products checks them all first, so that a refused destination does not leave
    some products of the new run beside others of the old one.
    """
    for rel in rels:
        check_not_symlink(root, rel, rel)


def open_log_append(root: str | os.PathLike[str], rel: str, what: str):
    """A text file at ``root / rel`` opened to append lines (``O_NOFOLLOW | O_APPEND``), line-buffered.

    Refuses a symlink (also one swapped in after the check) or a non-regular file.
    """
    path = check_not_symlink(root, rel, what)
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND | os.O_NOFOLLOW | os.O_NONBLOCK
                     | getattr(os, "O_CLOEXEC", 0), 0o644)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise UnsafeSessionPath(f"{what}: {_shown(path)} is a symlink; a session may not contain symlinks "
                                    "(remove it)") from None
        raise
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise UnsafeSessionPath(f"{what}: {_shown(path)} is not a regular file; remove it")
    except BaseException:
        os.close(fd)
        raise
    return os.fdopen(fd, "a", encoding="utf-8", buffering=1)
