"""Camera panel: shoot a RAW frame, show its decoded preview with the detected chart outlined and each
patch's quality, and a histogram of the linear signal with a clipping warning.

A thin shell over :func:`processing.camera.raw_decode.decode_raw` (black level,
white level and saturation from the file's own metadata),
:func:`processing.camera.raw_decode.preview_srgb8` and
:func:`processing.camera.chart_detection.detect_chart`.  Frames are shot with the
camera of the Devices tab (:class:`app.capture.devices.Gphoto2Shooter` /
:class:`app.capture.devices.HotFolderShooter`) into a folder of the window's
own (test shots are not captures of the session); any RAW file can be
opened too, and any of the session's chart frames, listed by the pass each
belongs to (:func:`session_chart_frames`; the Spectra tab lists the same
ones).  Where ``cv2.mcc`` does not find the chart, "Mark the chart's
corners" takes four clicks on the frame -- the chart's outer corners,
top-left (patch 1, dark skin) first, clockwise -- and places the patches
from them (:func:`processing.camera.chart_detection.chart_from_corners`);
the Spectra tab then calibrates with those corners too.

A patch's quality is judged on its central half (clear of the edges the
homography may misplace by a pixel): ``clipped`` if any photosite of it
reached the white level (its colour is then wrong), ``dark`` if its green
signal is below 2% of full scale (quantisation and read noise dominate),
``noisy`` if its signal-to-noise ratio is below 20, else ``ok``.

Examples
--------
>>> patch_quality(np.array([0.5, 0.5, 0.5]), np.array([0.01, 0.01, 0.01]), 0.0)
'ok'
>>> patch_quality(np.array([0.9, 0.9, 0.9]), np.array([0.01, 0.01, 0.01]), 0.02)
'clipped'
>>> patch_quality(np.array([0.01, 0.01, 0.01]), np.array([0.001, 0.001, 0.001]), 0.0)
'dark'
"""

from __future__ import annotations

import re
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from PySide6.QtCore import Qt, Signal
from PySide6.QtWidgets import (
    QComboBox,
    QFileDialog,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QSplitter,
    QVBoxLayout,
    QWidget,
)

from app.gui.figures import (
    HISTOGRAM_BINS,
    QUALITY_COLOURS,
    display_image,
    empty_figure,
    frame_figure,
    histogram_figure,
)
from app.gui.plots import FigureDrawer, PlotImage
from app.gui.station_link import StationLink
from app.gui.widgets import Panel
from app.gui.workers import JobContext, Lane

__all__ = ["CameraPanel", "FrameView", "analyse_frame", "patch_quality", "QUALITY_COLOURS", "session_chart_frames",
           "clipping_message",
           "chart_frame_label", "corners_text", "CORNER_NAMES"]

#: The chart's outer corners in the order they are clicked.
CORNER_NAMES = ("top-left (patch 1, dark skin)", "top-right", "bottom-right", "bottom-left (patch 19, white)")

#: Fraction of clipped pixels above which the histogram warns.
CLIP_WARN = 0.001


def patch_quality(mean: np.ndarray, std: np.ndarray, clipped_fraction: float) -> str:
    """``ok``, ``noisy``, ``dark`` or ``clipped`` from a patch's channel means and deviations (see module)."""
    if clipped_fraction > 0:
        return "clipped"
    if float(mean[1]) < 0.02:
        return "dark"
    snr = float(np.min(mean / np.maximum(std, 1e-9)))
    return "noisy" if snr < 20 else "ok"


@dataclass
class FrameView:
    """A decoded frame as the panel shows it."""

    path: Path
    preview: np.ndarray                    # (H, W, 3) uint8
    rgb: np.ndarray                        # (H, W, 3) float32 linear camera RGB (1 = saturation)
    saturated: np.ndarray                  # (H, W) bool
    scale: int
    chart: Any = None                      # processing.camera.chart_detection.ChartDetection or None
    chart_problem: str = ""
    quads: np.ndarray | None = None        # (N, 4, 2) patch corners in preview pixels
    qualities: list[str] | None = None
    raw: Any = None
    outline: np.ndarray | None = None      # (4, 2) the chart's corners in preview pixels
    histogram: np.ndarray | None = None    # (3, 128) pixel counts of the linear signal over HISTOGRAM_BINS
    clipped: float = 0.0                   # fraction of saturated pixels
    mesh_outlines: list[np.ndarray] | None = None   # the mesh's projected outline, preview pixels
    posed: str = ""                        # "p01/frame/03: IoU 0.991" for a posed frame


def clipping_message(clipped: float, chart_found: bool, clipped_patches: list[int]) -> tuple[str, str]:
    """What the clipped share of a frame means, and how serious it is (``""``, ``"note"`` or ``"warn"``).

    Clipped chart patches spoil the colour calibration (lower the exposure);
    clipping elsewhere on a chart frame, or on an object frame, is mostly the
    specular highlights of polished metal, which have no measurable colour
    anyway and are left out of the spectra.

    Examples
    --------
    >>> clipping_message(0.0002, True, [])
    ('', '')
    >>> clipping_message(0.004, True, [19])[1], clipping_message(0.004, False, [])[1]
    ('warn', 'note')
    """
    if clipped <= CLIP_WARN:
        return "", ""
    share = f"{100 * clipped:.2f}% of the pixels are clipped"
    if clipped_patches:
        listed = ", ".join(str(n) for n in clipped_patches)
        return (f"{share}, chart patch{'es' if len(clipped_patches) > 1 else ''} {listed} among them: lower the "
                "exposure or the light (a clipped patch's colour cannot be measured)", "warn")
    where = "none on the chart: " if chart_found else ""
    return (f"{share} ({where}most likely the object's specular highlights, which have no measurable colour and "
            "are left out of the spectra); lower the exposure only if the object's own colours are clipped", "note")


def session_chart_frames(root: Path) -> list[tuple[str, int, Path]]:
    """The session's chart frames as ``(capture id, pass number, file)``, in pass order.

    A scan pass has one chart frame (``pNN/chart``), a swatch pass several
    (``pNN/chart/00``, ...).
    """
    from app.session import Session

    caps = Session.read(root)["captures"]
    found = [(cid, int(r.get("pass", 0)), root / r["file"]) for cid, r in caps.items()
             if r.get("kind") == "chart" and r.get("status", "done") == "done" and r.get("file")]
    return sorted(found, key=lambda t: (t[1], t[0]))


def chart_frame_label(cid: str, pass_number: int) -> str:
    """What the user reads for a chart frame: its pass first.

    >>> chart_frame_label("p02/chart", 2), chart_frame_label("p01/chart/01", 1)
    ('pass 2 chart frame', 'pass 1 chart frame 2')
    """
    parts = cid.split("/")
    return f"pass {pass_number} chart frame" + (f" {int(parts[2]) + 1}" if len(parts) > 2 else "")


def corners_text(corners: np.ndarray) -> str:
    """``(4, 2)`` sensor corners as :func:`processing.camera.chart_detection.parse_corners` reads them.

    >>> corners_text(np.array([[1, 2], [3.25, 4], [5, 6], [7, 8]]))
    '1.0,2.0,3.25,4.0,5.0,6.0,7.0,8.0'
    """
    return ",".join(repr(float(v)) for v in np.asarray(corners, dtype=float).ravel())


def analyse_frame(path: str | Path, posed: dict[str, Any] | None = None,
                  corners: np.ndarray | None = None) -> FrameView:
    """Decode ``path``, make its preview, find the chart and judge each patch.

    ``posed``: :func:`app.workflows.posed_frames.frame_outline` of the frame
    (outlines in full-resolution pixels), drawn over the preview.
    ``corners``: the chart's four outer corners (sensor pixels, top-left
    first, clockwise) instead of looking for it.
    """
    from processing.camera.chart_detection import ChartDetectionError, chart_from_corners, detect_chart
    from processing.camera.raw_decode import decode_raw, preview_srgb8

    raw = decode_raw(path, mode="bin2x2")
    view = FrameView(Path(path), preview_srgb8(raw), raw.rgb, raw.saturated, raw.scale, raw=raw)
    if posed is not None:
        view.mesh_outlines = [raw.from_sensor(o) for o in posed["outlines"]]
        iou = posed.get("iou")
        view.posed = f"{posed['frame']}: mesh outline, silhouette IoU " + ("not checked" if iou is None else
                                                                         f"{iou:.3f}")
    view.clipped = float(raw.saturated.mean())
    view.histogram = np.stack([np.histogram(np.clip(raw.rgb[..., c], 0, 1), bins=HISTOGRAM_BINS)[0]
                               for c in range(3)])
    if posed is not None:
        return view                     # an object frame: no chart to look for
    try:
        if corners is None:
            det = detect_chart(raw)
        else:
            h, w = raw.shape
            det = chart_from_corners(corners, image_size=(w * raw.scale, h * raw.scale))
    except ChartDetectionError as exc:
        # the window's way to give corners is to click them, not the command line's option
        view.chart_problem = re.sub(r"[;,] (or )?pass the chart's four outer corners as --chart-corners \S+", "",
                                    str(exc))
        return view
    view.chart = det
    view.outline = raw.from_sensor(det.corners)
    quads = raw.from_sensor(det.quads)
    view.quads = quads
    h, w = raw.shape
    qualities = []
    for q in quads:
        c = q.mean(axis=0)
        half = 0.25 * np.abs(q - c).max(axis=0)        # the central half of the patch
        x0, x1 = int(max(c[0] - half[0], 0)), int(min(c[0] + half[0], w - 1)) + 1
        y0, y1 = int(max(c[1] - half[1], 0)), int(min(c[1] + half[1], h - 1)) + 1
        block = raw.rgb[y0:y1, x0:x1].reshape(-1, 3)
        if block.size == 0:
            qualities.append("dark")
            continue
        clipped = float(raw.saturated[y0:y1, x0:x1].mean())
        qualities.append(patch_quality(block.mean(axis=0), block.std(axis=0), clipped))
    view.qualities = qualities
    return view


class CameraPanel(Panel):
    """See the module docstring."""

    frame_shown = Signal(object)           # FrameView
    corners_marked = Signal(str, str)      # chart frame file, its corners (sensor pixels, parse_corners' text)

    def __init__(self, link: StationLink, lane: Lane, drawer: FigureDrawer, session_root: Callable[[], Path | None],
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.link = link
        self.lane = lane
        self.session_root = session_root
        self.frame: FrameView | None = None
        #: Chart corners marked by hand, per chart frame file (sensor pixels, top-left first, clockwise).
        self.manual_corners: dict[str, np.ndarray] = {}
        self._marks: list[tuple[float, float]] | None = None       # clicks so far while marking corners
        self._charts_root: Path | None = None
        self._shots = tempfile.TemporaryDirectory(prefix="kogei-gui-shots-")
        self._count = 0
        outer = QVBoxLayout(self)
        row = QHBoxLayout()
        self.shoot_button = QPushButton("Capture RAW  (Ctrl+R)")
        self.shoot_button.setShortcut("Ctrl+R")
        self.open_button = QPushButton("Open RAW…")
        self.chart_frames = QComboBox()
        self.chart_frames.setMinimumContentsLength(16)
        self.chart_frames.setToolTip("the open session's chart frames, one per pass: the pass each belongs to")
        self.chart_frame_button = QPushButton("Open chart frame")
        self.chart_frame_button.setToolTip("decode the chosen chart frame of the session and find the chart in it")
        self.corners_button = QPushButton("Mark the chart's corners")
        self.corners_button.setCheckable(True)
        self.corners_button.setToolTip("when the chart is not found: click its four outer corners on the frame, "
                                       "top-left (patch 1, dark skin) first, then clockwise")
        self.corners_button.toggled.connect(self._marking)
        self.posed_list = QComboBox()
        self.posed_list.setMinimumContentsLength(14)
        self.posed_list.setPlaceholderText("no posed frames yet")
        self.chart_frames.setPlaceholderText("no chart frames")
        self.posed_list.setToolTip("the session's frames posed on the mesh (after kogei process with a camera "
                                   "calibration, or kogei project)")
        self.posed_button = QPushButton("Show with the mesh outline")
        self.posed_button.clicked.connect(self.safe(self.open_posed))
        self.shoot_button.clicked.connect(self.safe(self.shoot))
        self.open_button.clicked.connect(self.safe(self._open))
        self.chart_frame_button.clicked.connect(self.safe(self.open_session_chart))
        self.shoot_button.setToolTip("shoot a test frame with the camera of the Devices tab (not kept in the "
                                     "session)")
        self.open_button.setToolTip("decode any RAW file and look for a colour chart in it")
        self.posed_button.setToolTip("show the chosen frame with the scanned mesh's outline drawn over it")
        for b in (self.shoot_button, self.open_button, self.chart_frames, self.chart_frame_button,
                  self.corners_button):
            row.addWidget(b)
        row.addStretch(1)
        outer.addLayout(row)
        posed_row = QHBoxLayout()                  # a second row: the toolbar fits a 1024 px wide window
        posed_row.addWidget(QLabel("Posed on the mesh:"))
        posed_row.addWidget(self.posed_list)
        posed_row.addWidget(self.posed_button)
        posed_row.addStretch(1)
        outer.addLayout(posed_row)
        self.state = QLabel("no frame yet: open a chart frame of the session, a RAW file, or capture one")
        self.state.setWordWrap(True)
        outer.addWidget(self.state)
        self.clip_warning = QLabel("")
        self.clip_warning.setStyleSheet("color:#7a1512; font-weight:bold;")
        self.clip_warning.setWordWrap(True)
        outer.addWidget(self.clip_warning)
        split = QSplitter(Qt.Orientation.Horizontal)
        self.image_plot = PlotImage(drawer)
        self.image_plot.clicked.connect(self._clicked)
        self.hist_plot = PlotImage(drawer)
        split.addWidget(self.image_plot)
        split.addWidget(self.hist_plot)
        self.image_plot.plot(empty_figure, title="Frame", hint="open a chart frame of the session, a RAW file,\n"
                                                                "or capture one")
        self.hist_plot.plot(empty_figure, title="Linear signal", hint="the histogram of the frame's RAW signal")
        split.setStretchFactor(0, 3)
        split.setStretchFactor(1, 2)
        outer.addWidget(split, 1)

    # ------------------------------------------------------------ sources
    def shoot(self) -> None:
        from app.capture.devices import Gphoto2Shooter, HotFolderShooter
        from app.errors import UsageError

        cam = dict(self.link.camera)
        if cam.get("kind", "none") == "none":
            raise UsageError("no camera chosen: pick gphoto2 or a hot folder on the Devices tab")
        problem = self.link.camera_problem()
        if problem:
            raise UsageError(problem)
        self._count += 1
        name = f"shot_{self._count:03d}"
        staging = Path(self._shots.name)
        shutter = self.link.shutter

        def work(ctx: JobContext) -> FrameView:
            if cam["kind"] == "gphoto2":
                shooter: Any = Gphoto2Shooter(staging, cam.get("executable", "gphoto2"), float(cam.get("timeout_s", 60)))
            else:
                shooter = HotFolderShooter(staging, cam["folder"], shutter, float(cam.get("stable_s", 0.3)),
                                           float(cam.get("timeout_s", 60)))
            return analyse_frame(shooter.shoot(name))

        self.state.setText("shooting…")
        self.lane.run(work, "shoot", succeeded=self.show_frame, failed=self._failed)

    def open_file(self, path: str | Path, label: str = "") -> None:
        """Decode and show a RAW file (on a worker thread), with the corners marked on it by hand if any."""
        self.state.setText(f"decoding {label or path}…")
        corners = self.manual_corners.get(str(path))
        self.lane.run(lambda ctx: analyse_frame(path, corners=corners), "decode", succeeded=self.show_frame,
                      failed=self._failed)

    def _open(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "RAW file", "", "RAW (*.dng *.DNG *.cr2 *.nef *.arw);;All (*)")
        if path:
            self.open_file(path)

    def refresh_charts(self) -> list[tuple[str, int, Path]]:
        """List the open session's chart frames by pass (the first one chosen); returns them."""
        root = self.session_root()
        found = [] if root is None or not (root / "session.json").exists() else session_chart_frames(root)
        current = self.chart_frames.currentData()
        self.chart_frames.clear()
        for cid, number, _path in found:
            self.chart_frames.addItem(chart_frame_label(cid, number), cid)
        index = self.chart_frames.findData(current) if root == self._charts_root else -1
        self.chart_frames.setCurrentIndex(max(index, 0))
        self._charts_root = root
        return found

    def open_session_chart(self) -> None:
        """Open the chart frame chosen in the list (pass 1's unless another was chosen)."""
        from app.errors import UsageError

        root = self.session_root()
        if root is None or not (root / "session.json").exists():
            raise UsageError("open a session with camera frames first (Session tab)")
        if root != self._charts_root or self.chart_frames.count() == 0:
            self.refresh_charts()
        if self.chart_frames.count() == 0:
            raise UsageError(f"session {root} has no chart frame (was the plan's chart option off?)")
        found = {cid: path for cid, _, path in session_chart_frames(root)}
        cid = self.chart_frames.currentData()
        if cid not in found:
            self.refresh_charts()
            cid = self.chart_frames.currentData()
        self.open_file(found[cid], self.chart_frames.currentText())

    # ------------------------------------------------------------ corners by hand
    def _marking(self, on: bool) -> None:
        if on and (self.frame is None or self.frame.posed):
            self.corners_button.setChecked(False)
            self.error.emit("camera: open a chart frame first, then mark its corners")
            return
        self._marks = [] if on else None
        if on:
            self.state.setText(f"click the chart's {CORNER_NAMES[0]} corner on the frame")
        self._redraw()

    def _clicked(self, gid: str, x: float, y: float) -> None:
        if gid != "frame" or self._marks is None or self.frame is None:
            return
        self._marks.append((x, y))
        if len(self._marks) < 4:
            self.state.setText(f"corner {len(self._marks)} of 4 marked; now the {CORNER_NAMES[len(self._marks)]} "
                               "corner")
            self._redraw()
            return
        self.set_corners(np.array(self._marks))

    def set_corners(self, preview_corners: np.ndarray) -> None:
        """Place the chart of the frame shown from its four outer corners in preview pixels (as clicked)."""
        view = self.frame
        marks = np.asarray(preview_corners, dtype=float).reshape(4, 2)
        self._marks = None
        self.corners_button.blockSignals(True)
        self.corners_button.setChecked(False)
        self.corners_button.blockSignals(False)
        sensor = view.raw.to_sensor(marks)
        path = view.path
        self.state.setText("placing the patches from the marked corners…")

        def done(new: FrameView) -> None:
            if new.chart is not None:
                self.manual_corners[str(path)] = sensor
                self.corners_marked.emit(str(path), corners_text(sensor))
            self.show_frame(new)

        self.lane.run(lambda ctx: analyse_frame(path, corners=sensor), "decode", succeeded=done, failed=self._failed)

    def _redraw(self) -> None:
        if self.frame is not None:
            self.show_frame(self.frame)

    def refresh_posed(self) -> list[str]:
        """Fill the list of the session's posed frames; returns them."""
        from app.workflows.posed_frames import posed_frame_names

        root = self.session_root()
        names = [] if root is None or not (root / "session.json").exists() else posed_frame_names(root)
        current = self.posed_list.currentText()
        self.posed_list.clear()
        self.posed_list.addItems(names)
        if current in names:
            self.posed_list.setCurrentText(current)
        return names

    def open_posed(self) -> None:
        """Open the chosen posed frame with the mesh's outline projected on it (decoded on a worker thread)."""
        from app.errors import UsageError
        from app.session import Session
        from app.workflows.posed_frames import frame_outline

        root = self.session_root()
        if not self.posed_list.currentText() and not self.refresh_posed():
            raise UsageError("the session's frames are not posed on the mesh yet: calibrate the camera, then "
                             "process the session with --camera-calibration (or kogei project)")
        cid = self.posed_list.currentText()
        rec = Session.read(root)["captures"][cid]
        self.state.setText(f"projecting the mesh onto {cid}…")
        self.lane.run(lambda ctx: analyse_frame(root / rec["file"], frame_outline(root, cid)), "decode",
                      succeeded=self.show_frame, failed=self._failed)

    def _failed(self, text: str, exc: Any) -> None:
        self.state.setText(f"failed: {text}")
        self.error.emit(f"camera: {text}")

    # ------------------------------------------------------------ display
    def show_frame(self, view: FrameView) -> None:
        self.frame = view
        h, w = view.preview.shape[:2]
        if view.quads is not None and view.chart is not None:
            counts = {k: (view.qualities or []).count(k) for k in QUALITY_COLOURS}
            from app.gui.guidance import chart_verdict

            verdict = chart_verdict(view.chart.confidence, view.chart.method)
            self.chart_verdict = verdict
            found = ("placed from the marked corners" if view.chart.method == "manual"
                     else f"found, confidence {view.chart.confidence:.2f} ({verdict.level})")
            title = (f"{view.chart.chart} chart {found}; patches: "
                     + ", ".join(f"{v} {k}" for k, v in counts.items() if v))
        else:
            title = f"{view.path.name}: no chart found" if view.chart_problem else view.path.name
        if view.posed:
            title = view.posed
        self.image_plot.plot(frame_figure, image=display_image(view.preview), size=(w, h), title=title,
                             outline=view.outline, quads=view.quads, qualities=view.qualities,
                             mesh_outlines=view.mesh_outlines,
                             marks=None if not self._marks else np.array(self._marks))
        clipped = view.clipped
        if view.histogram is not None:
            self.hist_plot.plot(histogram_figure, counts=view.histogram, clipped=clipped)
        patches = [k + 1 for k, q in enumerate(view.qualities or []) if q == "clipped"]
        text, level = clipping_message(clipped, view.chart is not None, patches)
        self.clip_warning.setText(text)
        self.clip_warning.setStyleSheet("color:#7a1512; font-weight:bold;" if level == "warn" else "color:#5a4300;")
        self.clip_level = level
        verdict = getattr(self, "chart_verdict", None) if view.chart is not None else None
        self.state.setToolTip(verdict.tooltip if verdict is not None else "")
        self.state.setText((f"chart {verdict.level.upper()}: {verdict.why} · " if verdict is not None else "")
                           + f"{view.path.name}: {w}x{h} preview (2x2 binned)"
                           + (f" · {view.posed}" if view.posed else "")
                           + (f" · chart: {view.chart_problem}; mark its four corners with \"Mark the chart's "
                              "corners\"" if view.chart_problem else ""))
        if self._marks is not None:
            self.state.setText(f"corner {len(self._marks)} of 4 marked; click the chart's "
                               f"{CORNER_NAMES[len(self._marks)]} corner")
            return
        self.frame_shown.emit(view)
