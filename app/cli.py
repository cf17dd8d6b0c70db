"""The ``kogei`` command line: a thin shell over the library calls.

Every subcommand parses its arguments, calls the same functions the GUI and
the batch runner use, and turns bad input into a one-line message with exit
code 2 (never a traceback).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from app.errors import UsageError

__all__ = ["main", "build_parser"]

EXIT_USAGE = 2


def _add_render(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "render",
        help="render a mesh or a TOML scene spectrally to an sRGB PNG (and float XYZ TIFF)",
        description="Render MESH (PLY/OBJ/STL/glTF) or a TOML scene file.",
    )
    p.add_argument("scene", metavar="MESH|SCENE.toml")
    p.add_argument("--material", default=None,
                   help="preset name with optional overrides, e.g. gold:roughness=0.2,mirror=0 "
                        "(see 'kogei materials'); default gold")
    p.add_argument("--light", action="append", default=[], metavar="SPEC",
                   help="directional:DX,DY,DZ (toward the light) or point:X,Y,Z; optional @SPECTRUM "
                        "and *INTENSITY; repeatable")
    p.add_argument("--illuminant", default=None, help="D65, A, D50, F2, ..., a CCT such as 3200K, or a CSV file")
    p.add_argument("--sky", default=None, choices=["uniform", "gradient", "none"],
                   help="environment seen in mirror reflections (default gradient)")
    p.add_argument("--eye", default=None, metavar="X,Y,Z")
    p.add_argument("--target", default=None, metavar="X,Y,Z")
    p.add_argument("--up", default=None, metavar="X,Y,Z")
    p.add_argument("--fov", type=float, default=None, metavar="DEG", help="vertical field of view")
    p.add_argument("--size", default=None, metavar="WxH", help="image size, default 800x600")
    p.add_argument("--preset", default=None, choices=["draft", "standard", "reference"])
    p.add_argument("--weave-angle", type=float, default=None, metavar="DEG",
                   help="weave orientation for cloth materials")
    p.add_argument("--out", required=True, metavar="IMG.png")
    p.add_argument("--xyz", default=None, metavar="IMG.tiff", help="also write float32 CIE XYZ")
    p.add_argument("--quiet", action="store_true")


def _add_materials(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("materials", help="list material presets, or the parameters of one")
    p.add_argument("name", nargs="?", help="a preset name (optionally with overrides)")


def _add_demo(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="render the showcase (procedural hawk, material spheres)")
    p.add_argument("--out", default="out/demo")
    p.add_argument("--preset", default="standard", choices=["draft", "standard", "reference"])
    p.add_argument("--hawk-triangles", type=int, default=None,
                   help="triangle count of the hawk mesh (default: about 1M)")
    p.add_argument("--size", default=None, metavar="WxH")
    p.add_argument("--capture-steps", type=int, default=120, metavar="N",
                   help="profiles per revolution of the simulated capture session (0: no capture)")
    p.add_argument("--capture-passes", type=int, default=3, metavar="P", help="placements of the simulated capture")
    p.add_argument("--capture-camera", default="gphoto2", choices=["gphoto2", "hotfolder", "none"],
                   help="camera of the simulated capture")


def _add_devices(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("devices", help="list serial ports with USB VID:PID and serial number")
    p.add_argument("--all", action="store_true", help="also list ports without a USB id (on-board UARTs)")
    p.add_argument("--json", action="store_true", help="print the ports as JSON")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="kogei",
        description="kogei: digitise craft objects as geometry plus spectral appearance.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_render(sub)
    _add_materials(sub)
    _add_demo(sub)
    _add_devices(sub)
    from app.capture_command import add_capture_parser

    add_capture_parser(sub)
    from app.mock_command import add_mock_parser

    add_mock_parser(sub)
    from app.calibrate_command import add_calibrate_parser

    add_calibrate_parser(sub)
    from app.process_command import add_process_parser

    add_process_parser(sub)
    from app.register_command import add_register_parser

    add_register_parser(sub)
    from app.gui_command import add_gui_parser

    add_gui_parser(sub)
    from app.chart_command import add_chart_parser

    add_chart_parser(sub)
    from app.batch_command import add_batch_parser

    add_batch_parser(sub)
    from app.report_command import add_report_parser

    add_report_parser(sub)
    from app.cloth_command import add_cloth_parser

    add_cloth_parser(sub)
    from app.spectral_command import add_spectral_parser

    add_spectral_parser(sub)
    from app.identify_command import add_identify_parser

    add_identify_parser(sub)
    return parser


def _run(args: argparse.Namespace) -> int:
    # Imports are deferred so that `kogei --help` answers instantly.
    if args.command == "render":
        from app.render_command import run_render

        return run_render(args)
    if args.command == "materials":
        from app.materials_command import run_materials

        return run_materials(args)
    if args.command == "demo":
        from app.demo import run_demo

        return run_demo(args)
    if args.command == "devices":
        from app.devices_command import run_devices

        return run_devices(args)
    if args.command == "capture":
        from app.capture_command import run_capture_command

        return run_capture_command(args)
    if args.command == "mock":
        from app.mock_command import run_mock

        return run_mock(args)
    if args.command == "calibrate":
        from app.calibrate_command import run_calibrate

        return run_calibrate(args)
    if args.command == "process":
        from app.process_command import run_process

        return run_process(args)
    if args.command == "register":
        from app.register_command import run_register

        return run_register(args)
    if args.command == "chart":
        from app.chart_command import run_chart

        return run_chart(args)
    if args.command == "batch":
        from app.batch_command import run_batch_command

        return run_batch_command(args)
    if args.command == "report":
        from app.report_command import run_report

        return run_report(args)
    if args.command == "gui":
        from app.gui_command import run_gui

        return run_gui(args)
    if args.command == "cloth":
        from app.cloth_command import run_cloth

        return run_cloth(args)
    if args.command == "spectral":
        from app.spectral_command import run_spectral

        return run_spectral(args)
    if args.command == "identify":
        from app.identify_command import run_identify

        return run_identify(args)
    raise AssertionError(args.command)  # argparse only admits the commands above


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return _run(args)
    except UsageError as exc:
        print(f"kogei {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except Exception as exc:
        from app.capture import CaptureInterrupted

        if not isinstance(exc, CaptureInterrupted):
            raise
        print(f"kogei {args.command}: {exc}", file=sys.stderr)
        return 130 if exc.reason == "cancelled" else 1
    except KeyboardInterrupt:
        print(f"kogei {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
