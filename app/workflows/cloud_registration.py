"""Point clouds from files registered into the frame of the first, without an initial guess.

:func:`read_cloud` reads PLY / PCD / XYZ clouds (Open3D readers; normals are
used when the file has them), :func:`read_picks` the manual fallback's picked
point pairs, :func:`register_clouds` registers every pair and optimises a pose
graph (:func:`processing.geometry.registration.register_passes`), and
:func:`poses_document` / :func:`write_merged_cloud` give ``poses.json`` and the
merged cloud ``kogei register`` writes.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from app.errors import UsageError
from processing.common.files import JSONFileError, atomic_path, parse_json

__all__ = ["BYTES_PER_POINT", "MAX_PICKS_BYTES", "POSES_FORMAT", "READABLE", "UNITS_MM", "WRITABLE", "read_cloud", "read_picks", "poses_document", "write_poses",
           "write_merged_cloud"]

#: ``format`` field of poses.json.
POSES_FORMAT = "kogei-poses"

#: Point-cloud file suffixes read and written.
READABLE = (".ply", ".pcd", ".xyz", ".xyzn", ".xyzrgb", ".pts")
WRITABLE = (".ply", ".pcd", ".xyz", ".xyzn", ".pts")

#: Units of the files' coordinates (``kogei register --units``) and millimetres per unit.
UNITS_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "in": 25.4}


def _in_units(transform: np.ndarray, units: str) -> np.ndarray:
    """A 4 x 4 transform in mm with its translation expressed in ``units`` instead."""
    t = np.array(transform, dtype=np.float64)
    t[:3, 3] /= UNITS_MM[units]
    return t


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
    if path.suffix.lower() not in READABLE:
        raise UsageError(f"{path}: unsupported point-cloud format {path.suffix!r}; use one of {', '.join(READABLE)}")
    if not path.is_file():
        raise UsageError(f"{path}: file not found")
    _check_cloud_size(path)
    try:
        with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
            pcd = o3d.io.read_point_cloud(str(path), remove_nan_points=False, remove_infinite_points=False)
    except MemoryError:
        raise UsageError(f"{path}: not enough memory to read this point cloud; subsample it first") from None
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


#: Peak bytes per point of :func:`read_cloud`: measured 128 B (``ru_maxrss``, a 4M-point binary PLY with
#: normals: Open3D's float64 points and normals, their NumPy copies, the finiteness checks); rounded up.
BYTES_PER_POINT = 160


def _check_cloud_size(path: Path) -> None:
    """Refuse a file whose header declares more points than it holds, or than fit in the available memory."""
    from render.meshio import MeshError, check_declared_counts
    from render.renderer import available_memory_bytes

    try:
        declared = check_declared_counts(path)
    except MeshError as exc:
        raise UsageError(str(exc)) from None
    if not declared:
        return
    available = available_memory_bytes()
    need = declared * BYTES_PER_POINT
    if available is not None and need > available:
        raise UsageError(f"{path}: {declared} points need about {need / 1e9:.1f} GB of memory but "
                         f"{available / 1e9:.1f} GB is available; subsample the cloud first")


#: Largest picks file read: a few dozen picked points are a few kB.
MAX_PICKS_BYTES = 1 << 20
#: What to do about a picks file that cannot be read.
_PICKS_REMEDY = 'give a JSON list of {"pair": [i, j], "points": [A, B]} entries'


def read_picks(path: Path, n_inputs: int) -> dict[tuple[int, int], tuple[np.ndarray, np.ndarray]]:
    """Manual picks from a JSON file as ``{(i, j): (points_on_i, points_on_j)}`` with ``i < j``."""
    path = Path(path)
    if not path.is_file():
        raise UsageError(f"--picks: {path}: file not found")
    if path.stat().st_size > MAX_PICKS_BYTES:
        raise UsageError(f"--picks: {path}: {path.stat().st_size} bytes is too large for a picks file "
                         f"(at most {MAX_PICKS_BYTES} bytes)")
    try:
        data = parse_json(path.read_bytes(), f"--picks: {path}", _PICKS_REMEDY)
    except OSError as exc:
        raise UsageError(f"--picks: {path}: unreadable ({exc.strerror or exc})") from None
    except JSONFileError as exc:
        raise UsageError(f"--picks: {path}: not valid JSON ({exc.reason}); {_PICKS_REMEDY}") from None
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
            raise UsageError(f"{where}: points must be lists of [x, y, z] numbers in mm (or in --units)") from None
        if a.ndim != 2 or a.shape[1:] != (3,) or a.shape != b.shape:
            raise UsageError(
                f"{where}: points must be two equally long lists of [x, y, z], got shapes {a.shape} and {b.shape}"
            )
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            raise UsageError(f"{where}: points must be finite numbers (no NaN or Infinity)")
        if i > j:
            i, j, a, b = j, i, b, a
        out[(i, j)] = (a, b)
    return out


def poses_document(files: list[str], counts: list[int], result: Any, *, units: str = "mm") -> dict[str, Any]:
    """The JSON form of poses.json: per input its pose into the first's frame, every pair, the pose graph.

    ``result`` is in mm; the matrices' translations are written in ``units`` (the files'
    unit, see :data:`UNITS_MM`), every ``*_mm`` metric stays in mm.
    """
    if units not in UNITS_MM:
        raise UsageError(f"--units: unknown unit {units!r}; use one of {', '.join(UNITS_MM)}")
    inputs = []
    for f, n, pose in zip(files, counts, result.poses):
        inputs.append({
            "file": f,
            "points": n,
            "registered": pose.registered,
            "reason": pose.reason,
            "matrix": None if pose.transform is None else _in_units(pose.transform, units).tolist(),
        })
    pairs = []
    for r in result.pairs:
        d = r.as_dict()
        d["transform"] = _in_units(r.transform, units).tolist()
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
        "units": units,
        "preset": result.preset.name,
        "inputs": inputs,
        "pairs": pairs,
        "pose_graph": graph,
        "seconds": result.seconds,
    }


def write_poses(path: Path, document: dict[str, Any]) -> None:
    """Write poses.json atomically (NaN, e.g. a picked pair's margin, is not allowed: give None)."""
    with atomic_path(path, durable=False) as tmp:
        tmp.write_text(json.dumps(document, indent=2, allow_nan=False) + "\n")


def write_merged_cloud(path: Path, clouds: list[np.ndarray], result: Any, normals: list[np.ndarray | None],
                       *, units: str = "mm") -> None:
    """The registered inputs merged in the first one's frame, written atomically (with normals if all have them).

    ``clouds`` and ``result`` are in mm; the file is written in ``units`` (see :data:`UNITS_MM`).
    """
    import open3d as o3d

    from processing.geometry.registration import merge_passes

    if units not in UNITS_MM:
        raise UsageError(f"--units: unknown unit {units!r}; use one of {', '.join(UNITS_MM)}")
    pts, nrm, _ = merge_passes(clouds, result, normals)
    pts = pts / UNITS_MM[units]
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    if nrm is not None:
        pcd.normals = o3d.utility.Vector3dVector(nrm)
    with atomic_path(path, durable=False) as tmp:
        if not o3d.io.write_point_cloud(str(tmp), pcd):
            raise UsageError(f"--out: {path}: could not be written")
