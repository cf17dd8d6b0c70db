"""Where the held-out-photo error comes from: sensor noise, geometry, pose, exposure, materials.

On the demo's simulated hawk session (``bench.object_bench``, cases ``session`` then ``heldout``),
every held-out frame is re-shot by the simulated camera with the truth the simulation knows:

* the session's own photo, and one new frame (the same camera, decoder and chart gains, new noise:
  its figures must match the session photo's, which checks the re-shooting);
* a **burst** of ``N`` frames at the same table angle, each with its own sensor noise (the first is
  the session's photo, the others new seeds), written as DNG, decoded (bilinear demosaic) and
  averaged in linear camera RGB -- what a capture plan shooting ``N`` frames per held-out angle gives;
* the **noiseless** photo: the expected photosite values (mean electrons, no shot or read noise)
  through the same demosaic and chart gains.

and rendered (:func:`render.photo_signal.render_signal`, chart-calibrated exposure ``1``) six ways:
the measured materials on the scanned mesh (the product), the one-material baseline, the true
materials on the scanned mesh with its shading normals and with the true object's normals, the true
object (its own mesh and materials) at the session's estimated frame pose, and the true object at
the true camera, lamp and pose.  Each rendering is compared with each photo per pixel and pooled in
``2 x 2`` and ``4 x 4`` blocks, over one set of pixels per frame defined from the truth and the
photo: the true object's silhouette and the scanned mesh's, both eroded by 2 px, less pixels a photo
clipped.  Each compared pixel is put in one category, from the truth: the silhouette band (within
4 px of the true outline), highlight (noiseless luminance >= 0.25 of the white diffuser's), shadow
(no direct light on the true object), dark metal (noiseless luminance < 0.03), the rest.

``python -m bench.object_bench --case heldout --work DIR`` (after the ``session`` case).
"""

from __future__ import annotations

import dataclasses
import json
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["decomposition", "BURST", "POOLS", "CATEGORIES"]

#: Burst length of the held-out angles (frames averaged), and the shorter burst also reported.
BURST = 16
#: Spatial scales compared (block side, pixels).
POOLS = (1, 2, 4)
#: Pixel categories, in the order a pixel is assigned to them.
CATEGORIES = ("silhouette band", "highlight", "shadow", "dark metal", "rest")
_BAND_PX, _HIGHLIGHT_Y, _DARK_Y = 4, 0.25, 0.03


def _truth_world(work: Path) -> Any:
    """The simulated station's hawk (its camera configuration: mesh, materials, camera, lamp)."""
    from mocks.fake_gphoto2 import _world, read_config

    path = work / "station" / "camera.json"
    return _world(read_config(path)["world"], path)


def _shots(world: Any, rec: dict[str, Any], pose: np.ndarray, gains: np.ndarray, n: int, root: Path,
           exposure_s: float, tmp: Path) -> tuple[list[np.ndarray], np.ndarray, int]:
    """The frame re-shot ``n`` times, each with its own noise seed (decoded, chart-normalised), and its
    noiseless photo."""
    from mocks.camera_sim import SensorModel, simulate_raw, write_raw
    from mocks.noise_seed import stable_seed
    from processing.camera.raw_decode import bilinear_demosaic, decode_raw

    w = dataclasses.replace(world, pose=np.asarray(pose, dtype=np.float64),
                            table_angle_deg=float(rec["angle_deg"]))
    frame = w.frame("object")
    first = stable_seed("held-out burst", int(rec["pass"]), float(rec["angle_deg"]))
    seeds = [stable_seed("burst", first, j) for j in range(n)]
    photos, raw = [], None
    for s in seeds:
        raw = simulate_raw(frame.radiance, frame.grid, frame.light, exposure_s=exposure_s, seed=s)
        path = write_raw(tmp / "burst.dng", raw)
        photos.append(decode_raw(path, mode="demosaic").rgb.astype(np.float64) * gains)
    sensor = SensorModel()
    index = np.array(["RGB".index(c) for c in raw.cfa_pattern])
    span = raw.white_level - raw.black_level          # a photosite past the white level reads the white level
    values = np.minimum(raw.mean_electrons / sensor.gain_e_per_dn / span, 1.0).astype(np.float32)
    none = np.zeros(values.shape, bool)
    clean = bilinear_demosaic(values, index, none, none)[0].astype(np.float64) * gains
    return photos, clean, first


def _true_frame_pose(world: Any, frame: Any, poses: dict[str, Any]) -> Any:
    """The frame's pose from the simulation's truth: true camera, lamp and placement, M = placement 1."""
    from processing.appearance.frame_poses import FramePose

    p1 = np.asarray(poses["1"], dtype=np.float64)
    pp = np.asarray(poses[str(frame.pass_index)], dtype=np.float64)
    lamp = {"name": frame.lamps[0].name if frame.lamps else "lamp", **world.lamp_truth()}
    lamp.pop("kind", None), lamp.pop("spectrum", None), lamp.pop("radius_mm", None)
    return FramePose.from_chain(frame.name, frame.pass_index, world.room_to_camera(), frame.table_angle_deg,
                                p1 @ np.linalg.inv(pp), world.camera_intrinsics(), np.zeros(5),
                                frame.image_size, [lamp])


def _true_mesh(world: Any, p1: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    import open3d as o3d

    wv = world.vertices @ p1[:3, :3].T + p1[:3, 3]
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(wv),
                                     o3d.utility.Vector3iVector(world.triangles.astype(np.int32)))
    return wv, world.triangles.astype(np.int64), np.asarray(mesh.compute_vertex_normals().vertex_normals)


def _categories(clean: np.ndarray, true_render: np.ndarray, true_mask: np.ndarray, matrix: np.ndarray
                ) -> np.ndarray:
    """Category index per pixel (:data:`CATEGORIES`), from the truth only."""
    from scipy import ndimage

    white_y = float((matrix @ np.ones(3))[1])
    y = np.nan_to_num(clean) @ matrix[1] / white_y
    band = ndimage.distance_transform_edt(true_mask) <= _BAND_PX
    unlit = np.all(np.nan_to_num(true_render) <= 0.0, axis=-1)
    cat = np.full(clean.shape[:2], 4, np.int64)
    cat[y < _DARK_Y] = 3
    cat[unlit] = 2
    cat[y >= _HIGHLIGHT_Y] = 1
    cat[band] = 0
    return cat


def decomposition(work: Path, images_dir: Path | None = None) -> dict[str, Any]:
    """Run the decomposition on the ``session`` case's products in ``work``; figures into ``images_dir``."""
    from scipy import ndimage

    from app.demo.capture import SCAN_EXPOSURE_S
    from app.session import Session
    from app.workflows.object_materials import (
        _GRID,
        _clip_level,
        _held_out,
        _load_inputs,
        _reference_distance,
        read_object_materials,
    )
    from app.workflows.posed_frames import calibrated_images, noise_model
    from bench.object_bench import _true_normals
    from processing.appearance.photo_comparison import camera_to_xyz_matrix, compare_images, noise_floor
    from processing.appearance.shading_normals import SMOOTHING_CELLS, smoothed_normals
    from processing.camera.response import camera_sensitivities
    from processing.spectral.spectra import SpectralGrid, light_spectrum
    from render.material_mesh import read_material_mesh
    from render.photo_signal import pixel_faces, render_signal

    t_start = time.perf_counter()
    summary = json.loads((work / "summary.json").read_text())
    truth, root = summary["simulation_truth"], Path(summary["session"])
    poses = {str(k): p for k, p in truth["poses"].items()}
    manifest = Session.read(root)
    data = _load_inputs(root, manifest)
    v, t, n = data["mesh"]
    held = _held_out(data["obs"].frame_names, data["records"], 4)
    frames = [f for f, h in zip(data["frames"], held) if h]
    records = [(nm, r) for nm, r, h in zip(data["obs"].frame_names, data["records"], held) if h]
    photos = calibrated_images(root, manifest, records, "demosaic")
    grid = SpectralGrid(*_GRID)
    light = light_spectrum(data["spectrum"] if data["spectrum"] is not None else "D65", grid)
    sens = camera_sensitivities(grid)
    matrix = camera_to_xyz_matrix(sens, light, grid)
    d_ref = _reference_distance(data)
    clip = _clip_level(photos)
    noise = noise_model(records, photos.gains)
    doc = read_object_materials(root)
    product = read_material_mesh(root / "products/object-mesh.ply")
    specs = [r.get("spec") for r in doc["regions"]]
    world = _truth_world(work)
    p1 = np.asarray(poses["1"], dtype=np.float64)
    from app.demo.object import true_face_materials

    faces = true_face_materials(v, t, world, p1)
    names = sorted(set(faces))
    face_truth = np.array([names.index(f) for f in faces])
    shading = smoothed_normals(v, t, n, SMOOTHING_CELLS * data["cell_mm"])
    true_n = _true_normals(v, world, p1)
    tv, tt, tn = _true_mesh(world, p1)
    world_specs = [world.materials[r] for r in world.region_names]
    kw = dict(sensitivities=sens, scale=1.0, grid=grid, irradiance_ref_mm=d_ref)
    renders = {
        "measured materials": lambda f: render_signal(v, t, product.normals, product.face_material, specs, f, light, **kw),
        "one material (baseline)": lambda f: render_signal(v, t, product.normals, np.zeros(len(t), np.int64),
                                                           [doc["baseline"]["spec"]], f, light, **kw),
        "true materials, scanned mesh": lambda f: render_signal(v, t, shading, face_truth, names, f, light, **kw),
        "true materials, scanned mesh, true normals": lambda f: render_signal(v, t, true_n, face_truth, names, f,
                                                                              light, **kw),
        "true object, estimated pose": lambda f: render_signal(tv, tt, tn, world.region, world_specs, f, light, **kw),
    }
    values: dict[tuple[str, str, int], list[np.ndarray]] = {}
    cats: dict[tuple[str, str], list[np.ndarray]] = {}
    regions: dict[tuple[str, str], list[np.ndarray]] = {}
    floors: dict[tuple[str, int, int], list[np.ndarray]] = {}
    scale_ratio, example = [], None
    t_shots = t_render = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        for k, (frame, (cid, rec)) in enumerate(zip(frames, records)):
            p = int(rec["pass"])
            gains = np.asarray(photos.gains.get(p, np.ones(3)), dtype=np.float64)
            t0 = time.perf_counter()
            shots, clean, _ = _shots(world, rec, poses[str(p)], gains, BURST, root, SCAN_EXPOSURE_S, Path(tmp))
            t_shots += time.perf_counter() - t0
            imgs = {"session photo": np.asarray(photos[k], dtype=np.float64), "single frame": shots[0], f"burst of {BURST // 4}": np.mean(shots[:BURST // 4], axis=0),
                    f"burst of {BURST}": np.mean(shots, axis=0), "noiseless": clean}
            t0 = time.perf_counter()
            rendered = {name: fn(frame) for name, fn in renders.items()}
            true_pose = _true_frame_pose(world, frame, poses)
            rendered["true object, true pose"] = render_signal(tv, tt, tn, world.region, world_specs, true_pose,
                                                               light, **kw)
            t_render += time.perf_counter() - t0
            true_img, true_mask = rendered["true object, true pose"]
            unclipped = ~np.any(np.stack([*shots, imgs["session photo"]]) >= clip, axis=(0, -1))
            common = (ndimage.binary_erosion(true_mask, iterations=2)
                      & ndimage.binary_erosion(rendered["measured materials"][1], iterations=2) & unclipped)
            rendered["noiseless photo"] = (clean, common)     # against the photos: the real noise floor
            seen = pixel_faces(v, t, frame)
            label = np.where(seen >= 0, face_truth[np.maximum(seen, 0)], -1)
            cat = _categories(clean, true_img, true_mask, matrix)
            lit = common & (cat == 4)
            scale_ratio.append(np.median(clean[lit] / np.maximum(true_img[lit], 1e-6), axis=0))
            for rname, (img, _) in rendered.items():
                for pname, photo in imgs.items():
                    for s in POOLS:
                        res = compare_images(photo, np.nan_to_num(img), common, matrix, edge_margin_px=0, pool_px=s)
                        em = res.error_map
                        values.setdefault((rname, pname, s), []).append(
                            em[::s, ::s][np.isfinite(em[::s, ::s])].astype(np.float64))
                        if s == 1:
                            cats.setdefault((rname, pname), []).append(
                                np.stack([em[common], cat[common].astype(np.float64)], axis=1))
                            regions.setdefault((rname, pname), []).append(
                                np.stack([em[common], label[common].astype(np.float64)], axis=1))
                        if rname == "measured materials" and pname in ("single frame", f"burst of {BURST}") \
                                and s in (1, 4) and k == 0:
                            example = example or {}
                            example[(pname, s)] = em
            for nframes in (1, BURST // 4, BURST):
                for s in POOLS:
                    for cfa in ("RGGB", None):
                        fl = noise_floor(true_img, common, matrix, noise[k], edge_margin_px=0, cfa=cfa,
                                         frames=nframes, pool_px=s)
                        em = fl.error_map
                        floors.setdefault((cfa or "independent", nframes, s), []).append(
                            em[::s, ::s][np.isfinite(em[::s, ::s])].astype(np.float64))
            if k == 0:
                example = {**(example or {}), "photo": shots[0], "burst": imgs[f"burst of {BURST}"],
                           "render": rendered["measured materials"][0], "mask": common, "frame": cid}
    table = {f"{r} | {p} | {s}": _stats(x) for (r, p, s), x in values.items()}
    by_cat = {}
    for (r, p), parts in cats.items():
        a = np.concatenate(parts)
        total = float(a[:, 0].sum())
        by_cat[f"{r} | {p}"] = {c: {"share_pixels": float(np.mean(a[:, 1] == i)),
                                    "mean_de2000": float(a[a[:, 1] == i, 0].mean()) if np.any(a[:, 1] == i) else None,
                                    "share_of_error": float(a[a[:, 1] == i, 0].sum() / total) if total else None}
                                for i, c in enumerate(CATEGORIES)}
    by_region = {}
    for (r, p), parts in regions.items():
        a = np.concatenate(parts)
        by_region[f"{r} | {p}"] = {nm: {"share_pixels": float(np.mean(a[:, 1] == i)),
                                        "mean_de2000": float(a[a[:, 1] == i, 0].mean()) if np.any(a[:, 1] == i)
                                        else None} for i, nm in enumerate(names)}
    out = {"frames": len(frames), "burst": BURST, "true_materials": by_region, "pools_px": list(POOLS), "table": table, "categories": by_cat,
           "model_floor": {f"{c} | {nf} | {s}": _stats(x) for (c, nf, s), x in floors.items()},
           "exposure_ratio_noiseless_over_true_render": np.median(np.array(scale_ratio), axis=0).tolist(),
           "seconds": {"shots": round(t_shots, 1), "renders": round(t_render, 1),
                       "all": round(time.perf_counter() - t_start, 1)},
           "per_frame_shot_s": round(t_shots / max(len(frames), 1) / BURST, 3)}
    if images_dir is not None and example is not None:
        out["figures"] = _figures(out, example, matrix, images_dir)
    return out


def _stats(parts: list[np.ndarray]) -> dict[str, float | int]:
    a = np.concatenate(parts) if parts else np.zeros(0)
    return {"mean": float(a.mean()), "p95": float(np.percentile(a, 95)), "n": int(a.size)} if a.size else {"n": 0}


def _figures(out: dict[str, Any], ex: dict[str, Any], matrix: np.ndarray, images_dir: Path) -> list[str]:
    """The ladder and category charts and one frame's error maps, as PNGs in ``images_dir``."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from app.workflows.holdout_validation import ERROR_RANGE_DE
    from processing.spectral.display import xyz_to_srgb8

    images_dir.mkdir(parents=True, exist_ok=True)
    t = out["table"]
    rungs = ["true object, true pose", "true object, estimated pose", "true materials, scanned mesh, true normals",
             "true materials, scanned mesh", "measured materials", "one material (baseline)"]
    photos = ["noiseless", "single frame", f"burst of {BURST}"]
    fig = Figure(figsize=(9, 4.2), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    width = 0.26
    for j, ph in enumerate(photos):
        ys = [t[f"{r} | {ph} | 1"]["mean"] for r in rungs]
        ax.bar(np.arange(len(rungs)) + (j - 1) * width, ys, width, label=f"against the {ph} photo"
               if ph != "noiseless" else "against the noiseless photo")
    ax.axhline(2.0, color="k", lw=0.8, ls="--")
    ax.set_xticks(np.arange(len(rungs)), ["true object\ntrue pose", "true object\nest. pose",
                                          "scanned mesh\ntrue normals", "scanned mesh\nshading normals",
                                          "measured\nmaterials", "one material\n(baseline)"], fontsize=8)
    ax.set_ylabel("mean CIEDE2000 (per pixel)")
    ax.set_title("Held-out photos: what each step from the truth to the product adds", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    ladder = images_dir / "heldout-ladder.png"
    fig.savefig(ladder)

    fig = Figure(figsize=(9, 3.6), dpi=100)
    FigureCanvasAgg(fig)
    for j, ph in enumerate(("single frame", f"burst of {BURST}")):
        ax = fig.add_subplot(1, 2, j + 1)
        c = out["categories"][f"measured materials | {ph}"]
        ct = out["categories"][f"true object, true pose | {ph}"]
        x = np.arange(len(CATEGORIES))
        ax.bar(x - 0.2, [c[k]["share_of_error"] for k in CATEGORIES], 0.4, label="measured materials")
        ax.bar(x + 0.2, [ct[k]["share_of_error"] for k in CATEGORIES], 0.4, label="true object, true pose")
        ax.set_xticks(x, [f"{k}\n{100 * c[k]['share_pixels']:.0f} % px\n{c[k]['mean_de2000']:.1f} dE"
                          for k in CATEGORIES], fontsize=7)
        ax.set_ylabel("share of the summed CIEDE2000")
        ax.set_title(f"{ph} photos", fontsize=9)
        ax.legend(fontsize=7)
    fig.tight_layout()
    cats = images_dir / "heldout-categories.png"
    fig.savefig(cats)

    white = matrix @ np.ones(3)

    def srgb(img: np.ndarray) -> np.ndarray:
        return xyz_to_srgb8(np.clip(np.nan_to_num(img), 0, None) @ matrix.T / white[1], white / white[1])

    ys, xs = np.nonzero(ex["mask"])
    y0, y1 = max(ys.min() - 8, 0), ys.max() + 8
    x0, x1 = max(xs.min() - 8, 0), xs.max() + 8
    panels = [("photo (one frame)", srgb(ex["photo"])), (f"mean of {BURST} frames", srgb(ex["burst"])),
              ("measured materials rendered", srgb(ex["render"])),
              ("error, one frame, per pixel", ex[("single frame", 1)]),
              (f"error, {BURST} frames, per pixel", ex[(f"burst of {BURST}", 1)]),
              (f"error, {BURST} frames, 4 x 4 px", ex[(f"burst of {BURST}", 4)])]
    fig = Figure(figsize=(12, 4.4), dpi=100)
    FigureCanvasAgg(fig)
    import matplotlib

    cmap = matplotlib.colormaps["magma"].with_extremes(bad=(40 / 255,) * 3)
    for i, (title, img) in enumerate(panels):
        ax = fig.add_subplot(2, 3, i + 1)
        crop = img[y0:y1, x0:x1]
        if crop.ndim == 3:
            ax.imshow(crop)
        else:
            im = ax.imshow(np.ma.masked_invalid(crop), cmap=cmap, vmin=0, vmax=ERROR_RANGE_DE,
                           interpolation="nearest")
            vals = crop[np.isfinite(crop)]
            title += f": mean {vals.mean():.2f}"
        ax.set_title(title, fontsize=8)
        ax.set_axis_off()
    fig.colorbar(im, ax=fig.axes, label="CIEDE2000", shrink=0.8)
    maps = images_dir / "heldout-maps.png"
    fig.savefig(maps)
    return [str(ladder), str(cats), str(maps)]
