"""A small scan session posed with the simulated station's *true* camera and lamp, for projection tests.

The session holds: an icosphere mesh as ``products/mesh.ply`` (the object itself: radius 22 mm,
standing on the table), a process report with one registered pass (identity pose), a camera
calibration whose ``room_to_camera`` and ``K`` are the simulated camera's truth, a distant lamp that
is the world's light, and RAW frames of the sphere rendered by the simulated camera at several table
angles (matte red lacquer, so the whole outline differs from the backdrop).  With the geometry exact,
what :func:`app.workflows.posed_frames.project_session` measures is the projection itself.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

__all__ = ["build_posed_session", "RADIUS_MM", "ANGLES_DEG", "SIZE"]

RADIUS_MM = 22.0
ANGLES_DEG = (0.0, 90.0, 200.0)
SIZE = (480, 320)


def _camera_json(world, calibrated_size: tuple[int, int]) -> dict:
    """A camera calibration JSON holding the simulated camera's truth at ``calibrated_size``."""
    from mocks.world import World

    full = World(world.vertices, world.triangles, world.region, world.region_names, world.materials,
                 width=calibrated_size[0], height=calibrated_size[1], mesh_source=world.mesh_source)
    r2c = full.room_to_camera()
    return {"schema": "kogei.camera_calibration", "version": 1, "image_size": list(calibrated_size),
            "K": full.camera_intrinsics().tolist(), "dist": [0.0] * 5, "gauge_to_camera": r2c.tolist(),
            "room_to_camera": r2c.tolist(), "view_rms_px": {}, "rms_px": 0.05, "stds": {}, "board": {},
            "dropped_views": [], "gauge_cov": None, "held": []}


def build_posed_session(root: Path) -> dict:
    """Write the session (not yet projected) under ``root``; returns the world and the mesh for checks."""
    import open3d as o3d

    from app.session import Session
    from app.workflows.station_calibration import install_station_calibration
    from mocks.camera_sim import simulate_raw, write_raw
    from mocks.world import World
    from processing.geometry.mesh_ply import write_mesh_ply

    sphere = o3d.geometry.TriangleMesh.create_sphere(RADIUS_MM, resolution=40)
    sphere.translate((8.0, 5.0, RADIUS_MM))          # off the axis, resting on the table
    sphere.compute_vertex_normals()
    v, t = np.asarray(sphere.vertices), np.asarray(sphere.triangles)
    world = World(v, t, np.zeros(len(t), np.int64), ("object",), {"object": "urushi-red"},
                  width=SIZE[0], height=SIZE[1], mesh_source="test-sphere")
    plan = {"kind": "scan", "steps": 4, "passes": 1, "camera_angles_deg": list(ANGLES_DEG), "chart": False,
            "lasers": [1], "camera": True, "chart_frames": 1}
    s = Session.create(root, plan=plan)
    try:
        stage = root / ".incoming"
        stage.mkdir(exist_ok=True)
        write_mesh_ply(stage / "mesh.ply", v, t, np.asarray(sphere.vertex_normals))
        info = s.adopt_file(stage / "mesh.ply", "products/mesh.ply")
        report = {"passes": [{"pass": 1, "registered": True, "pose": np.eye(4).tolist()}]}
        rep = s.write_file("products/process-report.json", json.dumps(report).encode())
        s.update("products", {"mesh": {"file": "products/mesh.ply", "sha256": info.sha256},
                              "process_report": {"file": "products/process-report.json", "sha256": rep.sha256}})
        install_station_calibration(s, "camera_calibration", _camera_json(world, (2 * SIZE[0], 2 * SIZE[1])))
        lamp = np.asarray(world.light_direction, float)
        install_station_calibration(s, "lamp_calibration", {
            "schema": "kogei.lamp_calibration", "version": 1, "sphere_radius_mm": 20.0,
            "lamps": [{"name": "lamp1", "kind": "distant", "position_mm": None,
                       "direction": (lamp / np.linalg.norm(lamp)).tolist(), "covariance": np.zeros((3, 3)).tolist(),
                       "spectrum": "D65", "n_observations": 12, "rms_deg": 0.05}],
            "frames": {"names": [], "sphere_rms_px": [], "ray_miss_deg": [], "circle_miss_mm": []}})
        for k, angle in enumerate(ANGLES_DEG):
            frame = world.frame("object", angle)
            raw = simulate_raw(frame.radiance, frame.grid, frame.light, seed=k)
            path = write_raw(stage / f"frame_{k:02d}.dng", raw)
            fi = s.adopt_file(path, f"passes/p01/raw/frame_{k:02d}.dng")
            s.add_capture(f"p01/frame/{k:02d}", kind="frame", status="done", index=k, angle_deg=angle,
                          file=fi.path, sha256=fi.sha256, bytes=fi.bytes, **{"pass": 1})
    finally:
        s.close()
    return {"world": world, "vertices": v, "triangles": t}
