"""Processing panel: scanner calibration, registration and meshing of the open session with progress and cancel,
the residuals, and the manual 3-point registration when automatic registration fails.

A thin shell over :func:`app.workflows.calibration.calibrate_session` and
:func:`app.workflows.process_session.process_session` (what ``kogei calibrate`` and
``kogei process`` run).  Processing runs in a separate process
(:class:`app.gui.workers.ProcessJob`): registration and meshing hold the
interpreter for long stretches, and *Cancel* can stop them at once; the
session's files are written atomically, so a cancelled run leaves it as it was.
The residuals are the report's: per pass the points used, per pair the
registration's RMS residual against the residual expected from the clouds'
roughness, the overlap and the check's outcome, and the pose graph's consistency.
Each pair and the sphere calibration get a pass / warn / fail verdict with its
thresholds and why in a tooltip (:mod:`app.gui.guidance`).  Once the session has a
mesh, the panel shows it: a draft render (:func:`render_mesh_view`, the Preview
tab's renderer) made in a worker process, with a busy bar while it renders.

*Measure materials on the mesh* is a thin shell over
:func:`app.workflows.object_materials.measure_object` (what ``kogei fit-materials``
runs), in a worker process with its own *Cancel*.  It is enabled once the open
session's photos are posed on its mesh (``products/observations.npz``: camera and
lamp calibrations, then *Process*); its result line names the regions' answers
with a verdict (:func:`app.gui.guidance.materials_verdict`) and the held-out
photos' error when validated, and the window re-reads the session so the
Preview tab offers the measured material.  A cancelled run removes the object's
files it had written and not yet recorded (the mesh, scene and validation images
of a first measurement), so the session is left as it was; a cancelled
re-measurement may leave the previous measurement's files overwritten.

Examples
--------
>>> pair_row({"source": 1, "target": 0, "rmse_mm": 0.0312, "expected_rmse_mm": 0.03, "overlap": 0.61,
...           "verified": True, "reason": "ok", "method": "global"}, ["pass 1", "pass 2"])
['pass 2 → pass 1', '0.0312', '0.0300', '61%', 'global', 'yes', 'ok', 'pass: 1.0x the expected residual']
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from PySide6.QtCore import Qt, Signal
from PySide6.QtGui import QPixmap
from PySide6.QtWidgets import (
    QCheckBox,
    QComboBox,
    QDoubleSpinBox,
    QFileDialog,
    QFormLayout,
    QFrame,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QProgressBar,
    QPushButton,
    QScrollArea,
    QSizePolicy,
    QTreeWidget,
    QTreeWidgetItem,
    QVBoxLayout,
    QWidget,
)

from app.gui.plots import FigureDrawer
from app.gui.widgets import Panel, browse_row
from app.gui.workers import JobContext, Lane, ProcessJob

__all__ = ["ProcessingPanel", "pair_row", "run_processing", "run_materials", "materials_missing", "materials_summary",
           "camera_summary", "remove_unrecorded", "render_mesh_view", "MESH_VIEW_SIZE"]

#: Size (pixels) of the mesh view's render.
MESH_VIEW_SIZE = (360, 270)


def pair_row(pair: dict[str, Any], names: list[str]) -> list[str]:
    """Columns of one registered pair: pair, RMS, expected RMS, overlap, method, verified, reason, verdict."""
    def mm(v: Any) -> str:
        return "–" if v is None else f"{float(v):.4f}"

    src = names[pair["source"]] if pair["source"] < len(names) else str(pair["source"])
    tgt = names[pair["target"]] if pair["target"] < len(names) else str(pair["target"])
    overlap = pair.get("overlap")
    return [f"{src} → {tgt}", mm(pair.get("rmse_mm")), mm(pair.get("expected_rmse_mm")),
            "–" if overlap is None else f"{100 * float(overlap):.0f}%", str(pair.get("method", "")),
            "yes" if pair.get("verified") else "NO", str(pair.get("reason", "")), _pair_verdict(pair).level
            + ": " + _pair_verdict(pair).figure]


def _pair_verdict(pair: dict[str, Any]) -> Any:
    from app.gui.guidance import registration_verdict

    rmse, expected = pair.get("rmse_mm"), pair.get("expected_rmse_mm")
    return registration_verdict(None if rmse is None else float(rmse), None if expected is None else float(expected),
                                bool(pair.get("verified")))


def run_processing(session: str, preset: str, calibration: str | None, picks: dict | None = None,
                   camera_calibration: str | None = None, lamp_calibration: str | None = None, *,
                   message: Callable[[str], None]) -> dict[str, Any]:
    """:func:`app.workflows.process_session.process_session` in a worker process (module-level: picklable)."""
    from app.workflows.process_session import process_session

    return process_session(session, preset=preset, calibration=calibration, message=message, picks=picks,
                           camera_calibration=camera_calibration, lamp_calibration=lamp_calibration)


def run_materials(session: str, validate: bool, *, message: Callable[[str], None]) -> dict[str, Any]:
    """:func:`app.workflows.object_materials.measure_object` in a worker process (module-level: picklable)."""
    from app.workflows.object_materials import measure_object

    return measure_object(session, validate=validate, message=message)


def materials_missing(root: Path | None, manifest: dict[str, Any] | None) -> str | None:
    """Why the materials cannot be measured on the open session's mesh, or None when they can.

    Examples
    --------
    >>> materials_missing(None, None)
    'open a processed session first (Session tab)'
    """
    if root is None or not isinstance(manifest, dict):
        return "open a processed session first (Session tab)"
    ref = (manifest.get("products") or {}).get("observations")
    if not isinstance(ref, dict) or not (Path(root) / str(ref.get("file") or "")).is_file():
        return ("this session's photos are not posed on its mesh (no products/observations.npz): calibrate the "
                "camera and the lamps (above), then press 'Process the open session'")
    return None


def materials_summary(doc: dict[str, Any]) -> str:
    """The result line's text after the verdict word: regions, their answers, the held-out photos' error.

    Examples
    --------
    >>> gold = {"index": 0, "material": "gold", "confidence": 0.934, "group": ["gold"]}
    >>> materials_summary({"regions": [gold]})
    '1 region: 0 gold (confidence 0.93) · not validated on held-out photos'
    >>> materials_summary({"regions": [gold], "not_measured": {"faces": 12, "share": 0.0951}})
    '1 region: 0 gold (confidence 0.93) · 9.5 % of the surface not measured · not validated on held-out photos'
    >>> materials_summary({"regions": [gold], "not_measured": {"faces": 1, "share": 0.0002}}).split(" · ")[1]
    'under 0.1 % of the surface not measured'
    """
    from app.workflows.object_materials import answer_text, unmeasured_share_text

    regions = list(doc.get("regions") or [])
    answers = "; ".join(f"{r.get('index', i)} {answer_text(r)}" for i, r in enumerate(regions))
    val = doc.get("validation") or {}
    de, base = val.get("mean_de2000"), val.get("baseline_mean_de2000")
    held = (f"held-out photos: mean ΔE00 {de:.2f} (one material for the whole object: {base:.2f})"
            if de is not None and base is not None else
            "not validated on held-out photos" if not val else str(val.get("note") or "not validated"))
    unmeasured = unmeasured_share_text(doc.get("not_measured") or {})
    share = f" · {unmeasured} not measured" if unmeasured else ""
    return f"{len(regions)} region{'s' if len(regions) != 1 else ''}: {answers}{share} · {held}"


def _stamp(path: Path) -> tuple[int, int] | None:
    """A file's (size, mtime in ns), or None when it does not exist."""
    try:
        st = path.stat()
    except OSError:
        return None
    return (st.st_size, st.st_mtime_ns)


def remove_unrecorded(root: Path | None, before: dict[str, Any]) -> int:
    """Remove the object's files a stopped materials run wrote that the session does not record; how many.

    ``before`` maps each of the run's products (relative to ``root``) to its :func:`_stamp` before the run (None:
    it did not exist).  A result the session records, written by this run, stays: the run finished recording it
    before the stop.  Runs on a worker thread (the window's lane).
    """
    import shutil

    from app.session import Session
    from app.workflows.object_materials import OBJECT_MATERIALS

    if root is None:
        return 0
    recorded = ((Session.read(root).get("products") or {}).get("object_materials") or {}).get("file")
    written = _stamp(root / OBJECT_MATERIALS)
    if recorded == OBJECT_MATERIALS and written is not None and written != before.get(OBJECT_MATERIALS):
        return 0                                  # the run finished recording before the stop: keep it
    removed = 0
    for rel, was in before.items():
        if was is None and (root / rel).is_file():
            (root / rel).unlink()
            removed += 1
        elif was is None and (root / rel).is_dir():       # the validation's images of a first run
            removed += sum(1 for f in (root / rel).rglob("*") if f.is_file())
            shutil.rmtree(root / rel)
    return removed


def camera_summary(ref: dict[str, Any]) -> str:
    """One line on a stored camera calibration (its manifest reference).

    Examples
    --------
    >>> camera_summary({"rms_px": 0.112, "image_size": [960, 640],
    ...                 "source": {"frames_used": 30, "frames_rejected": ["a", "b"], "sphere_photos": 4}})
    'camera: reprojection rms 0.112 px over 30 board frames (2 rejected), 960 x 640 px, tied to the turntable by 4 sphere photos'
    """
    src = ref.get("source") or {}
    size = ref.get("image_size") or ["?", "?"]
    return (f"camera: reprojection rms {ref['rms_px']:.3f} px over {src.get('frames_used', '?')} board frames "
            f"({len(src.get('frames_rejected') or [])} rejected), {size[0]} x {size[1]} px, tied to the turntable "
            f"by {src.get('sphere_photos', '?')} sphere photos")


def render_mesh_view(mesh: str, size: tuple[int, int] = MESH_VIEW_SIZE,
                     message: Callable[[str], None] | None = None) -> dict[str, Any]:
    """A draft render of the mesh file ``mesh`` for the panel's mesh view (run in a worker process).

    The Preview tab's :func:`app.gui.preview_panel.render_view` at the ``draft`` preset: the
    preview's default material under D65, lit from the upper left, seen from the front and
    15 degrees above the table.

    Returns
    -------
    dict
        ``srgb8`` ``(H, W, 3)`` uint8, ``mask`` ``(H, W)``, ``triangles`` and ``seconds``.
    """
    import numpy as np

    from app.gui.preview_panel import light_vector, render_view
    from render.meshio import load_mesh

    note = message or (lambda text: None)
    m = load_mesh(mesh)
    v = np.asarray(m.vertices, float)
    note(f"rendering the mesh ({len(m.triangles)} triangles, draft)")
    out = render_view(mesh, "nami-shibuichi", "D65", light_vector(200.0, 50.0), -90.0, 15.0, size, "draft",
                      (v.min(axis=0), v.max(axis=0)))
    return {"srgb8": out["srgb8"], "mask": out["mask"], "triangles": len(m.triangles), "seconds": out["seconds"]}


def _projection_text(proj: dict[str, Any] | None) -> str:
    """The posed-frames part of the summary line."""
    if not proj:
        return " · photos not posed (no camera calibration)"
    iou = proj.get("iou_min")
    return (f" · {len(proj['frames'])} photos posed on the mesh"
            + ("" if iou is None else f", silhouette IoU >= {iou:.3f}") + " (Camera tab: Show with the mesh outline)")


class ProcessingPanel(Panel):
    """See the module docstring."""

    processed = Signal(object)          # the report
    materials_measured = Signal(object)  # the materials document (products/object-materials.json)

    def __init__(self, lane: Lane, session_root: Callable[[], Path | None], drawer: FigureDrawer,
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.lane = lane
        self.session_root = session_root
        self.drawer = drawer                    # draws the manual registration dialog's clouds
        self.job: ProcessJob | None = None
        self.cancelled_by_user = False
        self.report: dict[str, Any] | None = None
        self.picks: dict[tuple[int, int], tuple[Any, Any]] = {}
        # the panel scrolls when the window is too short for it (a 700 px high window)
        inner = QWidget()
        outer = QVBoxLayout(inner)
        self.scroll_area = scroll = QScrollArea()
        scroll.setWidget(inner)
        scroll.setWidgetResizable(True)
        scroll.setFrameShape(QFrame.Shape.NoFrame)
        page = QVBoxLayout(self)
        page.setContentsMargins(0, 0, 0, 0)
        page.addWidget(scroll)

        cal = QGroupBox("Scanner calibration")
        f = QFormLayout(cal)
        self.calibration = QLineEdit()
        self.calibration.setPlaceholderText("a session calibrated from a sphere scan, or its calibration.json "
                                            "(empty: the session's own)")
        row = browse_row(self.calibration, self._browse)
        f.addRow("Calibration", row)
        self.radius = QDoubleSpinBox()
        self.radius.setRange(0.1, 1000.0)
        self.radius.setValue(25.0)
        self.radius.setSuffix(" mm")
        self.radius.setToolTip("the reference sphere's radius as measured (mm)")
        self.calibrate_button = QPushButton("Calibrate from the open session (a sphere scan)")
        self.calibrate_button.setToolTip("fit the scanner's geometry to the open session's scan of the reference "
                                         "sphere; the result is judged pass / warn / fail")
        self.calibrate_button.clicked.connect(self.safe(self.calibrate))
        crow = QHBoxLayout()
        crow.addWidget(QLabel("Sphere radius"))
        crow.addWidget(self.radius)
        crow.addWidget(self.calibrate_button)
        crow.addStretch(1)
        f.addRow(crow)
        self.cal_state = QLabel("")
        f.addRow(self.cal_state)
        # the calibrations and the run on the left, the mesh view beside them (the line edits have room to give)
        head = QHBoxLayout()
        controls = QVBoxLayout()
        head.addLayout(controls, 2)
        mesh_group = QGroupBox("Mesh")
        mesh_group.setLayout(self._mesh_box())
        # the mesh and what is measured on it share the right-hand column (the mesh view gives up the room)
        side = QVBoxLayout()
        side.addWidget(mesh_group, 1)
        side.addWidget(self._materials_box())
        head.addLayout(side, 1)
        outer.addLayout(head)
        controls.addWidget(cal)
        controls.addWidget(self._station_box())

        run = QGroupBox("Registration and meshing")
        v = QVBoxLayout(run)
        r = QHBoxLayout()
        self.preset = QComboBox()
        self.preset.addItems(["draft", "standard", "reference"])
        self.preset.setCurrentText("standard")
        self.preset.setToolTip("draft: quick look; standard: the usual mesh; reference: the finest, slowest")
        self.run_button = QPushButton("Process the open session")
        self.run_button.setToolTip("align the passes and build the watertight mesh (and pose the photos on it "
                                   "when the camera is calibrated)")
        self.cancel_button = QPushButton("Cancel")
        self.cancel_button.setToolTip("stop processing; the session is left as it was")
        self.pick_button = QPushButton("Manual 3-point registration…")
        self.pick_button.setToolTip("align two passes by clicking three matching points on each, when the "
                                    "automatic alignment failed")
        self.run_button.clicked.connect(self.safe(self.run))
        self.cancel_button.clicked.connect(self.safe(self.cancel))
        self.pick_button.clicked.connect(self.safe(self.open_pick_dialog))
        r.addWidget(QLabel("Preset"))
        r.addWidget(self.preset)
        for b in (self.run_button, self.cancel_button, self.pick_button):
            r.addWidget(b)
        r.addStretch(1)
        v.addLayout(r)
        self.busy = QProgressBar()
        self.busy.setRange(0, 1)
        self.busy.setValue(0)
        self.stage = QLabel("idle")
        self.stage.setWordWrap(True)
        v.addWidget(self.busy)
        v.addWidget(self.stage)
        controls.addWidget(run)

        res = QGroupBox("Residuals")
        rv = QVBoxLayout(res)
        self.passes_tree = QTreeWidget()
        self.passes_tree.setHeaderLabels(["Pass", "Points", "Registered", "Note"])
        self.passes_tree.setRootIsDecorated(False)
        self.pairs_tree = QTreeWidget()
        self.pairs_tree.setHeaderLabels(["Pair", "RMS (mm)", "Expected (mm)", "Overlap", "Method", "Verified",
                                         "Reason", "Verdict"])
        self.pairs_tree.headerItem().setToolTip(2, "the residual the two clouds' own noise and spacing explain")
        self.pairs_tree.headerItem().setToolTip(7, "pass <= 2x the expected residual, warn <= 4x, fail above or "
                                                   "when the pair's check failed")
        self.pairs_tree.setRootIsDecorated(False)
        self.pairs_tree.setColumnWidth(0, 150)
        self.summary = QLabel("")
        self.summary.setWordWrap(True)
        for tree in (self.passes_tree, self.pairs_tree):
            # the trees take the room there is (at least 3 rows) rather than asking for 192 px each, so the
            # scrolled panel fits the window when it can
            tree.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Ignored)
            tree.setMinimumHeight(80)
        rv.addWidget(self.passes_tree, 1)
        rv.addWidget(self.pairs_tree, 1)
        rv.addWidget(self.summary)
        outer.addWidget(res, 1)
        self.cancel_button.setEnabled(False)
        self.pick_button.setEnabled(False)

    def _mesh_box(self) -> QVBoxLayout:
        """The mesh view: the session's mesh rendered once processing has made it."""
        box = QVBoxLayout()
        self.mesh_view = QLabel("no mesh yet: press 'Process the open session'; the watertight mesh is shown here")
        self.mesh_view.setWordWrap(True)
        self.mesh_view.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self.mesh_view.setMinimumSize(200, 150)
        # Ignored: the image is scaled to the room the layout gives, never the other way round
        self.mesh_view.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Ignored)
        self.mesh_view.setStyleSheet("background:#202020; color:#ddd;")
        self.mesh_view.setToolTip("the session's mesh (products/mesh.ply), a quick render; the Preview tab renders "
                                  "it under the light and material you choose")
        self.mesh_busy = QProgressBar()
        self.mesh_busy.setRange(0, 0)
        self.mesh_busy.setMaximumHeight(8)
        self.mesh_busy.setTextVisible(False)
        self.mesh_busy.hide()
        box.addWidget(self.mesh_view, 1)
        box.addWidget(self.mesh_busy)
        self.mesh_image: Any = None
        self.mesh_mask: Any = None
        self.mesh_job: ProcessJob | None = None
        self.mesh_shown: str | None = None
        return box

    def show_mesh(self, root: Path | None) -> None:
        """Render the session's ``products/mesh.ply`` into the mesh view (or say there is none yet)."""
        mesh = None if root is None else Path(root) / "products" / "mesh.ply"
        if self.mesh_job is not None and not self.mesh_job.done:
            self.mesh_job.cancel()
        if mesh is None or not mesh.is_file():
            self.mesh_image, self.mesh_shown = None, None
            self.mesh_view.setPixmap(QPixmap())
            self.mesh_view.setText("no mesh yet: press 'Process the open session'; the watertight mesh is shown here")
            return
        self.mesh_view.setPixmap(QPixmap())
        self.mesh_view.setText(f"rendering {mesh.name}…")
        self.mesh_busy.show()
        job = ProcessJob(render_mesh_view, str(mesh), MESH_VIEW_SIZE, parent=self)
        job.message.connect(lambda text: self.mesh_view.setText(text + "…") if self.mesh_image is None else None)
        job.succeeded.connect(lambda out, m=str(mesh): self._mesh_rendered(m, out))
        job.failed.connect(self._mesh_failed)
        job.finished.connect(self.mesh_busy.hide)
        self.mesh_job = job.start()

    def _mesh_rendered(self, mesh: str, out: dict[str, Any]) -> None:
        self.mesh_image = out["srgb8"]
        self.mesh_mask = out["mask"]
        self.mesh_shown = mesh
        self.mesh_view.setToolTip(f"{mesh}: {out['triangles']} triangles, rendered in {out['seconds']:.1f} s "
                                  "(draft); the Preview tab renders it under the light and material you choose")
        self._scale_mesh_image()

    def _mesh_failed(self, text: str, detail: Any) -> None:
        if self.mesh_job is not None and self.mesh_job.cancelled:
            return                         # replaced by a newer render
        self.mesh_view.setText(f"the mesh could not be rendered: {text.splitlines()[0]}")
        self.log.emit(f"mesh view: {text}")

    def _scale_mesh_image(self) -> None:
        from app.gui.session_panel import rgb_to_qimage

        if self.mesh_image is None:
            return
        pix = QPixmap.fromImage(rgb_to_qimage(self.mesh_image))
        self.mesh_view.setPixmap(pix.scaled(self.mesh_view.contentsRect().size(), Qt.AspectRatioMode.KeepAspectRatio,
                                            Qt.TransformationMode.SmoothTransformation))

    def resizeEvent(self, event: Any) -> None:  # noqa: N802 - Qt's name
        super().resizeEvent(event)
        self._scale_mesh_image()

    # ------------------------------------------------------------ materials on the mesh
    def _materials_box(self) -> QGroupBox:
        """Measure the materials on the mesh from the posed photos (``kogei fit-materials``)."""
        box = QGroupBox("Materials on the mesh")
        v = QVBoxLayout(box)
        r = QHBoxLayout()
        self.materials_button = QPushButton("Measure materials on the mesh")
        self.materials_validate = QCheckBox("Validate on photos")
        self.materials_validate.setChecked(True)
        self.materials_validate.setToolTip("render every 4th table angle (held out of the fit) with the measured "
                                           "materials and compare with the photos (CIEDE2000); takes longer")
        self.materials_cancel_button = QPushButton("Cancel")
        self.materials_cancel_button.setToolTip("stop measuring the materials; the session is left as it was")
        self.materials_button.clicked.connect(self.safe(self.measure_materials))
        self.materials_cancel_button.clicked.connect(self.safe(self.cancel_materials))
        # stacked: the column is narrow in a 1024 px window; Cancel sits beside the busy bar it stops
        v.addWidget(self.materials_button)
        v.addWidget(self.materials_validate)
        v.addLayout(r)
        self.materials_busy = QProgressBar()
        self.materials_busy.setRange(0, 1)
        self.materials_busy.setValue(0)
        self.materials_busy.setMaximumHeight(10)
        self.materials_busy.setMinimumWidth(40)
        self.materials_busy.setTextVisible(False)
        self.materials_state = QLabel("")
        self.materials_state.setWordWrap(True)
        self.materials_state.setToolTip("the regions found on the mesh and each one's material, with a verdict")
        r.addWidget(self.materials_busy, 1)
        r.addWidget(self.materials_cancel_button)
        v.addWidget(self.materials_state)
        self.materials_job: ProcessJob | None = None
        self._tidying = False                    # a cancelled run's files being removed on the lane
        self.materials_cancelled = False
        self.materials_doc: dict[str, Any] | None = None
        self.materials_verdict: Any = None
        self._materials_before: dict[str, Any] = {}
        self._materials_shown_root: Path | None = None
        self.materials_cancel_button.setEnabled(False)
        self.show_materials_state(None, None)
        return box

    def show_materials_state(self, root: Path | None, manifest: dict[str, Any] | None) -> None:
        """Enable the measurement when the open session's photos are posed on its mesh; say what is missing if not."""
        missing = materials_missing(root, manifest)
        running = self.measuring
        self.materials_button.setEnabled(missing is None and not running)
        self.materials_button.setToolTip(
            "segment the mesh into regions of one material and fit each region's material to the posed photos "
            "(kogei fit-materials); the Preview tab then renders the measured material"
            if missing is None else f"not available: {missing}")
        if running:
            return
        if missing is not None:
            self.materials_state.setText(missing)
            self.materials_state.setToolTip("what the measurement needs")
        elif root != self._materials_shown_root:
            self._show_recorded_materials(root, manifest)   # a newly opened session: its earlier result, if any
        self._materials_shown_root = root if missing is None else None

    def _show_recorded_materials(self, root: Path, manifest: dict[str, Any]) -> None:
        from app.workflows.object_materials import read_object_materials

        self.materials_doc, self.materials_verdict = None, None
        self.materials_state.setText("")
        if not isinstance((manifest.get("products") or {}).get("object_materials"), dict):
            return
        try:
            doc = read_object_materials(root)
        except Exception as exc:  # noqa: BLE001 - a damaged product must not stop the session from opening
            self.materials_state.setText(f"the materials measured earlier cannot be read: {exc}")
            return
        self._show_materials_result(doc, "measured earlier: ")

    def _show_materials_result(self, doc: dict[str, Any], lead: str = "") -> None:
        from app.gui.guidance import materials_verdict

        self.materials_doc = doc
        verdict = self.materials_verdict = materials_verdict(doc)
        # why and the thresholds in the tooltip: the column is narrow, and the Processing tab should fit unscrolled
        self.materials_state.setText(f"{verdict.html()} {lead}{materials_summary(doc)}")
        self.materials_state.setToolTip(f"{verdict.level}: {verdict.why}. Thresholds — {verdict.thresholds}")

    def measure_materials(self) -> None:
        from app.errors import UsageError
        from app.session import Session
        from app.workflows.object_materials import OBJECT_MATERIALS, OBJECT_MESH, OBJECT_SCENE, VALIDATION_DIR

        root = self.session_root()
        manifest = Session.read(root) if root is not None and (root / "session.json").exists() else None
        missing = materials_missing(root, manifest)
        if missing is not None:
            raise UsageError(missing)
        if self.measuring:
            raise UsageError("the materials are already being measured")
        # what the object's files were: a cancelled run removes what it wrote and did not record
        self._materials_before = {rel: _stamp(root / rel) for rel in (OBJECT_MATERIALS, OBJECT_MESH, OBJECT_SCENE)}
        self._materials_before[VALIDATION_DIR] = (root / VALIDATION_DIR).exists() or None
        self._materials_root = root
        validate = self.materials_validate.isChecked()
        self.materials_job = ProcessJob(run_materials, str(root), validate, parent=self)
        self.materials_job.message.connect(self._materials_message)
        self.materials_job.succeeded.connect(self._materials_done)
        self.materials_job.failed.connect(self._materials_failed)
        self.materials_job.finished.connect(self._materials_finished)
        self.materials_busy.setRange(0, 0)
        self.materials_state.setText(f"measuring the materials on the mesh of {root}"
                                     + (" (with validation)" if validate else "") + "…")
        self.materials_button.setEnabled(False)
        self.materials_cancel_button.setEnabled(True)
        self.materials_cancelled = False
        self.materials_doc = None
        self.log.emit(self.materials_state.text())
        self.materials_job.start()

    def cancel_materials(self) -> None:
        if self.materials_job is not None and not self.materials_job.done:
            self.materials_cancelled = True
            self.materials_job.cancel()

    @property
    def measuring(self) -> bool:
        """True while the materials are being measured, or a cancelled run's files are being removed."""
        return (self.materials_job is not None and not self.materials_job.done) or self._tidying

    def _materials_message(self, text: str) -> None:
        self.materials_state.setText(text)
        self.log.emit(f"materials: {text}")

    def _materials_done(self, doc: dict[str, Any]) -> None:
        self._show_materials_result(doc)
        self._materials_shown_root = self.session_root()
        self.log.emit(f"materials measured ({self.materials_verdict.level}): {materials_summary(doc)}")
        self.materials_measured.emit(doc)

    def _materials_failed(self, text: str, detail: Any) -> None:
        line = text.splitlines()[0] if text else "failed"
        if not self.materials_cancelled:
            self.materials_state.setText(f"stopped: {line}")
            self.error.emit(line)
            return
        # what the user asked for: information, not a fault; the run's unrecorded files go on the lane (a disk's
        # wait, a folder of validation images, stays off the window), and Measure waits for them
        root, before = getattr(self, "_materials_root", None), dict(self._materials_before)
        self._tidying = True
        self.materials_state.setText("cancelled: removing what the run wrote…")
        self.lane.run(lambda ctx: remove_unrecorded(root, before), "remove a cancelled run's files",
                      succeeded=lambda removed: self._tidied(line, removed),
                      failed=lambda why, exc: self._tidied(line, None, why), finished=self._tidy_finished)

    def _tidied(self, line: str, removed: int | None, why: str = "") -> None:
        if removed is None:
            self.materials_state.setText("cancelled: some of what the run wrote is still there")
            self.error.emit(f"measuring the materials {line}, but what it wrote could not be removed "
                            f"({why.splitlines()[0]}): remove it by hand or measure again")
            return
        self.materials_state.setText("cancelled: the session is as it was")
        self.notice.emit(f"measuring the materials {line}"
                         + (f" ({removed} unrecorded file{'s' if removed != 1 else ''} removed)" if removed else ""))

    def _tidy_finished(self) -> None:
        self._tidying = False
        self._materials_finished()

    def _materials_finished(self) -> None:
        self.materials_cancel_button.setEnabled(False)
        if self._tidying:                        # a cancelled run's files are being removed: not done yet
            return
        self.materials_busy.setRange(0, 1)
        self.materials_busy.setValue(1 if self.materials_doc is not None else 0)
        self.materials_button.setEnabled(True)

    def _station_box(self) -> QGroupBox:
        """Camera and lamp calibration: sources for processing, and buttons to calibrate from the open session."""
        box = QGroupBox("Camera and lamps (pose every photo on the mesh)")
        f = QFormLayout(box)
        self.camera_cal = QLineEdit()
        self.camera_cal.setPlaceholderText("a camera-calibrated board session or its camera_calibration.json "
                                           "(empty: the session's own, if any)")
        f.addRow("Camera", browse_row(self.camera_cal, lambda: self._browse_into(self.camera_cal)))
        self.lamp_cal = QLineEdit()
        self.lamp_cal.setPlaceholderText("a lamp-calibrated mirror-sphere session or its lamp_calibration.json")
        f.addRow("Lamps", browse_row(self.lamp_cal, lambda: self._browse_into(self.lamp_cal)))
        row = QHBoxLayout()
        self.camera_button = QPushButton("Calibrate the camera from the open session (board)")
        self.camera_button.setToolTip("the open session is a camera-calibration capture; the scanner calibration "
                                      "above names the sphere session whose photos tie the camera to the turntable")
        self.lamp_button = QPushButton("Calibrate the lamps from the open session (mirror sphere)")
        self.lamp_button.setToolTip("locate the lamps from the highlights on the mirror sphere in the open "
                                    "session's photos")
        self.camera_button.clicked.connect(self.safe(self.calibrate_camera))
        self.lamp_button.clicked.connect(self.safe(self.calibrate_lamps))
        row.addWidget(self.camera_button)
        row.addWidget(self.lamp_button)
        row.addStretch(1)
        f.addRow(row)
        self.station_state = QLabel("")
        self.station_state.setWordWrap(True)
        self.camera_verdict: Any = None                 # the last camera calibration's verdict (app.gui.guidance)
        f.addRow(self.station_state)
        return box

    def show_station(self, manifest: dict[str, Any] | None) -> None:
        """Show the open session's installed camera and lamp calibrations (or that it has none)."""
        cam = (manifest or {}).get("camera_calibration")
        lamps = (manifest or {}).get("lamp_calibration")
        parts = []
        if isinstance(cam, dict) and isinstance(cam.get("rms_px"), (int, float)):
            parts.append(camera_summary(cam))
        if isinstance(lamps, dict):
            parts.append(f"lamps: {lamps.get('lamps', '?')} located")
        self.station_state.setText(" · ".join(parts) if parts else
                                   "this session has no camera calibration: its photos are not posed on the mesh")

    def _browse_into(self, field: QLineEdit) -> None:
        path = QFileDialog.getExistingDirectory(self, "Calibrated session")
        if path:
            field.setText(path)

    def calibrate_camera(self) -> None:
        from app.errors import UsageError

        root = self.session_root()
        scanner = self.calibration_source()
        if root is None:
            raise UsageError("open the camera-calibration (board) session first (Session tab)")
        if scanner is None or not Path(scanner).is_dir():
            raise UsageError("name the scanner's sphere session in Scanner calibration above: its photos of the "
                             "sphere tie the camera to the turntable")

        def work(ctx: JobContext) -> dict[str, Any]:
            from app.workflows.station_calibration import calibrate_camera_session

            return calibrate_camera_session(root, scanner, message=ctx.message)

        def done(ref: dict[str, Any]) -> None:
            from app.gui.guidance import camera_verdict

            verdict = camera_verdict(float(ref["rms_px"]))
            self.camera_verdict = verdict
            self.camera_cal.setText(str(root))
            self.station_state.setText(f"{verdict.html()} {camera_summary(ref)} — {verdict.why}")
            self.station_state.setToolTip(verdict.tooltip)
            self.log.emit(f"{verdict.level.upper()} {camera_summary(ref)}")

        self.station_state.setText("calibrating the camera…")
        self.lane.run(work, "calibrate camera", succeeded=done,
                      failed=lambda text, exc: (self.station_state.setText(""), self.error.emit(text)))

    def calibrate_lamps(self) -> None:
        from app.errors import UsageError

        root = self.session_root()
        camera = self.camera_cal.text().strip()
        if root is None:
            raise UsageError("open the lamp-calibration (mirror sphere) session first (Session tab)")
        if not camera:
            raise UsageError("name the calibrated camera (Camera above) first")

        def work(ctx: JobContext) -> dict[str, Any]:
            from app.workflows.station_calibration import calibrate_lamp_session

            return calibrate_lamp_session(root, camera, message=ctx.message)

        def done(ref: dict[str, Any]) -> None:
            self.lamp_cal.setText(str(root))
            self.station_state.setText(f"lamps: {ref['lamps']} located from {root}")
            self.log.emit(self.station_state.text())

        self.station_state.setText("locating the lamps…")
        self.lane.run(work, "calibrate lamps", succeeded=done,
                      failed=lambda text, exc: (self.station_state.setText(""), self.error.emit(text)))

    def _browse(self) -> None:
        path = QFileDialog.getExistingDirectory(self, "Calibrated session")
        if path:
            self.calibration.setText(path)

    def calibration_source(self) -> str | None:
        text = self.calibration.text().strip()
        return text or None

    # ------------------------------------------------------------ calibrate
    def calibrate(self) -> None:
        from app.errors import UsageError

        root = self.session_root()
        if root is None:
            raise UsageError("open the sphere-scan session first (Session tab)")
        radius = float(self.radius.value())

        def work(ctx: JobContext) -> dict[str, Any]:
            from app.workflows.calibration import calibrate_session

            return calibrate_session(root, radius)

        def done(ref: dict[str, Any]) -> None:
            from app.gui.guidance import sphere_verdict

            verdict = sphere_verdict(float(ref["rms_mm"]))
            self.calibration.setText(str(root))
            self.cal_state.setText(f"{verdict.html()} calibrated from {root}: sphere residual rms "
                                   f"{ref['rms_mm']:.4f} mm, max {ref['max_mm']:.4f} mm — {verdict.why}")
            self.cal_state.setToolTip(verdict.tooltip)
            self.calibration_verdict = verdict
            self.log.emit(self.cal_state.text())

        self.cal_state.setText("calibrating…")
        self.lane.run(work, "calibrate", succeeded=done, failed=lambda text, exc: (self.cal_state.setText(""),
                                                                                     self.error.emit(text)))

    # ------------------------------------------------------------ process
    def run(self) -> None:
        from app.errors import UsageError

        root = self.session_root()
        if root is None or not (root / "session.json").exists():
            raise UsageError("open a captured session first (Session tab)")
        if self.job is not None and not self.job.done:
            raise UsageError("processing is already running")
        picks = {k: (list(map(list, a)), list(map(list, b))) for k, (a, b) in self.picks.items()} or None
        self.job = ProcessJob(run_processing, str(root), self.preset.currentText(), self.calibration_source(), picks,
                              self.camera_cal.text().strip() or None, self.lamp_cal.text().strip() or None,
                              parent=self)
        self.job.message.connect(self._on_message)
        self.job.succeeded.connect(self._on_done)
        self.job.failed.connect(self._on_failed)
        self.job.finished.connect(self._on_finished)
        self.busy.setRange(0, 0)          # busy: the stages have no fixed length
        self.stage.setText(f"processing {root} ({self.preset.currentText()})…")
        self.run_button.setEnabled(False)
        self.cancel_button.setEnabled(True)
        self.cancelled_by_user = False
        self.log.emit(self.stage.text())
        self.job.start()

    def cancel(self) -> None:
        if self.job is not None and not self.job.done:
            self.cancelled_by_user = True
            self.job.cancel()

    @property
    def running(self) -> bool:
        return self.job is not None and not self.job.done

    def _on_message(self, text: str) -> None:
        self.stage.setText(text)
        self.log.emit(f"process: {text}")

    def _on_done(self, report: dict[str, Any]) -> None:
        self.show_report(report)
        self.processed.emit(report)

    def _on_failed(self, text: str, detail: Any) -> None:
        self.stage.setText(f"stopped: {text.splitlines()[0]}")
        if self.cancelled_by_user:           # what the user asked for: information, not a fault
            self.notice.emit(f"processing {text.splitlines()[0]}; the session is as it was")
            return
        self.error.emit(text)

    def _on_finished(self) -> None:
        self.busy.setRange(0, 1)
        self.busy.setValue(1 if self.report is not None else 0)
        self.run_button.setEnabled(True)
        self.cancel_button.setEnabled(False)

    def show_report(self, report: dict[str, Any]) -> None:
        self.report = report
        self.passes_tree.clear()
        names = []
        failed = False
        for p in report["passes"]:
            if "points" in p and not (p.get("skipped") or "").startswith("only"):
                names.append(f"pass {p['pass']}")
            reg = p.get("registered")
            failed = failed or reg is False
            self.passes_tree.addTopLevelItem(QTreeWidgetItem([
                f"pass {p['pass']}", str(p.get("points", "–")), {True: "yes", False: "NO", None: "–"}[reg],
                p.get("skipped", "") or ("" if not p.get("angle_uncertain_deg") else
                                         f"angle uncertain by {p['angle_uncertain_deg']:g}°")]))
        self.pairs_tree.clear()
        from PySide6.QtGui import QBrush, QColor

        from app.gui.guidance import VERDICT_COLOURS

        for pr in report["registration"]["pairs"]:
            item = QTreeWidgetItem(pair_row(pr, names))
            verdict = _pair_verdict(pr)
            item.setForeground(7, QBrush(QColor(VERDICT_COLOURS[verdict.level])))
            item.setToolTip(7, verdict.tooltip)
            self.pairs_tree.addTopLevelItem(item)
        for tree in (self.passes_tree, self.pairs_tree):            # whole verdicts in a narrow window
            for col in range(tree.columnCount()):
                tree.resizeColumnToContents(col)
        self.scroll_area.ensureWidgetVisible(self.pairs_tree)      # the verdicts in view in a short window
        c = report["registration"]["consistency"]
        m = report["mesh"]
        self.summary.setText(
            (f"Pose graph: largest disagreement {c['max_rotation_deg']:.3f}° / {c['max_displacement_mm']:.3f} mm · "
             if c else "") +
            f"Mesh: {m['triangles']} triangles, {'watertight' if m['watertight'] else 'NOT watertight'} · "
            f"{report['timings_s']['total']:.1f} s"
            + (" · a pass was not registered: use the manual 3-point registration" if failed else "")
            + _projection_text(report.get("projection")))
        self.stage.setText("done")
        self.pick_button.setEnabled(True)
        self.log.emit(f"processed: {self.summary.text()}")
        self.show_mesh(self.session_root())

    # ------------------------------------------------------------ manual registration
    def open_pick_dialog(self) -> None:
        from app.errors import UsageError
        from app.gui.pick_dialog import PickDialog

        root = self.session_root()
        if root is None or not (root / "session.json").exists():
            raise UsageError("open a captured session first (Session tab)")
        dlg = PickDialog(root, self.calibration_source(), self.lane, self.drawer, self)
        dlg.error.connect(self.error.emit)
        if dlg.exec():
            self.picks[dlg.pair] = dlg.picked()
            self.log.emit(f"manual registration: {len(dlg.picked()[0])} point pairs for passes {dlg.pair}; "
                          "press Process to use them")
            self.stage.setText(f"picks for passes {dlg.pair[0]} and {dlg.pair[1]} set: press Process")
