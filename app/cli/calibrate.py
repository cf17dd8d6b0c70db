"""``kogei calibrate``: the scanner calibration from a session that scanned a reference sphere.

A shell over :func:`app.workflows.calibration.calibrate_session`; other
sessions use the result with ``kogei process SESSION --calibration
CAL_SESSION``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from app.workflows.calibration import calibrate_session

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibrate", help="scanner calibration from a session that scanned a reference sphere",
                       description="Fit the laser plane's pose relative to the table axis from one pass of a "
                                   "sphere of known radius on the table; store it in the session.")
    p.add_argument("session", metavar="SESSION")
    p.add_argument("--sphere-radius", type=float, required=True, metavar="MM",
                   help="radius of the reference sphere (mm, from its certificate)")
    p.add_argument("--sphere-height", type=float, default=None, metavar="MM",
                   help="height of the sphere's centre above the table if the table top is not in view "
                        "(a sphere resting on the table: its radius)")
    p.add_argument("--pass", dest="pass_no", type=int, default=1, metavar="N", help="which pass to use (default 1)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")


def run(args: argparse.Namespace) -> int:
    ref = calibrate_session(args.session, args.sphere_radius, sphere_height_mm=args.sphere_height,
                            pass_no=args.pass_no)
    if args.json:
        print(json.dumps(ref, indent=1))
    else:
        print(f"calibrated {args.session}: sphere residual rms {ref['rms_mm']:.4f} mm, max {ref['max_mm']:.4f} mm "
              f"-> {Path(args.session) / ref['path']}")
    return 0
