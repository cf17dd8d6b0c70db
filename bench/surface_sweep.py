"""Poisson depth sweep of the surface stage on the procedural hawk.

Samples the hawk (``hawk_head(250_000)``, about 67 x 40 x 74 mm) uniformly by
area with 0.05 mm Gaussian noise along the normal, cuts two patches out of
the cloud (8 mm around the top of the crown, 5 mm around the widest point of
the cheek), reconstructs it with the ``standard`` preset at each Poisson
depth and prints, per depth: time, triangles, the two-sided mean distance to
the hawk's mesh, the median / 95th percentile distance of the filled
patches, and whether the mesh is watertight.

Run: ``python -m bench.surface_sweep [--points 200000] [--depths 8 9 10 11]
[--decimate]``.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

__all__ = ["sweep", "main"]


def _sample(v: np.ndarray, t: np.ndarray, n: int, rng: np.random.Generator, noise: float):
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    cross = np.cross(b - a, c - a)
    area = np.linalg.norm(cross, axis=1)
    idx = rng.choice(t.shape[0], n, p=area / area.sum())
    r1, r2 = np.sqrt(rng.random(n)), rng.random(n)
    p = (1 - r1)[:, None] * a[idx] + (r1 * (1 - r2))[:, None] * b[idx] + (r1 * r2)[:, None] * c[idx]
    normal = cross[idx] / area[idx, None]
    return p + noise * rng.standard_normal(n)[:, None] * normal, normal


def sweep(points: int = 200_000, depths: tuple[int, ...] = (8, 9, 10, 11), *, decimate: bool = False,
          noise: float = 0.05, seed: int = 0) -> list[dict[str, float]]:
    """One row per depth (see the module docstring)."""
    from mocks.procedural_hawk import hawk_head
    from processing.geometry.surface import SURFACE_PRESETS, reconstruct_surface
    from processing.geometry.surface_distance import surface_distance

    hawk = hawk_head(250_000)
    v, t = hawk.vertices, hawk.triangles.astype(np.int64)
    p, n = _sample(v, t, points, np.random.default_rng(seed), noise)
    crown = v[np.argmax(v[:, 2])]
    cheek = v[np.argmax(v[:, 1])]
    cut = (np.linalg.norm(p - crown, axis=1) < 8.0) | (np.linalg.norm(p - cheek, axis=1) < 5.0)
    rows = []
    for depth in depths:
        preset = replace(SURFACE_PRESETS["standard"], depth=depth,
                         target_triangles=SURFACE_PRESETS["standard"].target_triangles if decimate else None)
        t0 = time.perf_counter()
        res = reconstruct_surface(p[~cut], n[~cut], preset=preset)
        seconds = time.perf_counter() - t0
        region = np.concatenate([h.triangles for h in res.support.holes]) if res.support.holes else None
        d = surface_distance(res.vertices, res.triangles, v, t, n_samples=200_000, region_triangles=region)
        rows.append({
            "depth": depth,
            "seconds": seconds,
            "poisson_s": res.timings.poisson_s,
            "triangles": res.n_triangles,
            "to_truth_mean": d.to_truth.mean,
            "from_truth_mean": d.from_truth.mean,
            "p95": max(d.to_truth.p95, d.from_truth.p95),
            "holes": res.n_holes,
            "hole_median": d.region.median if d.region else float("nan"),
            "hole_p95": d.region.p95 if d.region else float("nan"),
            "watertight": res.watertight,
        })
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=200_000)
    parser.add_argument("--depths", type=int, nargs="+", default=[8, 9, 10, 11])
    parser.add_argument("--decimate", action="store_true", help="decimate to the standard preset's target")
    args = parser.parse_args(argv)
    rows = sweep(args.points, tuple(args.depths), decimate=args.decimate)
    print(f"hawk, {args.points} points, 0.05 mm noise, two cut patches; standard preset"
          + (" with decimation" if args.decimate else ", no decimation"))
    print("| depth | time s | Poisson s | triangles | mean to truth mm | mean from truth mm | p95 mm "
          "| holes | filled median mm | filled p95 mm | watertight |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['depth']} | {r['seconds']:.1f} | {r['poisson_s']:.1f} | {r['triangles']} | "
              f"{r['to_truth_mean']:.4f} | {r['from_truth_mean']:.4f} | {r['p95']:.3f} | {r['holes']} | "
              f"{r['hole_median']:.3f} | {r['hole_p95']:.3f} | {r['watertight']} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
