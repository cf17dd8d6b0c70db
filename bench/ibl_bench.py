"""Image-based lighting benchmarks: a rough gold sphere against Mitsuba 3, and the cost of an environment.

Cases (``python -m bench.ibl_bench --case NAME``, one JSON line each; ``bench/run.py --only ibl``):

``mitsuba``
    A rough gold sphere (Beckmann sigma 0.2, Smith, the Johnson-Christy
    gold indices, no mirror lobe) under a test environment map, rendered by
    kogei (``standard``, and with more environment samples) and by Mitsuba 3
    (``scalar_spectral``, ``envmap`` emitter of the same map, ``roughconductor``
    with the same complex indices, a mesh with the same vertices and
    normals, box-filtered pixels) at high spp: the reference is the mean of
    :data:`REFERENCE_SEEDS` renders of :data:`MITSUBA_SPP` spp with different
    seeds, and the mean of half the seeds against the other half gives the
    reference's own noise (that figure over 2).  The map is grey (R = G = B):
    Mitsuba's RGB upsampling and kogei's Mallett-Yuksel upsampling both give
    exactly D65 times the luminance, so the spectral handling is the same.
    The same comparison under one directional light (D65) is the baseline
    the direct-light renders reach; a second Mitsuba render with another
    seed gives the reference's own noise.
``speed``
    The procedural hawk at about 1M triangles, 1024 x 1024, gold without the
    mirror lobe: ``standard`` under the test map vs under one directional
    light; ``draft`` at 640 x 480 under the map, built afresh and re-rendered
    with a :class:`render.renderer.GeometryCache` (an interactive view).
``trade``
    The gold sphere at 256 x 256: environment samples per hit and map
    height against time and delta E00 to the Mitsuba reference.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time
from pathlib import Path

import numpy as np

from bench.common import ROOT, peak_rss_mb

SIZE = (256, 256)
MITSUBA_SPP = 512
REFERENCE_SEEDS = 8              # Mitsuba renders averaged into the reference of the map case
MAP_HEIGHT = 256
GOLD = "gold:roughness=0.2,gloss=1,mirror=0"
EYE, TARGET, UP, FOV = (0.0, -4.2, 1.3), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 30.0
SUN = (-0.5, -0.8, 0.9)          # the directional light of the baseline (toward the light)
CACHE = ROOT / "out" / "bench"


# --------------------------------------------------------------------------- the scene
def sample_map_luminance(height: int = MAP_HEIGHT) -> np.ndarray:
    """``(H, 2H)`` luminance of the test map: a sky gradient, a dark ground, a soft window and a small lamp."""
    from processing.lighting.environment_map import pixel_directions

    d = pixel_directions(height, 2 * height)
    z = d[..., 2]
    y = np.where(z > 0, 0.25 + 0.35 * z, 0.08 + 0.04 * np.cos(3 * np.arctan2(d[..., 1], d[..., 0])))
    window = np.array([0.45, -0.75, 0.48])
    y = y + 2.5 * np.exp(-((d @ (window / np.linalg.norm(window))) - 1.0) ** 2 / (2 * 0.01 ** 2))
    lamp = np.array([-0.8, -0.2, 0.55])
    y = y + 12.0 * np.exp(-((d @ (lamp / np.linalg.norm(lamp))) - 1.0) ** 2 / (2 * 0.002 ** 2))
    return y


def sample_environment(height: int = MAP_HEIGHT):
    from processing.lighting.environment_map import EnvironmentMap, srgb_basis

    y = sample_map_luminance(height)
    rgb = np.repeat(y[..., None], 3, axis=-1).astype(np.float32)      # grey: D65 times Y in both renderers
    return EnvironmentMap(rgb, srgb_basis(), source=f"test map {height} rows")


def six_basis_environment(height: int = MAP_HEIGHT):
    """The test map as 6 basis spectra (the size of a map from two bracket sets): D65 of luminance 1 split by
    six hat functions over 400-700 nm, every coefficient the map's luminance -- the same light as
    :func:`sample_environment`, at the renderer's cost of six."""
    from processing.lighting.environment_map import EnvironmentMap
    from processing.spectral.display import spectra_to_xyz
    from processing.spectral.spectra import REFERENCE_GRID, light_spectrum

    g = REFERENCE_GRID
    d65 = light_spectrum("D65", g)
    d65 = d65 / float(spectra_to_xyz(d65, g)[1])
    nodes = np.linspace(g.start, g.stop, 6)
    hats = np.clip(1.0 - np.abs(g.wavelengths[None, :] - nodes[:, None]) / (nodes[1] - nodes[0]), 0.0, None)
    y = sample_map_luminance(height)
    coeff = np.repeat(y[..., None], 6, axis=-1).astype(np.float32)
    return EnvironmentMap(coeff, hats * d65[None, :], g, source=f"test map {height} rows, 6 basis spectra")


def uv_sphere(n_theta: int = 160, n_phi: int = 320):
    """Vertices, triangles and exact unit normals of a UV sphere of radius 1."""
    theta = np.linspace(0.0, math.pi, n_theta + 1)[1:-1]
    phi = np.linspace(0.0, 2 * math.pi, n_phi, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    v = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1).reshape(-1, 3)
    v = np.concatenate([[[0.0, 0.0, 1.0]], v, [[0.0, 0.0, -1.0]]])
    rows = n_theta - 1
    j = np.arange(n_phi)
    jn = (j + 1) % n_phi
    tris = [np.stack([np.zeros(n_phi, int), 1 + j, 1 + jn], 1)]
    for i in range(rows - 1):
        a, b = 1 + i * n_phi + j, 1 + i * n_phi + jn
        c, d = 1 + (i + 1) * n_phi + j, 1 + (i + 1) * n_phi + jn
        tris += [np.stack([a, c, b], 1), np.stack([b, c, d], 1)]
    last = len(v) - 1
    tris.append(np.stack([np.full(n_phi, last), 1 + (rows - 1) * n_phi + jn, 1 + (rows - 1) * n_phi + j], 1))
    return v, np.concatenate(tris), v.copy()


def kogei_scene(env=None, directional: bool = False):
    from render.meshio import make_mesh
    from render.scene import Light, Scene, SceneObject, Sky

    v, t, n = uv_sphere()
    obj = SceneObject(make_mesh(v, t, n), [GOLD], name="gold sphere")
    lights = [Light("directional", SUN, "D65", 1.0)] if directional else []
    return Scene([obj], lights, Sky("none"), environment=env)


def kogei_camera(size=SIZE):
    from render.camera import Camera

    return Camera(EYE, TARGET, UP, FOV, size[0], size[1])


# --------------------------------------------------------------------------- Mitsuba
#: The envmap's to_world that makes Mitsuba's map agree with kogei's layout (z up, row 0 the zenith,
#: azimuth from +x toward +y): found by evaluating Mitsuba's emitter along random directions against
#: EnvironmentMap.luminance (mean difference 0.2 % of the map's range at 64 rows, the two bilinear lookups).
_ENV_TO_WORLD = [[0.0, 0.0, -1.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]


def mitsuba_render(directional: bool, spp: int, seed: int = 0, size=SIZE) -> np.ndarray:
    """CIE XYZ ``(H, W, 3)`` of the gold sphere by Mitsuba 3 (scalar_spectral), kogei's units."""
    import mitsuba as mi

    mi.set_variant("scalar_spectral")
    from processing.materials.metal_model import ConductorFresnel

    wl = np.arange(360.0, 831.0, 5.0)
    eta = ConductorFresnel({"Au": 1.0}).eta(np.clip(wl, 400.0, 700.0))[0]   # held constant outside 400-700 nm

    def spectrum(values):
        return {"type": "irregular", "wavelengths": ",".join(f"{x:g}" for x in wl),
                "values": ",".join(f"{x:.6g}" for x in values)}

    bsdf = mi.load_dict({"type": "roughconductor", "distribution": "beckmann", "alpha": 0.2,
                         "eta": spectrum(eta.real), "k": spectrum(np.abs(eta.imag))})
    scene_dict = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 3},
        "sensor": {"type": "perspective", "fov": FOV, "fov_axis": "y",
                   "to_world": mi.ScalarTransform4f().look_at(origin=list(EYE), target=list(TARGET), up=list(UP)),
                   "sampler": {"type": "independent", "sample_count": spp, "seed": seed},
                   "film": {"type": "hdrfilm", "width": size[0], "height": size[1], "pixel_format": "xyz",
                            "rfilter": {"type": "box"}}},
        "sphere": {"type": "ply", "filename": str(_sphere_ply()), "bsdf": bsdf, "face_normals": False},
    }
    if directional:
        d = -np.asarray(SUN) / np.linalg.norm(SUN)
        scene_dict["sun"] = {"type": "directional", "direction": d.tolist(),
                             "irradiance": {"type": "d65", "scale": math.pi}}
    else:
        rgb = np.repeat(sample_map_luminance(MAP_HEIGHT)[..., None], 3, axis=-1).astype(np.float32)
        scene_dict["env"] = {"type": "envmap", "bitmap": mi.Bitmap(rgb), "to_world": mi.ScalarTransform4f(_ENV_TO_WORLD)}
    scene = mi.load_dict(scene_dict)
    return np.asarray(mi.render(scene, spp=spp, seed=seed), dtype=np.float64)


def _sphere_ply() -> Path:
    """The benchmark sphere as a binary PLY with vertex normals (Mitsuba reads it), cached."""
    CACHE.mkdir(parents=True, exist_ok=True)
    path = CACHE / "ibl_sphere.ply"
    if path.exists():
        return path
    v, t, n = uv_sphere()
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"element vertex {len(v)}\nproperty float x\nproperty float y\nproperty float z\n"
              "property float nx\nproperty float ny\nproperty float nz\n"
              f"element face {len(t)}\nproperty list uchar int vertex_indices\nend_header\n")
    verts = np.hstack([v, n]).astype("<f4")
    faces = np.empty(len(t), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    faces["n"] = 3
    faces["i"] = t
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(verts.tobytes())
        fh.write(faces.tobytes())
    return path


def mitsuba_reference(directional: bool, spp: int = MITSUBA_SPP, seed: int = 0) -> tuple[np.ndarray, float]:
    """The Mitsuba image (cached in out/bench) and the seconds it took (when rendered now; else the cached time)."""
    CACHE.mkdir(parents=True, exist_ok=True)
    name = f"ibl_mitsuba_{'sun' if directional else 'env'}_{SIZE[0]}x{SIZE[1]}_{spp}spp_seed{seed}.npz"
    path = CACHE / name
    if path.exists():
        data = np.load(path)
        return data["xyz"], float(data["seconds"])
    t0 = time.perf_counter()
    xyz = mitsuba_render(directional, spp, seed)
    secs = time.perf_counter() - t0
    np.savez_compressed(path, xyz=xyz, seconds=secs)
    return xyz, secs


# --------------------------------------------------------------------------- comparison
def _white():
    from processing.spectral.display import white_xyz
    from processing.spectral.spectra import REFERENCE_GRID, light_spectrum

    return white_xyz(light_spectrum("D65", REFERENCE_GRID), REFERENCE_GRID)


def compare(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> dict:
    """Mean / p95 CIEDE2000 per pixel and of 4 x 4 pixel blocks, chromaticity difference of the means,
    mean per-pixel u'v' difference (pixels above 1 % of the white) and the ratio of the mean luminances."""
    from processing.spectral.display import delta_e00

    de = np.asarray(delta_e00(a[mask], b[mask], _white()))

    def xy(x):
        s = x.sum(axis=-1, keepdims=True)
        return (x / np.where(s > 0, s, 1))[..., :2]

    def uv(x):
        d = x[..., 0] + 15 * x[..., 1] + 3 * x[..., 2]
        d = np.where(d > 0, d, 1)
        return np.stack([4 * x[..., 0] / d, 9 * x[..., 1] / d], axis=-1)

    mean_a, mean_b = a[mask].mean(axis=0), b[mask].mean(axis=0)
    lit = mask & (a[..., 1] > 0.01) & (b[..., 1] > 0.01)      # chromaticity of pixels that are not black
    # 4 x 4 pixel blocks inside the mask: the noise of both renders falls 4 times, what stays is systematic
    h, w = (mask.shape[0] // 4) * 4, (mask.shape[1] // 4) * 4

    def blocks(x):
        return x[:h, :w].reshape(h // 4, 4, w // 4, 4, -1).mean(axis=(1, 3))

    full = blocks(mask[..., None].astype(float))[..., 0] == 1.0
    de_blocks = np.asarray(delta_e00(blocks(a)[full], blocks(b)[full], _white()))
    return {"de_mean": float(de.mean()), "de_p95": float(np.percentile(de, 95)),
            "de_mean_4x4": float(de_blocks.mean()),
            "dxy_mean_colour": float(np.linalg.norm(xy(mean_a) - xy(mean_b))),
            "duv_pixel_mean": float(np.linalg.norm(uv(a[lit]) - uv(b[lit]), axis=-1).mean()),
            "y_ratio": float(mean_a[1] / mean_b[1])}


def _interior(mask: np.ndarray) -> np.ndarray:
    from scipy.ndimage import binary_erosion

    return binary_erosion(mask >= 1.0, iterations=2)


def averaged_reference(seeds: range) -> tuple[np.ndarray, list[float]]:
    """Mean of the cached (or rendered) Mitsuba map renders with ``seeds``, and each one's seconds."""
    renders = [mitsuba_reference(False, seed=s) for s in seeds]
    return np.mean([r[0] for r in renders], axis=0), [r[1] for r in renders]


def case_mitsuba() -> dict:
    from render.presets import get_preset
    from render.renderer import render

    camera = kogei_camera()
    rows = []
    env = sample_environment()
    half = REFERENCE_SEEDS // 2
    first, t_first = averaged_reference(range(half))
    second, t_second = averaged_reference(range(half, REFERENCE_SEEDS))
    ref_env = 0.5 * (first + second)
    # the median render's time times the number of renders (a render slowed by other jobs does not count)
    t_ref_env = statistics.median(t_first + t_second) * REFERENCE_SEEDS
    ref_sun, t_ref_sun = mitsuba_reference(True)
    other_sun, _ = mitsuba_reference(True, seed=1)
    std = get_preset("standard")
    variants = [("one directional light", True, std),
                ("environment map", False, std),
                ("environment map, 32 samples per hit", False, std.replace(environment_samples=32)),
                ("environment map, 128 samples per hit", False, std.replace(environment_samples=128)),
                ("environment map, 512 samples per hit", False, std.replace(environment_samples=512))]
    mask = None
    for name, directional, settings in variants:
        scene = kogei_scene(None if directional else env, directional)
        t0 = time.perf_counter()
        res = render(scene, camera, settings)
        secs = time.perf_counter() - t0
        mask = _interior(res.mask) if mask is None else mask
        ref = ref_sun if directional else ref_env
        rows.append({"variant": name, "preset": settings.name, "environment_samples": settings.environment_samples,
                     "seconds": secs, **compare(res.xyz.astype(np.float64), ref, mask)})
    background = res.mask == 0
    floor_env = compare(first, second, mask)          # two references of half the seeds each
    floor_sun = compare(other_sun, ref_sun, mask)
    bg = compare(res.xyz.astype(np.float64), ref_env, background) if background.any() else {}
    return {"size": list(SIZE), "mitsuba_spp": MITSUBA_SPP, "reference_seeds": REFERENCE_SEEDS,
            "map_height": MAP_HEIGHT, "mitsuba_seconds_env": t_ref_env, "mitsuba_seconds_sun": t_ref_sun,
            "rows": rows, "mitsuba_noise_env": floor_env, "mitsuba_noise_sun": floor_sun,
            "background": bg, "peak_rss_mb": peak_rss_mb()}


def case_trade() -> dict:
    from render.presets import get_preset
    from render.renderer import render

    camera = kogei_camera()
    ref, _ = averaged_reference(range(REFERENCE_SEEDS))
    std = get_preset("standard")
    rows = []
    mask = None
    for height in (32, 128, MAP_HEIGHT, 1024):
        env = sample_environment(height)
        for samples in (2, 4, 8, 16, 32):
            if height != MAP_HEIGHT and samples != 8:
                continue
            settings = std.replace(environment_samples=samples)
            t0 = time.perf_counter()
            res = render(kogei_scene(env), camera, settings)
            secs = time.perf_counter() - t0
            mask = _interior(res.mask) if mask is None else mask
            rows.append({"map_height": height, "environment_samples": samples, "seconds": secs,
                         **compare(res.xyz.astype(np.float64), ref, mask)})
    draft = render(kogei_scene(sample_environment()), camera, get_preset("draft"))
    rows.append({"map_height": MAP_HEIGHT, "environment_samples": 0, "preset": "draft",
                 "seconds": draft.timings["total"], **compare(draft.xyz.astype(np.float64), ref, mask)})
    return {"size": list(SIZE), "rows": rows, "peak_rss_mb": peak_rss_mb()}


def case_speed(repeats: int = 3) -> dict:
    from bench.render_bench import _hawk_job
    from mocks.procedural_hawk import HAWK_PRESET_TRIANGLES
    from render.camera import Camera
    from render.renderer import GeometryCache, render
    from render.scene import Scene, Sky

    tri = HAWK_PRESET_TRIANGLES["reference"]
    env = sample_environment()
    out = {}
    job = _hawk_job((1024, 1024), "standard", tri, material="gold:mirror=0", sky="none")
    n_tri = sum(o.mesh.n_triangles for o in job.scene.objects)
    env_scene = Scene(job.scene.objects, [], Sky("none"), environment=env)
    six_scene = Scene(job.scene.objects, [], Sky("none"), environment=six_basis_environment())
    render(job.scene, job.camera, job.settings)                     # warm-up
    times = {"directional": [], "environment": [], "environment_6": []}
    stats = {}
    images = {}
    for _ in range(repeats):                                       # interleaved
        for name, scene in (("directional", job.scene), ("environment", env_scene), ("environment_6", six_scene)):
            t0 = time.perf_counter()
            res = render(scene, job.camera, job.settings)
            times[name].append(time.perf_counter() - t0)
            images[name] = res.xyz
            stats[name] = {"refined_fraction": res.stats["refined_fraction"],
                           "environment_rays": res.stats.get("environment_rays", 0),
                           "shadow_rays": res.stats["shadow_rays"], "timings": res.timings}
    out["standard"] = {"triangles": n_tri, "size": [1024, 1024],
                       "directional_s": statistics.median(times["directional"]),
                       "environment_s": statistics.median(times["environment"]),
                       "ratio": statistics.median(times["environment"]) / statistics.median(times["directional"]),
                       "environment_6_s": statistics.median(times["environment_6"]),
                       "ratio_6": statistics.median(times["environment_6"]) / statistics.median(times["directional"]),
                       # the same light in 6 basis spectra: the images agree but for the spectral integration
                       "six_vs_three_max_rel": float(np.abs(images["environment_6"] - images["environment"]).max()
                                                     / max(float(np.abs(images["environment"]).max()), 1e-30)),
                       "times": times, "stats": stats}
    draft = _hawk_job((640, 480), "draft", tri, material="gold:mirror=0", sky="none")
    cam = Camera(draft.camera.eye, draft.camera.target, draft.camera.up, draft.camera.fov_deg, 640, 480)
    scene = Scene(draft.scene.objects, [], Sky("none"), environment=env)
    render(scene, cam, draft.settings)                             # warm-up
    first, again = [], []
    cache = GeometryCache()
    for _ in range(repeats):                                       # interleaved
        t0 = time.perf_counter()
        res = render(scene, cam, draft.settings)
        first.append(time.perf_counter() - t0)
        cache.clear()
        render(scene, cam, draft.settings, geometry_cache=cache)   # the view's first render builds the tracer
        t0 = time.perf_counter()
        cached = render(scene, cam, draft.settings, geometry_cache=cache)
        again.append(time.perf_counter() - t0)
    out["draft"] = {"triangles": n_tri, "size": [640, 480], "environment_s": statistics.median(first),
                    "times": first, "timings": res.timings, "cached_s": statistics.median(again),
                    "cached_times": again, "cached_timings": cached.timings,
                    "cached_reused": bool(cached.stats["geometry_reused"])}
    out["peak_rss_mb"] = peak_rss_mb()
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--case", required=True, choices=["mitsuba", "trade", "speed"])
    args = ap.parse_args()
    result = {"mitsuba": case_mitsuba, "trade": case_trade, "speed": case_speed}[args.case]()
    print(json.dumps(result))


if __name__ == "__main__":
    main()
