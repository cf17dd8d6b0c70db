"""A camera seen through a hot folder, and moving files into a session without losing them.

Tethering programs (the camera maker's utility, darktable, Lightroom, a
gphoto2 loop) write each new RAW frame into a watched folder.  A file being
written is visible before it is complete, so :class:`HotFolderCamera` takes a
new RAW file only when its size (and modification time) has not changed for
``stable_s`` seconds, then moves it into the session with
:func:`move_file_atomic`:

* same filesystem: ``os.replace`` (a rename: atomic, the file is either in
  the folder or in the session);
* another filesystem (``EXDEV``): copy to a temporary file in the
  destination folder, ``fsync`` it, rename it to the final name, ``fsync``
  the folder, and only then remove the source.

A TIFF-based RAW file (DNG, NEF, CR2, ARW) whose size is stable but whose
image data ends past the end of the file (a writer that stopped mid-write)
is not taken either (:func:`tiff_complete`).

A crash at any point leaves the frame in the hot folder, in the session, or
both (never neither); an existing destination is never overwritten.

Examples
--------
>>> import tempfile, pathlib
>>> src = pathlib.Path(tempfile.mkdtemp()) / "a.dng"
>>> _ = src.write_bytes(b"raw")
>>> dst = move_file_atomic(src, pathlib.Path(tempfile.mkdtemp()) / "frame.dng")
>>> dst.read_bytes(), src.exists()
(b'raw', False)
"""

from __future__ import annotations

import errno
import os
import shutil
import stat
import struct
import tempfile
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

from drivers.camera_errors import (
    CameraConfigError,
    CameraFileExistsError,
    CameraTimeoutError,
    CameraTransferError,
)

__all__ = [
    "RAW_EXTENSIONS",
    "HotFolderCamera",
    "move_file_atomic",
    "check_capture_name",
    "tiff_complete",
    "raw_format_problem",
]

#: File name endings taken as RAW frames (case-insensitive).
RAW_EXTENSIONS: tuple[str, ...] = (".dng", ".cr2", ".cr3", ".nef", ".arw", ".raf", ".orf", ".rw2", ".pef")


def check_capture_name(name: str) -> str:
    """``name`` if it is a usable file stem for a capture, else a :class:`CameraConfigError`.

    Examples
    --------
    >>> check_capture_name("pass1_step003")
    'pass1_step003'
    """
    if not isinstance(name, str) or not name or name in (".", "..") or "/" in name or "\\" in name \
            or "\x00" in name or name.startswith("."):
        raise CameraConfigError(
            f"capture name {name!r} is not a plain file stem; use letters, digits, '-' and '_' "
            "(no folders, no leading dot)"
        )
    return name


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def move_file_atomic(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> Path:
    """Move ``src`` to ``dst`` so that the file is never lost and never half-written at ``dst``.

    Parameters
    ----------
    src
        The file to move.
    dst
        Its new path; the folder must exist and the file must not.

    Returns
    -------
    Path
        ``dst``.

    Raises
    ------
    CameraFileExistsError
        ``dst`` exists (nothing is changed).
    CameraTransferError
        The move failed (``src`` is kept; no partial ``dst`` is left).
    """
    source, target = Path(src), Path(dst)
    if not target.parent.is_dir():
        raise CameraTransferError(
            f"cannot move {source} into {target.parent}: the folder does not exist; create the session folder first",
            folder=str(target.parent),
        )
    if target.exists():
        raise CameraFileExistsError(
            f"{target} already exists; captures are never overwritten, choose another capture name",
            folder=str(target.parent),
        )
    try:
        os.replace(source, target)
        _fsync_dir(target.parent)
        return target
    except OSError as exc:
        if exc.errno != errno.EXDEV:
            raise CameraTransferError(
                f"cannot move {source} to {target}: {exc.strerror or exc}; the file stays in {source.parent}",
                folder=str(source.parent),
            ) from exc
    # another filesystem: copy to a temporary file next to the target, fsync, rename, remove source
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".part", dir=target.parent)
    try:
        with os.fdopen(fd, "wb") as out, open(source, "rb") as inp:
            shutil.copyfileobj(inp, out, 1 << 20)
            out.flush()
            os.fsync(out.fileno())
        if os.path.getsize(tmp) != os.path.getsize(source):
            raise OSError(errno.EIO, "size of the copy differs from the source")
        if target.exists():
            raise CameraFileExistsError(
                f"{target} appeared while copying; captures are never overwritten, choose another capture name",
                folder=str(target.parent),
            )
        os.replace(tmp, target)
        _fsync_dir(target.parent)
    except CameraFileExistsError:
        os.unlink(tmp)
        raise
    except OSError as exc:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise CameraTransferError(
            f"cannot copy {source} to {target}: {exc.strerror or exc}; the file stays in {source.parent}",
            folder=str(source.parent),
        ) from exc
    try:
        os.unlink(source)
    except FileNotFoundError:
        pass
    return target


_TIFF_TYPE_SIZE = {1: 1, 2: 1, 3: 2, 4: 4, 5: 8, 6: 1, 7: 1, 8: 2, 9: 4, 10: 8, 11: 4, 12: 8, 13: 4}


def tiff_complete(path: str | os.PathLike[str]) -> bool | None:
    """Whether a TIFF-based RAW file (DNG, NEF, CR2, ARW, ...) holds all the image data it declares.

    Reads the first IFD and its SubIFDs (tag 330) and checks that every
    strip or tile (tags 273/279, 324/325) ends inside the file, so a file
    cut short by a writer that stopped is recognised even when its size no
    longer changes.

    Returns
    -------
    bool or None
        True when complete, False when truncated or unreadable, None when
        the file is not TIFF-based (e.g. CR3) and cannot be checked.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "x.cr3"
    >>> _ = p.write_bytes(b"not a tiff")
    >>> tiff_complete(p) is None
    True
    """
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except OSError:
        return False
    size = len(data)
    if size < 8 or data[:4] not in (b"II*\x00", b"MM\x00*"):
        return None
    order = "<" if data[:2] == b"II" else ">"

    def read(fmt: str, at: int) -> tuple:
        n = struct.calcsize(order + fmt)
        if at < 0 or at + n > size:
            raise ValueError("outside the file")
        return struct.unpack_from(order + fmt, data, at)

    def values(typ: int, count: int, field: int) -> list[int]:
        width = _TIFF_TYPE_SIZE.get(typ, 1)
        at = field if width * count <= 4 else read("I", field)[0]
        code = {3: "H", 4: "I", 13: "I"}.get(typ)
        if code is None:
            return []
        return list(read(f"{count}{code}", at))

    try:
        pending = [read("I", 4)[0]]
        visited = 0
        while pending and visited < 16:
            ifd = pending.pop()
            visited += 1
            (count,) = read("H", ifd)
            tags: dict[int, list[int]] = {}
            for i in range(count):
                tag, typ, n = read("HHI", ifd + 2 + 12 * i)
                if tag in (273, 279, 324, 325, 330):
                    tags[tag] = values(typ, n, ifd + 2 + 12 * i + 8)
            pending.extend(tags.get(330, []))
            for off_tag, len_tag in ((273, 279), (324, 325)):
                offsets, lengths = tags.get(off_tag, []), tags.get(len_tag, [])
                if len(offsets) != len(lengths):
                    return False
                if any(o + n > size for o, n in zip(offsets, lengths)):
                    return False
    except (ValueError, struct.error):
        return False
    return True


#: RAW endings that are TIFF files (their header must be a TIFF header and their strips complete).
TIFF_RAW_EXTENSIONS: tuple[str, ...] = (".dng", ".nef", ".nrw", ".cr2", ".arw", ".srf", ".sr2", ".pef", ".srw",
                                        ".tif", ".tiff")

#: The leading bytes of the RAW formats that are not plain TIFF (offset, accepted magics).
_OTHER_MAGIC: dict[str, tuple[int, tuple[bytes, ...]]] = {
    ".cr3": (4, (b"ftyp",)),
    ".raf": (0, (b"FUJIFILM",)),
    ".orf": (0, (b"IIRO", b"IIRS", b"MMOR")),
    ".rw2": (0, (b"IIU\x00",)),
}


def raw_format_problem(path: str | os.PathLike[str]) -> str | None:
    """Why the file at ``path`` is not the RAW format its ending claims, or None if it looks right.

    TIFF-based formats (DNG, NEF, CR2, ARW, PEF, ...) need the TIFF header
    magic (``II*\\0`` or ``MM\\0*``) and a first IFD whose image data ends
    inside the file (:func:`tiff_complete`); CR3, RAF, ORF and RW2 need
    their own leading bytes.  Other endings are not checked.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "capt0000.dng"
    >>> _ = p.write_bytes(b"garbage!")
    >>> raw_format_problem(p)
    "capt0000.dng is not a DNG file: it starts with b'garbage!', not a TIFF header"
    """
    path = Path(path)
    ext = path.suffix.lower()
    kind = ext.lstrip(".").upper()
    try:
        if not stat.S_ISREG(path.lstat().st_mode):
            return f"{path.name} is not a regular file (a symbolic link, a folder or a device)"
        with open(path, "rb") as fh:
            head = fh.read(16)
    except OSError as exc:
        return f"{path.name} cannot be read: {exc.strerror or exc}"
    if not head:
        return f"{path.name} is empty"
    if ext in TIFF_RAW_EXTENSIONS:
        if head[:4] not in (b"II*\x00", b"MM\x00*"):
            return f"{path.name} is not a {kind} file: it starts with {head[:8]!r}, not a TIFF header"
        if tiff_complete(path) is not True:
            return f"{path.name} is a truncated or damaged {kind} file (its TIFF directory or image data is cut)"
        return None
    if ext in _OTHER_MAGIC:
        at, magics = _OTHER_MAGIC[ext]
        if not any(head[at:at + len(m)] == m for m in magics):
            return f"{path.name} is not a {kind} file: it starts with {head[:8]!r}"
    return None


@dataclass
class _Seen:
    size: int
    mtime_ns: int
    changed_at: float


class HotFolderCamera:
    """Frames from a folder that a tethering program fills.

    Files already in the folder when the camera is created are left alone
    (they belong to someone else) unless ``include_existing``; every later RAW file is taken once, in
    the order of their modification times.  Symbolic links are never taken.

    Parameters
    ----------
    folder
        The watched folder (must exist).
    dest_dir
        Where frames are moved (created if missing).
    extensions
        RAW file endings, case-insensitive.
    stable_s
        Seconds a file's size and modification time must stay unchanged
        before it is taken (> 0; raise it for slow network shares).
    timeout_s
        Seconds :meth:`wait_for_new` waits before giving up (> 0).
    poll_s
        Seconds between folder scans (> 0).
    include_existing
        Also take RAW files already in the folder (e.g. resuming after a
        crash between the tethering program's write and the move).
    clock, sleep
        Time source and sleep function (for tests).

    Examples
    --------
    >>> import tempfile, pathlib
    >>> hot, dest = pathlib.Path(tempfile.mkdtemp()), pathlib.Path(tempfile.mkdtemp())
    >>> cam = HotFolderCamera(hot, dest, stable_s=0.05, timeout_s=2.0, poll_s=0.01)
    >>> _ = (hot / "IMG_0001.DNG").write_bytes(b"x" * 100)
    >>> cam.wait_for_new("frame_000").name
    'frame_000.dng'
    """

    def __init__(
        self,
        folder: str | os.PathLike[str],
        dest_dir: str | os.PathLike[str],
        extensions: Iterable[str] = (".dng", ".cr2", ".nef", ".arw"),
        stable_s: float = 1.0,
        timeout_s: float = 60.0,
        poll_s: float = 0.1,
        *,
        include_existing: bool = False,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise CameraConfigError(
                f"hot folder {self.folder} does not exist or is not a folder; create it or point the "
                "tethering program and this driver at the same existing folder",
                folder=str(self.folder),
            )
        self.dest_dir = Path(dest_dir)
        exts = tuple(e.lower() if e.startswith(".") else "." + e.lower() for e in extensions)
        if not exts:
            raise CameraConfigError("extensions is empty; give at least one RAW ending such as '.dng'")
        self.extensions = exts
        for what, value in (("stable_s", stable_s), ("timeout_s", timeout_s), ("poll_s", poll_s)):
            if not (isinstance(value, (int, float)) and not isinstance(value, bool) and value > 0
                    and value < float("inf")):
                raise CameraConfigError(f"{what} must be a positive number of seconds, got {value!r}")
        self.stable_s = float(stable_s)
        self.timeout_s = float(timeout_s)
        self.poll_s = float(poll_s)
        self._clock = clock
        self._sleep = sleep
        self._ignored: set[str] = set() if include_existing else set(self._raw_names())
        self._seen: dict[str, _Seen] = {}
        self._incomplete: set[str] = set()

    def _raw_names(self) -> list[str]:
        try:
            entries = list(os.scandir(self.folder))
        except FileNotFoundError:
            raise CameraConfigError(
                f"hot folder {self.folder} disappeared; reconnect the share or recreate the folder",
                folder=str(self.folder),
            ) from None
        return [
            e.name for e in entries
            if not e.name.startswith(".") and e.name.lower().endswith(self.extensions)
            and e.is_file(follow_symlinks=False)
        ]

    def pending(self) -> list[Path]:
        """New RAW files in the folder not yet taken (complete or not), oldest first."""
        names = [n for n in self._raw_names() if n not in self._ignored]
        paths = [self.folder / n for n in names]
        return sorted(paths, key=lambda p: (p.stat().st_mtime_ns if p.exists() else 0, p.name))

    def _scan(self, now: float) -> list[Path]:
        """Update the size history; return the stable files, oldest first."""
        stable = []
        current = set()
        for path in self.pending():
            try:
                st = path.stat()
            except FileNotFoundError:
                continue
            current.add(path.name)
            seen = self._seen.get(path.name)
            if seen is None or seen.size != st.st_size or seen.mtime_ns != st.st_mtime_ns:
                self._seen[path.name] = _Seen(st.st_size, st.st_mtime_ns, now)
            elif st.st_size > 0 and now - seen.changed_at >= self.stable_s:
                if tiff_complete(path) is False:
                    self._incomplete.add(path.name)
                else:
                    self._incomplete.discard(path.name)
                    stable.append(path)
        for gone in set(self._seen) - current:
            del self._seen[gone]
            self._incomplete.discard(gone)
        return stable

    def wait_for_new(self, name: str) -> Path:
        """Wait for the next new RAW file with a stable size and move it to ``dest_dir/<name><ext>``.

        Parameters
        ----------
        name
            File stem of the capture in the destination; the RAW file's
            ending (lower case) is kept.

        Returns
        -------
        Path
            The frame in ``dest_dir``.

        Raises
        ------
        CameraTimeoutError
            No new RAW file became stable within ``timeout_s`` (the message
            says whether a file was still growing: a partial write).
        CameraFileExistsError, CameraTransferError
            See :func:`move_file_atomic`; the file stays in the hot folder.
        """
        check_capture_name(name)
        self.dest_dir.mkdir(parents=True, exist_ok=True)
        start = self._clock()
        while True:
            now = self._clock()
            stable = self._scan(now)
            if stable:
                src = stable[0]
                dst = self.dest_dir / f"{name}{src.suffix.lower()}"
                moved = move_file_atomic(src, dst)
                self._seen.pop(src.name, None)
                return moved
            if now - start >= self.timeout_s:
                break
            self._sleep(self.poll_s)
        cut = sorted(self._incomplete)
        if cut:
            names = ", ".join(f"{n} ({self._seen[n].size} bytes)" for n in cut if n in self._seen)
            raise CameraTimeoutError(
                f"hot folder {self.folder}: {names} stopped growing but is an incomplete RAW file (its image "
                f"data ends past the end of the file); it was not taken and is left in place. The tethering "
                "program probably stopped mid-write: delete the partial file and capture again",
                folder=str(self.folder),
            )
        growing = sorted(self._seen)
        if growing:
            sizes = ", ".join(f"{n} ({self._seen[n].size} bytes)" for n in growing)
            raise CameraTimeoutError(
                f"hot folder {self.folder}: {sizes} did not reach a stable size for {self.stable_s:g} s "
                f"within {self.timeout_s:g} s; the tethering program may have stopped mid-write (a partial "
                "file is never taken): check the camera connection and the program, then capture again",
                folder=str(self.folder),
            )
        raise CameraTimeoutError(
            f"hot folder {self.folder}: no new RAW file ({', '.join(self.extensions)}) appeared within "
            f"{self.timeout_s:g} s; check that the tethering program saves into this folder and that the "
            "camera fired",
            folder=str(self.folder),
        )
