"""Driver for the Horus turntable firmware (Ciclop scanner board).

``docs/protocols.md`` ("Turntable").
The Horus firmware is GRBL-derived: 115200 8N1, CR/LF lines, banner
``Horus 0.2 ['$' for help]`` after a Ctrl-X reset, every command line
answered by exactly one ``ok`` or ``error: <text>``, ``G1 X<x>`` an
absolute move whose ``ok`` arrives when the move has *finished*, real-time
``?`` status, unsolicited ``ALARM:...`` and ``[...]`` lines.

Degrees and the ``X`` value
---------------------------
The API takes degrees.  The table turns ``steps_per_degree`` motor steps per
degree (mechanics); the firmware counts ``X`` in units of
``firmware_steps_per_unit`` steps (its $100 setting).  A target angle is
rounded to a whole motor step, ``steps = round(deg * steps_per_degree)``,
and sent as ``X = steps / firmware_steps_per_unit``.  With the default
(firmware $100 equal to the mechanical steps per degree, as the Ciclop
ships) ``X`` is in degrees.  Feed rates convert the same way.

Deadlines
---------
A move's deadline is ``latency_s + t_move + margin_s + margin_frac * t_move``
with ``t_move`` from the trapezoidal profile (:func:`move_time_s`).  When it
passes, the driver sends ``?``: ``Run`` extends the deadline, ``Idle`` at the
target means the ``ok`` was lost (accepted), ``Idle`` elsewhere means the
command was lost (resent: every command this driver sends is idempotent),
no reply raises :class:`DeviceTimeout`.

Examples
--------
>>> parse_line(b"ok")
Reply(kind='ok', text='ok')
>>> parse_status("<Idle|MPos:90.000|FS:100,0>")
Status(state='Idle', position=90.0)
>>> round(move_time_s(90.0, 30.0, 60.0), 6)
3.5
"""

from __future__ import annotations

import logging
import math
import re
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from drivers.errors import (
    DeviceAlarm,
    DeviceError,
    DeviceResetError,
    DeviceTimeout,
    DriverError,
    HandshakeError,
    ResetSeen,
    TransportClosed,
    TransportTimeout,
)
from drivers.transport import SerialTransport

__all__ = [
    "HORUS_BANNER",
    "Reply",
    "Status",
    "parse_line",
    "parse_status",
    "move_time_s",
    "move_deadline_s",
    "format_number",
    "Turntable",
]

HORUS_BANNER = "Horus 0.2 ['$' for help]"
_BANNER_RE = re.compile(r"^(\S+ \S+) \['\$' for help\]$")
_STATUS_RE = re.compile(r"^<([A-Za-z]+)(?:[|,].*?MPos:\s*([-+]?\d*\.?\d+(?:[eE][-+]?\d+)?))?.*>$")
_LOG = logging.getLogger("kogei.drivers.turntable")


@dataclass(frozen=True)
class Reply:
    """One line from the firmware, classified.

    ``kind`` is ``'ok'``, ``'error'`` (``text`` = what follows ``error:``),
    ``'alarm'`` (``text`` = what follows ``ALARM:``), ``'feedback'``
    (``[...]``), ``'status'`` (``<...>``), ``'banner'``, ``'empty'`` or
    ``'noise'`` (anything else: line garbage).
    """

    kind: str
    text: str


@dataclass(frozen=True)
class Status:
    """A parsed ``?`` reply: machine state and position (units of ``X``)."""

    state: str
    position: float | None


def parse_line(raw: bytes) -> Reply:
    """Classify one received line (terminator already removed).

    Bytes outside printable ASCII (line noise) are dropped before matching,
    so noise that lands at the start of a reply still lets the reply through
    only when what remains is exactly a reply.

    Examples
    --------
    >>> parse_line(b"error: Invalid gcode ID:24")
    Reply(kind='error', text='Invalid gcode ID:24')
    >>> parse_line(b"ALARM:Hard limit").kind
    'alarm'
    >>> parse_line(b"\\xf0\\x93ok")
    Reply(kind='ok', text='ok')
    >>> parse_line(b"xok").kind
    'noise'
    """
    text = "".join(chr(b) for b in raw if 0x20 <= b < 0x7F).strip()
    if not text:
        return Reply("empty" if not raw.strip() else "noise", text)
    if text == "ok":
        return Reply("ok", text)
    if text.startswith("error:"):
        return Reply("error", text[6:].strip())
    if text.startswith("ALARM:"):
        return Reply("alarm", text[6:].strip())
    if text.startswith("[") and text.endswith("]"):
        return Reply("feedback", text)
    if text.startswith("<") and text.endswith(">"):
        return Reply("status", text)
    if _BANNER_RE.match(text):
        return Reply("banner", text)
    return Reply("noise", text)


def parse_status(text: str) -> Status:
    """Parse a GRBL-style status line (``<Idle|MPos:x...>`` or ``<Idle,MPos:x,...>``).

    Raises
    ------
    ValueError
        ``text`` is not a status line.

    Examples
    --------
    >>> parse_status("<Run,MPos:12.500,0.000,0.000,WPos:12.500,0.000,0.000>")
    Status(state='Run', position=12.5)
    """
    m = _STATUS_RE.match(text.strip())
    if m is None:
        raise ValueError(f"not a status line: {text!r} (expected e.g. '<Idle|MPos:0.000>')")
    return Status(m.group(1), float(m.group(2)) if m.group(2) is not None else None)


def move_time_s(distance_deg: float, speed_deg_s: float, accel_deg_s2: float) -> float:
    """Duration of a rest-to-rest move with a trapezoidal velocity profile.

    Parameters
    ----------
    distance_deg
        Rotation (degrees; sign ignored).
    speed_deg_s
        Cruise speed (deg/s, > 0).
    accel_deg_s2
        Acceleration = deceleration (deg/s^2, > 0).

    Returns
    -------
    float
        Seconds: ``d/v + v/a`` when the cruise speed is reached
        (``d >= v^2/a``), else ``2 sqrt(d/a)`` (triangular profile).

    Examples
    --------
    >>> move_time_s(0.0, 10.0, 10.0)
    0.0
    >>> move_time_s(4.0, 10.0, 1.0)   # never reaches 10 deg/s: 2 * sqrt(4)
    4.0
    """
    if not (speed_deg_s > 0 and accel_deg_s2 > 0):
        raise ValueError(f"speed_deg_s and accel_deg_s2 must be > 0, got {speed_deg_s!r}, {accel_deg_s2!r}")
    d = abs(float(distance_deg))
    if not math.isfinite(d):
        raise ValueError(f"distance_deg must be finite, got {distance_deg!r}")
    if d >= speed_deg_s * speed_deg_s / accel_deg_s2:
        return d / speed_deg_s + speed_deg_s / accel_deg_s2
    return 2.0 * math.sqrt(d / accel_deg_s2)


def move_deadline_s(distance_deg: float, speed_deg_s: float, accel_deg_s2: float,
                    latency_s: float, margin_s: float = 0.5, margin_frac: float = 0.1) -> float:
    """Seconds to wait for a move's ``ok`` before querying status.

    ``latency_s + t + margin_s + margin_frac * t`` with ``t`` from
    :func:`move_time_s`.

    Examples
    --------
    >>> move_deadline_s(90.0, 30.0, 60.0, latency_s=0.05, margin_s=0.5, margin_frac=0.1)
    4.4
    """
    t = move_time_s(distance_deg, speed_deg_s, accel_deg_s2)
    return round(latency_s + t + margin_s + margin_frac * t, 12)


def format_number(x: float) -> str:
    """Shortest fixed-point form (up to 6 decimals) for a G-code word.

    Examples
    --------
    >>> format_number(90.0), format_number(0.1125), format_number(-1e-9)
    ('90', '0.1125', '0')
    """
    s = f"{x:.6f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


class Turntable:
    """The Horus turntable over a :class:`SerialTransport`.

    Parameters
    ----------
    transport
        An open (or openable) transport to the board.
    steps_per_degree
        Motor steps per degree of table rotation (default 3200/360: a 1.8 deg
        motor at 1/16 microstepping driving the table directly).
    firmware_steps_per_unit
        The firmware's $100 (steps per unit of ``X``); default
        ``steps_per_degree``, i.e. ``X`` in degrees.
    speed_deg_s
        Cruise speed set on connect (``G1 F``).
    accel_deg_s2
        The firmware's configured acceleration ($120) in deg/s^2; only used
        for deadlines.
    latency_s
        Host + link latency allowance per command (s).
    margin_s, margin_frac
        Deadline margin: absolute seconds plus a fraction of the move time.
    status_timeout_s
        How long to wait for the reply to a ``?`` status query.
    handshake_timeout_s
        How long to wait for the banner after Ctrl-X.
    n_lasers
        Number of laser outputs (``laser(i, on)`` takes ``i`` in 1..n).
    max_resends
        Resends of a lost command (all commands are idempotent) before
        :class:`DeviceTimeout`.
    recover_resets
        On an unexpected banner (the board reset itself), restore state and
        retry the command (True) or raise :class:`DeviceResetError` (False).

    Notes
    -----
    What a caller does on errors:

    * :class:`TransportClosed` (cable pulled, USB reset): call
      :meth:`reconnect` (it waits for the port to come back), then check
      :attr:`position_uncertain_deg` -- non-zero if the port vanished during
      a move, whose partial rotation cannot be known without a home sensor --
      and repeat the interrupted :meth:`step` / :meth:`move_to` (absolute, so
      repeating is safe).
    * :class:`DeviceAlarm`: the move was aborted; call :meth:`connect` (a
      reset clears the alarm) once the cause (a jam) is removed.
    * :class:`DeviceError`: the firmware rejected the command; fix the
      command, the connection stays usable.
    * :class:`DeviceTimeout`: the board stopped answering, even to ``?``;
      power-cycle it and :meth:`reconnect`.
    """

    def __init__(
        self,
        transport: SerialTransport,
        *,
        steps_per_degree: float = 3200.0 / 360.0,
        firmware_steps_per_unit: float | None = None,
        speed_deg_s: float = 100.0,
        accel_deg_s2: float = 200.0,
        latency_s: float = 0.05,
        margin_s: float = 0.5,
        margin_frac: float = 0.1,
        status_timeout_s: float = 1.0,
        handshake_timeout_s: float = 3.0,
        n_lasers: int = 2,
        max_resends: int = 2,
        recover_resets: bool = True,
    ) -> None:
        for name, v in (("steps_per_degree", steps_per_degree), ("speed_deg_s", speed_deg_s),
                        ("accel_deg_s2", accel_deg_s2), ("status_timeout_s", status_timeout_s),
                        ("handshake_timeout_s", handshake_timeout_s)):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive finite number, got {v!r}")
        for name, v in (("latency_s", latency_s), ("margin_s", margin_s), ("margin_frac", margin_frac)):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
        if firmware_steps_per_unit is not None and not (
                math.isfinite(firmware_steps_per_unit) and firmware_steps_per_unit > 0):
            raise ValueError(f"firmware_steps_per_unit must be > 0 (the firmware's $100), got {firmware_steps_per_unit!r}")
        if not isinstance(n_lasers, int) or n_lasers < 1:
            raise ValueError(f"n_lasers must be a positive integer, got {n_lasers!r}")
        self.transport = transport
        self.steps_per_degree = float(steps_per_degree)
        self.firmware_steps_per_unit = float(firmware_steps_per_unit or steps_per_degree)
        self.speed_deg_s = float(speed_deg_s)
        self.accel_deg_s2 = float(accel_deg_s2)
        self.latency_s = float(latency_s)
        self.margin_s = float(margin_s)
        self.margin_frac = float(margin_frac)
        self.status_timeout_s = float(status_timeout_s)
        self.handshake_timeout_s = float(handshake_timeout_s)
        self.n_lasers = n_lasers
        self.max_resends = int(max_resends)
        self.recover_resets = recover_resets
        self.firmware_version: str | None = None
        self.unsolicited: deque[str] = deque(maxlen=200)
        self.recoveries: deque[str] = deque(maxlen=200)
        self.position_uncertain_deg = 0.0
        self._fw_units = 0.0
        self._offset_deg = 0.0
        self._motor_wanted = False
        self._lasers_wanted = [False] * n_lasers
        self._connected = False

    # ---------------------------------------------------------- unit helpers
    def _deg_per_unit(self) -> float:
        return self.firmware_steps_per_unit / self.steps_per_degree

    def _units_for(self, deg: float) -> float:
        """Firmware X for logical angle ``deg``, rounded to a whole motor step."""
        steps = round((deg - self._offset_deg) * self.steps_per_degree)
        return steps / self.firmware_steps_per_unit

    @property
    def position_deg(self) -> float:
        """Last confirmed table angle (degrees, in the frame set by :meth:`zero`)."""
        return self._fw_units * self._deg_per_unit() + self._offset_deg

    @property
    def firmware_offset_deg(self) -> float:
        """Logical angle of the firmware's position 0 (changes when the board resets mid-scan).

        A firmware position ``X`` (from a ``?`` status) is at logical angle
        ``X * firmware_steps_per_unit / steps_per_degree + firmware_offset_deg``.
        """
        return self._offset_deg

    def assume_position(self, deg: float) -> None:
        """Declare that the table is now at logical angle ``deg`` (e.g. after :meth:`connect`).

        Use when the angle is known from elsewhere -- a session's record of
        the last confirmed move -- since :meth:`connect` resets the firmware's
        position counter to 0 wherever the table stands.
        """
        if not (isinstance(deg, (int, float)) and math.isfinite(deg)):
            raise ValueError(f"deg must be a finite angle in degrees, got {deg!r}")
        self._fw_units = 0.0
        self._offset_deg = float(deg)
        self.position_uncertain_deg = 0.0

    @property
    def lasers_wanted(self) -> tuple[bool, ...]:
        """The laser states this driver asserts (not a reading of the board)."""
        return tuple(self._lasers_wanted)

    # ------------------------------------------------------------ lifecycle
    def connect(self) -> str:
        """Reset the board (Ctrl-X), check the banner, set the speed.

        Returns
        -------
        str
            The firmware version, e.g. ``'Horus 0.2'``.

        Raises
        ------
        HandshakeError
            No banner, or a different firmware's banner.
        """
        if not self.transport.is_open:
            self.transport.open()
        self._handshake()
        self._fw_units = 0.0
        self._offset_deg = 0.0
        self.position_uncertain_deg = 0.0
        self._restore()
        return self.firmware_version or ""

    def reconnect(self, timeout_s: float = 10.0) -> str:
        """Recover after :class:`TransportClosed`: reopen, reset, re-handshake.

        Waits up to ``timeout_s`` for the port to reappear, keeps the angle
        bookkeeping (the table did not move while the board was off: the
        firmware's new zero is the last confirmed angle) and re-applies speed,
        motor and laser state.
        """
        logical = self.position_deg
        self.transport.reopen(timeout_s=timeout_s)
        self._handshake()
        self._fw_units = 0.0
        self._offset_deg = logical
        self._restore()
        self.recoveries.append(f"reconnected at {logical:g} deg")
        return self.firmware_version or ""

    def close(self) -> None:
        """Lasers off, motor released, port closed -- best-effort, never raises."""
        self._lasers_wanted = [False] * self.n_lasers
        self._motor_wanted = False
        if self.transport.is_open and self._connected:
            try:
                for i in range(1, self.n_lasers + 1):
                    self._command(f"M70 T{i}", self.latency_s + self.margin_s, resend=False)
                self._command("M18", self.latency_s + self.margin_s, resend=False)
            except DriverError as exc:
                _LOG.warning("turntable close: could not switch off cleanly: %s", exc)
        self._connected = False
        self.transport.close()

    def __enter__(self) -> Turntable:
        if not self._connected:
            self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -------------------------------------------------------------- commands
    def move_to(self, deg: float) -> float:
        """Absolute move to ``deg``; returns when the firmware says ``ok``.

        Returns
        -------
        float
            The new confirmed angle (``deg`` rounded to a whole motor step).
        """
        if not (isinstance(deg, (int, float)) and math.isfinite(deg)):
            raise ValueError(f"deg must be a finite angle in degrees, got {deg!r}")
        start_deg = self.position_deg
        target: list[float] = []

        def build() -> tuple[str, float, float | None]:
            units = self._units_for(float(deg))
            distance = abs(units - self._fw_units) * self._deg_per_unit()
            self.position_uncertain_deg = max(self.position_uncertain_deg, distance)
            target[:] = [units]
            deadline = move_deadline_s(distance, self.speed_deg_s, self.accel_deg_s2,
                                       self.latency_s, self.margin_s, self.margin_frac)
            return f"G1 X{format_number(units)}", deadline, units

        try:
            self._command_built(build)
        except TransportClosed:
            raise  # the move may be partial: position_uncertain_deg says how much
        except DriverError:
            self.position_uncertain_deg = max(self.position_uncertain_deg, abs(self.position_deg - start_deg))
            raise
        self._fw_units = target[0]
        self.position_uncertain_deg = 0.0
        return self.position_deg

    def set_speed(self, deg_s: float) -> None:
        """Cruise speed in deg/s (``G1 F<units/s>``)."""
        if not (isinstance(deg_s, (int, float)) and math.isfinite(deg_s) and deg_s > 0):
            raise ValueError(f"deg_s must be a positive speed in deg/s, got {deg_s!r}")
        self._command(f"G1 F{format_number(deg_s / self._deg_per_unit())}", self._short_deadline())
        self.speed_deg_s = float(deg_s)

    def zero(self) -> None:
        """Make the current angle 0 (``G50``)."""
        self._command("G50", self._short_deadline())
        self._fw_units = 0.0
        self._offset_deg = 0.0

    def motor(self, on: bool) -> None:
        """Energise (``M17``) or release (``M18``) the motor."""
        self._command("M17" if on else "M18", self._short_deadline())
        self._motor_wanted = bool(on)

    def laser(self, i: int, on: bool) -> None:
        """Switch laser ``i`` (1-based) on (``M71 T<i>``) or off (``M70 T<i>``)."""
        self._check_laser(i)
        self._command(f"M{71 if on else 70} T{i}", self._short_deadline())
        self._lasers_wanted[i - 1] = bool(on)

    def step(self, deg: float, lasers: Iterable[int] | None = None) -> float:
        """One scan step: re-assert motor on and laser state, then move to ``deg``.

        Parameters
        ----------
        deg
            Absolute target angle (degrees).
        lasers
            Lasers (1-based) to have on from now on; ``None`` keeps the
            current choice.  Every step re-sends every laser's state: the
            firmware switches a laser off on its own after ~255 s.

        Returns
        -------
        float
            The confirmed angle.
        """
        if lasers is not None:
            wanted = set(lasers)
            for i in wanted:
                self._check_laser(i)
            self._lasers_wanted = [i + 1 in wanted for i in range(self.n_lasers)]
        self.motor(True)
        for i, on in enumerate(self._lasers_wanted, start=1):
            self.laser(i, on)
        return self.move_to(deg)

    def status(self) -> Status:
        """Send ``?`` and return the parsed status (no command may be pending)."""
        self.transport.write(b"?")
        end = time.monotonic() + self.status_timeout_s
        while True:
            try:
                raw = self.transport.read_line(max(0.0, end - time.monotonic()))
            except TransportTimeout:
                raise DeviceTimeout("?", f"no status reply within {self.status_timeout_s:g} s") from None
            r = parse_line(raw)
            if r.kind == "status":
                return parse_status(r.text)
            self._unsolicited(r, "?")

    # ------------------------------------------------------------- internals
    def _check_laser(self, i: int) -> None:
        if not isinstance(i, int) or not 1 <= i <= self.n_lasers:
            raise ValueError(f"laser index must be 1..{self.n_lasers}, got {i!r}")

    def _short_deadline(self) -> float:
        return self.latency_s + self.margin_s

    def _handshake(self) -> None:
        self._connected = False
        self.transport.reset_input()
        self.transport.write(b"\x18")
        end = time.monotonic() + self.handshake_timeout_s
        seen: list[str] = []
        while True:
            try:
                raw = self.transport.read_line(max(0.0, end - time.monotonic()))
            except TransportTimeout:
                raise HandshakeError(
                    "\\x18", f"{self.transport.url}: no banner within {self.handshake_timeout_s:g} s after "
                    f"reset (Ctrl-X){'; got ' + repr(seen[-3:]) if seen else ''}: is this the turntable port, "
                    "is the board powered, is it at 115200 baud?") from None
            r = parse_line(raw)
            if r.kind == "banner":
                if r.text != HORUS_BANNER:
                    raise HandshakeError("\\x18", f"{self.transport.url}: unsupported firmware {r.text!r}; "
                                                 f"expected {HORUS_BANNER!r} (flash Horus 0.2 onto the board)")
                self.firmware_version = _BANNER_RE.match(r.text).group(1)  # type: ignore[union-attr]
                self._connected = True
                return
            if r.kind != "empty":
                seen.append(r.text)

    def _restore(self) -> None:
        """Re-apply speed, motor and lasers after a reset (the firmware forgets them)."""
        self.set_speed(self.speed_deg_s)
        if self._motor_wanted:
            self.motor(True)
        for i, on in enumerate(self._lasers_wanted, start=1):
            if on:
                self.laser(i, True)

    def _unsolicited(self, r: Reply, pending: str) -> None:
        self.unsolicited.append(r.text)
        if r.kind == "feedback":
            _LOG.info("turntable says %s (while %r pending)", r.text, pending)
        elif r.kind != "empty":
            _LOG.warning("turntable: unexpected %s line %r (while %r pending)", r.kind, r.text, pending)

    def _command(self, line: str, timeout_s: float, *, target_units: float | None = None,
                 resend: bool = True) -> None:
        self._command_built(lambda: (line, timeout_s, target_units), resend=resend)

    def _command_built(self, build: Callable[[], tuple[str, float, float | None]], *,
                       resend: bool = True) -> None:
        """Send the command ``build()`` returns until it is acknowledged.

        ``build`` is called again for every attempt, so a move retried after
        a device reset is re-expressed in the firmware's new coordinates.
        """
        attempts = 0
        while True:
            line, timeout_s, target_units = build()
            self.transport.write(line.encode("ascii") + b"\n")
            try:
                outcome = self._await(line, timeout_s, target_units)
            except ResetSeen as seen:
                if not (self.recover_resets and resend) or attempts >= self.max_resends:
                    raise DeviceResetError(line, seen.banner) from None
                attempts += 1
                self._after_reset(line, seen.banner)
                continue
            if outcome == "ok":
                return
            if not resend or attempts >= self.max_resends:
                raise DeviceTimeout(line, f"the firmware is idle but never acknowledged it ({attempts + 1} tries)")
            attempts += 1
            self.recoveries.append(f"resent {line!r}: reply lost")
            _LOG.warning("turntable: reply to %r lost (device idle); resending", line)

    def _after_reset(self, line: str, banner: str) -> None:
        _LOG.warning("turntable reset itself (%r) while %r was pending; restoring state", banner, line)
        if banner != HORUS_BANNER:
            raise HandshakeError(line, f"{self.transport.url}: board reset with unsupported firmware {banner!r}")
        logical = self.position_deg
        self._fw_units = 0.0
        self._offset_deg = logical
        self.recoveries.append(f"device reset during {line!r}; restored at {logical:g} deg")
        self._restore()

    def _await(self, line: str, timeout_s: float, target_units: float | None) -> str:
        """Read until the reply to ``line``: 'ok', 'resend' (lost), or raise."""
        now = time.monotonic()
        end = now + timeout_s
        status_end: float | None = None
        checks = 0
        alarm: str | None = None
        while True:
            limit = status_end if status_end is not None else end
            try:
                raw = self.transport.read_line(max(0.0, limit - time.monotonic()))
            except TransportTimeout:
                if alarm is not None:
                    raise DeviceAlarm(line, alarm) from None
                if status_end is not None:
                    raise DeviceTimeout(line, f"no reply within {timeout_s:.3g} s and no answer to the '?' "
                                              f"status query within {self.status_timeout_s:g} s: check the "
                                              "cable and the board's power") from None
                self.transport.write(b"?")
                status_end = time.monotonic() + self.status_timeout_s
                continue
            r = parse_line(raw)
            if r.kind == "ok":
                if alarm is not None:
                    raise DeviceAlarm(line, alarm, "ok")
                return "ok"
            if r.kind == "error":
                if alarm is not None:
                    raise DeviceAlarm(line, alarm, f"error: {r.text}")
                raise DeviceError(line, r.text)
            if r.kind == "alarm":
                self._unsolicited(r, line)
                alarm = r.text
                end = time.monotonic() + self.latency_s + self.margin_s  # drain the command's reply
                status_end = None
                continue
            if r.kind == "banner":
                raise ResetSeen(r.text)
            if r.kind == "status" and status_end is not None:
                status_end = None
                checks += 1
                st = parse_status(r.text)
                if st.state == "Alarm":
                    raise DeviceAlarm(line, f"status {r.text}")
                if st.state == "Idle":
                    if target_units is None:
                        return "resend"
                    half_step = 0.5 / self.firmware_steps_per_unit
                    if st.position is not None and abs(st.position - target_units) <= half_step:
                        self.recoveries.append(f"{line!r}: ok lost, at target per status")
                        return "ok"
                    return "resend"
                if checks > 20:
                    raise DeviceTimeout(line, f"still {st.state} after {checks} status checks")
                # still busy: extend by the remaining move (if known) plus margin
                extra = self.latency_s + self.margin_s
                if target_units is not None and st.position is not None:
                    rest = abs(target_units - st.position) * self._deg_per_unit()
                    extra += (1 + self.margin_frac) * move_time_s(rest, self.speed_deg_s, self.accel_deg_s2)
                end = time.monotonic() + extra
                continue
            self._unsolicited(r, line)
