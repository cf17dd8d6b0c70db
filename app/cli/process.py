"""``kogei process``: mesh a captured session (a thin shell over :func:`app.workflows.process_session.process_session`)."""

from __future__ import annotations

import argparse
import json
import sys

__all__ = ["add_parser", "run", "projection_line", "EXIT_PARTIAL"]

#: Exit status of a partial result: a pass left out of the mesh or a mesh that is not watertight.
EXIT_PARTIAL = 1


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("process", help="profiles of a captured session -> registered, watertight mesh + report",
                       description="Turn a session's profiles into point clouds, register the passes, mesh the "
                                   "merged cloud and write products/mesh.ply and products/process-report.json. "
                                   "Exit status 0: every pass registered and the mesh watertight; 1: a partial "
                                   "result (written, with the reason and what to capture in the report); 2: bad "
                                   "input.")
    p.add_argument("session", metavar="SESSION", help="a scan session folder (kogei capture)")
    p.add_argument("--preset", default="standard", choices=["draft", "standard", "reference"],
                   help="speed against accuracy of the registration and the mesh: draft, standard, reference "
                        "(docs/processing.md) (default %(default)s)")
    p.add_argument("--calibration", default=None, metavar="CAL_SESSION|CAL.json",
                   help="install this scanner calibration into the session first")
    p.add_argument("--camera-calibration", default=None, metavar="BOARD_SESSION|FILE.json",
                   help="install this camera calibration first; then every RAW frame is posed on the mesh and "
                        "projected (products/frame-poses.json, observations.npz, projection-report.json)")
    p.add_argument("--lamp-calibration", default=None, metavar="LAMP_SESSION|FILE.json",
                   help="install this lamp calibration first (the observations' light directions)")
    p.add_argument("--no-project", action="store_true",
                   help="mesh only: do not pose and project the frames even if the session is camera-calibrated")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.add_argument("--quiet", action="store_true", help="no progress messages")


def run(args: argparse.Namespace) -> int:
    from app.workflows.process_session import process_session

    def message(text: str) -> None:
        if not args.quiet and not text.startswith("INCOMPLETE:"):     # printed once at the end, even with --quiet
            print(f"  {text}", file=sys.stderr)

    report = process_session(args.session, preset=args.preset, calibration=args.calibration,
                             camera_calibration=args.camera_calibration, lamp_calibration=args.lamp_calibration,
                             project=not args.no_project, message=message)
    partial = _warn_partial(args.session, report)
    if args.json:
        print(json.dumps(report, indent=1))
        return partial
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
    proj = report.get("projection")
    if proj:
        print(projection_line(args.session, proj))
    return partial


def _warn_partial(session: str, report: dict) -> int:
    """Print why a result is partial (even with --quiet) and give the exit status: 1 if partial, else 0."""
    warnings = report.get("warnings") or []
    for text in warnings:
        print(f"kogei process: INCOMPLETE: {session}: {text}", file=sys.stderr)
    return EXIT_PARTIAL if warnings else 0


def projection_line(session: str, proj: dict) -> str:
    """One line: frames posed, observations, worst silhouette IoU."""
    iou = proj.get("iou_min")
    return (f"frames: {len(proj['frames'])} posed on the mesh, {proj['observations']['count']} observations of "
            f"{proj['observations']['vertices_seen']} vertices"
            + ("" if iou is None else f", silhouette IoU >= {iou:.3f}")
            + f" -> {session}/products/projection-report.json")
