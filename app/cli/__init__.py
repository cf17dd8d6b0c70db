"""The ``kogei`` command line: a thin shell over the library calls.

One module per subcommand in this package, each exporting ``add_parser(sub)``
(its arguments) and ``run(args) -> int`` (a call into the workflows the GUI
and the batch runner use); :data:`COMMANDS` lists them in the order
``kogei --help`` shows: the order a session's work runs, from the station to
the products.  Bad input ends as a one-line message with exit code 2, never a
traceback: every input error derives from
:class:`processing.errors.InputError` and is caught here, once.  Output into a
pipe that closes early (``kogei materials gold | head``) ends quietly, as in
the Python documentation's note on SIGPIPE.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Sequence

from app.errors import caused_by_ctrl_c
from processing.errors import InputError

__all__ = ["main", "build_parser", "version", "COMMANDS", "EXIT_USAGE", "EXIT_BROKEN_PIPE"]

EXIT_USAGE = 2

#: Exit status when the reader of the output went away (``| head``), as the Python documentation advises.
EXIT_BROKEN_PIPE = 1

#: Subcommand name -> module of this package that implements it, in the order a session's work runs:
#: the station, calibration, geometry, appearance, the products, then everything at once.
COMMANDS = {
    "mock": "mock", "devices": "devices", "capture": "capture", "calibrate": "calibrate",
    "process": "process", "project": "project", "register": "register",
    "fit-materials": "fit_materials", "chart": "chart", "spectral": "spectral", "identify": "identify",
    "cloth": "cloth", "materials": "materials", "probe": "probe",
    "render": "render", "export": "export", "report": "report",
    "batch": "batch", "gui": "gui", "demo": "demo",
}

_EPILOG = """\
Commands are listed in the order a session's work runs: a station (mock, devices), capture,
calibration, geometry (process, project, register), appearance (fit-materials, chart, spectral,
identify, cloth, materials, probe), the products (render, export, report), then everything at once (batch,
gui, demo).  'kogei COMMAND --help' describes one; docs/ in the repository has the details."""


def _module(command: str):
    return importlib.import_module(f"app.cli.{COMMANDS[command]}")


def version() -> str:
    """The installed kogei's version (``pyproject.toml``'s when run from a checkout that is not installed)."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as dist_version

    try:
        return dist_version("kogei")
    except PackageNotFoundError:
        import tomllib
        from pathlib import Path

        pyproject = Path(__file__).resolve().parents[2] / "pyproject.toml"
        try:
            return str(tomllib.loads(pyproject.read_text(encoding="utf-8"))["project"]["version"])
        except (OSError, KeyError, tomllib.TOMLDecodeError):
            return "unknown"


def build_parser() -> argparse.ArgumentParser:
    """The ``kogei`` argument parser with every subcommand of :data:`COMMANDS`."""
    parser = argparse.ArgumentParser(
        prog="kogei",
        description="kogei: digitise craft objects as geometry plus spectral appearance.",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"kogei {version()}",
                        help="print kogei's version and exit")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for command in COMMANDS:
        _module(command).add_parser(sub)
    return parser


def _quiet_broken_pipe() -> int:
    """Point stdout at /dev/null so the interpreter's final flush cannot fail again; the exit status."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass
    return EXIT_BROKEN_PIPE


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``kogei`` with ``argv`` (default: the process's arguments); returns the exit code."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except BrokenPipeError:             # --help or --version into a closed pipe
        return _quiet_broken_pipe()
    try:
        status = _module(args.command).run(args)
        sys.stdout.flush()              # a closed pipe fails here, not in the interpreter's final flush
        return status
    except BrokenPipeError:
        return _quiet_broken_pipe()
    except InputError as exc:
        print(f"kogei {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print(f"kogei {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        from app.capture.runner import CaptureInterrupted

        if caused_by_ctrl_c(exc):       # a Ctrl-C wrapped by a compiled module's import
            print(f"kogei {args.command}: interrupted", file=sys.stderr)
            return 130
        if not isinstance(exc, CaptureInterrupted):
            raise
        print(f"kogei {args.command}: {exc}", file=sys.stderr)
        return 130 if exc.reason == "cancelled" else 1


if __name__ == "__main__":
    sys.exit(main())
