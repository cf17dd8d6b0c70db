"""``kogei identify``: the material of each region of a spectral result.

``kogei identify RESULT.npz [--regions LABELS.png] [--json]``: a shell over
:func:`app.workflows.identification.identify_result` (the method, the
``--min-level`` rule and the report's fields are described there and in
docs/colour-pipeline.md, "Command line").

* ``--regions``: a single-channel 8- or 16-bit PNG of the estimate's size
  (half the sensor's in ``bin2x2`` mode), one integer label per region, 0
  for pixels to ignore.  For a ``bin2x2`` estimate a label image drawn on the
  photo at full resolution is resampled nearest-neighbour, and the output
  says so (a ``notes`` line, in ``--json`` the ``notes`` list).
* Without ``--regions`` the whole unmasked image is one region: meant for a
  crop or a frame filled by one material.  Segmenting an object into
  materials is left to the labels, which the capture's mesh provides.
* ``--model-error`` defaults to
  :data:`processing.materials.identification.DEFAULT_MODEL_ERROR` (1.75 % of
  each channel), the same as the batch's materials step and the colour demo.
* Each region prints its misfit (the best candidate's reduced chi-square: about
  1 when it fits to the noise); beyond
  :data:`processing.materials.confidence.MAX_MISFIT` the region reads
  "no candidate fits (best: tin, reduced chi-square 3400)" rather than a name.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from app.errors import UsageError
from app.workflows.identification import MIN_LEVEL, identify_result, read_labels
from app.workflows.spectral import load_result
from processing.materials.confidence import MAX_MISFIT, NO_FIT
from processing.materials.identification import DEFAULT_MODEL_ERROR

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``identify`` subcommand to ``sub`` and return its parser."""
    p = sub.add_parser(
        "identify",
        help="identify the material of each region of a spectral result",
        description="Identify each region's material (metals, shibuichi, shakudo, bronze, urushi) by forward-"
                    "modelling the candidates into the camera; report confidence, runner-up and alloy weights.",
    )
    p.add_argument("result", metavar="RESULT.npz", help="written by 'kogei spectral estimate'")
    p.add_argument("--regions", default=None, metavar="LABELS.png",
                   help="integer label image of the result's size, or of the photo's for a bin2x2 result (then "
                        "resampled nearest-neighbour), 0 = ignore (default: the whole image is one region)")
    p.add_argument("--light-deg", type=float, default=30.0, metavar="DEG",
                   help="angle of the light from the surface normal at which candidates are modelled, degrees in "
                        "[0, 90) (default %(default)s)")
    p.add_argument("--noise", type=float, default=0.01, metavar="FRACTION",
                   help="relative noise per pixel, a fraction (0.01 = 1 %%) (default %(default)s)")
    p.add_argument("--model-error", type=float, default=DEFAULT_MODEL_ERROR, metavar="FRACTION",
                   help="relative error of the candidate models (a fraction of each channel: 0.02 = 2 %%), added in "
                        "quadrature to the noise of a region's mean (default: %(default)s, as in the batch and the "
                        f"demo); a region whose best candidate's reduced chi-square exceeds {MAX_MISFIT:g} reads "
                        "'no candidate fits'")
    p.add_argument("--min-level", type=float, default=MIN_LEVEL, metavar="FRACTION",
                   help="leave out pixels darker than this fraction of a white diffuser lit like the chart (shadows) "
                        "(default %(default)s)")
    p.add_argument("--json", action="store_true", help="print the regions as JSON")
    return p


def run(args: argparse.Namespace) -> int:
    """Run ``kogei identify``; returns the exit status (running out of memory is a one-line UsageError)."""
    try:
        return _identify(args)
    except MemoryError:
        raise UsageError(f"{args.result}: not enough memory to identify the materials of this result; "
                         "free memory or estimate a smaller image") from None


def _identify(args: argparse.Namespace) -> int:
    """Check the options, identify every region and print the reports."""
    for flag, v in (("--noise", args.noise), ("--model-error", args.model_error)):
        if not (np.isfinite(v) and 0 <= v < 1):
            raise UsageError(f"{flag} {v!r}: give a relative level in [0, 1), e.g. 0.01 for 1 %")
    if args.noise == 0 and args.model_error == 0:
        raise UsageError("--noise and --model-error are both 0: give the noise level of the camera values")
    if not 0 <= args.min_level < 1:
        raise UsageError(f"--min-level {args.min_level!r}: give a fraction in [0, 1)")
    if not 0 <= args.light_deg < 90:
        raise UsageError(f"--light-deg {args.light_deg!r}: give an angle in [0, 90) degrees from the normal")
    result = load_result(Path(args.result))
    notes: list[str] = []
    labels = None if args.regions is None else read_labels(Path(args.regions), result.mask.shape,
                                                           mode=result.metadata.get("mode"), note=notes.append)
    reports = identify_result(result, labels, light_deg=args.light_deg, noise=args.noise,
                              model_error=args.model_error, min_level=args.min_level)
    if args.json:
        print(json.dumps({"result": str(args.result), "method": result.method,
                          "wavelengths": result.wavelengths.tolist(), "notes": notes,
                          "regions": [r.as_dict() for r in reports]}))
        return 0
    for line in notes:
        print(line)
    for r in reports:
        if r.material is None:
            print(f"region {r.label}: {r.pixels} pixels, not identified: {r.note}")
            continue
        if r.material == NO_FIT:
            print(f"region {r.label}: {NO_FIT} (best: {r.group[0]}, reduced chi-square {r.misfit:.3g}), "
                  f"{r.pixels} pixels")
            continue
        line = (f"region {r.label}: {r.material} (confidence {r.confidence:.2f}; runner-up {r.runner_up}; "
                f"reduced chi-square {r.misfit:.3g}), {r.pixels} pixels")
        if len(r.group) > 1:
            line += f"; cannot tell apart {', '.join(r.group)}"
        if r.alloy_weights:
            line += "; alloy " + ", ".join(f"{m} {100 * v:.1f}%" for m, v in r.alloy_weights.items())
        print(line)
    return 0
