"""``kogei project``: pose a processed session's RAW frames on its mesh (a shell over
:func:`app.workflows.posed_frames.project_session`)."""

from __future__ import annotations

import argparse
import json
import sys

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("project", help="pose every RAW frame on the mesh; observations per vertex + silhouette check",
                       description="For a processed, camera-calibrated scan session: every RAW frame's camera pose "
                                   "relative to the mesh, the vertices it sees (occlusion, back faces, grazing "
                                   "angles and silhouette edges left out) with the chart-calibrated signal and the "
                                   "geometry, and the silhouette IoU of the projected mesh against the photo.  "
                                   "Writes products/frame-poses.json, observations.npz, projection-report.json and "
                                   "overlays/.")
    p.add_argument("session", metavar="SESSION", help="a processed, camera-calibrated session (kogei process)")
    p.add_argument("--decode", choices=["demosaic", "bin2x2"], default="demosaic",
                   help="RAW decoding: demosaic (full resolution, default) or bin2x2 (a quarter of the pixels)")
    p.add_argument("--max-view-deg", type=float, default=75.0, metavar="DEG",
                   help="largest angle between a vertex's normal and the view that counts as seen, degrees "
                        "(default 75)")
    p.add_argument("--edge-margin", type=float, default=2.0, metavar="PX",
                   help="leave out observations this close to a silhouette or depth edge (px, default 2)")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.add_argument("--quiet", action="store_true", help="no progress messages")


def run(args: argparse.Namespace) -> int:
    from app.cli.process import projection_line
    from app.workflows.posed_frames import project_session

    def message(text: str) -> None:
        if not args.quiet:
            print(f"  {text}", file=sys.stderr)

    report = project_session(args.session, decode=args.decode, max_view_deg=args.max_view_deg,
                             edge_margin_px=args.edge_margin, message=message)
    if args.json:
        print(json.dumps(report, indent=1))
        return 0
    for f in report["frames"]:
        iou = "not checked" if f.get("iou") is None else f"IoU {f['iou']:.3f}, offset {f['offset_px']:.2f} px"
        print(f"  {f['frame']} ({f['table_angle_deg']:.0f} deg): {iou}")
    print(projection_line(args.session, report))
    return 0
