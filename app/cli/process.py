"""``kogei process``: mesh a captured session (a thin shell over :func:`app.workflows.process_session.process_session`)."""

from __future__ import annotations

import argparse
import json
import sys

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("process", help="profiles of a captured session -> registered, watertight mesh + report",
                       description="Turn a session's profiles into point clouds, register the passes, mesh the "
                                   "merged cloud and write products/mesh.ply and products/process-report.json.")
    p.add_argument("session", metavar="SESSION")
    p.add_argument("--preset", default="standard", choices=["draft", "standard", "reference"])
    p.add_argument("--calibration", default=None, metavar="CAL_SESSION|CAL.json",
                   help="install this scanner calibration into the session first")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.add_argument("--quiet", action="store_true")


def run(args: argparse.Namespace) -> int:
    from app.workflows.process_session import process_session

    def message(text: str) -> None:
        if not args.quiet:
            print(f"  {text}", file=sys.stderr)

    report = process_session(args.session, preset=args.preset, calibration=args.calibration, message=message)
    if args.json:
        print(json.dumps(report, indent=1))
        return 0
    reg = report["registration"]
    print(f"session {args.session}: {sum(1 for p in report['passes'] if p.get('registered'))} of "
          f"{len(report['passes'])} passes registered"
          + ("" if reg["consistency"] is None else
             f" (pose graph: {reg['consistency']['max_rotation_deg']:.3f} deg, "
             f"{reg['consistency']['max_displacement_mm']:.3f} mm)"))
    for p in report["passes"]:
        state = p.get("skipped") or f"{p['points']} points"
        print(f"  pass {p['pass']}: {state}")
    m = report["mesh"]
    print(f"mesh: {m['triangles']} triangles, {'watertight' if m['watertight'] else 'NOT watertight'} -> "
          f"{args.session}/{m['file']} ({report['timings_s']['total']:.1f} s)")
    return 0
