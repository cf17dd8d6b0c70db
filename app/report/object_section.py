"""The report's "Materials on the mesh" section: the digitised object and how well it predicts photos.

Shown when the session's materials were measured on the mesh (``kogei fit-materials`` or the batch's
``materials`` step on a posed session): the material map on the mesh from four sides, one row per
region (material, confidence, parameters with their uncertainties, area, observations, and for a
region not measured what to capture), the held-out-photo error next to the one-material baseline,
photo | render | error triptychs of the held-out frames, and the confidence calibration measured by
the bench with this session's answers marked on it.
"""

from __future__ import annotations

import collections
import json
from collections.abc import Callable
from importlib import resources
from typing import Any

import numpy as np

__all__ = ["object_materials_section", "bench_reliability"]

#: Held-out triptychs shown (the rest are listed in the table).
MAX_TRIPTYCHS = 6


def bench_reliability() -> dict[str, Any] | None:
    """The reliability table the bench measured for on-mesh identification (shipped with kogei), or None."""
    try:
        text = resources.files("app.report").joinpath("reliability.json").read_text(encoding="utf-8")
    except (FileNotFoundError, OSError):
        return None
    doc = json.loads(text)
    return doc if isinstance(doc, dict) and {"stated", "observed", "count", "ece"} <= set(doc) else None


def _param_text(r: dict[str, Any]) -> str:
    unc = r.get("uncertainties") or {}
    return ", ".join(f"{k} {float(v):.3g} ± {float(unc[k]):.2g}" if k in unc else f"{k} {float(v):.3g}"
                     for k, v in (r.get("parameters") or {}).items())


def _judged(doc: dict[str, Any]) -> list[tuple[dict[str, Any], Any]]:
    """Every region with its verdict (:func:`app.report.readable.verdict`)."""
    from app.report.readable import verdict

    return [(r, verdict(r.get("material"), r.get("confidence"), r.get("chi2_per_dof"), r.get("group"),
                        r.get("reason") or ""))
            for r in doc.get("regions") or [] if isinstance(r, dict)]


def _rows(judged: list[tuple[dict[str, Any], Any]]) -> list[list[Any]]:
    """The plain table: region, answer, verdict, why, confidence, area."""
    return [[r.get("index"), v.answer, v.label, v.why, _confidence(r, v), _area(r)] for r, v in judged]


def _area(r: dict[str, Any]) -> str:
    """The region's area, and how much of it only its neighbours decided (its own views could not)."""
    nb = r.get("area_by_neighbours_mm2")
    return f"{float(r.get('area_mm2') or 0):.0f}" + (f" ({float(nb):.0f} by its neighbours)" if nb else "")


def _confidence(r: dict[str, Any], v: Any) -> str:
    """A region's confidence, or "-" when it names no material (the best candidate's is in the details)."""
    if v.answer in ("no candidate fits", "not measured") or r.get("confidence") is None:
        return "-"
    return f"{float(r['confidence']):.2f}"


def _technical_rows(judged: list[tuple[dict[str, Any], Any]]) -> list[list[Any]]:
    """The specialists' table: candidates, parameters, observations, misfit, what to capture."""
    from app.report.readable import misfit_number

    return [[r.get("index"), ", ".join(r.get("group") or []) if len(r.get("group") or []) > 1 else "",
             f"{float(r.get('confidence') or 0):.2f}", _param_text(r), f"{r.get('n_lit')} / {r.get('n_observations')}",
             misfit_number(r.get("chi2_per_dof")), r.get("reason") or ""] for r, v in judged]


def object_materials_section(ctx: Any, kit: dict[str, Callable[..., Any]]) -> tuple[str, bool]:
    """The section's HTML body and whether it has content.

    Parameters
    ----------
    ctx
        The report's session context (manifest, checked product reads).
    kit
        The report's HTML helpers: ``table``, ``kv``, ``img``, ``missing``, ``lead``, ``caveat``,
        ``details`` and ``verdict_table``.

    Returns
    -------
    tuple
        ``(html, shown)``.
    """
    doc = ctx.product_json("object_materials")
    if doc is None:
        return kit["missing"]("no materials measured on the mesh (the photos must be posed on it first)",
                              f"kogei fit-materials {ctx.root}"), False
    judged = _judged(doc)
    counts = collections.Counter(v.level for _, v in judged)
    nm = doc.get("not_measured") or {}
    body = kit["lead"](
        f"The photos, laid onto the 3-D mesh, show every part of the surface from several directions. The surface "
        f"was divided into {len(judged)} regions that reflect light alike, and for each the known material (metal, "
        f"alloy, lacquer) that best explains how its brightness and colour change with the angle was fitted: "
        f"{counts['reliable']} reliable, {counts['uncertain']} uncertain, {counts['unreliable']} unreliable, "
        f"{counts['missing']} not measured. A 'neutral metal' is one of the colourless metals (silver, aluminium, "
        "tin, ...), which the camera cannot tell apart.")
    bad = [(r, v) for r, v in judged if v.level == "unreliable"]
    if bad:
        body += kit["caveat"](f"{len(bad)} of {len(judged)} regions are unreliable and must not be taken as "
                              "identified: " + ", ".join(f"region {r.get('index')} ({v.answer})" for r, v in bad)
                              + ". The table says why for each.")
    body += _map(ctx, doc, judged, kit)
    levels = [v.level for _, v in judged]
    body += kit["verdict_table"](["region", "answer", "verdict", "why", "confidence", "area (mm²)"], _rows(judged),
                                 levels)
    technical = kit["verdict_table"](["region", "closest candidates", "best candidate's confidence",
                                      "parameters (± 1 sigma)",
                                      "lit / all observations", "misfit", "what to capture"],
                                     _technical_rows(judged), levels)
    body += kit["details"](technical + kit["kv"]([
        ("segmentation", (doc.get("segmentation") or {}).get("method")),
        ("lamp spectrum assumed", doc.get("light_spectrum")),
        ("model error", f"{100 * float(doc.get('model_error') or 0):.1f} % (added to the noise)"),
        ("not measured", f"{nm.get('faces', 0)} faces, {float(nm.get('area_mm2', 0)):.0f} mm²"
                         + (f"; {nm['advice']}" if isinstance(nm.get("advice"), str) else "")),
        ("fit / held-out frames", f"{len((doc.get('frames') or {}).get('fit') or [])} / "
                                  f"{len((doc.get('frames') or {}).get('held_out') or [])}"),
        ("misfit", "reduced chi-square of the fit: 1 means it matches within the measurement noise; above 25 no "
                   "candidate fits"),
        ("parameters", "Ag, Cu, Au: alloy composition (fractions); roughness: 0 mirror-like .. 1 matte; gloss, "
                       "mirror, diffuse: relative to the colour chart's white")]), "How the regions were fitted")
    body += _validation(ctx, doc, kit)
    rel = bench_reliability()
    if rel is not None:
        from app.report.object_figures import reliability_figure

        marks = [(f"{r.get('index')}: {r.get('material')}", float(r.get("confidence") or 0))
                 for r in doc.get("regions") or [] if isinstance(r, dict)]
        body += kit["details"](kit["img"](
            reliability_figure(rel, marks), "confidence calibration",
            f"Stated confidence against the share right over {int(np.nansum(rel['count']))} simulated regions "
            f"({rel.get('source', 'bench')}); red: this session's regions."),
            "Can the confidences be believed? (measured on simulated objects)")
    return body, True


def _map(ctx: Any, doc: dict[str, Any], judged: list[tuple[dict[str, Any], Any]],
         kit: dict[str, Callable[..., Any]]) -> str:
    """The material map on the mesh from four sides (empty when the mesh file is unreadable)."""
    from app.report.figures import palette_colour
    from app.report.object_figures import material_views_figure
    from render.errors import MeshError
    from render.material_mesh import read_material_mesh

    path = ctx.product_path(ctx.products.get("object_mesh") or {}, "products.object_mesh")
    if path is None:
        return ""
    try:
        mesh = read_material_mesh(path)
    except MeshError as exc:
        ctx.problems.append(f"products.object_mesh: {exc}")
        return ""
    regions = [r for r, _ in judged]
    colours = [palette_colour(i) for i in range(len(judged))]
    labels = [f"region {r.get('index')}: {v.answer} ({v.label})" for r, v in judged]
    png = material_views_figure(mesh.vertices, mesh.triangles, mesh.face_material, regions, colours, labels)
    return kit["img"](png, "material map on the mesh",
                      "The object from four sides, each region in its own colour (legend: region, answer, verdict; "
                      "grey: not measured). The colours only tell the regions apart; they are not the materials' "
                      "own colours.")


def _validation(ctx: Any, doc: dict[str, Any], kit: dict[str, Callable[..., Any]]) -> str:
    """Held-out-photo figures and triptychs (each render captioned with the materials it shows)."""
    from app.report.summary import render_materials_text

    val = doc.get("validation") or {}
    if val.get("mean_de2000") is None:
        return "<p>" + (val.get("note") or "The held-out photos were not compared.") + "</p>"
    base = doc.get("baseline") or {}
    frames = [f for f in val.get("frames") or [] if isinstance(f, dict)]
    mean, base_mean = float(val["mean_de2000"]), float(val.get("baseline_mean_de2000") or float("nan"))
    one = base.get("material")
    if one in ("no candidate fits", "not measured", None):
        one = str(base.get("spec") or "none").split(":")[0]
    html = "<h3>Held-out photos: a check against photos never used by the fit</h3>" + kit["lead"](
        f"{len(frames)} photos were kept aside. The object was rendered with the measured materials from each of "
        f"their viewpoints and compared with the photo: the colours differ by ΔE00 {mean:.2f} on average "
        f"(about 1 is just visible). With one material ({one}) for the whole object, as a single "
        f"identification would render it, they differ by {base_mean:.2f}.")
    if val.get("noise_floor_mean_de2000") is not None:
        html += kit["lead"](f"A perfect model would not reach 0: the photos' own sensor noise alone gives about ΔE00 "
                            f"{float(val['noise_floor_mean_de2000']):.2f} on the same comparison (estimated from the "
                            "camera's nominal noise).")
    pooled = val.get("pooled") or {}
    if pooled.get("mean_de2000") is not None:
        s = int(pooled["block_px"])
        floor = pooled.get("noise_floor_mean_de2000")
        html += kit["lead"](f"Compared at {s} x {s} pixels (the linear colours averaged in blocks before the "
                            f"comparison, which averages the sensor's noise of one photo away): ΔE00 "
                            f"{float(pooled['mean_de2000']):.2f}, one material {float(pooled['baseline_mean_de2000']):.2f}"
                            + ("" if floor is None else f", the noise alone about {float(floor):.2f}") + ".")
    if not mean < base_mean:
        html += kit["caveat"]("the measured materials predict these photos no better than one material for the "
                              "whole object.")
    html += kit["details"](kit["kv"]([
        ("measured materials", f"mean ΔE00 {val['mean_de2000']:.2f}, 95th percentile {val['p95_de2000']:.2f}"),
        (f"one material for the whole object ({one})",
         f"mean ΔE00 {val['baseline_mean_de2000']:.2f}, 95th percentile {val['baseline_p95_de2000']:.2f}")])
        + kit["table"](["frame", "mean ΔE00", "p95 ΔE00", "one material: mean", "one material: p95", "object pixels"],
                       [[f.get("frame"), _num(f.get("mean_de2000")), _num(f.get("p95_de2000")),
                         _num(f.get("baseline_mean_de2000")), _num(f.get("baseline_p95_de2000")), f.get("pixels")]
                        for f in frames]), "Every held-out photo")
    shown_text, _ = render_materials_text(ctx, force_measured=True)
    figs = []
    for f in frames[:MAX_TRIPTYCHS]:
        rel = f.get("triptych")
        blob = ctx.product_bytes({"file": rel}, "validation triptych") if rel else None
        if blob is not None:
            figs.append(kit["img"](blob, f"held-out {f.get('frame')}",
                                   f"{f.get('frame')}: photo | render | colour difference (mean ΔE00 "
                                   f"{_num(f.get('mean_de2000'))}). Materials shown in the render: {shown_text}.",
                                   kind="render"))
    html += "".join(figs[:2]) + kit["details"]("".join(figs[2:]), f"{len(figs) - 2} more held-out photos"
                                                ) if len(figs) > 2 else "".join(figs)
    return html


def _num(v: Any) -> str:
    return "-" if v is None else f"{float(v):.2f}"
