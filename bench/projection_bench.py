"""Speed and memory of posing frames on a large mesh: visibility of every vertex in 24 frames.

A sphere of ~1M triangles (Open3D, radius 100 mm, vertices jittered by
0.2 mm so the ray caster meets a rough surface) seen by 24 frames of
3000 x 2000 pixels (a 24 MP sensor binned 2 x 2) around the table, each with
the full :func:`processing.appearance.visibility.visible_vertices` test:
projection with distortion, facing, occlusion by ray casting (one ray per
candidate vertex) and the edge margin from a depth map cast at the frame's
resolution divided by ``depth_binning``.

Run ``python -m bench.projection_bench [--depth-binning 2] [--frames 24]``;
prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import time

import numpy as np
import open3d as o3d

from processing.appearance.frame_poses import FramePose
from processing.appearance.projection import mesh_arrays, raycasting_scene
from processing.appearance.visibility import visible_vertices

__all__ = ["projection_figures", "observe_figures", "main"]


def _look_at(eye, target) -> np.ndarray:
    z = np.asarray(target, float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    out = np.eye(4)
    out[:3, :3] = np.stack([x, np.cross(z, x), z])
    out[:3, 3] = -out[:3, :3] @ eye
    return out


def projection_figures(n_frames: int = 24, width: int = 3000, height: int = 2000, resolution: int = 500,
                       depth_binning: int = 2, edge_margin_px: float = 2.0, jitter_mm: float = 0.2) -> dict:
    """Time, ray throughput and peak memory of ``visible_vertices`` over ``n_frames`` frames.

    Returns a dict: triangles, vertices, seconds for the scene build and per frame, rays cast
    (vertex rays + depth-map rays), rays/s, visible vertices per frame and peak RSS (MB, ``getrusage``).
    """
    sphere = o3d.geometry.TriangleMesh.create_sphere(100.0, resolution=resolution).translate([0, 0, 110.0])
    v = np.asarray(sphere.vertices)
    v += np.random.default_rng(0).normal(0, jitter_mm, v.shape)
    sphere.vertices = o3d.utility.Vector3dVector(v)
    sphere.compute_vertex_normals()
    t0 = time.perf_counter()
    v, f, n = mesh_arrays(sphere)
    scene = raycasting_scene(v, f)
    build_s = time.perf_counter() - t0
    fx = (width / 2) / math.tan(math.radians(25.0) / 2)
    k = np.array([[fx, 0, width / 2 - 0.5], [0, fx, height / 2 - 0.5], [0, 0, 1.0]])
    dist = np.array([-0.05, 0.01, 0.0, 0.0, 0.0])
    room_to_camera = _look_at(np.array([600.0, 0.0, 300.0]), [0.0, 0.0, 110.0])
    seen, times = [], []
    t_all = time.perf_counter()
    for i in range(n_frames):
        frame = FramePose.from_chain(f"f{i}", 1, room_to_camera, 360.0 * i / n_frames, np.eye(4), k, dist,
                                     (width, height))
        t = time.perf_counter()
        vis = visible_vertices(v, f, n, frame, edge_margin_px=edge_margin_px, depth_binning=depth_binning,
                               scene=scene)
        times.append(time.perf_counter() - t)
        seen.append(int(vis.sum()))
    total_s = time.perf_counter() - t_all
    depth_rays = -(-width // depth_binning) * -(-height // depth_binning)
    rays = n_frames * depth_rays + sum(seen)  # lower bound: candidate vertex rays >= visible vertices
    return {"triangles": len(f), "vertices": len(v), "frames": n_frames, "image": [width, height],
            "depth_binning": depth_binning, "scene_build_s": round(build_s, 2), "total_s": round(total_s, 2),
            "per_frame_s": round(total_s / n_frames, 3), "slowest_frame_s": round(max(times), 3),
            "rays": rays, "rays_per_s": round(rays / total_s), "visible_per_frame": int(np.median(seen)),
            "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1)}


class _LazyImages:
    """``images[k]``: a 3-channel float32 image made on demand (a smooth gradient), one at a time."""

    def __init__(self, n: int, width: int, height: int) -> None:
        self.n, self.width, self.height = n, width, height

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, k: int) -> np.ndarray:
        u = np.linspace(0.1, 0.9, self.width, dtype=np.float32)
        v = np.linspace(0.2, 0.6, self.height, dtype=np.float32)[:, None]
        return np.stack(np.broadcast_arrays(u + 0 * v, v + 0 * u, (u * v + 0.01 * k).astype(np.float32)), -1)


def observe_figures(n_frames: int = 24, width: int = 3000, height: int = 2000, resolution: int = 500) -> dict:
    """Time and peak memory of :func:`~processing.appearance.observations.observe` with lazily made images."""
    from processing.appearance.observations import observe

    sphere = o3d.geometry.TriangleMesh.create_sphere(100.0, resolution=resolution).translate([0, 0, 110.0])
    sphere.compute_vertex_normals()
    fx = (width / 2) / math.tan(math.radians(25.0) / 2)
    k = np.array([[fx, 0, width / 2 - 0.5], [0, fx, height / 2 - 0.5], [0, 0, 1.0]])
    room_to_camera = _look_at(np.array([600.0, 0.0, 300.0]), [0.0, 0.0, 110.0])
    lamps = [{"name": "key", "position_mm": [300.0, 400.0, 600.0]}, {"name": "fill", "direction": [0.0, -0.6, 0.8]}]
    frames = [FramePose.from_chain(f"f{i}", 1, room_to_camera, 360.0 * i / n_frames, np.eye(4), k, np.zeros(5),
                                   (width, height), lamps) for i in range(n_frames)]
    t = time.perf_counter()
    obs = observe(frames, sphere, _LazyImages(n_frames, width, height), noise=[1e-5, 1e-3], clip_level=0.95)
    total = time.perf_counter() - t
    return {"frames": n_frames, "observations": len(obs), "total_s": round(total, 2),
            "per_frame_s": round(total / n_frames, 3),
            "observation_mb": round(sum(getattr(obs, a).nbytes for a in ("offsets", "vertex", "frame", "uv_px",
                                    "signal", "sigma", "clipped", "normal", "view_dir", "light_dir",
                                    "half_angle_deg", "distance_mm")) / 2**20, 1),
            "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1)}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--depth-binning", type=int, default=2)
    ap.add_argument("--observe", action="store_true", help="measure observe() instead of visibility alone")
    ap.add_argument("--jitter-mm", type=float, default=0.2)
    ap.add_argument("--resolution", type=int, default=500, help="Open3D sphere resolution (500: ~1M triangles)")
    args = ap.parse_args(argv)
    if args.observe:
        print(json.dumps(observe_figures(args.frames, resolution=args.resolution)))
        return
    print(json.dumps(projection_figures(args.frames, resolution=args.resolution, depth_binning=args.depth_binning,
                                          jitter_mm=args.jitter_mm)))


if __name__ == "__main__":
    main()
