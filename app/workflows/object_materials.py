"""The digitised object: materials measured on the mesh, written as products, checked on held-out photos.

:func:`measure_object` is what ``kogei fit-materials``, the batch's ``materials`` step (for a session
whose photos are posed), the window and the demo call.  From the observations of a projected session
(``products/observations.npz``, ``products/frame-poses.json``: ``kogei project``) it

1. holds out every :data:`HOLDOUT_EVERY`-th table angle (the same angles in every pass:
   :func:`app.workflows.holdout_validation.holdout_frames`) -- those frames are never used by the fit;
2. splits the surface into regions of one material from all views of every vertex
   (:func:`processing.appearance.surface_segmentation.segment_surface`);
3. fits every candidate material to each region's observations at their true normal, view and
   light directions and chooses by likelihood (:func:`processing.materials.forward_fit.fit_region`),
   and fits the paper's baseline -- one material for the whole object -- the same way;
4. writes ``products/object-mesh.ply`` (the mesh with a material index per face),
   ``products/object-materials.json`` (per region: material, confidence, parameters with
   uncertainties, area, observations) and ``products/object-scene.toml`` (a ``kogei render`` scene
   of the object in the booth);
5. renders the held-out frames with the calibrated camera and lamp, compares them with the photos in
   CIELAB (mean and p95 CIEDE2000 over object pixels), for the measured materials and the baseline,
   and writes the error maps and photo | render | error triptychs under ``products/validation/``.

docs/object-materials.md describes the products and how to read the figures.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from app.errors import UsageError

__all__ = ["measure_object", "burst_records", "answer_text", "area_text", "unmeasured_share_text", "read_object_materials", "region_observations", "face_region_at", "object_scene_toml", "OBJECT_MATERIALS",
           "OBJECT_MESH", "OBJECT_SCENE", "object_mesh_file", "VALIDATION_DIR", "HOLDOUT_EVERY", "FIT_MODEL_ERROR"]

OBJECT_MATERIALS = "products/object-materials.json"
OBJECT_MESH = "products/object-mesh.ply"
OBJECT_SCENE = "products/object-scene.toml"
VALIDATION_DIR = "products/validation"
#: Every n-th table angle is held out of the fit and used to validate it (the validation's rule).
HOLDOUT_EVERY = 4          # app.workflows.holdout_validation.HOLDOUT_EVERY (not imported: it loads Open3D)
#: The held-out comparison is also made at this spatial scale (pixels per block side).
POOL_PX = 4                # app.workflows.holdout_validation.POOL_PX
#: Relative error of the forward model added to each observation's noise (0.02 = 2 %), the one default of
#: ``kogei fit-materials --model-error`` and the batch's materials step on the mesh (docs/materials.md, "Weights").
FIT_MODEL_ERROR = 0.02
#: A region's own material competes with the largest region's for its pieces only when it was named with at
#: least this confidence (docs/materials.md, "Pieces that join the largest region").
_RIVAL_CONFIDENCE = 0.5
#: A region answered below this confidence has a material its fit cannot name (a dull, dark fit that a dozen
#: candidates explain alike, e.g. "bronze 0.07"); the largest region's alloy grades that cannot be told apart
#: (three at about 0.5) stay named.  Such a region takes no vertex in the relabelling.
_NAMED_CONFIDENCE = 0.25

#: Most rounds of the relabelling (:func:`_relabel_rounds`): another round only when a refit named a region.
RELABEL_ROUNDS = 3
#: A connected piece of a region whose vertices' own views a preset explains better than the region's fitted
#: material (neighbours agreeing) is fitted as a region of its own from this area (mm2) on
#: (docs/materials.md, "Pieces no region explains").
SPLIT_MIN_AREA_MM2 = 10.0
#: The camera's point spread is measured on this many fitted frames (evenly spread over the table's turn).
SPREAD_FRAMES = 3
#: Spectral grid of the fit (nm).
_GRID = (400.0, 700.0, 10.0)


def _held_out(names: tuple[str, ...], records: list[dict[str, Any]], every: int) -> np.ndarray:
    """True for the frames held out of the fit (:func:`app.workflows.holdout_validation.holdout_frames`)."""
    from app.workflows.holdout_validation import holdout_frames

    if every == 0:
        return np.zeros(len(names), dtype=bool)
    held = holdout_frames(list(names), [float(r.get("angle_deg") or 0.0) for r in records], every=every)
    return np.array([n in held for n in names])


def _load_inputs(root: Path, manifest: dict[str, Any]) -> dict[str, Any]:
    """Observations, frame poses (in the observations' frame order), their records, the mesh and the lamp."""
    from app.workflows.posed_frames import checked_product, read_frame_poses, session_mesh
    from app.workflows.station_calibration import session_lamp_calibration
    from processing.appearance.frame_poses import AppearanceError
    from processing.appearance.observations import read_observations

    products = manifest.get("products") or {}
    if not isinstance(products.get("observations"), dict) or not isinstance(products.get("frame_poses"), dict):
        raise UsageError(f"session {root} has no photos posed on its mesh (products/observations.npz); calibrate "
                         "the camera and the lamp (kogei calibrate --camera ... / --lamp ...), then run "
                         f"'kogei process {root} --camera-calibration BOARD --lamp-calibration LAMP'")
    path = checked_product(root, products["observations"], "products.observations", f"kogei project {root} again")
    try:
        obs = read_observations(path)
    except AppearanceError as exc:
        raise UsageError(f"session {root}: {exc}; run kogei project {root} again") from None
    if not obs.lamp_names:
        raise UsageError(f"session {root}: its observations carry no lamp (no lamp calibration when it was "
                         f"projected); run kogei calibrate --lamp LAMP_SESSION ..., then kogei process {root} "
                         "--lamp-calibration LAMP_SESSION")
    poses = {p.name: p for p in read_frame_poses(root, manifest)}
    missing = [n for n in obs.frame_names if n not in poses]
    if missing:
        raise UsageError(f"session {root}: frames {', '.join(missing[:3])} are observed but not posed; run kogei "
                         f"project {root} again")
    captures = manifest.get("captures") or {}
    lamps = session_lamp_calibration(root, manifest)
    spectrum = next((lp.spectrum for lp in lamps.lamps if lp.spectrum is not None), None) if lamps else None
    mesh = session_mesh(root, manifest)
    if obs.n_vertices != len(mesh[0]):
        raise UsageError(f"session {root}: its observations are of a mesh of {obs.n_vertices} vertices but its mesh "
                         f"has {len(mesh[0])} (the mesh was replaced after the photos were projected); run kogei "
                         f"project {root} again")
    return {"obs": obs, "frames": [poses[n] for n in obs.frame_names], "mesh": mesh,
            "records": [captures.get(n) or {} for n in obs.frame_names], "spectrum": spectrum,
            "cell_mm": _reconstruction_cell_mm(root, manifest)}


def _reconstruction_cell_mm(root: Path, manifest: dict[str, Any]) -> float | None:
    """The octree cell (mm) ``kogei process`` reconstructed the mesh at (its report); None for another mesh."""
    from app.session_paths import MAX_JSON_BYTES, read_confined_bytes
    from processing.common.files import parse_json

    ref = (manifest.get("products") or {}).get("process_report")
    try:        # a damaged report (a JSONFileError is a ValueError) costs only the cell size
        blob = read_confined_bytes(root, ref.get("file"), "products.process_report.file", MAX_JSON_BYTES) \
            if isinstance(ref, dict) else b"{}"
        report = parse_json(blob, "products.process_report", f"run kogei process {root} again")
        cell = float(report["surface"]["mesh"]["cell_mm"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return cell if math.isfinite(cell) and cell > 0 else None


def _forward_model(spectrum: Any, note: Callable[[str], None]) -> Any:
    """The forward model of the fit: the model camera and the lamp's spectrum (D65 when not measured)."""
    from processing.camera.response import camera_sensitivities
    from processing.materials.forward_fit import ForwardModel
    from processing.spectral.spectra import SpectralGrid, light_spectrum

    grid = SpectralGrid(*_GRID)
    if spectrum is None:
        note("the lamp calibration states no lamp spectrum: the fit assumes D65 (kogei calibrate --lamp ... "
             "--lamp-spectrum NAME|CCT)")
        spectrum = "D65"
    return ForwardModel(camera_sensitivities(grid), light_spectrum(spectrum, grid), grid), spectrum


def measure_object(session_dir: str | Path, *, holdout_every: int = HOLDOUT_EVERY, model_error: float = FIT_MODEL_ERROR,
                   max_regions: int = 8, normals: str = "mesh", validate: bool = True,
                   decode: str = "demosaic",
                   message: Callable[[str], None] | None = None,
                   cancel: Callable[[], bool] | None = None) -> dict[str, Any]:
    """Segment the mesh, fit each region's material, write the object's products and validate them.

    Parameters
    ----------
    session_dir
        A session projected by ``kogei project`` (or ``kogei process`` with camera and lamp
        calibrations).
    holdout_every
        Every n-th frame of a pass is held out of the fit and used for validation (0: none).
    model_error
        Relative error of the forward model added to the noise (0.02 = 2 %); default :data:`FIT_MODEL_ERROR`.
    max_regions
        Most regions of one material the segmentation may find.
    normals
        ``"mesh"``: the mesh's normals (smoothed over two cells of the reconstruction when ``kogei
        process`` built the mesh: the shading normals); ``"photometric"`` (experimental): after a
        first fit, tilt each vertex normal to where its region's highlights put it
        (:func:`processing.materials.photometric_normals.refine_normals`), then fit again and write the
        refined normals with the object.  On the demo's scan it makes every true region's fit right
        but leaves the session's answers (limited by the segmentation) as they are, at a slightly
        higher held-out error and about 20 s more (docs/materials.md, "Normals refined by the
        photos"), so it is not the default.
    validate
        Render the held-out frames and compare them with the photos.
    decode
        How the held-out photos are decoded (``demosaic`` or ``bin2x2``), as when they were projected.
    message
        Called with progress lines.
    cancel
        Polled between steps; True stops with :class:`UsageError` ("cancelled"), writing nothing.

    Returns
    -------
    dict
        The materials document (also ``products/object-materials.json``).
    """
    from threadpoolctl import threadpool_limits

    from app.session import Session, SessionError
    from app.session_paths import check_destinations

    note = message or (lambda text: None)
    stop = cancel or (lambda: False)
    if not (isinstance(model_error, (int, float)) and math.isfinite(model_error) and 0 <= model_error <= 0.5):
        raise UsageError(f"--model-error must be a relative level in [0, 0.5] (0.02 = 2 %), got {model_error!r}")
    if normals not in ("photometric", "mesh"):
        raise UsageError(f"--normals must be 'photometric' or 'mesh', got {normals!r}")
    if not (isinstance(max_regions, int) and 1 <= max_regions <= 32):
        raise UsageError(f"--max-regions must be an integer in [1, 32], got {max_regions!r}")
    root = Path(session_dir)
    try:
        session = Session.open(root)
    except SessionError as exc:
        raise UsageError(str(exc)) from None
    with session:
        check_destinations(root, (".incoming/object-mesh.ply", OBJECT_MESH, OBJECT_SCENE, OBJECT_MATERIALS,
                                   VALIDATION_DIR))
        data = _load_inputs(root, session.manifest)
        if isinstance(holdout_every, bool) or not isinstance(holdout_every, int) or holdout_every in (1,) \
                or holdout_every < 0:
            raise UsageError(f"--holdout-every must be 0 (no validation) or an integer >= 2, got {holdout_every!r}")
        held = _held_out(data["obs"].frame_names, data["records"], holdout_every)
        if held.all():
            raise UsageError(f"session {root}: every frame would be held out; use --holdout-every >= 2 or 0")
        # one BLAS thread: the fit's products are small, and OpenBLAS's spinning threads cost the whole
        # step several times its CPU on a shared machine (docs/BENCHMARKS.md, "Materials on the mesh")
        with threadpool_limits(limits=1, user_api="blas"):
            doc = _fit(data, held, model_error, max_regions, note, stop, refine=normals == "photometric")
        data["mesh"] = (*data["mesh"][:2], doc.pop("_normals"))       # the refined normals go with the object
        _check_cancel(stop)
        _write_products(session, root, data, doc)
        if validate and held.any() and doc["baseline"]["spec"] is None:
            doc["validation"] = {"frames": [], "note": "no region has a fitted material: nothing to render"}
        elif validate and held.any():
            doc["validation"] = _validate(session, root, data, doc, held, decode, note, stop)
            spread = doc["validation"].get("point_spread") or {}
            if spread.get("sigma_px"):
                _lens_share_of_roughness(data, doc, held, float(spread["sigma_px"]))
        elif validate:
            doc["validation"] = {"frames": [], "note": "no frame held out (--holdout-every 0): not validated"}
        _record(session, doc)
    return doc


def answer_text(region: dict[str, Any]) -> str:
    """A region's answer for people: the material and its confidence, or why there is none.

    Examples
    --------
    >>> answer_text({"material": "gold", "confidence": 0.934, "group": ["gold"]})
    'gold (confidence 0.93)'
    >>> answer_text({"material": "no candidate fits", "confidence": 0.9, "group": ["tin", "lead"], "chi2_per_dof": 41.0})
    'no candidate fits (best: tin, reduced chi-square 41)'
    """
    material, group = region.get("material"), list(region.get("group") or [])
    if material == "not measured":
        return "not measured"
    if material == "no candidate fits":
        return (f"no candidate fits (best: {group[0] if group else '?'}, reduced chi-square "
                f"{float(region.get('chi2_per_dof') or float('nan')):.3g})")
    text = f"{material} (confidence {float(region.get('confidence') or 0.0):.2f})"
    if material == "neutral metal":
        return f"{text}: one of {', '.join(group)}"
    others = [g for g in group if g != material]
    listed = ", ".join(others[:3]) + (f" and {len(others) - 3} others" if len(others) > 3 else "")
    text += f"; cannot be told from {listed}" if others else ""
    mixed = float(region.get("disagreeing_area_mm2") or 0.0)
    return text + (f"; {mixed:.0f} mm2 of it fits another region's material better" if mixed > 0 else "")


def unmeasured_share_text(not_measured: dict[str, Any]) -> str:
    """The share of the surface no region holds, for people ("" when none, or a document without it).

    Examples
    --------
    >>> unmeasured_share_text({"faces": 12, "share": 0.0951})
    '9.5 % of the surface'
    >>> unmeasured_share_text({"faces": 1, "share": 0.0002})
    'under 0.1 % of the surface'
    >>> unmeasured_share_text({"faces": 0, "share": 0.0})
    ''
    """
    if not not_measured.get("faces") or not_measured.get("share") is None:
        return ""
    pct = 100 * float(not_measured["share"])
    return f"{'under 0.1' if pct < 0.05 else f'{pct:.1f}'} % of the surface"


def area_text(region: dict[str, Any]) -> str:
    """A region's area for people, with how much of it only its neighbours decided.

    Examples
    --------
    >>> area_text({"area_mm2": 347.2, "area_by_neighbours_mm2": 114.0})
    '347 mm^2 (114 of it labelled by its neighbours)'
    >>> area_text({"area_mm2": 12.0})
    '12 mm^2'
    """
    nb = region.get("area_by_neighbours_mm2")
    return f"{float(region['area_mm2']):.0f} mm^2" + (f" ({float(nb):.0f} of it labelled by its neighbours)" if nb else "")


def _check_cancel(stop: Callable[[], bool]) -> None:
    if stop():
        raise UsageError("cancelled: no product written")


def _fit(data: dict[str, Any], held: np.ndarray, model_error: float, max_regions: int,
         note: Callable[[str], None], stop: Callable[[], bool], refine: bool = True) -> dict[str, Any]:
    """Segmentation, per-region fits and the one-material baseline, as the materials document."""
    from processing.appearance.observations import select_frames
    from processing.appearance.shading_normals import SMOOTHING_CELLS, smoothed_normals
    from processing.appearance.surface_segmentation import segment_surface

    v, t, _ = data["mesh"]
    d_ref = _reference_distance(data)
    # A reconstructed mesh's normals carry the iso-surface's facets; a mesh from elsewhere keeps its own.
    sigma_mm = 0.0 if data["cell_mm"] is None else SMOOTHING_CELLS * data["cell_mm"]
    t0 = time.perf_counter()
    shading = smoothed_normals(v, t, data["mesh"][2], sigma_mm)
    t_normals = time.perf_counter() - t0
    if sigma_mm > 0:
        note(f"shading normals: the mesh's normals smoothed over {sigma_mm:.2f} mm ({SMOOTHING_CELLS:g} cells of "
             "its reconstruction)")
    obs = select_frames(data["obs"], ~held)
    obs = dataclasses.replace(obs, normal=shading[obs.vertex].astype(np.float32))
    model, spectrum = _forward_model(data["spectrum"], note)
    t0 = time.perf_counter()
    note(f"segmenting the surface from {len(obs)} observations in {int((~held).sum())} frames "
         f"({int(held.sum())} held out)")
    seg = segment_surface(obs, v, t, max_regions=max_regions, frames=data["frames"])
    t_seg = time.perf_counter() - t0
    _check_cancel(stop)
    areas = _face_areas(v, t)
    t1 = time.perf_counter()
    fits = _fit_regions(obs, v, t, data, seg, d_ref, model, model_error, stop)
    normals_doc, vertex_normals = None, shading
    if refine:
        from processing.materials.photometric_normals import refine_normals
        from processing.materials.presets import get_material

        _check_cancel(stop)
        note("refining the mesh normals from the photos (each region's material, every view near a highlight)")
        t2 = time.perf_counter()
        ref = refine_normals(obs, v, t, shading, data["frames"], seg.vertex_region,
                             [get_material(f.spec) if f.spec else None for f in fits], model, reference_mm=d_ref)
        obs = dataclasses.replace(obs, normal=ref.normals[obs.vertex].astype(np.float32))
        vertex_normals = ref.normals
        normals_doc = {"method": "photometric", "decided_share": round(float(ref.decided.mean()), 4),
                       "median_tilt_deg": round(float(np.median(ref.tilt_deg[ref.decided])), 3)
                       if ref.decided.any() else 0.0,
                       "cost_before": round(ref.cost_before, 1), "cost_after": round(ref.cost_after, 1),
                       "views": ref.n_views, "seconds": round(time.perf_counter() - t2, 3)}
        note(f"normals: {100 * normals_doc['decided_share']:.0f} % of the vertices decided by their highlights, "
             f"median tilt {normals_doc['median_tilt_deg']:.1f} deg; fitting again")
        fits = _fit_regions(obs, v, t, data, seg, d_ref, model, model_error, stop)
    _check_cancel(stop)
    t_pieces = time.perf_counter()
    seg, fits, joined = _join_pieces(obs, v, t, data, seg, fits, d_ref, model, model_error, areas, stop)
    if joined["pieces"]:
        note(f"{joined['pieces']} pieces ({joined['area_mm2']:.0f} mm2) of other regions joined region "
             f"{joined['target']}: its material explains their observations as well as their own")
    t_relabel = time.perf_counter()
    seg, fits, relabelled = _relabel_rounds(obs, v, t, data, seg, fits, d_ref, model, model_error, areas, stop)
    if relabelled["vertices"]:
        rounds = f" ({relabelled['rounds']} rounds)" if relabelled["rounds"] > 1 else ""
        note(f"{relabelled['vertices']} vertices ({relabelled['area_mm2']:.0f} mm2) moved to the region whose fitted "
             f"material explains their own observations better{rounds}")
    seg, fits, split = _split(obs, v, t, data, seg, fits, d_ref, model, model_error, areas, stop,
                              samples=relabelled.pop("_samples", None))
    if split["regions"]:
        note(f"{split['regions']} piece(s) that no region's material explains ({sum(split['area_mm2']):.0f} mm2) "
             "fitted as regions of their own; relabelling again")
        seg, fits, again = _relabel_rounds(obs, v, t, data, seg, fits, d_ref, model, model_error, areas, stop)
        relabelled = _summed_moves(relabelled, again)
        relabelled.pop("_samples", None)
    t_relabel = time.perf_counter() - t_relabel
    fits, pieces = _check_pieces(obs, v, t, data, seg, fits, d_ref, model, model_error, areas)
    t_pieces = time.perf_counter() - t_pieces - t_relabel
    own = relabelled.pop("_own_views")
    # a face whose corners' own views mostly cannot tell the materials apart carries its neighbours' label
    by_neighbours = np.zeros(len(t), dtype=bool) if own is None else (~own)[t].sum(axis=1) >= 2
    regions = []
    for r, fit in enumerate(fits):
        faces = seg.face_region == r
        extra = {} if own is None else {"area_by_neighbours_mm2": round(float(areas[faces & by_neighbours].sum()), 3)}
        regions.append({"index": r, **fit.to_dict(), "area_mm2": round(float(areas[faces].sum()), 3),
                        "faces": int(faces.sum()), "vertices": int((seg.vertex_region == r).sum()), **extra,
                        **pieces[r]})
        note(f"region {r}: {answer_text(regions[-1])}, {int(faces.sum())} faces, {fit.n_lit} lit observations")
    t_fit = time.perf_counter() - t1
    unmeasured = seg.face_region < 0
    return {"schema": "kogei.object_materials", "version": 1, "mesh": OBJECT_MESH, "light_spectrum": spectrum,
            "irradiance_reference_mm": d_ref,
            "model_error": model_error, "segmentation": {"method": seg.method, "regions": seg.n_regions,
                                                          "features": list(seg.feature_names),
                                                          "joined": joined, "relabelled": relabelled,
                                                          "split": split},
            "regions": regions, "baseline": _baseline(regions),
            "not_measured": _not_measured(obs, v, t, areas, unmeasured),
            "area_mm2": round(float(areas.sum()), 3),
            "frames": {"fit": [n for n, h in zip(obs.frame_names, held) if not h],
                       "held_out": [n for n, h in zip(obs.frame_names, held) if h]},
            "normals": {**(normals_doc or {"method": "mesh"}), "smoothing_mm": round(sigma_mm, 4)},
            "interior_margin_mm": round(_interior_margin_mm(v, data["frames"]), 4),
            "timings_s": {"normals": round(t_normals, 3), "segmentation": round(t_seg, 3), "fit": round(t_fit, 3),
                          "pieces": round(t_pieces, 3), "relabel": round(t_relabel, 3)},
            "_face_region": seg.face_region, "_normals": vertex_normals}


def _fit_regions(obs: Any, v: np.ndarray, t: np.ndarray, data: dict[str, Any], seg: Any, d_ref: float | None,
                 model: Any, model_error: float, stop: Callable[[], bool], only: Any = None,
                 previous: list[Any] | None = None, fit_on: np.ndarray | None = None) -> list[Any]:
    """Each region's :class:`processing.materials.forward_fit.RegionFit` from its interior's observations.

    ``only``: the regions to fit; the others keep their fit from ``previous``.  ``fit_on``: ``(V,)`` bool,
    the vertices whose observations may be fitted (a region's interior without any keeps them all).
    """
    from processing.appearance.region_interior import border_distance_mm, interior_vertices
    from processing.materials.confidence import NOT_MEASURED
    from processing.materials.forward_fit import fit_region, region_samples

    distance = border_distance_mm(seg.vertex_region, v, t)
    margin = _interior_margin_mm(v, data["frames"])
    fits = []
    for r in range(seg.n_regions):
        _check_cancel(stop)
        if only is not None and r not in only and previous is not None:
            fits.append(previous[r])
            continue
        every = np.flatnonzero(seg.vertex_region == r)
        ids = interior_vertices(every, distance, margin)
        if fit_on is not None and fit_on[ids].any():
            ids = ids[fit_on[ids]]
        fit = fit_region(region_samples(obs, v, data["frames"], ids, triangles=t, reference_mm=d_ref), model,
                         model_error=model_error)
        if fit.material == NOT_MEASURED and len(ids) < len(every):     # a small region: its interior saw too little
            fit = fit_region(region_samples(obs, v, data["frames"], every, triangles=t, reference_mm=d_ref), model,
                             model_error=model_error)
        fits.append(fit)
    return fits


def _join_pieces(obs: Any, v: np.ndarray, t: np.ndarray, data: dict[str, Any], seg: Any, fits: list[Any],
                 d_ref: float | None, model: Any, model_error: float, areas: np.ndarray,
                 stop: Callable[[], bool]) -> tuple[Any, list[Any], dict[str, Any]]:
    """Pieces of the other regions that the largest region's material explains as well as their own join it.

    Every connected piece of every other region is scored against its own region's fitted material and
    the largest region's (:func:`processing.materials.region_consistency.joining_pieces`); the pieces
    that join are relabelled, regions left empty are dropped, and the regions that lost pieces are
    fitted again.  The largest region keeps its fit: the pieces joined because its material already
    explains them (docs/materials.md, "Pieces that join the largest region").
    """
    from processing.materials.forward_fit import INDEPENDENT, region_samples
    from processing.materials.presets import get_material
    from processing.materials.region_consistency import face_regions, joining_pieces, mesh_components, pieces_chi2

    none = {"target": None, "pieces": 0, "area_mm2": 0.0, "from_regions": []}
    target = int(np.argmax(_region_areas(seg, areas))) if seg.n_regions > 1 else -1
    if target < 0 or not fits[target].spec:
        return seg, fits, none
    piece = mesh_components(seg.vertex_region, t)
    target_mat = get_material(fits[target].spec)
    vertex_region = seg.vertex_region.copy()
    moved_from, n_pieces = set(), 0
    for r in range(seg.n_regions):
        _check_cancel(stop)
        if r == target:
            continue
        samples = region_samples(obs, v, data["frames"], np.flatnonzero(seg.vertex_region == r), triangles=t,
                                 reference_mm=d_ref)
        sp = piece[samples.vertex]
        # a region whose own fit cannot name its material (confidence under one half) offers no rival
        # explanation: its pieces join when the largest region's material fits them within the misfit limit
        own_mat = get_material(fits[r].spec) if fits[r].spec and fits[r].confidence >= _RIVAL_CONFIDENCE else None
        ids, chi2, n_obs, _ = pieces_chi2(samples, sp, model, [target_mat, own_mat], model_error=model_error)
        if not ids.size:
            continue
        join = joining_pieces(chi2[:, 0], chi2[:, 1], n_obs, independent=INDEPENDENT)
        if join.any():
            vertex_region[np.isin(piece, ids[join]) & (seg.vertex_region == r)] = target
            moved_from.add(r)
            n_pieces += int(join.sum())
    if not n_pieces:
        return seg, fits, none
    face_region = face_regions(vertex_region, t)
    moved_area = float(areas[(face_region == target) & (seg.face_region != target)].sum())
    keep = [r for r in range(seg.n_regions) if (face_region == r).any()]      # a region left without faces goes
    lut = np.full(seg.n_regions + 1, -1, dtype=np.int32)
    lut[keep] = np.arange(len(keep), dtype=np.int32)
    new = dataclasses.replace(seg, vertex_region=lut[vertex_region].astype(np.int32),
                              face_region=lut[face_region].astype(np.int32), n_regions=len(keep))
    refit = {int(lut[r]) for r in moved_from if lut[r] >= 0}
    fits = _fit_regions(obs, v, t, data, new, d_ref, model, model_error, stop, only=refit,
                        previous=[fits[r] for r in keep])
    return new, fits, {"target": int(lut[target]), "pieces": n_pieces, "area_mm2": round(moved_area, 3),
                       "from_regions": sorted(int(r) for r in moved_from)}


def _relabel(obs: Any, v: np.ndarray, t: np.ndarray, data: dict[str, Any], seg: Any, fits: list[Any],
             d_ref: float | None, model: Any, model_error: float, areas: np.ndarray,
             stop: Callable[[], bool]) -> tuple[Any, list[Any], dict[str, Any]]:
    """Every measured vertex given to the region whose fitted material explains its observations; refitted.

    :func:`processing.materials.vertex_relabelling.relabel_vertices` from the segmentation's labels
    (docs/materials.md, "Vertices the fitted materials claim"); a smaller region whose fit cannot name
    its material (confidence under :data:`_NAMED_CONFIDENCE`) takes no vertex.  The regions that gained
    or lost vertices are fitted again on the vertices that stayed and those their own views moved, and
    a region left without faces goes.
    """
    from processing.materials.forward_fit import region_samples
    from processing.materials.presets import get_material
    from processing.materials.region_consistency import face_regions
    from processing.materials.vertex_relabelling import relabel_vertices, vertex_material_costs

    none: dict[str, Any] = {"vertices": 0, "area_mm2": 0.0, "regions": [], "unnamed": [], "_own_views": None}
    mats = [get_material(f.spec) if f.spec else None for f in fits]
    if seg.n_regions < 2 or sum(m is not None for m in mats) < 2:
        return seg, fits, none
    _check_cancel(stop)
    samples = region_samples(obs, v, data["frames"], np.flatnonzero(seg.vertex_region >= 0), triangles=t,
                             reference_mm=d_ref)
    largest = int(np.argmax(_region_areas(seg, areas)))
    unnamed = [f.confidence < _NAMED_CONFIDENCE and r != largest for r, f in enumerate(fits)]
    named_not = [f"{fits[r].material} {fits[r].confidence:.2f}" for r, u in enumerate(unnamed) if u]
    cost = vertex_material_costs(samples, model, mats, len(v), model_error=model_error, unnamed=unnamed)
    labels = relabel_vertices(cost, seg.vertex_region, t)
    none.update(unnamed=named_not, _own_views=(own := _decided_by_own_views(cost, unnamed)), _samples=samples)
    moved = labels != seg.vertex_region
    if not moved.any():
        return seg, fits, none
    face_region = face_regions(labels, t)
    moved_area = float(areas[face_region != seg.face_region].sum())
    keep = [r for r in range(seg.n_regions) if (face_region == r).any()]
    lut = np.full(seg.n_regions + 1, -1, dtype=np.int32)
    lut[keep] = np.arange(len(keep), dtype=np.int32)
    new = dataclasses.replace(seg, vertex_region=lut[labels].astype(np.int32),
                              face_region=lut[face_region].astype(np.int32), n_regions=len(keep))
    changed = {int(lut[r]) for r in np.unique(np.concatenate([seg.vertex_region[moved], labels[moved]])) if lut[r] >= 0}
    _check_cancel(stop)
    # a vertex moved by its neighbours alone (its own views cannot tell the materials apart: a dark underside, an
    # eye in shadow) says nothing of its new region's parameters: the regions are fitted again on the vertices
    # that stayed and those their own views moved
    fits = _fit_regions(obs, v, t, data, new, d_ref, model, model_error, stop, only=changed,
                        previous=[fits[r] for r in keep], fit_on=~moved | own)
    return new, fits, {"vertices": int(moved.sum()), "area_mm2": round(moved_area, 3), "regions": sorted(changed),
                       "unnamed": named_not, "_own_views": own, "_samples": samples}


def _relabel_rounds(obs: Any, v: np.ndarray, t: np.ndarray, data: dict[str, Any], seg: Any, fits: list[Any],
                    d_ref: float | None, model: Any, model_error: float, areas: np.ndarray,
                    stop: Callable[[], bool]) -> tuple[Any, list[Any], dict[str, Any]]:
    """:func:`_relabel` again while its refit names a region that it could not name before (at most
    :data:`RELABEL_ROUNDS` rounds).

    An unnamed region takes no vertex; once the vertices its material does not explain have left it,
    its fit may name it (the demo's gold beak on another station seed: "shakudo 0.21" with the head's
    and the eyes' vertices, gold 0.97 without them), and then the vertices its own material explains
    better -- which the first round gave to its neighbours -- must be scored against it.  The report
    sums the rounds' moves; ``unnamed`` and the views that decided are the last round's.
    """
    named_before = _named_regions(fits)
    seg, fits, rep = _relabel(obs, v, t, data, seg, fits, d_ref, model, model_error, areas, stop)
    total = {**rep, "rounds": 1}
    while rep["vertices"] and _named_regions(fits) > named_before and total["rounds"] < RELABEL_ROUNDS:
        named_before = _named_regions(fits)
        seg, fits, rep = _relabel(obs, v, t, data, seg, fits, d_ref, model, model_error, areas, stop)
        if not rep["vertices"]:
            break
        total = _summed_moves(total, rep)
    return seg, fits, total


def _summed_moves(total: dict[str, Any], rep: dict[str, Any]) -> dict[str, Any]:
    """Two relabelling reports as one: moves and rounds (one when ``rep`` counts none) summed, the rest (what the
    last one decided) ``rep``'s."""
    return {**rep, "vertices": total["vertices"] + rep["vertices"],
            "area_mm2": round(total["area_mm2"] + rep["area_mm2"], 3),
            "regions": sorted(set(total["regions"]) | set(rep["regions"])), "rounds": total["rounds"] + rep.get("rounds", 1)}


def _split(obs: Any, v: np.ndarray, t: np.ndarray, data: dict[str, Any], seg: Any, fits: list[Any],
           d_ref: float | None, model: Any, model_error: float, areas: np.ndarray,
           stop: Callable[[], bool], samples: Any = None) -> tuple[Any, list[Any], dict[str, Any]]:
    """Pieces of regions that a preset explains better than their region's fitted material, as regions of their own.

    Each region's vertices are scored under its fitted material and every preset candidate outside the
    materials its fit could not tell from it (:func:`processing.materials.vertex_relabelling.vertex_material_costs`);
    connected pieces where the best rival wins, neighbours agreeing, of at least
    :data:`SPLIT_MIN_AREA_MM2` (:func:`~processing.materials.vertex_relabelling.unexplained_pieces`) are
    fitted, and a piece whose fit names a material with at least :data:`_RIVAL_CONFIDENCE` (as a region
    that competes for pieces) becomes a region when neither its answer nor its region's stands for the
    other (a piece of the head read "nami-shibuichi-uchi-sanbu", a grade its fit cannot tell from the
    head's, stays).  The report lists the new regions' areas (mm2).  ``samples``: the observations of every
    measured vertex, as the relabelling drew them (drawn here when None).
    """
    from processing.appearance._surface_features import vertex_areas
    from processing.materials.forward_fit import ALLOY, SURFACE_CANDIDATES, fit_region, region_samples
    from processing.materials.presets import get_material
    from processing.materials.region_consistency import face_regions
    from processing.materials.vertex_relabelling import unexplained_pieces, vertex_material_costs

    report: dict[str, Any] = {"regions": 0, "area_mm2": []}
    if not any(f.spec for f in fits):
        return seg, fits, report
    if samples is None:
        samples = region_samples(obs, v, data["frames"], np.flatnonzero(seg.vertex_region >= 0), triangles=t,
                                 reference_mm=d_ref)
    own, rival = np.zeros(len(v)), np.zeros(len(v))
    for r, fit in enumerate(fits):
        mine = np.flatnonzero(seg.vertex_region[samples.vertex] == r)
        names = [c for c in SURFACE_CANDIDATES if c != ALLOY and c != fit.material and c not in fit.group]
        if not fit.spec or not mine.size or not names:
            continue
        _check_cancel(stop)
        cost = vertex_material_costs(samples.subset(mine), model, [get_material(fit.spec), *map(get_material, names)],
                                     len(v), model_error=model_error)
        in_r = seg.vertex_region == r
        own[in_r], rival[in_r] = cost[in_r, 0], cost[in_r, 1:].min(axis=1)
    vertex_area = vertex_areas(v, t)
    labels, fits = seg.vertex_region.copy(), list(fits)
    taken = np.zeros(len(v), dtype=bool)
    for piece in unexplained_pieces(own, rival, seg.vertex_region, t, vertex_area, min_area=SPLIT_MIN_AREA_MM2):
        if taken[piece].any():
            continue
        _check_cancel(stop)
        parent = fits[int(seg.vertex_region[piece[0]])]
        fit = fit_region(region_samples(obs, v, data["frames"], piece, triangles=t, reference_mm=d_ref), model,
                         model_error=model_error)
        other = fit.material != parent.material and parent.material not in fit.group and fit.material not in parent.group
        if fit.spec and fit.confidence >= _RIVAL_CONFIDENCE and other:
            labels[piece] = len(fits)
            taken[piece] = True
            fits.append(fit)
            report["area_mm2"].append(round(float(vertex_area[piece].sum()), 3))
    report["regions"] = len(report["area_mm2"])
    if not report["regions"]:
        return seg, fits, report
    new = dataclasses.replace(seg, vertex_region=labels.astype(np.int32),
                              face_region=face_regions(labels, t).astype(np.int32), n_regions=len(fits))
    return new, fits, report


def _named_regions(fits: list[Any]) -> int:
    """How many regions' fits name their material (confidence at least :data:`_NAMED_CONFIDENCE`)."""
    return sum(f.confidence >= _NAMED_CONFIDENCE for f in fits)


def _region_areas(seg: Any, areas: np.ndarray) -> np.ndarray:
    """``(R,)`` area (mm2) of each region's faces."""
    measured = seg.face_region >= 0
    return np.bincount(seg.face_region[measured], weights=areas[measured], minlength=seg.n_regions)


def _decided_by_own_views(cost: np.ndarray, unnamed: list[bool]) -> np.ndarray:
    """``(V,)`` bool: the vertex's own observations favour one material by the relabelling's margin.

    Scored among the named materials (without the unnamed ones' added cost); elsewhere the label is the
    neighbours' (docs/materials.md, "Vertices the fitted materials claim").
    """
    from processing.materials.vertex_relabelling import DECIDED_NATS

    named = cost[:, [r for r, u in enumerate(unnamed) if not u]]
    if named.shape[1] < 2:
        return np.zeros(len(cost), dtype=bool)
    two = np.sort(named, axis=1)[:, :2]          # a region without a material costs infinity: never the best two
    return np.isfinite(two[:, 1]) & (two[:, 1] - two[:, 0] >= DECIDED_NATS)


def _check_pieces(obs: Any, v: np.ndarray, t: np.ndarray, data: dict[str, Any], seg: Any, fits: list[Any],
                  d_ref: float | None, model: Any, model_error: float,
                  areas: np.ndarray) -> tuple[list[Any], list[dict[str, Any]]]:
    """Each region's connected pieces tested against the other regions' materials; confidences capped.

    A piece with :data:`processing.materials.forward_fit.MIN_HIGHLIGHTS` highlight observations of its
    own that another region's fitted material explains far better than its region's
    (:func:`processing.materials.region_consistency.disagreeing_pieces`) shows that the region mixes
    materials: its answer cannot hold for that piece's area, so the region's confidence is at most the
    share of its area that does not disagree (docs/materials.md, "Parts that disagree with their region").
    """
    from processing.materials.forward_fit import HIGHLIGHT_DEG, INDEPENDENT, MIN_HIGHLIGHTS, region_samples
    from processing.materials.presets import get_material
    from processing.materials.region_consistency import disagreeing_pieces, mesh_components, pieces_chi2

    piece = mesh_components(seg.vertex_region, t)
    face_piece = np.where(seg.face_region >= 0, piece[t[:, 0]], -1)
    mats = [get_material(f.spec) if f.spec else None for f in fits]
    cos_hl = math.cos(math.radians(HIGHLIGHT_DEG))
    rows, n_obs, own, ids = [], [], [], []
    for r in range(seg.n_regions):
        samples = region_samples(obs, v, data["frames"], np.flatnonzero(seg.vertex_region == r), triangles=t,
                                 reference_mm=d_ref)
        sp = piece[samples.vertex]
        lit = np.bincount(sp[samples.cos_h >= cos_hl], minlength=int(piece.max()) + 1)
        tested = np.flatnonzero(lit[sp] >= MIN_HIGHLIGHTS)
        if not tested.size:
            continue
        p_ids, chi2, n, _ = pieces_chi2(samples.subset(tested), sp[tested], model, mats, model_error=model_error)
        rows.extend(chi2)
        n_obs.extend(n.tolist())
        own.extend([r] * p_ids.size)
        ids.extend(p_ids.tolist())
    disagrees = np.zeros(0, dtype=bool)
    better = np.zeros(0, dtype=np.int64)
    if rows:
        disagrees, better = disagreeing_pieces(np.array(rows), n_obs, own, independent=INDEPENDENT)
    out_fits, docs = [], []
    for r, fit in enumerate(fits):
        mine = [i for i, o in enumerate(own) if o == r]
        # a piece better explained by another region of the same answer is no mixture
        bad = [i for i in mine if disagrees[i] and fits[int(better[i])].material != fit.material]
        region_area = float(areas[seg.face_region == r].sum())
        bad_area = float(areas[np.isin(face_piece, [ids[i] for i in bad]) & (seg.face_region == r)].sum())
        cap = 1.0 - bad_area / region_area if region_area > 0 else 1.0
        if bad and fit.confidence > cap:
            fit = dataclasses.replace(fit, confidence=float(cap))
        out_fits.append(fit)
        docs.append({"pieces_tested": len(mine), "pieces_disagreeing": len(bad),
                     "disagreeing_area_mm2": round(bad_area, 3),
                     "disagreeing_better_regions": sorted({int(better[i]) for i in bad})})
    return out_fits, docs


def _not_measured(obs: Any, v: np.ndarray, t: np.ndarray, areas: np.ndarray, unmeasured: np.ndarray) -> dict[str, Any]:
    """What of the surface no region holds, why, which way it faces, and what to capture for it.

    A face is ``never_seen`` when no corner of it is in any fitted frame's view, else seen but never usable (the
    lamp below it or hidden by the object, or its highlights clipped).  ``facing`` is the unit mean of the faces'
    area-weighted normals in the mesh's frame (z up the table's axis) and ``coherence`` its length before
    normalising: near 1 one side of the object, near 0 hollows facing every way.
    """
    area = float(areas[unmeasured].sum())
    out: dict[str, Any] = {"faces": int(unmeasured.sum()), "area_mm2": round(area, 3),
                           "share": round(area / max(float(areas.sum()), 1e-300), 5)}
    if not unmeasured.any():
        return out
    from render.meshio import face_normals

    seen = np.zeros(len(v), dtype=bool)
    seen[obs.vertex] = True
    never = unmeasured & ~seen[t].any(axis=1)
    total = face_normals(v, t[unmeasured], unit=False).sum(axis=0)        # twice the area-weighted normal
    coherence = float(np.linalg.norm(total) / max(2.0 * area, 1e-300))
    facing = total / max(float(np.linalg.norm(total)), 1e-300)
    never_area = float(areas[never].sum())
    if coherence < 0.5:
        side = "in hollows and undersides facing every way"
    elif facing[2] <= -0.7:
        side = "on the side facing down"
    elif facing[2] >= 0.7:
        side = "on the side facing up"
    else:
        side = f"on the side facing {round(float(np.degrees(np.arctan2(facing[1], facing[0])))) % 360} deg about the table's axis"
    if never_area >= 0.5 * area:
        advice = f"mostly never in the camera's view ({never_area:.0f} mm^2), {side}: add a placement that shows it"
    else:
        advice = (f"seen but never lit ({area - never_area:.0f} mm^2: the lamp below the surface or hidden by the "
                  f"object, or every view of it clipped), {side}: add a placement that turns it toward the lamp")
    return {**out, "never_seen_mm2": round(never_area, 3), "facing": [round(float(c), 4) for c in facing],
            "coherence": round(coherence, 4), "advice": advice}


def _interior_margin_mm(vertices: np.ndarray, frames: list[Any]) -> float:
    """:data:`~processing.appearance.region_interior.MARGIN_PIXELS` photo pixels on the object (median frame), mm."""
    from processing.appearance.region_interior import MARGIN_PIXELS

    centre = vertices.mean(axis=0)
    pixel_mm = [float(np.linalg.norm(f.camera_centre_mm - centre) / f.K[0, 0]) for f in frames]
    return MARGIN_PIXELS * float(np.median(pixel_mm)) if pixel_mm else 0.0


def _baseline(regions: list[dict[str, Any]]) -> dict[str, Any]:
    """The paper's one-material model: the largest fitted region's material on the whole object."""
    fitted = [r for r in regions if r.get("spec")]
    if not fitted:
        return {"material": None, "spec": None, "note": "no region has a fitted material"}
    big = max(fitted, key=lambda r: r["area_mm2"])
    return {"material": big["material"], "spec": big["spec"], "region": big["index"],
            "note": "the largest region's material on the whole object, as Matsuda et al. rendered the hawk"}


def _reference_distance(data: dict[str, Any]) -> float | None:
    """``d_ref`` of the point lamp's relative irradiance ``(d_ref / d)^2``: first frame's lamp to the mesh centroid.

    The fit's amplitudes are relative to this irradiance, so the validation's renders use the same one
    (None for a distant lamp).
    """
    lamp = data["frames"][0].lamps[0]
    if lamp.kind != "point":
        return None
    return float(np.linalg.norm(np.asarray(lamp.vector) - data["mesh"][0].mean(axis=0)))


def _face_areas(v: np.ndarray, t: np.ndarray) -> np.ndarray:
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


def _specs(doc: dict[str, Any]) -> list[str | None]:
    return [r.get("spec") for r in doc["regions"]]


def _write_products(session: Any, root: Path, data: dict[str, Any], doc: dict[str, Any]) -> None:
    """``object-mesh.ply`` and ``object-scene.toml`` (the materials document is written by :func:`_record`)."""
    from app.session_paths import check_not_symlink
    from render.material_mesh import write_material_ply

    v, t, n = data["mesh"]
    tmp = check_not_symlink(root, ".incoming/object-mesh.ply", "object mesh staging file")
    tmp.parent.mkdir(parents=True, exist_ok=True)
    write_material_ply(tmp, v, t, n, doc["_face_region"], _specs(doc))
    check_not_symlink(root, OBJECT_MESH, "products.object_mesh")
    info = session.adopt_file(tmp, OBJECT_MESH)
    doc["mesh_sha256"] = info.sha256
    first = data["frames"][0]
    scene = object_scene_toml(v, first, doc["light_spectrum"])
    session.write_file(OBJECT_SCENE, scene.encode())


def object_scene_toml(vertices: np.ndarray, frame: Any, spectrum: Any) -> str:
    """A ``kogei render`` scene of the measured object in the booth, seen as by ``frame``'s camera.

    The camera sits where the frame's camera was (field of view from its intrinsics), the lamp
    where the frame's lamp was (a point light whose irradiance is 1 at the object's centre, as the
    chart-normalised signal); the booth is dark (no sky).
    """
    centre = vertices.mean(axis=0)
    eye = frame.camera_centre_mm
    fy, h = float(frame.K[1, 1]), float(frame.image_size[1])
    fov = math.degrees(2 * math.atan(h / 2 / fy))
    up = -np.asarray(frame.mesh_to_camera)[1, :3]           # the camera's y axis points down
    lines = ["# The measured object in the booth (kogei fit-materials); render with: kogei render object-scene.toml",
             "[render]", f'illuminant = "{spectrum}"', "", "[camera]", f"eye = {_vec(eye)}",
             f"target = {_vec(centre)}", f"up = {_vec(up)}", f"fov = {fov:.4f}", "", "[sky]", 'kind = "none"', ""]
    for lamp in frame.lamps:
        if lamp.kind == "point":
            d = float(np.linalg.norm(np.asarray(lamp.vector) - centre))
            lines += ["[[light]]", 'kind = "point"', f"position = {_vec(lamp.vector)}", f"intensity = {d * d:.6g}", ""]
        else:
            lines += ["[[light]]", 'kind = "directional"', f"direction = {_vec(lamp.vector)}", "intensity = 1.0", ""]
    lines += ["[[object]]", f'mesh = "{Path(OBJECT_MESH).name}"', ""]
    return "\n".join(lines)


def _vec(x: Any) -> str:
    return "[" + ", ".join(f"{float(c):.6g}" for c in np.asarray(x).reshape(3)) + "]"


def _validate(session: Any, root: Path, data: dict[str, Any], doc: dict[str, Any], held: np.ndarray, decode: str,
              note: Callable[[str], None], stop: Callable[[], bool]) -> dict[str, Any]:
    """Render the held-out frames with the measured materials and with the baseline; compare with the photos."""
    from app.workflows.holdout_validation import validate_frames
    from app.workflows.posed_frames import calibrated_images, noise_model
    from processing.camera.response import camera_sensitivities
    from processing.spectral.spectra import SpectralGrid, light_spectrum

    v, t, n = data["mesh"]
    names = [nm for nm, h in zip(data["obs"].frame_names, held) if h]
    frames = [f for f, h in zip(data["frames"], held) if h]
    records = [(nm, r) for nm, r, h in zip(data["obs"].frame_names, data["records"], held) if h]
    bursts = burst_records(session.manifest, records)
    n_avg = min((len(b) for b in bursts), default=1)
    photos = calibrated_images(root, session.manifest, records, decode, note)
    if n_avg > 1:
        photos = _BurstMeans(photos, calibrated_images(root, session.manifest,
                                                       [r for b in bursts for r in b[:n_avg]], decode, note), n_avg,
                             _clip_level(photos))
        note(f"held-out photos: each the linear mean of a burst of {n_avg} frames")
    grid = SpectralGrid(*_GRID)
    signal_kw = dict(sensitivities=camera_sensitivities(grid), scale=1.0, grid=grid,
                     irradiance_ref_mm=doc["irradiance_reference_mm"])
    light = light_spectrum(doc["light_spectrum"], grid)
    spread = _point_spread(root, session.manifest, data, doc, held, decode, light, signal_kw, note)
    note(f"validating on {len(frames)} held-out frames ({', '.join(names[:4])}{' ...' if len(names) > 4 else ''})")
    result = validate_frames(frames, photos, v, t, n, doc["_face_region"], _specs(doc), doc["baseline"].get("spec"),
                             light, signal_kw["sensitivities"], signal_kw["scale"],
                             irradiance_ref_mm=doc["irradiance_reference_mm"], grid=grid,
                             clip_level=_clip_level(photos), noise=noise_model(records, photos.gains),
                             cfa=_cfa(root, records[0], decode) if records else None, pool_px=POOL_PX,
                             frames_averaged=n_avg, spread_px=0.0 if spread is None else spread.sigma_px)
    result["point_spread"] = None if spread is None else spread.to_dict()
    return _write_validation(session, result)


def _lens_share_of_roughness(data: dict[str, Any], doc: dict[str, Any], held: np.ndarray, spread_px: float) -> None:
    """Each region's roughness overstatement by the measured point spread, added to its uncertainty.

    The normal smear (:func:`processing.materials.lens_smear.normal_smear_rad`) is the median over the
    region's fitted observations near the mirror direction, at the curvature of the normals the fit
    used (the mesh's shading normals); the overstatement goes in ``systematics.roughness_lens`` and, in
    quadrature, into the roughness uncertainty (docs/materials.md, "The lens's share of the roughness").
    """
    from processing.materials.forward_fit import HIGHLIGHT_DEG
    from processing.materials.lens_smear import mesh_curvature, normal_smear_rad, roughness_overstatement

    v, t, n = data["mesh"]
    curvature = mesh_curvature(v, t, n)
    obs = data["obs"]
    focal = np.array([0.5 * (float(f.K[0][0]) + float(f.K[1][1])) for f in data["frames"]])
    near = (obs.half_angle_deg[:, 0] < HIGHLIGHT_DEG) & ~held[obs.frame]
    region = _vertex_regions(t, doc["_face_region"], len(v))[obs.vertex]
    smear = normal_smear_rad(spread_px, obs.distance_mm / focal[obs.frame], curvature[obs.vertex])
    for r in doc["regions"]:
        m = (r.get("parameters") or {}).get("roughness")
        rows = near & (region == r["index"])
        if not m or not rows.any():
            continue
        s = float(np.median(smear[rows]))
        bias = roughness_overstatement(m, s)
        r["systematics"] = {"roughness_lens": round(bias, 6), "normal_smear_rad": round(s, 6)}
        unc = r.setdefault("uncertainties", {})
        unc["roughness"] = float(np.hypot(float(unc.get("roughness") or 0.0), bias))


def _point_spread(root: Path, manifest: dict[str, Any], data: dict[str, Any], doc: dict[str, Any], held: np.ndarray,
                  decode: str, light: Any, signal_kw: dict[str, Any], note: Callable[[str], None]) -> Any:
    """The camera's point spread measured on up to ``SPREAD_FRAMES`` fitted (not held-out) frames, or None.

    Each is rendered with the measured materials through a pinhole and the Gaussian spread that
    brings the renderings closest to their photos is kept
    (:func:`processing.camera.point_spread.fit_point_spread`); the held-out renderings then carry it.
    ``light`` and ``signal_kw`` are the validation's lamp spectrum and :func:`render.photo_signal.render_signal`
    settings.
    """
    from app.workflows.posed_frames import calibrated_images
    from processing.camera.point_spread import PointSpreadError, fit_point_spread
    from render.photo_signal import render_signal

    fitted = np.flatnonzero(~np.asarray(held, dtype=bool))
    if fitted.size == 0:
        return None
    pick = fitted[np.linspace(0, fitted.size - 1, min(SPREAD_FRAMES, fitted.size)).round().astype(int)]
    records = [(data["obs"].frame_names[i], data["records"][i]) for i in pick]
    photos = calibrated_images(root, manifest, records, decode, note)
    v, t, n = data["mesh"]
    renders = [render_signal(v, t, n, doc["_face_region"], _specs(doc), data["frames"][i], light, **signal_kw)
               for i in pick]
    try:
        fit = fit_point_spread([photos[k] for k in range(len(pick))], [r for r, _ in renders],
                               [m for _, m in renders], clip_level=_clip_level(photos))
    except PointSpreadError as exc:
        note(f"camera point spread not measured ({exc}); the held-out renderings are compared as a pinhole's")
        return None
    note(f"camera point spread: {'at least ' if fit.at_limit else ''}{fit.sigma_px:.2f} px (Gaussian sd) from "
         f"{len(pick)} fitted frames; rms {fit.rms_at_sigma:.4f} against {fit.rms_pinhole:.4f} through a pinhole"
         + ("; the largest spread tried: the renderings may lack fine detail the photos blur" if fit.at_limit else ""))
    return fit


def burst_records(manifest: dict[str, Any], records: list[tuple[str, dict[str, Any]]]
                  ) -> list[list[tuple[str, dict[str, Any]]]]:
    """Per frame, its burst: the frame itself then its done ``"burst"`` shots in shot order.

    A frame shot alone (no ``holdout_burst`` in the plan) is a burst of one.

    Examples
    --------
    >>> m = {"captures": {"p01/frame/02/burst/01": {"kind": "burst", "status": "done", "burst_of": "p01/frame/02",
    ...                                               "shot": 1}}}
    >>> [[c for c, _ in b] for b in burst_records(m, [("p01/frame/02", {}), ("p01/frame/03", {})])]
    [['p01/frame/02', 'p01/frame/02/burst/01'], ['p01/frame/03']]
    """
    extra: dict[str, list[tuple[int, str, dict[str, Any]]]] = {}
    for cid, rec in (manifest.get("captures") or {}).items():
        if isinstance(rec, dict) and rec.get("kind") == "burst" and rec.get("status") == "done":
            shot = rec.get("shot")
            if isinstance(shot, int) and not isinstance(shot, bool) and shot >= 1:     # else not a usable shot
                extra.setdefault(str(rec.get("burst_of")), []).append((shot, cid, rec))
    return [[(cid, rec)] + [(c, r) for _, c, r in sorted(extra.get(cid, []), key=lambda e: e[0])]
            for cid, rec in records]


class _BurstMeans(Sequence):
    """Each held-out photo as the mean of its burst of ``n`` frames, in linear signal (a lazy sequence).

    ``singles[k]`` is frame k's first shot; ``shots`` holds every frame's ``n`` shots one after the
    other.  The bilinear demosaic and the chart gain are linear, so the mean of the decoded frames is
    the decoded mean of their RAW mosaics; its noise variance is the single frame's divided by ``n``.
    A pixel that any shot clipped (at or above ``clip_level``) keeps that shot's value, so the
    comparison still leaves it out.
    """

    def __init__(self, singles: Sequence, shots: Sequence, n: int, clip_level: Any) -> None:
        self.singles, self.shots, self.n = singles, shots, n
        self.clip_level = np.asarray(clip_level, dtype=np.float64)
        self.gains, self.frames = getattr(singles, "gains", {}), getattr(singles, "frames", [])

    def __len__(self) -> int:
        return len(self.singles)

    def __getitem__(self, k: Any) -> Any:
        first = np.asarray(self.shots[k * self.n], dtype=np.float64)
        acc, top = first.copy(), first.copy()
        for j in range(1, self.n):
            shot = np.asarray(self.shots[k * self.n + j], dtype=np.float64)
            acc += shot
            np.maximum(top, shot, out=top)
        mean = acc / self.n
        clipped = top >= self.clip_level
        mean[clipped] = top[clipped]
        return mean.astype(np.float32)


def _cfa(root: Path, record: tuple[str, dict[str, Any]], decode: str) -> str | None:
    """The photos' Bayer pattern when they are demosaicked (the noise floor then demosaicks its noise too)."""
    from app.workflows.station_calibration import decode_frame

    return decode_frame(root, record[0], record[1], decode).cfa_pattern if decode == "demosaic" else None


def _clip_level(photos: Any) -> Any:
    """The photos' clip level per channel in signal units: the white level times the chart gain.

    With several passes the smallest gain of each channel over the held-out frames' passes is used
    (a pixel is never compared when it may be clipped).
    """
    from app.workflows.station_calibration import CLIP_LEVEL

    gains = [photos.gains.get(int(rec.get("pass") or 0)) for _, rec in photos.frames]
    return CLIP_LEVEL * np.min([np.ones(3) if g is None else np.asarray(g, dtype=np.float64) for g in gains], axis=0)


def _write_validation(session: Any, result: dict[str, Any]) -> dict[str, Any]:
    """Write the validation's PNGs under ``products/validation/``; the figures (no image bytes) for the document."""
    overall = result["overall"]
    floor = overall.get("noise_floor") or {}
    out = {**_figures(overall["measured"], overall["baseline"]), "n_frames": overall["n_frames"],
           "noise_floor_mean_de2000": floor.get("mean_de2000"), "noise_floor_p95_de2000": floor.get("p95_de2000"),
           "n_skipped": overall["n_skipped"], "regions": overall["regions"], "baseline_spec": result["baseline_spec"],
           "camera_to_xyz": result["camera_to_xyz"], "frames_averaged": int(result.get("frames_averaged", 1)),
           "point_spread": result.get("point_spread"), "edge_margin_px": result.get("edge_margin_px"),
           "frames": []}
    if "pooled" in overall:
        pooled = overall["pooled"]
        out["pooled"] = {"block_px": pooled["block_px"], **_figures(pooled["measured"], pooled["baseline"]),
                         "noise_floor_mean_de2000": (pooled.get("noise_floor") or {}).get("mean_de2000")}
    for entry in result["frames"]:
        row: dict[str, Any] = {"frame": entry["name"], "seconds": round(float(entry.get("seconds", 0.0)), 3)}
        if "skipped" in entry:
            row["skipped"] = entry["skipped"]
        else:
            row.update(_figures(entry["measured"], entry["baseline"]))
            row["clipped_pixels"] = entry.get("clipped_pixels")
        if "pooled" in entry:
            row["pooled"] = _figures(entry["pooled"]["measured"], entry["pooled"]["baseline"])
        for key in ("triptych_png", "error_map_png", "baseline_error_map_png", "pooled_error_map_png"):
            if isinstance(entry.get(key), (bytes, bytearray)):
                rel = f"{VALIDATION_DIR}/{str(entry['name']).replace('/', '_')}-{key[:-4].replace('_', '-')}.png"
                session.write_file(rel, bytes(entry[key]))
                row[key[:-4]] = rel
        out["frames"].append(row)
    return out


def _figures(measured: dict[str, Any], baseline: dict[str, Any]) -> dict[str, Any]:
    """Flat figures of one comparison: measured and baseline mean / p95 / median CIEDE2000 and pixels."""
    return {"mean_de2000": measured.get("mean_de2000"), "p95_de2000": measured.get("p95_de2000"),
            "median_de2000": measured.get("median_de2000"), "pixels": measured.get("n_pixels"),
            "baseline_mean_de2000": baseline.get("mean_de2000"), "baseline_p95_de2000": baseline.get("p95_de2000"),
            "baseline_median_de2000": baseline.get("median_de2000")}


def _record(session: Any, doc: dict[str, Any]) -> None:
    """Write the materials document and reference the products from the manifest."""
    face_region = doc.pop("_face_region")
    doc["faces"] = int(face_region.size)
    blob = (json.dumps(doc, indent=1, allow_nan=False) + "\n").encode()
    info = session.write_file(OBJECT_MATERIALS, blob)
    products = dict(session.manifest.get("products") or {})
    products["object_materials"] = {"file": OBJECT_MATERIALS, "sha256": info.sha256, "bytes": info.bytes}
    products["object_mesh"] = {"file": OBJECT_MESH, "sha256": doc.get("mesh_sha256")}
    products["object_scene"] = {"file": OBJECT_SCENE}
    session.update("products", products)
    named = ", ".join(f"{r['material']}" for r in doc["regions"])
    val = doc.get("validation") or {}
    de = val.get("mean_de2000")
    session.event("materials measured", f"{len(doc['regions'])} regions ({named})"
                  + ("" if de is None else f"; held-out mean dE00 {de:.2f} (one material: "
                                           f"{val.get('baseline_mean_de2000', float('nan')):.2f})"))


def read_object_materials(session_dir: str | Path) -> dict[str, Any]:
    """The session's ``products/object-materials.json`` (checksum checked).

    Raises :class:`UsageError` when the session has no measured materials or the file is damaged.
    """
    import hashlib

    from app.session import Session
    from app.session_paths import MAX_JSON_BYTES, read_confined_bytes
    from app.workflows._materials_document import materials_document_problem
    from processing.common.files import JSONFileError, parse_json

    root = Path(session_dir)
    ref = (Session.read(root).get("products") or {}).get("object_materials")
    if not isinstance(ref, dict):
        raise UsageError(f"session {root} has no materials measured on its mesh; run kogei fit-materials {root}")
    blob = read_confined_bytes(root, ref.get("file"), "products.object_materials.file", MAX_JSON_BYTES)
    if isinstance(ref.get("sha256"), str) and hashlib.sha256(blob).hexdigest() != ref["sha256"]:
        raise UsageError(f"session {root}: {ref.get('file')} does not match its checksum; run kogei fit-materials "
                         f"{root} again")
    where = str(root / str(ref.get("file")))
    try:
        doc = parse_json(blob, where, f"run kogei fit-materials {root} again")
    except JSONFileError as exc:
        raise UsageError(str(exc)) from None
    if not isinstance(doc, dict) or doc.get("schema") != "kogei.object_materials" or doc.get("version") != 1:
        raise UsageError(f"{where}: not a kogei.object_materials version 1 document; rerun kogei fit-materials")
    problem = materials_document_problem(doc)       # the regions' list and indices, then every field by kind
    if problem:
        raise UsageError(f"{where}: {problem}; the file is damaged or was not written by kogei: run kogei "
                         f"fit-materials {root} again")
    return doc


def object_mesh_file(root: Path, doc: dict[str, Any]) -> Path:
    """The materials document's mesh (``products/object-mesh.ply``), confined to the session and of the same run.

    The document records the SHA-256 of the mesh written with it (``mesh_sha256``); a mesh of another run (one
    interrupted or refused after writing it) does not match, and its regions would be mixed with the document's.
    Raises :class:`UsageError` naming the file and what to run.
    """
    from app.session_paths import MAX_PRODUCT_BYTES, confined_file
    from processing.common.files import sha256_file

    where = root / OBJECT_MATERIALS
    rel = doc.get("mesh", OBJECT_MESH)
    try:
        path = confined_file(root, rel, "materials file mesh", MAX_PRODUCT_BYTES)
    except FileNotFoundError:
        raise UsageError(f"{where}: its mesh {rel!r} is missing; run kogei fit-materials {root} again") from None
    digest = doc.get("mesh_sha256")
    if isinstance(digest, str) and sha256_file(path) != digest:
        raise UsageError(f"{where}: its mesh {rel!r} is not the one written with it (another run's, or edited); run "
                         f"kogei fit-materials {root} again")
    return path


def _vertex_regions(triangles: np.ndarray, face_region: np.ndarray, n_vertices: int) -> np.ndarray:
    """Region of each vertex: the region of most of its faces (-1 where none is measured)."""
    n_regions = int(face_region.max()) + 1 if face_region.size and face_region.max() >= 0 else 0
    votes = np.zeros((n_vertices, n_regions + 1))
    np.add.at(votes, (triangles.ravel(), np.repeat(np.where(face_region >= 0, face_region, n_regions), 3)), 1.0)
    best = np.argmax(votes[:, :n_regions], axis=1) if n_regions else np.zeros(n_vertices, dtype=np.int64)
    measured = votes[:, :n_regions].sum(axis=1) > 0 if n_regions else np.zeros(n_vertices, dtype=bool)
    return np.where(measured, best, -1)


def face_region_at(session_dir: str | Path, origin_mm: Any, direction: Any) -> int | None:
    """The region index of the measured object's face hit by a ray (mesh frame), or None for a miss.

    Used by the window: a click on the rendered object becomes a ray from the view's camera.
    """
    import open3d as o3d

    from render.material_mesh import read_material_mesh

    root = Path(session_dir)
    mesh = read_material_mesh(object_mesh_file(root, read_object_materials(root)))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)),
                        o3d.core.Tensor(mesh.triangles.astype(np.uint32)))
    ray = np.concatenate([np.asarray(origin_mm, np.float32).reshape(3), np.asarray(direction, np.float32).reshape(3)])
    ans = scene.cast_rays(o3d.core.Tensor(ray[None, :]))
    if not np.isfinite(ans["t_hit"].numpy()[0]):
        return None
    return int(mesh.face_material[int(ans["primitive_ids"].numpy()[0])])


def region_observations(session_dir: str | Path, region: int, *, max_points: int = 3000) -> dict[str, Any]:
    """A region's observations (fit frames) against its fitted model, for a plot.

    Parameters
    ----------
    session_dir
        A session whose materials were measured (``kogei fit-materials``).
    region
        The region index.
    max_points
        At most this many observations are returned (an even subsample).

    Returns
    -------
    dict
        ``half_angle_deg (n,)``, ``observed (n, 3)``, ``predicted (n, 3)`` (None when the region has no
        fitted material), ``region`` (its record in the materials file).
    """
    from processing.appearance.observations import select_frames
    from processing.materials.forward_fit import region_samples
    from processing.materials.presets import get_material
    from render.material_mesh import read_material_mesh

    root = Path(session_dir)
    doc = read_object_materials(root)
    rec = next((r for r in doc["regions"] if r.get("index") == region), None)
    if rec is None:
        raise UsageError(f"session {root}: no region {region}; regions: 0..{len(doc['regions']) - 1}")
    from app.session import Session

    data = _load_inputs(root, Session.read(root))
    mesh = read_material_mesh(object_mesh_file(root, doc))
    fit = set((doc.get("frames") or {}).get("fit") or [])
    obs = select_frames(data["obs"], np.array([n in fit for n in data["obs"].frame_names]))
    ids = np.flatnonzero(_vertex_regions(mesh.triangles, mesh.face_material, len(mesh.vertices)) == region)
    samples = region_samples(obs, mesh.vertices, data["frames"], ids, triangles=mesh.triangles)
    keep = np.linspace(0, len(samples.signal) - 1, min(max_points, len(samples.signal))).astype(np.int64) \
        if len(samples.signal) else np.zeros(0, dtype=np.int64)
    half = np.degrees(np.arccos(np.clip(samples.cos_h[keep], -1.0, 1.0)))
    predicted = None
    if rec.get("spec"):
        model, _ = _forward_model(doc.get("light_spectrum"), lambda text: None)
        predicted = model.predict(get_material(rec["spec"]), samples)[keep]
    return {"region": rec, "half_angle_deg": half, "observed": np.asarray(samples.signal)[keep],
            "predicted": predicted}
