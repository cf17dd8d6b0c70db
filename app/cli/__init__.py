"""The ``kogei`` command line: a thin shell over the library calls.

One module per subcommand in this package, each exporting ``add_parser(sub)``
(its arguments) and ``run(args) -> int`` (a call into the workflows the GUI
and the batch runner use); :data:`COMMANDS` lists them in the order
``kogei --help`` shows.  Bad input ends as a one-line message with exit code
2, never a traceback: every input error derives from
:class:`processing.errors.InputError` and is caught here, once.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from processing.errors import InputError

__all__ = ["main", "build_parser", "COMMANDS", "EXIT_USAGE"]

EXIT_USAGE = 2

#: Subcommand name -> module of this package that implements it.
COMMANDS = {
    "render": "render", "materials": "materials", "demo": "demo", "devices": "devices",
    "capture": "capture", "mock": "mock", "calibrate": "calibrate", "process": "process",
    "project": "project", "fit-materials": "fit_materials",
    "register": "register", "gui": "gui", "chart": "chart", "batch": "batch", "report": "report",
    "cloth": "cloth", "spectral": "spectral", "identify": "identify",
    "export": "export",
}


def _module(command: str):
    return importlib.import_module(f"app.cli.{COMMANDS[command]}")


def build_parser() -> argparse.ArgumentParser:
    """The ``kogei`` argument parser with every subcommand of :data:`COMMANDS`."""
    parser = argparse.ArgumentParser(
        prog="kogei",
        description="kogei: digitise craft objects as geometry plus spectral appearance.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for command in COMMANDS:
        _module(command).add_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``kogei`` with ``argv`` (default: the process's arguments); returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return _module(args.command).run(args)
    except InputError as exc:
        print(f"kogei {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print(f"kogei {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        from app.capture.runner import CaptureInterrupted

        if not isinstance(exc, CaptureInterrupted):
            raise
        print(f"kogei {args.command}: {exc}", file=sys.stderr)
        return 130 if exc.reason == "cancelled" else 1


if __name__ == "__main__":
    sys.exit(main())
