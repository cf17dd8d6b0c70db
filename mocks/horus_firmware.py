"""Emulator of the Horus turntable firmware on a pseudo-terminal pair.

``docs/protocols.md`` ("Turntable (Horus firmware)"): the Horus firmware (GRBL 0.9 derived, the Ciclop scanner's board) at
115200 8N1, CR/LF lines.  After a reset (Ctrl-X, 0x18) it prints the banner
``Horus 0.2 ['$' for help]``; every command line is answered by exactly one
``ok`` or ``error: <text>``; ``G1 X<x>`` is an absolute move whose ``ok``
comes when the move has finished (trapezoidal profile from the feed rate
``G1 F<units/s>`` and the configured acceleration); ``?`` is a real-time
status query answered at once with ``<Idle|MPos:x>``, ``<Run|MPos:x>`` or
``<Alarm|MPos:x>``; each laser turns itself off after ``laser_watchdog_s``
(255 s by default) unless re-commanded on.

The firmware's unit ``x`` is its configured ``steps_per_unit`` ($100); the
table turns ``steps_per_degree`` motor steps per degree, so with equal values
(the default) the unit is the degree.  Motion takes ``time_scale`` real
seconds per simulated second (0: instant).  With the motor released (M18)
the firmware still counts steps but the table does not turn.

An optional ``on_move_done(angle_deg)`` callback runs in the firmware thread
when a move has finished, *before* its ``ok`` is sent, with the physical table
angle: whoever else simulates the station (the camera's view) is up to date by
the time the host sees the ``ok``.

Faults come from a shared :class:`mocks.faults.Faults`; see its attributes.

Examples
--------
>>> import os, time
>>> with HorusFirmware() as fw:
...     fd = os.open(fw.path, os.O_RDWR | os.O_NOCTTY)
...     _ = os.write(fd, b"\\x18")
...     time.sleep(0.2)
...     print(os.read(fd, 100).decode().strip())
...     os.close(fd)
Horus 0.2 ['$' for help]
"""

from __future__ import annotations

import logging
import math
import os
import re
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from mocks.faults import Faults
from mocks.pty_link import PtyDevice

__all__ = ["BANNER", "HorusFirmware", "trapezoid_time", "trapezoid_distance"]

BANNER = "Horus 0.2 ['$' for help]"
_log = logging.getLogger(__name__)
_WORD = re.compile(r"([A-Z])\s*([-+]?(?:\d+\.?\d*|\.\d+))")


def trapezoid_time(distance: float, speed: float, accel: float) -> float:
    """Duration of a rest-to-rest move with a trapezoidal velocity profile.

    Parameters
    ----------
    distance
        Path length (any unit u; sign ignored).
    speed
        Cruise speed (u/s, > 0).
    accel
        Acceleration and deceleration (u/s^2, > 0).

    Returns
    -------
    float
        Seconds: ``d/v + v/a`` if the cruise speed is reached
        (``d >= v^2/a``), else the triangular ``2 sqrt(d/a)``.

    Examples
    --------
    >>> trapezoid_time(90.0, 30.0, 60.0)   # 3 s cruise-equivalent + 0.5 s
    3.5
    >>> trapezoid_time(1.0, 30.0, 4.0)     # triangular: 2 * sqrt(1/4)
    1.0
    """
    d = abs(distance)
    if d >= speed * speed / accel:
        return d / speed + speed / accel
    return 2.0 * math.sqrt(d / accel)


def trapezoid_distance(t: float, distance: float, speed: float, accel: float) -> float:
    """Distance covered after ``t`` seconds of the move of :func:`trapezoid_time`.

    Examples
    --------
    >>> trapezoid_distance(0.5, 90.0, 30.0, 60.0)   # end of the ramp: a t^2 / 2
    7.5
    >>> trapezoid_distance(10.0, 90.0, 30.0, 60.0)
    90.0
    """
    d = abs(distance)
    total = trapezoid_time(d, speed, accel)
    if t >= total:
        return d
    if t <= 0:
        return 0.0
    v = min(speed, math.sqrt(d * accel))  # peak speed
    ta = v / accel
    if t < ta:
        return 0.5 * accel * t * t
    if t <= total - ta:
        return 0.5 * v * ta + v * (t - ta)
    rem = total - t
    return d - 0.5 * accel * rem * rem


@dataclass
class _Move:
    command: str
    start_units: float
    target_units: float
    start_phys_deg: float
    turns_table: bool
    t0: float
    duration_real: float
    duration_sim: float


class HorusFirmware(PtyDevice):
    """The Horus firmware, served from a thread on a pty pair.

    Parameters
    ----------
    link_path
        Stable symlink to the current ``/dev/pts/N`` (e.g.
        ``<tmpdir>/turntable``); ``None`` for a private temporary path.
    steps_per_unit
        Firmware setting $100: motor steps per unit of ``X``.
    steps_per_degree
        Mechanics: motor steps per degree of table rotation
        (default 3200 microsteps per revolution: 1.8 deg motor, 1/16 stepping).
    accel_units_s2
        Firmware setting $120: acceleration (units/s^2).
    feed_units_s
        Feed rate after reset (units/s).
    time_scale
        Real seconds per simulated second (0: motion is instant).
    laser_watchdog_s
        Simulated seconds a laser stays on without being re-commanded.
    lasers
        Number of laser outputs (``T1`` .. ``T<lasers>``).
    faults
        Shared fault switches (a fresh all-off :class:`Faults` if omitted).
    banner
        Banner printed after reset (change it to emulate other firmware).
    on_move_done
        Called as ``on_move_done(angle_deg)`` with the physical table angle
        when a move finishes, before its ``ok`` is sent (in the firmware
        thread, with the firmware's lock held: keep it short and do not call
        back into the firmware's host side).  An exception it raises is
        logged and the ``ok`` is sent anyway.
    """

    _thread_name = "horus-firmware"

    def __init__(
        self,
        link_path: str | os.PathLike[str] | None = None,
        *,
        steps_per_unit: float = 3200.0 / 360.0,
        steps_per_degree: float = 3200.0 / 360.0,
        accel_units_s2: float = 200.0,
        feed_units_s: float = 100.0,
        time_scale: float = 0.0,
        laser_watchdog_s: float = 255.0,
        lasers: int = 2,
        faults: Faults | None = None,
        banner: str = BANNER,
        on_move_done: Callable[[float], None] | None = None,
    ) -> None:
        for name, v in (("steps_per_unit", steps_per_unit), ("steps_per_degree", steps_per_degree),
                        ("accel_units_s2", accel_units_s2), ("feed_units_s", feed_units_s),
                        ("laser_watchdog_s", laser_watchdog_s)):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive finite number, got {v!r}")
        if not (math.isfinite(time_scale) and time_scale >= 0):
            raise ValueError(f"time_scale must be >= 0 (0 = instant motion), got {time_scale!r}")
        if not isinstance(lasers, int) or lasers < 1:
            raise ValueError(f"lasers must be a positive integer, got {lasers!r}")
        if on_move_done is not None and not callable(on_move_done):
            raise ValueError("on_move_done must be a callable taking the table angle in degrees, or None")
        self._open_link(link_path, "horus-", "turntable")
        self.steps_per_unit = float(steps_per_unit)
        self.steps_per_degree = float(steps_per_degree)
        self.accel = float(accel_units_s2)
        self.default_feed = float(feed_units_s)
        self.time_scale = float(time_scale)
        self.laser_watchdog_s = float(laser_watchdog_s)
        self.n_lasers = lasers
        self.faults = faults if faults is not None else Faults()
        self.banner = banner
        self.on_move_done = on_move_done
        self.received: list[str] = []  # every command line, for tests
        self.resets = 0
        self.status_queries = 0
        self._lock = threading.RLock()
        self._phys_deg = 0.0
        self._replug_at: float | None = None
        self._watchdog_now = False
        self._watchdog_on_command = False
        self._power_on()

    # ----------------------------------------------------------- public state
    @property
    def angle_deg(self) -> float:
        """Physical table angle (degrees since the emulator started; thread-safe)."""
        with self._lock:
            return self._phys_now(time.monotonic())

    @property
    def position_units(self) -> float:
        """The firmware's position counter in units of ``X``."""
        with self._lock:
            return self._units_now(time.monotonic())

    @property
    def lasers(self) -> tuple[bool, ...]:
        """On/off state of each laser (T1 first)."""
        with self._lock:
            return tuple(t is not None for t in self._laser_on_since)

    @property
    def motor_enabled(self) -> bool:
        """True after M17, False after M18 or a reset."""
        with self._lock:
            return self._motor

    @property
    def feed_units_s(self) -> float:
        """Current feed rate (units/s)."""
        with self._lock:
            return self._feed

    @property
    def state(self) -> str:
        """``'Idle'``, ``'Run'``, ``'Alarm'`` or ``'Unplugged'``."""
        with self._lock:
            if not self.link.plugged:
                return "Unplugged"
            return self._state()

    # ---------------------------------------------------------------- control
    def _before_unplug(self, now: float) -> None:
        # the board loses power: a move in progress stops where the table is
        self._freeze(now)

    def fire_laser_watchdog(self) -> None:
        """Make the watchdog turn every laser off now (as after 255 s)."""
        with self._lock:
            self._watchdog_now = True

    def release_motor(self) -> None:
        """Release the motor behind the host's back (as a firmware glitch would)."""
        with self._lock:
            self._motor = False

    # ------------------------------------------------------------- internals
    def _power_on(self) -> None:
        self._pos_units = 0.0
        self._motor = False
        self._laser_on_since: list[float | None] = [None] * self.n_lasers
        self._feed = self.default_feed
        self._relative = False
        self._alarm = False
        self._move: _Move | None = None
        self._lines: deque[str] = deque()
        self._inbuf = bytearray()
        self._out = bytearray()
        self._pending: deque[tuple[float, bytes]] = deque()  # (due, reply) command replies
        self._discard_line = False
        self._silent = False

    def _state(self) -> str:
        if self._alarm:
            return "Alarm"
        return "Run" if (self._move or self._pending or self._lines) else "Idle"

    def _fraction(self, now: float) -> float:
        m = self._move
        if m is None or m.duration_real <= 0:
            return 1.0
        t_sim = (now - m.t0) / self.time_scale
        d = abs(m.target_units - m.start_units)
        if d == 0:
            return 1.0
        return trapezoid_distance(t_sim, d, self._feed, self.accel) / d

    def _units_now(self, now: float) -> float:
        m = self._move
        if m is None:
            return self._pos_units
        return m.start_units + self._fraction(now) * (m.target_units - m.start_units)

    def _phys_now(self, now: float) -> float:
        m = self._move
        if m is None or not m.turns_table:
            return self._phys_deg
        return m.start_phys_deg + (self._units_now(now) - m.start_units) * self.steps_per_unit / self.steps_per_degree

    def _freeze(self, now: float) -> None:
        """Stop any move where it is now."""
        if self._move is not None:
            self._phys_deg = self._phys_now(now)
            self._pos_units = self._units_now(now)
            self._move = None

    def _send(self, data: bytes) -> None:
        if self._silent:            # the silent_after_move fault: nothing reaches the host until a reset
            return
        self._out += data

    def _reply(self, text: str, now: float) -> None:
        if self.faults.take("drop_replies"):
            return
        data = text.encode() + b"\r\n"
        if self.faults.take("garbage_replies"):
            data = bytes(self.faults.garbage) + data
        self._pending.append((now + max(0.0, self.faults.reply_delay_s), data))

    def _reset(self, now: float) -> None:
        self._freeze(now)
        self._power_on()
        self.resets += 1
        self._send(b"\r\n" + self.banner.encode() + b"\r\n")

    def _status(self, now: float) -> bytes:
        return f"<{self._state()}|MPos:{self._units_now(now):.3f}|FS:{self._feed:g},0>\r\n".encode()

    def _next_wait(self, now: float) -> float:
        wait = 0.05
        if self._move is not None:
            wait = min(wait, self._move.t0 + self._move.duration_real - now)
        if self._pending:
            wait = min(wait, self._pending[0][0] - now)
        if self._lines and not self._busy():
            wait = 0.0
        return max(0.0, wait)

    def _busy(self) -> bool:
        return self._move is not None or bool(self._pending)

    def _flush(self) -> None:
        if self._out and self.link.plugged:
            try:
                n = os.write(self.link.master_fd, bytes(self._out))
                del self._out[:n]
            except (BlockingIOError, InterruptedError):
                pass
            except OSError:
                self._out.clear()

    def _watchdog(self, now: float, fire: bool) -> None:
        """Turn off every laser on for longer than the watchdog time (every laser if ``fire``)."""
        limit = self.laser_watchdog_s * self.time_scale if self.time_scale > 0 else math.inf
        for i, since in enumerate(self._laser_on_since):
            if since is not None and (fire or now - since >= limit):
                self._laser_on_since[i] = None
                self._send(f"[MSG:Laser {i + 1} off: watchdog]\r\n".encode())

    def _move_finished(self, angle_deg: float) -> None:
        """Callback and watchdog-fault bookkeeping of a finished move (before its ``ok``)."""
        if self.on_move_done is not None:
            try:
                self.on_move_done(angle_deg)
            except Exception:  # the firmware must keep answering whatever the simulator does
                _log.exception("on_move_done(%r) failed", angle_deg)
        if self.faults.take("laser_watchdog_after_moves") and self.faults.laser_watchdog_after_moves == 0:
            self._watchdog_on_command = True

    def _tick(self, now: float) -> None:
        self._watchdog(now, self._watchdog_now)
        self._watchdog_now = False
        progressed = True
        while progressed and self.link.plugged:
            progressed = False
            m = self._move
            if m is not None and now >= m.t0 + m.duration_real:
                self._move = None
                self._pos_units = m.target_units
                if m.turns_table:
                    self._phys_deg = m.start_phys_deg + (m.target_units - m.start_units) * (
                        self.steps_per_unit / self.steps_per_degree)
                self._move_finished(self._phys_deg)
                self._reply("ok", now)
                progressed = True
            while self._pending and self._pending[0][0] <= now:
                self._send(self._pending.popleft()[1])
                progressed = True
            if self._lines and not self._busy():
                self._execute(self._lines.popleft(), now)
                progressed = True
        self._flush()

    def _receive(self, data: bytes, now: float) -> None:
        if self.faults.mute:
            return
        for b in data:
            if b == 0x18:
                self._reset(now)
            elif b == 0x3F:  # '?' real-time status, picked out anywhere
                self.status_queries += 1
                self._send(self._status(now))
            elif b in (0x0A, 0x0D):
                line = self._inbuf.decode("ascii", "replace").strip()
                self._inbuf.clear()
                if line:
                    self._lines.append(line)
            elif len(self._inbuf) < 128:
                self._inbuf.append(b)
        self._tick(now)

    def _execute(self, line: str, now: float) -> None:
        self.received.append(line)
        if self._watchdog_on_command:  # the laser_watchdog_after_moves fault comes due
            self._watchdog_on_command = False
            self._watchdog(now, True)
        if self.faults.take("unplug_on_command"):
            self._freeze(now)
            self.link.unplug()
            after = self.faults.replug_after_s
            self._replug_at = None if after is None else now + after
            return
        if self.faults.take("reset_on_command"):
            self._reset(now)
            return
        cmd = line.upper().replace(" ", "")
        try:
            self._dispatch(line, cmd, now)
        except _FirmwareError as exc:
            self._reply(f"error: {exc}", now)

    def _dispatch(self, line: str, cmd: str, now: float) -> None:
        if cmd == "$":
            self._send(b"[HLP:$$ $X G1 G50 G90 G91 M17 M18 M70 M71 ?]\r\n")
            return self._reply("ok", now)
        if cmd == "$$":
            self._send(f"$100={self.steps_per_unit:.3f}\r\n$120={self.accel:.3f}\r\n".encode())
            return self._reply("ok", now)
        if cmd == "$X":
            self._alarm = False
            self._send(b"[MSG:Caution: Unlocked]\r\n")
            return self._reply("ok", now)
        words = _WORD.findall(cmd)
        if "".join(a + b for a, b in words) != cmd or not words:
            raise _FirmwareError("Invalid statement")
        letter, value = words[0]
        code = float(value)
        params = {a: float(b) for a, b in words[1:]}
        if letter == "G" and code in (0, 1):
            if set(params) - {"X", "F"}:
                raise _FirmwareError("Unsupported axis (the turntable has only X)")
            if "F" in params:
                if not params["F"] > 0:
                    raise _FirmwareError("Invalid feed rate")
                self._feed = params["F"]
            if "X" in params:
                if self._alarm:
                    raise _FirmwareError("Alarm lock")
                return self._start_move(line, params["X"], now)
            return self._reply("ok", now)
        if letter == "G" and code == 50 and not params:
            self._pos_units = 0.0
            return self._reply("ok", now)
        if letter == "G" and code in (90, 91) and not params:
            self._relative = code == 91
            return self._reply("ok", now)
        if letter == "M" and code in (17, 18) and not params:
            self._motor = code == 17
            return self._reply("ok", now)
        if letter == "M" and code in (70, 71):
            t = params.get("T")
            if set(params) != {"T"} or t is None or t != int(t) or not 1 <= t <= self.n_lasers:
                raise _FirmwareError(f"Invalid laser index (T1..T{self.n_lasers})")
            self._laser_on_since[int(t) - 1] = now if code == 71 else None
            return self._reply("ok", now)
        raise _FirmwareError("Unsupported command")

    def _start_move(self, line: str, x: float, now: float) -> None:
        target = self._pos_units + x if self._relative else x
        # the firmware moves in whole steps
        target = round(target * self.steps_per_unit) / self.steps_per_unit
        alarm = self.faults.take_alarm()
        if alarm is not None:
            self._alarm = True
            self._send(f"ALARM:{alarm}\r\n".encode())
            self._reply("error: Alarm lock", now)
            return
        d = abs(target - self._pos_units)
        t_sim = trapezoid_time(d, self._feed, self.accel) if d > 0 else 0.0
        self._move = _Move(line, self._pos_units, target, self._phys_deg, self._motor, now,
                           t_sim * self.time_scale, t_sim)
        if d > 0 and self.faults.take("silent_after_move"):     # a move that turns the table
            self._silent = True


class _FirmwareError(Exception):
    pass
