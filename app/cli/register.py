"""``kogei register``: register point clouds from anywhere into the frame of the first.

``kogei register A.ply B.ply ... --out merged.ply --poses poses.json
[--preset draft|standard|reference]`` reads PLY / PCD / XYZ clouds (Open3D
readers; normals are used when the file has them and estimated otherwise),
registers every pair without an initial guess and optimises a pose graph
(:func:`processing.geometry.registration.register_passes`), then writes

* ``poses.json``: per input its 4 x 4 matrix mapping it into the first
  input's frame (``null`` when it could not be registered, with the reason),
  every pairwise result with its ``verified`` flag and metrics (overlap,
  RMS residual and the residual expected from the clouds' roughness, margin
  over the strongest competing pose, time), and the pose-graph consistency;
* the merged cloud of the registered inputs (PLY, PCD or XYZ by extension),
  with normals if every registered input has them.

``--picks`` takes the manual fallback: three or more picked point pairs for
a pair the automatic search cannot settle (e.g. a symmetric object).
``--units mm|cm|m|in`` names the unit of the files' coordinates (default mm):
they are converted to mm for the registration (its presets and metrics are in
mm) and the merged cloud and the poses' translations are written back in that
unit.

Exit status 0 when every input is registered, 1 when some could not be (the
files are still written, without those inputs, and the reasons are printed),
2 for bad input (a one-line message naming the file).  The reading,
registering and writing are :mod:`app.workflows.cloud_registration`.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from app.cli.outputs import check_output_file, writing
from app.errors import UsageError
from app.workflows.cloud_registration import (
    UNITS_MM,
    WRITABLE,
    poses_document,
    read_cloud,
    read_picks,
    write_merged_cloud,
    write_poses,
)

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``register`` subcommand to ``sub`` and return its parser."""
    p = sub.add_parser(
        "register",
        help="register point clouds (PLY/PCD/XYZ) into the first one's frame and merge them",
        description="Register CLOUD files without an initial guess (global search, ICP, pose graph); "
                    "every pair is verified and a failure is reported, never a wrong pose.",
    )
    p.add_argument("clouds", nargs="+", metavar="CLOUD", help="two or more point clouds (.ply .pcd .xyz ...)")
    p.add_argument("--out", default=None, metavar="MERGED.ply", help="write the merged cloud here")
    p.add_argument("--poses", default=None, metavar="POSES.json",
                   help="write the poses and pairwise metrics here")
    p.add_argument("--preset", default="standard", choices=["draft", "standard", "reference"],
                   help="speed against accuracy of the registration: draft, standard, reference (docs/processing.md) "
                        "(default %(default)s)")
    p.add_argument("--pairs", default="all", choices=["all", "sequential"],
                   help="all: register every pair (default); sequential: consecutive pairs plus last-to-first")
    p.add_argument("--picks", default=None, metavar="PICKS.json",
                   help='manual picks: [{"pair": [i, j], "points": [[[x,y,z], ...], [[x,y,z], ...]]}], '
                        "3 or more corresponding points on input i and input j (0-based)")
    p.add_argument("--units", default="mm", choices=sorted(UNITS_MM),
                   help="unit of the files' coordinates (and of --picks); converted to mm for the registration, "
                        "the merged cloud and the poses are written in it (default %(default)s)")
    p.add_argument("--drop-invalid", action="store_true",
                   help="drop NaN / infinite points instead of refusing the file")
    p.add_argument("--seed", type=int, default=0, metavar="N", help="seed of the random subsampling (default %(default)s)")
    p.add_argument("--quiet", action="store_true", help="no progress messages")
    return p


def _check_output(path: str | None, flag: str, suffixes: tuple[str, ...]) -> Path | None:
    """The output ``path`` of ``flag`` (or None), its ending and its folder checked before the registration."""
    if path is None:
        return None
    out = Path(path)
    if out.suffix.lower() not in suffixes:
        raise UsageError(f"{flag}: {out} must end in one of {', '.join(suffixes)}")
    return check_output_file(out, flag, make_parents=True)


def run(args: argparse.Namespace) -> int:
    """Run ``kogei register``; returns the exit status (an input error for bad input, or when out of memory)."""
    try:
        return _register(args)
    except MemoryError:
        raise UsageError("not enough memory to register these clouds; subsample them (or use --preset draft) "
                         "or free memory") from None


def _register(args: argparse.Namespace) -> int:
    """Read, register and write; the exit status."""
    from processing.geometry.registration import register_passes

    out = _check_output(args.out, "--out", WRITABLE)
    poses_path = _check_output(args.poses, "--poses", (".json",))
    if out is None and poses_path is None:
        raise UsageError("nothing to write: give --out MERGED.ply and/or --poses POSES.json")
    if len(args.clouds) < 2:
        raise UsageError("give at least two point clouds to register")
    files = [str(c) for c in args.clouds]
    mm = UNITS_MM[args.units]
    clouds, normals = [], []
    for f in files:
        pts, nrm = read_cloud(Path(f), drop_invalid=args.drop_invalid)
        clouds.append(pts * mm)
        normals.append(nrm)
    picks = read_picks(Path(args.picks), len(files)) if args.picks else None
    if picks is not None:
        picks = {k: (a * mm, b * mm) for k, (a, b) in picks.items()}
    result = register_passes(clouds, normals, preset=args.preset, pairs=args.pairs, picks=picks,
                             names=files, seed=args.seed)

    say = (lambda *a: None) if args.quiet else (lambda *a: print(*a, file=sys.stderr))
    for r in result.pairs:
        head = f"{files[r.source]} -> {files[r.target]}"
        if r.verified:
            turn = (f", turn about the symmetry axis +-{r.turn_uncertainty_deg:.2f} deg"
                    if math.isfinite(r.turn_uncertainty_deg) else "")
            say(f"{head}: verified ({r.method}), overlap {r.overlap:.1%}, RMS {r.rmse_mm:.3g} mm "
                f"(expected {r.expected_rmse_mm:.3g}), margin {r.margin:.2f}{turn}, {r.seconds:.1f} s")
        else:
            say(f"{head}: NOT verified ({r.method}): {r.reason}")
    if result.consistency is not None:
        c = result.consistency
        say(f"pose graph: edges agree within {c.max_rotation_deg:.3g} deg and {c.max_displacement_mm:.3g} mm")

    if poses_path is not None:
        with writing(poses_path, "--poses"):
            write_poses(poses_path, poses_document(files, [len(c) for c in clouds], result, units=args.units))
    if out is not None:
        with writing(out, "--out"):
            write_merged_cloud(out, clouds, result, normals, units=args.units)
    written = ", ".join(str(p) for p in (out, poses_path) if p is not None)
    n_ok = sum(p.registered for p in result.poses)
    say(f"wrote {written} ({n_ok} of {len(files)} inputs registered, {result.seconds:.1f} s)")
    missing = [p for p in result.poses if not p.registered]
    for p in missing:
        print(f"kogei register: {p.reason}", file=sys.stderr)
    return 1 if missing else 0
