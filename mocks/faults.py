"""Fault-injection settings shared by the device emulators.

DESIGN.md section 3 ("Devices"): the simulated devices inject the faults a
capture station meets (unplugged cable, line noise, lost and slow replies,
spontaneous resets, the laser watchdog) so the drivers' recovery paths run in
tests.  A :class:`Faults` object is shared between the test (or ``kogei
mock``) thread and the emulator thread; every field may be changed at run
time.  Counters ("the next N replies") are consumed atomically with
:meth:`Faults.take`.

Examples
--------
>>> f = Faults(drop_replies=1)
>>> f.take("drop_replies"), f.take("drop_replies")
(True, False)
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

__all__ = ["Faults", "DEFAULT_GARBAGE"]

#: Line noise as a wrong baud rate or a ground loop produces it: high-bit and
#: control bytes, no newline.
DEFAULT_GARBAGE = bytes([0xF0, 0x00, 0x93, 0xFE, 0x07, 0x81, 0xC3, 0x1B])


@dataclass
class Faults:
    """Run-time switchable faults (all off by default).

    Attributes
    ----------
    garbage_replies
        Number of next replies preceded by ``garbage`` bytes (no newline, so
        the garbage lands at the start of the reply line).
    garbage
        The injected bytes.
    drop_replies
        Number of next command replies (``ok``/``error:``) never sent.
    reply_delay_s
        Extra real seconds before every command reply (a slow device).
    reset_on_command
        Number of next command lines at whose arrival the device resets
        (power brown-out): the command is lost and the banner is sent.
    unplug_on_command
        Number of next command lines at whose arrival the device is
        unplugged (the pseudo-terminal disappears); ``replug()`` restores it.
    replug_after_s
        If set, an unplugged emulator plugs itself back in after this many
        real seconds (as a user re-seating the cable); ``None`` waits for an
        explicit ``replug()``.
    alarm_on_move
        If set, the next move is aborted with ``ALARM:<text>``.
    mute
        While True the device ignores everything it receives (a hung
        firmware: no replies, no status, no reset).
    laser_watchdog_after_moves
        For the turntable: counts down by one per finished move; when it
        reaches 0 the laser watchdog fires as the next command line arrives
        (every laser off, ``[MSG:Laser <n> off: watchdog]``, before that
        command runs), as if the lasers had been left on too long while the
        host was busy.  A host that re-asserts the lasers at every step
        recovers at once; one that switched them on once does not.
    corrupt_frames, drop_frames
        For binary-frame emulators: number of next frames sent with a bad
        CRC / not sent.
    garbage_frames
        For binary-frame emulators: number of next frames preceded by
        ``garbage`` bytes (the reader must resynchronise on the magic).
    """

    garbage_replies: int = 0
    garbage: bytes = DEFAULT_GARBAGE
    drop_replies: int = 0
    reply_delay_s: float = 0.0
    reset_on_command: int = 0
    unplug_on_command: int = 0
    replug_after_s: float | None = None
    alarm_on_move: str | None = None
    mute: bool = False
    laser_watchdog_after_moves: int = 0
    corrupt_frames: int = 0
    drop_frames: int = 0
    garbage_frames: int = 0
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)

    def take(self, name: str) -> bool:
        """Consume one unit of the counter ``name``; True if one was left."""
        with self._lock:
            n = getattr(self, name)
            if not isinstance(n, int) or isinstance(n, bool):
                raise ValueError(f"Faults.{name} is not a counter")
            if n > 0:
                setattr(self, name, n - 1)
                return True
            return False

    def take_alarm(self) -> str | None:
        """Consume and return ``alarm_on_move``."""
        with self._lock:
            text, self.alarm_on_move = self.alarm_on_move, None
            return text
