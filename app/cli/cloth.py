"""``kogei cloth fit SESSION``: fit Yasuda et al.'s cloth model to a swatch capture.

Prints the fitted parameters with their uncertainties and the residual,
writes ``cloth-fit.json`` and ``cloth-fit.png`` (measured vs fitted
responses over table angle) into ``--out`` (default: ``SESSION/cloth-fit``).

``kogei cloth simulate SESSION --cloth SPEC``: a swatch session from the
simulated station (:func:`app.workflows.cloth_fit.capture_swatch_session`),
with the set-up ``SESSION/swatch.json`` that ``kogei cloth fit`` reads.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from app.cli.outputs import check_output_folder, writing
from app.errors import UsageError

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("cloth", help="woven cloth: fit the cloth model to a swatch capture")
    csub = p.add_subparsers(dest="cloth_command", required=True, metavar="ACTION")
    f = csub.add_parser("fit", help="fit the cloth model to a swatch session (kogei capture --plan swatch)")
    f.add_argument("session", metavar="SESSION", help="a swatch session folder (kogei capture --plan swatch)")
    f.add_argument("--geometry", default=None, metavar="FILE.json",
                   help="the set-up: camera pose, light direction, swatch size (default SESSION/swatch.json)")
    f.add_argument("--yarn", default="silk", choices=["silk", "cotton", "satin"],
                   help="preset whose layer count, rounding, fibre index and weave are held (default silk)")
    f.add_argument("--layers", default=None, metavar="K|auto",
                   help="internal layers to hold (default: the yarn's), or 'auto': fit 1, 2, 3, 4, 6 and 8 layers "
                        "and keep the best")
    f.add_argument("--pixels", type=int, default=160, metavar="N",
                   help="swatch pixels fitted (spread over the swatch; default 160)")
    f.add_argument("--out", default=None, metavar="DIR", help="where to write cloth-fit.json and cloth-fit.png (default SESSION/cloth-fit)")
    f.add_argument("--quiet", action="store_true", help="no progress messages")
    s = csub.add_parser("simulate", help="capture a swatch session of a simulated cloth swatch (for kogei cloth fit)",
                        description="Capture a swatch session on the simulated station: a flat 80 mm swatch of a "
                                    "cloth material turned by the table under a fixed lamp, a chart frame then one "
                                    "RAW frame per table step, and the set-up SESSION/swatch.json.")
    s.add_argument("session", metavar="SESSION", help="new session folder (must not exist)")
    s.add_argument("--cloth", default="silk", metavar="SPEC",
                   help="the swatch's material: silk, cotton, satin, tamamushi or a spec such as "
                        "silk:a_t=0.08,a_b=0.5 (see 'kogei materials silk'); default silk")
    s.add_argument("--steps", type=int, default=24, metavar="N", help="table steps (frames) per pass (default 24)")
    s.add_argument("--size", default="96x72", metavar="WxH", help="frame size in pixels (default 96x72)")
    s.add_argument("--camera", default="hotfolder", choices=["hotfolder", "gphoto2"],
                   help="the station's hot folder (rendered in this process) or its fake gphoto2 (default %(default)s)")
    s.add_argument("--seed", type=int, default=1, metavar="N", help="seed of the sensor noise (default 1)")


def _simulate(args: argparse.Namespace) -> int:
    from app.workflows.cloth_fit import GEOMETRY_FILE, capture_swatch_session

    try:
        width, height = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        raise UsageError(f"--size must be WxH in pixels, e.g. 96x72, got {args.size!r}") from None
    if args.steps < 2:
        raise UsageError(f"--steps must be at least 2, got {args.steps}")
    if args.seed < 0:
        raise UsageError(f"--seed must be >= 0, got {args.seed}")
    if os.path.lexists(args.session):
        raise UsageError(f"{args.session} exists; give a new folder for the swatch session")
    out = capture_swatch_session(args.session, args.cloth, steps=args.steps, seed=args.seed, width=width,
                                 height=height, camera=args.camera)
    print(f"swatch session {out}: {args.cloth}, {args.steps} frames of {width} x {height}; set-up "
          f"{out / GEOMETRY_FILE}; next: kogei cloth fit {out}")
    return 0


def run(args: argparse.Namespace) -> int:
    if args.cloth_command == "simulate":
        return _simulate(args)
    from app.workflows.cloth_fit import fit_figure, fit_report, load_swatch_session
    from processing.cloth.fit import ClothFitError, choose_layers, fit_swatch

    layers = args.layers
    if layers is not None and layers != "auto":
        try:
            layers = int(layers)
        except ValueError:
            raise UsageError(f"--layers must be a whole number 0..50 or 'auto', got {args.layers!r}") from None
        if not 0 <= layers <= 50:
            raise UsageError(f"--layers must be 0..50 or 'auto', got {layers}")
    session = Path(args.session)
    if not session.is_dir():
        raise UsageError(f"{session}: session folder not found")
    if args.pixels < 8:
        raise UsageError(f"--pixels must be at least 8, got {args.pixels}")
    out = check_output_folder(args.out or session / "cloth-fit", "--out")     # before the fit
    data = load_swatch_session(session, args.geometry, max_pixels=args.pixels)
    costs = None
    try:
        if layers == "auto":
            fit, costs = choose_layers(data.measurement, data.geometry, yarn=args.yarn)
        else:
            fit = fit_swatch(data.measurement, data.geometry, yarn=args.yarn, layers=layers)
    except ClothFitError as exc:
        raise UsageError(f"{session}: {exc}") from None
    report = fit_report(data, fit)
    if costs is not None:
        report["layer_costs"] = {str(k): v for k, v in costs.items()}
    with writing(out, "--out"):
        out.mkdir(parents=True, exist_ok=True)
        (out / "cloth-fit.json").write_text(json.dumps(report, indent=2) + "\n")
        figure = fit_figure(data, fit, out / "cloth-fit.png")
    if not args.quiet:
        print(f"{data.measurement.angles_deg.size} angles x {data.measurement.pixels.shape[0]} pixels")
        for name, value in fit.parameters.items():
            print(f"  {name:<9} {value:9.4f} +- {fit.sigma[name]:.4f}")
        print(f"  layers    {fit.fixed['layers']:9d}" + ("  (held)" if costs is None else "  (lowest cost of "
              + ", ".join(f"K={k}: {c:.4g}" for k, c in costs.items()) + ")"))
        print(f"  residual rms {fit.residual_rms:.4g} ({100 * fit.relative_residual:.2f} % of the mean)")
        print(f"  material: {fit.spec}")
        print(f"wrote {out / 'cloth-fit.json'} and {figure}", file=sys.stderr)
    return 0
