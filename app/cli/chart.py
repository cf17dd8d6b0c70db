"""``kogei chart``: locate the colour chart in a RAW frame, sample its patches and check them.

``kogei chart RAW [--chart classic24|sg140|vinyl18] [--chart-corners x1,y1,...,x4,y4]
[--mode bin2x2|demosaic] [--json OUT.json]`` decodes the RAW
(:func:`processing.camera.raw_decode.decode_raw`), finds the chart with ``cv2.mcc``
(:func:`processing.camera.chart_detection.detect_chart`) or takes its four outer
corners from ``--chart-corners`` (sensor pixels, top-left of the chart first,
clockwise), samples the linear RGB of every patch and checks the shot
(:func:`processing.camera.chart_sampling.check_patches`), all through
:func:`app.workflows.chart.chart_report`.  It prints one summary line
and one line per excluded patch; ``--json`` writes the per-patch statistics,
the patch positions and the exposure metadata.

Exit status 0 when the chart is usable, 2 with a one-line message for a bad
file, no chart, a chart partly outside the frame or a rejected shot
(:class:`processing.errors.InputError`).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from app.cli.outputs import check_output_file, writing
from app.workflows.chart import chart_report
from processing.common.files import atomic_path

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``chart`` subcommand to ``sub`` and return its parser."""
    p = sub.add_parser(
        "chart",
        help="find, sample and check the colour chart in a RAW frame",
        description="Locate the colour chart in a RAW frame (cv2.mcc, or --chart-corners), sample the linear "
                    "camera RGB of each patch and reject clipped, uneven or mis-ordered charts.",
    )
    p.add_argument("raw", metavar="RAW", help="the chart frame (DNG, CR2, NEF, ARW, ...)")
    p.add_argument("--chart", default="classic24", choices=["classic24", "sg140", "vinyl18"],
                   help="the chart's type: classic24 (ColorChecker Classic, 24 patches), sg140 (ColorChecker "
                        "Digital SG, 140), vinyl18 (the 18-patch vinyl chart of OpenCV mcc) (default %(default)s)")
    p.add_argument("--chart-corners", default=None, metavar="x1,y1,x2,y2,x3,y3,x4,y4",
                   help="the chart's outer corners in sensor pixels, top-left (next to patch 1) first, clockwise "
                        "(default: found by OpenCV mcc)")
    p.add_argument("--mode", default="bin2x2", choices=["bin2x2", "demosaic"],
                   help="RAW decoding: bin2x2 (each 2x2 Bayer cell is one pixel: half the width and height) or "
                        "demosaic (full resolution) (default %(default)s)")
    p.add_argument("--inset", type=float, default=0.6, metavar="FRACTION",
                   help="fraction of each patch's side sampled, centred, in (0, 1] (default %(default)s)")
    p.add_argument("--trim", type=float, default=0.1, metavar="FRACTION",
                   help="fraction of the samples cut from each end for the trimmed mean, in [0, 0.5) "
                        "(default %(default)s)")
    p.add_argument("--json", default=None, metavar="OUT.json", help="write the patch statistics here (default: not written)")
    p.add_argument("--quiet", action="store_true", help="print nothing when the chart is usable")
    return p


def run(args: argparse.Namespace) -> int:
    """Run ``kogei chart``; returns the exit status."""
    raw_path = Path(args.raw)
    out = check_output_file(args.json, "--json") if args.json else None     # before the work
    report = chart_report(raw_path, chart=args.chart, corners=args.chart_corners, mode=args.mode,
                          inset=args.inset, trim=args.trim)
    if out is not None:
        with writing(out, "--json"), atomic_path(out, durable=False, make_parents=False) as tmp:
            tmp.write_text(json.dumps(report, indent=1), encoding="utf-8")
    if not args.quiet:
        usable = sum(p["usable"] for p in report["patches"])
        how = (f"found by mcc (confidence {report['confidence']:.2f}, {report['detect_seconds']:.2f} s)"
               if report["method"] == "mcc" else "from the given corners")
        print(f"{raw_path.name}: {report['chart']} chart {how}; {usable} of {len(report['patches'])} patches usable")
        for line in report["warnings"]:
            print(f"  {line}")
    return 0
