"""``kogei demo``: the whole product on simulated devices (a shell over :func:`app.demo.showcase.run_demo`)."""

from __future__ import annotations

import argparse

from app.demo.capture import DEMO_PASSES

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add ``kogei demo`` to the subcommands."""
    p = sub.add_parser("demo", help="render the showcase (procedural hawk, material spheres)")
    p.add_argument("--out", default="out/demo", metavar="DIR",
                   help="folder for the images, the simulated sessions and demo.json (default %(default)s)")
    p.add_argument("--preset", default="standard", choices=["draft", "standard", "reference"],
                   help="speed against accuracy of the renders and the geometry: draft, standard, reference "
                        "(docs/rendering.md, docs/processing.md) (default %(default)s)")
    p.add_argument("--hawk-triangles", type=int, default=None, metavar="N",
                   help="triangle count of the hawk mesh (default: about 1M)")
    p.add_argument("--size", default=None, metavar="WxH", help="render size in pixels (default 1024x768)")
    p.add_argument("--capture-steps", type=int, default=120, metavar="N",
                   help="profiles per revolution of the simulated capture session (0: no capture) "
                        "(default %(default)s)")
    p.add_argument("--capture-passes", type=int, default=DEMO_PASSES, metavar="P",
                   help="placements of the simulated capture (default %(default)s)")
    p.add_argument("--capture-camera", default="gphoto2", choices=["gphoto2", "hotfolder", "none"],
                   help="camera of the simulated capture (default %(default)s)")


def run(args: argparse.Namespace) -> int:
    """Run the demo into ``args.out``."""
    from app.demo.showcase import run_demo

    return run_demo(args)
