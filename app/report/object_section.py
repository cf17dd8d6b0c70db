"""The report's "Materials on the mesh" section: the digitised object and how well it predicts photos.

Shown when the session's materials were measured on the mesh (``kogei fit-materials`` or the batch's
``materials`` step on a posed session): the material map on the mesh from four sides, one row per
region (material, confidence, parameters with their uncertainties, area, observations, and for a
region not measured what to capture), the held-out-photo error next to the one-material baseline,
photo | render | error triptychs of the held-out frames, and the confidence calibration measured by
the bench with this session's answers marked on it.
"""

from __future__ import annotations

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


def _rows(doc: dict[str, Any]) -> list[list[Any]]:
    return [[r.get("index"), r.get("material"), f"{float(r.get('confidence') or 0):.2f}",
             ", ".join(r.get("group") or []) if len(r.get("group") or []) > 1 else "",
             _param_text(r), f"{float(r.get('area_mm2') or 0):.0f}",
             f"{r.get('n_lit')} / {r.get('n_observations')}",
             "" if r.get("chi2_per_dof") is None else f"{float(r['chi2_per_dof']):.2f}", r.get("reason") or ""]
            for r in doc.get("regions") or [] if isinstance(r, dict)]


def object_materials_section(ctx: Any, kit: dict[str, Callable[..., Any]]) -> tuple[str, bool]:
    """The section's HTML body and whether it has content.

    Parameters
    ----------
    ctx
        The report's session context (manifest, checked product reads).
    kit
        The report's HTML helpers: ``table``, ``kv``, ``img``, ``missing``.

    Returns
    -------
    tuple
        ``(html, shown)``.
    """
    doc = ctx.product_json("object_materials")
    if doc is None:
        return kit["missing"]("no materials measured on the mesh (the photos must be posed on it first)",
                              f"kogei fit-materials {ctx.root}"), False
    body = kit["kv"]([("regions", len(doc.get("regions") or [])),
                      ("segmentation", (doc.get("segmentation") or {}).get("method")),
                      ("lamp spectrum assumed", doc.get("light_spectrum")),
                      ("model error", f"{100 * float(doc.get('model_error') or 0):.1f} % (added to the noise)"),
                      ("not measured", f"{(doc.get('not_measured') or {}).get('faces', 0)} faces, "
                                       f"{float((doc.get('not_measured') or {}).get('area_mm2', 0)):.0f} mm²"),
                      ("fit / held-out frames", f"{len((doc.get('frames') or {}).get('fit') or [])} / "
                                                f"{len((doc.get('frames') or {}).get('held_out') or [])}")])
    body += _map(ctx, doc, kit)
    body += kit["table"](["region", "material", "confidence", "indistinguishable from", "parameters (± 1 sigma)",
                          "area (mm²)", "lit / all observations", "reduced chi²", "what to capture"], _rows(doc))
    body += _validation(ctx, doc, kit)
    rel = bench_reliability()
    if rel is not None:
        from app.report.object_figures import reliability_figure

        marks = [(f"{r.get('index')}: {r.get('material')}", float(r.get("confidence") or 0))
                 for r in doc.get("regions") or [] if isinstance(r, dict)]
        body += kit["img"](reliability_figure(rel, marks), "confidence calibration",
                           f"Stated confidence against the share right over {int(np.nansum(rel['count']))} simulated "
                           f"regions ({rel.get('source', 'bench')}); red: this session's regions.")
    return body, True


def _map(ctx: Any, doc: dict[str, Any], kit: dict[str, Callable[..., Any]]) -> str:
    """The material map on the mesh from four sides (empty when the mesh file is unreadable)."""
    from app.batch.materials import material_colour
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
    regions = [r for r in doc.get("regions") or [] if isinstance(r, dict)]
    colours = [_colour(r, material_colour) for r in regions]
    png = material_views_figure(mesh.vertices, mesh.triangles, mesh.face_material, regions, colours)
    return kit["img"](png, "material map on the mesh", "Each face coloured by its region's material under D65 "
                                                       "(grey: not measured).")


def _validation(ctx: Any, doc: dict[str, Any], kit: dict[str, Callable[..., Any]]) -> str:
    """Held-out-photo figures and triptychs."""
    val = doc.get("validation") or {}
    if val.get("mean_de2000") is None:
        return "<p>" + (val.get("note") or "The held-out photos were not compared.") + "</p>"
    base = doc.get("baseline") or {}
    html = "<h3>Held-out photos (never used by the fit)</h3>" + kit["kv"]([
        ("measured materials", f"mean CIEDE2000 {val['mean_de2000']:.2f}, p95 {val['p95_de2000']:.2f}"),
        (f"one material for the whole object ({base.get('material')})",
         f"mean CIEDE2000 {val['baseline_mean_de2000']:.2f}, p95 {val['baseline_p95_de2000']:.2f}")])
    frames = [f for f in val.get("frames") or [] if isinstance(f, dict)]
    html += kit["table"](["frame", "mean dE00", "p95 dE00", "baseline mean", "baseline p95", "object pixels"],
                         [[f.get("frame"), _num(f.get("mean_de2000")), _num(f.get("p95_de2000")),
                           _num(f.get("baseline_mean_de2000")), _num(f.get("baseline_p95_de2000")), f.get("pixels")]
                          for f in frames])
    for f in frames[:MAX_TRIPTYCHS]:
        rel = f.get("triptych")
        blob = ctx.product_bytes({"file": rel}, "validation triptych") if rel else None
        if blob is not None:
            html += kit["img"](blob, f"held-out {f.get('frame')}",
                               f"{f.get('frame')}: photo | render with the measured materials | CIEDE2000 error "
                               f"(mean {_num(f.get('mean_de2000'))}).")
    return html


def _colour(region: dict[str, Any], material_colour: Callable[[str | None], tuple[int, int, int]]
            ) -> tuple[int, int, int]:
    """A region's map colour: its fitted material's colour under D65; magenta when it names none."""
    from app.workflows.materials import preset_srgb
    from processing.errors import InputError

    spec = region.get("spec")
    if region.get("material") in ("not measured", "no candidate fits") or not spec:
        return material_colour(None)
    try:
        return tuple(int(v) for v in preset_srgb(str(spec)))
    except InputError:
        return material_colour(None)


def _num(v: Any) -> str:
    return "-" if v is None else f"{float(v):.2f}"
