"""Reading an ``.npz`` archive that came from outside (a session, a user's file) without trusting it.

:func:`numpy.load` trusts the archive: it allocates whatever shape an array's
header claims before reading a byte of the data (a 3 kB file can ask for
hundreds of gigabytes), names no file in its errors and advises loading
pickled objects "unsafely".  :func:`read_npz` reads the same archives but
checks, before anything is allocated, that

* the file is a zip archive (else it says what it looks like: empty, text, a
  single ``.npy``, binary);
* every wanted array is there, each member stored or deflated (the
  compressions :func:`numpy.savez` / :func:`numpy.savez_compressed` write)
  and its compressed size inside the file;
* each member's ``.npy`` header declares no Python objects and exactly the
  number of bytes the member holds, and the member's size is possible for
  its compressed size (deflate expands at most about 1032-fold);
* the arrays together fit the memory the caller says is available.

Every failure is one line of the caller's error class naming the file (and
the array) and ending with the caller's remedy.

Examples
--------
>>> import tempfile, os
>>> path = os.path.join(tempfile.mkdtemp(), "a.npz")
>>> np.savez(path, x=np.arange(3))
>>> read_npz(path, ("x",), what="a test file", remedy="write it again")["x"].tolist()
[0, 1, 2]
"""

from __future__ import annotations

import math
import os
import zipfile
import zlib
from collections.abc import Sequence
from typing import IO, Any

import numpy as np
from numpy.typing import NDArray

from processing.errors import InputError

__all__ = ["read_npz"]

#: First bytes of a zip archive (an ``.npz`` is one: local file header, or the end record of an empty one).
_ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")

#: The most deflate can expand: 1032 bytes out per byte in, plus a little slack for tiny members.
_DEFLATE_RATIO, _DEFLATE_SLACK = 1032, 1024


def read_npz(path: str | os.PathLike[str], keys: Sequence[str] | None = None, *, what: str, remedy: str,
             error: type[Exception] = InputError, available_bytes: int | None = None,
             memory_remedy: str = "free memory and try again") -> dict[str, NDArray[Any]]:
    """The arrays of an untrusted ``.npz``, each checked against its member before it is allocated.

    Parameters
    ----------
    path
        The archive.
    keys
        The arrays wanted (all must be there); None: every ``.npy`` member.
    what
        What the file should be, for messages ("a kogei spectral result file").
    remedy
        What the user should do, ending every message ("write it with ...").
    error
        The exception class raised (called with the one-line message).
    available_bytes
        Memory the arrays may take together; None: not checked (a :class:`MemoryError`
        while reading is still turned into ``error``).
    memory_remedy
        What to do when the arrays do not fit ``available_bytes``.

    Returns
    -------
    dict
        Array name (without ``.npy``) -> array.

    Raises
    ------
    Exception
        ``error``, one line naming ``path`` (and the array) and ending with ``remedy``.
    """
    shown = os.fspath(path)
    _check_magic(shown, what, remedy, error)
    try:
        with zipfile.ZipFile(shown) as zf:
            infos = _members(shown, zf, keys, what, remedy, error)
            size = os.path.getsize(shown)
            for key, info in infos.items():
                _check_stored_size(shown, key, info, size, remedy, error)
            need = sum(info.file_size for info in infos.values())
            if available_bytes is not None and need > available_bytes:
                raise error(f"{shown}: its arrays need {need / 1e9:.1f} GB of memory but "
                            f"{available_bytes / 1e9:.1f} GB is available; {memory_remedy}")
            return {key: _read_member(shown, zf, info, key, remedy, error, memory_remedy)
                    for key, info in infos.items()}
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, NotImplementedError, RuntimeError) as exc:
        raise error(f"{shown}: a damaged .npz archive ({exc}); {remedy}") from None


def _check_magic(path: str, what: str, remedy: str, error: type[Exception]) -> None:
    """Refuse a file that is not a zip archive, saying what it looks like instead."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(512)
    except OSError as exc:
        raise error(f"{path}: cannot be read ({exc.strerror or exc}); {remedy}") from None
    if head.startswith(_ZIP_MAGIC):
        return
    if not head:
        kind = "an empty file"
    elif head.startswith(b"\x93NUMPY"):
        kind = "a single NumPy array (.npy)"
    elif all(32 <= b < 127 or b in b"\t\r\n" for b in head):
        kind = "a text file"
    else:
        kind = "not a zip archive"
    raise error(f"{path}: not {what} ({kind}, not an .npz archive); {remedy}")


def _members(path: str, zf: zipfile.ZipFile, keys: Sequence[str] | None, what: str, remedy: str,
             error: type[Exception]) -> dict[str, zipfile.ZipInfo]:
    """Array name -> zip member of the arrays wanted; refuses an archive that lacks one."""
    members = {info.filename: info for info in zf.infolist()}
    arrays = {name[:-4]: info for name, info in members.items() if name.endswith(".npy")}
    if not arrays:
        raise error(f"{path}: a zip archive of no NumPy arrays, not {what}; {remedy}")
    if keys is None:
        return arrays
    missing = [k for k in keys if k not in arrays]
    if missing:
        raise error(f"{path}: not {what}, missing {', '.join(missing)}; {remedy}")
    return {k: arrays[k] for k in keys}


def _check_stored_size(path: str, key: str, info: zipfile.ZipInfo, size: int, remedy: str,
                       error: type[Exception]) -> None:
    """Refuse a member whose sizes in the zip directory are impossible for the file that holds it."""
    where = f"{path}: array {key!r}"
    if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
        raise error(f"{where} is compressed with method {info.compress_type}, which kogei does not read "
                    f"(only stored or deflated members); {remedy}")
    if info.header_offset + info.compress_size > size:
        raise error(f"{where}: the zip directory claims {info.compress_size} bytes at offset "
                    f"{info.header_offset} but the file has {size}; {remedy}")
    most = info.compress_size if info.compress_type == zipfile.ZIP_STORED else \
        _DEFLATE_RATIO * info.compress_size + _DEFLATE_SLACK
    if info.file_size > most:
        raise error(f"{where}: the zip directory claims {info.file_size} bytes in {info.compress_size} "
                    f"stored bytes, more than they can hold; {remedy}")


def _read_member(path: str, zf: zipfile.ZipFile, info: zipfile.ZipInfo, key: str, remedy: str,
                 error: type[Exception], memory_remedy: str) -> NDArray[Any]:
    """One ``.npy`` member: its header checked (no objects, size matching the member) before the data is read."""
    fmt = np.lib.format
    where = f"{path}: array {key!r}"
    try:
        with zf.open(info) as fh:
            shape, dtype, header = _header(fh, where, remedy, error)
        if dtype.hasobject:
            raise error(f"{where} holds Python objects (pickled data), which kogei never writes, so it is "
                        f"not read; {remedy}")
        expected = header + math.prod(shape) * dtype.itemsize
        if any(n < 0 for n in shape) or expected != info.file_size:
            raise error(f"{where}: its header declares shape {shape} of {dtype} ({expected} bytes) "
                        f"but the member holds {info.file_size} bytes; {remedy}")
        with zf.open(info) as fh:
            return fmt.read_array(fh, allow_pickle=False)
    except MemoryError:
        raise error(f"{where}: its {info.file_size / 1e9:.1f} GB do not fit in the free memory; "
                    f"{memory_remedy}") from None
    except ValueError as exc:
        if isinstance(exc, error):
            raise
        raise error(f"{where}: not a valid .npy array ({exc}); {remedy}") from None


def _header(fh: IO[bytes], where: str, remedy: str, error: type[Exception]) -> tuple[tuple[int, ...], np.dtype[Any], int]:
    """Shape, dtype and header length of the ``.npy`` at the start of ``fh`` (format 1.0 or 2.0)."""
    fmt = np.lib.format
    version = fmt.read_magic(fh)
    if version not in ((1, 0), (2, 0)):
        raise error(f"{where}: .npy format version {version} is not one kogei writes; {remedy}")
    reader = fmt.read_array_header_1_0 if version == (1, 0) else fmt.read_array_header_2_0
    shape, _, dtype = reader(fh)
    return tuple(shape), dtype, fh.tell()
