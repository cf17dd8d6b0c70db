"""Accuracy and speed of scan processing against the simulated station's ground truth.

Every profile is measured by the profiler emulator of :class:`mocks.station.SimulatedStation`
and travels the way a real capture's does: the turntable and profiler firmware emulators on
pseudo-terminals, the drivers, :func:`app.capture.runner.run_capture` writing the session, then
:func:`app.workflows.calibration.calibrate_session` (the station geometry comes from a scan of a
reference sphere, never from the truth) and :func:`app.workflows.process_session.process_session`
(``kogei process``).  Nothing of the truth is given to processing; it is used only to score:

* the pose of pass ``p`` (object -> table frame of that pass) is ``Rz(theta_p) @ place(p)``,
  ``theta_p`` the table's physical angle when the object was placed (the capture zeroes the
  table right after the placement), so the true transform of pass ``j`` into pass ``i``'s frame
  is ``T_i @ inv(T_j)``;
* the true surface in pass 1's frame is the world mesh moved by ``T_1``.

Measured per object (the procedural hawk on the default station; the Stanford bunny and Igea
scaled to 200 mm on a larger station):

* the calibration's residual and its error against the station's true sensor pose;
* pairwise automatic registration (:func:`processing.geometry.registration.register_pair`) of random
  placement pairs: success = verified *and* within 0.5 deg / 0.5 mm of the truth; a verified pair
  outside those limits is listed as verified-but-wrong;
* pose error after the pose graph (:func:`processing.geometry.registration.register_passes`);
* ``kogei process`` of a 3-pass session at each preset: pose errors, mesh -> truth and truth ->
  mesh distances (:func:`processing.geometry.surface_distance.surface_distance`), the error of the filled
  holes (truth -> mesh over the object's surface that no pass measured: farther than the surface
  stage's own hole threshold from every registered point), and the time.

Pose errors are a rotation angle (deg) and the largest displacement (mm) of the object's
vertices between the estimated and the true transform (:func:`pose_difference` with points),
which is stricter than a difference of translations.

Run ``python -m bench.geometry_bench [--quick] [--case hawk|bunny|igea|all]``; prints one JSON
object (the last line of the output).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import statistics
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bench.common import ROOT, machine_description, peak_rss_mb

__all__ = [
    "MESH_DIR",
    "OBJECTS",
    "StationGeometry",
    "BenchSettings",
    "SMALL_STATION",
    "LARGE_STATION",
    "FULL",
    "QUICK",
    "read_ply_tristrips",
    "close_boundary_loops",
    "prepare_scan_mesh",
    "load_object",
    "capture_session",
    "session_clouds",
    "calibrate_station",
    "pair_trials",
    "pose_graph_trial",
    "process_trial",
    "score_mesh",
    "run_object",
    "main",
]

#: Where the real scans live: ``$KOGEI_DATA/meshes``; by default the lab's data folder beside the checkout.
MESH_DIR = Path(os.environ.get("KOGEI_DATA", ROOT.parent / "shared" / "data")) / "meshes"

#: Objects of the benchmark: file name (None: procedural), the station they need, the mesh's up axis.
OBJECTS: dict[str, dict[str, Any]] = {
    "hawk": {"file": None, "station": "small"},
    "bunny": {"file": "stanford-bunny.obj", "station": "large", "up_axis": 1},
    "igea": {"file": "igea.ply", "station": "large", "up_axis": 1},
}

#: A pair (or pass) counts as registered correctly within these limits.
PAIR_LIMIT_DEG = 0.5
PAIR_LIMIT_MM = 0.5


@dataclass(frozen=True)
class StationGeometry:
    """A scan station's geometry and its reference sphere.

    Attributes
    ----------
    name
        Label for the tables.
    standoff_mm, height_mm, tilt_deg
        The sensor pose (:func:`mocks.station.station_sensor_to_room`).
    fov_deg, range_mm, n_points
        The profiler's fan (degrees), range window along ``Z_s`` (mm) and points per profile.
    table_radius_mm
        Radius of the table top (mm).
    sphere_radius_mm, sphere_offset_mm
        The calibration sphere and its distance from the table axis (mm).
    calibration_steps
        Profiles of the sphere scan.

    Examples
    --------
    >>> g = StationGeometry("t", 260.0, 120.0, 20.0, 40.0, (150.0, 360.0), 640, 100.0, 25.0, 60.0)
    >>> sorted(g.station_kwargs())
    ['fov_deg', 'n_points', 'range_mm', 'sensor_to_room', 'table_radius_mm']
    """

    name: str
    standoff_mm: float
    height_mm: float
    tilt_deg: float
    fov_deg: float
    range_mm: tuple[float, float]
    n_points: int
    table_radius_mm: float
    sphere_radius_mm: float
    sphere_offset_mm: float
    calibration_steps: int = 180

    def sensor_to_room(self) -> NDArray[np.float64]:
        """The true sensor pose (4 x 4, mm)."""
        from mocks.station import station_sensor_to_room

        return station_sensor_to_room(self.standoff_mm, self.height_mm, self.tilt_deg)

    def station_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of :class:`mocks.station.SimulatedStation` (noise and incidence: defaults)."""
        return {"sensor_to_room": self.sensor_to_room(), "fov_deg": self.fov_deg, "range_mm": self.range_mm,
                "n_points": self.n_points, "table_radius_mm": self.table_radius_mm}

    def describe(self) -> str:
        """One line for the tables."""
        return (f"{self.name}: emitter {self.standoff_mm:g} mm from the axis, {self.height_mm:g} mm up, "
                f"tilted {self.tilt_deg:g} deg, fan {self.fov_deg:g} deg x {self.n_points} points, range "
                f"{self.range_mm[0]:g}-{self.range_mm[1]:g} mm, table radius {self.table_radius_mm:g} mm")


#: The station's default geometry (``SimulatedStation()``): the hawk is seen top to bottom.
SMALL_STATION = StationGeometry("default station", 260.0, 120.0, 20.0, 40.0, (150.0, 360.0), 640, 100.0,
                                25.0, 60.0)
#: A station for ~200 mm objects: farther, higher, a wider fan, a bigger table and sphere.
LARGE_STATION = StationGeometry("large station", 450.0, 250.0, 25.0, 50.0, (250.0, 700.0), 640, 180.0,
                                40.0, 100.0)
STATIONS = {"small": SMALL_STATION, "large": LARGE_STATION}


@dataclass(frozen=True)
class BenchSettings:
    """How much the benchmark measures.

    Attributes
    ----------
    pairs
        Random placement pairs per object (consecutive placements ``(k, k + 1)``).
    pair_steps
        Profiles per revolution of the pair passes (the global registration downsamples anyway).
    steps
        Profiles per revolution of the pose-graph and 3-pass sessions, per station (``small``,
        ``large``): about 200 000 points per pass.
    graph_passes
        Placements of the pose-graph session (its first three are those of the 3-pass session).
    presets
        Presets of ``kogei process`` measured on the 3-pass session.
    repeats
        Runs of ``kogei process --preset standard`` (the median time is reported).
    samples
        Points sampled per surface for the distances.
    truth_triangles
        Triangles of the procedural hawk.
    objects
        Which objects to measure.
    """

    pairs: int = 20
    pair_steps: int = 360
    steps: dict[str, int] = field(default_factory=lambda: {"small": 900, "large": 800})
    graph_passes: int = 6
    presets: tuple[str, ...] = ("draft", "standard", "reference")
    repeats: int = 3
    samples: int = 200_000
    truth_triangles: int = 200_000
    objects: tuple[str, ...] = ("hawk", "bunny", "igea")


FULL = BenchSettings()
QUICK = BenchSettings(pairs=3, pair_steps=120, steps={"small": 180, "large": 180}, graph_passes=4,
                      presets=("draft", "standard"), repeats=1, samples=50_000, truth_triangles=40_000,
                      objects=("hawk",))


# ---------------------------------------------------------------------------------------------- meshes
def read_ply_tristrips(path: str | Path) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Vertices and triangles of a binary PLY whose faces are one ``tristrips`` list (strips split by -1).

    Strips alternate their winding: triangle ``k`` of a strip is ``(s_k, s_k+1, s_k+2)`` for even
    ``k`` and ``(s_k+1, s_k, s_k+2)`` for odd ``k``; degenerate triangles (a repeated index) are
    dropped.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "s.ply"
    >>> head = ("ply\\nformat binary_little_endian 1.0\\nelement vertex 4\\nproperty float x\\n"
    ...         "property float y\\nproperty float z\\nelement tristrips 1\\n"
    ...         "property list int int vertex_indices\\nend_header\\n").encode()
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], "<f4")
    >>> _ = p.write_bytes(head + v.tobytes() + np.array([5, 0, 1, 2, 3, -1], "<i4").tobytes())
    >>> read_ply_tristrips(p)[1].tolist()
    [[0, 1, 2], [2, 1, 3]]
    """
    path = Path(path)
    with open(path, "rb") as fh:
        header = []
        while True:
            line = fh.readline()
            if not line:
                raise ValueError(f"{path}: no end_header line; not a PLY file")
            text = line.decode("ascii", "replace").strip()
            header.append(text)
            if text == "end_header":
                break
        body = fh.read()
    if "format binary_little_endian 1.0" not in header:
        raise ValueError(f"{path}: only binary little-endian PLY tristrips are read here")
    try:
        n_vertices = int(next(h for h in header if h.startswith("element vertex")).split()[2])
    except StopIteration:
        raise ValueError(f"{path}: no vertex element") from None
    vertex_props = []
    in_vertex = False
    for h in header:
        if h.startswith("element"):
            in_vertex = h.startswith("element vertex")
        elif in_vertex and h.startswith("property"):
            vertex_props.append(h)
    if vertex_props != ["property float x", "property float y", "property float z"] or \
            "element tristrips 1" not in header:
        raise ValueError(f"{path}: expected float x, y, z vertices and one tristrips element")
    v = np.frombuffer(body, "<f4", count=3 * n_vertices).reshape(-1, 3).astype(np.float64)
    off = 12 * n_vertices
    count = int(np.frombuffer(body, "<i4", count=1, offset=off)[0])
    s = np.frombuffer(body, "<i4", count=count, offset=off + 4).astype(np.int64)
    # start of the strip of every position: one past the last -1 before it
    marks = np.where(s == -1, np.arange(s.size), -1)
    start = np.maximum.accumulate(marks) + 1
    k = np.arange(max(s.size - 2, 0))
    ok = (s[k] >= 0) & (s[k + 1] >= 0) & (s[k + 2] >= 0)
    k = k[ok]
    odd = (k - start[k]) % 2 == 1
    a = np.where(odd, s[k + 1], s[k])
    b = np.where(odd, s[k], s[k + 1])
    t = np.stack([a, b, s[k + 2]], axis=1)
    t = t[(t[:, 0] != t[:, 1]) & (t[:, 1] != t[:, 2]) & (t[:, 0] != t[:, 2])]
    if t.size == 0 or t.max() >= n_vertices:
        raise ValueError(f"{path}: the strips hold no triangle or index past the {n_vertices} vertices")
    return v, t


def close_boundary_loops(vertices: ArrayLike, triangles: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Close every boundary loop of a mesh with a fan of triangles around the loop's centroid.

    A scanned object (the Stanford bunny has five holes in its base where the scanner saw
    nothing) is a solid in reality; closing the loops keeps the simulated profiler from seeing the
    inside of the shell through them.  The new triangles traverse each boundary edge opposite to
    its triangle, so the orientation stays consistent.

    Examples
    --------
    >>> from processing.geometry.mesh_topology import mesh_topology
    >>> box = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]])
    >>> open_box = [[0, 2, 1], [0, 3, 2], [0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6],
    ...             [3, 0, 4], [3, 4, 7]]                      # no lid
    >>> v, t = close_boundary_loops(box, open_box)
    >>> len(v), len(t), mesh_topology(t).watertight
    (9, 14, True)
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from processing.geometry.mesh_topology import boundary_edges

    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    e = boundary_edges(t)
    if e.size == 0:
        return v, t
    n = v.shape[0]
    graph = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    loops, loop_of_edge = np.unique(label[e[:, 0]], return_inverse=True)
    on_loop = np.unique(e.reshape(-1))
    loop_of_vertex = np.searchsorted(loops, label[on_loop])
    counts = np.bincount(loop_of_vertex, minlength=len(loops)).astype(np.float64)
    centroid = np.stack([np.bincount(loop_of_vertex, weights=v[on_loop, k], minlength=len(loops))
                         for k in range(3)], axis=1) / counts[:, None]
    centre_index = n + loop_of_edge
    fan = np.stack([e[:, 1], e[:, 0], centre_index], axis=1)
    return np.vstack([v, centroid]), np.vstack([t, fan])


def prepare_scan_mesh(vertices: ArrayLike, triangles: ArrayLike, size_mm: float = 200.0,
                      up_axis: int = 1) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """A scanned mesh as a solid object for the station: closed, outward, ``up_axis`` -> +z, scaled.

    The largest bounding-box extent becomes ``size_mm``; the box's centre is put on the z axis and
    its bottom at ``z = 0``.

    Examples
    --------
    >>> v = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0], [0, 0, 2.0]])
    >>> pv, pt = prepare_scan_mesh(v, [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], 10.0, up_axis=2)
    >>> np.ptp(pv, axis=0).tolist(), float(pv[:, 2].min())
    ([10.0, 10.0, 10.0], 0.0)
    """
    from processing.geometry.mesh_topology import mesh_topology

    v, t = close_boundary_loops(vertices, triangles)
    topo = mesh_topology(t)
    if not topo.watertight:
        raise ValueError(f"the mesh is not a closed two-manifold after closing its holes: {topo}")
    axes = [(up_axis + 1) % 3, (up_axis + 2) % 3, up_axis]   # a cyclic permutation: a proper rotation
    v = v[:, axes]
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    if np.einsum("ij,ij->i", a, np.cross(b, c)).sum() < 0:   # signed volume: the normals point inward
        t = t[:, [0, 2, 1]]
    lo, hi = v.min(axis=0), v.max(axis=0)
    v = (v - [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]]) * (size_mm / float((hi - lo).max()))
    return v, t


def _read_scan_mesh(path: Path) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Vertices and triangles of a mesh file (PLY triangle strips included, which Open3D does not read)."""
    from render.meshio import load_mesh

    if path.suffix.lower() == ".ply":
        with open(path, "rb") as fh:
            head = fh.read(4096)
        if b"element tristrips" in head.split(b"end_header")[0]:
            return read_ply_tristrips(path)
    mesh = load_mesh(path)
    return mesh.vertices, mesh.triangles


def load_object(name: str, work: Path, settings: BenchSettings) -> tuple[Any, str] | None:
    """The world of object ``name`` and a note on where it came from; None if its file is missing."""
    from mocks.world import World
    from processing.geometry.mesh_ply import write_mesh_ply
    from processing.geometry.mesh_topology import boundary_edges

    spec = OBJECTS[name]
    if spec["file"] is None:
        return World.hawk(settings.truth_triangles), f"procedural hawk head, {settings.truth_triangles:,} triangles"
    src = MESH_DIR / spec["file"]
    if not src.is_file():
        return None
    v, t = _read_scan_mesh(src)
    open_edges = len(boundary_edges(t))
    pv, pt = prepare_scan_mesh(v, t, 200.0, up_axis=spec["up_axis"])
    path = work / f"{name}-200mm.ply"
    write_mesh_ply(path, pv, pt, comment="millimetres")
    note = (f"{spec['file']}, {len(pt):,} triangles, scaled to 200 mm, {'xyz'[spec['up_axis']]} up"
            + (f", {len(pv) - len(v)} holes ({open_edges} boundary edges) closed" if len(pv) > len(v) else ""))
    return World.from_mesh_file(path), note


# ---------------------------------------------------------------------------------------------- capture
def _transformed(transform: NDArray[np.float64], points: NDArray[np.float64]) -> NDArray[np.float64]:
    return points @ transform[:3, :3].T + transform[:3, 3]


def capture_session(world: Any, geometry: StationGeometry, root: Path, *, steps: int, passes: int,
                    seed: int) -> dict[int, NDArray[np.float64]]:
    """Scan ``world`` in ``passes`` placements through the station's emulators into ``root/session``.

    The station works on a copy of ``world`` (it moves the copy's pose), so every session starts from
    the world's own base pose: placement 1 is that pose resting on the table.

    Returns
    -------
    dict
        Per pass, the true object -> table-frame transform ``Rz(theta_p) @ place(p)`` (4 x 4).
    """
    from app.capture.devices import build_devices
    from app.capture.runner import CaptureHooks, CapturePlan, run_capture
    from app.session import Session
    from mocks.station import SimulatedStation
    from mocks.world import rotation_z

    truth: dict[int, NDArray[np.float64]] = {}
    world = replace(world, pose=np.array(world.pose))   # the station moves its world's pose
    with SimulatedStation(world, root=root / "station", seed=seed, **geometry.station_kwargs()) as st:
        plan = CapturePlan("scan", steps=steps, passes=passes, camera=False)
        config = {"turntable": {"port": str(st.turntable_path)}, "profiler": {"port": str(st.profiler_path)}}
        session = Session.create(root / "session", plan=plan.to_dict())

        def before_pass(p: int, n: int) -> None:
            theta = st.table_angle_deg          # the capture zeroes the table right after this
            truth[p] = rotation_z(theta) @ st.place(p)

        try:
            run_capture(session, plan, build_devices(config, session.root), CaptureHooks(before_pass=before_pass))
        finally:
            session.close()
    return truth


def calibrate_station(geometry: StationGeometry, root: Path, seed: int = 7) -> dict[str, Any]:
    """Scan the geometry's reference sphere, calibrate with ``kogei calibrate``, compare with the truth."""
    from app.session import Session
    from app.workflows.calibration import calibrate_session, session_calibration
    from mocks.world import World
    from processing.geometry.registration import pose_difference

    world = World.calibration_sphere(geometry.sphere_radius_mm, geometry.sphere_offset_mm)
    t0 = time.perf_counter()
    capture_session(world, geometry, root, steps=geometry.calibration_steps, passes=1, seed=seed)
    ref = calibrate_session(root / "session", geometry.sphere_radius_mm)
    cal = session_calibration(root / "session", Session.read(root / "session"))
    rot, shift = pose_difference(cal.sensor_to_room, geometry.sensor_to_room())
    return {"session": str(root / "session"), "rms_mm": ref["rms_mm"], "max_mm": ref["max_mm"],
            "rotation_error_deg": rot, "origin_error_mm": shift, "seconds": time.perf_counter() - t0}


def session_clouds(session_dir: Path, calibration: str) -> list[dict[str, Any]]:
    """Per pass the cloud exactly as ``kogei process`` builds it (after installing the calibration)."""
    from app.session import Session
    from app.workflows.calibration import install_calibration, load_calibration_source, session_calibration
    from app.workflows.process_session import _pass_clouds

    with Session.open(session_dir) as s:
        install_calibration(s, load_calibration_source(calibration))
        manifest = s.manifest
        cal = session_calibration(session_dir, manifest)
        return _pass_clouds(session_dir, manifest, cal, lambda text: None)


def _stats(values: list[float]) -> dict[str, float]:
    arr = np.asarray(values, dtype=np.float64)
    if arr.size == 0:
        return {"median": math.nan, "max": math.nan}
    return {"median": float(np.median(arr)), "max": float(arr.max())}


# ---------------------------------------------------------------------------------------------- trials
def pair_trials(clouds: list[dict[str, Any]], truth: dict[int, NDArray[np.float64]], world: Any,
                pairs: int, preset: str = "standard") -> dict[str, Any]:
    """Register placements ``(k, k + 1)``, ``k = 1..pairs``, with no initial guess; score against the truth.

    ``clouds`` are the session's pass clouds as ``kogei process`` builds them (:func:`session_clouds`).
    """
    from processing.geometry.registration import pose_difference, register_pair

    rows = []
    for k in range(1, pairs + 1):
        a, b = clouds[k - 1], clouds[k]
        row: dict[str, Any] = {"pair": [k, k + 1]}
        if "cloud" not in a or "cloud" not in b:
            row.update(verified=False, correct=False, reason="a pass has no usable cloud: "
                       + "; ".join(e.get("skipped", "") for e in (a, b) if "cloud" not in e))
            rows.append(row)
            continue
        res = register_pair(b["cloud"][0], a["cloud"][0], source_normals=b["cloud"][1],
                            target_normals=a["cloud"][1], preset=preset, seed=k)
        true = truth[k] @ np.linalg.inv(truth[k + 1])
        rot, disp = pose_difference(res.transform, true, _transformed(truth[k + 1], world.vertices))
        row.update(verified=bool(res.verified), reason=res.reason, rotation_error_deg=rot,
                   displacement_error_mm=disp, seconds=res.seconds, overlap=res.overlap, margin=res.margin,
                   correct=bool(rot <= PAIR_LIMIT_DEG and disp <= PAIR_LIMIT_MM))
        rows.append(row)
    ok = [r for r in rows if r["verified"] and r["correct"]]
    wrong = [r for r in rows if r["verified"] and not r["correct"]]
    unverified = [r for r in rows if not r["verified"]]
    return {
        "preset": preset,
        "pairs": len(rows),
        "succeeded": len(ok),
        "rate": len(ok) / len(rows) if rows else math.nan,
        "verified_wrong": wrong,
        "unverified": unverified,
        "rotation_error_deg": _stats([r["rotation_error_deg"] for r in ok]),
        "displacement_error_mm": _stats([r["displacement_error_mm"] for r in ok]),
        "seconds": _stats([r["seconds"] for r in rows if "seconds" in r]),
        "points_per_pass": int(np.median([e["points"] for e in clouds if "points" in e])),
        "rows": rows,
    }


def pose_graph_trial(clouds: list[dict[str, Any]], truth: dict[int, NDArray[np.float64]], world: Any,
                     passes: int, samples: int, preset: str = "standard") -> dict[str, Any]:
    """Register the first ``passes`` placements together (all pairs + pose graph), as ``kogei process``
    does; pose error per pass, and the ``standard`` mesh of the merged passes (``mesh["_scene"]``: what
    :func:`score_mesh` needs, scored by :func:`run_object`)."""
    from processing.geometry.registration import merge_passes, register_passes
    from processing.geometry.surface import reconstruct_surface

    clouds = [e for e in clouds[:passes] if "cloud" in e]
    res = register_passes([e["cloud"][0] for e in clouds], [e["cloud"][1] for e in clouds], preset=preset,
                          names=[f"pass {e['pass']}" for e in clouds])
    errors = _pose_errors([e["pass"] for e in clouds], [p.transform for p in res.poses], truth, world)
    points, normals, _ = merge_passes([e["cloud"][0] for e in clouds], res, [e["cloud"][1] for e in clouds])
    confidence = np.concatenate([e["cloud"][2] for e, p in zip(clouds, res.poses) if p.registered])
    t0 = time.perf_counter()
    surf = reconstruct_surface(points, normals, confidence, preset=preset)
    mesh = {"points": int(len(points)), "seconds": time.perf_counter() - t0, "watertight": bool(surf.watertight),
            "_scene": (surf.vertices, surf.triangles, points, truth[clouds[0]["pass"]])}
    return {"passes": passes, "used": len(clouds), "registered": sum(p.registered for p in res.poses),
            "pairs_verified": sum(r.verified for r in res.pairs), "pairs": len(res.pairs),
            "seconds": res.seconds, "points_per_pass": int(np.median([len(e["cloud"][0]) for e in clouds])),
            "mesh": mesh, **errors}


def _pose_errors(pass_numbers: list[int], transforms: list[Any], truth: dict[int, NDArray[np.float64]],
                 world: Any) -> dict[str, Any]:
    """Errors of the poses (pass -> first pass's frame) against ``T_first @ inv(T_p)``."""
    from processing.geometry.registration import pose_difference

    first = pass_numbers[0]
    rows = []
    for p, t in zip(pass_numbers[1:], transforms[1:]):
        if t is None:
            rows.append({"pass": p, "registered": False})
            continue
        true = truth[first] @ np.linalg.inv(truth[p])
        rot, disp = pose_difference(np.asarray(t), true, _transformed(truth[p], world.vertices))
        rows.append({"pass": p, "registered": True, "rotation_error_deg": rot, "displacement_error_mm": disp})
    good = [r for r in rows if r["registered"]]
    return {"pose_rows": rows,
            "rotation_error_deg": _stats([r["rotation_error_deg"] for r in good]),
            "displacement_error_mm": _stats([r["displacement_error_mm"] for r in good])}


def process_trial(session_dir: Path, calibration: str, clouds: list[dict[str, Any]],
                  truth: dict[int, NDArray[np.float64]], world: Any, preset: str, samples: int,
                  repeats: int = 1) -> dict[str, Any]:
    """``kogei process`` at ``preset`` (``repeats`` times, the median time kept): time, report, pose errors.

    ``clouds`` (:func:`session_clouds` of the same session) give the registered measured points;
    ``"_scene"`` holds what :func:`score_mesh` needs (:func:`run_object` scores the meshes).
    """
    from app.workflows.process_session import process_session
    from render.meshio import load_mesh

    times, report = [], None
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        report = process_session(session_dir, preset=preset, calibration=calibration)
        times.append(time.perf_counter() - t0)
    assert report is not None
    passes = report["passes"]
    registered = [e for e in passes if e.get("registered")]
    errors = _pose_errors([e["pass"] for e in registered], [e["pose"] for e in registered], truth, world)
    mesh = load_mesh(Path(session_dir) / report["mesh"]["file"])
    pose = {e["pass"]: np.asarray(e["pose"]) for e in registered}
    merged = np.concatenate([_transformed(pose[e["pass"]], e["cloud"][0]) for e in clouds if e["pass"] in pose])
    first = registered[0]["pass"]
    diag = max(float(np.linalg.norm(np.ptp(e["cloud"][0], axis=0))) for e in clouds if "cloud" in e)
    return {
        "preset": preset,
        "seconds": statistics.median(times),
        "seconds_all": times,
        "timings_s": report["timings_s"],
        "points_per_pass": [e.get("points") for e in passes],
        "registered": len(registered),
        "passes": len(passes),
        "settings": {**_preset_settings(preset), "pair_size_mm": diag,
                     "poisson_cell_mm": report["surface"]["mesh"]["cell_mm"],
                     "hole_threshold_mm": report["surface"]["holes"]["threshold_mm"],
                     "point_spacing_mm": report["surface"]["points"]["spacing_mm"]},
        "consistency": report["registration"]["consistency"],
        "mesh": {**report["mesh"], "area_mm2": report["surface"]["mesh"]["area_mm2"],
                 "holes_reported": report["surface"]["holes"]["count"],
                 "hole_area_reported_mm2": report["surface"]["holes"]["total_area_mm2"],
                 "warnings": report["surface"]["warnings"]},
        "_scene": (mesh.vertices, mesh.triangles, merged, truth[first]),
        **errors,
    }


def score_mesh(vertices: NDArray[np.float64], triangles: NDArray[np.int64], merged: NDArray[np.float64],
               truth_pose: NDArray[np.float64], world: Any, samples: int, unseen_mm: float) -> dict[str, Any]:
    """Distances of a mesh (in the first pass's frame) to the world mesh moved by ``truth_pose``.

    Returns the mesh -> truth and truth -> mesh statistics (mm), the mesh's area (mm^2), and the
    truth -> mesh statistics split by what was measured: the *unseen* part of the object is its
    surface farther than ``unseen_mm`` from every registered measured point (``merged``): the part
    the mesh had to fill; the rest is the *seen* part.
    """
    from scipy.spatial import cKDTree

    from processing.geometry.mesh_support import triangle_areas
    from processing.geometry.surface_distance import DistanceStats, distance_to_mesh, sample_surface, surface_distance

    v, t = np.asarray(vertices, np.float64), np.asarray(triangles, np.int64)
    truth_v = _transformed(truth_pose, world.vertices)
    d = surface_distance(v, t, truth_v, world.triangles, n_samples=samples)
    on_truth = sample_surface(truth_v, world.triangles, samples, seed=5)
    to_mesh = distance_to_mesh(on_truth, v, t)
    to_data, _ = cKDTree(merged).query(on_truth, workers=-1)
    unseen = to_data > unseen_mm
    return {
        "to_truth_mm": asdict(d.to_truth),
        "from_truth_mm": asdict(d.from_truth),
        "seen_mm": asdict(DistanceStats.of(to_mesh[~unseen])),
        "unseen_mm": asdict(DistanceStats.of(to_mesh[unseen])),
        "unseen_share": float(unseen.mean()),
        "unseen_threshold_mm": float(unseen_mm),
        "area_mm2": float(triangle_areas(v, t).sum()),
    }


def _preset_settings(preset: str) -> dict[str, Any]:
    from processing.geometry.registration import PRESETS
    from processing.geometry.surface import SURFACE_PRESETS

    r, s = PRESETS[preset], SURFACE_PRESETS[preset]
    return {"rotation_samples": r.rotation_samples, "icp_voxels": list(r.icp_voxels),
            "icp_distance_voxels": r.icp_distance, "icp_iterations": r.icp_iterations,
            "max_rmse": r.max_rmse, "min_overlap": r.min_overlap, "min_margin": r.min_margin,
            "poisson_depth": s.depth, "fuse_voxel_factor": s.fuse_voxel_factor,
            "target_triangles": s.target_triangles}


def _same_profiles(a: Path, b: Path, passes: int) -> bool:
    """Whether two sessions hold bit-identical profiles and angles in their first ``passes`` passes."""
    from app.capture.runner import load_pass_profiles

    for p in range(1, passes + 1):
        pa, pb = load_pass_profiles(a, p), load_pass_profiles(b, p)
        if not all(np.array_equal(pa[k], pb[k], equal_nan=True) for k in ("angles_deg", "x_mm", "z_mm")):
            return False
    return True


def run_object(name: str, settings: BenchSettings, work: Path) -> dict[str, Any]:
    """Every measurement of one object (a JSON-ready dict; ``missing`` when its file is absent)."""
    t_all = time.perf_counter()
    work.mkdir(parents=True, exist_ok=True)
    loaded = load_object(name, work, settings)
    geometry = STATIONS[OBJECTS[name]["station"]]
    if loaded is None:
        return {"object": name, "missing": f"{MESH_DIR / OBJECTS[name]['file']} not found"}
    world, note = loaded
    extent = np.ptp(world.vertices, axis=0)
    out: dict[str, Any] = {"object": name, "source": note, "size_mm": extent.round(1).tolist(),
                           "station": geometry.describe()}
    cal = calibrate_station(geometry, work / "calibration")
    out["calibration"] = cal
    t0 = time.perf_counter()
    pair_truth = capture_session(world, geometry, work / "pairs", steps=settings.pair_steps,
                                 passes=settings.pairs + 1, seed=11)
    out["pair_capture_s"] = time.perf_counter() - t0
    out["pair_steps"] = settings.pair_steps
    out["pairs"] = pair_trials(session_clouds(work / "pairs" / "session", cal["session"]), pair_truth, world,
                               settings.pairs)
    steps = settings.steps[OBJECTS[name]["station"]]
    out["steps"] = steps
    # the same station seed: the pose-graph session's first three placements are the 3-pass session's
    graph_truth = capture_session(world, geometry, work / "graph", steps=steps, passes=settings.graph_passes,
                                  seed=23)
    out["pose_graph"] = pose_graph_trial(session_clouds(work / "graph" / "session", cal["session"]), graph_truth,
                                         world, settings.graph_passes, settings.samples)
    t0 = time.perf_counter()
    mesh_truth = capture_session(world, geometry, work / "mesh", steps=steps, passes=3, seed=23)
    out["mesh_capture_s"] = time.perf_counter() - t0
    out["mesh_matches_graph_session"] = _same_profiles(work / "mesh" / "session", work / "graph" / "session", 3)
    out["truth_poses"] = {"pairs": {p: t.tolist() for p, t in pair_truth.items()},
                          "graph": {p: t.tolist() for p, t in graph_truth.items()},
                          "mesh": {p: t.tolist() for p, t in mesh_truth.items()}}
    clouds = session_clouds(work / "mesh" / "session", cal["session"])
    out["presets"] = [process_trial(work / "mesh" / "session", cal["session"], clouds, mesh_truth, world, preset,
                                    settings.samples, settings.repeats if preset == "standard" else 1)
                      for preset in settings.presets]
    # The unseen part of the object: farther than the surface stage's own hole threshold (4 point
    # spacings) of the 3-pass `standard` mesh from every measured point; one threshold for every mesh
    # of the object, so the presets and the session of more placements are compared on one region rule.
    ref = next((r for r in out["presets"] if r["preset"] == "standard"), out["presets"][0])
    unseen_mm = ref["settings"]["hole_threshold_mm"]
    out["unseen_threshold_mm"] = unseen_mm
    for r in [*out["presets"], out["pose_graph"]["mesh"]]:
        r.update(score_mesh(*r.pop("_scene"), world, settings.samples, unseen_mm))
    out["seconds"] = time.perf_counter() - t_all
    out["peak_rss_mb"] = peak_rss_mb()
    return out


def main(argv: list[str] | None = None) -> None:
    """Run the benchmark and print its JSON (one object per run; ``--case all`` nests them)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", default="all", choices=[*OBJECTS, "all"])
    ap.add_argument("--quick", action="store_true", help="a few pairs, short scans, the hawk only (a smoke run)")
    ap.add_argument("--keep", default=None, metavar="DIR", help="keep the sessions in DIR (default: a temporary "
                                                                 "folder removed at the end)")
    args = ap.parse_args(argv)
    settings = QUICK if args.quick else FULL
    names = list(settings.objects) if args.case == "all" else [args.case]
    base = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="kogei-geobench-"))
    try:
        results = {n: run_object(n, settings, base / n) for n in names}
    finally:
        if not args.keep:
            shutil.rmtree(base, ignore_errors=True)
    payload: dict[str, Any] = {"machine": machine_description(), "quick": bool(args.quick),
                               "settings": {k: v for k, v in asdict(settings).items()}}
    payload.update(results[names[0]] if args.case != "all" else {"objects": results})
    print(json.dumps(payload, default=_json_default, allow_nan=True))


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"{type(value).__name__} is not JSON data")


if __name__ == "__main__":
    main(sys.argv[1:])
