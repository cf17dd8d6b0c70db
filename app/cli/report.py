"""``kogei report``: the session's self-contained HTML report (a thin shell over :func:`app.report.html.write_report`)."""

from __future__ import annotations

import argparse
import os
import sys

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("report", help="one self-contained HTML report of everything a session holds",
                       description="Write an HTML report (plots embedded) of the session: metadata, capture log, "
                                   "calibration, registration, mesh, coverage, colour, materials, renders, timing.")
    p.add_argument("session", metavar="SESSION", help="a session folder, at any stage of its processing")
    p.add_argument("--out", default=None, metavar="FILE.html",
                   help="where to write it (default: SESSION/products/report.html, recorded in the session)")


def run(args: argparse.Namespace) -> int:
    from app.cli.outputs import check_output_file
    from app.report.html import write_report

    if args.out is not None:
        check_output_file(args.out, "--out", make_parents=True)     # before the report is built
    path = write_report(args.session, args.out)
    shown = os.fsdecode(path).encode("utf-8", "backslashreplace").decode("utf-8")
    print(f"report: {shown}", file=sys.stderr)
    out = getattr(sys.stdout, "buffer", None)
    if out is None:
        print(shown)
    else:       # the path's own bytes, so a script can open it even when the name is not UTF-8
        sys.stdout.flush()
        out.write(os.fsencode(path) + b"\n")
        out.flush()
    return 0
