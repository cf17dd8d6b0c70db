"""``kogei spectral``: per-pixel spectral reflectance of a RAW image calibrated by a chart shot.

``kogei spectral estimate IMAGE --chart CHART [--method paper|wiener|rootpoly|more-basis|twolight]
[--second IMAGE2 --second-chart CHART2] [--chart-corners ...] [--mode bin2x2|demosaic] --out RESULT.npz``
is a shell over :func:`app.workflows.spectral.estimate_spectral` (the chain,
the exposure rule and the RESULT file are described there and in
docs/colour-pipeline.md, "Command line").

``kogei spectral at RESULT.npz X Y [--json]`` prints the reflectance at one
pixel with its uncertainty (the estimate's RMS error on the chart,
``chart_rmse``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from app.cli.outputs import check_output_file, writing
from app.errors import UsageError
from app.workflows.identification import MIN_LEVEL, pixel_level
from app.workflows.spectral import METHODS, estimate_spectral, load_result, save_result

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``spectral`` subcommand (``estimate``, ``at``) to ``sub`` and return its parser."""
    p = sub.add_parser(
        "spectral",
        help="spectral reflectance per pixel from a RAW image and its chart shot",
        description="Estimate spectral reflectance as per-pixel basis weights (estimate) and read it back (at).",
    )
    ss = p.add_subparsers(dest="spectral_command", required=True, metavar="ACTION")
    e = ss.add_parser("estimate", help="RAW image + chart shot -> RESULT.npz of basis weights",
                      description="Calibrate a spectral estimator with the chart shot taken with the object and "
                                  "apply it to every pixel of the image.")
    e.add_argument("image", metavar="IMAGE", help="the object's RAW frame (DNG, CR2, NEF, ARW, ...)")
    e.add_argument("--chart", required=True, metavar="CHART", help="RAW frame of the colour chart under the same light")
    e.add_argument("--method", default="rootpoly", choices=METHODS,
                   help="estimator (default rootpoly; twolight needs --second and --second-chart)")
    e.add_argument("--second", default=None, metavar="IMAGE2", help="the same view under the second light (twolight)")
    e.add_argument("--second-chart", default=None, metavar="CHART2", help="the chart under the second light (twolight)")
    e.add_argument("--chart-type", default="classic24", choices=["classic24", "sg140", "vinyl18"],
                   help="the chart's type: classic24 (ColorChecker Classic, 24 patches), sg140 (ColorChecker "
                        "Digital SG, 140), vinyl18 (the 18-patch vinyl chart of OpenCV mcc) (default %(default)s)")
    e.add_argument("--chart-reflectances", default=None, metavar="CSV",
                   help="the chart's patch reflectances (nm, one column per patch in reading order); "
                        "default: ColorChecker N Ohta for classic24")
    e.add_argument("--chart-corners", default=None, metavar="x1,y1,x2,y2,x3,y3,x4,y4",
                   help="the chart's outer corners in sensor pixels, top-left (next to patch 1) first, clockwise "
                        "(default: found by OpenCV mcc)")
    e.add_argument("--second-chart-corners", default=None, metavar="x1,y1,...", help="corners in CHART2")
    e.add_argument("--patches", default=None, metavar="LIST",
                   help="patches used for the calibration, 1-based, e.g. 1-18 or 1,2,5-9 (default: every usable one)")
    e.add_argument("--mode", default="bin2x2", choices=["bin2x2", "demosaic"],
                   help="RAW decoding: bin2x2 (each 2x2 Bayer cell is one pixel: the result is half the sensor's "
                        "width and height) or demosaic (full resolution) (default %(default)s)")
    e.add_argument("--light", default="D65", metavar="NAME|CCT|CSV",
                   help="light of IMAGE and CHART: a CIE name, a correlated colour temperature in kelvin such as "
                        "3200K, or a CSV of (wavelength nm, relative power) (default %(default)s)")
    e.add_argument("--second-light", default="A", metavar="NAME|CCT|CSV",
                   help="light of IMAGE2 and CHART2 (twolight), as --light (default %(default)s)")
    e.add_argument("--camera", default="Nikon 5100 (NPL)",
                   help="model camera: a colour-science camera name or a CSV of sensitivities (nm, r, g, b) "
                        "(default %(default)s)")
    e.add_argument("--database", default="training", metavar="training|CSV",
                   help="training reflectances: 'training' (the built-in set) or a CSV (nm, one column per sample) "
                        "(default %(default)s)")
    e.add_argument("--noise", type=float, default=0.01, metavar="FRACTION",
                   help="relative noise of the camera values, a fraction (0.01 = 1 %%) (default %(default)s)")
    e.add_argument("--out", required=True, metavar="RESULT.npz", help="the result to write (required)")
    e.add_argument("--quiet", action="store_true", help="do not print the summary")
    a = ss.add_parser("at", help="the spectrum at one pixel of a RESULT.npz",
                      description="Print the reflectance at pixel (X, Y) of RESULT (image coordinates of the "
                                  "estimate: half the sensor's in bin2x2 mode) with its uncertainty.")
    a.add_argument("result", metavar="RESULT.npz", help="written by 'kogei spectral estimate'")
    a.add_argument("x", type=int, metavar="X", help="column of the pixel in the result, 0 at the left (px)")
    a.add_argument("y", type=int, metavar="Y", help="row of the pixel in the result, 0 at the top (px)")
    a.add_argument("--json", action="store_true", help="print JSON instead of a table")
    return p


def _refuse_non_finite(result, out: str) -> None:
    """Refuse (nothing written) an estimate with NaN or infinite weights, camera values or chart RMSE."""
    bad = [name for name, values in (("basis weights", result.weights), ("camera values", result.camera))
           if not np.all(np.isfinite(values))]
    if not np.isfinite(float(result.metadata.get("chart_rmse", np.nan))):
        bad.append("chart RMSE")
    if bad:
        raise UsageError(f"--out {out}: not written: the estimate's {' and '.join(bad)} are NaN or infinite; "
                         "check that --camera, --database and --chart-reflectances hold physical values "
                         "(sensitivities and reflectances of ordinary size)")


def _run_estimate(args: argparse.Namespace) -> int:
    for flag, value in (("IMAGE", args.image), ("--chart", args.chart), ("--second", args.second),
                        ("--second-chart", args.second_chart)):
        if value is not None and not Path(value).exists():
            raise UsageError(f"{flag} {value}: no such file")
    out = check_output_file(args.out, "--out")      # before the work, not after it
    result = estimate_spectral(
        Path(args.image), Path(args.chart), method=args.method,
        second=None if args.second is None else Path(args.second),
        second_chart=None if args.second_chart is None else Path(args.second_chart),
        chart_type=args.chart_type, chart_reflectances=args.chart_reflectances, chart_corners=args.chart_corners,
        second_chart_corners=args.second_chart_corners, patches=args.patches, mode=args.mode, light=args.light,
        second_light=args.second_light, camera=args.camera, database=args.database, noise=args.noise,
    )
    _refuse_non_finite(result, args.out)
    with writing(out, "--out"):
        save_result(result, out)
    if not args.quiet:
        h, w, p = result.weights.shape
        md = result.metadata
        print(f"{Path(args.out).name}: {w} x {h} pixels, {p} basis weights ({result.method}); "
              f"{len(md['patches_used'])} chart patches, condition {md['condition'].get('chart', float('nan')):.3g}, "
              f"chart RMSE {md['chart_rmse']:.4f}; {md['masked_pixels']} pixels masked")
        for line in md["chart_warnings"]:
            print(f"  {line}")
    return 0


def _run_at(args: argparse.Namespace) -> int:
    res = load_result(Path(args.result))
    h, w = res.mask.shape
    if not (0 <= args.x < w and 0 <= args.y < h):
        raise UsageError(f"pixel ({args.x}, {args.y}) is outside the image of {w} x {h} pixels "
                         f"(x in 0-{w - 1}, y in 0-{h - 1})")
    if not res.mask[args.y, args.x]:
        raise UsageError(f"pixel ({args.x}, {args.y}) is masked (saturated or dead in the RAW); pick another pixel")
    spectrum = res.weights[args.y, args.x].astype(np.float64) @ res.basis.T
    err = res.method_error
    level = pixel_level(res, args.x, args.y)
    note = ""
    if level < MIN_LEVEL:
        note = (f"pixel ({args.x}, {args.y}) is backdrop / below the noise floor: its brightest channel is "
                f"{level:.2g} of a white diffuser lit like the chart (below {MIN_LEVEL:g}), so the spectrum "
                "below is noise, not the object's; pick a pixel on the object")
    if args.json:
        print(json.dumps({"x": args.x, "y": args.y, "method": res.method,
                          "wavelengths": res.wavelengths.tolist(), "reflectance": spectrum.tolist(),
                          "uncertainty": err, "level": level, "note": note}))
    else:
        if note:
            print(note)
        print(f"pixel ({args.x}, {args.y}), {res.method}; uncertainty +-{err:.3f} (RMS error on the chart); "
              f"level {level:.3g} of a white diffuser")
        print("nm  reflectance")
        for lam, v in zip(res.wavelengths, spectrum):
            print(f"{lam:.0f} {v:.4f}")
    return 0


def run(args: argparse.Namespace) -> int:
    """Run ``kogei spectral estimate`` or ``kogei spectral at``; returns the exit status.

    Running out of memory is a one-line :class:`UsageError`, not a traceback.
    """
    try:
        if args.spectral_command == "estimate":
            return _run_estimate(args)
        return _run_at(args)
    except MemoryError:
        raise UsageError(f"not enough memory for 'kogei spectral {args.spectral_command}'; "
                         "use a smaller image (or --mode bin2x2) or free memory") from None
