"""A scan session of a simulated object with several materials, posed with the station's *true* camera and lamp.

The session holds the object's own mesh as ``products/mesh.ply`` (so the truth per face is exact),
a process report with one registered pass (identity pose), a camera calibration and a lamp
calibration that are the simulated station's truth, a colour-chart frame (the classic 24-patch
chart laid out on the backdrop) and RAW frames of the object at many table angles, rendered by the
simulated camera.  :func:`app.workflows.posed_frames.project_session` has not run yet.  What the
materials-on-the-mesh chain measures on it is the segmentation, the fit and the validation, not the
calibration or the registration.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from tests._shared_build import built_once, copy_tree
from tests.integration.posed_session import _camera_json

__all__ = ["build_object_session", "projected_hawk_session", "measured_hawk_session",
           "projected_hawk_two_placements", "tilted_pose", "SIZE"]

SIZE = (480, 320)


def _lamp_json(world) -> dict:
    truth = world.lamp_truth()
    lamp = {"name": "lamp1", "kind": truth["kind"], "position_mm": truth.get("position_mm"),
            "direction": truth.get("direction"), "covariance": np.zeros((3, 3)).tolist(), "spectrum": world.light,
            "n_observations": 12, "rms_deg": 0.05}
    return {"schema": "kogei.lamp_calibration", "version": 1, "sphere_radius_mm": 20.0, "lamps": [lamp],
            "frames": {"names": [], "sphere_rms_px": [], "ray_miss_deg": [], "circle_miss_mm": []}}


def tilted_pose(tilt_deg: float, about_mm=(0.0, 0.0, 37.0), azimuth_deg: float = 0.0) -> np.ndarray:
    """An object -> table pose tilted by ``tilt_deg`` about a horizontal axis through ``about_mm`` (a re-placement)."""
    from processing.common.rotation import rotation_z_deg

    a = np.radians(tilt_deg)
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    r = rotation_z_deg(azimuth_deg)[:3, :3] @ rx
    c = np.asarray(about_mm, dtype=np.float64)
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = r, c - r @ c
    return m


def build_object_session(root: Path, world, angles_deg, *, exposure_s: float = 0.0025,
                         placements: tuple = (None,), holdout_burst: int = 1) -> dict:
    """Write the session (not yet projected) under ``root``; returns the world and the mesh for checks.

    ``placements`` are the object -> table poses of the passes (None: the world's own pose); pass 1's
    table frame is the mesh frame M, and pass p's registered pose is ``pose_1 @ inv(pose_p)``.

    ``world`` is a :class:`mocks.world.World` (its size is the frames' size; its chart layout must be
    one ``kogei`` detects, e.g. ``"classic24"``); the mesh is the world's mesh in its table pose.
    ``exposure_s`` is short enough that metal highlights stay below the white level, as a
    photographer exposes for them (the chart frame takes the same exposure).
    ``holdout_burst`` > 1 shoots that many frames at each held-out angle (every 4th), recorded as a
    capture plan with ``holdout_burst`` records them: ``pNN/frame/KK/burst/JJ`` of kind ``"burst"``, each
    with its own noise; the first frame is the one a session without a burst has.
    """
    import dataclasses

    import open3d as o3d

    from app.session import Session
    from app.workflows.station_calibration import install_station_calibration
    from mocks.camera_sim import simulate_raw, write_raw
    from processing.geometry.mesh_ply import write_mesh_ply

    poses = [np.asarray(world.pose if p is None else p, dtype=np.float64) for p in placements]
    m = poses[0]
    v = world.vertices @ m[:3, :3].T + m[:3, 3]
    t = world.triangles
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(t.astype(np.int32)))
    mesh.compute_vertex_normals()
    plan = {"kind": "scan", "steps": 4, "passes": len(poses), "camera_angles_deg": [float(a) for a in angles_deg],
            "chart": True, "lasers": [1], "camera": True, "chart_frames": 1}
    held: set = set()
    if holdout_burst > 1:
        from app.workflows.holdout_validation import holdout_frames

        plan.update(holdout_burst=holdout_burst, holdout_every=4)
        held = holdout_frames([str(i) for i in range(len(angles_deg))], [float(a) for a in angles_deg], every=4)
    s = Session.create(root, plan=plan)
    try:
        stage = root / ".incoming"
        stage.mkdir(exist_ok=True)
        write_mesh_ply(stage / "mesh.ply", v, t, np.asarray(mesh.vertex_normals))
        info = s.adopt_file(stage / "mesh.ply", "products/mesh.ply")
        report = {"passes": [{"pass": k + 1, "registered": True, "pose": (m @ np.linalg.inv(p)).tolist()}
                             for k, p in enumerate(poses)]}
        rep = s.write_file("products/process-report.json", json.dumps(report).encode())
        s.update("products", {"mesh": {"file": "products/mesh.ply", "sha256": info.sha256},
                              "process_report": {"file": "products/process-report.json", "sha256": rep.sha256}})
        install_station_calibration(s, "camera_calibration", _camera_json(world, (2 * world.width, 2 * world.height)))
        install_station_calibration(s, "lamp_calibration", _lamp_json(world))
        for k, pose in enumerate(poses, start=1):
            placed = dataclasses.replace(world, pose=pose)
            chart = placed.frame("chart")
            raw = simulate_raw(chart.radiance, chart.grid, chart.light, exposure_s=exposure_s, seed=100 + k)
            fi = s.adopt_file(write_raw(stage / "chart.dng", raw), f"passes/p{k:02d}/raw/chart.dng")
            s.add_capture(f"p{k:02d}/chart", kind="chart", status="done", index=0, file=fi.path, sha256=fi.sha256,
                          bytes=fi.bytes, **{"pass": k})
            for i, angle in enumerate(angles_deg, start=1):
                frame = placed.frame("object", float(angle))
                raw = simulate_raw(frame.radiance, frame.grid, frame.light, exposure_s=exposure_s, seed=1000 * k + i)
                fi = s.adopt_file(write_raw(stage / "frame.dng", raw), f"passes/p{k:02d}/raw/frame_{i:02d}.dng")
                s.add_capture(f"p{k:02d}/frame/{i:02d}", kind="frame", status="done", index=i,
                              angle_deg=float(angle), file=fi.path, sha256=fi.sha256, bytes=fi.bytes, **{"pass": k})
                for j in range(1, holdout_burst if str(i - 1) in held else 1):
                    raw = simulate_raw(frame.radiance, frame.grid, frame.light, exposure_s=exposure_s,
                                       seed=100_000 * j + 1000 * k + i)
                    fi = s.adopt_file(write_raw(stage / "frame.dng", raw),
                                      f"passes/p{k:02d}/raw/frame_{i:02d}_burst_{j:02d}.dng")
                    s.add_capture(f"p{k:02d}/frame/{i:02d}/burst/{j:02d}", kind="burst", status="done", index=i,
                                  angle_deg=float(angle), burst_of=f"p{k:02d}/frame/{i:02d}", shot=j,
                                  file=fi.path, sha256=fi.sha256, bytes=fi.bytes, **{"pass": k})
    finally:
        s.close()
    return {"world": world, "vertices": v, "triangles": t}


def _shared_projected(tmp_path_factory, dst: Path, name: str, angles_deg, placements: tuple) -> Path:
    """A copy at ``dst`` of the projected hawk session of ``angles_deg`` x ``placements``, built once per run
    (:func:`tests._shared_build.built_once`)."""

    def build(folder: Path) -> None:
        from app.workflows.posed_frames import project_session
        from mocks.world import World

        world = World.hawk(4000, width=240, height=160, chart_layout="classic24")
        build_object_session(folder / "session", world, angles_deg, placements=placements)
        project_session(folder / "session")

    return copy_tree(built_once(tmp_path_factory, name, build) / "session", dst)


def projected_hawk_session(tmp_path_factory, dst: Path) -> Path:
    """A copy at ``dst`` of the hawk's object session, projected: the world ``World.hawk(4000, width=240,
    height=160, chart_layout="classic24")`` in three placements (upright, tilted +35 deg, tilted -35 deg about
    azimuth 90 deg) x 12 table angles (0 to 330 deg), then :func:`app.workflows.posed_frames.project_session`.

    Several test modules start from this session; it is built once per test run on disk and shared by the
    xdist workers (a file lock lets one build it while the others wait), and each caller gets its own copy.
    """
    return _shared_projected(tmp_path_factory, dst, "shared-projected-hawk", np.arange(0.0, 360.0, 30.0),
                             (None, tilted_pose(35.0), tilted_pose(-35.0, azimuth_deg=90)))


def projected_hawk_two_placements(tmp_path_factory, dst: Path) -> Path:
    """As :func:`projected_hawk_session`, smaller: two placements (upright, tilted +35 deg) x 8 table angles
    (0 to 315 deg).  The GUI's materials tests start from it; built once per run, shared likewise."""
    return _shared_projected(tmp_path_factory, dst, "shared-projected-hawk-2x8", np.arange(0.0, 360.0, 45.0),
                             (None, tilted_pose(35.0)))


def measured_hawk_session(tmp_path_factory, dst: Path) -> tuple[Path, dict]:
    """A copy at ``dst`` of :func:`projected_hawk_session` with its materials measured on the mesh
    (:func:`app.workflows.object_materials.measure_object` with its defaults, held-out validation included),
    and the document that call returned.

    Built once per test run and shared by the xdist workers like the projected session (the report's
    and the materials' tests both start from it); each caller gets its own copy.
    """
    import pickle

    def build(folder: Path) -> None:
        from app.workflows.object_materials import measure_object

        projected_hawk_session(tmp_path_factory, folder / "session")
        doc = measure_object(folder / "session")
        (folder / "measure_object.pickle").write_bytes(pickle.dumps(doc))

    built = built_once(tmp_path_factory, "shared-measured-hawk", build)
    copy_tree(built / "session", dst)
    return dst, pickle.loads((built / "measure_object.pickle").read_bytes())
