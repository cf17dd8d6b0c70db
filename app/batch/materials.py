"""The ``materials`` step of ``kogei batch``: the object's regions and their identified materials per pass.

docs/batch.md.  Matsuda et al., section 4: for each pass the chart frame, as
measured by the colour step (its patch means in ``products/colour/pNN-chart.json``),
calibrates the spectral estimator (``rootpoly``, the default of ``kogei
spectral estimate``, through the same chain:
:func:`app.workflows.spectral.estimate_from_chart`); every object RAW frame
of the pass gives basis weights and chart-calibrated camera values with
saturated and dead pixels masked (:func:`estimate_frame`).  The frames of a pass are
pooled side by side, split into regions without ground truth
(:func:`processing.materials.segmentation.segment_regions`: backdrop removed
by its level and colour measured on the frame's border, lit pixels clustered
by chromaticity), each cluster identified (:func:`app.workflows.identification.
identify_result`: eq. (11), (3)-(4)), and clusters whose identified material
agrees merged and identified again as one region.  The camera's lens mixes
neighbouring colours over about a pixel: a cluster that is only the mixed
edge between two others (no pixel with all of its neighbours in it) is given
back to them, and each cluster is identified from its interior pixels (its
edge pixels hold its neighbours' light too); the map and the pixel counts
keep every pixel (``pixels_identified`` says how many were used).

Products: ``products/materials.json`` (per region: pixel count, pixels identified, frames,
material, confidence, runner-up, chi-square, alloy weights with their
standard deviations, mean reflectance with its uncertainty) and a material
map PNG per object frame (``products/materials/pNN-frame_KK.png``, each
pixel coloured by its region's material under D65, backdrop dark grey).

The regions are found in the images only: without the camera's pose
relative to the table (not recorded by a session) they are not mapped onto
the mesh.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.errors import UsageError
from app.session_paths import MAX_JSON_BYTES, check_not_symlink, confined_file, read_confined_bytes
from processing.common.files import parse_json
from processing.common.png import png_bytes
from processing.errors import InputError
from processing.materials.identification import DEFAULT_MODEL_ERROR

__all__ = ["materials_inputs", "materials_params", "materials_run", "estimate_frame", "largest_material",
           "material_colour", "METHOD", "LIGHT_DEG", "MODEL_ERROR", "MATERIALS_FILE", "MERGE_CONFIDENCE"]

#: Spectral estimator (the best one-shot method in docs/BENCHMARKS.md, ``kogei spectral estimate``'s default).
METHOD = "rootpoly"
#: Light angle from the normal at which candidates are modelled (``kogei identify``'s default).
LIGHT_DEG = 30.0
#: Relative model error of the candidates: a region pools many pixels at varying angles (app.demo.colour);
#: the one default of every identification (``kogei identify``'s too).
MODEL_ERROR = DEFAULT_MODEL_ERROR
#: Least confidence of a cluster's answer for it to be merged with the other clusters of that material.
MERGE_CONFIDENCE = 0.5
MATERIALS_FILE = "products/materials.json"
MAPS_DIR = "products/materials"
_BACKDROP_COLOUR = (40, 40, 40)
_UNIDENTIFIED_COLOUR = (255, 0, 255)
_RENDERABLE = ("metal", "alloy", "dielectric")


def _frames_of_pass(manifest: dict[str, Any], number: int) -> list[tuple[str, dict[str, Any]]]:
    return [(cid, rec) for cid, rec in sorted(manifest["captures"].items())
            if rec.get("kind") == "frame" and rec.get("status") == "done" and int(rec.get("pass", 0)) == number]


def materials_inputs(root: Path, manifest: dict[str, Any], options: Any) -> dict[str, str]:
    inputs = {cid: rec.get("sha256", "") for cid, rec in sorted(manifest["captures"].items())
              if rec.get("kind") == "frame"}
    colour = (manifest.get("products") or {}).get("colour") or {}
    for tag, files in sorted((colour.get("passes") or {}).items()):
        inputs[f"colour/{tag}"] = (files.get("chart") or {}).get("sha256", "")
    return inputs


def materials_params(options: Any) -> dict[str, Any]:
    return {"chart": options.chart, "method": METHOD, "light_deg": LIGHT_DEG, "model_error": MODEL_ERROR,
            "mode": "bin2x2"}


def material_colour(name: str | None) -> tuple[int, int, int]:
    """8-bit sRGB of a material on the map: its colour under D65; grey for a neutral metal, magenta for none or no fit.

    Examples
    --------
    >>> material_colour(None)
    (255, 0, 255)
    """
    from app.workflows.materials import preset_srgb
    from processing.materials.identification import NEUTRAL_METAL, NO_FIT

    if name is None or name == NO_FIT:
        return _UNIDENTIFIED_COLOUR
    if name == NEUTRAL_METAL:
        return (190, 190, 198)
    return tuple(int(v) for v in preset_srgb(name))


def largest_material(regions: list[dict[str, Any]]) -> tuple[str, int] | None:
    """The identified material covering most pixels over all regions (metals, alloys, lacquers), with its count.

    A region answered with a confidence below :data:`MERGE_CONFIDENCE` (a short list, not a name) does not count.

    Examples
    --------
    >>> largest_material([{"material": "gold", "pixels": 10}, {"material": "copper", "pixels": 6},
    ...                   {"material": "copper", "pixels": 7}, {"material": None, "pixels": 50},
    ...                   {"material": "gold", "pixels": 9, "confidence": 0.2}])
    ('copper', 13)
    """
    from processing.materials.identification import NEUTRAL_METAL, NO_FIT
    from processing.materials.presets import get_material

    totals: dict[str, int] = {}
    for reg in regions:
        name = reg.get("material")
        if name is None or name in (NEUTRAL_METAL, NO_FIT) or get_material(name).family not in _RENDERABLE:
            continue
        if float(reg.get("confidence") if reg.get("confidence") is not None else 1.0) < MERGE_CONFIDENCE:
            continue
        totals[name] = totals.get(name, 0) + int(reg["pixels"])
    if not totals:
        return None
    name = max(sorted(totals), key=lambda n: totals[n])
    return name, totals[name]


def _chart_record(root: Path, tag: str, files: dict[str, Any]) -> dict[str, Any]:
    import hashlib

    rec = files.get("chart") or {}
    try:
        blob = read_confined_bytes(root, rec.get("file", ""), f"products.colour.passes.{tag}.chart.file",
                                   MAX_JSON_BYTES)
    except FileNotFoundError:
        blob = None
    if blob is None or hashlib.sha256(blob).hexdigest() != rec.get("sha256"):
        raise UsageError(f"session {root}: {rec.get('file', tag)} is missing or changed since the colour step "
                         f"wrote it; run 'kogei batch {root} --steps colour' again")
    return parse_json(blob, f"session {root}: {rec.get('file', tag)}", f"run 'kogei batch {root} --steps colour' "
                                                                       "again")


def _pooled(results: list[Any]) -> Any:
    """One spectral result of a pass's frames side by side (their pixels pool per region)."""
    from app.workflows.spectral import SpectralResult

    first = results[0]
    return SpectralResult(
        np.concatenate([r.weights for r in results], axis=1), first.basis, first.wavelengths,
        np.concatenate([r.mask for r in results], axis=1), np.concatenate([r.camera for r in results], axis=1),
        first.sensitivities, first.lights, first.method,
        {**first.metadata, "chart_rmse": max(r.method_error for r in results)})


def _relative_levels(result: Any) -> NDArray[np.float64]:
    """Camera values over those of a white diffuser lit like the chart (1.0 = white)."""
    from app.workflows.identification import white_response

    white = white_response(result)
    return result.camera.astype(np.float64) / np.maximum(white, 1e-12)


def _identify_merged(result: Any, labels: NDArray[np.int64]) -> tuple[NDArray[np.int64], list[Any], dict[int, int]]:
    """Identify every cluster, merge clusters of the same material, identify the merged regions.

    Returns the merged labels, their reports and how many clusters each merged region holds.
    """
    from app.workflows.identification import identify_result
    from processing.materials.identification import NO_FIT

    labels = _mixed_edges(labels)
    reports = identify_result(result, _interior(labels), light_deg=LIGHT_DEG, model_error=MODEL_ERROR)
    groups: dict[Any, list[int]] = {}
    for rep in reports:
        # an unidentified cluster, one no candidate fits, or one whose answer is less likely than not (a short
        # list: a highlight's fringe, a cluster straddling two materials) stays on its own; the others group by
        # material
        named = rep.material not in (None, NO_FIT) and (rep.confidence or 0.0) >= MERGE_CONFIDENCE
        key = rep.material if named else ("none", rep.label)
        groups.setdefault(key, []).append(rep.label)
    order = sorted(groups.values(), key=lambda g: -sum(int((labels == v).sum()) for v in g))
    lut = np.zeros(int(labels.max()) + 1, np.int64)
    for new, members in enumerate(order, start=1):
        lut[members] = new
    merged = lut[labels]
    counts = {new: len(members) for new, members in enumerate(order, start=1)}
    return merged, identify_result(result, _interior(merged), light_deg=LIGHT_DEG, model_error=MODEL_ERROR), counts


def _mixed_edges(labels: NDArray[np.int64], rounds: int = 4) -> NDArray[np.int64]:
    """Clusters that are only the lens-mixed edge between two others, given pixel by pixel to their neighbours.

    A cluster none of whose pixels has all of its 3 x 3 neighbours in it, and which borders at least two
    other clusters, is at most two pixels wide along their common edge: the camera's point spread mixes the
    two there, so it is no material of its own.  Each of its pixels takes the most frequent other cluster
    among its 3 x 3 neighbours (repeated ``rounds`` times inward); the backdrop (0) is never given pixels.

    Examples
    --------
    >>> lab = np.ones((5, 8), np.int64); lab[:, 4:] = 2; lab[:, 3] = 3
    >>> _mixed_edges(lab).tolist()[2]
    [1, 1, 1, 1, 2, 2, 2, 2]
    >>> line = np.ones((5, 8), np.int64); line[2, 1:7] = 3      # a thin highlight inside one cluster stays
    >>> _mixed_edges(line).tolist()[2]
    [1, 3, 3, 3, 3, 3, 3, 1]
    """
    lab = np.asarray(labels, dtype=np.int64).copy()
    same = _uniform(lab)
    thin = [c for c in np.unique(lab[lab > 0]).tolist() if not same[lab == c].any()]
    for c in thin:
        around = np.unique(_neighbours(lab)[:, lab == c])
        if np.count_nonzero((around != c) & (around > 0)) < 2:
            continue
        for _ in range(rounds):
            members = np.flatnonzero((lab == c).ravel())
            near = _neighbours(lab).reshape(8, -1)[:, members]
            near = np.where((near != c) & (near > 0), near, 0)
            if not near.any():
                break
            counts = np.stack([(near == k).sum(axis=0) for k in range(int(lab.max()) + 1)])
            counts[0] = 0
            rows = np.flatnonzero(counts.max(axis=0) > 0)
            lab.ravel()[members[rows]] = counts.argmax(axis=0)[rows]
    return lab


def _interior(labels: NDArray[np.int64]) -> NDArray[np.int64]:
    """``labels`` with 0 on a cluster's edge pixels (a 3 x 3 neighbour in another cluster or the backdrop).

    The camera's lens mixes the neighbour's light into those pixels, so they hold neither material's colour;
    a cluster with no interior pixel (a thin one) keeps all of its pixels.

    Examples
    --------
    >>> lab = np.ones((5, 8), np.int64); lab[:, 4:] = 2; lab[:, 7] = 3
    >>> _interior(lab).tolist()[2]               # 3 is one column wide: it keeps its pixels
    [1, 1, 1, 0, 0, 2, 0, 3]
    """
    lab = np.asarray(labels, dtype=np.int64)
    out = np.where(_uniform(lab), lab, 0)
    lost = np.setdiff1d(np.unique(lab[lab > 0]), np.unique(out[out > 0]))
    keep = np.isin(lab, lost)
    out[keep] = lab[keep]
    return out


def _uniform(lab: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Pixels whose 3 x 3 neighbourhood (edges extended) holds only their own label."""
    from scipy.ndimage import maximum_filter, minimum_filter

    return (maximum_filter(lab, size=3, mode="nearest") == lab) & (minimum_filter(lab, size=3, mode="nearest") == lab)


def _neighbours(lab: NDArray[np.int64]) -> NDArray[np.int64]:
    """``(8, H, W)`` each pixel's eight neighbours' labels (edges extended)."""
    h, w = lab.shape
    pad = np.pad(lab, 1, mode="edge")
    return np.stack([pad[1 + dy:1 + dy + h, 1 + dx:1 + dx + w] for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dy or dx])


def estimate_frame(frame: Path, chart: dict[str, Any], chart_type: str = "classic24") -> Any:
    """One object frame's spectral estimate (:data:`METHOD`), calibrated by the colour step's chart report.

    The report's patch means are those ``kogei spectral estimate`` measures
    on the chart frame, and the estimate is the same call
    (:func:`app.workflows.spectral.estimate_spectral` with the measurement),
    so the weights equal the command's for the same frames.
    """
    from app.workflows.chart import ChartMeasurement
    from app.workflows.spectral import estimate_spectral

    return estimate_spectral(frame, ChartMeasurement.from_report(chart), method=METHOD, chart_type=chart_type)


def _pass_materials(root: Path, tag: str, chart: dict[str, Any], frames: list[tuple[str, dict[str, Any]]],
                    options: Any, log: Callable[[str], None]) -> tuple[list[dict[str, Any]], dict[str, bytes], dict]:
    from processing.materials.segmentation import SegmentationError, segment_regions

    results = []
    for cid, rec in frames:
        try:
            frame = confined_file(root, rec.get("file"), f"captures.{cid}.file")
            results.append(estimate_frame(frame, chart, options.chart))
        except InputError as exc:
            raise UsageError(f"{cid} ({rec['file']}): {exc}") from None
    pooled = _pooled(results)
    try:
        seg = segment_regions(_relative_levels(pooled), pooled.mask)
    except SegmentationError as exc:
        raise UsageError(f"{tag}: {exc}") from None
    widths = [r.mask.shape[1] for r in results]
    edges = np.cumsum([0] + widths)
    info = {"chart_rmse": pooled.method_error, "backdrop_level": seg.backdrop_rgb.tolist(),
            "clusters": int(seg.labels.max()), "masked_pixels": int((~pooled.mask).sum())}
    if seg.labels.max() == 0:
        log(f"{tag}: no lit object pixel apart from the backdrop in {len(frames)} frame(s)")
        merged, reports, counts = seg.labels, [], {}
    else:
        merged, reports, counts = _identify_merged(pooled, seg.labels)
    from app.workflows.identification import usable_regions

    live = usable_regions(pooled, merged)
    regions = []
    colours = np.zeros((len(reports) + 1, 3), np.uint8)
    for rep in reports:
        cols = np.flatnonzero((live == rep.label).any(axis=0))
        in_frames = [cid for (cid, _), a, b in zip(frames, edges[:-1], edges[1:]) if np.any((cols >= a) & (cols < b))]
        colours[rep.label] = material_colour(rep.material)
        regions.append({"region": f"{tag}-r{rep.label}", "pass": tag, "clusters": counts.get(rep.label, 1),
                        "frames": in_frames, **{k: v for k, v in rep.as_dict().items() if k != "label"},
                        "pixels": int((live == rep.label).sum()), "pixels_identified": rep.as_dict()["pixels"]})
    maps = {}
    for (cid, _), a, b in zip(frames, edges[:-1], edges[1:]):
        img = colours[np.where(live[:, a:b] > 0, live[:, a:b], 0)]
        img[(live[:, a:b] == 0) & seg.backdrop[:, a:b]] = _BACKDROP_COLOUR
        maps[cid] = png_bytes(img)
    return regions, maps, info


def materials_run(root: Path, options: Any, log: Callable[[str], None]) -> dict[str, Any]:
    from app.session import Session

    manifest = Session.read(root)
    charts = [cid for cid, rec in manifest["captures"].items() if rec.get("kind") == "chart" and
              rec.get("status") == "done"]
    if not charts:
        raise UsageError(f"session {root} has no colour-chart frame, so its RAW frames cannot be calibrated and "
                         "no material can be identified; capture with the camera on, the chart in the first frame "
                         "of every pass")
    colour = (manifest.get("products") or {}).get("colour")
    if not colour or not colour.get("passes"):
        raise UsageError(f"session {root}: the colour step has not run (its chart products calibrate the "
                         f"materials step); run 'kogei batch {root} --steps colour,materials'")
    if colour.get("chart") != options.chart:
        raise UsageError(f"session {root}: the colour step read a {colour.get('chart')} chart, this run says "
                         f"--chart {options.chart}; run the colour step with --chart {options.chart} first")
    regions, maps, passes = [], {}, {}
    for tag, files in sorted(colour["passes"].items()):
        frames = _frames_of_pass(manifest, int(tag.lstrip("p")))
        if not frames:
            log(f"{tag}: no object RAW frame; skipped")
            continue
        chart = _chart_record(root, tag, files)
        regs, pass_maps, info = _pass_materials(root, tag, chart, frames, options, log)
        regions += regs
        maps.update(pass_maps)
        passes[tag] = {**info, "frames": [cid for cid, _ in frames]}
        for reg in regs:
            conf = "" if reg["confidence"] is None else f" ({reg['confidence']:.2f})"
            log(f"{reg['region']}: {reg['material'] or 'not identified'}{conf}, {reg['pixels']} pixels")
    if not maps:
        raise UsageError(f"session {root} has no object RAW frame in a pass with a chart frame; capture with "
                         "the camera on (--camera-angles)")
    from app.workflows.spectral import GRID
    from processing.spectral.spectra import SpectralGrid

    wavelengths = SpectralGrid(*GRID).wavelengths.tolist()
    largest = largest_material(regions)
    doc = {"format": "kogei-materials", "version": 1, "method": METHOD, "light_deg": LIGHT_DEG,
           "model_error": MODEL_ERROR, "chart": options.chart, "wavelengths": wavelengths, "passes": passes,
           "regions": regions,
           "largest": None if largest is None else {"material": largest[0], "pixels": largest[1]}}
    check_not_symlink(root, f"{MAPS_DIR}/x", "materials products")
    with Session.open(root) as session:
        rep = session.write_file(MATERIALS_FILE, (json.dumps(doc, indent=1, allow_nan=False) + "\n").encode())
        files = {}
        for cid, png in maps.items():
            info = session.write_file(f"{MAPS_DIR}/{cid.replace('/', '-')}.png", png)
            files[cid] = {"file": info.path, "sha256": info.sha256, "bytes": info.bytes}
        products = dict(session.manifest.get("products") or {})
        products["materials"] = {"report": {"file": rep.path, "sha256": rep.sha256, "bytes": rep.bytes},
                                 "maps": files, "largest": doc["largest"]}
        session.update("products", products)
    identified = sum(r["material"] is not None for r in regions)
    log(f"materials: {identified} of {len(regions)} regions identified"
        + (f", largest {largest[0]} ({largest[1]} pixels)" if largest else ""))
    return {"products": ("materials",),
            "summary": {"regions": len(regions), "identified": identified,
                        "largest": None if largest is None else largest[0]}}
