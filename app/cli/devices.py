"""``kogei devices``: the serial ports present, to pick the turntable's and the profiler's."""

from __future__ import annotations

import argparse
import dataclasses
import json

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add ``kogei devices`` to the subcommands."""
    p = sub.add_parser("devices", help="list serial ports with USB VID:PID and serial number")
    p.add_argument("--all", action="store_true", help="also list ports without a USB id (on-board UARTs)")
    p.add_argument("--json", action="store_true", help="print the ports as JSON")


def run(args: argparse.Namespace) -> int:
    from drivers.discovery import format_ports, list_ports

    rows = list_ports(include_non_usb=args.all)
    if args.json:
        print(json.dumps([dataclasses.asdict(r) for r in rows], indent=2))
    elif not rows:
        hint = "" if args.all else "; 'kogei devices --all' also lists ports without a USB id"
        print(f"no serial ports found (is the device plugged in and powered?){hint}")
    else:
        print(format_ports(rows))
    return 0
