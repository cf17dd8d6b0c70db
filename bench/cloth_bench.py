"""Cloth benchmarks: render cost of cloth against metal at the same size, and the
speed/accuracy of the internal layer count K (1, 3, 10, 30) against K = 50.

``python -m bench.cloth_bench`` runs both cases and prints one JSON line;
``--case cost`` or ``--case layers`` runs one.  :func:`section` turns the
results into the Markdown of docs/BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time

import numpy as np

from bench.common import machine_description, peak_rss_mb

COST_SIZE = (320, 240)
LAYER_SIZE = (160, 120)
LAYERS = (1, 3, 10, 30)
REFERENCE_LAYERS = 50


def _render(material: str, size, preset: str):
    from app.workflows.cloth_scene import ACROSS_WARP, render_cloth

    t0 = time.perf_counter()
    result = render_cloth(material, size, preset, view=ACROSS_WARP)
    return time.perf_counter() - t0, result


def case_cost(repeats: int = 3) -> dict:
    """The draped sheet (about 21 000 triangles), sun + uniform sky, ``standard`` preset, silk vs gold."""
    from processing.materials.presets import get_material

    rows = []
    for material in ("gold", "gold:mirror=0", "silk", "tamamushi"):
        _render(material, COST_SIZE, "standard")                 # warm-up: imports, page cache
        times, setups, shading = [], [], []
        for _ in range(repeats):
            seconds, res = _render(material, COST_SIZE, "standard")
            times.append(seconds)
            setups.append(res.timings["setup"])
            shading.append(res.timings["shading"])
        rows.append({"material": material, "lobes": len(get_material(material).lobes),
                     "total_s": statistics.median(times), "times_s": times,
                     "setup_s": statistics.median(setups), "shading_s": statistics.median(shading)})
    mirror, gloss = rows[0]["total_s"], rows[1]["total_s"]
    for r in rows:
        r["ratio_to_metal"] = r["total_s"] / gloss
        r["ratio_to_mirror_metal"] = r["total_s"] / mirror
    return {"case": "cost", "size": list(COST_SIZE), "rows": rows, "peak_rss_mb": peak_rss_mb()}


def case_layers(repeats: int = 3) -> dict:
    """silk with K internal layers vs K = 50: time and CIEDE2000 per covered pixel."""
    from processing.spectral.display import delta_e00

    t_ref, ref = _render(f"silk:layers={REFERENCE_LAYERS}", LAYER_SIZE, "standard")
    on = ref.mask > 0.99
    rows = []
    for k in LAYERS + (REFERENCE_LAYERS,):
        times = []
        for _ in range(repeats):
            seconds, res = _render(f"silk:layers={k}", LAYER_SIZE, "standard")
            times.append(seconds)
        de = delta_e00(res.xyz[on], ref.xyz[on], ref.white)
        rows.append({"layers": k, "total_s": statistics.median(times), "times_s": times,
                     "setup_s": res.timings["setup"], "de_mean": float(np.mean(de)),
                     "de_p95": float(np.percentile(de, 95))})
    return {"case": "layers", "size": list(LAYER_SIZE), "rows": rows, "peak_rss_mb": peak_rss_mb()}


def run_all() -> dict:
    load0 = os.getloadavg()[0]
    out = {"cost": case_cost(), "layers": case_layers(), "machine": machine_description()}
    out["load_average"] = [load0, os.getloadavg()[0]]
    return out


def section(results: dict | None = None) -> list[str]:
    """The Markdown section of docs/BENCHMARKS.md (runs the benchmark when no results are given)."""
    r = results or run_all()
    c, k = r["cost"], r["layers"]
    lines = [
        "## Cloth",
        "",
        "`bench/cloth_bench.py`: the draped sheet of docs/cloth.md seen across the warp, one sun and a uniform",
        f"sky, `standard` preset (4 samples per pixel, angular XYZ tables), {c['size'][0]} x {c['size'][1]}.",
        "Medians of 3 runs after a warm-up; `setup` includes the tables and the sky-light albedo tables of every",
        "lobe (an anisotropic lobe's albedo is integrated over the view azimuth, `processing.cloth.anisotropic_albedo`).",
        "",
        f"Machine: {r['machine']}."
        + (f"  Load average (1 min) at the start and end of the run: {r['load_average'][0]:.1f}, "
           f"{r['load_average'][1]:.1f} -- other work shared the cores." if "load_average" in r else ""),
        "",
        "### Render cost of cloth vs metal",
        "",
        "`gold` has its mirror lobe, which traces a reflected ray per sample (one bounce at `standard`);",
        "`gold:mirror=0` has only the gloss lobe and casts the same rays as the cloth, so it is the like-for-like",
        "metal.  Cloth lobes: per yarn one specular, K = 4 internal and one diffuse lobe.",
        "",
        "| material | lobes | total (s) | runs (s) | setup (s) | shading (s) | ratio to gold:mirror=0 | "
        "ratio to gold |",
        "|---|---:|---:|---|---:|---:|---:|---:|",
    ]
    for row in c["rows"]:
        lines.append(f"| {row['material']} | {row['lobes']} | {row['total_s']:.2f} | "
                     f"{', '.join(f'{t:.2f}' for t in row['times_s'])} | {row['setup_s']:.2f} | "
                     f"{row['shading_s']:.2f} | **{row['ratio_to_metal']:.2f}** | "
                     f"{row.get('ratio_to_mirror_metal', float('nan')):.2f} |")
    lines += [
        "",
        f"### Internal layers K against K = {REFERENCE_LAYERS}",
        "",
        f"silk with `layers=K`, {k['size'][0]} x {k['size'][1]}; delta E00 per fully covered pixel against the",
        f"K = {REFERENCE_LAYERS} render (the layers' weights are normalised per K, so fewer layers also change the",
        "brightness of the internal term, not only its shape).",
        "",
        "| K | total (s) | runs (s) | setup (s) | mean dE00 | p95 dE00 |",
        "|---:|---:|---|---:|---:|---:|",
    ]
    for row in k["rows"]:
        lines.append(f"| {row['layers']} | {row['total_s']:.2f} | {', '.join(f'{t:.2f}' for t in row['times_s'])} | "
                     f"{row['setup_s']:.2f} | {row['de_mean']:.3f} | {row['de_p95']:.3f} |")
    lines.append("")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--case", choices=["all", "cost", "layers"], default="all")
    args = parser.parse_args()
    if args.case == "cost":
        out = case_cost()
    elif args.case == "layers":
        out = case_layers()
    else:
        out = run_all()
    print(json.dumps(out))


if __name__ == "__main__":
    main()
