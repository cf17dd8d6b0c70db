"""The steps ``kogei batch`` runs on a session, and when each one is up to date.

docs/batch.md.  A step reads some records of the session (captures and
products, each with its SHA-256 in the manifest), takes some parameters and
runs some code.  Its **fingerprint** is the SHA-256 of those three:

* inputs: the SHA-256 of every capture or product record the step reads;
* parameters: the options that change its result (preset, calibration, ...);
* code: :func:`app.batch.code_version.code_version` of the modules it runs.

After a step has written its products (atomically, checksummed, referenced
from the manifest's ``products``), its record -- fingerprint, inputs,
parameters, the SHA-256 of each product it wrote, seconds -- goes into the
manifest's ``batch.steps`` as the step's *last* journal write.  That record
is the commit point: a step killed before it has no record and runs again;
a step with a record is up to date only while its fingerprint matches and
every product it lists is still intact.  So Ctrl-C or ``kill -9`` at any
moment leaves the session consistent, and the rerun redoes exactly the
interrupted step.

Steps: ``geometry`` (:func:`app.workflows.process_session.process_session`),
``colour`` (the chart frames, :mod:`app.batch.colour`), ``materials`` (the
object frames' regions and materials, :mod:`app.batch.materials`), ``render``
(the mesh under D65 and A, in the largest identified material) and ``report`` (:func:`app.report.html.build_report`).
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from app.batch.code_version import code_version
from app.errors import UsageError
from app.session_paths import check_not_symlink, confined_file
from processing.common.png import png_bytes

__all__ = ["BatchOptions", "Step", "STEPS", "STEP_NAMES", "UNAVAILABLE_STEPS", "parse_steps", "fingerprint",
           "step_inputs", "up_to_date", "run_step", "DEFAULT_MATERIAL", "RENDER_ILLUMINANTS", "RENDER_SIZE"]

#: Material of the render step when the session holds no identified materials (stated in the report).
DEFAULT_MATERIAL = "nami-shibuichi"
#: The render step's "material" when the session's materials were measured on the mesh (per face).
MEASURED = "measured on the mesh"
RENDER_ILLUMINANTS = ("D65", "A")
RENDER_SIZE = (320, 240)
RENDERS = "products/renders"
REPORT_FILE = "products/report.html"


@dataclass(frozen=True)
class BatchOptions:
    """Parameters of a batch run (the same for every session).

    Attributes
    ----------
    preset
        ``draft``, ``standard`` or ``reference``: the geometry preset and the render preset.
    calibration
        A calibrated session or calibration JSON installed into every session
        before its geometry step (``kogei process --calibration``); None: each
        session's own calibration.
    render_size
        Width and height of the renders (pixels).
    chart
        The colour chart in the chart frames: ``classic24``, ``sg140`` or ``vinyl18``.
    """

    preset: str = "standard"
    calibration: str | None = None
    render_size: tuple[int, int] = RENDER_SIZE
    chart: str = "classic24"

    def __post_init__(self) -> None:
        if self.preset not in ("draft", "standard", "reference"):
            raise UsageError(f"--preset must be draft, standard or reference, got {self.preset!r}")
        w, h = self.render_size
        if not (isinstance(w, int) and isinstance(h, int) and 16 <= w <= 4096 and 16 <= h <= 4096):
            raise UsageError(f"render size must be 16..4096 pixels each way, got {w}x{h}")
        if self.chart not in ("classic24", "sg140", "vinyl18"):
            raise UsageError(f"--chart must be classic24, sg140 or vinyl18, got {self.chart!r}")


Log = Callable[[str], None]


@dataclass(frozen=True)
class Step:
    """One batch step: what it reads, which parameters and code it depends on, how it runs."""

    name: str
    modules: tuple[str, ...]
    inputs: Callable[[Path, dict[str, Any], BatchOptions], dict[str, str]]
    params: Callable[[BatchOptions], dict[str, Any]]
    run: Callable[[Path, BatchOptions, Log], dict[str, Any]]
    needs: tuple[str, ...] = field(default=())


# ---------------------------------------------------------------------------- geometry
def _calibration_sha(source: str) -> str:
    from app.workflows.calibration import calibration_source_bytes

    return hashlib.sha256(calibration_source_bytes(source)[1]).hexdigest()


def _geometry_inputs(root: Path, manifest: dict[str, Any], options: BatchOptions) -> dict[str, str]:
    inputs = {cid: rec.get("sha256", "") for cid, rec in sorted(manifest["captures"].items())
              if rec.get("kind") == "profiles"}
    if options.calibration is None:
        cal = manifest.get("calibration") or {}
        inputs["calibration"] = cal.get("sha256", "none")
    return inputs


def _geometry_params(options: BatchOptions) -> dict[str, Any]:
    return {"preset": options.preset,
            "calibration": None if options.calibration is None else _calibration_sha(options.calibration)}


def _geometry_run(root: Path, options: BatchOptions, log: Log) -> dict[str, Any]:
    from app.workflows.process_session import process_session

    report = process_session(root, preset=options.preset, calibration=options.calibration, message=log)
    registered = sum(1 for p in report["passes"] if p.get("registered"))
    log(f"mesh: {report['mesh']['triangles']} triangles, {registered} of {len(report['passes'])} passes registered")
    for text in report.get("warnings") or []:
        log(f"INCOMPLETE: {text}")        # and in the manifest, the report and the batch's summary line
    return {"products": ("mesh", "process_report"),
            "summary": {"triangles": report["mesh"]["triangles"], "watertight": report["mesh"]["watertight"],
                        "registered_passes": registered, "passes": len(report["passes"]),
                        "complete": report.get("complete", True), "warnings": report.get("warnings", []),
                        "timings_s": report["timings_s"]}}


# ---------------------------------------------------------------------------- render
def _render_inputs(root: Path, manifest: dict[str, Any], options: BatchOptions) -> dict[str, str]:
    products = manifest.get("products") or {}
    materials = ((products.get("materials") or {}).get("report") or {}).get("sha256", "none")
    return {"mesh": (products.get("mesh") or {}).get("sha256", "none"), "materials": materials,
            "object_materials": (products.get("object_materials") or {}).get("sha256", "none")}


def render_material(root: Path) -> tuple[str, str]:
    """The render's material and where it comes from: the identified material covering most pixels, or the default.

    Regions are found in the RAW frames, not on the mesh (the camera's pose relative to the table is not
    recorded), so one material stands for the whole mesh.
    """
    products = _manifest(root).get("products") or {}
    if isinstance(products.get("object_mesh"), dict) and isinstance(products.get("object_materials"), dict):
        return MEASURED, "measured on the mesh: each region with its fitted material (products/object-mesh.ply)"
    largest = (products.get("materials") or {}).get("largest")
    if largest and largest.get("material"):
        return largest["material"], (f"identified: the material covering the largest identified area "
                                     f"({largest['pixels']} pixels of the object frames), for the whole mesh")
    return DEFAULT_MATERIAL, "default (no identified materials)"


def _render_params(options: BatchOptions) -> dict[str, Any]:
    return {"preset": options.preset, "size": list(options.render_size), "illuminants": list(RENDER_ILLUMINANTS),
            "default_material": DEFAULT_MATERIAL}


def render_session_mesh(root: Path, illuminant: str, size: tuple[int, int], preset: str,
                        material: str = DEFAULT_MATERIAL, direction: tuple[float, float, float] | None = None) -> Any:
    """Render the session's ``products/mesh.ply`` with one material under one illuminant.

    Returns the :class:`render.renderer.RenderResult`.  The key light is
    :data:`app.workflows.scene_build.DEFAULT_LIGHT` with the illuminant's spectrum; the
    camera frames the mesh from ``direction`` (default: the renderer's view).
    """
    from app.workflows.scene_build import build_job
    from app.workflows.scene_spec import ObjectSpec, SceneSpec
    from processing.materials.presets import MaterialError
    from render.camera import Camera
    from render.errors import RenderInputError
    from render.renderer import render

    products = _manifest(root).get("products") or {}
    mesh = products.get("object_mesh") if material == MEASURED else products.get("mesh")
    if not mesh:
        raise UsageError(f"session {root} has no mesh; run 'kogei batch {root} --steps geometry' "
                         f"(or 'kogei process {root}') first")
    path = confined_file(root, mesh.get("file") if isinstance(mesh, dict) else None, "products.mesh.file")
    spec = SceneSpec(objects=[ObjectSpec(mesh=path, material=DEFAULT_MATERIAL if material == MEASURED else material)],
                     illuminant=illuminant, size=size,
                     preset=preset)
    try:
        job = build_job(spec)
        if direction is not None:
            lo, hi = job.scene.bounds()
            job.camera = Camera.framing(lo, hi, size[0], size[1], direction=direction)
        return render(job.scene, job.camera, job.settings)
    except (RenderInputError, MaterialError) as exc:
        raise UsageError(f"session {root}: render: {exc}") from None


def _render_run(root: Path, options: BatchOptions, log: Log) -> dict[str, Any]:
    from app.session import Session

    images = {}
    seconds = {}
    material, source = render_material(root)
    log(f"render material: {material} ({source})")
    for ill in RENDER_ILLUMINANTS:
        t = time.perf_counter()
        result = render_session_mesh(root, ill, options.render_size, options.preset, material=material)
        seconds[ill] = round(time.perf_counter() - t, 3)
        images[ill] = png_bytes(result.srgb8)
        log(f"rendered under {ill} ({options.render_size[0]}x{options.render_size[1]}, {seconds[ill]:.2f} s)")
    check_not_symlink(root, f"{RENDERS}/{RENDER_ILLUMINANTS[0]}.png", "render")
    with Session.open(root) as session:
        files = {ill: session.write_file(f"{RENDERS}/{ill}.png", blob) for ill, blob in images.items()}
        products = dict(session.manifest.get("products") or {})
        products["renders"] = {
            "material": material, "material_source": source,
            "size": list(options.render_size), "preset": options.preset,
            "images": {ill: {"file": f.path, "sha256": f.sha256, "bytes": f.bytes} for ill, f in files.items()},
        }
        session.update("products", products)
    return {"products": ("renders",), "summary": {"seconds": seconds, "material": material}}


# ---------------------------------------------------------------------------- report
def _report_inputs(root: Path, manifest: dict[str, Any], options: BatchOptions) -> dict[str, str]:
    # Everything the report shows is in the manifest or referenced from it with a checksum, so the manifest
    # (without the report's own traces and the checkpoint time) is its input.
    view = {k: v for k, v in manifest.items() if k not in ("updated_utc", "products", "batch")}
    view["products"] = {k: v for k, v in (manifest.get("products") or {}).items() if k != "report"}
    view["batch"] = {k: v for k, v in ((manifest.get("batch") or {}).get("steps") or {}).items() if k != "report"}
    blob = json.dumps(view, sort_keys=True, separators=(",", ":")).encode()
    return {"manifest": hashlib.sha256(blob).hexdigest()}


def _report_params(options: BatchOptions) -> dict[str, Any]:
    return {}


def _report_run(root: Path, options: BatchOptions, log: Log) -> dict[str, Any]:
    from app.report.html import build_report
    from app.session import Session

    html = build_report(root).encode("utf-8", "backslashreplace")
    check_not_symlink(root, REPORT_FILE, "report")
    with Session.open(root) as session:
        info = session.write_file(REPORT_FILE, html)
        products = dict(session.manifest.get("products") or {})
        products["report"] = {"file": info.path, "sha256": info.sha256, "bytes": info.bytes}
        session.update("products", products)
    log(f"report: {REPORT_FILE} ({info.bytes / 1024:.0f} KiB)")
    return {"products": ("report",), "summary": {"bytes": info.bytes}}


def _colour_step() -> Step:
    from app.batch.colour import colour_inputs, colour_params, colour_run

    return Step("colour", ("app.batch.steps", "app.batch.colour", "app.workflows.chart", "processing.camera.raw_decode",
                           "processing.camera.chart_detection", "processing.camera.chart_sampling", "processing.camera.chart_layout"),
                colour_inputs, colour_params, colour_run)


def _posed(manifest: dict[str, Any]) -> bool:
    """True when the session's photos are posed on its mesh (observations and frame poses exist)."""
    products = manifest.get("products") or {}
    return isinstance(products.get("observations"), dict) and isinstance(products.get("frame_poses"), dict)


def _materials_inputs(root: Path, manifest: dict[str, Any], options: BatchOptions) -> dict[str, str]:
    from app.batch.materials import materials_inputs

    if not _posed(manifest):
        return materials_inputs(root, manifest, options)
    products = manifest["products"]
    return {"observations": str(products["observations"].get("sha256", "")),
            "frame_poses": str(products["frame_poses"].get("sha256", "")),
            "mesh": str((products.get("mesh") or {}).get("sha256", ""))}


def _materials_params(options: BatchOptions) -> dict[str, Any]:
    from app.batch.materials import materials_params
    from app.workflows.object_materials import FIT_MODEL_ERROR, HOLDOUT_EVERY

    return {"image_only": materials_params(options),
            "on_mesh": {"holdout_every": HOLDOUT_EVERY, "model_error": FIT_MODEL_ERROR}}


def _materials_run(root: Path, options: BatchOptions, log: Log) -> dict[str, Any]:
    """Materials on the mesh when the photos are posed; else the image-only path, labelled as such."""
    from app.batch.materials import materials_run

    if not _posed(_manifest(root)):
        log("materials: image-only -- the photos are not posed on the mesh (no camera calibration), so regions "
            "are found in the images and one material stands for the mesh; calibrate the camera and the lamp "
            "(kogei calibrate) and process with them to measure materials on the mesh")
        return materials_run(root, options, log)
    from app.workflows.object_materials import measure_object

    doc = measure_object(root, message=log)
    val = doc.get("validation") or {}
    return {"products": ("object_materials", "object_mesh", "object_scene"),
            "summary": {"regions": len(doc["regions"]), "materials": [r["material"] for r in doc["regions"]],
                        "holdout_mean_de2000": val.get("mean_de2000"),
                        "baseline_mean_de2000": val.get("baseline_mean_de2000")}}


def _materials_step() -> Step:
    return Step("materials", ("app.batch.steps", "app.batch.materials", "app.workflows.spectral", "app.workflows.chart",
                              "app.workflows.identification", "app.workflows.materials", "processing.materials.segmentation",
                              "app.workflows.object_materials", "app.workflows.holdout_validation",
                              "processing.appearance.surface_segmentation", "processing.materials.forward_fit",
                              "processing.materials.confidence"),
                _materials_inputs, _materials_params, _materials_run, needs=("colour",))


STEPS: dict[str, Step] = {
    "geometry": Step("geometry", ("app.batch.steps", "app.workflows.process_session", "app.workflows.calibration", "app.capture.runner"),
                     _geometry_inputs, _geometry_params, _geometry_run),
    "colour": _colour_step(),
    "materials": _materials_step(),
    "render": Step("render", ("app.batch.steps", "app.workflows.scene_build", "app.workflows.scene_spec", "render.renderer"),
                   _render_inputs, _render_params, _render_run, needs=("geometry",)),
    "report": Step("report", ("app.batch.steps", "app.report.html", "app.report.figures", "app.demo.capture", "app.capture.runner"),
                   _report_inputs, _report_params, _report_run),
}
STEP_NAMES = tuple(STEPS)
#: Steps this version cannot run, with the reason given to the user.
UNAVAILABLE_STEPS: dict[str, str] = {}


def parse_steps(text: str | None) -> tuple[str, ...]:
    """Comma-separated step names -> the steps in pipeline order; unknown names are a :class:`UsageError`.

    Examples
    --------
    >>> parse_steps("report,geometry")
    ('geometry', 'report')
    >>> parse_steps(None)
    ('geometry', 'colour', 'materials', 'render', 'report')
    """
    if text is None:
        return STEP_NAMES
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise UsageError(f"--steps: give one or more of {','.join(STEP_NAMES)}")
    for n in names:
        if n in UNAVAILABLE_STEPS:
            raise UsageError(f"--steps: step {n!r} is not available: {UNAVAILABLE_STEPS[n]}; "
                             f"available steps: {','.join(STEP_NAMES)}")
        if n not in STEPS:
            raise UsageError(f"--steps: unknown step {n!r}; available steps: {','.join(STEP_NAMES)}")
    return tuple(n for n in STEP_NAMES if n in names)


# ---------------------------------------------------------------------------- fingerprints
def _manifest(root: Path) -> dict[str, Any]:
    from app.session import Session, SessionError

    try:
        return Session.read(root)
    except SessionError as exc:
        raise UsageError(str(exc)) from None


def step_inputs(step: Step, root: Path, manifest: dict[str, Any], options: BatchOptions) -> dict[str, Any]:
    """The step's inputs, parameters and code version (what its fingerprint hashes)."""
    return {"inputs": step.inputs(root, manifest, options), "params": step.params(options),
            "code": code_version(step.modules).sha256}


def fingerprint(parts: dict[str, Any]) -> str:
    """SHA-256 of the canonical JSON of a step's inputs, parameters and code version.

    Examples
    --------
    >>> a = fingerprint({"inputs": {"x": "1"}, "params": {"preset": "draft"}, "code": "c"})
    >>> a == fingerprint({"code": "c", "params": {"preset": "draft"}, "inputs": {"x": "1"}})
    True
    >>> a == fingerprint({"inputs": {"x": "2"}, "params": {"preset": "draft"}, "code": "c"})
    False
    """
    return hashlib.sha256(json.dumps(parts, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def _outputs_intact(root: Path, outputs: dict[str, Any]) -> str | None:
    from app.session import sha256_file

    for key, files in outputs.items():
        for rec in files:
            try:
                p = confined_file(root, rec.get("file"), f"batch.steps outputs {key}")
            except OSError:
                return f"{rec['file']} is missing"
            if sha256_file(p) != rec["sha256"]:
                return f"{rec['file']} was changed since the step wrote it"
    return None


def up_to_date(step: Step, root: Path, manifest: dict[str, Any], options: BatchOptions) -> tuple[bool, str, dict]:
    """Whether ``step`` can be skipped: (skip?, why it runs or why it is skipped, its fingerprint parts)."""
    parts = step_inputs(step, root, manifest, options)
    record = ((manifest.get("batch") or {}).get("steps") or {}).get(step.name)
    if record is None:
        return False, "never run", parts
    if record.get("fingerprint") != fingerprint(parts):
        changed = [k for k in ("inputs", "params", "code") if record.get(k) != parts[k]]
        return False, f"{' and '.join(changed) or 'fingerprint'} changed", parts
    broken = _outputs_intact(root, record.get("outputs") or {})
    if broken:
        return False, broken, parts
    return True, "up to date", parts


def _product_files(product: Any) -> list[dict[str, Any]]:
    """Every ``{"file", "sha256"}`` record inside a product entry (nested dicts included)."""
    if not isinstance(product, dict):
        return []
    if "file" in product and "sha256" in product:
        return [{"file": product["file"], "sha256": product["sha256"]}]
    return [f for value in product.values() for f in _product_files(value)]


def run_step(step: Step, root: Path, options: BatchOptions, log: Log) -> dict[str, Any]:
    """Run ``step`` on the session at ``root`` and commit its record (the step's last write).

    Returns the record written into ``batch.steps``.
    """
    from app.session import Session, SessionError

    before = _manifest(root)
    parts = step_inputs(step, root, before, options)
    t0 = time.perf_counter()
    result = step.run(root, options, log)
    seconds = time.perf_counter() - t0
    try:
        with Session.open(root) as session:
            products = session.manifest.get("products") or {}
            outputs = {key: _product_files(products[key]) for key in result["products"]}
            batch = dict(session.manifest.get("batch") or {})
            steps = dict(batch.get("steps") or {})
            steps[step.name] = {"fingerprint": fingerprint(parts), **parts, "outputs": outputs,
                                "utc": _utc(), "seconds": round(seconds, 3), "summary": result.get("summary", {})}
            batch["steps"] = steps
            session.update("batch", batch)
            return steps[step.name]
    except SessionError as exc:
        raise UsageError(str(exc)) from None


def _utc() -> str:
    from app.session import utc_now

    return utc_now()
