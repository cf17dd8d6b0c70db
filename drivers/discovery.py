"""Serial port discovery: device path, USB VID:PID, serial number, description.

The rows come from
:func:`serial.tools.list_ports.comports` (pyserial), and :func:`format_ports`
is the table printed by ``kogei devices``.

Examples
--------
>>> rows = [PortInfo("/dev/ttyUSB0", 0x1A86, 0x7523, None, "USB-Serial")]
>>> print(format_ports(rows))
DEVICE        VID:PID    SERIAL  DESCRIPTION
/dev/ttyUSB0  1a86:7523  -       USB-Serial
"""

from __future__ import annotations

from dataclasses import dataclass

from serial.tools import list_ports as _list_ports

__all__ = ["PortInfo", "list_ports", "format_ports"]


@dataclass(frozen=True)
class PortInfo:
    """One serial port.

    Attributes
    ----------
    device
        Path to open (``/dev/ttyUSB0``, ``COM3``).
    vid, pid
        USB vendor and product id, ``None`` for non-USB ports.
    serial_number
        USB serial number string, if the device reports one (stable across
        re-plugging: use it to tell two identical adapters apart).
    description
        Human-readable description from the OS.
    """

    device: str
    vid: int | None
    pid: int | None
    serial_number: str | None
    description: str

    @property
    def vid_pid(self) -> str | None:
        """``'vvvv:pppp'`` in lower-case hex, or ``None``."""
        if self.vid is None or self.pid is None:
            return None
        return f"{self.vid:04x}:{self.pid:04x}"


def list_ports(include_non_usb: bool = False) -> list[PortInfo]:
    """Serial ports present now, sorted by device path.

    Parameters
    ----------
    include_non_usb
        Also list ports without a USB VID:PID (on-board UARTs, which Linux
        lists by the dozen as ``/dev/ttyS*``).

    Returns
    -------
    list of PortInfo
    """
    rows = []
    for p in _list_ports.comports():
        if p.vid is None and not include_non_usb:
            continue
        desc = p.description if p.description and p.description != "n/a" else ""
        rows.append(PortInfo(p.device, p.vid, p.pid, p.serial_number or None, desc))
    return sorted(rows, key=lambda r: r.device)


def format_ports(rows: list[PortInfo]) -> str:
    """A plain-text table of ``rows`` (or a hint when there are none).

    Examples
    --------
    >>> format_ports([])
    'no serial ports found (is the device plugged in? try include_non_usb=True)'
    """
    if not rows:
        return "no serial ports found (is the device plugged in? try include_non_usb=True)"
    table = [("DEVICE", "VID:PID", "SERIAL", "DESCRIPTION")]
    table += [(r.device, r.vid_pid or "-", r.serial_number or "-", r.description or "-") for r in rows]
    widths = [max(len(row[i]) for row in table) for i in range(3)]
    return "\n".join(
        "  ".join(cell.ljust(w) for cell, w in zip(row[:3], widths)) + "  " + row[3] for row in table
    )
