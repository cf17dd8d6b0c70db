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

Exit status 0 when every input is registered, 1 when some could not be (the
files are still written, without those inputs, and the reasons are printed),
2 for bad input (:class:`app.errors.UsageError`, raised with the file named).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from app.errors import UsageError

__all__ = ["POSES_FORMAT", "add_parser", "read_cloud", "read_picks", "run"]

#: ``format`` field of poses.json.
POSES_FORMAT = "kogei-poses"

_READABLE = (".ply", ".pcd", ".xyz", ".xyzn", ".xyzrgb", ".pts")
_WRITABLE = (".ply", ".pcd", ".xyz", ".xyzn", ".pts")


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
    p.add_argument("--preset", default="standard", choices=["draft", "standard", "reference"])
    p.add_argument("--pairs", default="all", choices=["all", "sequential"],
                   help="register every pair (default) or consecutive pairs plus last-to-first")
    p.add_argument("--picks", default=None, metavar="PICKS.json",
                   help='manual picks: [{"pair": [i, j], "points": [[[x,y,z], ...], [[x,y,z], ...]]}], '
                        "3 or more corresponding points on input i and input j (0-based)")
    p.add_argument("--drop-invalid", action="store_true",
                   help="drop NaN / infinite points instead of refusing the file")
    p.add_argument("--seed", type=int, default=0, help="seed of the random subsampling")
    p.add_argument("--quiet", action="store_true")
    return p


def read_cloud(path: Path, *, drop_invalid: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """Points ``(N, 3)`` and normals (or None) of a point-cloud file; UsageError names the file.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> f = pathlib.Path(tempfile.mkdtemp()) / "three.xyz"
    >>> _ = f.write_text("0 0 0\\n1 0 0\\n0 1 0\\n")
    >>> pts, nrm = read_cloud(f)
    >>> pts.shape, nrm is None
    ((3, 3), True)
    """
    import open3d as o3d

    path = Path(path)
    if path.suffix.lower() not in _READABLE:
        raise UsageError(f"{path}: unsupported point-cloud format {path.suffix!r}; use one of {', '.join(_READABLE)}")
    if not path.is_file():
        raise UsageError(f"{path}: file not found")
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        pcd = o3d.io.read_point_cloud(str(path), remove_nan_points=False, remove_infinite_points=False)
    pts = np.asarray(pcd.points, dtype=np.float64)
    if len(pts) == 0:
        raise UsageError(f"{path}: no points could be read (empty, damaged, or not a point cloud)")
    nrm = np.asarray(pcd.normals, dtype=np.float64) if pcd.has_normals() else None
    bad = ~np.all(np.isfinite(pts), axis=1)
    if nrm is not None:
        nbad = ~np.all(np.isfinite(nrm), axis=1) | (np.linalg.norm(np.nan_to_num(nrm), axis=1) < 1e-12)
        if nbad.all():
            nrm = None
        else:
            bad |= nbad
    if bad.any():
        if not drop_invalid:
            raise UsageError(
                f"{path}: {int(bad.sum())} of {len(pts)} points have NaN or infinite coordinates "
                "(or normals); remove them, or pass --drop-invalid"
            )
        pts = pts[~bad]
        nrm = None if nrm is None else nrm[~bad]
        if len(pts) == 0:
            raise UsageError(f"{path}: every point is NaN or infinite")
    if nrm is not None:
        nrm = nrm / np.linalg.norm(nrm, axis=1, keepdims=True)
    return pts, nrm


def read_picks(path: Path, n_inputs: int) -> dict[tuple[int, int], tuple[np.ndarray, np.ndarray]]:
    """Manual picks from a JSON file as ``{(i, j): (points_on_i, points_on_j)}`` with ``i < j``."""
    path = Path(path)
    if not path.is_file():
        raise UsageError(f"--picks: {path}: file not found")
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise UsageError(f"--picks: {path}: not valid JSON ({exc})") from None
    if not isinstance(data, list):
        raise UsageError(f'--picks: {path}: expected a list of {{"pair": [i, j], "points": [A, B]}} entries')
    out: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
    for k, entry in enumerate(data):
        where = f"--picks: {path}: entry {k}"
        if not isinstance(entry, dict) or "pair" not in entry or "points" not in entry:
            raise UsageError(f'{where}: needs "pair": [i, j] and "points": [points on i, points on j]')
        pair, points = entry["pair"], entry["points"]
        if (not isinstance(pair, list) or len(pair) != 2
                or not all(isinstance(v, int) and not isinstance(v, bool) for v in pair)):
            raise UsageError(f"{where}: pair must be two input indices (0-based), got {pair!r}")
        i, j = pair
        if not (0 <= i < n_inputs and 0 <= j < n_inputs) or i == j:
            raise UsageError(f"{where}: pair {pair} must name two different inputs among 0..{n_inputs - 1}")
        if not isinstance(points, list) or len(points) != 2:
            raise UsageError(f"{where}: points must be [points on input {i}, points on input {j}]")
        try:
            a = np.asarray(points[0], dtype=np.float64)
            b = np.asarray(points[1], dtype=np.float64)
        except (TypeError, ValueError):
            raise UsageError(f"{where}: points must be lists of [x, y, z] numbers in mm") from None
        if a.ndim != 2 or a.shape[1:] != (3,) or a.shape != b.shape:
            raise UsageError(
                f"{where}: points must be two equally long lists of [x, y, z], got shapes {a.shape} and {b.shape}"
            )
        if i > j:
            i, j, a, b = j, i, b, a
        out[(i, j)] = (a, b)
    return out


def _write_atomically(path: Path, write: Any) -> None:
    """Write through a temporary file in the same folder, then rename."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        write(Path(tmp))
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _check_output(path: str | None, flag: str, suffixes: tuple[str, ...]) -> Path | None:
    if path is None:
        return None
    out = Path(path)
    if out.suffix.lower() not in suffixes:
        raise UsageError(f"{flag}: {out} must end in one of {', '.join(suffixes)}")
    if out.exists() and out.is_dir():
        raise UsageError(f"{flag}: {out} is a directory")
    return out


def _poses_document(files: list[str], counts: list[int], result: Any) -> dict[str, Any]:
    inputs = []
    for f, n, pose in zip(files, counts, result.poses):
        inputs.append({
            "file": f,
            "points": n,
            "registered": pose.registered,
            "reason": pose.reason,
            "matrix": None if pose.transform is None else np.asarray(pose.transform).tolist(),
        })
    pairs = []
    for r in result.pairs:
        d = r.as_dict()
        d["source_file"], d["target_file"] = files[r.source], files[r.target]
        pairs.append(d)
    graph = None
    if result.consistency is not None:
        c = result.consistency
        graph = {
            "max_rotation_deg": c.max_rotation_deg,
            "max_displacement_mm": c.max_displacement_mm,
            "edges": [
                {"source": s, "target": t, "rotation_deg": rd, "displacement_mm": dm, "confidence": cf}
                for s, t, rd, dm, cf in c.edges
            ],
        }
    return {
        "format": POSES_FORMAT,
        "version": 1,
        "frame": files[0],
        "preset": result.preset.name,
        "inputs": inputs,
        "pairs": pairs,
        "pose_graph": graph,
        "seconds": result.seconds,
    }


def run(args: argparse.Namespace) -> int:
    """Run ``kogei register``; returns the exit status (UsageError for bad input)."""
    import open3d as o3d

    from processing.geometry.registration import RegistrationError, merge_passes, register_passes

    out = _check_output(args.out, "--out", _WRITABLE)
    poses_path = _check_output(args.poses, "--poses", (".json",))
    if out is None and poses_path is None:
        raise UsageError("nothing to write: give --out MERGED.ply and/or --poses POSES.json")
    if len(args.clouds) < 2:
        raise UsageError("give at least two point clouds to register")
    files = [str(c) for c in args.clouds]
    clouds, normals = [], []
    for f in files:
        pts, nrm = read_cloud(Path(f), drop_invalid=args.drop_invalid)
        clouds.append(pts)
        normals.append(nrm)
    picks = read_picks(Path(args.picks), len(files)) if args.picks else None
    try:
        result = register_passes(clouds, normals, preset=args.preset, pairs=args.pairs, picks=picks,
                                 names=files, seed=args.seed)
    except RegistrationError as exc:
        raise UsageError(str(exc)) from None

    say = (lambda *a: None) if args.quiet else (lambda *a: print(*a, file=sys.stderr))
    for r in result.pairs:
        head = f"{files[r.source]} -> {files[r.target]}"
        if r.verified:
            say(f"{head}: verified ({r.method}), overlap {r.overlap:.1%}, RMS {r.rmse_mm:.3g} mm "
                f"(expected {r.expected_rmse_mm:.3g}), margin {r.margin:.2f}, {r.seconds:.1f} s")
        else:
            say(f"{head}: NOT verified ({r.method}): {r.reason}")
    if result.consistency is not None:
        c = result.consistency
        say(f"pose graph: edges agree within {c.max_rotation_deg:.3g} deg and {c.max_displacement_mm:.3g} mm")

    if poses_path is not None:
        doc = _poses_document(files, [len(c) for c in clouds], result)
        _write_atomically(poses_path, lambda p: p.write_text(json.dumps(doc, indent=2, allow_nan=False) + "\n"))
    if out is not None:
        pts, nrm, _ = merge_passes(clouds, result, normals)
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
        if nrm is not None:
            pcd.normals = o3d.utility.Vector3dVector(nrm)

        def write(p: Path) -> None:
            if not o3d.io.write_point_cloud(str(p), pcd):
                raise UsageError(f"--out: {out}: could not be written")

        _write_atomically(out, write)
    written = ", ".join(str(p) for p in (out, poses_path) if p is not None)
    n_ok = sum(p.registered for p in result.poses)
    say(f"wrote {written} ({n_ok} of {len(files)} inputs registered, {result.seconds:.1f} s)")
    missing = [p for p in result.poses if not p.registered]
    for p in missing:
        print(f"kogei register: {p.reason}", file=sys.stderr)
    return 1 if missing else 0
