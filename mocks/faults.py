"""Fault injection for the simulated devices: the switches and the ``--faults`` mini-language.

The simulated devices inject the faults a capture station meets (unplugged
cable, line noise, lost and slow replies, spontaneous resets, the laser
watchdog) so the drivers' recovery paths run in tests (docs/simulator.md,
"Faults"; docs/protocols.md).  A :class:`Faults` object is shared between
the test (or ``kogei mock``) thread and the emulator thread; every field may
be changed at run time.  Counters ("the next N replies") are consumed
atomically with :meth:`Faults.take`.  :class:`HotFolderFaults` are the
simulated tethering program's switches.

``kogei mock --faults`` names faults as ``DEVICE.NAME=VALUE`` items
(:data:`FAULT_NAMES`); :func:`parse_faults` reads them and
:func:`format_faults` writes them back.

Examples
--------
>>> f = Faults(drop_replies=1)
>>> f.take("drop_replies"), f.take("drop_replies")
(True, False)
>>> parse_faults("camera.busy=2,world.chart_present=off")
{'camera': {'busy': 2}, 'world': {'chart_present': False}}
"""

from __future__ import annotations

import math
import re
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from processing.errors import InputError

__all__ = [
    "Faults",
    "DEFAULT_GARBAGE",
    "HotFolderFaults",
    "FAULT_NAMES",
    "FaultSpecError",
    "parse_faults",
    "format_faults",
]

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
    silent_after_move
        For the turntable: number of next moves that turn the table after
        which the device sends nothing (the move's ``ok``, status replies,
        messages) until it is reset; the move itself runs to its end.  What
        the host sees when the board's replies stop reaching it mid-move (a
        stalled USB link, a host too busy to read them in time): a move whose
        end it cannot know.
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
    silent_after_move: int = 0
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


@dataclass
class HotFolderFaults:
    """Run-time switchable faults of the simulated tethering program (all off by default).

    Attributes
    ----------
    partial
        Number of next shots that leave a truncated file in the hot folder
        (a download cut short); such a shot does not use up the chart frame.
    saturate
        Number of next shots over-exposed (bright pixels at the white level).

    Examples
    --------
    >>> f = HotFolderFaults(partial=1)
    >>> f.take("partial"), f.take("partial")
    (True, False)
    """

    partial: int = 0
    saturate: int = 0
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)

    def take(self, name: str) -> bool:
        """Consume one unit of the counter ``name``; True if one was left."""
        with self._lock:
            n = int(getattr(self, name))
            if n > 0:
                setattr(self, name, n - 1)
                return True
            return False


# ------------------------------------------------------------------ the --faults syntax
#: Faults ``kogei mock --faults`` knows, per device, with the kind of value each takes.
FAULT_NAMES: dict[str, dict[str, str]] = {
    "turntable": {
        "garbage_replies": "count", "drop_replies": "count", "reply_delay_s": "seconds",
        "reset_on_command": "count", "unplug_on_command": "count", "replug_after_s": "seconds",
        "alarm_on_move": "text", "mute": "switch", "laser_watchdog_after_moves": "count",
        "silent_after_move": "count",
    },
    "profiler": {
        "garbage_replies": "count", "drop_replies": "count", "reply_delay_s": "seconds",
        "reset_on_command": "count", "unplug_on_command": "count", "replug_after_s": "seconds",
        "mute": "switch", "corrupt_frames": "count", "drop_frames": "count", "garbage_frames": "count",
    },
    "camera": {
        "no_camera": "switch", "busy": "count", "slow_s": "seconds", "exit_code": "exit code",
        "no_output": "switch", "saturate": "switch",
    },
    "hotfolder": {"partial": "count", "saturate": "count"},
    "world": {"chart_present": "switch", "chart_outside": "switch"},
}

_KIND_HELP = {
    "count": "a whole number >= 0",
    "seconds": "a number of seconds >= 0",
    "switch": "1/0, true/false, on/off or yes/no",
    "text": "some text",
    "exit code": "a whole number 0..255",
}
_TRUE = {"1", "true", "yes", "on"}
_FALSE = {"0", "false", "no", "off"}


class FaultSpecError(InputError):
    """A ``--faults`` item is not valid; the message names it and lists what is known."""


def _fault_value(item: str, device: str, name: str, text: str) -> Any:
    """The value ``text`` of fault ``device.name`` as its kind reads it (``item`` names it in errors)."""
    kind = FAULT_NAMES[device][name]
    low = text.strip().lower()
    bad = FaultSpecError(f"fault {item!r}: {device}.{name} takes {_KIND_HELP[kind]}, got {text.strip()!r}")
    if kind == "switch":
        if low in _TRUE:
            return True
        if low in _FALSE:
            return False
        raise bad
    if kind in ("count", "exit code"):
        if not re.fullmatch(r"\+?\d+", low):
            raise bad
        n = int(low)
        if kind == "exit code" and n > 255:
            raise bad
        return n
    if kind == "seconds":
        try:
            x = float(low)
        except ValueError:
            raise bad from None
        if not (math.isfinite(x) and x >= 0):
            raise bad
        return x
    if not text.strip():
        raise bad
    return text.strip()


def parse_faults(spec: str | Sequence[str]) -> dict[str, dict[str, Any]]:
    """Parse ``DEVICE.NAME=VALUE[,DEVICE.NAME=VALUE...]`` into ``{device: {name: value}}``.

    Devices and names are those of :data:`FAULT_NAMES`; values are counts,
    seconds, switches (1/0, true/false, on/off, yes/no) or text by name.  A
    sequence of specs (a repeated ``--faults``) is read as one.

    Raises
    ------
    FaultSpecError
        One line naming the bad item and listing what is known.

    Examples
    --------
    >>> parse_faults("turntable.garbage_replies=3,camera.busy=1,turntable.replug_after_s=1.5")
    {'turntable': {'garbage_replies': 3, 'replug_after_s': 1.5}, 'camera': {'busy': 1}}
    >>> parse_faults("turntable.garbage=3")
    Traceback (most recent call last):
    ...
    mocks.faults.FaultSpecError: fault 'turntable.garbage=3': unknown turntable fault 'garbage'; known: garbage_replies, drop_replies, reply_delay_s, reset_on_command, unplug_on_command, replug_after_s, alarm_on_move, mute, laser_watchdog_after_moves, silent_after_move
    """
    items: list[str] = []
    for part in ([spec] if isinstance(spec, str) else list(spec)):
        items.extend(i.strip() for i in str(part).split(","))
    out: dict[str, dict[str, Any]] = {}
    for item in items:
        if not item:
            continue
        key, eq, value = item.partition("=")
        device, dot, name = key.strip().partition(".")
        if not eq or not dot:
            raise FaultSpecError(f"fault {item!r}: write DEVICE.NAME=VALUE, e.g. turntable.garbage_replies=3; "
                                 f"devices: {', '.join(FAULT_NAMES)}")
        if device not in FAULT_NAMES:
            raise FaultSpecError(f"fault {item!r}: unknown device {device!r}; known: {', '.join(FAULT_NAMES)}")
        if name not in FAULT_NAMES[device]:
            raise FaultSpecError(f"fault {item!r}: unknown {device} fault {name!r}; "
                                 f"known: {', '.join(FAULT_NAMES[device])}")
        out.setdefault(device, {})[name] = _fault_value(item, device, name, value)
    return out


def format_faults(faults: Mapping[str, Mapping[str, Any]]) -> str:
    """The inverse of :func:`parse_faults` (for messages); ``"none"`` when empty.

    Examples
    --------
    >>> format_faults({"camera": {"busy": 1, "no_camera": True}})
    'camera.busy=1,camera.no_camera=1'
    """
    parts = [f"{d}.{n}={int(v) if isinstance(v, bool) else v}" for d, names in faults.items()
             for n, v in names.items()]
    return ",".join(parts) or "none"
