"""Session panel: new / open / resume a session, the object's metadata, the captures with status and thumbnails.

The session store is :mod:`app.session` (``docs/session-format.md``).  The
list is read with :meth:`app.session.Session.read` (the manifest with the
journal replayed, without locking), so it can be refreshed while a capture
writes the session; RAW thumbnails are decoded on a worker thread
(:func:`processing.camera.raw_decode.decode_raw`, :func:`processing.camera.raw_decode.preview_srgb8`).

The session's outputs have buttons: "Make report" writes the session's HTML
report (:func:`app.report.html.write_report`, as ``kogei report``) and opens
it; "Open session folder" opens the folder in the desktop's file manager;
"Export glTF…" writes the measured object as a ``.glb``
(:func:`app.workflows.gltf_export.export_gltf`, as ``kogei export``).  The
report and the export run on a worker thread.

Examples
--------
>>> capture_row("p01/profile/0003", {"kind": "profile", "pass": 1, "angle_deg": 90.0, "valid": 412, "status": "done"})
['p01/profile/0003', 'profile', '1', '90.00', 'done', '412 points']
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from PySide6.QtCore import QSize, Qt, QUrl, Signal
from PySide6.QtGui import QDesktopServices, QIcon, QImage, QPixmap
from PySide6.QtWidgets import (
    QFileDialog,
    QFormLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QListWidget,
    QListWidgetItem,
    QPushButton,
    QSplitter,
    QTreeWidget,
    QTreeWidgetItem,
    QVBoxLayout,
    QWidget,
)

from app.gui.widgets import Panel, browse_row
from app.gui.workers import JobContext, Lane

__all__ = ["SessionPanel", "capture_row", "rgb_to_qimage", "METADATA_FIELDS"]

#: Object metadata fields of the form (manifest ``object`` keys and labels).
METADATA_FIELDS = (("name", "Object name"), ("collection_id", "Collection no."), ("period", "Period / maker"),
                   ("materials", "Materials (as catalogued)"), ("operator", "Operator"), ("notes", "Notes"))


def capture_row(cid: str, rec: dict[str, Any]) -> list[str]:
    """Columns of one capture in the list: id, kind, pass, angle, status, detail."""
    angle = rec.get("angle_deg")
    detail = ""
    if rec.get("kind") == "profile":
        detail = f"{rec.get('valid', 0)} points"
    elif rec.get("kind") == "profiles":
        detail = f"{rec.get('steps', '?')} profiles gathered"
    elif rec.get("file"):
        detail = Path(rec["file"]).name
    return [cid, str(rec.get("kind", "")), str(rec.get("pass", "")),
            "" if angle is None else f"{float(angle):.2f}", str(rec.get("status", "")), detail]


def rgb_to_qimage(rgb: np.ndarray) -> QImage:
    """A copy of an ``(H, W, 3)`` uint8 RGB array as a QImage."""
    a = np.ascontiguousarray(rgb, dtype=np.uint8)
    h, w = a.shape[:2]
    return QImage(a.data, w, h, 3 * w, QImage.Format.Format_RGB888).copy()


def _thumbnail(path: Path, side: int = 96) -> np.ndarray:
    from processing.camera.raw_decode import decode_raw, preview_srgb8

    img = preview_srgb8(decode_raw(path, mode="bin2x2"))
    step = max(1, int(np.ceil(max(img.shape[:2]) / side)))
    return np.ascontiguousarray(img[::step, ::step])


class SessionPanel(Panel):
    """See the module docstring.  ``root`` is the open session (None if none)."""

    session_chosen = Signal(object)        # Path of a session folder, or None
    manifest_shown = Signal()              # the session list was (re-)read

    def __init__(self, lane: Lane, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.lane = lane
        self.root: Path | None = None
        self.manifest: dict[str, Any] | None = None
        self._thumbs: set[str] = set()
        outer = QVBoxLayout(self)

        top = QGroupBox("Session")
        form = QFormLayout(top)
        self.folder = QLineEdit()
        self.folder.setPlaceholderText("folder of a new session, or of one to open / resume")
        row = browse_row(self.folder, self._browse)
        form.addRow("Folder", row)
        buttons = QHBoxLayout()
        self.new_button = QPushButton("New session")
        self.new_button.setToolTip("a new session in the folder (an empty or new one); it is written when the "
                                   "capture starts")
        self.open_button = QPushButton("Open / resume")
        self.open_button.setToolTip("open the session in the folder; an interrupted capture goes on with Start "
                                    "on the Capture tab")
        self.save_meta = QPushButton("Save metadata")
        self.save_meta.setToolTip("store the object's fields in the open session (and its report)")
        self.new_button.clicked.connect(self.safe(self.new_session))
        self.open_button.clicked.connect(self.safe(lambda: self.open_session(self.folder.text().strip())))
        self.save_meta.clicked.connect(self.safe(self.save_metadata))
        for b in (self.new_button, self.open_button, self.save_meta):
            buttons.addWidget(b)
        buttons.addStretch(1)
        form.addRow(buttons)
        self.status = QLabel("no session open")
        self.status.setWordWrap(True)
        form.addRow("Status", self.status)
        outer.addWidget(top)
        outputs = QHBoxLayout()
        self.report_button = QPushButton("Make report")
        self.report_button.setToolTip("write the session's HTML report (products/report.html) and open it")
        self.folder_button = QPushButton("Open session folder")
        self.folder_button.setToolTip("open the session's folder in the file manager (RAW frames, products)")
        self.export_button = QPushButton("Export glTF…")
        self.export_button.setToolTip("write the measured object -- mesh and materials -- as a .glb file for "
                                      "other 3-D programs (after 'kogei fit-materials')")
        self.report_button.clicked.connect(self.safe(self.make_report))
        self.folder_button.clicked.connect(self.safe(self.open_folder))
        self.export_button.clicked.connect(self.safe(self._export))
        for b in (self.report_button, self.folder_button, self.export_button):
            outputs.addWidget(b)
        outputs.addStretch(1)
        form.addRow("Outputs", outputs)

        split = QSplitter(Qt.Orientation.Horizontal)
        meta = QGroupBox("Object")
        mform = QFormLayout(meta)
        self.meta_edits: dict[str, QLineEdit] = {}
        for key, label in METADATA_FIELDS:
            edit = QLineEdit()
            edit.setMinimumWidth(260)          # a catalogue name fits whole
            edit.setToolTip(f"{label}: kept in the session and shown in its report"
                            + ("; e.g. 'shibuichi, gold, urushi': the Spectra tab can compare with just these"
                               if key == "materials" else ""))
            self.meta_edits[key] = edit
            mform.addRow(label, edit)
        split.addWidget(meta)
        caps = QWidget()
        cl = QVBoxLayout(caps)
        cl.setContentsMargins(0, 0, 0, 0)
        self.tree = QTreeWidget()
        self.tree.setHeaderLabels(["Capture", "Kind", "Pass", "Angle (deg)", "Status", "Detail"])
        self.tree.setRootIsDecorated(False)
        self.tree.setAlternatingRowColors(True)
        self.tree.setColumnWidth(0, 150)
        cl.addWidget(self.tree, 2)
        self.thumbs = QListWidget()
        self.thumbs.setViewMode(QListWidget.ViewMode.IconMode)
        self.thumbs.setIconSize(QSize(96, 72))
        self.thumbs.setResizeMode(QListWidget.ResizeMode.Adjust)
        self.thumbs.setMinimumHeight(110)
        cl.addWidget(QLabel("RAW frames"))
        cl.addWidget(self.thumbs, 1)
        split.addWidget(caps)
        split.setStretchFactor(1, 2)
        split.setSizes([470, 810])
        outer.addWidget(split, 1)
        self.capturing = False

    # ------------------------------------------------------------ actions
    def _browse(self) -> None:
        path = QFileDialog.getExistingDirectory(self, "Session folder")
        if path:
            self.folder.setText(path)

    def set_metadata(self, values: dict[str, str]) -> None:
        """Fill the object form (each field shows its beginning)."""
        for key, edit in self.meta_edits.items():
            edit.setText(values.get(key, ""))
            edit.setCursorPosition(0)

    def metadata(self) -> dict[str, str]:
        return {k: e.text().strip() for k, e in self.meta_edits.items() if e.text().strip()}

    def new_session(self) -> None:
        """Choose a new session folder; the session is created when its capture starts (with its plan)."""
        from app.errors import UsageError

        text = self.folder.text().strip()
        if not text:
            raise UsageError("give the folder of the new session")
        path = Path(text).expanduser()
        if path.exists() and (not path.is_dir() or any(path.iterdir())):
            raise UsageError(f"{path} already exists and is not empty; choose a new folder, or use Open / resume")
        self.root = path
        self.manifest = None
        self.tree.clear()
        self.thumbs.clear()
        self._thumbs.clear()
        self.status.setText(f"new session {path}: set the plan on the Capture tab and press Start")
        self.session_chosen.emit(path)

    def open_session(self, text: str) -> None:
        """Open an existing session (read-only view; a capture resumes it)."""
        from app.errors import UsageError
        from app.session import Session, SessionError

        path = Path(text).expanduser()
        if not text:
            raise UsageError("give the folder of the session to open")
        try:
            manifest = Session.read(path)
        except SessionError as exc:
            raise UsageError(str(exc)) from None
        self.root = path
        self.folder.setText(str(path))
        self.set_metadata({k: str(v) for k, v in manifest.get("object", {}).items()})
        self._thumbs.clear()
        self.thumbs.clear()
        self.show_manifest(manifest)
        self.session_chosen.emit(path)

    # ------------------------------------------------------------ outputs
    #: Opens a file or folder URL (the desktop's default program); replaced in tests.
    opener = staticmethod(lambda url: QDesktopServices.openUrl(url))

    def _session_on_disk(self) -> Path:
        from app.errors import UsageError

        if self.root is None or not (self.root / "session.json").exists():
            raise UsageError("open a session first (a new one exists once its capture has started)")
        return self.root

    def open_folder(self) -> None:
        """Open the session's folder in the desktop's file manager."""
        self.opener(QUrl.fromLocalFile(str(self._session_on_disk())))

    def make_report(self) -> None:
        """Write the session's report on a worker thread, then open it."""
        from app.errors import UsageError

        root = self._session_on_disk()
        if self.capturing:
            raise UsageError("the capture is writing the session; make the report when it has stopped")

        def work(ctx: JobContext) -> Path:
            from app.report.html import write_report

            return write_report(root)

        def done(path: Path) -> None:
            self.report_path = Path(path)
            self.log.emit(f"report written: {path}")
            self.notice.emit(f"report written: {path} (opened in the browser)")
            self.opener(QUrl.fromLocalFile(str(path)))
            self.refresh()

        self.notice.emit("making the report…")
        self.lane.run(work, "report", succeeded=done, failed=lambda text, exc: self.error.emit(f"report: {text}"))

    def _export(self) -> None:
        root = self._session_on_disk()
        path, _ = QFileDialog.getSaveFileName(self, "Export the measured object", str(root / "object.glb"),
                                              "glTF binary (*.glb)")
        if path:
            self.export_to(path)

    def export_to(self, path: str | Path) -> None:
        """Write the measured object as a ``.glb`` at ``path`` (replacing it) on a worker thread."""
        root = self._session_on_disk()

        def work(ctx: JobContext) -> dict[str, Any]:
            from app.workflows.gltf_export import export_gltf

            return export_gltf(root, path, force=True)

        def done(info: dict[str, Any]) -> None:
            self.exported = info
            self.notice.emit(f"exported {info['out']}: {info['triangles']:,} triangles, "
                             f"{len(info['regions'])} materials, {info['bytes'] / 1e6:.1f} MB")

        self.lane.run(work, "export", succeeded=done, failed=lambda text, exc: self.error.emit(f"export: {text}"))

    def save_metadata(self) -> None:
        from app.errors import UsageError
        from app.session import Session, SessionError

        if self.root is None or self.manifest is None:
            raise UsageError("no session on disk yet: the metadata is stored when the capture starts")
        if self.capturing:
            raise UsageError("the capture is writing the session; save the metadata when it has stopped")
        root, edits = self.root, self.metadata()

        def work(ctx: JobContext) -> None:        # writes and syncs the session file: not on the GUI thread
            try:
                with Session.open(root) as s:
                    s.update("object", {**s.manifest.get("object", {}), **edits})
            except SessionError as exc:
                raise UsageError(str(exc)) from None

        def done(_: Any) -> None:
            self.notice.emit(f"metadata saved in {root}")
            self.refresh()

        self.lane.run(work, "save metadata", succeeded=done,
                      failed=lambda text, exc: self.error.emit(f"save metadata: {text}"))

    # ------------------------------------------------------------ list
    def refresh(self) -> None:
        """Re-read the session (on a worker thread) and update the list."""
        if self.root is None or not (self.root / "session.json").exists():
            return
        root = self.root

        def work(ctx: JobContext) -> dict[str, Any]:
            from app.session import Session

            return Session.read(root)

        self.lane.run(work, "read session", succeeded=self.show_manifest)

    def show_manifest(self, manifest: dict[str, Any]) -> None:
        self.manifest = manifest
        caps = manifest.get("captures", {})
        passes = manifest.get("passes", {})
        done = sum(1 for r in caps.values() if r.get("kind") in ("profile", "frame", "chart", "burst"))
        plan = manifest.get("plan", {})
        obj = manifest.get("object", {}).get("name", "")
        self.status.setText(f"{self.root}: <b>{manifest.get('status')}</b>{' · ' + obj if obj else ''} · "
                            f"{plan.get('kind', '?')} plan, {plan.get('steps', '?')} steps × "
                            f"{plan.get('passes', '?')} passes · {done} captures · passes complete: "
                            f"{sum(1 for p in passes.values() if p.get('status') == 'complete')}"
                            + (" · mesh ready" if (manifest.get("products") or {}).get("mesh") else ""))
        self.tree.setUpdatesEnabled(False)
        self.tree.clear()
        items = []
        for cid, rec in caps.items():
            rec = {**rec, "status": rec.get("status", "done")}
            items.append(QTreeWidgetItem(capture_row(cid, rec)))
        self.tree.addTopLevelItems(items)
        self.tree.setUpdatesEnabled(True)
        for cid, rec in caps.items():
            if rec.get("kind") in ("chart", "frame") and cid not in self._thumbs and rec.get("file"):
                self._thumbs.add(cid)
                self._load_thumb(cid, self.root / rec["file"])
        self.manifest_shown.emit()

    def _load_thumb(self, cid: str, path: Path) -> None:
        def work(ctx: JobContext) -> tuple[str, np.ndarray]:
            return cid, _thumbnail(path)

        def show(result: tuple[str, np.ndarray]) -> None:
            name, rgb = result
            item = QListWidgetItem(QIcon(QPixmap.fromImage(rgb_to_qimage(rgb))), name)
            item.setToolTip(str(path))
            self.thumbs.addItem(item)

        self.lane.run(work, f"thumbnail {cid}", succeeded=show,
                      failed=lambda text, exc: self.thumbs.addItem(QListWidgetItem(f"{cid}: {text}")))
