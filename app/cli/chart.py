"""``kogei chart``: locate the colour chart in a RAW frame, sample its patches and check them.

``kogei chart RAW [--chart classic24|sg140|vinyl18] [--chart-corners x1,y1,...,x4,y4]
[--mode bin2x2|demosaic] [--json OUT.json]`` decodes the RAW
(:func:`processing.camera.raw_decode.decode_raw`), finds the chart with ``cv2.mcc``
(:func:`processing.camera.chart_detection.detect_chart`) or takes its four outer
corners from ``--chart-corners`` (sensor pixels, top-left of the chart first,
clockwise), samples the linear RGB of every patch and checks the shot
(:func:`processing.camera.chart_sampling.check_patches`).  It prints one summary line
and one line per excluded patch; ``--json`` writes the per-patch statistics,
the patch positions and the exposure metadata.

Exit status 0 when the chart is usable, 2 with a one-line message for a bad
file, no chart, a chart partly outside the frame or a rejected shot
(:class:`app.errors.UsageError`).
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
from pathlib import Path

from app.errors import UsageError

__all__ = ["add_parser", "run", "chart_report"]


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``chart`` subcommand to ``sub`` and return its parser."""
    p = sub.add_parser(
        "chart",
        help="find, sample and check the colour chart in a RAW frame",
        description="Locate the colour chart in a RAW frame (cv2.mcc, or --chart-corners), sample the linear "
                    "camera RGB of each patch and reject clipped, uneven or mis-ordered charts.",
    )
    p.add_argument("raw", metavar="RAW", help="the chart frame (DNG, CR2, NEF, ARW, ...)")
    p.add_argument("--chart", default="classic24", choices=["classic24", "sg140", "vinyl18"])
    p.add_argument("--chart-corners", default=None, metavar="x1,y1,x2,y2,x3,y3,x4,y4",
                   help="the chart's outer corners in sensor pixels, top-left (next to patch 1) first, clockwise")
    p.add_argument("--mode", default="bin2x2", choices=["bin2x2", "demosaic"])
    p.add_argument("--inset", type=float, default=0.6, help="fraction of each patch's side sampled")
    p.add_argument("--trim", type=float, default=0.1, help="fraction cut from each end for the trimmed mean")
    p.add_argument("--json", default=None, metavar="OUT.json", help="write the patch statistics here")
    p.add_argument("--quiet", action="store_true")
    return p


def chart_report(raw_path: Path, *, chart: str = "classic24", corners: str | None = None, mode: str = "bin2x2",
                 inset: float = 0.6, trim: float = 0.1) -> dict:
    """Decode, locate, sample and check; the JSON-ready report.  Errors are ``UsageError``."""
    from processing.camera.chart_detection import ChartDetectionError, chart_from_corners, detect_chart, parse_corners
    from processing.camera.chart_sampling import ChartRejectedError, ChartSamplingError, check_patches, sample_patches
    from processing.camera.raw_decode import RawDecodeError, decode_raw

    try:
        img = decode_raw(raw_path, mode=mode)
        h, w = img.shape
        size = (w * img.scale, h * img.scale)
        if corners is not None:
            det = chart_from_corners(parse_corners(corners), chart, image_size=size)
        else:
            det = detect_chart(img, chart)
        samples = sample_patches(img, det, inset=inset, trim=trim)
        check = check_patches(samples)
    except (RawDecodeError, ChartDetectionError, ChartSamplingError, ChartRejectedError) as exc:
        raise UsageError(str(exc)) from None
    layout = det.layout
    return {
        "format": "kogei-chart",
        "version": 1,
        "raw": os.fspath(raw_path),
        "chart": chart,
        "method": det.method,
        "confidence": det.confidence,
        "detect_seconds": det.seconds,
        "mode": mode,
        "exposure_time": img.exposure_time,
        "iso": img.iso,
        "f_number": img.f_number,
        "make": img.make,
        "model": img.model,
        "black_levels": list(img.black_levels),
        "white_level": img.white_level,
        "corners": det.corners.tolist(),
        "warnings": check.warnings,
        "patches": [
            {
                "number": k + 1,
                "name": layout.names[k],
                "centre": det.centres[k].tolist(),
                "mean": samples.mean[k].tolist(),
                "std": samples.std[k].tolist(),
                "clipped": float(samples.clipped[k]),
                "count": int(samples.count[k]),
                "nonuniformity": float(samples.nonuniformity[k]),
                "usable": bool(check.usable[k]),
            }
            for k in range(layout.size)
        ],
    }


def run(args: argparse.Namespace) -> int:
    """Run ``kogei chart``; returns the exit status."""
    raw_path = Path(args.raw)
    report = chart_report(raw_path, chart=args.chart, corners=args.chart_corners, mode=args.mode,
                          inset=args.inset, trim=args.trim)
    if args.json:
        out = Path(args.json)
        if not out.parent.is_dir():
            raise UsageError(f"--json {out}: the folder {out.parent} does not exist")
        fd, tmp = tempfile.mkstemp(dir=out.parent, prefix=".chart-", suffix=".json")
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            json.dump(report, fh, indent=1)
        os.replace(tmp, out)
    if not args.quiet:
        usable = sum(p["usable"] for p in report["patches"])
        how = (f"found by mcc (confidence {report['confidence']:.2f}, {report['detect_seconds']:.2f} s)"
               if report["method"] == "mcc" else "from the given corners")
        print(f"{raw_path.name}: {report['chart']} chart {how}; {usable} of {len(report['patches'])} patches usable")
        for line in report["warnings"]:
            print(f"  {line}")
    return 0
