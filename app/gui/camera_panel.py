"""Camera panel: shoot a RAW frame, show its decoded preview with the detected chart outlined and each
patch's quality, and a histogram of the linear signal with a clipping warning.

A thin shell over :func:`processing.camera.raw_decode.decode_raw` (black level,
white level and saturation from the file's own metadata),
:func:`processing.camera.raw_decode.preview_srgb8` and
:func:`processing.camera.chart_detection.detect_chart`.  Frames are shot with the
camera of the Devices tab (:class:`app.capture.devices.Gphoto2Shooter` /
:class:`app.capture.devices.HotFolderShooter`) into a folder of the window's
own (test shots are not captures of the session); any RAW file, such as a
session's chart frame, can be opened too.

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

from app.gui.figures import HISTOGRAM_BINS, QUALITY_COLOURS, display_image, frame_figure, histogram_figure
from app.gui.plots import FigureDrawer, PlotImage
from app.gui.station_link import StationLink
from app.gui.widgets import Panel
from app.gui.workers import JobContext, Lane

__all__ = ["CameraPanel", "FrameView", "analyse_frame", "patch_quality", "QUALITY_COLOURS"]

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


def analyse_frame(path: str | Path, posed: dict[str, Any] | None = None) -> FrameView:
    """Decode ``path``, make its preview, find the chart and judge each patch.

    ``posed``: :func:`app.workflows.posed_frames.frame_outline` of the frame
    (outlines in full-resolution pixels), drawn over the preview.
    """
    from processing.camera.chart_detection import ChartDetectionError, detect_chart
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
        det = detect_chart(raw)
    except ChartDetectionError as exc:
        view.chart_problem = str(exc)
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

    def __init__(self, link: StationLink, lane: Lane, drawer: FigureDrawer, session_root: Callable[[], Path | None],
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.link = link
        self.lane = lane
        self.session_root = session_root
        self.frame: FrameView | None = None
        self._shots = tempfile.TemporaryDirectory(prefix="kogei-gui-shots-")
        self._count = 0
        outer = QVBoxLayout(self)
        row = QHBoxLayout()
        self.shoot_button = QPushButton("Capture RAW  (Ctrl+R)")
        self.shoot_button.setShortcut("Ctrl+R")
        self.open_button = QPushButton("Open RAW…")
        self.chart_frame_button = QPushButton("Open the session's chart frame")
        self.posed_list = QComboBox()
        self.posed_list.setMinimumContentsLength(14)
        self.posed_list.setToolTip("the session's frames posed on the mesh (after kogei process with a camera "
                                   "calibration, or kogei project)")
        self.posed_button = QPushButton("Show with the mesh outline")
        self.posed_button.clicked.connect(self.safe(self.open_posed))
        self.shoot_button.clicked.connect(self.safe(self.shoot))
        self.open_button.clicked.connect(self.safe(self._open))
        self.chart_frame_button.clicked.connect(self.safe(self.open_session_chart))
        for b in (self.shoot_button, self.open_button, self.chart_frame_button, self.posed_list, self.posed_button):
            row.addWidget(b)
        row.addStretch(1)
        outer.addLayout(row)
        self.state = QLabel("no frame yet")
        self.state.setWordWrap(True)
        outer.addWidget(self.state)
        self.clip_warning = QLabel("")
        self.clip_warning.setStyleSheet("color:#7a1512; font-weight:bold;")
        self.clip_warning.setWordWrap(True)
        outer.addWidget(self.clip_warning)
        split = QSplitter(Qt.Orientation.Horizontal)
        self.image_plot = PlotImage(drawer)
        self.hist_plot = PlotImage(drawer)
        split.addWidget(self.image_plot)
        split.addWidget(self.hist_plot)
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

    def open_file(self, path: str | Path) -> None:
        """Decode and show a RAW file (on a worker thread)."""
        self.state.setText(f"decoding {path}…")
        self.lane.run(lambda ctx: analyse_frame(path), "decode", succeeded=self.show_frame, failed=self._failed)

    def _open(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "RAW file", "", "RAW (*.dng *.DNG *.cr2 *.nef *.arw);;All (*)")
        if path:
            self.open_file(path)

    def open_session_chart(self) -> None:
        from app.errors import UsageError
        from app.session import Session

        root = self.session_root()
        if root is None or not (root / "session.json").exists():
            raise UsageError("open a session with camera frames first (Session tab)")
        caps = Session.read(root)["captures"]
        charts = [r for k, r in caps.items() if r.get("kind") == "chart"]
        if not charts:
            raise UsageError(f"session {root} has no chart frame (was the plan's chart option off?)")
        self.open_file(root / charts[-1]["file"])

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
            title = (f"{view.chart.chart} chart, confidence {view.chart.confidence:.2f}; patches: "
                     + ", ".join(f"{v} {k}" for k, v in counts.items() if v))
        else:
            title = f"{view.path.name}: no chart found" if view.chart_problem else view.path.name
        if view.posed:
            title = view.posed
        self.image_plot.plot(frame_figure, image=display_image(view.preview), size=(w, h), title=title,
                             outline=view.outline, quads=view.quads, qualities=view.qualities,
                             mesh_outlines=view.mesh_outlines)
        clipped = view.clipped
        if view.histogram is not None:
            self.hist_plot.plot(histogram_figure, counts=view.histogram, clipped=clipped)
        if clipped > CLIP_WARN:
            self.clip_warning.setText(f"{100 * clipped:.2f}% of the pixels are clipped: lower the exposure or the "
                                      "light (clipped colours cannot be measured)")
        else:
            self.clip_warning.setText("")
        self.state.setText(f"{view.path.name}: {w}x{h} preview (2x2 binned)"
                           + (f" · {view.posed}" if view.posed else "")
                           + (f" · chart: {view.chart_problem}" if view.chart_problem else ""))
        self.frame_shown.emit(view)
