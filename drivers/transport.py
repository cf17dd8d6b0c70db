"""Serial byte transport with read deadlines and a wire log.

A device driver takes a transport (as in
pyserial, the link is swappable), every read has a deadline, binary protocols
resynchronise on garbage, and both directions of the wire are logged into the
session.  The port is opened with :func:`serial.serial_for_url`, so a device
path (``/dev/ttyUSB0``, a pseudo-terminal ``/dev/pts/N`` or a symlink to
one) and any pyserial URL (``loop://``, ``socket://host:port``) work.

Wire log format (one line per message, flushed per line so a crash keeps
it)::

    2025-01-31T10:15:02.123456Z turntable > G1 X90.000\\r\\n
    2025-01-31T10:15:03.456789Z turntable < ok

``>`` is sent, ``<`` received; bytes outside printable ASCII are written as
``\\r``, ``\\n``, ``\\t``, ``\\\\`` or ``\\xNN``.

Examples
--------
>>> t = SerialTransport("loop://", wire_log=None)
>>> t.write(b"ok\\r\\n")
>>> t.read_line(1.0)
b'ok'
>>> t.close()
"""

from __future__ import annotations

import datetime as dt
import errno
import os
import stat
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, NoReturn

import serial

from drivers.errors import TransportClosed, TransportTimeout

__all__ = ["escape_bytes", "WireLog", "Frame", "SerialTransport"]

_PRINTABLE = {i: chr(i) for i in range(0x20, 0x7F)}
_PRINTABLE[0x5C] = "\\\\"
_PRINTABLE.update({0x0D: "\\r", 0x0A: "\\n", 0x09: "\\t"})


def escape_bytes(data: bytes) -> str:
    """Printable form of ``data`` for the wire log.

    Parameters
    ----------
    data
        Raw bytes.

    Returns
    -------
    str
        Printable ASCII kept, ``\\r \\n \\t \\\\`` escaped, others as ``\\xNN``.

    Examples
    --------
    >>> escape_bytes(b"ok\\r\\n\\x18\\xff")
    'ok\\\\r\\\\n\\\\x18\\\\xff'
    """
    return "".join(_PRINTABLE.get(b) or f"\\x{b:02x}" for b in data)


def _open_append(path: Path) -> IO[str]:
    """Open ``path`` for appending without following a symbolic link (the file or its folder).

    A link, a FIFO, a device or any other non-regular file is refused with a
    ``ValueError`` naming it: a log never writes outside where it was put.
    """
    links = "; kogei never follows links in a session: remove the link and try again"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"wire_log: cannot create the folder of {str(path)!r}: {exc}") from exc
    if path.parent.is_symlink():
        raise ValueError(f"wire_log: the folder {str(path.parent)!r} is a symbolic link{links}")
    flags = (os.O_WRONLY | os.O_APPEND | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0)
             | getattr(os, "O_CLOEXEC", 0))
    try:
        fd = os.open(path, flags, 0o666)
    except OSError as exc:
        if exc.errno == errno.ELOOP or path.is_symlink():
            raise ValueError(f"wire_log: {str(path)!r} is a symbolic link{links}") from None
        raise ValueError(f"wire_log: cannot open {str(path)!r} for appending: {exc}") from exc
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise ValueError(f"wire_log: {str(path)!r} is not a regular file; remove it and try again")
    return os.fdopen(fd, "a", encoding="ascii", buffering=1)


class WireLog:
    """Append-only, line-flushed log of the bytes on one or more links.

    Parameters
    ----------
    path
        File to append to (created with its parent folders); a symbolic link,
        a link as its folder, or a non-regular file is refused (``ValueError``).

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "wire.log"
    >>> with WireLog(p) as log:
    ...     log.record("tt", ">", b"G50\\r\\n")
    >>> p.read_text().split(" ", 1)[1]
    'tt > G50\\\\r\\\\n\\n'
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self._fh: IO[str] | None = _open_append(self.path)
        self._lock = threading.Lock()

    def record(self, label: str, direction: str, data: bytes) -> None:
        """Append one timestamped line (``direction`` is ``'>'`` or ``'<'``)."""
        stamp = dt.datetime.now(dt.UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")
        line = f"{stamp} {label} {direction} {escape_bytes(data)}\n"
        with self._lock:
            if self._fh is not None:
                self._fh.write(line)
                self._fh.flush()

    def note(self, label: str, text: str) -> None:
        """Append a ``#`` comment line (reconnects, resynchronisation)."""
        self.record(label, "#", text.encode("ascii", "backslashreplace"))

    def close(self) -> None:
        """Close the file (further records are dropped)."""
        with self._lock:
            if self._fh is not None:
                self._fh.close()
                self._fh = None

    def __enter__(self) -> WireLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass(frozen=True)
class Frame:
    """A binary frame returned by :meth:`SerialTransport.read_frame`.

    Attributes
    ----------
    data
        The whole frame, magic first.
    skipped
        Bytes discarded before the magic while resynchronising.
    """

    data: bytes
    skipped: bytes


class SerialTransport:
    """A serial port (or pyserial URL) with deadlines on every read.

    Parameters
    ----------
    url_or_path
        Device path or pyserial URL (``loop://``, ``socket://host:port``).
    baudrate
        Bits per second (8N1 framing unless ``bytesize/parity/stopbits`` say
        otherwise).
    bytesize, parity, stopbits
        Character framing, as in pyserial.
    write_timeout_s
        Seconds a write may block before the port counts as gone.
    poll_s
        Internal blocking granularity of reads (seconds); a read never waits
        past its own deadline by more than this.
    wire_log
        ``None``, a file path (opened in append mode) or a shared
        :class:`WireLog`.
    label
        Name of this link in the wire log (default: the port's file name).
    open
        Open the port now (default) or later with :meth:`open`.

    Notes
    -----
    One owner thread per transport; the buffer is not locked.
    """

    def __init__(
        self,
        url_or_path: str | os.PathLike[str],
        baudrate: int = 115200,
        *,
        bytesize: int = 8,
        parity: str = "N",
        stopbits: float = 1,
        write_timeout_s: float = 2.0,
        poll_s: float = 0.05,
        wire_log: str | os.PathLike[str] | WireLog | None = None,
        label: str | None = None,
        open: bool = True,
    ) -> None:
        self.url = os.fspath(url_or_path)
        if not self.url:
            raise ValueError("url_or_path is empty: give a device path such as /dev/ttyUSB0 or a pyserial URL")
        if not isinstance(baudrate, int) or baudrate <= 0:
            raise ValueError(f"baudrate must be a positive integer (e.g. 115200), got {baudrate!r}")
        if not poll_s > 0 or not write_timeout_s > 0:
            raise ValueError("poll_s and write_timeout_s must be positive seconds")
        self.baudrate = baudrate
        self._framing = dict(bytesize=bytesize, parity=parity, stopbits=stopbits)
        self._write_timeout_s = float(write_timeout_s)
        self._poll_s = float(poll_s)
        self.label = label or (self.url.rstrip("/").rsplit("/", 1)[-1] or self.url)
        self._owns_log = not isinstance(wire_log, WireLog) and wire_log is not None
        self.wire_log: WireLog | None = (
            wire_log if isinstance(wire_log, WireLog) or wire_log is None else WireLog(wire_log)
        )
        self._port: serial.SerialBase | None = None
        self._buf = bytearray()
        if open:
            self.open()

    # ------------------------------------------------------------------ state
    @property
    def is_open(self) -> bool:
        """True while the port is open and has not failed."""
        return self._port is not None

    def open(self) -> None:
        """Open the port; :class:`TransportClosed` if it is not there."""
        if self._port is not None:
            return
        try:
            self._port = serial.serial_for_url(
                self.url, baudrate=self.baudrate, timeout=self._poll_s,
                write_timeout=self._write_timeout_s, **self._framing,
            )
        except ValueError as exc:
            raise ValueError(f"port {self.url!r}: invalid serial settings: {exc}") from exc
        except (serial.SerialException, OSError) as exc:
            raise TransportClosed(self.url, f"cannot open port ({exc}); check the cable and the path "
                                            "(`kogei devices` lists the ports)") from exc
        self._buf.clear()
        self._note("opened")

    def close(self) -> None:
        """Close the port (idempotent); unread buffered bytes are logged."""
        port, self._port = self._port, None
        if self._buf:
            self._log("<", bytes(self._buf))
            self._buf.clear()
        if port is not None:
            try:
                port.close()
            except (serial.SerialException, OSError):
                pass
            self._note("closed")

    def close_log(self) -> None:
        """Close the wire log if this transport opened it."""
        if self._owns_log and self.wire_log is not None:
            self.wire_log.close()

    def reopen(self, timeout_s: float = 0.0, retry_s: float = 0.1) -> None:
        """Close and open the port again, retrying until ``timeout_s`` passes.

        Use after :class:`TransportClosed`: a USB device that was unplugged
        comes back under the same path (or the same stable symlink).
        """
        self.close()
        end = time.monotonic() + max(0.0, timeout_s)
        while True:
            try:
                self.open()
                return
            except TransportClosed:
                if time.monotonic() >= end:
                    raise
                time.sleep(retry_s)

    def __enter__(self) -> SerialTransport:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
        self.close_log()

    # ------------------------------------------------------------------ I/O
    def write(self, data: bytes) -> None:
        """Send ``data``; :class:`TransportClosed` if the port is gone."""
        port = self._require_open()
        self._log(">", data)
        try:
            port.write(data)
        except serial.SerialTimeoutException as exc:
            self._fail(f"write of {len(data)} bytes blocked for {self._write_timeout_s} s ({exc})")
        except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
            self._fail(f"write failed ({exc})")

    def reset_input(self) -> None:
        """Discard everything received so far (logged as received)."""
        port = self._require_open()
        try:
            n = port.in_waiting
            if n:
                self._buf += port.read(n)
        except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
            self._fail(f"read failed ({exc})")
        if self._buf:
            self._log("<", bytes(self._buf))
            self._buf.clear()

    def read_line(self, deadline_s: float, *, max_len: int = 4096) -> bytes:
        """Next line without its ``\\r``/``\\n`` terminator.

        Parameters
        ----------
        deadline_s
            Seconds from now to wait at most.
        max_len
            A run of this many bytes without a newline is returned as a line
            (garbage on the wire must not block the reader forever).

        Raises
        ------
        TransportTimeout
            No complete line within ``deadline_s``.
        TransportClosed
            The port vanished.
        """
        end = time.monotonic() + deadline_s
        while True:
            i = self._buf.find(b"\n")
            if i >= 0 or len(self._buf) >= max_len:
                cut = i + 1 if i >= 0 else max_len
                raw = bytes(self._buf[:cut])
                del self._buf[:cut]
                self._log("<", raw)
                return raw.rstrip(b"\r\n")
            if time.monotonic() >= end:
                raise TransportTimeout(self.url, f"no complete line within {deadline_s:.3g} s",
                                       bytes(self._buf))
            self._fill(end)

    def read_exact(self, n: int, deadline_s: float) -> bytes:
        """Exactly ``n`` bytes, or :class:`TransportTimeout` after ``deadline_s`` s."""
        if n < 0:
            raise ValueError(f"n must be >= 0, got {n}")
        end = time.monotonic() + deadline_s
        while len(self._buf) < n:
            if time.monotonic() >= end:
                raise TransportTimeout(self.url, f"only {len(self._buf)} of {n} bytes within {deadline_s:.3g} s",
                                       bytes(self._buf))
            self._fill(end)
        data = bytes(self._buf[:n])
        del self._buf[:n]
        self._log("<", data)
        return data

    def read_frame(
        self,
        magic: bytes,
        header_size: int,
        frame_size: Callable[[bytes], int],
        deadline_s: float,
    ) -> Frame:
        """A binary frame that starts with ``magic``, resynchronising on garbage.

        Parameters
        ----------
        magic
            Start-of-frame marker (non-empty).
        header_size
            Bytes (including ``magic``) needed before the total size is known.
        frame_size
            Maps the header to the total frame size in bytes; raising
            ValueError marks a false magic match (the search continues one
            byte further).
        deadline_s
            Seconds from now to wait at most.

        Returns
        -------
        Frame
            The frame bytes and the garbage skipped before them.  Integrity
            checks (CRC) are the protocol's job.
        """
        if not magic or header_size < len(magic):
            raise ValueError("magic must be non-empty and header_size >= len(magic)")
        end = time.monotonic() + deadline_s
        skipped = bytearray()
        while True:
            i = self._buf.find(magic)
            if i < 0:
                keep = len(magic) - 1  # a magic split across reads
                drop = max(0, len(self._buf) - keep)
            else:
                drop = i
            if drop:
                skipped += self._buf[:drop]
                self._log("<", bytes(self._buf[:drop]))
                del self._buf[:drop]
            if i >= 0 and len(self._buf) >= header_size:
                try:
                    size = int(frame_size(bytes(self._buf[:header_size])))
                    if size < header_size:
                        raise ValueError(f"frame size {size} < header size {header_size}")
                except ValueError:
                    skipped += self._buf[:1]
                    self._log("<", bytes(self._buf[:1]))
                    del self._buf[:1]
                    continue
                if len(self._buf) >= size:
                    data = bytes(self._buf[:size])
                    del self._buf[:size]
                    self._log("<", data)
                    if skipped:
                        self._note(f"resynchronised: skipped {len(skipped)} bytes before a frame")
                    return Frame(data, bytes(skipped))
            if time.monotonic() >= end:
                raise TransportTimeout(self.url, f"no complete frame within {deadline_s:.3g} s "
                                                 f"({len(skipped)} bytes skipped)", bytes(self._buf))
            self._fill(end)

    # ------------------------------------------------------------- internals
    def _require_open(self) -> serial.SerialBase:
        if self._port is None:
            raise TransportClosed(self.url, "port is not open; call reopen() once the device is back")
        return self._port

    def _fill(self, end: float) -> None:
        """Block at most ``poll_s`` (and not past ``end``) for more bytes."""
        port = self._require_open()
        try:
            n = port.in_waiting
            chunk = port.read(n if n > 0 else 1)
        except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
            self._fail(f"read failed, device unplugged? ({exc})")
        self._buf += chunk

    def _fail(self, message: str) -> NoReturn:
        self._note(f"port lost: {message}")
        self.close()
        raise TransportClosed(self.url, message + "; reconnect when the device is back")

    def _log(self, direction: str, data: bytes) -> None:
        if self.wire_log is not None and data:
            self.wire_log.record(self.label, direction, data)

    def _note(self, text: str) -> None:
        if self.wire_log is not None:
            self.wire_log.note(self.label, f"{text} {self.url}")
