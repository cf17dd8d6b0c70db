"""The capture station's main window: tabs for each stage, a drop-out banner, a log panel, shortcuts, settings.

Tabs: Devices, Session, Capture, Camera, Processing, Spectra and materials,
Preview (one module each).  Long work runs off the GUI thread
(:mod:`app.gui.workers`); errors appear as a readable line above the tabs and
in the log panel, never as a lost session.  Window layout, ports, camera,
simulated-station folder, last session and calibration persist in
:class:`QSettings` (organisation ``kogei``, application ``capture-station``).

On start the window reopens the last session it had open (when it is still
there); File > Recent sessions lists the last :data:`MAX_RECENT`.  A session
that was moved or deleted is said so in the window and taken off the list.

Keyboard: F5 start / resume the capture, F6 pause / continue, Esc abort,
Enter continue at a placement prompt, Ctrl+Left / Ctrl+Right jog the table
by one step, Ctrl+0 zero the table, Ctrl+L / Ctrl+Shift+L laser on / off,
Ctrl+1..7 switch tabs.
"""

from __future__ import annotations

import logging
import sys
import tempfile
from pathlib import Path
from typing import Any

from PySide6.QtCore import QCoreApplication, QSettings, Qt
from PySide6.QtGui import QAction, QKeySequence, QShortcut
from PySide6.QtWidgets import (
    QDockWidget,
    QHBoxLayout,
    QLabel,
    QMainWindow,
    QPlainTextEdit,
    QPushButton,
    QTabWidget,
    QVBoxLayout,
    QWidget,
)

from app.gui.camera_panel import CameraPanel
from app.gui.capture_panel import CapturePanel
from app.gui.devices_panel import SIMULATED_OBJECTS, DevicesPanel
from app.gui.plots import FigureDrawer
from app.gui.preview_panel import PreviewPanel
from app.gui.processing_panel import ProcessingPanel
from app.gui.session_panel import SessionPanel
from app.gui.spectra_panel import SpectraPanel
from app.gui.station_link import INSTRUMENTS, StationLink
from app.gui.warm_up import freeze_heap, warm_up
from app.gui.widgets import Banner, Panel, StepStrip
from app.gui.workers import Lane

__all__ = ["MainWindow", "SETTINGS_ORG", "SETTINGS_APP", "MAX_RECENT", "simulated_world", "station_frame_size",
           "TARGET_BINNING"]

SETTINGS_ORG = "kogei"
SETTINGS_APP = "capture-station"
#: How many sessions File > Recent sessions lists.
MAX_RECENT = 8


#: The simulated camera's photosites per station-frame pixel along each side: the board and the chrome sphere
#: are photographed at the sensor's full resolution (960 x 640 for the 240 x 160 station frames, as ``kogei
#: demo``), the piece and the reference sphere binned 4 x 4 (the camera calibration scales to binned frames).
TARGET_BINNING = 4


def simulated_world(name: str, triangles: int = 4000, image_size: tuple[int, int] = (240, 160)) -> Any:
    """The :class:`mocks.world.World` of an entry of :data:`app.gui.devices_panel.SIMULATED_OBJECTS`.

    ``image_size`` is the station's frame (the piece's photos); the calibration targets' worlds
    (:class:`mocks.board_world.BoardWorld`, :class:`mocks.mirror_world.MirrorWorld`) are photographed at
    :data:`TARGET_BINNING` times it, through the same simulated camera.
    """
    from app.demo.station import MIRROR_OFFSET_MM, MIRROR_RADIUS_MM
    from mocks.world import STATION_CHART_LAYOUT, World

    w, h = image_size
    if name == SIMULATED_OBJECTS[0]:
        return World.hawk(triangles, width=w, height=h, chart_layout=STATION_CHART_LAYOUT)
    if name == SIMULATED_OBJECTS[1]:
        return World.calibration_sphere(25.0, 60.0, width=w, height=h, chart_layout=STATION_CHART_LAYOUT)
    if name == SIMULATED_OBJECTS[2]:
        from mocks.board_world import BoardWorld

        return BoardWorld.charuco(width=w * TARGET_BINNING, height=h * TARGET_BINNING)
    if name == SIMULATED_OBJECTS[3]:
        from mocks.mirror_world import MirrorWorld

        return MirrorWorld.mirror_sphere(MIRROR_RADIUS_MM, MIRROR_OFFSET_MM, width=w * TARGET_BINNING,
                                         height=h * TARGET_BINNING)
    raise ValueError(f"unknown simulated object {name!r}; choose one of: {', '.join(SIMULATED_OBJECTS)}")


def station_frame_size(world: Any) -> tuple[int, int]:
    """The station's frame size (the piece's photos) of a simulated world on its table."""
    if _is_target(world):
        return world.width // TARGET_BINNING, world.height // TARGET_BINNING
    return world.width, world.height


def _is_target(world: Any) -> bool:
    """A camera or lamp calibration target (board, chrome sphere), photographed at full resolution."""
    return (world.mesh_source or "").startswith(("board:", "mirror:"))


#: The capture plan that goes with each simulated object.
_PLAN_OF = dict(zip(SIMULATED_OBJECTS, ("scan", "sphere-calibration", "camera-calibration", "lamp-calibration"),
                    strict=True))


def _object_label(world: Any) -> str:
    source = world.mesh_source or ""
    if source.startswith("sphere:"):
        _, r, off = source.split(":")
        return f"the calibration sphere (radius {r} mm, {off} mm off the axis)"
    if source.startswith("board:"):
        b = world.board
        return f"the ChArUco board ({b['squares_x']} x {b['squares_y']} squares of {b['square_mm']:g} mm)"
    if source.startswith("mirror:"):
        _, r, off = source.split(":")
        return f"the chrome sphere (radius {r} mm, {off} mm off the axis)"
    return "the hawk head" if "head" in world.region_names else f"the object {source or '(inline mesh)'}"


class _LogHandler(logging.Handler):
    def __init__(self, window: MainWindow) -> None:
        super().__init__(logging.INFO)
        self.window = window

    def emit(self, record: logging.LogRecord) -> None:
        # records can come from worker threads: only the first line, through the queued log signal
        self.window.link.log.emit(record.getMessage().splitlines()[0])


class MainWindow(QMainWindow):
    """See the module docstring.

    Parameters
    ----------
    settings
        A :class:`QSettings` to use (tests pass one backed by a temporary file).
    """

    def __init__(self, settings: QSettings | None = None, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        # Worker threads (capture, drawing, reading) share the interpreter lock with this thread; a short
        # switch interval (default 5 ms) hands it back to the event loop sooner when they are busy.
        sys.setswitchinterval(min(sys.getswitchinterval(), 0.001))
        warm_up()                                    # first uses that hold the interpreter lock, before showing
        freeze_heap()                                # and keep the start-up heap out of later full collections
        self.setWindowTitle("kogei — capture station")
        self.settings = settings or QSettings(SETTINGS_ORG, SETTINGS_APP)
        self.station: Any = None                     # a simulated station started by the window
        self.device_lane = Lane(1)                   # every serial operation, in order
        self.work_lane = Lane(2)                     # reading sessions, thumbnails, decoding, renders
        self.drawer = FigureDrawer()                 # figures, drawn in a worker process (app.gui.plots)
        self.drawer.start()
        self._wire_tmp = tempfile.TemporaryDirectory(prefix="kogei-gui-wire-")
        self.link = StationLink(self.device_lane, Path(self._wire_tmp.name), self)

        central = QWidget()
        v = QVBoxLayout(central)
        from app.gui.guidance import STEPS

        self.steps = StepStrip(STEPS)
        v.addWidget(self.steps)
        self.banner = Banner()
        v.addWidget(self.banner)
        err_row = QHBoxLayout()
        self.error_line = QLabel()
        self.error_line.setWordWrap(True)
        self.error_line.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.error_line.setStyleSheet("color:#7a1512; background:#fff0ef; padding:4px;")
        self.error_dismiss = QPushButton("Dismiss")
        self.error_dismiss.setToolTip("hide this message (it stays in the log)")
        self.error_dismiss.clicked.connect(lambda: self.show_error(""))
        err_row.addWidget(self.error_line, 1)
        err_row.addWidget(self.error_dismiss)
        v.addLayout(err_row)
        self.message_kind = ""                       # "error", "info" or "" (nothing shown)
        self._message_source: Any = None
        self.show_error("")
        self.tabs = QTabWidget()
        self.tabs.currentChanged.connect(self._tab_changed)
        v.addWidget(self.tabs, 1)
        self.setCentralWidget(central)

        self.devices = DevicesPanel(self.link)
        self.session = SessionPanel(self.work_lane)
        self.processing = ProcessingPanel(self.work_lane, lambda: self.session.root, self.drawer)
        self.capture = CapturePanel(self.link, lambda: self.session.root, self.session.metadata,
                                    self.processing.calibration_source, self.drawer, self.devices.apply)
        self.camera = CameraPanel(self.link, self.work_lane, self.drawer, lambda: self.session.root)
        self.spectra = SpectraPanel(self.work_lane, self.drawer, lambda: self.session.root,
                                    catalogue=lambda: self.session.metadata().get("materials", ""))
        self.camera.corners_marked.connect(self.spectra.set_chart_corners)
        self.preview = PreviewPanel(self.work_lane, lambda: self.session.root, self.drawer)
        for panel, title in ((self.devices, "Devices"), (self.session, "Session"), (self.capture, "Capture"),
                             (self.camera, "Camera"), (self.processing, "Processing"),
                             (self.spectra, "Spectra and materials"), (self.preview, "Preview")):
            self.tabs.addTab(panel, title)
            if hasattr(panel, "error"):
                panel.error.connect(lambda text, p=panel: self.show_error(text, source=p))
            if isinstance(panel, Panel):
                panel.notice.connect(lambda text, p=panel: self.show_info(text, source=p))
            if hasattr(panel, "log"):
                panel.log.connect(self.append_log)

        self.log_view = QPlainTextEdit()
        self.log_view.setReadOnly(True)
        self.log_view.setMaximumBlockCount(5000)
        dock = QDockWidget("Log", self)
        dock.setObjectName("log-dock")
        dock.setWidget(self.log_view)
        self.addDockWidget(Qt.DockWidgetArea.BottomDockWidgetArea, dock)
        self.resizeDocks([dock], [150], Qt.Orientation.Vertical)
        self.log_dock = dock

        self.link.log.connect(self.append_log)
        self.link.banner.connect(self.banner.show_text)
        self.link.state.connect(self._state_changed)
        self.devices.simulated_requested.connect(lambda: self.run_safely(self.start_simulated_station_async))
        self.devices.object_requested.connect(lambda name: self.run_safely(lambda: self.put_simulated_object(name)))
        self.session.session_chosen.connect(self._session_chosen)
        self.capture.capture_started.connect(lambda: setattr(self.session, "capturing", True))
        self.capture.capture_started.connect(lambda: self.remember_session(self.session.root))
        self.capture.capture_stopped.connect(self._capture_stopped)
        self._refresh_counter = 0
        self.capture.progress.valueChanged.connect(self._maybe_refresh_session)
        self.processing.processed.connect(self._processed)
        self.processing.materials_measured.connect(self._materials_measured)
        # every re-read of the session (after processing, a capture) says whether its photos are posed yet
        self.session.manifest_shown.connect(
            lambda: self.processing.show_materials_state(self.session.root, self.session.manifest))
        self.steps.step_clicked.connect(self._show_step)
        for sig in (self.link.state, self.session.session_chosen, self.session.manifest_shown,
                    self.capture.capture_started, self.capture.capture_stopped,
                    self.processing.processed, self.processing.materials_measured, self.spectra.map_ready,
                    self.processing.calibration.textChanged, self.processing.camera_cal.textChanged,
                    self.processing.lamp_cal.textChanged):
            sig.connect(lambda *_: self.update_steps())
        self.update_steps()
        self.statusBar().showMessage("ready")
        self._log_handler = _LogHandler(self)
        logging.getLogger("kogei.gui").addHandler(self._log_handler)
        logging.getLogger("kogei.gui").setLevel(logging.INFO)
        self._shortcuts()
        self._menu()
        self.restore_settings()
        self.resize(1280, 860) if not self.settings.value("geometry") else None
        self.reopen_last_session()

    # ------------------------------------------------------------ errors and log
    #: Style of the message line: an error (red) or information for the user (blue).
    MESSAGE_STYLES = {"error": "color:#7a1512; background:#fff0ef; padding:4px;",
                      "info": "color:#123f6e; background:#eaf3fc; padding:4px;"}

    def show_error(self, text: str, source: Any = None) -> None:
        """Show a readable error above the tabs ('' hides it) and write it to the log.

        ``source``: the panel it came from; the message is cleared when
        another tab is shown (it stays in the log).
        """
        self._message(text, "error", source)

    def show_info(self, text: str, source: Any = None) -> None:
        """As :meth:`show_error`, for information that is not a fault (a stop the user asked for)."""
        self._message(text, "info", source)

    def _message(self, text: str, kind: str, source: Any) -> None:
        self.error_line.setText(text)
        self.error_line.setStyleSheet(self.MESSAGE_STYLES[kind])
        self.error_line.setVisible(bool(text))
        self.error_dismiss.setVisible(bool(text))
        self.message_kind = kind if text else ""
        self._message_source = source if text else None
        if text:
            self.append_log(f"{'ERROR' if kind == 'error' else 'NOTE'}: {text}")
            self.statusBar().showMessage(text.splitlines()[0], 15_000)

    def _tab_changed(self, index: int) -> None:
        # a panel's message belongs to its tab: it would read as being about the tab now shown
        if self._message_source is not None and self.tabs.widget(index) is not self._message_source:
            self._message("", "error", None)

    def append_log(self, text: str) -> None:
        import time

        self.log_view.appendPlainText(f"{time.strftime('%H:%M:%S')}  {text}")

    def run_safely(self, fn: Any) -> None:
        from app.gui.workers import describe_error

        try:
            fn()
        except Exception as exc:  # noqa: BLE001 - shown in the window
            self.show_error(describe_error(exc))

    # ------------------------------------------------------------ shortcuts, menu
    def _shortcuts(self) -> None:
        def key(seq: Any, fn: Any) -> None:
            sc = QShortcut(QKeySequence(seq), self)
            sc.activated.connect(self.capture.safe(fn))

        cap = self.capture
        key(Qt.Key.Key_F5, lambda: cap.start_capture() if cap.start.isEnabled() else None)
        key(Qt.Key.Key_F6, cap.toggle_pause)
        key(Qt.Key.Key_Escape, cap.abort_capture)
        key(Qt.Key.Key_Return, cap.answer_prompt)
        key(Qt.Key.Key_Enter, cap.answer_prompt)
        key("Ctrl+Left", lambda: cap.jog("move", cap.angle.value() - cap.step_size.value()))
        key("Ctrl+Right", lambda: cap.jog("move", cap.angle.value() + cap.step_size.value()))
        key("Ctrl+0", lambda: cap.jog("zero"))
        key("Ctrl+L", lambda: cap.jog("laser", 1))
        key("Ctrl+Shift+L", lambda: cap.jog("laser", 0))
        for i in range(7):
            sc = QShortcut(QKeySequence(f"Ctrl+{i + 1}"), self)
            sc.activated.connect(lambda i=i: self.tabs.setCurrentIndex(i))

    def _menu(self) -> None:
        f = self.menuBar().addMenu("&File")
        act = QAction("Open session…", self)
        act.setShortcut(QKeySequence.StandardKey.Open)
        act.triggered.connect(lambda: self.run_safely(self._open_session_dialog))
        f.addAction(act)
        self.recent_menu = f.addMenu("Recent sessions")
        self.recent_menu.aboutToShow.connect(self._fill_recent_menu)
        self._fill_recent_menu()
        m = self.menuBar().addMenu("&Station")
        act = QAction("Connect all instruments", self)
        act.triggered.connect(lambda: self.run_safely(self.devices.connect_all))
        m.addAction(act)
        act = QAction("Start a simulated station", self)
        act.triggered.connect(lambda: self.run_safely(self.start_simulated_station_async))
        m.addAction(act)
        m.addSeparator()
        act = QAction("Quit", self)
        act.setShortcut(QKeySequence.StandardKey.Quit)
        act.triggered.connect(self.close)
        m.addAction(act)
        view = self.menuBar().addMenu("&View")
        view.addAction(self.log_dock.toggleViewAction())
        help_menu = self.menuBar().addMenu("&Help")
        act = QAction("Steps of a session", self)
        act.triggered.connect(self.show_steps_help)
        help_menu.addAction(act)
        act = QAction("About kogei", self)
        act.triggered.connect(self.show_about)
        help_menu.addAction(act)

    def steps_help_text(self) -> str:
        """The steps of a session, each with what to do there (the Help menu)."""
        from app.gui.guidance import STEPS, step_hint

        return "\n".join(f"{i}. {step}: {step_hint(step)}" for i, step in enumerate(STEPS, start=1))

    def show_steps_help(self) -> None:
        from PySide6.QtWidgets import QMessageBox

        QMessageBox.information(self, "Steps of a session", self.steps_help_text())

    def about_text(self) -> str:
        from importlib.metadata import PackageNotFoundError, version

        try:
            v = version("kogei")
        except PackageNotFoundError:
            v = "(not installed)"
        return (f"kogei {v}: the capture station for museum objects -- turntable and laser profiler scans, RAW "
                "photos calibrated with a colour chart, spectral reflectance and metal identification, spectral "
                "rendering.  The documentation is in the repository's README.md and docs/.")

    def show_about(self) -> None:
        from PySide6.QtWidgets import QMessageBox

        QMessageBox.about(self, "About kogei", self.about_text())

    # ------------------------------------------------------------ simulated station
    def start_simulated_station(self, triangles: int = 4000, seed: int = 0, image_size: tuple[int, int] = (240, 160),
                                root: str | Path | None = None, n_points: int = 320, world: Any = None,
                                time_scale: float = 0.0) -> Any:
        """Start :class:`mocks.station.SimulatedStation` in this process and point the Devices tab at it
        (``time_scale``: real seconds per simulated second of the table's motion; 0, instant)."""
        from mocks.station import SimulatedStation
        from mocks.world import World

        if self.station is not None:
            raise ValueError("a simulated station is already running in this window")
        if world is None:
            from mocks.world import STATION_CHART_LAYOUT

            world = World.hawk(triangles, width=image_size[0], height=image_size[1], chart_layout=STATION_CHART_LAYOUT)
        st = SimulatedStation(world, root=root, seed=seed, n_points=n_points, time_scale=time_scale)
        st.start()
        return self._attach_station(st)

    def start_simulated_station_async(self) -> None:
        """The Devices tab's button: build the simulated world and start the station on a worker thread."""
        if self.station is not None or getattr(self, "_station_starting", False):
            raise ValueError("a simulated station is already running in this window")
        self._station_starting = True
        self.devices.sim_state.setText("starting (building the simulated world)…")

        name = self.devices.sim_object.currentText()

        def work(ctx: Any) -> Any:
            from mocks.station import SimulatedStation

            return SimulatedStation(simulated_world(name), n_points=320).start()

        def done(st: Any) -> None:
            self._station_starting = False
            self._attach_station(st)

        def failed(text: str, exc: Any) -> None:
            self._station_starting = False
            self.devices.sim_state.setText("none")
            self.show_error(f"simulated station: {text}")

        self.work_lane.run(work, "start simulated station", succeeded=done, failed=failed)

    def put_simulated_object(self, name: str) -> None:
        """The Devices tab's "Put on the table": swap the simulated station's object (on a worker thread)."""
        from app.errors import UsageError

        st = self.station
        if st is None:
            raise UsageError("no simulated station runs in this window: start one first")
        if self.capture.job is not None and not self.capture.job.done:
            raise UsageError("a capture is running: the object stays on the table until it ends")
        size = station_frame_size(st.world)
        self.devices.put_button.setEnabled(False)
        self.devices.sim_state.setText(f"putting the {name} on the table…")

        def work(ctx: Any) -> Any:
            return st.put_object(simulated_world(name, image_size=size))

        def done(pose: Any) -> None:
            self.devices.put_button.setEnabled(True)
            self._describe_station(st)
            self.append_log(f"simulated station: the {name} is on the table")
            # the plan that goes with what is on the table: a calibration target's plan, or the piece's scan
            kind = _PLAN_OF[name]
            if self.capture.kind.currentText() != kind and self.capture.start.isEnabled():
                self.capture.kind.setCurrentText(kind)
                self.append_log(f"capture plan: {kind} (for the {name})")
            if kind == "lamp-calibration":
                self.capture.mirror_radius.setValue(float(st.world.sphere_radius_mm))

        def failed(text: str, exc: Any) -> None:
            self.devices.put_button.setEnabled(True)
            self._describe_station(st)
            self.show_error(f"simulated station: {text}")

        self.work_lane.run(work, "put the object on the table", succeeded=done, failed=failed)

    def _describe_station(self, st: Any) -> None:
        self.devices.sim_state.setText(f"running in this window: {st.root} with {_object_label(st.world)} on the "
                                       "table (its ports are filled in above)")
        self.devices.sim_state.setToolTip(f"turntable {st.turntable_path}, profiler {st.profiler_path}, "
                                          f"gphoto2 {st.gphoto2_path}")

    def _attach_station(self, st: Any) -> Any:
        """Point the Devices tab at a running simulated station (ports, gphoto2 shim, placements)."""
        self.station = st
        self.link.placer = st.place
        self.link.shutter = st.shoot
        self.devices.set_port("turntable", str(st.turntable_path))
        self.devices.set_port("profiler", str(st.profiler_path))
        self.devices.camera_kind.setCurrentText("gphoto2")
        self.devices.camera_path.setText(str(st.gphoto2_path))
        self._describe_station(st)
        self.devices.put_button.setEnabled(True)
        self.devices.start_sim_button.setEnabled(False)          # one simulated station per window
        self.devices.apply()
        self.append_log(f"simulated station started in {st.root}")
        return st

    # ------------------------------------------------------------ state
    # ------------------------------------------------------------ guidance
    def steps_done(self) -> dict[str, bool]:
        """What has been done, as :func:`app.gui.guidance.current_step` reads it."""
        root = self.session.root
        manifest = self.session.manifest if root is not None else None
        plan = manifest.get("plan") if isinstance(manifest, dict) else None
        kind = plan.get("kind") if isinstance(plan, dict) else None
        target = kind if kind in ("camera-calibration", "lamp-calibration") else None
        target_captured = bool(target and manifest.get("status") == "complete")
        if isinstance(plan, dict) and kind != "scan":
            # a calibration (or swatch, probe) session is not the piece's: the piece's session comes next
            root, manifest = None, None
        products = Path(root) / "products" if root is not None else None
        return {
            "devices": all(self.link.states.get(n) in ("connected", "capture") for n in ("turntable", "profiler")),
            "calibrated": bool(self.processing.calibration_source())
            or bool(products is not None and (Path(root) / "calibration.json").exists()),
            "session": root is not None,
            "captured": bool(manifest and manifest.get("status") == "complete"),
            "processed": bool(products is not None and (products / "mesh.ply").exists()),
            "materials": self.spectra.map is not None
            or bool(products is not None and (products / "object-mesh.ply").exists()),
            "camera": bool(self.processing.camera_cal.text().strip()),
            "lamps": bool(self.processing.lamp_cal.text().strip()),
            "target": target,
            "target_captured": target_captured,
        }

    def update_steps(self) -> None:
        """Highlight the next step of the strip and say what to do there."""
        from app.gui.guidance import calibration_hint, current_step, step_hint

        done = self.steps_done()
        step = current_step(done)
        if self.capture.job is not None and not self.capture.job.done:
            step = "Calibrate" if done["target"] else step
            if step in ("Capture", "Calibrate"):
                self.steps.set_current(step, "Now: the capture runs; answer its prompts to re-place the object")
                return
        extra = calibration_hint(done)
        if done["target"] and extra:
            # a board or chrome-sphere session is open: its calibration is the step at hand
            self.steps.set_current("Calibrate", f"Next: {extra}")
        elif extra and step == "Session":
            self.steps.set_current(step, f"Next: {extra}, or name the piece and press 'New session'")
        else:
            self.steps.set_current(step, f"Next: {step_hint(step)}")

    def _show_step(self, step: str) -> None:
        tabs = {"Devices": self.devices, "Calibrate": self.processing, "Session": self.session,
                "Capture": self.capture, "Process": self.processing, "Materials": self.spectra,
                "Preview": self.preview}
        if step == "Materials" and self.processing.materials_button.isEnabled():
            tabs[step] = self.processing             # the photos are posed: measure the materials on the mesh
        self.tabs.setCurrentWidget(tabs[step])

    def _state_changed(self, name: str, state: str, detail: str) -> None:
        summary = " · ".join(f"{n}: {self.link.states.get(n)}" for n in INSTRUMENTS)
        self.statusBar().showMessage(summary, 5000)

    # ------------------------------------------------------------ recent sessions
    def recent_sessions(self) -> list[str]:
        """The recent sessions' folders, the latest first (as stored in the settings)."""
        value = self.settings.value("session/recent", [])
        if isinstance(value, str):                  # an ini file gives a one-item list back as its item
            value = [value]
        return [str(v) for v in (value or []) if str(v)]

    def _set_recent(self, items: list[str]) -> None:
        self.settings.setValue("session/recent", items[:MAX_RECENT])
        self._fill_recent_menu()

    def remember_session(self, root: Any) -> None:
        """Put the session ``root`` first in File > Recent sessions (once it exists on disk)."""
        if root is None or not (Path(root) / "session.json").is_file():
            return
        text = str(Path(root))
        self._set_recent([text] + [r for r in self.recent_sessions() if r != text])

    def _forget_session(self, text: str) -> None:
        self._set_recent([r for r in self.recent_sessions() if r != text])
        if str(self.settings.value("session/last", "") or "") == text:
            self.settings.setValue("session/last", "")

    def open_recent(self, text: str) -> None:
        """Open a session of the recent list; one no longer there is said so and taken off the list."""
        from app.errors import UsageError

        if not (Path(text) / "session.json").is_file():
            self._forget_session(text)
            raise UsageError(f"the session {text} is no longer there (moved or deleted?); it was taken off the "
                             "recent sessions: open it where it is now with File > Open session…")
        self.session.open_session(text)

    def reopen_last_session(self) -> None:
        """Reopen the session the window had open when it was closed (start-up)."""
        last = str(self.settings.value("session/last", "") or "")
        if not last:
            return
        if (Path(last) / "session.json").is_file():
            self.run_safely(lambda: self.session.open_session(last))
            if self.session.root is not None and str(self.session.root) == last:
                self.show_info(f"reopened the last session, {last} (File > Recent sessions lists the others)")
        elif last in self.recent_sessions():       # a session that was there and is gone
            self._forget_session(last)
            self.show_info(f"the last session, {last}, is no longer there (moved or deleted?); it was taken off "
                           "the recent sessions")

    def _fill_recent_menu(self) -> None:
        menu = self.recent_menu
        menu.clear()
        items = self.recent_sessions()
        for text in items:
            there = (Path(text) / "session.json").is_file()
            act = menu.addAction(text if there else f"{text}  (not found)")
            act.setToolTip("open this session" if there else "moved or deleted: choosing it takes it off the list")
            act.triggered.connect(lambda _=False, t=text: self.run_safely(lambda: self.open_recent(t)))
        if not items:
            menu.addAction("(none yet)").setEnabled(False)
        else:
            menu.addSeparator()
            menu.addAction("Clear the list").triggered.connect(lambda: self._set_recent([]))

    def _open_session_dialog(self) -> None:
        from PySide6.QtWidgets import QFileDialog

        path = QFileDialog.getExistingDirectory(self, "Open a session folder", self.session.folder.text())
        if path:
            self.session.open_session(path)

    def _session_chosen(self, root: Any) -> None:
        self.settings.setValue("session/last", str(root) if root else "")
        self.remember_session(root)
        manifest = self.session.manifest
        if manifest is not None:
            self.capture.set_plan(manifest.get("plan", {}))
        self.processing.show_station(manifest)
        self.processing.show_materials_state(root, manifest)
        self.processing.show_mesh(root)              # the session's mesh, or that it has none yet
        # what the tabs show of the previous session goes; the Preview shows this session's mesh if it has one
        self.camera.refresh_charts()
        self.spectra.forget()
        if root and (Path(root) / "products" / "mesh.ply").exists():
            self.run_safely(self.preview.mesh_changed)
        try:
            self.camera.refresh_posed()
        except Exception as exc:  # noqa: BLE001 - a damaged product must not stop the session from opening
            self.camera.state.setText(f"posed frames not listed: {exc}")
        self.setWindowTitle(f"kogei — capture station — {root}")

    def _maybe_refresh_session(self, value: int) -> None:
        # the session list follows a running capture at most once every 10 steps
        self._refresh_counter += 1
        if self._refresh_counter % 10 == 0:
            self.session.refresh()

    def _capture_stopped(self, status: str) -> None:
        self.session.capturing = False
        self.session.refresh()
        self.remember_session(self.session.root)
        self.statusBar().showMessage(f"capture {status}", 10_000)

    def _processed(self, report: Any) -> None:
        self.session.refresh()
        self.run_safely(self.preview.mesh_changed)

    def _materials_measured(self, doc: Any) -> None:
        # the session is re-read: the Preview takes the measured object (products/object-mesh.ply)
        self.session.refresh()
        self.run_safely(self.preview.mesh_changed)

    # ------------------------------------------------------------ settings
    def restore_settings(self) -> None:
        s = self.settings
        geo = s.value("geometry")
        if geo is not None:
            self.restoreGeometry(geo)
        state = s.value("windowState")
        if state is not None:
            self.restoreState(state)
        for name in INSTRUMENTS:
            port = s.value(f"ports/{name}", "")
            if port:
                self.devices.set_port(name, str(port))
        kind = s.value("camera/kind", "")
        if kind:
            self.devices.camera_kind.setCurrentText(str(kind))
        self.devices.camera_path.setText(str(s.value("camera/path", "") or ""))
        self.devices.control_dir.setText(str(s.value("station/control", "") or ""))
        self.session.folder.setText(str(s.value("session/last", "") or ""))
        self.processing.calibration.setText(str(s.value("processing/calibration", "") or ""))
        self.tabs.setCurrentIndex(int(s.value("tab", 0) or 0))

    def save_settings(self) -> None:
        s = self.settings
        s.setValue("geometry", self.saveGeometry())
        s.setValue("windowState", self.saveState())
        for name in INSTRUMENTS:
            s.setValue(f"ports/{name}", self.devices.port(name))
        s.setValue("camera/kind", self.devices.camera_kind.currentText())
        s.setValue("camera/path", self.devices.camera_path.text())
        s.setValue("station/control", self.devices.control_dir.text())
        s.setValue("processing/calibration", self.processing.calibration.text())
        s.setValue("tab", self.tabs.currentIndex())
        s.sync()

    def shutdown(self) -> None:
        """Stop the capture and the workers, close the instruments and the simulated station."""
        self.capture.abort_capture()
        self.processing.cancel()
        self.processing.cancel_materials()
        final = getattr(self.preview, "_process_job", None)
        if final is not None and not final.done:
            final.cancel()                   # a full-size preview render in its worker process
        self.preview.render_worker.stop()    # the process the preview's full-size renders run in
        mesh_view = self.processing.mesh_job
        if mesh_view is not None and not mesh_view.done:
            mesh_view.cancel()               # the Processing tab's mesh view, rendering in its worker process
        self.device_lane.wait(30_000)
        self.work_lane.wait(30_000)
        self.drawer.shutdown(30_000)
        # deliver the finished jobs' results (a simulated station that finished starting is stopped below)
        QCoreApplication.processEvents()
        self.link.shutdown()
        if self.station is not None:
            self.station.stop()
            self.station = None
        logging.getLogger("kogei.gui").removeHandler(self._log_handler)
        self._wire_tmp.cleanup()

    def closeEvent(self, event: Any) -> None:  # noqa: N802 - Qt's name
        self.save_settings()
        self.shutdown()
        super().closeEvent(event)
