"""Where the 3-placement hawk mesh had to guess: docs/images/hawk-unseen.png.

Scans the procedural hawk in the 3 placements of ``bench.geometry_bench`` (same station, seed
and profiles per pass), runs ``kogei process --preset standard`` and plots the measured points
and the *unseen* part of the true surface (farther than the surface stage's hole threshold from
every registered point), coloured by its truth -> mesh distance.  Run
``python -m bench.unseen_figure [--out PNG]`` (about a minute).
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np

from bench.common import ROOT

__all__ = ["main"]


def main(argv: list[str] | None = None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy.spatial import cKDTree

    from bench.geometry_bench import (
        FULL,
        STATIONS,
        _transformed,
        calibrate_station,
        capture_session,
        load_object,
        process_trial,
        session_clouds,
    )
    from processing.geometry.surface_distance import distance_to_mesh, sample_surface

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "docs" / "images" / "hawk-unseen.png"))
    args = ap.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix="kogei-unseen-"))
    try:
        world, _ = load_object("hawk", work, FULL)
        geometry = STATIONS["small"]
        cal = calibrate_station(geometry, work / "calibration")
        truth = capture_session(world, geometry, work / "mesh", steps=FULL.steps["small"], passes=3, seed=23)
        clouds = session_clouds(work / "mesh" / "session", cal["session"])
        r = process_trial(work / "mesh" / "session", cal["session"], clouds, truth, world, "standard", 1, 1)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    v, t, merged, pose = r["_scene"]
    on_truth = sample_surface(_transformed(pose, world.vertices), world.triangles, 200_000, seed=5)
    err = distance_to_mesh(on_truth, v, t)
    unseen = cKDTree(merged).query(on_truth)[0] > r["settings"]["hole_threshold_mm"]
    shown = merged[:: max(1, len(merged) // 20_000)]
    fig, axes = plt.subplots(1, 2, figsize=(10, 5.2))
    for ax, (i, j), title in zip(axes, [(0, 2), (1, 2)], ["side (x, z)", "front (y, z)"]):
        ax.scatter(shown[:, i], shown[:, j], s=0.15, c="0.75", rasterized=True)
        sc = ax.scatter(on_truth[unseen, i], on_truth[unseen, j], s=1.5, c=err[unseen], cmap="inferno_r",
                        vmin=0, vmax=2, rasterized=True)
        ax.set_aspect("equal")
        ax.set_title(title)
        ax.set_xlabel("mm")
        ax.set_ylabel("mm")
    bar = fig.colorbar(sc, ax=axes, shrink=0.8)
    bar.set_label("filled surface: distance truth -> mesh (mm)")
    fig.suptitle("Hawk, 3 placements, standard: measured points (grey) and the unseen part (coloured)")
    fig.savefig(args.out, dpi=80)
    print(json.dumps({"out": args.out, "unseen_share": float(unseen.mean()),
                      "unseen_median_mm": float(np.median(err[unseen]))}))


if __name__ == "__main__":
    main()
