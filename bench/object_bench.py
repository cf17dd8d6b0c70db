"""The digitised object against the simulation's truth: materials on the mesh, held-out photos, speed.

Cases (each prints one JSON object; ``--work DIR`` is shared):

* ``session``: the demo's whole chain (:func:`app.demo.capture.simulated_capture`: scanner, camera
  and lamp calibration, the three-placement hawk scan, processing, every photo posed) into ``DIR``,
  then :func:`app.workflows.object_materials.measure_object` timed; the materials compared per face
  with the simulation's truth (:mod:`app.demo.object`), the head's Ag share and roughness against
  the preset's, the held-out-photo CIEDE2000 of the measured materials and of the one-material
  baseline, peak memory.
* ``captures``: the ``session`` case once per station seed (``--station-seeds``, default 1, 2, 3:
  other rest poses for the placements after the first, other noise; seed 1 is the demo's capture,
  in ``DIR`` as the ``session`` case), the others into ``DIR/seed-N``: how much the share right,
  the head's answer and the held-out error move with the capture.
* ``photometric``: the ``session`` case with the normals refined by the photos
  (``measure_object(..., normals="photometric")``, experimental).
* ``normals``: each true region fitted with the scanned, the refined (when the ``photometric`` case
  left its products) and the true normals.
* ``heldout``: where the held-out-photo error comes from -- the held-out frames re-shot by the
  simulated camera (one frame, bursts of 4 and 16 frames averaged, noiseless), rendered from the truth
  and from the product step by step, per pixel and in blocks, split by pixel category
  (:mod:`bench.holdout_decomposition`).
* ``large``: the procedural hawk at about 1M triangles, 24 table angles (every 15 degrees) at
  960 x 640 (simulated observations with the true camera and lamp,
  :func:`mocks.observation_sim.simulated_observations`): the product's whole fitting step timed
  (segmentation, fits, relabelling, pieces), peak memory.
* ``trade``: on the ``session`` case's observations, the fit with fewer frames (every 2nd fitted
  angle), fewer observations per vertex (half of each vertex's views) and a smaller candidate set
  (the catalogue's Japanese alloys, gold, silver, copper and the lacquers): time and agreement.
* ``reliability``: the confidence calibration of on-mesh identification (simulated regions,
  ``bench.surface_fit_bench``) and of single-image identification (``bench.reliability``); the
  on-mesh table is also written to ``app/report/reliability.json`` for the session report.

``python -m bench.object_bench --case all --work DIR``; :func:`section` writes the Markdown.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["session_case", "captures_case", "normals_case", "heldout_case", "large_case", "trade_case", "reliability_case", "section", "main", "TARGETS"]

TARGETS = {"share_right": 0.95, "ag_pts": 3.0, "roughness_rel": 0.10, "mean_de2000": 2.0, "baseline_ratio": 3.0,
           "fit_s": 60.0, "large_s": 300.0, "large_gb": 4.0, "ece": 0.05, "high_accuracy": 0.90}
_HEAD = {"Ag": 0.25, "roughness": 0.15}


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _agreement(session: Path, doc: dict[str, Any], truth: dict[str, Any]) -> dict[str, Any]:
    """Per-face agreement with the truth and the head region's parameters against the preset."""
    from app.demo.object import material_agreement, true_face_materials
    from mocks.world import World
    from render.material_mesh import read_material_mesh

    mesh = read_material_mesh(session / "products/object-mesh.ply")
    v, t = mesh.vertices, mesh.triangles
    area = 0.5 * np.linalg.norm(np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]), axis=1)
    world = World.hawk(int(truth.get("triangles", 20_000)))
    poses = {str(k): p for k, p in truth["poses"].items()}          # int keys in memory, str after JSON
    faces = true_face_materials(v, t, world, np.asarray(poses["1"]))
    agree = material_agreement(doc, mesh.face_material, area, faces)
    truth_arr = np.asarray(faces, dtype=str)
    per_region = []
    for r in doc["regions"]:
        sel = mesh.face_material == r["index"]
        names, where = np.unique(truth_arr[sel], return_inverse=True)
        if not names.size:
            continue
        major = str(names[np.argmax(np.bincount(where, weights=area[sel]))])
        named = set(r.get("group") or []) if r["material"] == "neutral metal" else {r["material"]}
        per_region.append({"index": r["index"], "majority_truth": major, "right": major in named,
                           "confidence": r.get("confidence")})
    agree["regions"] = per_region
    agree["confident_wrong"] = [x["index"] for x in per_region
                                if not x["right"] and (x["confidence"] or 0) >= 0.9
                                and doc["regions"][x["index"]]["material"] not in ("no candidate fits", "not measured")]
    head = np.array([f == "nami-shibuichi" for f in faces])
    counts = [float(area[(mesh.face_material == r["index"]) & head].sum()) for r in doc["regions"]]
    reg = doc["regions"][int(np.argmax(counts))] if doc["regions"] else {}
    params = reg.get("parameters") or {}
    agree["head"] = {"material": reg.get("material"), "confidence": reg.get("confidence"),
                     "Ag": params.get("Ag"), "roughness": params.get("roughness"),
                     "Ag_error_pts": None if params.get("Ag") is None else round(100 * (params["Ag"] - _HEAD["Ag"]), 2),
                     "roughness_error_rel": None if params.get("roughness") is None else
                     round(params["roughness"] / _HEAD["roughness"] - 1.0, 4)}
    return agree


def _true_normals(v: np.ndarray, world: Any, pose: np.ndarray) -> np.ndarray:
    """The simulated object's smooth normal at the point of it nearest to each scanned vertex (mesh frame)."""
    import open3d as o3d

    wv = world.vertices @ pose[:3, :3].T + pose[:3, 3]
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(wv),
                                     o3d.utility.Vector3iVector(world.triangles.astype(np.int32)))
    wn = np.asarray(mesh.compute_vertex_normals().vertex_normals)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(wv.astype(np.float32)), o3d.core.Tensor(world.triangles.astype(np.uint32)))
    cp = scene.compute_closest_points(o3d.core.Tensor(np.asarray(v, np.float32)))
    tri = world.triangles[cp["primitive_ids"].numpy().astype(np.int64)]
    uv = cp["primitive_uvs"].numpy().astype(np.float64)
    n = (1 - uv[:, :1] - uv[:, 1:]) * wn[tri[:, 0]] + uv[:, :1] * wn[tri[:, 1]] + uv[:, 1:] * wn[tri[:, 2]]
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def normals_case(work: Path) -> dict[str, Any]:
    """Each true region of the ``session`` case fitted with the scanned mesh's normals and with the true ones.

    What the fit can do when the geometry is right, and how far the scanned normals are off.
    """
    import dataclasses

    from app.demo.object import true_face_materials
    from app.session import Session
    from app.workflows.object_materials import _forward_model, _held_out, _load_inputs, _reference_distance
    from mocks.world import World
    from processing.appearance.observations import select_frames
    from processing.appearance.shading_normals import SMOOTHING_CELLS, smoothed_normals
    from processing.materials.forward_fit import fit_region, region_samples

    summary = json.loads((work / "summary.json").read_text())
    truth, session = summary["simulation_truth"], Path(summary["session"])
    data = _load_inputs(session, Session.read(session))
    v, t, n = data["mesh"]
    world = World.hawk(int(truth.get("triangles", 20_000)))
    pose = np.asarray({str(k): p for k, p in truth["poses"].items()}["1"])
    faces = np.asarray(true_face_materials(v, t, world, pose))
    names = sorted(set(faces.tolist()))
    votes = np.zeros((len(v), len(names)))
    np.add.at(votes, (t.ravel(), np.repeat([names.index(f) for f in faces], 3)), 1.0)
    vertex_truth = np.argmax(votes, axis=1)
    true_n = _true_normals(v, world, pose)
    error = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", true_n, n), -1.0, 1.0)))
    shading = smoothed_normals(v, t, n, SMOOTHING_CELLS * data["cell_mm"])
    shading_error = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", true_n, shading), -1.0, 1.0)))
    obs = select_frames(data["obs"], ~_held_out(data["obs"].frame_names, data["records"], 4))
    model, _ = _forward_model(data["spectrum"], lambda text: None)
    d_ref = _reference_distance(data)
    rows = []
    variants = [("scanned", obs, t), ("shading", dataclasses.replace(obs, normal=shading[obs.vertex].astype(np.float32)), t)]
    refined_error = None
    mesh_file = session / "products/object-mesh.ply"
    if mesh_file.exists():                  # the session case's products: the normals the photos refined
        from render.material_mesh import read_material_mesh

        rn = read_material_mesh(mesh_file).normals
        if rn.shape == v.shape:
            e = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", true_n, rn), -1.0, 1.0)))
            moved = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", n, rn), -1.0, 1.0))) > 1e-3
            refined_error = {"median": float(np.median(e)), "p90": float(np.percentile(e, 90)),
                             "moved_share": float(moved.mean()),
                             "moved_median_before": float(np.median(error[moved])) if moved.any() else None,
                             "moved_median_after": float(np.median(e[moved])) if moved.any() else None}
            variants.append(("refined", dataclasses.replace(obs, normal=rn[obs.vertex].astype(np.float32)), t))
    variants.append(("true", dataclasses.replace(obs, normal=true_n[obs.vertex].astype(np.float32)), None))
    for label, o, tri in variants:
        for k, name in enumerate(names):
            ids = np.flatnonzero(vertex_truth == k)
            fit = fit_region(region_samples(o, v, data["frames"], ids, triangles=tri, reference_mm=d_ref), model)
            rows.append({"normals": label, "truth": name, "answer": fit.material, "confidence": fit.confidence,
                         "group": list(fit.group), "parameters": fit.parameters, "misfit": fit.chi2_per_dof})
    return {"normal_error_deg": {"median": float(np.median(error)), "p90": float(np.percentile(error, 90))},
            "shading_error_deg": {"median": float(np.median(shading_error)),
                                  "p90": float(np.percentile(shading_error, 90)),
                                  "smoothing_mm": SMOOTHING_CELLS * data["cell_mm"]},
            "refined_error_deg": refined_error, "rows": rows}


def session_case(work: Path, normals: str = "mesh", holdout_burst: int = 1, station_seed: int = 1) -> dict[str, Any]:
    """The demo chain once into ``work``, then the materials on the mesh timed and checked.

    ``normals="photometric"``: with the normals refined by the photos (the ``normals`` case then
    reads them from the products).  ``holdout_burst``: frames shot at each held-out table angle
    (the capture plan's option; give the burst a ``work`` of its own).  ``station_seed``: the
    simulated station's seed (1: the demo's capture; give another a ``work`` of its own).
    """
    from app.demo.capture import simulated_capture
    from app.workflows.object_materials import measure_object

    summary_path = work / "summary.json"
    if summary_path.exists():
        summary = json.loads(summary_path.read_text())
    else:
        summary = simulated_capture(work, holdout_burst=holdout_burst, seed=station_seed)
        summary_path.write_text(json.dumps(summary, indent=1, default=str))
    session = Path(summary["session"])
    load = [round(x, 1) for x in os.getloadavg()]
    t0, c0 = time.perf_counter(), time.process_time()
    doc = measure_object(session, validate=False, normals=normals)
    t_fit, c_fit = time.perf_counter() - t0, time.process_time() - c0
    load += [round(x, 1) for x in os.getloadavg()]
    t0, c0 = time.perf_counter(), time.process_time()
    doc = measure_object(session, normals=normals)
    t_all, c_all = time.perf_counter() - t0, time.process_time() - c0
    val = doc.get("validation") or {}
    return {"fit_s": round(t_fit, 2), "fit_cpu_s": round(c_fit, 2), "with_validation_s": round(t_all, 2),
            "with_validation_cpu_s": round(c_all, 2), "load_average": [min(load), max(load)],
            "timings_s": doc.get("timings_s"),
            "regions": [{k: r.get(k) for k in ("index", "material", "confidence", "group", "parameters",
                                               "uncertainties", "area_mm2", "n_lit", "n_observations",
                                               "chi2_per_dof", "pieces_tested", "pieces_disagreeing",
                                               "disagreeing_area_mm2")} for r in doc["regions"]],
            "joined": (doc.get("segmentation") or {}).get("joined"),
            "agreement": _agreement(session, doc, summary["simulation_truth"]),
            "validation": {k: val.get(k) for k in ("mean_de2000", "p95_de2000", "baseline_mean_de2000",
                                                   "baseline_p95_de2000", "noise_floor_mean_de2000", "n_frames",
                                                   "pixels", "pooled", "frames_averaged")},
            "capture_stages_s": summary.get("stages_s"), "captures_taken": summary.get("captures_taken"),
            "passes": summary.get("passes"),
            "normals": doc.get("normals"), "baseline": doc.get("baseline"), "frames": {k: len(v) for k, v in doc["frames"].items()},
            "not_measured_mm2": (doc.get("not_measured") or {}).get("area_mm2"),
            "peak_rss_mb": round(_peak_mb(), 1)}


def captures_case(work: Path, station_seeds: tuple[int, ...] = (1, 2, 3),
                  measured: dict[int, dict[str, Any]] | None = None) -> dict[str, Any]:
    """The ``session`` case per station seed, in ``work/seed-N`` (seed 1, the demo's, in ``work`` as the
    ``session`` case): the figures that move with the capture.  ``measured``: results of the ``session``
    case already at hand, by station seed (not measured again)."""
    rows = []
    for seed in station_seeds:
        s = (measured or {}).get(seed) or session_case(work if seed == 1 else work / f"seed-{seed}",
                                                        station_seed=seed)
        a, v = s["agreement"], s["validation"]
        rows.append({"station_seed": seed, "share_right": a["share_right"], "per_true_material": a["per_true_material"],
                     "head": a["head"], "confident_wrong": a.get("confident_wrong", []),
                     "regions": [{k: r.get(k) for k in ("material", "confidence", "area_mm2", "parameters")}
                                 for r in s["regions"]],
                     "not_measured_mm2": s.get("not_measured_mm2"), "mean_de2000": v.get("mean_de2000"),
                     "baseline_mean_de2000": v.get("baseline_mean_de2000"),
                     "pooled": v.get("pooled"), "fit_s": s["fit_s"]})
    return {"rows": rows}


def _captures_lines(c: dict[str, Any] | None) -> list[str]:
    if not c:
        return []
    lines = ["", "Per capture (`bench/object_bench.py`, case `captures`; station seed 1 is the demo's):", "",
             "| station seed | share right | per true material | head: answer (Ag, roughness) | not measured (mm2) | "
             "held-out mean dE00: measured / one material | 4 x 4 blocks |", "|---:|---:|---|---|---:|---|---|"]
    for r in c["rows"]:
        h, pooled = r["head"], r.get("pooled") or {}
        per = ", ".join(f"{k} {100 * x:.0f} %" for k, x in r["per_true_material"].items())
        ag, rough = (f"{x:.3f}" if x is not None else "-" for x in (h["Ag"], h["roughness"]))
        lines.append(f"| {r['station_seed']} | {100 * r['share_right']:.2f} % | {per} | {h['material']} "
                     f"{h['confidence'] or 0:.2f} ({ag}, {rough}) | {r['not_measured_mm2'] or 0:.0f} | "
                     f"{r['mean_de2000']:.2f} / {r['baseline_mean_de2000']:.2f} | "
                     f"{pooled.get('mean_de2000', float('nan')):.2f} / {pooled.get('baseline_mean_de2000', float('nan')):.2f} |")
    return lines


def floor_case(work: Path) -> dict[str, Any]:
    """The held-out comparison with the simulation's true materials on the scanned mesh: the best any fit can do.

    Rendered at the shading normals the fit uses and at the simulated object's own normals, with the
    noise floor (the true-material rendering against itself plus the sensor's noise).
    """
    from app.demo.object import true_face_materials
    from app.session import Session
    from app.workflows.holdout_validation import validate_frames
    from app.workflows.object_materials import _GRID, _clip_level, _held_out, _load_inputs, _reference_distance
    from app.workflows.posed_frames import calibrated_images, noise_model
    from mocks.world import World
    from processing.appearance.shading_normals import SMOOTHING_CELLS, smoothed_normals
    from processing.camera.response import camera_sensitivities
    from processing.spectral.spectra import SpectralGrid, light_spectrum

    summary = json.loads((work / "summary.json").read_text())
    truth, root = summary["simulation_truth"], Path(summary["session"])
    data = _load_inputs(root, Session.read(root))
    v, t, n = data["mesh"]
    world = World.hawk(int(truth.get("triangles", 20_000)))
    pose = np.asarray({str(k): p for k, p in truth["poses"].items()}["1"])
    faces = true_face_materials(v, t, world, pose)
    names = sorted(set(faces))
    face_region = np.array([names.index(f) for f in faces])
    held = _held_out(data["obs"].frame_names, data["records"], 4)
    frames = [f for f, h in zip(data["frames"], held) if h]
    records = [(nm, r) for nm, r, h in zip(data["obs"].frame_names, data["records"], held) if h]
    photos = calibrated_images(root, Session.read(root), records, "demosaic")
    grid = SpectralGrid(*_GRID)
    spectrum = data["spectrum"] if data["spectrum"] is not None else "D65"
    head = max(set(faces), key=faces.count)
    out = {}
    for label, normals in (("shading", smoothed_normals(v, t, n, SMOOTHING_CELLS * data["cell_mm"])),
                           ("true", _true_normals(v, world, pose))):
        res = validate_frames(frames, photos, v, t, normals, face_region, names, head,
                              light_spectrum(spectrum, grid), camera_sensitivities(grid), 1.0,
                              irradiance_ref_mm=_reference_distance(data), grid=grid, clip_level=_clip_level(photos),
                              images=False, noise=noise_model(records, photos.gains))
        o = res["overall"]
        out[label] = {"mean_de2000": o["measured"]["mean_de2000"], "p95_de2000": o["measured"]["p95_de2000"],
                      "baseline_mean_de2000": o["baseline"]["mean_de2000"],
                      "noise_floor_mean_de2000": o["noise_floor"]["mean_de2000"]}
    return out


def heldout_case(work: Path) -> dict[str, Any]:
    """Where the held-out-photo error comes from (:mod:`bench.holdout_decomposition`), after ``session``.

    Writes its figures to ``docs/images/heldout-*.png``.
    """
    from bench.common import ROOT
    from bench.holdout_decomposition import decomposition

    return decomposition(work, ROOT / "docs" / "images")


def large_case(triangles: int = 1_000_000) -> dict[str, Any]:
    """The product's whole fitting step on a ~1M-triangle hawk seen in 24 frames (every 15 degrees, 960 x 640).

    Segmentation, per-region fits, the pieces joined, the relabelling, the pieces no region explains and
    the piece checks (``app.workflows.object_materials._fit`` with the mesh's normals, as ``kogei
    fit-materials`` by default), no frame held out.  Peak memory: the whole process (``peak_rss_mb``,
    the simulation included) and from the fitting step's start (``fit_peak_rss_mb``: the high-water mark
    reset through ``/proc/self/clear_refs``; the process's when the kernel does not allow it).
    """
    import open3d as o3d

    from app.workflows.object_materials import FIT_MODEL_ERROR, _fit
    from bench.common import peak_rss_mb
    from mocks.observation_sim import simulated_observations
    from mocks.world import World

    t0 = time.perf_counter()
    sim = simulated_observations(World.hawk(triangles, width=960, height=640), np.arange(0.0, 360.0, 15.0))
    t_sim = time.perf_counter() - t0
    peak_all = peak_rss_mb()
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(sim.vertices),
                                     o3d.utility.Vector3iVector(sim.triangles))
    mesh.compute_vertex_normals()
    data = {"obs": sim.observations, "frames": list(sim.frames), "spectrum": "D65", "cell_mm": None,
            "mesh": (sim.vertices, sim.triangles, np.asarray(mesh.vertex_normals))}
    try:
        with open("/proc/self/clear_refs", "w", encoding="ascii") as fh:
            fh.write("5")                               # reset the high-water mark
    except OSError:
        pass
    t0, c0 = time.perf_counter(), time.process_time()
    doc = _fit(data, np.zeros(len(sim.frames), dtype=bool), FIT_MODEL_ERROR, 8, lambda _: None, lambda: False,
               refine=False)
    t_fit, c_fit = time.perf_counter() - t0, time.process_time() - c0
    timings = doc["timings_s"]
    return {"triangles": int(len(sim.triangles)), "vertices": int(len(sim.vertices)), "frames": 24,
            "observations": int(len(sim.observations)),
            "simulate_s": round(t_sim, 1), "segmentation_s": round(timings["segmentation"], 2),
            "fit_s": round(t_fit - timings["segmentation"], 2), "step_s": round(t_fit, 2), "step_cpu_s": round(c_fit, 1),
            "timings_s": timings, "split": doc["segmentation"]["split"],
            "regions": [f"{r['material']} {r['confidence']:.2f}" for r in doc["regions"]],
            "fit_peak_rss_mb": round(peak_rss_mb(), 1), "peak_rss_mb": round(max(peak_all, peak_rss_mb()), 1)}


def reliability_case(out: Path | None = None) -> dict[str, Any]:
    """On-mesh and single-image confidence calibration; the on-mesh table for the session report."""
    from bench.reliability import highlight_reliability, single_image_reliability
    from bench.surface_fit_bench import calibration_case

    t0 = time.perf_counter()
    mesh = calibration_case()
    t_mesh = time.perf_counter() - t0
    single = single_image_reliability(n_regions=4000, seed=0)
    patches = highlight_reliability(n_patches=3000, seed=1)
    blind = highlight_reliability(n_patches=3000, seed=1, fringe=False)
    if out is not None:
        out.write_text(json.dumps(_on_mesh_table(mesh), indent=1) + "\n")
    return {"on_mesh": mesh, "on_mesh_s": round(t_mesh, 1), "single_image": single, "highlights": patches,
            "highlights_no_fringe": blind}


def _on_mesh_table(mesh: dict[str, Any]) -> dict[str, Any]:
    """The on-mesh reliability table in the report's form (``stated``, ``observed``, ``count``, ``ece``)."""
    bins = mesh["bins"]
    return {"edges": [round(0.1 * i, 1) for i in range(len(bins["count"]) + 1)], "count": bins["count"],
            "stated": bins["stated"], "observed": bins["observed"], "ece": mesh["ece"],
            "high_accuracy": mesh["high_accuracy"], "high_count": mesh["high_count"],
            "source": f"{mesh['regions']} simulated regions of bench.surface_fit_bench"}


def trade_case(work: Path) -> dict[str, Any]:
    """Frames used, observations per vertex and candidate set against time and agreement."""
    from app.session import Session
    from app.workflows.object_materials import _fit, _held_out, _load_inputs

    summary = json.loads((work / "summary.json").read_text())
    session = Path(summary["session"])
    data = _load_inputs(session, Session.read(session))
    held = _held_out(data["obs"].frame_names, data["records"], 4)
    rows = []
    variants = {"all fitted frames, normals refined": (held, True),
                "every 2nd fitted angle, normals refined": (_every_second(data, held), True),
                "all fitted frames, the mesh's normals (the default)": (held, False)}
    for name, (mask, refine) in variants.items():
        t0 = time.perf_counter()
        doc = _fit(data, mask, 0.02, 8, lambda text: None, lambda: False, refine=refine)
        secs = time.perf_counter() - t0
        doc.pop("_face_region"), doc.pop("_normals")
        rows.append({"variant": name, "frames": int((~mask).sum()), "seconds": round(secs, 2),
                     "materials": [r["material"] for r in doc["regions"]]})
    return {"rows": rows}


def _every_second(data: dict[str, Any], held: np.ndarray) -> np.ndarray:
    angles = np.array([float(r.get("angle_deg") or 0.0) for r in data["records"]])
    fitted = np.unique(np.round(angles[~held], 2))
    drop = set(fitted[1::2].tolist())
    return held | np.array([round(a, 2) in drop for a in angles])


def section(results: dict[str, Any]) -> list[str]:
    """The Markdown of docs/BENCHMARKS.md's "Materials on the mesh" section."""
    from app.workflows.object_materials import answer_text

    s, lines = results["session"], ["## Materials on the mesh", ""]
    a, v, h = s["agreement"], s["validation"], s["agreement"]["head"]
    lines += [
        f"The demo's simulated hawk session ({s['passes']} placements x 12 table angles, one distant lamp, every",
        "photo posed with the calibrated camera and lamp; `bench/object_bench.py`, case `session`): the",
        "materials on the mesh against the simulation's truth per face, the held-out photos (every 4th",
        "table angle, never fitted) against renders of the measured materials and of the paper's",
        "one-material baseline (the largest region's material on the whole object).  "
        f"Measured {time.strftime('%Y-%m-%d')}.",
        "",
        "| figure | measured | target |",
        "|---|---:|---:|",
        f"| area-weighted share of the mesh with the right material | {100 * a['share_right']:.1f} % | >= 95 % |",
        f"| head (nami-shibuichi): answer | {_head_answer(s, h, answer_text)} | nami-shibuichi |",
        f"| head: Ag share error | {h['Ag_error_pts']} points | within +-3 points |",
        f"| head: roughness error | {100 * (h['roughness_error_rel'] or float('nan')):.1f} % | within 10 % |",
        f"| held-out photos: mean / p95 CIEDE2000, measured materials | {v['mean_de2000']:.2f} / "
        f"{v['p95_de2000']:.2f} | mean <= 2.0 |",
        f"| held-out photos: mean / p95 CIEDE2000, one material ({s['baseline']['material']}) | "
        f"{v['baseline_mean_de2000']:.2f} / {v['baseline_p95_de2000']:.2f} | |",
        f"| baseline / measured mean CIEDE2000 | {v['baseline_mean_de2000'] / v['mean_de2000']:.2f} | >= 3 |",
        *_floor_rows(results.get("floor"), v),
        f"| segmentation + fit, demo session: wall (CPU), load average {_load_text(s)} | {s['fit_s']:.1f} s "
        f"({s.get('fit_cpu_s', float('nan')):.1f} s) | <= 60 s |",
        f"| with the validation renders: wall (CPU) | {s['with_validation_s']:.1f} s "
        f"({s.get('with_validation_cpu_s', float('nan')):.1f} s) | |",
        "",
        "Per true material, share of its area with the right answer: "
        + ", ".join(f"{k} {100 * x:.0f} %" for k, x in a["per_true_material"].items()) + ".  Regions named "
        "with a confidence >= 0.9 whose largest true material is not the answer (target: none): "
        + (", ".join(str(i) for i in a.get("confident_wrong", [])) or "none") + "." + _joined_text(s),
        "",
        "| region | answer | largest true material | parameters of the best candidate | area (mm2) | "
        "lit / all observations |",
        "|---:|---|---|---|---:|---|",
    ]
    major = {x["index"]: x["majority_truth"] for x in a.get("regions", [])}
    for r in s["regions"]:
        p = ", ".join(f"{k} {x:.3g}" for k, x in (r.get("parameters") or {}).items())
        lines.append(f"| {r['index']} | {answer_text(r)} | {major.get(r['index'], '-')} | {p} | "
                     f"{r['area_mm2']:.0f} | {r['n_lit']} / {r['n_observations']} |")
    lines += _captures_lines(results.get("captures"))
    lines += _heldout_lines(results.get("heldout"), v)
    lines += _photometric_lines(results.get("photometric"), answer_text)
    lines += _normals_lines(results.get("normals"), answer_text)
    big = results.get("large")
    if big:
        step = (f"the whole fitting step {big['step_s']:.1f} s (segmentation {big['segmentation_s']:.1f} s, the "
                f"rest {big['fit_s']:.1f} s)" if "step_s" in big else
                f"segmentation {big['segmentation_s']:.1f} s, fit {big['fit_s']:.1f} s")
        peak = (f"peak RSS from the step's start {big['fit_peak_rss_mb']:.0f} MB, of the process with the "
                f"simulation {big['peak_rss_mb']:.0f} MB" if "fit_peak_rss_mb" in big else
                f"peak RSS {big['peak_rss_mb']:.0f} MB")
        lines += ["", f"Large: the hawk at {big['triangles']:,} triangles, 24 table angles at 960 x 640 "
                      f"({big['observations']:,} observations): {step} (target: <= 5 min with 24 frames), "
                      f"{peak} (target <= 4 GB)."]
    trade = results.get("trade")
    if trade:
        lines += ["", "| trade | frames fitted | seconds | answers |", "|---|---:|---:|---|"]
        lines += [f"| {r['variant']} | {r['frames']} | {r['seconds']:.1f} | {', '.join(r['materials'])} |"
                  for r in trade["rows"]]
    rel = results.get("reliability")
    if rel:
        lines += ["", "### Material confidence", ""] + _reliability_lines(rel)
    return lines + [""]


def _load_text(s: dict[str, Any]) -> str:
    lo, hi = s.get("load_average") or (float("nan"), float("nan"))
    return f"{lo:.1f}-{hi:.1f}"


def _joined_text(s: dict[str, Any]) -> str:
    """The sentence on the pieces that joined the largest region and the time of the piece tests."""
    j, secs = s.get("joined") or {}, (s.get("timings_s") or {}).get("pieces")
    if not j:
        return ""
    return (f"  Pieces of smaller regions that joined the largest (region {j.get('target')}): {j.get('pieces')} "
            f"({j.get('area_mm2', 0):.0f} mm2, from regions {', '.join(str(r) for r in j.get('from_regions', []))})"
            + ("" if secs is None else f"; joining and checking the pieces took {secs:.1f} s of the fit") + ".")


def _floor_rows(f: dict[str, Any] | None, v: dict[str, Any]) -> list[str]:
    """Rows of the ``floor`` case: what the simulation's true materials score on the same comparison."""
    rows = []
    if v.get("noise_floor_mean_de2000") is not None:
        rows.append(f"| noise floor: the measured rendering against itself with the sensor's noise (drawn on the "
                    f"mosaic, demosaicked) | {v['noise_floor_mean_de2000']:.2f} | |")
    pooled = v.get("pooled") or {}
    if pooled.get("mean_de2000") is not None:
        b = pooled["block_px"]
        rows += [f"| held-out photos in {b} x {b} px blocks: mean / p95 CIEDE2000, measured materials | "
                 f"{pooled['mean_de2000']:.2f} / {pooled['p95_de2000']:.2f} | mean <= 2.0 |",
                 f"| the same, one material; noise floor | {pooled['baseline_mean_de2000']:.2f} / "
                 f"{pooled['baseline_p95_de2000']:.2f}; {pooled['noise_floor_mean_de2000']:.2f} | |",
                 f"| baseline / measured mean CIEDE2000 in {b} x {b} px blocks | "
                 f"{pooled['baseline_mean_de2000'] / pooled['mean_de2000']:.2f} | >= 3 |"]
    if f:
        rows += [f"| the simulation's true materials on the scanned mesh, shading normals: mean CIEDE2000 "
                 f"(one material: {f['shading']['baseline_mean_de2000']:.2f}) | {f['shading']['mean_de2000']:.2f} | |",
                 f"| the same at the simulated object's own normals (one material: "
                 f"{f['true']['baseline_mean_de2000']:.2f}) | {f['true']['mean_de2000']:.2f} | |"]
    return rows


def _heldout_lines(h: dict[str, Any] | None, v: dict[str, Any]) -> list[str]:
    """The ``heldout`` case: the held-out comparison per pixel and pooled, one frame and bursts, step by step."""
    if not h:
        return []
    t, n = h["table"], h["burst"]
    photos = ["single frame", f"burst of {n // 4}", f"burst of {n}", "noiseless"]
    rungs = [("measured materials", "measured materials (the product)"),
             ("one material (baseline)", "one material for the whole object (the paper's baseline)"),
             ("true materials, scanned mesh", "true materials, scanned mesh and its shading normals"),
             ("true materials, scanned mesh, true normals", "true materials, scanned mesh, the true object's normals"),
             ("true object, estimated pose", "true object (mesh, normals, materials), the estimated frame pose"),
             ("true object, true pose", "true object, true camera, lamp and placement")]
    head = "| rendering | " + " | ".join(f"{p}, {s} px" for s in (1, 4) for p in photos[:3]) + " | noiseless, 1 px |"
    lines = ["", f"Where the held-out error comes from (case `heldout`, `bench/holdout_decomposition.py`; "
                 f"{h['frames']} held-out frames, each re-shot by the simulated camera: one new frame, bursts "
                 f"of {n // 4} and {n} frames with independent noise averaged in linear RAW, the noiseless photo; "
                 "one pixel set per frame from the truth and the photos; docs/validation.md).  Mean CIEDE2000:", "",
             head, "|---|" + "---:|" * 7]
    for key, label in rungs:
        cells = [t[f"{key} | {p} | {s}"]["mean"] for s in (1, 4) for p in photos[:3]] + \
            [t[f"{key} | noiseless | 1"]["mean"]]
        lines.append(f"| {label} | " + " | ".join(f"{c:.2f}" for c in cells) + " |")
    mf = h["model_floor"]
    lines.append("| noise floor, the model's (noise on the mosaic, demosaicked) | "
                 + " | ".join(f"{mf[f'RGGB | {nf} | {s}']['mean']:.2f}" for s in (1, 4) for nf in (1, n // 4, n))
                 + " | 0 |")
    lines.append("| noise floor, real (the photo against its own noiseless photo) | "
                 + " | ".join(f"{t[f'noiseless photo | {p} | {s}']['mean']:.2f}" for s in (1, 4)
                              for p in photos[:3]) + " | 0 |")
    c1, cn = h["categories"]["measured materials | single frame"], h["categories"][f"measured materials | burst of {n}"]
    lines += ["", "Per pixel category (from the truth), measured materials: share of the pixels, mean CIEDE2000 "
                  f"one frame / {n} frames, share of the summed error one frame / {n} frames: "
              + "; ".join(f"{k} {100 * c1[k]['share_pixels']:.0f} %, {c1[k]['mean_de2000']:.2f} / "
                          f"{cn[k]['mean_de2000']:.2f}, {100 * c1[k]['share_of_error']:.0f} / "
                          f"{100 * cn[k]['share_of_error']:.0f} %" for k in c1) + ".",
              f"Re-shooting check: the measured materials against the session's own photos "
              f"{t['measured materials | session photo | 1']['mean']:.2f}, against a new frame "
              f"{t['measured materials | single frame | 1']['mean']:.2f}.  Cost: {h['per_frame_shot_s']:.2f} s "
              "per simulated frame (simulate, write the DNG, decode), besides its spectral render."]
    return lines


def _photometric_lines(p: dict[str, Any] | None, answer_text: Any) -> list[str]:
    """The ``photometric`` case: the session with the normals refined by the photos."""
    if not p:
        return []
    a, v, h, nd = p["agreement"], p["validation"], p["agreement"]["head"], p.get("normals") or {}
    lines = ["", "With the normals refined by the photos (`measure_object(..., normals=\"photometric\")`, "
                 f"experimental; {100 * nd.get('decided_share', 0):.0f} % of the vertices decided by their "
                 f"highlights, median tilt {nd.get('median_tilt_deg', 0):.1f} deg, refinement "
                 f"{nd.get('seconds', 0):.1f} s):", "",
             "| figure | measured | target |", "|---|---:|---:|",
             f"| area-weighted share of the mesh with the right material | {100 * a['share_right']:.1f} % | >= 95 % |",
             f"| head: answer | {_head_answer(p, h, answer_text)} | nami-shibuichi |",
             f"| head: Ag share error / roughness error | {h['Ag_error_pts']} points / "
             f"{100 * (h['roughness_error_rel'] or float('nan')):.1f} % | +-3 points / 10 % |",
             f"| held-out photos: mean / p95 CIEDE2000, measured / one material | {v['mean_de2000']:.2f} / "
             f"{v['p95_de2000']:.2f}, {v['baseline_mean_de2000']:.2f} / {v['baseline_p95_de2000']:.2f} | mean <= 2.0 |",
             f"| segmentation + fit + refinement + fit again | {p['fit_s']:.1f} s | <= 60 s |", "",
             "| region | answer | parameters of the best candidate | area (mm2) |", "|---:|---|---|---:|"]
    for r in p["regions"]:
        par = ", ".join(f"{k} {x:.3g}" for k, x in (r.get("parameters") or {}).items())
        lines.append(f"| {r['index']} | {answer_text(r)} | {par} | {r['area_mm2']:.0f} |")
    return lines


def _normals_lines(nc: dict[str, Any] | None, answer_text: Any) -> list[str]:
    """The ``normals`` case: each true region with the scanned and with the true normals."""
    if not nc:
        return []
    e = nc["normal_error_deg"]
    r = nc.get("refined_error_deg")
    refined = "" if not r else (
        f"  Refined by the photos (`measure_object(..., normals=\"photometric\")`, experimental), they are a median "
        f"{r['median']:.1f} deg (p90 {r['p90']:.1f} deg) off; on the {100 * r['moved_share']:.0f} % of the "
        f"vertices the refinement moved, {r['moved_median_before']:.1f} deg before and "
        f"{r['moved_median_after']:.1f} deg after.")
    sh = nc.get("shading_error_deg")
    shading = "" if not sh else (
        f"  The shading normals the fit uses (smoothed over {sh['smoothing_mm']:.2f} mm, two cells of the "
        f"reconstruction) are a median {sh['median']:.1f} deg (p90 {sh['p90']:.1f} deg) off.")
    lines = ["", f"The normals (case `normals`): the scanned mesh's vertex normals are a median {e['median']:.1f} deg "
                 f"(p90 {e['p90']:.1f} deg) off the simulated object's.{shading}{refined}  Each true region fitted "
                 "to the same observations with the mesh's, the shading, the refined and the true normals:", "",
             "| true material | normals | answer | reduced chi-square | parameters |", "|---|---|---|---:|---|"]
    for r in nc["rows"]:
        p = ", ".join(f"{k} {x:.3g}" for k, x in (r.get("parameters") or {}).items())
        text = answer_text({"material": r["answer"], "confidence": r["confidence"], "group": r["group"],
                            "chi2_per_dof": r["misfit"]})
        lines.append(f"| {r['truth']} | {r['normals']} | {text} | {r['misfit']:.2f} | {p} |")
    return lines


def _head_answer(s: dict[str, Any], head: dict[str, Any], answer_text: Any) -> str:
    reg = next((r for r in s["regions"] if r.get("material") == head["material"]
                and r.get("confidence") == head["confidence"]), None)
    return answer_text(reg) if reg else str(head["material"])


def _reliability_lines(rel: dict[str, Any]) -> list[str]:
    out = []
    tables = [("On the mesh (simulated regions, `bench/surface_fit_bench.py`)", _on_mesh_table(rel["on_mesh"])),
              ("One image (`bench/reliability.py`)", {**rel["single_image"]["table"],
                                                       **{k: rel["single_image"][k] for k in
                                                          ("ece", "high_accuracy", "high_count")}})]
    if rel.get("highlights"):
        h = rel["highlights"]
        tables.append(("One image, clicked patches through a Bayer sensor and the bin2x2 decode "
                       "(`bench/reliability.py`, `highlight_reliability`)",
                       {**h["table"], **{k: h[k] for k in ("ece", "high_accuracy", "high_count")}}))
    for title, table in tables:
        out += [f"{title}: ECE {table['ece']:.3f} (target <= 0.05); right among answers stated >= 0.9: "
                f"{100 * table['high_accuracy']:.1f} % of {table['high_count']} (target >= 90 %).", "",
                "| stated | answers | mean stated | share right |", "|---|---:|---:|---:|"]
        edges = table["edges"]
        for i, n in enumerate(table["count"]):
            if n:
                out.append(f"| {edges[i]:.1f}-{edges[i + 1]:.1f} | {n} | {table['stated'][i]:.3f} | "
                           f"{table['observed'][i]:.3f} |")
        out.append("")
    h, b = rel.get("highlights"), rel.get("highlights_no_fringe")
    if h and b:
        out += [f"Clicked patches: {h['regions']} judged ({h['refused']} refused: too dark or fringe only), "
                f"{h['abstained']} 'no candidate fits'; stated >= 0.9 and wrong: {len(h['high_wrong'])}. "
                f"The same patches without the fringe term: ECE {b['ece']:.3f}, right among >= 0.9 "
                f"{100 * b['high_accuracy']:.1f} % of {b['high_count']} ({len(b['high_wrong'])} wrong).", ""]
        if h["high_wrong"]:
            out += ["Stated >= 0.9 and wrong (truth -> answer, lighting, pixels): " + "; ".join(
                f"{w['truth']} -> {w['answer']} ({w['shape']}, {w['pixels']})" for w in h["high_wrong"]) + ".", ""]
    m = rel["on_mesh"]
    out += [f"On the mesh, {m['no_fit']} of {m['regions']} regions answered \"no candidate fits\" (abstentions); "
            f"all answers right {100 * m['accuracy']:.1f} %; the nami-shibuichi Ag share's median error "
            f"{100 * m['nami_shibuichi_ag_abs_err_median']:.1f} points.", ""]
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", required=True, choices=["session", "captures", "photometric", "normals", "floor", "heldout",
                                                      "large", "trade", "reliability", "all"])
    ap.add_argument("--work", default="out/bench-object")
    ap.add_argument("--holdout-burst", type=int, default=1, metavar="N",
                    help="session case: frames shot at each held-out table angle (use its own --work)")
    ap.add_argument("--station-seeds", default="1,2,3", metavar="N,N,...",
                    help="captures case: the simulated station's seeds (1: the demo's capture)")
    args = ap.parse_args(argv)
    try:
        seeds = tuple(int(x) for x in args.station_seeds.split(","))
    except ValueError:
        ap.error(f"--station-seeds: give whole numbers separated by commas, got {args.station_seeds!r}")
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    if args.case == "all":
        from bench.common import ROOT, run_case_subprocess

        demo = session_case(work)
        out = {"session": demo, "captures": captures_case(work, seeds, measured={1: demo}),
               "photometric": session_case(work, "photometric"),
               "normals": normals_case(work), "floor": floor_case(work), "heldout": heldout_case(work),
               "trade": trade_case(work),
               "large": run_case_subprocess("bench.object_bench", "large"),   # its own peak memory, not the cases' before it
               "reliability": reliability_case(ROOT / "app" / "report" / "reliability.json")}
    elif args.case == "session":
        out = session_case(work, holdout_burst=args.holdout_burst)
    elif args.case == "captures":
        out = captures_case(work, seeds)
    elif args.case == "photometric":
        out = session_case(work, "photometric")
    elif args.case == "normals":
        out = normals_case(work)
    elif args.case == "floor":
        out = floor_case(work)
    elif args.case == "heldout":
        out = heldout_case(work)
    elif args.case == "trade":
        out = trade_case(work)
    elif args.case == "large":
        out = large_case()
    else:
        out = reliability_case()
    print(json.dumps(out, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
