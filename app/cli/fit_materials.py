"""``kogei fit-materials``: the object's materials measured on its mesh and checked on held-out photos
(a shell over :func:`app.workflows.object_materials.measure_object`)."""

from __future__ import annotations

import argparse
import json
import sys

from app.workflows.object_materials import FIT_MODEL_ERROR, HOLDOUT_EVERY

__all__ = ["add_parser", "run", "summary_lines"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("fit-materials", help="segment the mesh into materials, fit each at its true angles, validate",
                       description="For a session whose photos are posed on the mesh (kogei project): regions of "
                                   "one material on the surface, each region's material fitted by forward modelling "
                                   "at the observations' true normal, view and light directions, with parameters, "
                                   "uncertainties and a calibrated confidence; then held-out frames rendered and "
                                   "compared with the photos (CIEDE2000), next to the one-material baseline.  Writes "
                                   "products/object-mesh.ply, object-materials.json, object-scene.toml and "
                                   "validation/.")
    p.add_argument("session", metavar="SESSION", help="a session processed and projected (kogei process, kogei project)")
    p.add_argument("--holdout-every", type=int, default=HOLDOUT_EVERY, metavar="N",
                   help="hold every N-th frame of each pass out of the fit and validate on it (0: none) "
                        "(default %(default)s)")
    p.add_argument("--model-error", type=float, default=FIT_MODEL_ERROR, metavar="FRACTION",
                   help="relative error of the forward model added to each observation's noise, a fraction "
                        "(0.02 = 2 %%) (default %(default)s, as the batch's materials step)")
    p.add_argument("--max-regions", type=int, default=8, metavar="N",
                   help="most regions of one material the segmentation may find (default 8)")
    p.add_argument("--no-validate", action="store_true", help="skip rendering and comparing the held-out frames")
    p.add_argument("--decode", choices=["demosaic", "bin2x2"], default="demosaic",
                   help="RAW decoding of the held-out photos (default demosaic, as kogei project)")
    p.add_argument("--json", action="store_true", help="print the materials document as JSON")
    p.add_argument("--quiet", action="store_true", help="no progress messages")


def _de(figures: dict, key: str) -> str:
    """A CIEDE2000 figure for people: two decimals, or "-" where the document has none.

    >>> _de({"mean_de2000": 3.0312, "p95_de2000": None}, "mean_de2000"), _de({"p95_de2000": None}, "p95_de2000")
    ('3.03', '-')
    """
    x = figures.get(key)
    return "-" if x is None else f"{x:.2f}"


def summary_lines(doc: dict) -> list[str]:
    """The human-readable lines of a materials document (regions, baseline, validation)."""
    from app.workflows.object_materials import answer_text, area_text, unmeasured_share_text

    lines = []
    for r in doc["regions"]:
        params = ", ".join(f"{k} {v:.3g} +- {r.get('uncertainties', {}).get(k, float('nan')):.2g}"
                           for k, v in (r.get("parameters") or {}).items())
        why = f" -- {r['reason']}" if r.get("reason") else ""
        lines.append(f"  region {r['index']}: {answer_text(r)}, {area_text(r)}, "
                     f"{r['n_lit']} lit of {r['n_observations']} observations"
                     + (f"; {params}" if params else "") + why)
    nd = doc.get("normals") or {}
    if nd.get("method") == "photometric":
        lines.append(f"  normals refined by the photos: {100 * nd['decided_share']:.0f} % of the vertices decided by "
                     f"their highlights, median tilt {nd['median_tilt_deg']:.1f} deg")
    nm = doc.get("not_measured") or {}
    if nm.get("faces"):
        share = f", {text}" if (text := unmeasured_share_text(nm)) else ""
        advice = f": {nm['advice']}" if nm.get("advice") else " (no usable observation)"
        lines.append(f"  not measured: {nm['faces']} faces, {nm['area_mm2']:.0f} mm^2{share}{advice}")
    val = doc.get("validation") or {}
    if val.get("mean_de2000") is not None:
        lines.append(f"held-out photos ({len(val.get('frames') or [])} frames): mean CIEDE2000 "
                     f"{_de(val, 'mean_de2000')}, p95 {_de(val, 'p95_de2000')}; one material for the whole object "
                     f"({(doc.get('baseline') or {}).get('material')}): mean {_de(val, 'baseline_mean_de2000')}, p95 "
                     f"{_de(val, 'baseline_p95_de2000')}")
        if val.get("noise_floor_mean_de2000") is not None:
            lines.append(f"  the photos' own noise alone would give about {_de(val, 'noise_floor_mean_de2000')} "
                         "(a perfect model against photos with the sensor's noise, from the nominal noise model)")
        pooled = val.get("pooled") or {}
        if pooled.get("mean_de2000") is not None:
            s = pooled.get("block_px")
            floor = pooled.get("noise_floor_mean_de2000")
            lines.append(f"  at {s} x {s} px (linear values averaged in blocks before the colour conversion): mean "
                         f"{_de(pooled, 'mean_de2000')}, p95 {_de(pooled, 'p95_de2000')}; one material: mean "
                         f"{_de(pooled, 'baseline_mean_de2000')}"
                         + ("" if floor is None else f"; the noise alone about {floor:.2f}"))
    elif val.get("note"):
        lines.append(f"held-out photos: {val['note']}")
    return lines


def run(args: argparse.Namespace) -> int:
    from app.workflows.object_materials import measure_object

    def message(text: str) -> None:
        if not args.quiet:
            print(f"  {text}", file=sys.stderr)

    doc = measure_object(args.session, holdout_every=args.holdout_every, model_error=args.model_error,
                         max_regions=args.max_regions, validate=not args.no_validate, decode=args.decode,
                         message=message)
    if args.json:
        print(json.dumps(doc, indent=1))
        return 0
    print(f"{args.session}: {len(doc['regions'])} regions on the mesh")
    for line in summary_lines(doc):
        print(line)
    return 0
