"""``kogei cloth fit SESSION``: fit Yasuda et al.'s cloth model to a swatch capture.

Prints the fitted parameters with their uncertainties and the residual,
writes ``cloth-fit.json`` and ``cloth-fit.png`` (measured vs fitted
responses over table angle) into ``--out`` (default: ``SESSION/cloth-fit``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from app.errors import UsageError

__all__ = ["add_cloth_parser", "run_cloth"]


def add_cloth_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("cloth", help="woven cloth: fit the cloth model to a swatch capture")
    csub = p.add_subparsers(dest="cloth_command", required=True, metavar="ACTION")
    f = csub.add_parser("fit", help="fit the cloth model to a swatch session (kogei capture --plan swatch)")
    f.add_argument("session", metavar="SESSION")
    f.add_argument("--geometry", default=None, metavar="FILE.json",
                   help="the set-up: camera pose, light direction, swatch size (default SESSION/swatch.json)")
    f.add_argument("--yarn", default="silk", choices=["silk", "cotton", "satin"],
                   help="preset whose layer count, rounding, fibre index and weave are held (default silk)")
    f.add_argument("--layers", type=int, default=None, metavar="K", help="internal layers to hold (default: the yarn's)")
    f.add_argument("--pixels", type=int, default=160, metavar="N",
                   help="swatch pixels fitted (spread over the swatch; default 160)")
    f.add_argument("--out", default=None, metavar="DIR", help="where to write cloth-fit.json and cloth-fit.png")
    f.add_argument("--quiet", action="store_true")


def run_cloth(args: argparse.Namespace) -> int:
    from processing.cloth_fit import ClothFitError, fit_swatch

    from app.cloth_fit_session import fit_figure, fit_report, load_swatch_session

    if args.layers is not None and not 0 <= args.layers <= 50:
        raise UsageError(f"--layers must be 0..50, got {args.layers}")
    session = Path(args.session)
    if not session.is_dir():
        raise UsageError(f"{session}: session folder not found")
    if args.pixels < 8:
        raise UsageError(f"--pixels must be at least 8, got {args.pixels}")
    data = load_swatch_session(session, args.geometry, max_pixels=args.pixels)
    try:
        fit = fit_swatch(data.measurement, data.geometry, yarn=args.yarn, layers=args.layers)
    except ClothFitError as exc:
        raise UsageError(f"{session}: {exc}") from None
    out = Path(args.out) if args.out else session / "cloth-fit"
    out.mkdir(parents=True, exist_ok=True)
    report = fit_report(data, fit)
    (out / "cloth-fit.json").write_text(json.dumps(report, indent=2) + "\n")
    figure = fit_figure(data, fit, out / "cloth-fit.png")
    if not args.quiet:
        print(f"{data.measurement.angles_deg.size} angles x {data.measurement.pixels.shape[0]} pixels")
        for name, value in fit.parameters.items():
            print(f"  {name:<9} {value:9.4f} +- {fit.sigma[name]:.4f}")
        print(f"  residual rms {fit.residual_rms:.4g} ({100 * fit.relative_residual:.2f} % of the mean)")
        print(f"  material: {fit.spec}")
        print(f"wrote {out / 'cloth-fit.json'} and {figure}", file=sys.stderr)
    return 0
