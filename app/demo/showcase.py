"""``kogei demo``: the product end to end on simulated devices.

* a capture session of the procedural hawk's head from the simulated station
  (turntable and laser profiler emulators on pseudo-terminals, a fake
  gphoto2), several placements, profiles and RAW frames with the chart first
  (:mod:`app.demo.capture`);
* the hawk's materials identified from simulated RAW frames calibrated by the
  colour chart, compared with the simulation's truth (:mod:`app.demo.colour`);
* the procedural hawk's head with the materials of the paper's object
  (Matsuda et al., section 5: nami-shibuichi head, gold and urushi beak,
  copper eyes) under daylight: a sun plus a gradient sky;
* a simulated light probe of a room of known light, merged, unwrapped and compared with the room's
  truth, and the hawk (measured when the capture ran) under it and under a daylight sky
  (:mod:`app.demo.light`);
* one sphere per material preset under D65 and under illuminant A, labelled,
  so the colour shift of each alloy between the two lights can be compared;
* woven cloth (Yasuda et al.): silk and tamamushi (shot silk) on a draped sheet.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from app.workflows.scene_spec import CameraSpec, LightSpec, ObjectSpec, SceneSpec, SkySpec, parse_size

__all__ = ["run_demo", "hawk_spec", "spheres_spec", "label_spheres"]

#: The stage of the second process that shoots and builds the light probe (the "light" stage renders with it).
PROBE_STAGE = "light probe (shots, merge, unwrap)"
SPHERE_COLUMNS = 6
SPHERE_SPACING = 2.6


def hawk_spec(size: tuple[int, int], preset: str, triangles: int) -> SceneSpec:
    """The hawk's head under daylight, seen three-quarters from the front."""
    return SceneSpec(
        objects=[ObjectSpec(procedural="hawk", procedural_args={"triangles": triangles})],
        lights=[LightSpec("directional", (0.6, -0.9, 1.4), "D65", 1.0)],
        sky=SkySpec(kind="gradient", zenith=0.12, horizon=0.45, spectrum="D65"),
        camera=CameraSpec(eye=(118.0, -100.0, 70.0), target=(0.0, 0.0, 35.0), up=(0, 0, 1), fov_deg=35.0),
        illuminant="D65",
        size=size,
        preset=preset,
    )


def _sphere_centres(n: int) -> np.ndarray:
    rows = math.ceil(n / SPHERE_COLUMNS)
    idx = np.arange(n)
    x = (idx % SPHERE_COLUMNS - (SPHERE_COLUMNS - 1) / 2) * SPHERE_SPACING
    z = ((rows - 1) / 2 - idx // SPHERE_COLUMNS) * SPHERE_SPACING
    return np.stack([x, np.zeros(n), z], axis=1)


def spheres_spec(names: list[str], illuminant: str, size: tuple[int, int], preset: str) -> SceneSpec:
    """One unit sphere per material, in rows, lit from the upper left-front."""
    centres = _sphere_centres(len(names))
    objects = [
        ObjectSpec(procedural="sphere", procedural_args={"radius": 1.0, "triangles": 20_000},
                   material=name, translate=tuple(c))
        for name, c in zip(names, centres)
    ]
    rows = math.ceil(len(names) / SPHERE_COLUMNS)
    half_h = rows * SPHERE_SPACING / 2 + 0.6          # room for the labels and the title
    half_w = SPHERE_COLUMNS * SPHERE_SPACING / 2 + 0.3
    dist = 60.0
    fov = 2 * math.degrees(math.atan(max(half_h, half_w * size[1] / size[0]) / dist))
    return SceneSpec(
        objects=objects,
        lights=[LightSpec("directional", (-0.5, -1.0, 0.8), illuminant, 1.0)],
        sky=SkySpec(kind="gradient", zenith=0.3, horizon=0.7, spectrum=illuminant),
        camera=CameraSpec(eye=(0.0, -dist, 0.0), target=(0.0, 0.0, 0.0), up=(0, 0, 1), fov_deg=fov),
        illuminant=illuminant,
        size=size,
        preset=preset,
    )


def label_spheres(srgb8: np.ndarray, camera, names: list[str], title: str) -> np.ndarray:
    """Write each material's name under its sphere and a title, with Pillow."""
    from PIL import Image, ImageDraw, ImageFont

    img = Image.fromarray(np.ascontiguousarray(srgb8))
    draw = ImageDraw.Draw(img)
    h = img.height
    font = ImageFont.load_default(size=max(10, h // 48))
    title_font = ImageFont.load_default(size=max(12, h // 32))
    centres = _sphere_centres(len(names)) - np.array([0.0, 0.0, 1.12])
    px = np.asarray(camera.project(centres))
    for name, (x, y) in zip(names, px[:, :2]):
        # Long alloy names go on two lines so neighbours do not collide.
        head, sep, tail = name.rpartition("-") if len(name) > 16 else ("", "", name)
        text = f"{head}-\n{tail}" if sep else name
        box = draw.multiline_textbbox((0, 0), text, font=font, align="center")
        left = min(max(x - (box[2] - box[0]) / 2, 2), img.width - (box[2] - box[0]) - 2)
        draw.multiline_text((left, y), text, fill=(40, 40, 40), font=font, align="center")
    draw.text((10, 8), title, fill=(20, 20, 20), font=title_font)
    return np.asarray(img)


def _render(spec: SceneSpec, hawk_triangles: int):
    from app.workflows.scene_build import build_job
    from render.renderer import render

    job = build_job(spec, default_hawk_triangles=hawk_triangles)
    t0 = time.perf_counter()
    result = render(job.scene, job.camera, job.settings)
    return job, result, time.perf_counter() - t0


def run_demo(args: argparse.Namespace) -> int:
    """The showcase into ``args.out``: a simulated capture, the colour demo, the renders; ``demo.json``.

    Two chains of stages run at once, one per core: the capture chain (the hawk's capture, the chrome
    sphere's capture, the reference sphere's scan that calibrates the scanner, the camera and lamp
    calibrations, the processing, the batch, the measured object, the hawk under the measured light)
    in this process; in a second process first what the capture chain needs from outside it -- the
    board's capture the camera calibration needs, the simulated light probe --
    then the stages that need nothing from the capture (:func:`_independent_stages`: the colour demo,
    the hawk, the spheres, the cloth).  ``demo.json``'s ``stages_s`` and the console's last lines give
    each stage's seconds (each measured in the process that ran it) and the whole demo's.
    """
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context

    from mocks.procedural_hawk import HAWK_PRESET_TRIANGLES

    t0 = time.perf_counter()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    triangles = args.hawk_triangles or HAWK_PRESET_TRIANGLES["reference"]
    size = size_of(args)
    if args.capture_steps and (args.capture_steps < 1 or args.capture_passes < 1):
        from app.errors import UsageError

        raise UsageError("--capture-steps and --capture-passes must be >= 1 (or --capture-steps 0: no capture)")
    summary: dict = {"preset": args.preset, "renders": [], "stages_s": {}}
    with ProcessPoolExecutor(max_workers=1, mp_context=get_context("spawn")) as pool:
        station = None
        if args.capture_steps and args.capture_camera != "none":
            from app.demo.station import capture_station_sessions

            # first in the second process: the board's session, which the capture chain needs only after
            # the hawk's capture, the mirror sphere's and the reference sphere's (all three here); then
            # the light probe and the stages that need nothing from the capture
            station = pool.submit(capture_station_sessions, out / "capture", seed=1, kinds=("camera",))
        probe = pool.submit(_probe_stage, out)
        other = pool.submit(_independent_stages, out, size, args.preset, triangles)
        if args.capture_steps:
            _demo_capture(out, args, summary, station)
        probe_result, probe_s = probe.result()
        summary["stages_s"][PROBE_STAGE] = probe_s
        _timed("light", summary, _demo_light, out, size, args.preset, triangles, summary, probe_result)
        parts = other.result()
    summary["colour"] = parts["colour"]
    summary["renders"] = parts["renders"] + summary["renders"]
    summary["shift_D65_to_A"] = parts["shift_D65_to_A"]
    summary["stages_s"].update(parts["stages_s"])
    summary["seconds"] = round(time.perf_counter() - t0, 1)
    summary["stages_s"] = {k: round(v, 1) for k, v in summary["stages_s"].items()}
    (out / "demo.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    print(f"demo written to {out}/ in {summary['seconds']:.0f} s; the stages (two chains at once, one per core):",
          file=sys.stderr)
    for name, secs in summary["stages_s"].items():
        print(f"  {name:<44} {secs:7.1f} s", file=sys.stderr)
    return 0


def _timed(name: str, summary: dict, stage, *args):
    """Run ``stage(*args)`` and add its seconds to ``summary["stages_s"][name]``."""
    t0 = time.perf_counter()
    result = stage(*args)
    summary["stages_s"][name] = summary["stages_s"].get(name, 0.0) + time.perf_counter() - t0
    return result


def _probe_stage(out: Path) -> tuple[dict, float]:
    """The simulated light probe shot and built (``probe.exr``), and its seconds (in the second process)."""
    from app.demo.light import simulated_probe

    t0 = time.perf_counter()
    probe = simulated_probe(out / "probe-capture", out / "probe.exr")
    return probe, time.perf_counter() - t0


def _independent_stages(out: Path, size: tuple[int, int], preset: str, triangles: int) -> dict:
    """The stages that need nothing from the capture: colour demo, hawk, spheres, cloth (a process of their own)."""
    summary: dict = {"renders": [], "stages_s": {}}
    _timed("colour (RAW frames, chart, identification)", summary, _demo_colour, out, summary)
    _timed("hawk render", summary, _demo_hawk, out, size, preset, triangles, summary)
    _timed("spheres (D65 and A)", summary, _demo_spheres, out, size, preset, triangles, summary)
    _timed("cloth", summary, _demo_cloth, out, size, preset, summary)
    return summary


def _demo_capture(out: Path, args: argparse.Namespace, summary: dict, station_sessions=None) -> None:
    """A simulated capture session, processed, then the batch's other steps on it.

    ``station_sessions``: a future of the board's session, captured in the other process (the chrome
    sphere's is captured here after the hawk's, then the reference sphere is scanned).
    """
    from app.demo.capture import simulated_capture

    cap = simulated_capture(out / "capture", steps=args.capture_steps, passes=args.capture_passes,
                            camera=args.capture_camera, process_preset=args.preset, seed=1,
                            station_sessions=station_sessions, scan_after_capture=True,
                            lamp_session_here=station_sessions is not None)
    summary["capture"] = cap
    summary["stages_s"].update(cap["stages_s"])
    print(f"capture: {cap['captures_taken']} captures in {cap['seconds']:.1f} s -> {cap['session']}",
          file=sys.stderr)
    proc = cap.get("process")
    if proc:
        errs = proc["pose_error_vs_truth"]
        worst = (max(e["rotation_deg"] for e in errs), max(e["translation_mm"] for e in errs)) if errs else (0, 0)
        print(f"process: mesh {proc['mesh']['triangles']} triangles "
              f"({'watertight' if proc['mesh']['watertight'] else 'NOT watertight'}), registration error vs "
              f"the simulation's truth <= {worst[0]:.3f} deg, {worst[1]:.3f} mm -> "
              f"{cap['session']}/{proc['mesh']['file']}", file=sys.stderr)
        proj = proc.get("projection")
        if proj:
            print(f"photos: {proj['frames']} RAW frames posed on the mesh; the mesh's outline covers the object "
                  f"with silhouette IoU >= {proj['iou_min']:.3f}, mean boundary offset {proj['offset_px_mean']:.2f} px "
                  f"({proj['observations']} observations, {proj['seconds']:.1f} s)", file=sys.stderr)

    if proc:
        summary["batch"] = _timed("batch (colour, materials, render, report)", summary, _batch_steps,
                                  Path(cap["session"]), args.preset)
        if proc.get("projection"):
            summary["object"] = _timed("measured object (materials, glTF, render)", summary,
                                       _demo_measured_object, out, Path(cap["session"]), cap, size_of(args),
                                       args.preset)


def size_of(args: argparse.Namespace) -> tuple[int, int]:
    """The demo's render size (``--size``, default 1024 x 768)."""
    return parse_size(args.size) if args.size else (1024, 768)


def _demo_measured_object(out: Path, session: Path, cap: dict, size: tuple[int, int], preset: str) -> dict:
    """The hawk's materials on its mesh against the truth, its glTF, and a render of the measured object."""
    import numpy as np

    from app.demo.object import demo_object
    from app.workflows.object_materials import OBJECT_SCENE
    from mocks.world import World
    from render.image_io import write_png

    truth = cap["simulation_truth"]
    world = World.hawk(int(truth.get("triangles", 20_000)))
    result = demo_object(session, out, world, np.asarray(truth["poses"][1]))
    from app.workflows.scene_build import build_job
    from app.workflows.scene_spec import load_scene_file
    from render.renderer import render

    spec = load_scene_file(session / OBJECT_SCENE)
    spec.size, spec.preset = (size[0] * 5 // 8, size[1] * 5 // 8), preset
    job = build_job(spec)
    t0 = time.perf_counter()
    image = render(job.scene, job.camera, job.settings)
    write_png(out / "hawk-measured.png", image.srgb8)
    secs = time.perf_counter() - t0
    print(f"measured hawk rendered from its scene file ({secs:.1f} s) -> {out / 'hawk-measured.png'}",
          file=sys.stderr)
    result["render"] = {"image": "hawk-measured.png", "seconds": round(secs, 2)}
    return result


def _demo_colour(out: Path, summary: dict) -> None:
    """The colour demo (app.demo.colour) and its comparison with the simulation's truth."""
    from app.demo.colour import colour_demo

    colour = colour_demo(out / "colour")
    summary["colour"] = {k: colour[k] for k in ("correct", "regions_identified", "seconds")}
    summary["colour"]["regions"] = [{k: r[k] for k in ("region", "true_material", "material", "correct", "confidence",
                                                       "runner_up", "alloy_weights", "true_alloy_weights")}
                                    for r in colour["regions"]]
    print(f"colour: the hawk's regions identified from RAW frames calibrated by the chart, "
          f"{colour['correct']} of {colour['regions_identified']} as in the simulation ({colour['seconds']:.1f} s):",
          file=sys.stderr)
    for r in colour["regions"]:
        print(f"  {r['region']:<8} true {r['true_material']:<16} identified {r['material']:<16} "
              f"confidence {r['confidence']:.2f}{'' if r['correct'] else '  (wrong)'}", file=sys.stderr)


def _demo_hawk(out: Path, size: tuple[int, int], preset: str, triangles: int, summary: dict) -> None:
    """The hawk rendered (hawk.png, hawk.tiff)."""
    from render.image_io import write_png, write_xyz_tiff

    job, result, secs = _render(hawk_spec(size, preset, triangles), triangles)
    write_png(out / "hawk.png", result.srgb8)
    write_xyz_tiff(out / "hawk.tiff", result.xyz)
    n_tri = sum(o.mesh.n_triangles for o in job.scene.objects)
    summary["renders"].append({"image": "hawk.png", "triangles": n_tri, "seconds": round(secs, 3),
                               "size": list(size), "timings": _plain(result.timings)})
    print(f"hawk: {n_tri} triangles, {secs:.1f} s -> {out / 'hawk.png'}", file=sys.stderr)


def _demo_light(out: Path, size: tuple[int, int], preset: str, triangles: int, summary: dict,
                probe: dict | None = None) -> None:
    """The simulated light probe and the hawk under it and under a daylight sky (app.demo.light).

    The hawk is the measured object (its scene file) when the capture produced one, else the preset
    hawk; rendered at half the demo's size to keep the added time small.  ``probe``: the probe already
    shot and built (:func:`_probe_stage`).
    """
    from app.demo.light import demo_light
    from app.workflows.object_materials import OBJECT_SCENE
    from app.workflows.scene_spec import load_scene_file

    half = (max(size[0] // 2, 16), max(size[1] // 2, 16))
    session = Path(summary["capture"]["session"]) if "object" in summary else None
    if session is not None and (session / OBJECT_SCENE).is_file():
        base, source = load_scene_file(session / OBJECT_SCENE), "the measured hawk"
    else:
        base, source = hawk_spec(half, preset, triangles), "the preset hawk"
    base.size, base.preset = half, preset
    summary["light"] = demo_light(out, base, source, default_hawk_triangles=triangles, probe=probe)


def _demo_spheres(out: Path, size: tuple[int, int], preset: str, triangles: int, summary: dict) -> None:
    """Every material preset as a sphere under D65 and A, and the colour shift between them."""
    from processing.materials.presets import list_materials
    from processing.spectral.display import xyz_to_srgb8
    from render.image_io import write_png, write_xyz_tiff

    names = list_materials()
    sphere_size = (size[0], int(size[0] * 0.6))
    results = {}
    for illum in ("D65", "A"):
        job, result, secs = _render(spheres_spec(names, illum, sphere_size, preset), triangles)
        results[illum] = result
        title = f"material presets under {'D65 (daylight)' if illum == 'D65' else 'illuminant A (tungsten), adapted'}"
        write_png(out / f"spheres-{illum}.png", label_spheres(result.srgb8, job.camera, names, title))
        write_xyz_tiff(out / f"spheres-{illum}.tiff", result.xyz)
        summary["renders"].append({"image": f"spheres-{illum}.png", "seconds": round(secs, 3),
                                   "size": list(sphere_size), "timings": _plain(result.timings)})
        print(f"spheres under {illum}: {secs:.1f} s -> {out / f'spheres-{illum}.png'}", file=sys.stderr)
    # Without adaptation the display shows the tungsten light's own colour, as a D65-balanced camera would.
    raw_a = xyz_to_srgb8(results["A"].xyz, results["D65"].white, adapt=False)
    write_png(out / "spheres-A-unadapted.png",
              label_spheres(raw_a, job.camera, names, "material presets under illuminant A, display balanced for D65"))
    summary["shift_D65_to_A"] = colour_shift_table(results["D65"], results["A"], job.camera, names)
    for name, de in summary["shift_D65_to_A"].items():
        print(f"  {name:<28} mean delta E00 D65 vs A (both adapted): {de:.2f}", file=sys.stderr)


def _demo_cloth(out: Path, size: tuple[int, int], preset: str, summary: dict) -> None:
    """The cloth scenes (Yasuda et al.), silk and tamamushi."""
    from app.workflows.cloth_scene import render_cloth_scene

    for cloth in ("silk", "tamamushi"):
        t0 = time.perf_counter()
        png = render_cloth_scene(out, preset, (size[0] * 5 // 8, size[1] * 5 // 8), material=cloth)
        secs = time.perf_counter() - t0
        summary["renders"].append({"image": png.name, "seconds": round(secs, 3)})
        print(f"cloth ({cloth}, Yasuda et al.): {secs:.1f} s -> {png}", file=sys.stderr)


def _batch_steps(session: Path, preset: str) -> dict:
    """The session's colour, materials, render and report steps through ``kogei batch`` (its geometry is processed)."""
    import json

    from app.batch.runner import run_batch
    from app.batch.steps import BatchOptions

    t0 = time.perf_counter()
    result = run_batch([session], "colour,materials,render,report", options=BatchOptions(preset=preset),
                       workers=1).results[0]
    secs = time.perf_counter() - t0
    report = session / "products" / "report.html"
    print(f"batch (colour, materials, render, report): {result.status}"
          + (f" ({result.reason})" if result.reason else "") + f", {secs:.1f} s; report -> {report}", file=sys.stderr)
    materials = []
    path = session / "products" / "materials.json"
    if path.is_file():
        doc = json.loads(path.read_text(encoding="utf-8"))
        materials = [{k: r[k] for k in ("region", "material", "confidence", "pixels")} for r in doc["regions"]]
        largest = doc.get("largest") or {}
        print(f"batch materials (regions found without labels; renders in {largest.get('material', 'the default')}):",
              file=sys.stderr)
        for r in materials:
            conf = "" if r["confidence"] is None else f" (confidence {r['confidence']:.2f})"
            print(f"  {r['region']:<8} {r['material'] or 'not identified':<24}{conf}, {r['pixels']} pixels",
                  file=sys.stderr)
    return {"status": result.status, "reason": result.reason, "seconds": round(secs, 2),
            "report": str(report) if report.is_file() else None, "materials": materials}


def colour_shift_table(res_d65, res_a, camera, names: list[str]) -> dict[str, float]:
    """Mean CIEDE2000 difference per sphere between the D65 and the A render, each adapted
    to D65 (what an observer adapted to each light sees): the part of the colour change that
    only a spectral model predicts, since an RGB model's adapted colours would not change.
    """
    from colour.adaptation import chromatic_adaptation_VonKries

    from processing.spectral.display import delta_e00

    d65_white = np.asarray(res_d65.white, dtype=np.float64)
    xyz_a = chromatic_adaptation_VonKries(np.asarray(res_a.xyz, dtype=np.float64),
                                          np.asarray(res_a.white, dtype=np.float64), d65_white,
                                          transform="CAT02")
    de = np.asarray(delta_e00(np.asarray(res_d65.xyz, dtype=np.float64), xyz_a, d65_white))
    h, w = de.shape
    centres3d = _sphere_centres(len(names))
    centres = np.asarray(camera.project(centres3d))[:, :2]
    rim = np.asarray(camera.project(centres3d[:1] + [1.0, 0.0, 0.0]))[0, :2]   # unit spheres
    radius_px = 0.8 * float(np.linalg.norm(rim - centres[0]))                   # stay off the rims
    yy, xx = np.mgrid[0:h, 0:w]
    covered = np.asarray(res_d65.mask) > 0.99
    table = {}
    for name, (cx, cy) in zip(names, centres):
        inside = ((xx - cx) ** 2 + (yy - cy) ** 2 < radius_px**2) & covered
        table[name] = round(float(de[inside].mean()), 3) if inside.any() else float("nan")
    return table


def _plain(d: dict) -> dict:
    return {k: (round(float(v), 4) if isinstance(v, (int, float, np.floating)) else str(v)) for k, v in d.items()}
