"""Driver for the laser line-profile sensor.

``docs/protocols.md`` ("Laser
profiler").  ASCII command lines are answered by ``OK,<cmd>[,<values>]`` or
``ER,<cmd>,<code>``; profiles arrive as binary frames::

    "KPRF" | version u16 | length u32 | seq u32 | timestamp_us u64 | n u32 |
    n x (x i32, z i32) micrometres | CRC-32 u32 (zlib.crc32 of all before)

all little-endian, with both coordinates ``INT32_MIN`` for a point without a
return.  The reader resynchronises on the magic through
:meth:`SerialTransport.read_frame` (an implausible header is a false match),
re-requests a frame with ``RSND,<seq>`` when its CRC fails or it never
arrives, drops stale and duplicate frames by sequence number, and after
``max_retries`` failed attempts raises an error naming the port.

Examples
--------
>>> import struct, zlib
>>> body = struct.pack("<4sHIIQI", b"KPRF", 1, 16, 5, 0, 2) + struct.pack("<4i", 1000, 2000, INVALID, INVALID)
>>> raw = decode_frame(body + struct.pack("<I", zlib.crc32(body)))
>>> raw.seq, raw.x_um.tolist(), raw.z_um.tolist()
(5, [1000, -2147483648], [2000, -2147483648])
>>> p = to_profile(raw)
>>> p.x_mm.tolist(), p.valid.tolist()
([1.0, nan], [True, False])
"""

from __future__ import annotations

import logging
import math
import re
import struct
import time
import zlib
from collections import deque
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drivers.errors import (
    DeviceError,
    DeviceResetError,
    DeviceTimeout,
    HandshakeError,
    ResetSeen,
    TransportTimeout,
)
from drivers.transport import SerialTransport

__all__ = [
    "MAGIC",
    "HEADER_SIZE",
    "INVALID",
    "ERROR_CODES",
    "FrameError",
    "RawFrame",
    "Profile",
    "frame_size",
    "decode_frame",
    "to_profile",
    "parse_reply",
    "LaserProfiler",
]

MAGIC = b"KPRF"
HEADER_SIZE = 26
INVALID = -(2**31)
_HEADER = struct.Struct("<4sHIIQI")
_CRC = struct.Struct("<I")
ERROR_CODES = {
    "01": "unknown command",
    "02": "wrong number of parameters",
    "03": "parameter out of range",
    "04": "not allowed in the current state",
    "05": "laser interlock open",
    "99": "internal error",
}
_REPLY_RE = re.compile(r"(OK|ER),([A-Z]+)((?:,[^,]*)*)$")
_BANNER_RE = re.compile(r"PROFILER (\S+) (\S+)$")
_LOG = logging.getLogger("kogei.drivers.profiler")


class FrameError(ValueError):
    """A frame failed its integrity check (CRC, header, length)."""


@dataclass(frozen=True)
class RawFrame:
    """A decoded frame: header fields and points in micrometres (int32)."""

    seq: int
    timestamp_us: int
    x_um: NDArray[np.int32]
    z_um: NDArray[np.int32]


@dataclass(frozen=True)
class Profile:
    """One laser-line profile in the sensor frame.

    Attributes
    ----------
    x_mm
        Position along the laser line (mm); NaN where invalid.
    z_mm
        Range (mm); NaN where invalid.
    valid
        True where the sensor saw a return.
    seq
        The sensor's frame sequence number.
    timestamp_us
        The sensor's timestamp (microseconds).
    """

    x_mm: NDArray[np.float64]
    z_mm: NDArray[np.float64]
    valid: NDArray[np.bool_]
    seq: int
    timestamp_us: int


def frame_size(header: bytes, max_points: int = 4096) -> int:
    """Total frame size from its 26-byte header; ValueError for a false magic match.

    Examples
    --------
    >>> frame_size(struct.pack("<4sHIIQI", b"KPRF", 1, 16, 0, 0, 2))
    46
    >>> frame_size(struct.pack("<4sHIIQI", b"KPRF", 1, 15, 0, 0, 2))
    Traceback (most recent call last):
    ...
    ValueError: implausible KPRF header: length 15 is not 8 * 2 points
    """
    magic, version, length, _seq, _t, n = _HEADER.unpack(header[:HEADER_SIZE])
    if magic != MAGIC or version != 1:
        raise ValueError(f"implausible KPRF header: magic {magic!r} version {version}")
    if length != 8 * n or n > max_points:
        raise ValueError(f"implausible KPRF header: length {length} is not 8 * {n} points"
                         if length != 8 * n else f"implausible KPRF header: {n} > {max_points} points")
    return HEADER_SIZE + length + _CRC.size


def decode_frame(data: bytes, max_points: int = 4096) -> RawFrame:
    """Check and decode a complete frame.

    Raises
    ------
    FrameError
        Wrong size, bad header or CRC mismatch.
    """
    if len(data) < HEADER_SIZE + _CRC.size:
        raise FrameError(f"frame of {len(data)} bytes is shorter than header + CRC")
    try:
        size = frame_size(data[:HEADER_SIZE], max_points)
    except ValueError as exc:
        raise FrameError(str(exc)) from None
    if size != len(data):
        raise FrameError(f"frame of {len(data)} bytes, header says {size}")
    (crc,) = _CRC.unpack(data[-4:])
    if zlib.crc32(data[:-4]) != crc:
        raise FrameError(f"CRC mismatch (computed {zlib.crc32(data[:-4]):08x}, frame says {crc:08x})")
    _m, _v, _l, seq, t_us, n = _HEADER.unpack(data[:HEADER_SIZE])
    pts = np.frombuffer(data, dtype="<i4", count=2 * n, offset=HEADER_SIZE).reshape(n, 2)
    return RawFrame(seq, t_us, pts[:, 0].astype(np.int32), pts[:, 1].astype(np.int32))


def to_profile(raw: RawFrame) -> Profile:
    """Micrometres to millimetres, sentinel points to NaN with ``valid`` False."""
    valid = (raw.x_um != INVALID) & (raw.z_um != INVALID)
    x = np.where(valid, raw.x_um / 1000.0, np.nan)
    z = np.where(valid, raw.z_um / 1000.0, np.nan)
    return Profile(x, z, valid, raw.seq, raw.timestamp_us)


def parse_reply(raw: bytes) -> tuple[str, str, list[str]]:
    """Classify one received line.

    Returns ``(kind, cmd, fields)`` with kind ``'OK'``, ``'ER'`` (fields =
    ``[code]``), ``'banner'`` (cmd = model, fields = ``[version]``) or
    ``'noise'``.  Non-printable bytes (line noise) are dropped first and a
    reply may follow printable noise on the same line.

    Examples
    --------
    >>> parse_reply(b"\\xf0\\x93OK,ID,KP-200,SN1,1.3.0")
    ('OK', 'ID', ['KP-200', 'SN1', '1.3.0'])
    >>> parse_reply(b"ER,SET,03")
    ('ER', 'SET', ['03'])
    >>> parse_reply(b"PROFILER KP-200 1.3.0")
    ('banner', 'KP-200', ['1.3.0'])
    """
    text = "".join(chr(b) for b in raw if 0x20 <= b < 0x7F).strip()
    m = _BANNER_RE.search(text)
    if m is not None:
        return "banner", m.group(1), [m.group(2)]
    hits = list(re.finditer(r"(?:OK|ER),", text))
    if hits:
        m = _REPLY_RE.match(text[hits[-1].start():])
        if m is not None:
            fields = m.group(3).split(",")[1:] if m.group(3) else []
            return m.group(1), m.group(2), fields
    return "noise", "", [text]


class LaserProfiler:
    """The laser line-profile sensor over a :class:`SerialTransport`.

    Parameters
    ----------
    transport
        An open (or openable) transport to the sensor.
    exposure_us
        Exposure set on connect and after every reset (``SET,EXP``).
    rate_hz
        Streaming rate set on connect (``SET,RATE``).
    max_points
        Largest plausible point count (frames claiming more are false magic
        matches).
    latency_s, margin_s
        Link latency allowance and deadline margin per command (s).
    max_retries
        Re-requests of one profile (CRC failure, lost frame) and resends of a
        command after a device reset before giving up.

    Notes
    -----
    Errors: :class:`DeviceError` on ``ER`` (code and meaning in the message)
    or after ``max_retries`` bad frames; :class:`DeviceTimeout` when the
    sensor stops answering; :class:`TransportClosed` when the port vanishes
    (call :meth:`reconnect`).  All messages name the port.
    """

    def __init__(
        self,
        transport: SerialTransport,
        *,
        exposure_us: int = 500,
        rate_hz: int = 100,
        max_points: int = 4096,
        latency_s: float = 0.05,
        margin_s: float = 0.3,
        max_retries: int = 3,
    ) -> None:
        if not isinstance(exposure_us, int) or not 10 <= exposure_us <= 100_000:
            raise ValueError(f"exposure_us must be an integer in 10..100000 us, got {exposure_us!r}")
        if not isinstance(rate_hz, int) or not 1 <= rate_hz <= 2000:
            raise ValueError(f"rate_hz must be an integer in 1..2000 Hz, got {rate_hz!r}")
        if not isinstance(max_points, int) or max_points < 1:
            raise ValueError(f"max_points must be a positive integer, got {max_points!r}")
        for name, v in (("latency_s", latency_s), ("margin_s", margin_s)):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be a finite number >= 0 (seconds), got {v!r}")
        if not isinstance(max_retries, int) or max_retries < 0:
            raise ValueError(f"max_retries must be an integer >= 0, got {max_retries!r}")
        self.transport = transport
        self.exposure_us = exposure_us
        self.rate_hz = rate_hz
        self.max_points = max_points
        self.latency_s = float(latency_s)
        self.margin_s = float(margin_s)
        self.max_retries = max_retries
        self.model: str | None = None
        self.serial_number: str | None = None
        self.firmware_version: str | None = None
        self.recoveries: deque[str] = deque(maxlen=200)
        self.lost_seqs: deque[int] = deque(maxlen=1000)
        self.streaming = False
        self._laser_wanted = False
        self._last_n: int | None = None
        self._last_seq: int | None = None
        self._dirty = True

    @property
    def port(self) -> str:
        """The port path or URL (used in every error message)."""
        return self.transport.url

    # ------------------------------------------------------------ lifecycle
    def connect(self) -> str:
        """Identify the sensor (``ID``) and apply exposure, rate and laser state.

        Returns
        -------
        str
            The firmware version, e.g. ``'1.3.0'``.

        Raises
        ------
        HandshakeError
            No answer to ``ID`` or not a profiler.
        """
        if not self.transport.is_open:
            self.transport.open()
        self.transport.reset_input()
        self._dirty = False
        try:
            fields = self._command("ID", retry_resets=True)
        except DeviceTimeout:
            raise HandshakeError("ID", f"{self.port}: no answer to 'ID': is this the profiler port, is the "
                                       "sensor powered, is the baud rate right?") from None
        if len(fields) != 3:
            raise HandshakeError("ID", f"{self.port}: 'ID' reply {fields!r} is not <model>,<serial>,<version>")
        self.model, self.serial_number, self.firmware_version = fields
        self.streaming = False
        self._restore()
        return self.firmware_version

    def reconnect(self, timeout_s: float = 10.0) -> str:
        """Recover after :class:`TransportClosed`: reopen (waiting up to ``timeout_s``) and :meth:`connect`."""
        self.transport.reopen(timeout_s=timeout_s)
        version = self.connect()
        self.recoveries.append(f"reconnected to {self.port}")
        return version

    def reset(self) -> str:
        """``RST``: reset the sensor, wait for its banner, restore the settings."""
        self._command("RST")
        end = time.monotonic() + self.latency_s + self.margin_s + 1.0
        while True:
            try:
                raw = self.transport.read_line(max(0.0, end - time.monotonic()))
            except TransportTimeout:
                raise DeviceTimeout("RST", f"{self.port}: no banner after reset") from None
            kind, model, fields = parse_reply(raw)
            if kind == "banner":
                self.firmware_version = fields[0]
                break
        self.streaming = False
        self._restore()
        return self.firmware_version or ""

    def close(self) -> None:
        """Stop streaming, laser off, port closed -- best-effort, never raises."""
        self._laser_wanted = False
        if self.transport.is_open:
            try:
                if self.streaming:
                    self.stop_stream()
                self._command("LAS,0")
            except Exception as exc:  # noqa: BLE001 - closing must not raise
                _LOG.warning("profiler %s: could not switch the laser off cleanly: %s", self.port, exc)
        self.streaming = False
        self.transport.close()

    def __enter__(self) -> LaserProfiler:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---------------------------------------------------------- configuration
    def set_exposure(self, us: int) -> None:
        """``SET,EXP,<us>`` (10..100000 microseconds)."""
        self._command(f"SET,EXP,{int(us)}")
        self.exposure_us = int(us)

    def set_rate(self, hz: int) -> None:
        """``SET,RATE,<hz>``: streaming rate (1..2000 Hz)."""
        self._command(f"SET,RATE,{int(hz)}")
        self.rate_hz = int(hz)

    def get(self, name: str) -> str:
        """``GET,<name>`` (``EXP``, ``RATE``, ``LAS``): the value as text."""
        fields = self._command(f"GET,{name}")
        if len(fields) != 2 or fields[0] != name:
            raise DeviceError(f"GET,{name}", ",".join(fields), f"{self.port}: unexpected reply to GET,{name}: {fields!r}")
        return fields[1]

    def laser(self, on: bool) -> None:
        """``LAS,1`` / ``LAS,0``; re-asserted after every device reset."""
        self._command(f"LAS,{int(bool(on))}")
        self._laser_wanted = bool(on)

    def start_stream(self) -> None:
        """``STRT``: continuous profiles at ``rate_hz`` (read them with :meth:`profile`)."""
        self._command("STRT")
        self.streaming = True
        self._last_seq = None

    def stop_stream(self) -> None:
        """``STOP``; frames still in flight are discarded."""
        self.streaming = False
        self._dirty = True
        self._command("STOP", skip_frames=True)
        self._dirty = True

    # ----------------------------------------------------------------- data
    def _frame_deadline(self) -> float:
        n = self._last_n if self._last_n is not None else self.max_points
        transfer = (HEADER_SIZE + 8 * n + 4) * 10.0 / self.transport.baudrate
        return self.exposure_us * 1e-6 + transfer + self.latency_s + self.margin_s

    def _size(self, header: bytes) -> int:
        return frame_size(header, self.max_points)

    def profile(self, deadline_s: float = 5.0) -> Profile:
        """One profile: ``TRG`` (or the next streamed frame), checked and converted to mm.

        Parameters
        ----------
        deadline_s
            Seconds for the whole exchange, re-requests included.

        Raises
        ------
        DeviceError
            ``ER`` reply, or ``max_retries`` corrupted frames in a row.
        DeviceTimeout
            No frame within ``deadline_s`` or after ``max_retries`` re-requests.
        """
        if not (isinstance(deadline_s, (int, float)) and deadline_s > 0):
            raise ValueError(f"deadline_s must be a positive number of seconds, got {deadline_s!r}")
        end = time.monotonic() + deadline_s
        if self.streaming:
            return self._next_streamed(end)
        fields = self._command("TRG", retry_resets=True)
        seq = self._seq_field("TRG", fields)
        failures = 0
        while True:
            left = end - time.monotonic()
            if left <= 0:
                self._dirty = True
                raise DeviceTimeout("TRG", f"{self.port}: no valid profile frame within {deadline_s:g} s")
            problem = ""
            try:
                frame = self.transport.read_frame(MAGIC, HEADER_SIZE, self._size, min(left, self._frame_deadline()))
                raw = decode_frame(frame.data, self.max_points)
                if raw.seq != seq:
                    self.recoveries.append(f"dropped stale frame {raw.seq} (waiting for {seq})")
                    continue
                self._last_n = raw.x_um.size
                return to_profile(raw)
            except TransportTimeout:
                problem = "frame lost"
            except FrameError as exc:
                problem = f"bad frame ({exc})"
            failures += 1
            _LOG.warning("profiler %s: frame %d: %s", self.port, seq, problem)
            if failures > self.max_retries:
                self._dirty = True
                cls = DeviceTimeout if problem == "frame lost" else DeviceError
                msg = (f"{self.port}: frame {seq}: {problem}; gave up after {self.max_retries} re-requests "
                       "(check the cable, shielding and baud rate)")
                raise cls("TRG", msg) if cls is DeviceTimeout else DeviceError("TRG", problem, msg)
            seq = self._rerequest(seq)
            self.recoveries.append(f"re-requested frame {seq}: {problem}")

    def _rerequest(self, seq: int) -> int:
        """``RSND,<seq>``; if the sensor no longer has it, a fresh ``TRG``."""
        try:
            fields = self._command(f"RSND,{seq}")
            return self._seq_field("RSND", fields)
        except DeviceError as exc:
            if exc.text != "03":
                raise
        fields = self._command("TRG", retry_resets=True)
        return self._seq_field("TRG", fields)

    def _next_streamed(self, end: float) -> Profile:
        while True:
            left = end - time.monotonic()
            if left <= 0:
                raise DeviceTimeout("STRT", f"{self.port}: no valid streamed frame before the deadline")
            try:
                frame = self.transport.read_frame(MAGIC, HEADER_SIZE, self._size,
                                                  min(left, self._frame_deadline() + 1.0 / self.rate_hz))
                raw = decode_frame(frame.data, self.max_points)
            except TransportTimeout:
                continue
            except FrameError as exc:
                _LOG.warning("profiler %s: streamed frame discarded: %s", self.port, exc)
                continue
            last = self._last_seq
            if last is not None:
                ahead = (raw.seq - last) % 2**32
                if ahead == 0 or ahead >= 2**31:
                    self.recoveries.append(f"dropped duplicate frame {raw.seq}")
                    continue
                for k in range(1, min(ahead, 1001)):
                    self.lost_seqs.append((last + k) % 2**32)
            self._last_seq = raw.seq
            self._last_n = raw.x_um.size
            return to_profile(raw)

    # ------------------------------------------------------------- internals
    def _seq_field(self, cmd: str, fields: list[str]) -> int:
        try:
            seq = int(fields[0])
            if not 0 <= seq < 2**32:
                raise ValueError
            return seq
        except (IndexError, ValueError):
            raise DeviceError(cmd, ",".join(fields), f"{self.port}: reply to {cmd} has no sequence number: "
                                                     f"{fields!r}") from None

    def _restore(self) -> None:
        self._command(f"SET,EXP,{self.exposure_us}")
        self._command(f"SET,RATE,{self.rate_hz}")
        self._command(f"LAS,{int(self._laser_wanted)}")

    def _command(self, line: str, *, retry_resets: bool = True, skip_frames: bool = False) -> list[str]:
        """Send ``line``; the reply's fields after ``OK,<cmd>``."""
        cmd = line.split(",", 1)[0]
        attempts = 0
        while True:
            if self._dirty:
                self.transport.reset_input()
                self._dirty = False
            self.transport.write(line.encode("ascii") + b"\r\n")
            try:
                return self._await(line, cmd, skip_frames)
            except ResetSeen as seen:
                self._dirty = True
                if cmd == "RST":
                    raise DeviceResetError(line, seen.banner) from None
                if not retry_resets or attempts >= self.max_retries:
                    raise DeviceResetError(line, seen.banner) from None
                attempts += 1
                _LOG.warning("profiler %s reset itself (%r) during %r; restoring", self.port, seen.banner, line)
                self.recoveries.append(f"device reset during {line!r}; settings restored")
                self.streaming = False
                self.transport.reset_input()
                self._dirty = False
                self._restore()

    def _await(self, line: str, cmd: str, skip_frames: bool = False) -> list[str]:
        timeout = self.latency_s + self.margin_s
        end = time.monotonic() + timeout
        while True:
            try:
                raw = self.transport.read_line(max(0.0, end - time.monotonic()))
            except TransportTimeout:
                self._dirty = True
                raise DeviceTimeout(line, f"{self.port}: no reply within {timeout:.3g} s (is the sensor "
                                          "powered and on this port?)") from None
            kind, rcmd, fields = parse_reply(raw)
            if kind == "banner" and cmd != "RST":
                raise ResetSeen(f"PROFILER {rcmd} {fields[0]}")
            if kind in ("OK", "ER") and rcmd == cmd:
                if kind == "OK":
                    return fields
                code = fields[0] if fields else "?"
                meaning = ERROR_CODES.get(code, "unknown error code")
                raise DeviceError(line, code, f"{self.port}: profiler answered ER,{cmd},{code} ({meaning}) "
                                              f"to {line!r}")
            if kind != "noise" or (fields and fields[0] and not skip_frames):
                _LOG.info("profiler %s: ignored line %r while %r pending", self.port, raw[:80], line)
