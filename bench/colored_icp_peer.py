"""Open3D's coloured ICP beside kogei's colour step on the plain bowl's turn.

The plain bowl's shape fits any turn about its axis; only its painted motif
tells the turns apart.  Open3D's answer to such a pair is coloured ICP
(Park, Zhou & Koltun 2017, doi:10.1109/ICCV.2017.25;
:func:`open3d.pipelines.registration.registration_colored_icp`): a local
fit of geometry plus colour, started from a pose the caller gives.  This
bench colours each pass from its posed frames exactly as kogei colours a
session (:func:`bench.symmetric_bench._posed_colours`), starts coloured ICP
from the true pose turned by ``delta`` about the bowl's axis, and reports
where it ends: the true error of its turn (deg), against the 0.5 deg the
registration benchmark accepts.  Two ways of running it are measured: the
Open3D tutorial's coarse-to-fine schedule (voxels of 2, 1 and 0.5 mm, the
tutorial's 4, 2, 1 cm scaled to a bowl, 50 / 30 / 14 iterations) and the
finest voxel alone (0.5 mm, 50 iterations).  The colours are given as the
photos show them (linear RGB over its 99th percentile) and, since coloured
ICP assumes that a point is equally bright in both passes while the lamp
shades the two placements differently, as chromaticity (each colour over
its sum) too.

Examples
--------
>>> import numpy as np
>>> rgb = np.array([[0.2, 0.1, 0.1], [np.nan, np.nan, np.nan], [0.4, 0.2, 0.2]])
>>> keep, shown = peer_colours(rgb, "chromaticity")
>>> keep.tolist(), np.round(shown, 3).tolist()
([True, False, True], [[1.0, 0.5, 0.5], [1.0, 0.5, 0.5]])
"""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["DELTAS_DEG", "SCHEDULES", "peer_colours", "peer_rows", "main"]

#: Turns (deg) about the bowl's axis by which the start differs from the true pose.
DELTAS_DEG = (0.0, 1.0, -1.0, 3.0, 10.0, 100.0)

#: Voxel sizes (mm; also the correspondence distance) and iterations of each way of running coloured ICP.
SCHEDULES: dict[str, tuple[tuple[float, ...], tuple[int, ...]]] = {
    "coarse-to-fine": ((2.0, 1.0, 0.5), (50, 30, 14)),
    "finest": ((0.5,), (50,)),
}


def peer_colours(rgb: NDArray[np.float64], mode: str) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
    """The points a photo coloured and their colours in [0, 1] for coloured ICP (``mode``: "rgb" or "chromaticity")."""
    keep = np.isfinite(rgb).all(axis=1)
    c = np.asarray(rgb, float)[keep]
    if mode == "chromaticity":
        c = c / np.maximum(c.sum(axis=1, keepdims=True), 1e-12)
        return keep, np.clip(c / max(float(c.max()), 1e-12), 0.0, 1.0)
    if mode != "rgb":
        raise ValueError(f"colour mode must be 'rgb' or 'chromaticity', got {mode!r}")
    return keep, np.clip(c / max(float(np.percentile(c, 99)), 1e-12), 0.0, 1.0)


def _cloud(p: Any, rgb: NDArray[np.float64], mode: str) -> Any:
    import open3d as o3d

    keep, shown = peer_colours(rgb, mode)
    c = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p.points[keep]))
    c.normals = o3d.utility.Vector3dVector(p.normals[keep])
    c.colors = o3d.utility.Vector3dVector(shown)
    return c


def _coloured_icp(source: Any, target: Any, start: NDArray[np.float64], schedule: str) -> NDArray[np.float64]:
    import open3d as o3d

    reg = o3d.pipelines.registration
    transform = start
    for voxel_mm, iterations in zip(*SCHEDULES[schedule]):
        res = reg.registration_colored_icp(
            source.voxel_down_sample(voxel_mm), target.voxel_down_sample(voxel_mm), voxel_mm, transform,
            reg.TransformationEstimationForColoredICP(),
            reg.ICPConvergenceCriteria(relative_fitness=1e-6, relative_rmse=1e-6, max_iteration=iterations))
        transform = res.transformation
    return np.asarray(transform)


def peer_rows(seed: int, frame_size: tuple[int, int] | None = None) -> list[dict[str, Any]]:
    """Coloured ICP on the plain bowl's pair (placements 2 and 3) at station ``seed``: one row per colour mode and
    schedule, the true turn error (deg) reached from each start in :data:`DELTAS_DEG`, and the CPU it took."""
    from bench.symmetric_bench import STEPS, _posed_colours, _turn_error_deg
    from mocks.pass_cloud import simulated_pass
    from mocks.world import World
    from processing.geometry.registration.photo_consistency import _turned

    world = World.turned("plain-bowl")
    a, b = simulated_pass(world, seed, 2, steps=STEPS), simulated_pass(world, seed, 3, steps=STEPS)
    rgb_a, rgb_b = _posed_colours(world, a, frame_size).colours, _posed_colours(world, b, frame_size).colours
    truth = a.pose @ np.linalg.inv(b.pose)
    axis, point = a.pose[:3, 2], a.pose[:3, 3]
    starts = _turned(truth, axis, point, np.radians(DELTAS_DEG))
    rows = []
    for mode in ("rgb", "chromaticity"):
        source, target = _cloud(b, rgb_b, mode), _cloud(a, rgb_a, mode)
        for schedule in SCHEDULES:
            c0 = time.process_time()
            ends = [_coloured_icp(source, target, start, schedule) for start in starts]
            errors = {f"{d:+g}": round(_turn_error_deg(end, truth, axis), 3) for d, end in zip(DELTAS_DEG, ends)}
            rows.append({"seed": seed, "colours": mode, "schedule": schedule, "turn_error_deg": errors,
                         "cpu_s_per_start": round((time.process_time() - c0) / len(DELTAS_DEG), 2)})
    return rows


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=lambda v: [int(x) for x in v.split(",")], default=[0, 1, 2, 3, 4, 5],
                    help="station seeds of the plain bowl (comma-separated; default 0-5, the end-to-end rows')")
    ap.add_argument("--frame-size", type=lambda v: tuple(int(x) for x in v.lower().split("x")), default=None,
                    metavar="WxH", help="the station camera sampled at W x H pixels (default its 240 x 160)")
    args = ap.parse_args(argv)
    for seed in args.seeds:
        for row in peer_rows(seed, args.frame_size):
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
