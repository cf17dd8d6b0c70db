"""``make bench``: run every benchmark case in its own process and write docs/BENCHMARKS.md."""

from __future__ import annotations

import argparse
import datetime as dt
import json
import subprocess
import sys
from pathlib import Path

from bench.common import ROOT, machine_description, run_case_subprocess


def render_section() -> list[str]:
    lines = ["## Renderer (issue #2)", ""]
    lines += [
        "### Speed: shading cost relative to bare ray casting",
        "",
        "1024x1024 image of the procedural hawk's head at about 1M triangles, gold (mirror lobe off, no sky,",
        "so the renderer casts exactly primary + shadow rays), one directional light with shadows.",
        "`cast` is Open3D's bare `cast_rays` for the same primary rays (base and adaptive refinement, replayed",
        "from the render's refined-pixel mask) plus the shadow rays of the same hits, in a freshly built scene,",
        "timed in the same run.  'with build' = render / (build + cast): both pay Open3D's BVH build;",
        "'without build' = (render - its build) / cast.  Medians of 3 interleaved runs after a warm-up.",
        "Target at `standard`: ratio <= 2.0 (without build), peak memory <= 2 GB.",
        "",
        "| preset | triangles | samples/pixel | refined | render (s) | build (s) | cast (s) | ratio with build | "
        "ratio without build | ratios without build | peak RSS (MB) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|",
    ]
    for case in ("speed-standard", "speed-draft"):
        r = run_case_subprocess("bench.render_bench", case)
        spp = f"{r['samples_per_pixel']}" + (f" / {r['adaptive_samples']}" if r["adaptive_samples"] else "")
        lines.append(
            f"| {r['preset']} | {r['triangles']:,} | {spp} | {100 * r['refined_fraction']:.1f}% | "
            f"{r['render_s']:.2f} | {r['build_s']:.2f} | {r['cast_no_build_s']:.2f} | {r['ratio']:.2f} | "
            f"**{r['ratio_no_build']:.2f}** | {', '.join(f'{x:.2f}' for x in r['ratios_no_build'])} | "
            f"{r['peak_rss_mb']:.0f} |"
        )
    a = run_case_subprocess("bench.render_bench", "accuracy")
    lines += [
        "",
        "### Accuracy and time of presets and spectral sampling",
        "",
        f"Hawk's head ({a['triangles']:,} triangles, all five region materials), {a['size'][0]}x{a['size'][1]},",
        "sun + gradient sky (mirror reflections), D65.  delta E00 (CIEDE2000) per covered pixel against the",
        "`reference` render; the jittered 'other seed' row repeats the reference with a different sample",
        "pattern, so it is the reference's own noise floor.  Rows named 'reference samples, ...' use 16",
        "uniform samples without refinement on both sides and change only the spectral handling, which",
        "isolates the spectral error.  Target: `standard` within 0.1 mean delta E00 of `reference`.",
        "",
        "| variant | settings | refined | time (s) | mean dE00 | p95 dE00 |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for row in a["rows"]:
        lines.append(f"| {row['variant']} | {row['settings']} | {100 * row['refined_fraction']:.1f}% | "
                     f"{row['seconds']:.2f} | "
                     f"{row['de_mean']:.3f} | {row['de_p95']:.3f} |")
    lines.append("")
    return lines


def devices_section() -> list[str]:
    """Host-side cost of one turntable step against the instant emulator (issue #3)."""
    proc = subprocess.run([sys.executable, "-m", "bench.device_bench", "--steps", "400"], cwd=ROOT,
                          capture_output=True, text=True, timeout=600, check=True)
    r = json.loads(proc.stdout.strip().splitlines()[-1])
    c = r["capture"]
    return [
        "## Devices (issue #3)",
        "",
        "Host-side overhead of one `Turntable.step` (motor and laser re-asserted, absolute move: four",
        "command round trips over a real pseudo-terminal, wire log on) against the Horus firmware emulator",
        "with instant motion, so only the host's own cost is timed.  Target: <= 5 ms per step.",
        "",
        "| steps | median (ms/step) | p95 (ms/step) |",
        "|---:|---:|---:|",
        f"| {r['steps']} | **{r['overhead_ms_per_step']:.2f}** | {r['p95_ms']:.2f} |",
        "",
        "A whole capture pass (`kogei capture`'s engine, `app.capture.run_capture`) against the simulated",
        f"station, camera off, {c['steps']} steps, {c['points']} points per profile: per step the turntable",
        "step, one profile (trigger, binary frame, CRC), the profile written atomically into the session and",
        "its journal record `fsync`-ed.  The station computes each profile by ray casting the world in the",
        "same process (real hardware does that in the sensor); that time is measured alone and subtracted.",
        "",
        "| per profile step | median (ms) |",
        "|---|---:|",
        f"| whole step (wall) | {c['step_ms']:.2f} |",
        f"| station's ray casting (simulated device time) | {c['device_ms']:.2f} |",
        f"| **host-side overhead** (difference) | **{c['host_ms']:.2f}** |",
        f"| of which: session store (file + journal, both `fsync`-ed) | {c['store_ms']:.2f} |",
        "",
        f"Throughput: **{c['profiles_per_s']:.0f} profiles/s** over the whole pass.",
        "",
    ]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=str(ROOT / "docs" / "BENCHMARKS.md"))
    args = ap.parse_args()
    lines = [
        "# Benchmarks",
        "",
        "Regenerated by `make bench` (each case in a fresh process).  These machines are noisy: read",
        "medians and ratios, not single times.",
        "",
        f"Machine: {machine_description()}",
        "",
    ]
    lines += render_section()
    lines += devices_section()
    Path(args.out).write_text("\n".join(lines) + "\n", encoding="utf-8")
    print(f"wrote {args.out} ({dt.datetime.now():%Y-%m-%d %H:%M})")


if __name__ == "__main__":
    main()
