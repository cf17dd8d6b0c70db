"""``kogei probe``: a light probe from bracketed RAW frames of a mirror sphere, as a spectral environment map.

``kogei probe SESSION_OR_FRAMES... --out probe.exr [--chart RAW] [--camera-calibration BOARD_SESSION]
[--sphere-radius MM] [--sphere-reflectance R] [--light D65] [--method wiener|paper] [--decode demosaic|bin2x2]
[--height ROWS] [--f-number N] [--camera-mask DEG] [--back-mask DEG] [--filter-frames SESSION_OR_FOLDER
--filter CSV [--filter-chart RAW] [--components K]]`` merges the brackets into linear HDR,
finds the sphere, unwraps it into an equirectangular map in the room frame and makes it spectral with the
chart shot in the same light (:func:`app.workflows.light_probe.build_probe`); with a second bracket set
shot through a colour filter of known transmission (and the chart through it), six camera values per
direction go through the two-light root polynomial and the map keeps K basis spectra; it writes the map as OpenEXR
and a JSON report beside it (:func:`app.workflows.light_probe.write_probe`); from a probe session, both are
also kept in the session's products (:func:`app.workflows.light_probe.record_probe`) for its report.  SESSION_OR_FRAMES is a
session captured with ``kogei capture --plan probe``, a folder of RAW files or the RAW files themselves.
docs/lighting.md describes each step.

Exit status 0, or 2 with a one-line message naming the file for bad input: brackets saturated
everywhere, a frame without exposure metadata, no probe sphere found, a chart that cannot be used.
"""

from __future__ import annotations

import argparse

from app.cli.outputs import check_output_file, writing
from app.workflows.light_probe import build_probe, probe_inputs, record_probe, write_probe

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``probe`` subcommand to ``sub`` and return its parser."""
    p = sub.add_parser(
        "probe",
        help="a spectral environment map from bracketed RAW frames of a mirror sphere",
        description="Merge bracketed RAW frames of a mirror sphere into HDR, unwrap the sphere into an "
                    "equirectangular map of the light around it (room frame) and make it spectral with the chart "
                    "shot in the same light.  Writes OUT.exr and OUT.json.",
    )
    p.add_argument("sources", nargs="+", metavar="SESSION_OR_FRAMES",
                   help="a probe session (kogei capture --plan probe), a folder of RAW files, or the RAW files")
    p.add_argument("--out", required=True, metavar="OUT.exr", help="the environment map to write (OpenEXR)")
    p.add_argument("--chart", default=None, metavar="RAW",
                   help="the colour chart's frame shot in the same light (default: the session's chart frame)")
    p.add_argument("--chart-type", default="classic24", choices=["classic24", "sg140", "vinyl18"],
                   help="the chart's type (default %(default)s)")
    p.add_argument("--camera-calibration", default=None, metavar="BOARD_SESSION",
                   help="the camera calibration (a calibrated board session or its camera_calibration.json); "
                        "default: the session's")
    p.add_argument("--sphere-radius", type=float, default=None, metavar="MM",
                   help="the mirror sphere's radius in mm, 1 to 500 (half its diameter) (default: the session plan's)")
    p.add_argument("--sphere-reflectance", type=float, default=0.6, metavar="R",
                   help="the sphere's mirror reflectance, the fraction of light it reflects, 0.02-1 (chrome about 0.6; "
                        "under 0.02 it is not a mirror) (default %(default)s)")
    p.add_argument("--light", default="D65", metavar="NAME_OR_CCT",
                   help="the light's spectrum where the chart lies: a name such as D65 or A, a CCT in K, or a CSV "
                        "file of a measured spectrum (wavelength_nm, value) (default %(default)s)")
    p.add_argument("--method", default=None, choices=["wiener", "paper", "twolight"],
                   help="the spectral estimator: wiener or paper for one bracket set, twolight (root polynomial of "
                        "six channels) for two (default: wiener, or twolight with --filter-frames)")
    p.add_argument("--filter-frames", default=None, metavar="SESSION_OR_FOLDER",
                   help="a second bracket set of the sphere shot through a colour filter (a probe session or a "
                        "folder of RAW files): six camera values per direction instead of three")
    p.add_argument("--filter", default=None, metavar="CSV",
                   help="the filter's transmission: wavelength_nm, transmission (0-1) rows from its data sheet")
    p.add_argument("--filter-chart", default=None, metavar="RAW",
                   help="the chart shot through the filter (default: the filtered session's chart frame)")
    p.add_argument("--components", type=int, default=None, metavar="K",
                   help="basis spectra a map from two bracket sets keeps, 1-6: the render's cost grows with them "
                        "(default 6)")
    p.add_argument("--decode", default="demosaic", choices=["demosaic", "bin2x2"],
                   help="RAW decoding: full resolution or 2x2 binned (a quarter of the memory) (default %(default)s)")
    p.add_argument("--height", type=int, default=None, metavar="ROWS",
                   help="rows of the map (width twice that; default: about the sphere's radius in pixels)")
    p.add_argument("--f-number", type=float, default=None, metavar="N",
                   help="the aperture, for files that do not record it (a manual lens) (default: the files' own)")
    p.add_argument("--camera-mask", type=float, default=12.0, metavar="DEG",
                   help="half-angle in degrees of the unobserved cap toward the camera (default %(default)s)")
    p.add_argument("--back-mask", type=float, default=45.0, metavar="DEG",
                   help="half-angle in degrees of the unobserved cap away from the camera (default %(default)s)")
    p.add_argument("--quiet", action="store_true", help="print nothing on success")
    return p


def run(args: argparse.Namespace) -> int:
    """Run ``kogei probe``; returns the exit status."""
    out = check_output_file(args.out, "--out", suffixes=(".exr",))      # the map and its report, before the work
    check_output_file(out.with_suffix(".json"), "--out (its report)")
    inputs = probe_inputs(args.sources, chart=args.chart, camera_calibration=args.camera_calibration,
                          sphere_radius_mm=args.sphere_radius, filter_frames=args.filter_frames,
                          filter_chart=args.filter_chart, filter_transmission=args.filter)
    say = (lambda text: None) if args.quiet else (lambda text: print(f"  {text}"))
    result = build_probe(inputs, light=args.light, method=args.method, chart_type=args.chart_type,
                         decode=args.decode, reflectance=args.sphere_reflectance, height=args.height,
                         f_number=args.f_number, camera_mask_deg=args.camera_mask, back_mask_deg=args.back_mask,
                         components=args.components, message=say)
    with writing(out, "--out"):
        exr, report = write_probe(result, out)
    kept = record_probe(inputs.session, result) if inputs.session is not None else None
    if not args.quiet:
        r = result.report
        sec = r["seconds"]
        sets = "" if "filter_frames" not in r["spectral"] else f" + {len(r['spectral']['filter_frames'])} through the filter"
        print(f"{exr}: {r['map']['width']} x {r['map']['height']} environment from {len(r['frames'])} brackets{sets}, "
              f"{100 * r['map']['observed_fraction']:.0f} % of directions seen; merge {sec['merge']:.1f} s, "
              f"unwrap {sec['unwrap']:.1f} s; chart RMS reflectance error {r['spectral']['chart_rmse']:.3f}")
        print(f"{report}: the report")
        if kept is not None:
            print(f"{kept[0]}: kept in the session (its report shows it)")
    return 0
