"""``kogei report``: one self-contained HTML file describing everything a session holds.

docs/report.md.  The report reads the session without locking it
(:meth:`app.session.Session.read`), checks every product it shows against the
SHA-256 in the manifest, and draws its plots with matplotlib; images are
embedded as base64 PNG data URIs, so the file can be mailed or archived
alone.  It is written for curators as well as engineers: an "At a glance"
box (:mod:`app.report.summary`) states what was measured, how well and what
is uncertain; each section opens with a plain caption and folds its
technical tables into ``<details>``; every material answer carries a verdict
(:mod:`app.report.readable`), and every image rendered from the mesh says in
its caption which materials it shows.  Sections, in order: object and plan,
capture log, scanner calibration, registration and pose graph, camera and
lamp, mesh views, coverage and filled holes, colour chart, spectra, materials
on the mesh, material map, renders under D65 and A, the light probe (a probe session only), timing.  A section whose
data the session does not hold says what is missing and which command
produces it.
"""

from __future__ import annotations

import collections
import datetime as _dt
import html
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from app.errors import UsageError
from app.report.figures import (
    calibration_residuals_figure,
    coverage_figure,
    data_uri,
    frame_residuals_figure,
    holes_figure,
    overlay_sheet,
    pose_graph_figure,
    timing_figure,
)
from app.session_paths import (
    MAX_JSON_BYTES,
    MAX_PRODUCT_BYTES,
    UnsafeSessionPath,
    check_not_symlink,
    confined_file,
    read_confined_bytes,
)
from app.workflows._materials_document import materials_document_problem
from processing.common.files import JSONFileError, parse_json
from processing.common.png import png_bytes

__all__ = ["Section", "build_report", "write_report", "report_sections", "REPORT_FILE"]

REPORT_FILE = "products/report.html"
MESH_VIEW_MATERIAL = "aluminium:roughness=0.5,mirror=0,gloss=1"   # neutral grey: shows shape, not colour
MESH_VIEWS = (("front", (0.0, -1.0, 0.35)), ("side", (1.0, 0.0, 0.35)), ("above", (0.05, -0.05, 1.0)))
MESH_VIEW_SIZE = (240, 180)


@dataclass
class Section:
    """One report section: a title, its HTML body, and whether the session had its data."""

    key: str
    title: str
    body: str
    has_data: bool


def _e(value: Any) -> str:
    return html.escape(str(value))


def _fmt(value: Any) -> str:
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.4g}" if np.isfinite(value) else "unknown"
    if isinstance(value, (list, tuple)) and all(isinstance(v, (int, float)) for v in value):
        return "[" + ", ".join(_fmt(v) for v in value) + "]"
    if isinstance(value, dict):
        return ", ".join(f"{k}: {_fmt(v)}" for k, v in value.items())
    return str(value)


def _table(header: list[str], rows: list[list[Any]]) -> str:
    head = "".join(f"<th>{_e(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{_e(_fmt(c))}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _kv(pairs: list[tuple[str, Any]]) -> str:
    rows = "".join(f"<tr><th>{_e(k)}</th><td>{_e(_fmt(v))}</td></tr>" for k, v in pairs)
    return f"<table class='kv'>{rows}</table>"


def _img(png: bytes, alt: str, caption: str = "", kind: str = "") -> str:
    """A figure; ``kind="render"`` marks an image rendered from the mesh (its caption names the materials shown)."""
    cap = f"<figcaption>{_e(caption)}</figcaption>" if caption else ""
    cls = f" class='{kind}'" if kind else ""
    return f"<figure{cls}><img src='{data_uri(png)}' alt='{_e(alt)}'>{cap}</figure>"


def _lead(text: str) -> str:
    """A section's plain-language caption: what it shows and what to make of it."""
    return f"<p class='lead'>{_e(text)}</p>"


def _caveat(text: str) -> str:
    """A highlighted warning (a stand-in, an unreliable result)."""
    return f"<p class='caveat'><b>Caution:</b> {_e(text)}</p>"


def _details(inner: str, label: str = "Technical details") -> str:
    """Tables for specialists, folded away (HTML ``<details>``)."""
    return f"<details><summary>{_e(label)}</summary>{inner}</details>" if inner else ""


def _q(value: Any, spec: str, unit: str = "") -> str:
    """A number formatted with ``spec`` and its unit, or "unknown" when missing or not finite."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        return "unknown"
    if not np.isfinite(v):
        return "unknown"
    return f"{v:{spec}}" + (f" {unit}" if unit else "")


def _um(mm: Any) -> str:
    """Millimetres as micrometres (µm), or "unknown"."""
    try:
        return f"{float(mm) * 1000:.1f} µm"
    except (TypeError, ValueError):
        return "unknown"


def _missing(what: str, command: str) -> str:
    return (f"<p class='missing'><b>Not in this session:</b> {_e(what)}. "
            f"Produced by: <code>{_e(command)}</code></p>")


def _step_command(root: Path, step: str) -> str:
    """The command that produces a step's products, or why this version cannot."""
    from app.batch.steps import STEPS, UNAVAILABLE_STEPS

    if step in STEPS:
        return f"kogei batch {root} --steps {step}"
    return f"kogei batch --steps {step} (not available: {UNAVAILABLE_STEPS[step]})"


class _Context:
    """The session as the sections read it: manifest, verified product files, the problems found."""

    def __init__(self, root: Path) -> None:
        from app.session import Session, SessionError

        self.root = root
        try:
            self.manifest, journal_problems = Session.read_checked(root)
        except SessionError as exc:
            raise UsageError(str(exc)) from None
        except (OSError, ValueError, TypeError, KeyError, AttributeError) as exc:
            raise UsageError(f"session {_shown(root)}: session.json or session.journal is damaged "
                             f"({type(exc).__name__}: {exc}); restore it from a backup") from None
        self.problems: list[str] = []
        self.problems += _manifest_problems(self.manifest)
        self.problems += journal_problems
        self.manifest = _sanitized(self.manifest)
        self.products: dict[str, Any] = self.manifest.get("products") or {}

    def product_bytes(self, rec: dict[str, Any] | None, what: str = "products",
                      max_bytes: int = MAX_PRODUCT_BYTES) -> bytes | None:
        """The bytes of a product file if present, inside the session and matching its checksum.

        Anything else is noted in ``problems`` and gives None: a path outside the
        session, a symlink, a FIFO or device, an oversized, missing or changed file.
        """
        import hashlib

        if not isinstance(rec, dict) or "file" not in rec:
            return None
        name = rec["file"]
        try:
            blob = read_confined_bytes(self.root, name, f"{what}.file", max_bytes)
        except UnsafeSessionPath as exc:
            self.problems.append(f"{exc}; it is not shown")
            return None
        except OSError:
            self.problems.append(f"{name} is listed in the manifest ({what}) but missing")
            return None
        if rec.get("sha256") and hashlib.sha256(blob).hexdigest() != rec["sha256"]:
            self.problems.append(f"{name} does not match its checksum in the manifest (changed after it "
                                 "was written); it is not shown")
            return None
        return blob

    def product_path(self, rec: dict[str, Any], what: str) -> Path | None:
        """The checked path of a product (for a loader that opens it itself), or None (a problem noted)."""
        if self.product_bytes(rec, what) is None:
            return None
        try:
            return confined_file(self.root, rec["file"], f"{what}.file")
        except (UnsafeSessionPath, OSError) as exc:
            self.problems.append(f"{exc}; it is not shown")
            return None

    def product_doc(self, rec: dict[str, Any] | None, what: str) -> Any:
        """The JSON in a product file (see :meth:`product_bytes`), or None with the problem noted.

        A file that is not JSON -- not UTF-8, malformed, nested too deeply -- is one problem line naming it.
        """
        blob = self.product_bytes(rec, what, MAX_JSON_BYTES)
        if blob is None or not isinstance(rec, dict):
            return None
        try:
            return parse_json(blob, _shown(str(rec["file"])), "it is not shown; write it again with the step that "
                                                              "made it")
        except JSONFileError as exc:
            self.problems.append(str(exc))
            return None

    def process_report(self) -> dict[str, Any] | None:
        doc = self.product_doc(self.products.get("process_report"), "products.process_report")
        return doc if isinstance(doc, dict) else None

    def calibration(self, key: str = "calibration") -> dict[str, Any] | None:
        """A referenced calibration file's JSON (``calibration``, ``camera_calibration`` or ``lamp_calibration``)."""
        ref = self.manifest.get(key)
        if not ref:
            return None
        if not isinstance(ref, dict) or not isinstance(ref.get("path"), str):
            self.problems.append(f"session.json: {key} is not a record with a 'path'; it is not shown")
            return None
        doc = self.product_doc({"file": ref["path"], "sha256": ref.get("sha256")}, key)
        return doc if isinstance(doc, dict) else None

    def product_json(self, key: str) -> dict[str, Any] | None:
        """A JSON product (``products.<key>``), checked, or None."""
        rec = self.products.get(key)
        doc = self.product_doc(rec, f"products.{key}")
        if doc is None:
            return None
        if not isinstance(doc, dict):
            self.problems.append(f"{rec['file']} is not a JSON object; it is not shown")
            return None
        problem = _PRODUCT_CHECKS[key](doc) if key in _PRODUCT_CHECKS else None
        if problem:
            self.problems.append(f"{rec['file']}: {problem}; it is not shown")
            return None
        return doc


#: The checks of a JSON product's fields before a section reads it: ``products`` key -> first problem or None.
_PRODUCT_CHECKS: dict[str, Callable[[dict[str, Any]], str | None]] = {"object_materials": materials_document_problem}
#: Expected types of the manifest's top-level fields (a wrong type is listed under "problems found").
_FIELD_TYPES: dict[str, tuple[type, ...]] = {
    "object": (dict,), "devices": (dict,), "settings": (dict,), "plan": (dict,), "passes": (dict,),
    "state": (dict,), "captures": (dict,), "history": (list,), "products": (dict,), "batch": (dict,),
    "calibration": (dict, type(None)), "camera_calibration": (dict, type(None)),
    "lamp_calibration": (dict, type(None)), "status": (str,), "created_utc": (str,), "updated_utc": (str,),
}
#: The largest pass count the report looks at (a plan is bounded far below this by ``kogei capture``).
MAX_PASSES = 1000
try:
    from PIL.Image import DecompressionBombError as _DecompressionBomb
except ImportError:                 # pragma: no cover - Pillow is a dependency
    _DecompressionBomb = MemoryError


def _manifest_problems(manifest: dict[str, Any]) -> list[str]:
    """One line per top-level manifest field of the wrong type, and per out-of-bounds plan count."""
    out = [f"session.json: {key} is a {type(manifest[key]).__name__}, expected "
           f"{' or '.join('null' if t is type(None) else t.__name__ for t in kinds)}; it is ignored"
           for key, kinds in _FIELD_TYPES.items() if key in manifest and not isinstance(manifest[key], kinds)]
    plan = manifest.get("plan")
    if isinstance(plan, dict) and "passes" in plan and _plan_passes(manifest) != plan["passes"]:
        out.append(f"session.json: plan.passes {plan['passes']!r} is not a whole number 0..{MAX_PASSES}; "
                   "no pass is shown")
    captures = manifest.get("captures")
    if isinstance(captures, dict):
        bad = [cid for cid, rec in captures.items() if not isinstance(rec, dict)]
        if bad:
            out.append(f"session.json: captures {', '.join(map(str, bad[:5]))} are not records; they are ignored")
    return out


def _sanitized(manifest: dict[str, Any]) -> dict[str, Any]:
    """The manifest with every wrong-typed top-level field emptied and non-record captures dropped."""
    out = dict(manifest)
    for key, kinds in _FIELD_TYPES.items():
        if key in out and not isinstance(out[key], kinds):
            out[key] = None if type(None) in kinds else kinds[0]()
    out["captures"] = {k: v for k, v in (out.get("captures") or {}).items() if isinstance(v, dict)}
    out["history"] = [h for h in (out.get("history") or []) if isinstance(h, dict)]
    return out


def _plan_passes(manifest: dict[str, Any]) -> int:
    """``plan.passes`` if it is a whole number within bounds, else 0."""
    plan = manifest.get("plan")
    n = plan.get("passes", 0) if isinstance(plan, dict) else 0
    return n if isinstance(n, int) and not isinstance(n, bool) and 0 <= n <= MAX_PASSES else 0


def _shown(path: Path | str) -> str:
    """A path as text, whatever bytes its name holds (a non-UTF-8 name is shown with escapes)."""
    return os.fsdecode(path).encode("utf-8", "backslashreplace").decode("utf-8")


# ---------------------------------------------------------------------------- sections
def _object(ctx: _Context) -> Section:
    from app.report.readable import plan_rows

    m = ctx.manifest
    obj = m.get("object") or {}
    pairs = [(k, v) for k, v in obj.items()] or [("object", "no metadata given (kogei capture --object NAME)")]
    pairs += [("session folder", _shown(ctx.root.resolve())), ("capture status", m.get("status")),
              ("created", _when(m.get("created_utc"))), ("last updated", _when(m.get("updated_utc")))]
    body = _lead("The object as recorded at the station, and the capture plan the station followed.")
    body += _kv(pairs)
    rows = plan_rows(m.get("plan"))
    body += "<h3>Capture plan</h3>" + (_table(["setting", "value"], [list(r) for r in rows]) if rows else
                                        "<p>No capture plan recorded.</p>")
    dev = m.get("devices") or {}
    devices = []
    for name, d in dev.items():
        if isinstance(d, dict):
            keep = [f"{k.replace('_', ' ')} {v}" for k, v in d.items()
                    if k in ("model", "kind", "firmware", "serial_number", "port")]
            devices.append([name, ", ".join(keep) or "no details"])
    if devices:
        body += _details(_table(["device", "details"], devices), "Devices used")
    return Section("object", "Object and plan", body, True)


def _capture_log(ctx: _Context) -> Section:
    m = ctx.manifest
    caps = m.get("captures") or {}
    if not caps:
        return Section("capture", "Capture log", _missing("no captures", "kogei capture ... --out SESSION"), False)
    per_pass: dict[int, collections.Counter] = collections.defaultdict(collections.Counter)
    size = 0
    for rec in caps.values():
        per_pass[int(rec.get("pass", 0))][rec.get("kind", "?")] += 1
        size += int(rec.get("bytes", 0))
    kinds = sorted({k for c in per_pass.values() for k in c})
    rows = [[f"pass {p}", (m.get("passes") or {}).get(str(p), {}).get("status", "")] + [c.get(k, 0) for k in kinds]
            for p, c in sorted(per_pass.items())]
    labels = {"chart": "chart frames", "frame": "RAW frames", "profile": "profiles", "profiles": "gathered profiles"}
    history = m.get("history") or []
    events = collections.Counter(h["event"] for h in history)
    start = next((h["utc"] for h in history if h["event"] in ("started", "resumed")), None)
    end = next((h["utc"] for h in reversed(history) if h["event"] in ("complete", "interrupted", "failed")), None)
    lead = _lead(f"{len(caps)} files were captured ({size / 1e6:.1f} MB) in {len(per_pass)} placement(s) of the "
                 f"object; the station noted {events.get('note', 0)} fault(s) it recovered from, the capture was "
                 f"interrupted {events.get('interrupted', 0)} time(s) and resumed {events.get('resumed', 0)} time(s).")
    body = _table(["pass", "status"] + [labels.get(k, k) for k in kinds], rows)
    body += _kv([("files", f"{len(caps)} records, {size / 1e6:.1f} MB"),
                 ("events", ", ".join(f"{k} {v}x" for k, v in sorted(events.items())) or "none"),
                 ("first start -> last end (UTC)", f"{start or 'unknown'} -> {end or 'unknown'}")])
    notable = [h for h in history if h["event"] not in ("created",)]
    if notable:
        shown = notable[-40:]
        body += "<h3>History</h3>" + _table(["UTC", "event", "detail"], [[h["utc"], h["event"], h["detail"]]
                                                                           for h in shown])
        if len(notable) > len(shown):
            body += f"<p>({len(notable) - len(shown)} earlier events not shown; see session.json)</p>"
    wire = ctx.root / "wire"
    wires = sorted(wire.glob("*.log")) if wire.is_dir() and not wire.is_symlink() else []
    if wires:
        body += _kv([(f"device log {_shown(w.name)}", f"{w.lstat().st_size / 1e3:.0f} kB") for w in wires])
    body = lead + _details(body, "Captures per pass, history and device logs")
    return Section("capture", "Capture log", body, True)


def _calibration(ctx: _Context) -> Section:
    cal = ctx.calibration()
    root = ctx.root
    if cal is None:
        return Section("calibration", "Scanner calibration",
                       _missing("no scanner calibration", f"kogei calibrate CAL_SESSION --sphere-radius MM; "
                                f"kogei process {root} --calibration CAL_SESSION"), False)
    body = _lead(f"Before the object, the scanner measured a reference sphere of known size: the points it returned "
                 f"lie within {_um(cal.get('rms_mm'))} of the true sphere on average (root mean square; 1 µm is "
                 "a thousandth of a millimetre). This is the accuracy of the shape measurement.")
    tech = _kv([("sphere residual RMS", _um(cal.get("rms_mm"))), ("largest residual", _um(cal.get("max_mm"))),
                ("sphere radius given / fitted", f"{cal['sphere_radius_mm']:.3f} / {cal['fitted_radius_mm']:.3f} mm"),
                ("table-top RMS", _um(cal.get("table_rms_mm"))),
                ("profiles used", cal.get("n_profiles")), ("sphere / table points", f"{cal.get('n_sphere_points')} / "
                                                                                    f"{cal.get('n_table_points')}"),
                ("source", cal.get("source"))])
    if cal.get("step_indices"):
        tech += _img(calibration_residuals_figure(cal["step_indices"], cal["step_rms_mm"], cal["rms_mm"]),
                     "calibration residuals", "Residual of each sphere-scan profile used by the calibration.")
    body += _details(tech)
    return Section("calibration", "Scanner calibration", body, True)


def _registration(ctx: _Context, rep: dict[str, Any] | None) -> Section:
    if rep is None:
        return Section("registration", "Registration", _missing(
            "no registration (the session has not been processed)",
            f"kogei process {ctx.root} --calibration CAL_SESSION  (or kogei batch {ctx.root})"), False)
    reg = rep["registration"]
    passes = rep["passes"]
    rows = [[p["pass"], p.get("points", ""), "yes" if p.get("registered") else "no", p.get("skipped", "")]
            for p in passes]
    registered = sum(1 for p in passes if p.get("registered"))
    lead = _lead(f"The object was scanned in {len(passes)} placement(s) (passes); {registered} of them were aligned "
                 "into one shape. Each pair of overlapping passes is checked: its surfaces must meet within the "
                 "expected residual (RMS), overlap enough and face the same way ('normal agreement': the share of "
                 "matched points whose surface directions agree).")
    rms = [float(pr["rmse_mm"]) for pr in reg.get("pairs") or []
           if pr.get("verified") and isinstance(pr.get("rmse_mm"), (int, float))]
    if rms:
        lead += _lead(f"The aligned passes meet within {_um(max(rms))} RMS at worst "
                      f"({len(rms)} verified pair(s)).")
    if registered < len(passes):
        lead += _caveat(f"{len(passes) - registered} pass(es) could not be aligned; their part of the shape is missing.")
    body = _table(["pass", "points", "registered", "note"], rows)
    pairs = reg.get("pairs") or []
    # pair indices count the passes that reached registration, in order
    reached = [p["pass"] for p in passes if "registered" in p]

    def label(i: int) -> str:
        return f"pass {reached[i]}" if 0 <= i < len(reached) else f"cloud {i}"

    if pairs:
        body += "<h3>Pairs</h3>" + _table(
            ["pair", "verified", "RMS (mm)", "expected RMS (mm)", "overlap", "normal agreement", "method", "reason"],
            [[f"{label(int(pr['source']))} -> {label(int(pr['target']))}", "yes" if pr.get("verified") else "no", pr.get("rmse_mm"),
              pr.get("expected_rmse_mm"), pr.get("overlap"), pr.get("normal_agreement"), pr.get("method", ""),
              pr.get("reason", "")] for pr in pairs])
    cons = reg.get("consistency")
    body += _kv([("all passes registered", "yes" if reg.get("all_registered") else "no"),
                 ("pose graph consistency", "n/a (fewer than three registered passes)" if cons is None else
                  f"{cons['max_rotation_deg']:.4f} deg, {cons['max_displacement_mm']:.4f} mm")])
    body += _img(pose_graph_figure(passes, pairs), "pose graph", "The pose graph of the passes.")
    body = lead + _details(body)
    return Section("registration", "Registration and pose graph", body, True)


def _camera_rows(cam: dict[str, Any]) -> list[tuple[str, Any]]:
    """Key figures of a camera calibration's JSON."""
    k = cam.get("K") or [[float("nan")] * 3] * 3
    stds = cam.get("stds") or {}
    src = cam.get("source") or {}
    size = cam.get("image_size") or ["?", "?"]
    return [("reprojection RMS", _q(cam.get("rms_px"), ".3f", "px")),
            ("calibrated frame size", f"{size[0]} x {size[1]} px"),
            ("focal length", f"{k[0][0]:.1f} x {k[1][1]:.1f} px (± {_q(stds.get('fx_px'), '.2f', 'px')})"),
            ("principal point", f"({k[0][2]:.1f}, {k[1][2]:.1f}) px"),
            ("distortion k1, k2, p1, p2, k3", ", ".join(f"{v:.4g}" for v in cam.get("dist") or [])),
            ("held at nominal values (long lens)", ", ".join(str(h) for h in cam.get("held") or []) or "none"),
            ("board frames used / rejected", f"{src.get('frames_used', '?')} / {len(src.get('frames_rejected') or [])}"),
            ("board coverage of the image", "not recorded" if not isinstance(src.get("coverage"), dict) else
             f"{100 * float(src['coverage'].get('fraction', 0.0)):.0f} % of a 12 x 8 grid of cells"),
            ("sphere photos tying the camera to the turntable", src.get("sphere_photos")),
            ("axis direction ±", _q(stds.get("axis_direction_deg"), ".4f", "deg")),
            ("rotation about the axis ±", _q(stds.get("gauge_rotation_deg"), ".4f", "deg"))]


def _lamp_rows(lamps: dict[str, Any]) -> list[list[Any]]:
    """One row per lamp: kind, where, uncertainty, rays used."""
    import math as _math

    rows = []
    for lp in lamps.get("lamps") or []:
        cov = lp.get("covariance") or [[0.0] * 3] * 3
        sd = [_math.sqrt(max(float(cov[i][i]), 0.0)) for i in range(3)]
        if lp.get("kind") == "point":
            where = "(" + ", ".join(f"{v:.1f}" for v in lp.get("position_mm") or []) + ") mm"
            unc = "± (" + ", ".join(f"{v:.1f}" for v in sd) + ") mm"
        else:
            where = "toward (" + ", ".join(f"{v:.4f}" for v in lp.get("direction") or []) + ")"
            unc = f"± {_math.degrees(max(sd)):.3f} deg"
        rows.append([lp.get("name"), lp.get("kind"), where, unc, lp.get("n_observations"),
                     _q(lp.get("rms_deg"), ".3f", "deg"), lp.get("spectrum")])
    return rows


#: Most posed frames drawn in the report's contact sheet.
MAX_OVERLAYS = 48


def _posed(ctx: _Context) -> Section:
    """Camera and lamp calibration, and the mesh's outline on every photo with its silhouette IoU."""
    cam = ctx.calibration("camera_calibration")
    if cam is None:
        return Section("posed", "Camera and lamp", _missing(
            "no camera calibration: the photos are not posed on the mesh",
            f"kogei calibrate --camera BOARD_SESSION --scanner SPHERE_SESSION; kogei process {ctx.root} "
            "--camera-calibration BOARD_SESSION --lamp-calibration LAMP_SESSION"), False)
    lead = _lead("The camera and the lamp were calibrated so that every photo can be laid exactly onto the 3-D "
                 "mesh: then each point of the surface is seen from known directions under known light, which is "
                 "what measuring its material on the mesh needs.")
    body = "<h3>Camera</h3>" + _kv(_camera_rows(cam))
    views = cam.get("view_rms_px") or {}
    if views:
        body += _img(frame_residuals_figure(list(views), list(views.values()), cam.get("rms_px", 0.0)),
                     "board frame residuals", "Reprojection RMS of each board frame used.")
    lamps = ctx.calibration("lamp_calibration")
    body += "<h3>Lamps</h3>" + (_table(["lamp", "kind", "where (table frame)", "uncertainty (1 sigma)", "rays",
                                        "ray RMS", "spectrum"], _lamp_rows(lamps)) if lamps else
                                "<p>No lamp calibration: observations have no light directions "
                                "(<code>kogei calibrate --lamp LAMP_SESSION --camera-calibration BOARD_SESSION</code>)."
                                "</p>")
    proj = ctx.product_json("projection_report")
    if proj is None:
        body = lead + _details(body) + _missing("the frames are not projected yet", f"kogei project {ctx.root}")
        return Section("posed", "Camera and lamp", body, True)
    frames = [f for f in proj.get("frames") or [] if isinstance(f, dict)]
    obs = proj.get("observations") or {}
    iou = proj.get("iou_min")
    lead += _lead(f"{len(frames)} photos were laid onto the mesh; the mesh's outline covers the object in every photo "
                  + ("" if iou is None else f"with at least {100 * float(iou):.1f} % overlap (silhouette IoU "
                                            f"{float(iou):.3f}; 100 % is a perfect fit)") + ".")
    body += "<h3>Every photo posed on the mesh</h3>" + _kv([
        ("frames posed", len(frames)), ("lowest silhouette IoU", proj.get("iou_min")),
        ("mean boundary offset", _q(proj.get("offset_px_mean"), ".2f", "px")),
        ("observations", f"{obs.get('count')} of {obs.get('vertices_seen')} / {obs.get('vertices')} vertices seen, "
                         f"median {obs.get('median_per_seen_vertex')} frames per seen vertex"),
        ("chart-calibrated passes", ", ".join(str(p) for p in proj.get("chart_calibrated_passes") or []) or "none")])
    body += _table(["frame", "pass", "table angle", "IoU", "offset (px)"],
                   [[f.get("frame"), f.get("pass"), f"{f.get('table_angle_deg', 0):.0f} deg",
                     "-" if f.get("iou") is None else f"{f['iou']:.4f}",
                     "-" if f.get("offset_px") is None else f"{f['offset_px']:.2f}"] for f in frames])
    tiles = []
    for f in frames[:MAX_OVERLAYS]:
        blob = ctx.product_bytes({"file": f.get("overlay")}, "projection overlay") if f.get("overlay") else None
        if blob is not None:
            tiles.append((blob, f"{f.get('frame')}" + ("" if f.get("iou") is None else f"  IoU {f['iou']:.3f}")))
    if tiles:
        body += _img(overlay_sheet(tiles), "overlays of every posed frame",
                     "The mesh's outline (cyan) projected with the calibrated camera onto every photo"
                     + (f" (the first {MAX_OVERLAYS})" if len(frames) > MAX_OVERLAYS else "") + ".")
    return Section("posed", "Camera and lamp", lead + _details(body), True)


def _mesh(ctx: _Context, rep: dict[str, Any] | None) -> Section:
    from app.batch.steps import render_session_mesh

    mesh = ctx.products.get("mesh")
    if not mesh or ctx.product_path(mesh, "products.mesh") is None:
        return Section("mesh", "Mesh", _missing("no mesh", f"kogei process {ctx.root} (or kogei batch {ctx.root} "
                                                "--steps geometry)"), False)
    pairs = [("file", mesh["file"]), ("preset", mesh.get("preset"))]
    if rep is not None and isinstance(rep.get("mesh"), dict):
        m = rep["surface"].get("mesh", {}) if isinstance(rep.get("surface"), dict) else {}
        pairs += [("vertices / triangles", f"{rep['mesh'].get('vertices')} / {rep['mesh'].get('triangles')}"),
                  ("watertight", rep["mesh"].get("watertight")), ("boundary edges", m.get("boundary_edges")),
                  ("components", m.get("components")), ("area", _q(m.get("area_mm2"), ".0f", "mm²"))]
    views = []
    for name, direction in MESH_VIEWS:
        result = render_session_mesh(ctx.root, "D65", MESH_VIEW_SIZE, "draft", material=MESH_VIEW_MATERIAL,
                                     direction=direction)
        views.append(_img(png_bytes(result.srgb8), f"mesh {name}",
                          f"{name}. Materials shown: none -- a uniform grey stand-in, for the shape only.",
                          kind="render"))
    body = (_lead("The measured 3-D shape, seen from three sides. It is drawn in one neutral grey on purpose: these "
                  "views show the shape, not the object's colours or materials.")
            + "<div class='row'>" + "".join(views) + "</div>" + _details(_kv(pairs)))
    warnings = rep.get("warnings") if rep is not None else None
    if isinstance(warnings, list) and warnings:
        body = "".join(f"<p class='missing'><b>Partial result:</b> {_e(str(w))}</p>" for w in warnings) + body
    return Section("mesh", "Mesh views", body, True)


def _coverage(ctx: _Context, rep: dict[str, Any] | None) -> Section:
    from app.capture.runner import load_pass_profiles
    from app.session import SessionError

    body = ""
    profiles = []
    captures = ctx.manifest.get("captures") or {}
    for p in range(1, _plan_passes(ctx.manifest) + 1):
        cid = f"p{p:02d}/profiles"
        if cid in captures:
            try:
                confined_file(ctx.root, captures[cid].get("file"), f"captures.{cid}.file")
                profiles.append(load_pass_profiles(ctx.root, p))
            except (SessionError, OSError) as exc:
                ctx.problems.append(str(exc))
    if profiles:
        rows = [[i + 1, f"{100 * float(np.isfinite(pr['z_mm']).mean()):.1f} %", pr["z_mm"].shape[0]]
                for i, pr in enumerate(profiles)]
        body += _table(["pass", "valid returns", "profiles"], rows)
        body += _img(coverage_figure(profiles), "coverage", "Range images of the passes (black: no return).")
        lead = _lead("How much of the object the laser scanner saw in each placement, and the holes left in the "
                     "surface (places no scan reached).")
        body = lead + _details(body, "Scanner coverage per pass")
    else:
        body += _missing("no gathered profiles", "kogei capture (a scan plan)")
    if rep is None or not isinstance(rep.get("surface"), dict):
        body += _missing("no hole report", f"kogei process {ctx.root}")
        return Section("coverage", "Coverage and filled holes", body, bool(profiles))
    holes = rep["surface"].get("holes") or {}
    items = holes.get("items") or []
    n_holes, n_filled = holes.get("count", len(items)), holes.get("filled")
    if n_holes:
        body += _lead(f"{n_holes} hole(s) of {float(holes.get('total_area_mm2', 0.0)):.0f} mm² in all were found; "
                      f"{n_filled or 0} of them were filled by smooth interpolation: there the shape is estimated, "
                      "not measured.")
    body += _kv([("holes found", n_holes), ("filled", n_filled),
                 ("total hole area", f"{holes.get('total_area_mm2', 0.0):.1f} mm²")])
    tech = _kv([("hole threshold", _q(holes.get("threshold_mm"), ".3f", "mm"))])
    if items:
        tech += _table(["area (mm²)", "largest distance to data (mm)", "filled by", "closed"],
                       [[h.get("area_mm2"), h.get("max_distance_mm"), h.get("filled_by"), h.get("closed")]
                        for h in items[:30]])
    mesh = ctx.products.get("mesh")
    path = ctx.product_path(mesh, "products.mesh") if mesh else None
    if path is not None:
        from render.meshio import load_mesh

        v = load_mesh(path).vertices
        body += _img(holes_figure(v, items), "holes", "Where the holes were: green filled and closed, red left open.")
    body += _details(tech, "Holes in detail")
    return Section("coverage", "Coverage and filled holes", body, True)


def _chart(ctx: _Context) -> Section:
    from app.report.figures import chart_overlay_figure, patch_error_figure
    from app.report.readable import exposure_text

    charts = {cid: rec for cid, rec in (ctx.manifest.get("captures") or {}).items() if rec.get("kind") == "chart"}
    cmd = _step_command(ctx.root, "colour")
    if not charts:
        return Section("chart", "Colour chart", _missing("no colour-chart frame was captured (plan without camera "
                                                         "or chart)", "kogei capture --camera ... (chart first)"),
                       False)
    colour = ctx.products.get("colour")
    if not colour:
        body = _kv([("chart frames", ", ".join(sorted(charts)))])
        body += _missing("chart detection and patch errors (the colour step has not run on this session)", cmd)
        return Section("chart", "Colour chart", body, False)
    body = ""
    shown = False
    for tag, files in sorted((colour.get("passes") or {}).items()):
        chart = ctx.product_doc(files.get("chart"), f"products.colour.passes.{tag}.chart")
        pre = ctx.product_bytes(files.get("preview"), f"products.colour.passes.{tag}.preview")
        if chart is None or pre is None:
            continue
        import io

        from PIL import Image

        preview = np.asarray(Image.open(io.BytesIO(pre)).convert("RGB"))
        errs = chart.get("patch_errors") or {}
        usable = [p["usable"] for p in chart["patches"]]
        mean_de = float(errs.get("mean", float("nan")))
        body += f"<h3>{_e(tag)}: {_e(chart['raw'])}</h3>"
        body += _lead(f"A colour chart of known colours was photographed with the object ({tag}). The camera's colours "
                      f"were calibrated on it: afterwards its patches differ from their true colours by "
                      f"ΔE00 {mean_de:.2f} on average (largest {float(errs.get('max', float('nan'))):.2f}); a ΔE00 of "
                      "about 1 is the smallest colour difference most people can see.")
        if chart.get("warnings"):
            body += _caveat("; ".join(chart["warnings"]))
        tech = _kv([("chart", chart["chart"]), ("found by", f"{chart['method']} (confidence {chart['confidence']:.2f}, "
                                                            f"{chart['detect_seconds']:.2f} s)"),
                    ("usable patches", f"{sum(usable)} of {len(usable)}"),
                    ("patch error (ΔE00, 3 x 3 colour fit)", f"mean {mean_de:.2f}, max {errs.get('max', float('nan')):.2f}"),
                    ("exposure", exposure_text(chart.get("exposure_time"), chart.get("iso"), chart.get("f_number"))),
                    ("warnings", "; ".join(chart.get("warnings") or []) or "none")])
        figs = "<div class='row'>" + _img(chart_overlay_figure(preview, chart), f"chart overlay {tag}",
                                          "The chart as found in the photo; each patch's remaining error is written "
                                          "on it (green: used, red: left out).")
        if errs.get("delta_e00"):
            figs += _img(patch_error_figure([p["name"] for p in chart["patches"]], errs["delta_e00"], usable),
                         f"patch errors {tag}", "Remaining colour error (ΔE00) of each patch after the calibration.")
        body += _details(tech + figs + "</div>", "The chart, its patches and the exposure")
        shown = True
    return Section("chart", "Colour chart", body or _missing("intact chart products", cmd), shown)


def _materials_doc(ctx: _Context) -> dict[str, Any] | None:
    return ctx.product_doc((ctx.products.get("materials") or {}).get("report"), "products.materials.report")


def _no_materials(ctx: _Context, what: str) -> str:
    from app.batch.steps import DEFAULT_MATERIAL

    if ctx.products.get("object_materials"):
        return ("<p class='lead'>Not needed for this session: its materials were measured on the 3-D mesh "
                "(see <a href='#object-materials'>Materials on the mesh</a>).</p>")
    return _missing(f"{what} (the materials step has not run on this session; the renders use the stated "
                    f"default material {DEFAULT_MATERIAL} as a stand-in)", _step_command(ctx.root, "materials"))


def _image_verdicts(doc: dict[str, Any]) -> list[tuple[dict[str, Any], Any]]:
    """Every image-only region with its verdict (:func:`app.report.readable.verdict`)."""
    from app.report.readable import verdict

    return [(r, verdict(r.get("material"), r.get("confidence"), r.get("misfit"),
                        r.get("group") or ([r["material"]] if r.get("material") else []), r.get("note") or ""))
            for r in doc.get("regions") or [] if isinstance(r, dict)]


def _spectra(ctx: _Context) -> Section:
    from app.report.figures import material_spectra_figure
    from processing.materials.identification import NO_FIT

    title = "Spectra with uncertainty vs model spectra"
    doc = _materials_doc(ctx)
    if doc is None:
        return Section("spectra", title, _no_materials(
            ctx, "estimated spectral reflectance of the object's regions with its uncertainty"), False)
    per_material: dict[str, list[tuple[dict[str, Any], Any]]] = {}
    for r, v in _image_verdicts(doc):
        if r.get("material") not in (None, NO_FIT) and r.get("reflectance") and r.get("uncertainty"):
            per_material.setdefault(r["material"], []).append((r, v))
    if not per_material:
        return Section("spectra", title, "<p>No region was identified, so there is no spectrum to show.</p>", False)
    entries = []
    for material, regs in per_material.items():
        r, v = max(regs, key=lambda rv: int(rv[0].get("pixels") or 0))
        more = f" (largest of {len(regs)})" if len(regs) > 1 else ""
        entries.append({"material": material, "reflectance": r["reflectance"], "uncertainty": r["uncertainty"],
                        "level": v.level, "title": f"{material}: {r['region']}{more}\n{v.label}, confidence "
                                                   f"{float(r.get('confidence') or 0):.2f}"})
    body = _lead("How much light each identified material reflects at each colour of the spectrum (blue on the "
                 "left, red on the right), as estimated from the photos, with its uncertainty (shaded). The "
                 "dashed red line is the shape the identified material should have; a close match supports the "
                 "identification. One plot per material, from its largest region.")
    vague = [e["material"] for e in entries
             if float(np.median(np.asarray(e["uncertainty"], float))) > float(np.max(np.asarray(e["reflectance"], float)))]
    if vague:
        body += _lead(f"For {', '.join(vague)} the uncertainty is larger than the spectrum itself (the shading fills "
                      "the plot): the photos pin its spectrum down poorly. The identification does not rest on this "
                      "curve; it compares the camera's colours with each candidate's directly.")
    if any(e["level"] == "unreliable" for e in entries):
        body += _caveat("titles in red are unreliable identifications: their spectra do not match the named "
                        "material (see the table below).")
    body += _img(material_spectra_figure(doc["wavelengths"], entries, doc["light_deg"]), "region spectra",
                 "Measured reflectance (solid) ± its uncertainty (shaded, clipped to the physical range) against "
                 "the identified material's model spectrum, scaled to the same mean (dashed).")
    body += _details(_kv([("estimator", f"{doc['method']}, chart {doc['chart']}"),
                          ("candidates modelled at", f"{doc['light_deg']:.0f} deg from the normal")]))
    return Section("spectra", title, body, True)


#: Material maps drawn in full (one per pass); the rest are listed in the folded details.
MAPS_SHOWN_PER_PASS = 1


def _materials(ctx: _Context) -> Section:
    from app.batch.materials import _BACKDROP_COLOUR, material_colour
    from app.report.figures import NO_MATERIAL_RGB, palette_colour, region_map_figure
    from app.report.readable import misfit_number
    from processing.materials.identification import NO_FIT

    title = "Material map and confidences"
    doc = _materials_doc(ctx)
    if doc is None:
        return Section("materials", title, _no_materials(ctx, "identified materials and their confidences"), False)
    judged = _image_verdicts(doc)
    answers = list(dict.fromkeys(r["material"] for r, _ in judged if r.get("material") not in (None, NO_FIT)))
    draw = {a: palette_colour(i) for i, a in enumerate(answers)}
    rows, tech_rows = [], []
    for r, v in judged:
        alloy = ""
        if r.get("alloy_weights") and v.level != "unreliable" and _is_alloy(r.get("material")):
            alloy = ", ".join(f"{m} {100 * r['alloy_weights'][m]:.0f} ± {100 * (r.get('alloy_std') or {}).get(m, 0):.0f} %"
                              for m in r["alloy_weights"])
        named = r.get("confidence") is not None and r.get("material") not in (None, NO_FIT)
        rows.append([r["region"], v.answer, v.label, v.why, f"{r['confidence']:.2f}" if named else "-", r["pixels"],
                     len(r.get("frames") or [])])
        tech_rows.append([r["region"], "" if r.get("confidence") is None else f"{r['confidence']:.2f}",
                          r.get("runner_up") or "", misfit_number(r.get("misfit")),
                          "" if r.get("chi2") is None else f"{float(r['chi2']):.1f}", alloy])
    counts = collections.Counter(v.level for _, v in judged)
    body = _lead(f"The photos were divided into regions of similar colour and each region compared with the known "
                 f"materials (metals, alloys, lacquers). {len(judged)} regions: {counts['reliable']} reliable, "
                 f"{counts['uncertain']} uncertain, {counts['unreliable']} unreliable. These regions are found in "
                 "the photos only, not placed on the 3-D mesh, so the same part of the object appears once per "
                 "placement.")
    bad = [(r, v) for r, v in judged if v.level == "unreliable"]
    if bad:
        body += _caveat(f"{len(bad)} of {len(judged)} regions are unreliable and must not be taken as identified: "
                        + ", ".join(f"{r['region']} ({v.answer})" for r, v in bad) + ". The table says why for each.")
    levels = [v.level for _, v in judged]
    body += _verdict_table(["region", "answer", "verdict", "why", "confidence", "pixels", "photos"], rows, levels)
    largest = doc.get("largest")
    body += _details(_verdict_table(["region", "best candidate's confidence", "runner-up", "misfit", "chi-square",
                                     "alloy Ag, Cu, Au (alloys only)"],
                                    tech_rows, levels)
                     + _kv([("largest identified material", "none" if not largest else
                             f"{largest['material']} ({largest['pixels']} pixels)"),
                            ("misfit", "reduced chi-square of the best candidate (its chi-square over its degrees of "
                                       "freedom): 1 means it matches within the measurement noise; above 25 no "
                                       "candidate fits")]))
    import io

    from PIL import Image

    figs, folded = "", ""
    per_pass: collections.Counter = collections.Counter()
    for cid, rec in sorted(((ctx.products.get("materials") or {}).get("maps") or {}).items()):
        blob = ctx.product_bytes(rec, f"products.materials.maps.{cid}")
        if blob is None:
            continue
        tag = f"p{cid[1:3]}" if cid[:1] == "p" else ""
        keys: dict[tuple[int, int, int], dict[str, list[str]]] = {}
        colours: dict[tuple[int, int, int], tuple[int, int, int]] = {}
        for r, v in judged:
            if r.get("pass") not in (None, tag) or cid not in (r.get("frames") or [cid]):
                continue
            src = material_colour(r.get("material"))       # the colour the materials step gave the answer
            keys.setdefault(src, {}).setdefault(f"{v.answer} ({v.label})", []).append(str(r["region"]))
            colours[src] = NO_MATERIAL_RGB if v.level == "unreliable" else draw.get(r.get("material"), NO_MATERIAL_RGB)
        legend = [(src, colours[src], "; ".join(f"{', '.join(names)}: {answer}" for answer, names in texts.items()))
                  for src, texts in keys.items()]
        img = np.asarray(Image.open(io.BytesIO(blob)).convert("RGB"))
        fig = _img(region_map_figure(img, legend, _BACKDROP_COLOUR, title=f"photo {cid}"), f"material map {cid}",
                   f"{cid}: each region of the object in its own colour (legend: region, answer, verdict).")
        per_pass[tag] += 1
        if per_pass[tag] <= MAPS_SHOWN_PER_PASS:
            figs += fig
        else:
            folded += fig
    body += figs + _details(folded, f"Material maps of the other {sum(per_pass.values()) - len(per_pass)} photos")
    return Section("materials", title, body, bool(figs))


def _is_alloy(name: Any) -> bool:
    """True for an alloy preset (a composition is meaningful only for an alloy)."""
    from processing.materials.presets import get_material

    try:
        return get_material(str(name)).family == "alloy"
    except (ValueError, KeyError):
        return False


def _verdict_table(header: list[str], rows: list[list[Any]], levels: list[str]) -> str:
    """A table whose rows are tinted by their verdict (unreliable red, uncertain amber, not measured grey)."""
    head = "".join(f"<th>{_e(h)}</th>" for h in header)
    body = "".join(f"<tr class='v-{lvl}'>" + "".join(f"<td>{_e(_fmt(c))}</td>" for c in row) + "</tr>"
                   for row, lvl in zip(rows, levels))
    return f"<table class='verdicts'><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _object_materials(ctx: _Context) -> Section:
    from app.report.object_section import object_materials_section

    kit = {"table": _table, "kv": _kv, "img": _img, "missing": _missing, "lead": _lead, "caveat": _caveat,
           "details": _details, "verdict_table": _verdict_table}
    body, shown = object_materials_section(ctx, kit)
    return Section("object-materials", "Materials on the mesh", body, shown)


def _renders(ctx: _Context) -> Section:
    from app.report.summary import render_materials_text

    rec = ctx.products.get("renders")
    if not rec:
        return Section("renders", "Renders under D65 and A", _missing(
            "no renders", f"kogei batch {ctx.root} --steps render"), False)
    shown, measured = render_materials_text(ctx)
    names = {"D65": "daylight (D65)", "A": "tungsten lamp light (illuminant A)"}
    figs = []
    for ill, img in (rec.get("images") or {}).items():
        blob = ctx.product_bytes(img, f"products.renders.images.{ill}")
        if blob is not None:
            figs.append(_img(blob, f"render under {ill}", f"Under {names.get(ill, ill)}. Materials shown: {shown}.",
                             kind="render"))
    body = _lead("Pictures computed from the measured shape and materials, as the object would look under "
                 "daylight and under warm tungsten light.")
    if not measured:
        body += _caveat(f"these renders show {shown} ({rec.get('material_source') or 'no source recorded'}). They "
                        "do not show how the object's different parts really look.")
    else:
        from app.report.summary import material_verdicts, region_names

        bad = [name for name, v, _ in material_verdicts(ctx)[1] if v.level == "unreliable"]
        if bad:
            body += _caveat(f"{len(bad)} region(s) have no reliable material ({region_names(bad)}); the renders draw "
                            "them with their closest candidate material, so there they may not look like the object.")
    body += "<div class='row'>" + "".join(figs) + "</div>"
    body += _details(_kv([("materials", f"{rec.get('material')} ({rec.get('material_source', '')})"),
                          ("size", f"{rec['size'][0]} x {rec['size'][1]} pixels"), ("quality preset", rec.get("preset"))]))
    return Section("renders", "Renders under D65 and A", body, bool(figs))


def _has_probe(ctx: _Context) -> bool:
    """A probe session (``kogei capture --plan probe``) or one holding a probe map."""
    plan = ctx.manifest.get("plan") or {}
    return (isinstance(plan, dict) and plan.get("kind") == "probe") or "probe" in ctx.products


def _probe(ctx: _Context) -> Section:
    """The light probe: the map tone-mapped over azimuth and elevation, and its report's figures."""
    from app.report.figures import probe_map_figure, probe_tone_map
    from processing.lighting.environment_map import pixel_directions, read_environment

    title = "Light probe"
    rec = ctx.products.get("probe")
    if not rec:
        return Section("probe", title, _missing("no light probe made from these brackets",
                                                f"kogei probe {ctx.root} --out probe.exr"), False)
    path = ctx.product_path(rec, "products.probe")
    if path is None:
        return Section("probe", title, "<p class='missing'>The probe's map could not be read (see Problems found)."
                                       "</p>", False)
    env = read_environment(path)
    rep = ctx.product_json("probe_report") or {}
    m = rep.get("map") or {}
    angle = caps = None
    toward = m.get("toward_camera")
    if isinstance(toward, list) and len(toward) == 3:
        d = pixel_directions(env.height, env.width)
        angle = np.degrees(np.arccos(np.clip(d @ np.asarray(toward, dtype=np.float64), -1.0, 1.0)))
        caps = (float(m.get("camera_mask_deg", 12.0)), 180.0 - float(m.get("back_mask_deg", 45.0)))
    png = probe_map_figure(probe_tone_map(env.to_linear_srgb()), angle, caps)
    lum = env.pixel_luminance()
    w = env.solid_angles()
    body = _lead("The light around the object as measured by the mirror sphere: every direction of the room "
                 "unwrapped onto a map (up at the top, the horizon across the middle), in the room's frame, with "
                 "the brightest lights compressed so the dim walls stay visible.")
    body += _img(png, "light probe map", "The light probe (tone-mapped). Inside the dashed lines: the "
                 "directions the sphere could not show (toward the camera and behind the sphere), filled from "
                 "their surroundings.")
    seconds = rep.get("seconds") or {}
    spectral = rep.get("spectral") or {}
    sphere = rep.get("sphere") or {}
    pairs = [("map", f"{env.width} x {env.height} pixels, {m.get('frame', 'room frame')}"),
             ("directions seen", _q(100 * float(m.get("observed_fraction", float("nan"))), ".0f", "%")),
             ("brightest / mean luminance", f"{_q(float(lum.max()), '.3g')} / "
                                            f"{_q(float((lum * w).sum() / w.sum()), '.3g')} "
                                            f"({m.get('units', 'relative units')})"),
             ("brackets", len(rep.get("frames") or [])),
             ("exposure times", ", ".join(_q(st.get("exposure_time_s"), ".4g", "s")
                                          for st in rep.get("settings") or [] if isinstance(st, dict))),
             ("pixels saturated in every bracket", _q(100 * float(rep.get("saturated_everywhere_fraction",
                                                                          float("nan"))), ".2f", "%")),
             ("sphere", f"radius {_q(sphere.get('radius_mm'), '.1f', 'mm')}, {_q(sphere.get('radius_px'), '.0f', 'px')} "
                        f"in the image, outline fit {_q(sphere.get('outline_rms_px'), '.2f', 'px RMS')}"),
             ("masked caps", f"{_q(m.get('camera_mask_deg'), '.0f', 'deg')} toward the camera, "
                             f"{_q(m.get('back_mask_deg'), '.0f', 'deg')} behind the sphere"),
             ("spectral calibration", f"{spectral.get('method', 'unknown')} estimator, chart light "
                                      f"{spectral.get('light', 'unknown')}, chart RMS reflectance error "
                                      f"{_q(spectral.get('chart_rmse'), '.3f')}")]
    second = spectral.get("filter_frames")
    if isinstance(second, list) and second:
        median = spectral.get("projection_spectral_median")
        median_pct = 100 * median if isinstance(median, (int, float)) and not isinstance(median, bool) else None
        pairs += [("second bracket set", f"{len(second)} brackets through the filter {spectral.get('filter', 'unknown')}, "
                                         f"its chart {spectral.get('filter_chart', 'unknown')}"),
                  ("basis spectra kept", f"{spectral.get('components', 'unknown')}: 99 % of directions within "
                                         f"{_q(spectral.get('projection_dxy_p99'), '.4f')} in xy of the estimated "
                                         f"spectra, median spectral error {_q(median_pct, '.1f', '%')}")]
    pairs.append(("time", ", ".join(f"{k} {_q(v, '.1f', 's')}" for k, v in seconds.items())))
    body += _details(_kv(pairs) + "<p>Render under it with <code>kogei render MESH --environment "
                     f"{_e(_shown(path))}</code>.</p>")
    return Section("probe", title, body, True)


def _when(text: Any) -> str:
    """A manifest time as "2026-11-28 17:47 UTC" (the text as given when it is not one)."""
    try:
        return _utc(str(text)).strftime("%Y-%m-%d %H:%M UTC")
    except ValueError:
        return str(text or "unknown")


def _utc(text: str) -> _dt.datetime:
    return _dt.datetime.strptime(text, "%Y-%m-%dT%H:%M:%S.%fZ")


def _timing(ctx: _Context, rep: dict[str, Any] | None) -> Section:
    from app.batch.steps import STEP_NAMES

    rows: list[tuple[str, float]] = []
    history = ctx.manifest.get("history") or []
    start = next((h["utc"] for h in history if h["event"] == "started"), None)
    end = next((h["utc"] for h in reversed(history) if h["event"] == "complete"), None)
    if start and end:
        rows.append(("capture (start -> complete)", (_utc(end) - _utc(start)).total_seconds()))
    if rep is not None:
        rows += [(f"geometry: {k}", float(v)) for k, v in (rep.get("timings_s") or {}).items()]
    steps = ((ctx.manifest.get("batch") or {}).get("steps") or {})
    # in the order the pipeline runs them (the manifest keeps the order of the last runs)
    order = {name: i for i, name in enumerate(STEP_NAMES)}
    ordered = sorted(steps.items(), key=lambda kv: (order.get(kv[0], len(order)), kv[0]))
    table = [[name, rec.get("utc"), rec.get("seconds"), rec.get("fingerprint", "")[:12]] for name, rec in ordered]
    rows += [(f"batch: {name}", float(rec.get("seconds", 0.0))) for name, rec in ordered]
    if not rows:
        return Section("timing", "Timing of every step", _missing("no step has run", f"kogei batch {ctx.root}"), False)
    body = _lead("How long each step took, in the order the steps run.")
    body += _img(timing_figure(rows), "timing", "Seconds per step.")
    if table:
        body += _details(_table(["step", "last run (UTC)", "seconds", "fingerprint"], table)
                         + "<p>The fingerprint identifies a step's inputs and settings: a step is run again only when "
                           "its fingerprint changes.</p>", "Batch steps")
    return Section("timing", "Timing of every step", body, True)


def report_sections(session_dir: str | os.PathLike[str]) -> list[Section]:
    """The report's sections for a session (see the module docstring)."""
    return _sections_and_summary(Path(session_dir))[0]


def _sections_and_summary(root: Path) -> tuple[list[Section], str]:
    """The sections and the HTML of the "At a glance" box (:mod:`app.report.summary`)."""
    from app.report.summary import glance

    ctx = _Context(root)
    rep = ctx.process_report()
    builders: list[tuple[str, str, Callable[[], Section]]] = [
        ("object", "Object and plan", lambda: _object(ctx)),
        ("capture", "Capture log", lambda: _capture_log(ctx)),
        ("calibration", "Scanner calibration", lambda: _calibration(ctx)),
        ("registration", "Registration and pose graph", lambda: _registration(ctx, rep)),
        ("posed", "Camera and lamp", lambda: _posed(ctx)),
        ("mesh", "Mesh views", lambda: _mesh(ctx, rep)),
        ("coverage", "Coverage and filled holes", lambda: _coverage(ctx, rep)),
        ("chart", "Colour chart", lambda: _chart(ctx)),
        ("spectra", "Spectra with uncertainty vs model spectra", lambda: _spectra(ctx)),
        ("object-materials", "Materials on the mesh", lambda: _object_materials(ctx)),
        ("materials", "Material map and confidences", lambda: _materials(ctx)),
        ("renders", "Renders under D65 and A", lambda: _renders(ctx)),
        ("timing", "Timing of every step", lambda: _timing(ctx, rep)),
    ]
    if _has_probe(ctx):                # only a probe session has one; other reports stay as they were
        builders.insert(-1, ("probe", "Light probe", lambda: _probe(ctx)))
    sections = []
    for key, title, build in builders:
        try:
            sections.append(build())
        except (ValueError, OSError, KeyError, TypeError, IndexError, AttributeError, OverflowError, MemoryError,
                _DecompressionBomb) as exc:
            # a product the section cannot read (an older or damaged file) must not cost the whole report
            text = f"{title}: the session's data could not be shown ({type(exc).__name__}: {exc})"
            ctx.problems.append(text)
            sections.append(Section(key, title, f"<p class='missing'><b>Could not be shown:</b> {_e(text)}</p>",
                                    False))
    try:
        box = glance(ctx, rep).html()
    except (ValueError, OSError, KeyError, TypeError, IndexError, AttributeError) as exc:
        text = f"At a glance: the summary could not be made ({type(exc).__name__}: {exc})"
        ctx.problems.append(text)
        box = f"<div class='glance' id='summary'><p class='missing'><b>Could not be shown:</b> {_e(text)}</p></div>"
    if ctx.problems:
        body = "<ul>" + "".join(f"<li>{_e(p)}</li>" for p in dict.fromkeys(ctx.problems)) + "</ul>"
        sections.insert(0, Section("problems", "Problems found", body, True))
    return sections, box


_CSS = """
body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;margin:0 auto;max-width:1000px;padding:1em 1.5em;
color:#222;line-height:1.4}
h1{font-size:1.6em;margin-bottom:0.2em}h2{border-bottom:2px solid #ddd;padding-bottom:0.2em;margin-top:1.6em}
h3{font-size:1em;margin-bottom:0.3em}table{border-collapse:collapse;margin:0.5em 0;font-size:0.85em}
td,th{border:1px solid #ddd;padding:2px 6px;text-align:left;vertical-align:top}th{background:#f4f4f4}
table.kv th{width:14em}figure{display:inline-table;vertical-align:top;margin:0.4em 0.8em 0.4em 0;min-width:15em}
figcaption{display:table-caption;caption-side:bottom;font-size:0.8em;color:#555;padding-top:2px}
img{max-width:100%}.row{display:flex;flex-wrap:wrap;gap:0.5em;align-items:flex-start}.missing{background:#fff8e1;border-left:4px solid #f0b400;
padding:0.4em 0.8em}nav a{margin-right:0.8em;font-size:0.9em}code{background:#f4f4f4;padding:0 3px}
p.lead{font-size:1em;margin:0.4em 0 0.6em;max-width:48em}
p.caveat{background:#fdecea;border-left:4px solid #c0392b;padding:0.4em 0.8em;max-width:48em}
details{margin:0.5em 0}summary{cursor:pointer;color:#2c5d8f;font-size:0.9em}
.glance{border:2px solid #2c5d8f;border-radius:6px;padding:0.2em 1em 0.6em;background:#f5f9fd;margin:1em 0}
.glance h2{border:none;margin:0.4em 0 0.2em}.glance table{font-size:0.95em;border:none}
.glance th,.glance td{border:none;border-bottom:1px solid #dde6ef;padding:4px 8px}.glance th{background:none;width:9em}
.badge{display:inline-block;min-width:5.5em;text-align:center;border-radius:3px;padding:0 4px;font-size:0.8em;
font-weight:bold;color:white}.badge.good{background:#2e7d32}.badge.check{background:#b26a00}
.badge.poor{background:#c0392b}.badge.none{background:#888}ul.uncertain li{margin:0.2em 0}
tr.v-unreliable td{background:#fdecea}tr.v-uncertain td{background:#fff8e1}tr.v-missing td{color:#777}
figure.render figcaption{font-size:0.85em;color:#333}
"""


def build_report(session_dir: str | os.PathLike[str]) -> str:
    """The HTML text of the report of the session at ``session_dir``.

    Raises
    ------
    UsageError
        ``session_dir`` is not a readable session.
    """
    from app.session import utc_now

    root = Path(session_dir)
    sections, box = _sections_and_summary(root)
    manifest = _Context(root).manifest
    name = (manifest.get("object") or {}).get("name") or _shown(root.name)
    nav = "<a href='#summary'>At a glance</a>" + "".join(f"<a href='#{s.key}'>{_e(s.title)}</a>" for s in sections)
    parts = [f"<section id='{s.key}'><h2>{_e(s.title)}</h2>{s.body}</section>" for s in sections]
    held = sum(s.has_data for s in sections)
    text = ("<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            f"<title>kogei report: {_e(name)}</title><style>{_CSS}</style></head><body>"
            f"<h1>{_e(name)}</h1><p>kogei session report, written {_e(_when(utc_now()))} from <code>{_e(_shown(root.resolve()))}"
            f"</code>; {held} of {len(sections)} sections have data. Each section starts with what it shows in plain "
            f"words; the figures behind it are folded away under <i>Technical details</i>.</p>{box}<nav>{nav}</nav>"
            + "".join(parts) + "</body></html>\n")
    # a non-UTF-8 session path (surrogate escapes) is shown with backslash escapes, never a crash
    return text.encode("utf-8", "backslashreplace").decode("utf-8")


def write_report(session_dir: str | os.PathLike[str], out: str | os.PathLike[str] | None = None) -> Path:
    """Write the report; returns its path.

    Parameters
    ----------
    session_dir
        The session.
    out
        The HTML file to write (atomically).  Default: ``products/report.html``
        inside the session, recorded in its manifest's ``products`` with its
        checksum (this needs the session's lock: not while a capture runs).
    """
    from app.session import Session, SessionError, atomic_write_bytes

    root = Path(session_dir)
    if out is not None and Path(out).suffix.lower() not in (".html", ".htm"):
        raise UsageError(f"--out: {out} must end in .html")
    text = build_report(root).encode("utf-8", "backslashreplace")
    if out is not None:
        try:
            return atomic_write_bytes(Path(out), text)
        except OSError as exc:
            raise UsageError(f"--out {out}: cannot write: {exc.strerror or exc}") from None
    try:
        check_not_symlink(root, REPORT_FILE, "report")
    except UnsafeSessionPath as exc:
        raise UsageError(f"{exc}; or write the report elsewhere with --out FILE.html") from None
    try:
        with Session.open(root) as session:
            info = session.write_file(REPORT_FILE, text)
            products = dict(session.manifest.get("products") or {})
            products["report"] = {"file": info.path, "sha256": info.sha256, "bytes": info.bytes}
            session.update("products", products)
    except SessionError as exc:
        raise UsageError(f"{exc}; or write the report elsewhere with --out FILE.html") from None
    return root / REPORT_FILE
