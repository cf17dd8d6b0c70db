"""The report's "At a glance" box: what was measured, how well, and what is uncertain, in plain words.

:func:`glance` reads the same checked products as the sections below it (the process report, the
scanner calibration, the colour chart, the materials, the validation, the renders) and states each
figure once, with a badge: **good**, **check** (uncertain, or a stand-in) or **poor** (unreliable).
Every material answer goes through :func:`app.report.readable.verdict`, so a region that fits
nothing is never summarised as a confident name, and renders are always said to show either the
measured materials or a one-material stand-in.
"""

from __future__ import annotations

import html
from dataclasses import dataclass, field
from typing import Any

from app.report.readable import verdict

__all__ = ["Glance", "glance", "material_verdicts", "render_materials_text", "region_names", "GOOD_DE00"]

#: Largest mean CIEDE2000 called good (chart after calibration, renders against held-out photos): a
#: difference of about 1 is just noticeable side by side, 3 is noticeable at a glance.
GOOD_DE00 = 3.0


@dataclass
class Glance:
    """Rows ``(topic, text, badge)`` and the uncertain points of the summary box."""

    rows: list[tuple[str, str, str]] = field(default_factory=list)
    uncertain: list[str] = field(default_factory=list)

    def html(self) -> str:
        """The box's HTML."""
        badge = {"good": "good", "check": "check", "poor": "poor", "none": "not done"}
        rows = "".join(f"<tr><th>{html.escape(t)}</th><td><span class='badge {b}'>{badge[b]}</span></td>"
                       f"<td>{html.escape(text)}</td></tr>" for t, text, b in self.rows)
        unc = "".join(f"<li>{html.escape(u)}</li>" for u in self.uncertain) or "<li>nothing flagged</li>"
        return (f"<div class='glance' id='summary'><h2>At a glance</h2><table class='glance'>{rows}</table>"
                f"<h3>What is uncertain</h3><ul class='uncertain'>{unc}</ul></div>")


def material_verdicts(ctx: Any) -> tuple[str, list[tuple[str, Any, dict[str, Any]]]]:
    """``(kind, [(name, Verdict, region), ...])``: the on-mesh regions, else the image-only ones, else none.

    ``kind`` is ``"mesh"``, ``"image"`` or ``""``.
    """
    doc = ctx.product_json("object_materials")
    if doc is not None:
        return "mesh", [(f"region {r.get('index')}", verdict(r.get("material"), r.get("confidence"),
                                                             r.get("chi2_per_dof"), r.get("group"), r.get("reason") or ""),
                         r) for r in doc.get("regions") or [] if isinstance(r, dict)]
    mat = _materials_doc(ctx)
    if mat is not None:
        return "image", [(str(r.get("region")), verdict(r.get("material"), r.get("confidence"), r.get("misfit"),
                                                        r.get("group") or _group(r), r.get("note") or ""), r)
                         for r in mat.get("regions") or [] if isinstance(r, dict)]
    return "", []


def _group(r: dict[str, Any]) -> list[str]:
    return [r["material"]] if r.get("material") else []


def _materials_doc(ctx: Any) -> dict[str, Any] | None:
    doc = ctx.product_doc((ctx.products.get("materials") or {}).get("report"), "products.materials.report")
    return doc if isinstance(doc, dict) else None


def render_materials_text(ctx: Any, force_measured: bool = False) -> tuple[str, bool]:
    """What the renders' materials are, in words, and whether they are the measured ones (else a stand-in).

    ``force_measured``: describe the materials measured on the mesh whatever the render step used (the
    held-out renders always use them).
    """
    from app.batch.steps import MEASURED

    rec = ctx.products.get("renders") or {}
    material = rec.get("material")
    if force_measured or material == MEASURED:
        kind, regions = material_verdicts(ctx)
        parts, starred = [], False
        for name, v, r in regions:
            if v.level == "missing":
                continue
            drawn = str(r.get("spec") or v.answer).split(":")[0]
            if v.answer == "no candidate fits":
                parts.append(f"{name}: {drawn}*")
                starred = True
            else:
                parts.append(f"{name}: {v.answer}" + ("" if v.level == "reliable" else f" ({v.label})"))
        doc = ctx.product_json("object_materials") or {}
        missing = any(v.level == "missing" for _, v, _ in regions) or bool(
            _num((doc.get("not_measured") or {}).get("faces")))
        text = ("the measured materials, region by region -- " + "; ".join(parts)
                + ("; faces not measured: neutral grey" if missing else "")
                + (" (* no candidate fits: its closest candidate is drawn; unreliable)" if starred else ""))
        return text, True
    return f"a stand-in -- one material, {material}, for the whole object, not the object's own materials", False


def _num(value: Any) -> float | None:
    try:
        return float(value)
    except (TypeError, ValueError):
        return None


def glance(ctx: Any, rep: dict[str, Any] | None) -> Glance:
    """The summary of a session (see the module docstring)."""
    g = Glance()
    m = ctx.manifest
    obj = m.get("object") or {}
    what = ", ".join(f"{k}: {v}" for k, v in obj.items() if k != "name")
    caps = m.get("captures") or {}
    photos = sum(1 for c in caps.values() if c.get("kind") == "frame")
    g.rows.append(("Object", f"{obj.get('name') or 'no name given'}" + (f" ({what})" if what else "")
                   + f"; capture {m.get('status') or 'not started'}, {len(caps)} files"
                   + (f" including {photos} photo{'s' if photos != 1 else ''}" if photos else ""), "good" if caps else "none"))
    _shape(ctx, rep, g)
    _colour(ctx, g)
    _materials(ctx, g)
    _renders(ctx, g)
    if ctx.problems:
        g.uncertain.insert(0, f"{len(ctx.problems)} problem(s) with the session's files: see 'Problems found'")
    return g


def _shape(ctx: Any, rep: dict[str, Any] | None, g: Glance) -> None:
    cal = ctx.calibration()
    if rep is None or not isinstance(rep.get("mesh"), dict):
        if ctx.products.get("mesh"):
            g.rows.append(("Shape", "a 3-D mesh is in the session, but its processing report holds no figures on "
                                    "how well it was measured", "check"))
            g.uncertain.append("the shape's accuracy is not recorded")
        else:
            g.rows.append(("Shape", "not measured yet (the session has not been processed)", "none"))
            g.uncertain.append("no 3-D shape: the session has not been processed")
        return
    mesh = rep["mesh"]
    surf = (rep.get("surface") or {}).get("mesh") or {} if isinstance(rep.get("surface"), dict) else {}
    passes = rep.get("passes") or []
    registered = sum(1 for p in passes if p.get("registered"))
    closed = bool(mesh.get("watertight"))
    text = (f"3-D mesh of {int(mesh.get('triangles', 0)):,} triangles, "
            + ("closed (watertight)" if closed else f"not closed ({surf.get('boundary_edges', '?')} open edges)")
            + (f", surface {float(surf['area_mm2']):,.0f} mm²" if _num(surf.get("area_mm2")) else "")
            + f"; {registered} of {len(passes)} placements aligned")
    ok = closed and registered == len(passes)
    if cal is not None and _num(cal.get("rms_mm")) is not None:
        text += f"; scanner calibrated to {1000 * float(cal['rms_mm']):.1f} µm RMS on a reference sphere"
    else:
        text += "; scanner calibration not in the session"
    g.rows.append(("Shape", text, "good" if ok else "check"))
    if registered < len(passes):
        g.uncertain.append(f"{len(passes) - registered} of {len(passes)} placements could not be aligned: "
                           "their part of the shape is missing")
    if not closed:
        g.uncertain.append("the mesh is not closed: some of the surface was not seen by the scanner")


def _colour(ctx: Any, g: Glance) -> None:
    colour = ctx.products.get("colour")
    if not colour:
        g.rows.append(("Colour calibration", "not done (no colour-chart step)", "none"))
        return
    means = []
    for tag, files in sorted((colour.get("passes") or {}).items()):
        chart = ctx.product_doc(files.get("chart"), f"products.colour.passes.{tag}.chart")
        if isinstance(chart, dict):
            mean = _num((chart.get("patch_errors") or {}).get("mean"))
            if mean is not None:
                means.append(mean)
    if not means:
        g.rows.append(("Colour calibration", "the chart products could not be read", "check"))
        return
    worst = max(means)
    g.rows.append(("Colour calibration", f"colour chart found in {len(means)} pass(es); colours after calibration "
                   f"differ from the chart's by mean ΔE00 {worst:.2f} in the worst pass (about 1 is the smallest "
                   "difference most people see)", "good" if worst <= GOOD_DE00 else "check"))
    if worst > GOOD_DE00:
        g.uncertain.append(f"the colour calibration leaves a visible error (mean ΔE00 {worst:.2f})")


def _materials(ctx: Any, g: Glance) -> None:
    kind, regions = material_verdicts(ctx)
    if not kind:
        g.rows.append(("Materials", "not measured (the materials step has not run)", "none"))
        g.uncertain.append("no material was measured")
        return
    counts = {lvl: sum(1 for _, v, _ in regions if v.level == lvl)
              for lvl in ("reliable", "uncertain", "unreliable", "missing")}
    where = "on the 3-D mesh" if kind == "mesh" else "in the photos only (not placed on the mesh)"
    text = (f"{len(regions)} regions {where}: {counts['reliable']} reliable, {counts['uncertain']} uncertain, "
            f"{counts['unreliable']} unreliable" + (f", {counts['missing']} not measured" if counts["missing"] else ""))
    groups = _grouped(regions)
    named = "; ".join(f"{region_names(names)}: {answer} ({label})" for (answer, label), names in groups.items())
    text += f" -- {named}" if named else ""
    badge = "poor" if counts["unreliable"] else ("check" if counts["uncertain"] or counts["missing"] else "good")
    g.rows.append(("Materials", text, badge))
    for (answer, label), names in groups.items():
        judged = [(n, v) for n, v, _ in regions if n in names]
        if label not in ("unreliable", "uncertain"):
            continue
        if len(judged) <= 2:
            g.uncertain += [f"{n} ({v.answer}) is {v.label}: {v.why}" for n, v in judged]
        elif answer == "no candidate fits":
            g.uncertain.append(f"{region_names(names)} ({answer}) are {label}: none of the known materials matches them "
                               "(see 'Materials' below for each region's closest candidate)")
        else:
            g.uncertain.append(f"{region_names(names)} ({answer}) are {label}: " + "; ".join(
                f"{n}: {v.why}" for n, v in judged))
    if kind == "mesh":
        doc = ctx.product_json("object_materials") or {}
        nm = doc.get("not_measured") or {}
        if _num(nm.get("area_mm2")):
            advice = f": {nm['advice']}" if isinstance(nm.get("advice"), str) else ""
            g.uncertain.append(f"{float(nm['area_mm2']):,.0f} mm² of the surface has no measured material "
                               f"(shown grey){advice}")
        val = doc.get("validation") or {}
        mean, base = _num(val.get("mean_de2000")), _num(val.get("baseline_mean_de2000"))
        if mean is not None:
            n = len([f for f in val.get("frames") or [] if isinstance(f, dict)])
            text = (f"renders with the measured materials differ from {n} photos not used for the fit by mean "
                    f"ΔE00 {mean:.2f}" + ("" if base is None else f" (one material for the whole object: {base:.2f})")
                    + "; about 1 is just visible side by side, 3 at a glance")
            better = base is None or mean < base
            g.rows.append(("Check against photos", text, "good" if better and mean <= GOOD_DE00 else "check"))
            if not better:
                g.uncertain.append("the measured materials predict the held-out photos no better than one material")
        else:
            g.rows.append(("Check against photos", val.get("note") or "not done", "none"))
    else:
        g.uncertain.append("the materials were identified in the photos only, not placed on the 3-D mesh "
                           "(no camera calibration): the renders cannot show them region by region")


def _grouped(regions: list[tuple[str, Any, dict[str, Any]]]) -> dict[tuple[str, str], list[str]]:
    """Region names per ``(answer, verdict label)``, in order of first appearance."""
    out: dict[tuple[str, str], list[str]] = {}
    for name, v, _ in regions:
        out.setdefault((v.answer, v.label), []).append(name)
    return out


def region_names(names: list[str]) -> str:
    """Region names in words: "region 1", "regions 1, 2 and 4", "p01-r1, p01-r3" (image-only ones name their pass)."""
    if all(n.startswith("region ") for n in names):
        nums = [n.removeprefix("region ") for n in names]
        if len(nums) == 1:
            return f"region {nums[0]}"
        return f"regions {', '.join(nums[:-1])} and {nums[-1]}"
    return ", ".join(names)


def _renders(ctx: Any, g: Glance) -> None:
    if not ctx.products.get("renders"):
        g.rows.append(("Renders", "none (the render step has not run)", "none"))
        return
    text, measured = render_materials_text(ctx)
    if measured:
        regions = material_verdicts(ctx)[1]
        bad = sum(1 for _, v, _ in regions if v.level == "unreliable")
        text = (f"show the measured materials, region by region ({len(regions)} regions"
                + (f"; {bad} of them unreliable, drawn with their closest candidate material)" if bad else ")"))
        g.rows.append(("Renders", text, "check" if bad else "good"))
        if bad:
            g.uncertain.append(f"the renders draw {bad} unreliable region(s) with their closest candidate material, "
                               "so they may not look like the object there")
        return
    g.rows.append(("Renders", "show " + text, "check"))
    if not measured:
        g.uncertain.append("the renders show " + text)
