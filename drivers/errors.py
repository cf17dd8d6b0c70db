"""Errors raised by the device drivers.

Every read has a deadline and every failure
names the port or the command, so a capture session can tell a cable that was
pulled (:class:`TransportClosed`, recover with ``reconnect()``) from a device
that refused a command (:class:`DeviceError`) or stopped answering
(:class:`DeviceTimeout`).

Hierarchy::

    DriverError
    +-- TransportError
    |   +-- TransportTimeout   (also a TimeoutError)
    |   +-- TransportClosed    (also a ConnectionError)
    +-- DeviceError            (.command, .text)
        +-- DeviceAlarm
        +-- DeviceResetError
        +-- DeviceTimeout      (also a TimeoutError)
        +-- HandshakeError

Examples
--------
>>> e = DeviceError("G1 X10", "Invalid gcode ID:24")
>>> str(e)
"device answered 'error: Invalid gcode ID:24' to command 'G1 X10'"
>>> isinstance(TransportTimeout("/dev/pts/3", "no line"), TimeoutError)
True
"""

from __future__ import annotations

__all__ = [
    "DriverError",
    "ResetSeen",
    "TransportError",
    "TransportTimeout",
    "TransportClosed",
    "DeviceError",
    "DeviceAlarm",
    "DeviceResetError",
    "DeviceTimeout",
    "HandshakeError",
]


class DriverError(Exception):
    """Base class of every error raised by :mod:`drivers`."""


class TransportError(DriverError):
    """A failure of the byte link itself; ``port`` names the port or URL.

    Parameters
    ----------
    port
        The port path or pyserial URL.
    message
        What went wrong and what to do about it.
    """

    def __init__(self, port: str, message: str) -> None:
        self.port = port
        super().__init__(f"{port}: {message}")


class TransportTimeout(TransportError, TimeoutError):
    """No complete line / frame arrived before the read deadline.

    ``partial`` holds the bytes received so far (they stay buffered in the
    transport too, so a later read still sees them).
    """

    def __init__(self, port: str, message: str, partial: bytes = b"") -> None:
        self.partial = partial
        super().__init__(port, message)


class TransportClosed(TransportError, ConnectionError):
    """The port vanished (unplugged, I/O error) or was never opened.

    Recover with ``SerialTransport.reopen()`` (or the device's
    ``reconnect()``) once the port is back.
    """


class DeviceError(DriverError):
    """The device answered a command with an error.

    Parameters
    ----------
    command
        The command line that was sent (without line terminator).
    text
        The device's error text (for Horus, what follows ``error:``).
    """

    def __init__(self, command: str, text: str, message: str | None = None) -> None:
        self.command = command
        self.text = text
        super().__init__(message or f"device answered 'error: {text}' to command {command!r}")


class DeviceAlarm(DeviceError):
    """An ``ALARM:`` line arrived while ``command`` was pending."""

    def __init__(self, command: str, text: str, reply: str | None = None) -> None:
        self.reply = reply
        then = f" (then answered {reply!r})" if reply else ""
        super().__init__(command, text, f"device raised 'ALARM:{text}' while command {command!r} was pending"
                                        f"{then}; the move was aborted: remove the cause, then reset the "
                                        "device with connect() and check the table angle")


class DeviceResetError(DeviceError):
    """The device reset itself (its banner arrived) while ``command`` was pending."""

    def __init__(self, command: str, text: str) -> None:
        super().__init__(command, text, f"device reset (banner {text!r}) while command {command!r} was pending")


class DeviceTimeout(DeviceError, TimeoutError):
    """No reply to ``command`` before its deadline, and no status reply either."""

    def __init__(self, command: str, text: str) -> None:
        super().__init__(command, text, f"no reply to command {command!r}: {text}")


class HandshakeError(DeviceError):
    """The device did not identify itself as the expected firmware."""

    def __init__(self, command: str, text: str) -> None:
        super().__init__(command, text, text)


class ResetSeen(Exception):
    """Internal signal of a driver: the device's power-on banner arrived while a
    command was pending (it reset); the driver restores its state or raises
    :class:`DeviceResetError`.  Never reaches a caller."""

    def __init__(self, banner: str) -> None:
        super().__init__(banner)
        self.banner = banner
