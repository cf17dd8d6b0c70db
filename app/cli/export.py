"""``kogei export``: a measured session's object as a file other programs open (a shell over
:func:`app.workflows.gltf_export.export_gltf`).

Examples
--------
>>> import argparse
>>> parser = argparse.ArgumentParser(prog="kogei")
>>> _ = add_parser(parser.add_subparsers(dest="command"))
>>> args = parser.parse_args(["export", "scan", "--gltf", "hawk.glb", "--force"])
>>> args.session, args.gltf, args.force
('scan', 'hawk.glb', True)
"""

from __future__ import annotations

import argparse
import json

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add the ``export`` subcommand to ``sub``."""
    p = sub.add_parser("export", help="write the measured object as glTF 2.0 (.glb) with PBR materials",
                       description="Write a measured session's mesh with its materials "
                                   "(products/object-materials.json and products/object-mesh.ply) as a binary "
                                   "glTF 2.0 file: one primitive per material region, a metallic-roughness "
                                   "material each (base colour from the measured spectra under D65), the exact "
                                   "material spec, parameters and uncertainties under extras.kogei.  See "
                                   "docs/export.md.")
    p.add_argument("session", metavar="SESSION", help="a session whose materials were fitted (kogei fit-materials)")
    p.add_argument("--gltf", required=True, metavar="OUT.glb", help="the .glb file to write (atomically)")
    p.add_argument("--force", action="store_true", help="replace OUT.glb if it exists")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")


def run(args: argparse.Namespace) -> int:
    """Export; print one line per region (or the JSON summary)."""
    from app.cli.outputs import check_output_file
    from app.workflows.gltf_export import export_gltf

    check_output_file(args.gltf, "--gltf")      # its folder exists and takes a file, before the work
    summary = export_gltf(args.session, args.gltf, force=args.force)
    if args.json:
        print(json.dumps(summary, indent=1))
        return 0
    for r in summary["regions"]:
        colour = ", ".join(f"{c:.3f}" for c in r["base_color"])
        what = r["spec"] if r["measured"] else "not measured (neutral grey)"
        print(f"  region {r['index']:>2}: {r['faces']:>7} faces  {r['name']:<16} base colour ({colour}) "
              f"metallic {r['metallic']:g} roughness {r['roughness']:.3f}  {what}")
    print(f"wrote {summary['out']}: {summary['triangles']} triangles, {len(summary['regions'])} primitives, "
          f"{summary['bytes']} bytes")
    return 0
