"""Renderer benchmarks: speed ratio to bare ray casting, and the
accuracy/time of each preset and spectral sampling against the reference render.

Run through ``bench/run.py``; each case runs in its own process
(``python -m bench.render_bench --case NAME``) and prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np

from bench.common import peak_rss_mb

SPEED_SIZE = (1024, 1024)
ACCURACY_SIZE = (320, 240)


def _hawk_job(size, preset, triangles, material=None, sky="none"):
    """The benchmark hawk: one sun; ``material`` replaces every region's default material."""
    from app.workflows.scene_build import build_job
    from app.workflows.scene_spec import CameraSpec, LightSpec, ObjectSpec, SceneSpec, SkySpec
    from mocks.procedural_hawk import DEFAULT_MATERIALS

    obj = ObjectSpec(procedural="hawk", procedural_args={"triangles": triangles})
    if material:
        obj.region_materials = {r: material for r in DEFAULT_MATERIALS}
    spec = SceneSpec(
        objects=[obj],
        lights=[LightSpec("directional", (0.6, -0.9, 1.4), "D65", 1.0)],
        sky=SkySpec(kind=sky, zenith=0.35, horizon=0.8, spectrum="D65"),
        camera=CameraSpec(eye=(175.0, -150.0, 95.0), target=(2.0, 0.0, 38.0), fov_deg=30.0),
        size=size,
        preset=preset,
    )
    return build_job(spec, default_hawk_triangles=triangles)


def case_speed(preset: str = "standard", repeats: int = 3) -> dict:
    """1024x1024, ~1M triangles, one directional light with shadows, metal (gold, no mirror lobe,
    no sky: exactly primary + shadow rays, so the baseline casts the same rays)."""
    from mocks.procedural_hawk import HAWK_PRESET_TRIANGLES
    from render.renderer import cast_rays_baseline, render

    tri = HAWK_PRESET_TRIANGLES["reference"]
    job = _hawk_job(SPEED_SIZE, preset, tri, material="gold:mirror=0", sky="none")
    n_tri = sum(o.mesh.n_triangles for o in job.scene.objects)
    render(job.scene, job.camera, job.settings)          # warm-up: tables, imports, page cache
    render_times, render_builds, bases, refined = [], [], [], 0.0
    for _ in range(repeats):                              # interleaved: both see the same machine load
        t0 = time.perf_counter()
        res = render(job.scene, job.camera, job.settings)
        render_times.append(time.perf_counter() - t0)
        render_builds.append(res.timings["bvh_build"])
        refined = res.stats["refined_fraction"]
        # the same primary (base + refinement) and shadow rays, in a freshly built scene
        bases.append(cast_rays_baseline(job.scene, job.camera, job.settings, refined=res.refined))
    with_build = [rt / b.with_build for rt, b in zip(render_times, bases)]
    no_build = [(rt - rb) / b.cast for rt, rb, b in zip(render_times, render_builds, bases)]
    r = statistics.median(render_times)
    return {"preset": preset, "triangles": n_tri, "size": list(SPEED_SIZE),
            "samples_per_pixel": job.settings.samples_per_pixel,
            "adaptive_samples": job.settings.adaptive_samples, "refined_fraction": refined,
            "primary_rays": bases[-1].primary_rays, "shadow_rays": bases[-1].shadow_rays,
            "render_s": r, "cast_s": statistics.median(b.with_build for b in bases),
            "build_s": statistics.median(b.build for b in bases),
            "cast_no_build_s": statistics.median(b.cast for b in bases),
            "ratio": statistics.median(with_build), "ratios": with_build,
            "ratio_no_build": statistics.median(no_build), "ratios_no_build": no_build,
            "peak_rss_mb": peak_rss_mb()}


def _accuracy_variants():
    from render.presets import get_preset

    ref = get_preset("reference")
    variants = {
        "draft preset": get_preset("draft"),
        "standard preset": get_preset("standard"),
        "reference preset, jittered samples, other seed (noise floor)": ref.replace(jitter=True, seed=ref.seed + 1),
    }
    # spectral handling alone: 16 uniform samples (no adaptive decisions that could differ), compared
    # with the same samples at 61 bands per pixel
    fixed = ref.replace(adaptive_samples=0)
    spectral = {}
    for step, bands in ((10.0, 31), (20.0, 16), (300.0 / 7.0, 8)):
        spectral[f"reference samples, {bands} bands per pixel"] = fixed.replace(spectral_step=step)
    for step, bands in ((5.0, 61), (20.0, 16)):
        spectral[f"reference samples, per-material tables, {bands} bands"] = fixed.replace(spectral_step=step,
                                                                                           use_tables=True)
    return ref, variants, fixed, spectral


def case_accuracy() -> dict:
    from mocks.procedural_hawk import HAWK_PRESET_TRIANGLES
    from processing.spectral.display import delta_e00, white_xyz
    from processing.spectral.spectra import REFERENCE_GRID, light_spectrum
    from render.renderer import render

    tri = HAWK_PRESET_TRIANGLES["draft"]
    job = _hawk_job(ACCURACY_SIZE, "reference", tri, sky="gradient")
    ref_settings, variants, fixed_settings, spectral = _accuracy_variants()
    white = white_xyz(light_spectrum("D65", REFERENCE_GRID), REFERENCE_GRID)

    def compare(base, base_time, base_settings, base_name, todo):
        mask = base.mask > 0
        rows = [{"variant": base_name, "settings": _describe(base_settings), "seconds": base_time,
                 "de_mean": 0.0, "de_p95": 0.0, "refined_fraction": base.stats["refined_fraction"]}]
        for name, settings in todo.items():
            t0 = time.perf_counter()
            res = render(job.scene, job.camera, settings)
            secs = time.perf_counter() - t0
            de = np.asarray(delta_e00(res.xyz[mask], base.xyz[mask], white))
            rows.append({"variant": name, "settings": _describe(settings), "seconds": secs,
                         "de_mean": float(de.mean()), "de_p95": float(np.percentile(de, 95)),
                         "refined_fraction": res.stats["refined_fraction"]})
        return rows

    t0 = time.perf_counter()
    ref = render(job.scene, job.camera, ref_settings)
    rows = compare(ref, time.perf_counter() - t0, ref_settings, "reference preset", variants)
    t0 = time.perf_counter()
    fixed = render(job.scene, job.camera, fixed_settings)
    rows += compare(fixed, time.perf_counter() - t0, fixed_settings, "reference samples (16 spp, no refinement)",
                    spectral)
    return {"size": list(ACCURACY_SIZE), "triangles": tri, "rows": rows, "peak_rss_mb": peak_rss_mb()}


def _describe(s) -> str:
    bands = int(round(300.0 / s.spectral_step)) + 1
    return (f"{bands} bands, {'tables' if s.use_tables else 'per-pixel spectra'}, "
            f"{s.samples_per_pixel} spp" + (f" (adaptive {s.adaptive_samples} above {s.adaptive_threshold:g} L*)"
                                              if s.adaptive_samples else "")
            + f", {s.mirror_bounces} bounce(s), {s.mirror_rays} mirror ray(s)")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--case", required=True, choices=["speed-standard", "speed-draft", "accuracy"])
    args = ap.parse_args()
    if args.case == "accuracy":
        result = case_accuracy()
    else:
        result = case_speed(args.case.split("-", 1)[1])
    print(json.dumps(result))


if __name__ == "__main__":
    main()
