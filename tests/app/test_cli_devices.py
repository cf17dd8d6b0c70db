"""`kogei devices` against pyserial's own enumeration of the machine's ports."""

from __future__ import annotations

import json

from serial.tools import list_ports as pyserial_ports

from app.cli import main


def test_devices_json_lists_every_port_pyserial_sees(capsys):
    assert main(["devices", "--all", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert sorted(r["device"] for r in rows) == sorted(p.device for p in pyserial_ports.comports())
    for r in rows:
        assert set(r) >= {"device", "vid", "pid", "serial_number", "description"}


def test_devices_without_all_shows_only_usb_ports(capsys):
    assert main(["devices", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    usb = sorted(p.device for p in pyserial_ports.comports() if p.vid is not None)
    assert sorted(r["device"] for r in rows) == usb
    assert main(["devices"]) == 0
    text = capsys.readouterr().out
    if not usb:
        assert "--all" in text
    else:
        assert all(d in text for d in usb)
