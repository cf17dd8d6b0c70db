"""Capture panel: turntable jog, laser, the scan plan, start / pause / abort with progress and ETA,
the live profile plot, the growing point cloud and the "re-place the object" step between passes.

A thin shell over :func:`app.capture.runner.run_capture` (the engine ``kogei
capture`` runs), on the instruments' lane of :class:`app.gui.station_link.StationLink`:

* a new session is created with :meth:`app.session.Session.create` (plan,
  object metadata, device configuration), an interrupted one is resumed with
  its own plan (ports may be changed, as ``kogei capture --resume``); Start
  checks the tabs' choices at once, and the session is then created or
  opened on the instruments' lane, since that writes and syncs files;
* the engine's ``before_pass`` hook waits for the technician's *Continue* in
  the window (:class:`PromptGate`); with a simulated station the station is
  then told to re-place the object;
* *Pause* holds the capture at the next step boundary (the progress hook
  waits); *Abort* sets the engine's cancel event, so the session stops
  consistent and resumable at the next step;
* each finished profile is read back from the session for the live plot;
  the pass's profiles become points with the chosen scanner calibration
  (:func:`processing.geometry.scan_points.profiles_to_points`), or a range image when
  there is none.

Examples
--------
>>> format_eta(None), format_eta(42.4), format_eta(3725)
('ETA –', 'ETA 42 s', 'ETA 1 h 02 min')
>>> parse_angles("0, 90,180")
(0.0, 90.0, 180.0)
>>> describe_action("p01/profile/0018"), describe_action("p02/chart"), describe_action("p03/frame/04")
('laser profile 19', 'photo of the colour chart', 'photo 5')
"""

from __future__ import annotations

import math
import re
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from PySide6.QtCore import QObject, Qt, QTimer, Signal
from PySide6.QtWidgets import (
    QCheckBox,
    QComboBox,
    QDoubleSpinBox,
    QFormLayout,
    QFrame,
    QGridLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QProgressBar,
    QPushButton,
    QScrollArea,
    QSpinBox,
    QSplitter,
    QVBoxLayout,
    QWidget,
)

from app.gui.figures import cloud_figure, empty_figure, profile_figure
from app.gui.plots import FigureDrawer, PlotImage
from app.gui.station_link import StationLink
from app.gui.widgets import Panel, WrapLabel
from app.gui.workers import Job, JobContext

__all__ = ["CapturePanel", "CaptureNotStarted", "PromptGate", "open_capture_session", "format_eta", "parse_angles",
           "describe_action", "completion_text", "MIRROR_KINDS"]

#: Plans of a mirror (chrome) sphere: their plan records the sphere's radius.
MIRROR_KINDS = ("lamp-calibration", "probe")


def describe_action(action: str) -> str:
    """A capture step's id (``p01/profile/0018``) as the user reads it (numbered from 1); others unchanged."""
    parts = action.split("/")
    if len(parts) >= 2 and re.fullmatch(r"p\d+", parts[0]):
        if parts[1] == "chart":
            return "photo of the colour chart" + (f" {int(parts[2]) + 1}" if len(parts) > 2 else "")
        if len(parts) == 3 and parts[2].isdigit():
            what = {"profile": "laser profile", "frame": "photo"}.get(parts[1], parts[1])
            return f"{what} {int(parts[2]) + 1}"
    return action


def completion_text(taken: int, skipped: int, recoveries: int, elapsed_s: float) -> str:
    """The line shown when a capture completes, in plain words.

    >>> completion_text(279, 0, 0, 56.04)
    'complete: 279 captures in 56 s'
    >>> completion_text(40, 20, 1, 30.0)
    'complete: 40 captures in 30 s, 20 kept from before the interruption, 1 instrument drop-out recovered'
    """
    text = f"complete: {taken} captures in {elapsed_s:.0f} s"
    if skipped:
        text += f", {skipped} kept from before the interruption"
    if recoveries:
        text += f", {recoveries} instrument drop-out{'s' if recoveries > 1 else ''} recovered"
    return text


def format_eta(seconds: float | None) -> str:
    """Remaining time for the progress line."""
    if seconds is None or not math.isfinite(seconds):
        return "ETA –"
    s = int(round(seconds))
    if s < 60:
        return f"ETA {s} s"
    if s < 3600:
        return f"ETA {s // 60} min {s % 60:02d} s"
    return f"ETA {s // 3600} h {(s % 3600) // 60:02d} min"


def parse_angles(text: str) -> tuple[float, ...]:
    """Camera angles typed as degrees separated by commas (ValueError naming the field otherwise)."""
    from app.capture.runner import parse_camera_angles

    return parse_camera_angles(text)


class PromptGate(QObject):
    """A question from the capture thread that the technician answers in the window.

    :meth:`ask` (capture thread) emits ``asked(text)`` and waits for
    :meth:`answer` (GUI thread); the cancel event ends the wait too.
    """

    asked = Signal(str)

    def __init__(self, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self._event = threading.Event()
        self._go = False
        self.pending = False

    def ask(self, text: str, cancel: threading.Event) -> bool:
        self._event.clear()
        self._go = False
        self.pending = True
        self.asked.emit(text)
        while not self._event.wait(0.05):
            if cancel.is_set():
                self.pending = False
                return False
        self.pending = False
        return self._go

    def answer(self, go: bool) -> None:
        self._go = bool(go)
        self._event.set()


class CapturePanel(Panel):
    """See the module docstring.

    Parameters
    ----------
    link
        The instruments.
    session_root
        Returns the session folder chosen on the Session tab (or None).
    metadata
        Returns the object metadata of the Session tab.
    calibration
        Returns the scanner calibration source (session folder or JSON), or None.
    drawer
        Draws the figures (in its own process).
    apply_devices
        Copies the Devices tab's choices into ``link`` before a capture starts.
    """

    capture_started = Signal()
    capture_stopped = Signal(str)         # 'complete', 'interrupted', 'cancelled', 'not started'
    note = Signal(str)
    _opened = Signal(object)              # the capture's plan, once its session is open (from the lane)

    def __init__(self, link: StationLink, session_root: Callable[[], Path | None],
                 metadata: Callable[[], dict[str, str]], calibration: Callable[[], str | None],
                 drawer: FigureDrawer, apply_devices: Callable[[], None] | None = None,
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.link = link
        self.apply_devices = apply_devices
        self.session_root = session_root
        self.metadata = metadata
        self.calibration = calibration
        self.gate = PromptGate(self)
        self.gate.asked.connect(self._show_prompt)
        self._opened.connect(self._on_opened)
        self.job: Job | None = None
        self.pause_event = threading.Event()
        self.last_progress: Any = None
        self.status_text = "idle"
        self._root: Path | None = None
        self._pending_profile: str | None = None
        self.profile_caption = ""
        self.cloud_caption = ""
        self._cloud_pass_no: int | None = None
        self._cloud_dirty = False
        self._pass_profiles: dict[int, dict[int, tuple[float, np.ndarray, np.ndarray]]] = {}
        self._cal_cache: tuple[str, Any] | None = None
        self._reconnect: list[str] = []

        outer = QHBoxLayout(self)
        column = QWidget()                  # the controls scroll when the window is short (700 px high)
        left = QVBoxLayout(column)
        left.setContentsMargins(0, 0, 0, 0)
        self.controls_scroll = scroll = QScrollArea()
        scroll.setWidget(column)
        scroll.setWidgetResizable(True)
        scroll.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        scroll.setFrameShape(QFrame.Shape.NoFrame)
        outer.addWidget(scroll, 0)

        jog = QGroupBox("Turntable and laser")
        g = QGridLayout(jog)
        self.angle = QDoubleSpinBox()
        self.angle.setRange(-3600.0, 3600.0)
        self.angle.setDecimals(2)
        self.angle.setSuffix(" °")
        self.go = QPushButton("Go to")
        self.step_size = QDoubleSpinBox()
        self.step_size.setRange(0.1, 180.0)
        self.step_size.setValue(15.0)
        self.step_size.setSuffix(" °")
        self.minus = QPushButton("− step")
        self.plus = QPushButton("+ step")
        self.zero = QPushButton("Zero here")
        self.laser_on = QPushButton("Laser on")
        self.laser_off = QPushButton("Laser off")
        for w, tip in ((self.angle, "the table angle to go to (degrees)"),
                       (self.go, "turn the table to the angle (Ctrl+Left / Ctrl+Right step it)"),
                       (self.step_size, "how far one step turns the table (degrees)"),
                       (self.minus, "turn the table back by one step (Ctrl+Left)"),
                       (self.plus, "turn the table on by one step (Ctrl+Right)"),
                       (self.zero, "call the table's present position 0° (Ctrl+0)"),
                       (self.laser_on, "switch the profiler's laser line on (Ctrl+L)"),
                       (self.laser_off, "switch the laser line off (Ctrl+Shift+L)")):
            w.setToolTip(tip)
        self.position = QLabel("table: – (connect the turntable)")
        g.addWidget(QLabel("Angle"), 0, 0)
        g.addWidget(self.angle, 0, 1)
        g.addWidget(self.go, 0, 2)
        g.addWidget(QLabel("Step"), 1, 0)
        g.addWidget(self.step_size, 1, 1)
        row = QHBoxLayout()
        row.addWidget(self.minus)
        row.addWidget(self.plus)
        g.addLayout(row, 1, 2)
        g.addWidget(self.zero, 2, 0)
        g.addWidget(self.laser_on, 2, 1)
        g.addWidget(self.laser_off, 2, 2)
        g.addWidget(self.position, 3, 0, 1, 3)
        self.go.clicked.connect(self.safe(lambda: self.jog("move", self.angle.value())))
        self.minus.clicked.connect(self.safe(lambda: self.jog("move", self.angle.value() - self.step_size.value())))
        self.plus.clicked.connect(self.safe(lambda: self.jog("move", self.angle.value() + self.step_size.value())))
        self.zero.clicked.connect(self.safe(lambda: self.jog("zero")))
        self.laser_on.clicked.connect(self.safe(lambda: self.jog("laser", 1)))
        self.laser_off.clicked.connect(self.safe(lambda: self.jog("laser", 0)))
        left.addWidget(jog)

        plan = QGroupBox("Scan plan")
        f = QFormLayout(plan)
        self.kind = QComboBox()
        self.kind.addItems(["scan", "sphere-calibration", "swatch", "camera-calibration", "lamp-calibration", "probe"])
        self.kind.setToolTip("scan: profiles + RAW frames of the piece; sphere-calibration: one pass of profiles of "
                             "the reference sphere for the scanner calibration (no chart; photos only at the camera "
                             "angles given); swatch: RAW frames of a cloth swatch at every step; "
                             "camera-calibration: a ChArUco board at every step, flat then on wedges; "
                             "lamp-calibration: a mirror sphere at every step; probe: the colour chart, then 7 "
                             "exposure brackets of a mirror sphere (a light probe for kogei probe)")
        self.steps = QSpinBox()
        self.steps.setRange(1, 100_000)
        self.steps.setValue(200)
        self.passes = QSpinBox()
        self.passes.setRange(1, 99)
        self.passes.setValue(3)
        self.camera_angles = QLineEdit(",".join(f"{a:g}" for a in range(0, 360, 30)))
        self.chart = QCheckBox("colour chart first in every pass")
        self.chart.setToolTip("shoot a frame of the colour chart at the start of each pass: it calibrates the "
                              "colours of that pass's photos")
        self.steps.setToolTip("table steps per full turn: more steps, denser scan, longer capture")
        self.passes.setToolTip("how many times the object is scanned, re-placed between passes so that every "
                               "side is seen")
        self.camera_angles.setToolTip("table angles (degrees, comma-separated) at which a RAW photo is taken; for a "
                                      "sphere-calibration leave it empty unless the camera will be calibrated too "
                                      "(the sphere's photos tie the camera to the scanner)")
        self.chart.setChecked(True)
        self.mirror_radius = QDoubleSpinBox()
        self.mirror_radius.setRange(1.0, 500.0)
        self.mirror_radius.setDecimals(2)
        self.mirror_radius.setSuffix(" mm")
        self.mirror_radius.setValue(20.0)
        self.mirror_radius.setEnabled(False)
        self.mirror_radius.setToolTip("lamp-calibration and probe: the mirror (chrome) sphere's radius, from its "
                                      "certificate; recorded with the plan, the lamp calibration reads it")
        self.kind.currentTextChanged.connect(self._kind_defaults)
        f.addRow("Kind", self.kind)
        f.addRow("Steps per turn", self.steps)
        f.addRow("Passes", self.passes)
        f.addRow("Camera angles (°)", self.camera_angles)
        f.addRow("Mirror sphere radius", self.mirror_radius)
        f.addRow(self.chart)
        left.addWidget(plan)

        run = QGroupBox("Capture")
        v = QVBoxLayout(run)
        buttons = QHBoxLayout()
        self.start = QPushButton("Start  (F5)")
        self.start.setToolTip("start the capture, or go on with an interrupted one where it stopped")
        self.pause = QPushButton("Pause  (F6)")
        self.pause.setToolTip("hold the capture after the current step; press again to continue")
        self.abort = QPushButton("Abort  (Esc)")
        self.abort.setToolTip("stop after the current step; the session stays intact and Start goes on with it")
        self.start.clicked.connect(self.safe(self.start_capture))
        self.pause.clicked.connect(self.safe(self.toggle_pause))
        self.abort.clicked.connect(self.safe(self.abort_capture))
        for b in (self.start, self.pause, self.abort):
            buttons.addWidget(b)
        v.addLayout(buttons)
        self.progress = QProgressBar()
        self.progress.setFormat("%v / %m  (%p%)")
        self.eta = QLabel("ETA –")
        self.paused_label = QLabel("PAUSED — the capture holds after the current step; press Continue (F6) to go "
                                   "on, or Abort (Esc) to stop (the session stays resumable)")
        self.paused_label.setWordWrap(True)
        self.paused_label.setStyleSheet("background:#fff3c4; color:#5a4300; font-weight:bold; padding:4px; "
                                        "border:1px solid #d9a400;")
        self.paused_label.hide()
        self.action = QLabel("idle")
        self.action.setWordWrap(True)
        v.addWidget(self.progress)
        v.addWidget(self.paused_label)
        v.addWidget(self.eta)
        v.addWidget(self.action)
        self.prompt = QFrame()
        self.prompt.setStyleSheet("QFrame{background:#fff6d6; border:1px solid #d9a400;}")
        pl = QVBoxLayout(self.prompt)
        self.prompt_text = WrapLabel()
        self.prompt_text.setWordWrap(True)
        self.prompt_text.setStyleSheet("font-weight:bold; border:none;")
        prow = QHBoxLayout()
        self.prompt_go = QPushButton("Continue  (Enter)")
        self.prompt_go.setToolTip("done as asked: go on with the capture")
        self.prompt_stop = QPushButton("Stop here")
        self.prompt_stop.setToolTip("stop the capture here; the session stays intact and Start goes on with it")
        self.prompt_go.clicked.connect(lambda: self._answer(True))
        self.prompt_stop.clicked.connect(lambda: self._answer(False))
        prow.addWidget(self.prompt_go)
        prow.addWidget(self.prompt_stop)
        pl.addWidget(self.prompt_text)
        pl.addLayout(prow)
        self.prompt.hide()
        v.addWidget(self.prompt)
        left.addWidget(run)
        left.addStretch(1)
        scroll.setMinimumWidth(column.sizeHint().width() + 24)     # no horizontal scrolling

        plots = QSplitter(Qt.Orientation.Vertical)
        self.profile_plot = PlotImage(drawer)
        self.cloud_plot = PlotImage(drawer)
        plots.addWidget(self.profile_plot)
        plots.addWidget(self.cloud_plot)
        outer.addWidget(plots, 1)
        self._draw_empty()
        self._timer = QTimer(self)
        # the plots follow the capture at 2 Hz (the profile) and 0.5 Hz (the cloud) whatever its pace: each
        # drawing costs 0.1-0.3 s of a core, which the capture and the instruments' threads need too
        self._timer.setInterval(500)
        self._ticks = 0
        self._timer.timeout.connect(self._refresh_plots)
        self._set_running(False)
        self.link.state.connect(self._device_state)

    def _device_state(self, name: str, state: str, detail: str) -> None:
        """The table line follows the turntable: not connected, connected, or driven by the capture."""
        if name != "turntable":
            return
        if state == "connected" and not self.position.text().startswith("table at"):
            self.position.setText("table: connected (its position is confirmed at the first move or Zero here)")
        elif state == "disconnected":
            self.position.setText("table: – (connect the turntable)")

    # ------------------------------------------------------------ jog
    def jog(self, action: str, value: float = 0.0) -> None:
        if action == "move":
            self.angle.setValue(value)
        self.link.jog(action, value, done=self._jogged)

    def _jogged(self, angle: float) -> None:
        if self.job is not None and not self.job.done:
            return                  # a jog that ended as Start was pressed: the capture drives the table now
        self.position.setText(f"table at {angle:.2f}° (confirmed by the firmware)")

    # ------------------------------------------------------------ plan and session
    def plan(self) -> Any:
        from app.capture.runner import CapturePlan

        camera = self.link.camera.get("kind", "none") != "none"
        kind = self.kind.currentText()
        radius = float(self.mirror_radius.value()) if kind in MIRROR_KINDS else None
        return CapturePlan(kind, steps=int(self.steps.value()), passes=int(self.passes.value()),
                           camera_angles_deg=parse_angles(self.camera_angles.text()),
                           chart=self.chart.isChecked(), camera=camera, sphere_radius_mm=radius)

    def _kind_defaults(self, kind: str) -> None:
        """Show a plan kind's defaults (steps, passes, chart) when the technician picks it."""
        from app.capture.runner import PROFILE_KINDS, CapturePlan

        plan = CapturePlan(kind)
        self.steps.setValue(int(plan.steps))
        self.passes.setValue(int(plan.passes))
        self.chart.setChecked(bool(plan.chart))
        self.chart.setEnabled(kind != "sphere-calibration")       # the scanner calibration reads no chart
        self.camera_angles.setEnabled(kind in PROFILE_KINDS)
        self.mirror_radius.setEnabled(kind in MIRROR_KINDS)
        if kind in PROFILE_KINDS:
            self.camera_angles.setText(",".join(f"{a:g}" for a in plan.camera_angles_deg))

    def set_plan(self, plan: dict[str, Any]) -> None:
        """Show a session's plan (an opened session resumes with its own plan)."""
        self.kind.setCurrentText(str(plan.get("kind", "scan")))
        self.steps.setValue(int(plan.get("steps", 200)))
        self.passes.setValue(int(plan.get("passes", 3)))
        self.camera_angles.setText(",".join(f"{a:g}" for a in plan.get("camera_angles_deg", ())))
        self.chart.setChecked(bool(plan.get("chart", True)))
        radius = plan.get("sphere_radius_mm")
        if isinstance(radius, (int, float)) and not isinstance(radius, bool):
            self.mirror_radius.setValue(float(radius))

    def _capture_request(self) -> dict[str, Any]:
        """What Start asks for, checked on the GUI thread without touching the disk beyond a look.

        A new session's plan and device configuration come from the tabs; an existing session is resumed
        with its own plan, so only the Devices tab's choices are taken here.  The session itself is created or
        opened on the instruments' lane (:func:`open_capture_session`): that writes and syncs files, which on a
        busy disk takes longer than the window may wait.
        """
        from app.capture.runner import PROFILE_KINDS
        from app.errors import UsageError

        root = self.session_root()
        if root is None:
            raise UsageError("choose a session first (Session tab: New session, or Open / resume)")
        if self.apply_devices is not None:
            self.apply_devices()            # the Devices tab's current choices
        if (root / "session.json").exists():
            chosen = self.link.camera.get("kind", "none") != "none"
            return {"root": root, "resume": True, "ports": {n: self.link.ports.get(n) for n in ("turntable", "profiler")},
                    "camera": dict(self.link.camera) if chosen else None}
        try:
            plan = self.plan()
        except ValueError as exc:
            raise UsageError(str(exc)) from None
        config = self.link.device_config()
        missing = [n for n, need in (("turntable", True), ("profiler", plan.kind in PROFILE_KINDS))
                   if need and n not in config]
        if missing:
            raise UsageError(f"choose the {' and the '.join(missing)} port on the Devices tab")
        problem = self.link.camera_problem()
        if plan.camera and problem:
            raise UsageError(problem)
        if plan.kind not in PROFILE_KINDS and not plan.camera:
            raise UsageError(f"a {plan.kind} capture takes only RAW frames: choose a camera on the Devices tab")
        return {"root": root, "resume": False, "plan": plan, "config": config, "object": self.metadata()}

    # ------------------------------------------------------------ run
    def start_capture(self) -> None:
        from app.capture.devices import build_devices
        from app.capture.runner import (
            CaptureHooks,
            CaptureInterrupted,
            CaptureSettings,
            placement_prompt,
            run_capture,
        )
        from app.errors import UsageError

        if self.job is not None and not self.job.done:
            raise UsageError("a capture is already running")
        # a jog still under way finishes first: the instruments' lane runs one job at a time, in order
        request = self._capture_request()
        self._root = request["root"]
        self._pass_profiles.clear()
        self._cloud_pass_no = None
        self._cloud_dirty = False
        self._draw_empty()
        self.pause_event.clear()
        self._reconnect = self.link.release_for_capture()
        link, gate = self.link, self.gate
        simulated = link.placer is not None or bool(link.control_dir)
        pause = self.pause_event
        opened = self._opened

        def work(ctx: JobContext) -> Any:
            try:        # creating or opening the session writes and syncs files: here, not on the GUI thread
                session, plan, config = open_capture_session(request)
            except UsageError as exc:
                raise CaptureNotStarted(str(exc)) from None
            opened.emit(plan)
            chart_prompt = plan.camera and plan.chart and not simulated

            def before_pass(p: int, n: int) -> None:
                text = placement_prompt(plan.kind, p)
                what = text[0].upper() + text[1:]
                chart = " and put the colour chart in view of the camera" if plan.camera and plan.chart else ""
                if not gate.ask(f"Pass {p} of {n}: {what}{chart}, then press Continue.", ctx.cancel):
                    raise CaptureInterrupted(f"stopped before pass {p}; the session {session.root} is intact and "
                                             "resumable (Start resumes it)", session=session.root, reason="cancelled")
                done = link.place(p)
                if done:
                    ctx.message(f"pass {p}: {done}")

            def after_chart(p: int) -> None:
                if chart_prompt and not gate.ask("Chart frame taken: remove the chart from the view, then press "
                                                 "Continue.", ctx.cancel):
                    raise CaptureInterrupted("stopped after the chart frame; resumable", session=session.root,
                                             reason="cancelled")

            def progress(pr: Any) -> None:
                ctx.progress(pr)
                while pause.is_set() and not ctx.cancel.is_set():
                    time.sleep(0.05)

            try:
                devices = build_devices(config, session.root, shutter=link.shutter)
                hooks = CaptureHooks(before_pass=before_pass, after_chart=after_chart, progress=progress,
                                     message=ctx.message, cancel=ctx.cancel)
                return run_capture(session, plan, devices, hooks, CaptureSettings(reconnect_timeout_s=self.reconnect_timeout_s))
            finally:
                session.close()

        self.job = Job(work, "capture")
        self.job.signals.progress.connect(self._on_progress)
        self.job.signals.message.connect(self._on_message)
        self.job.signals.succeeded.connect(self._on_done)
        self.job.signals.failed.connect(self._on_failed)
        self.job.signals.finished.connect(self._on_finished)
        self.link.lane.submit(self.job)
        self.status_text = "running"
        self.last_progress = None
        self.eta.setText("ETA –")                 # nothing of the previous capture's timing
        self.position.setText("table: driven by the capture")
        self.action.setText(f"opening the session {self._root}")
        self.progress.setRange(0, 0)              # busy until the session's plan is known
        self._set_running(True)
        self._timer.start()
        self.capture_started.emit()

    def _on_opened(self, plan: Any) -> None:
        """The session is open on the instruments' lane: show its plan (a resumed one has its own)."""
        self.set_plan(plan.to_dict())
        if self.last_progress is None:
            self.progress.setRange(0, len(plan.actions()))
            self.progress.setValue(0)
        self.action.setText(f"capturing into {self._root}")
        self.log.emit(f"capture started: {plan.kind}, {plan.steps} steps × {plan.passes} passes -> {self._root}")

    #: How long the engine waits for an unplugged instrument to come back (s).
    reconnect_timeout_s = 30.0

    def toggle_pause(self) -> None:
        if self.job is None or self.job.done:
            return
        if self.pause_event.is_set():
            self.pause_event.clear()
            self.pause.setText("Pause  (F6)")
            self.status_text = "running"
            self.paused_label.hide()
            self.action.setText("continuing")
            self.log.emit("capture continued")
        else:
            self.pause_event.set()
            self.pause.setText("Continue  (F6)")
            self.status_text = "paused"
            self.paused_label.show()
            self.action.setText("paused after the current step (the instruments hold their state)")
            self.log.emit("capture paused")

    def abort_capture(self) -> None:
        if self.job is None or self.job.done:
            return
        self.job.cancel()
        self.pause_event.clear()
        if self.gate.pending:
            self.gate.answer(False)
        self.action.setText("stopping after the current step…")
        self.log.emit("capture: abort requested (the session stays resumable)")

    def _answer(self, go: bool) -> None:
        self.prompt.hide()
        if self.job is not None and not self.job.done:
            self.pause.setEnabled(True)
        self.gate.answer(go)

    def answer_prompt(self) -> None:
        """The Enter shortcut: Continue if a prompt is shown."""
        if not self.prompt.isHidden():
            self._answer(True)

    def _show_prompt(self, text: str) -> None:
        self._refresh_plots(both=True)          # the pass just finished, whole
        self.prompt_text.setText(text)
        if self.pause_event.is_set():
            self.toggle_pause()                 # the capture waits for the user anyway: one Continue, the prompt's
        self.pause.setEnabled(False)
        self.prompt.show()
        self.prompt_go.setFocus()
        # in a short window the controls scroll: the prompt must be in view, whatever was scrolled to
        QTimer.singleShot(0, lambda: self.controls_scroll.ensureWidgetVisible(self.prompt, 0, 8))
        self.log.emit(text)

    def _set_running(self, running: bool) -> None:
        self.start.setEnabled(not running)
        self.pause.setEnabled(running)
        self.abort.setEnabled(running)
        for w in (self.go, self.minus, self.plus, self.zero, self.laser_on, self.laser_off, self.kind,
                  self.steps, self.passes, self.camera_angles, self.chart):
            w.setEnabled(not running)

    # ------------------------------------------------------------ engine signals
    def _on_progress(self, pr: Any) -> None:
        self.last_progress = pr
        self.progress.setMaximum(pr.total)
        self.progress.setValue(pr.done)
        self.eta.setText(f"{format_eta(pr.eta_s)} · elapsed {pr.elapsed_s:.0f} s")
        self.action.setText(f"pass {pr.pass_no}: {describe_action(pr.action)}")
        if "/profile/" in pr.action:
            self._pending_profile = pr.action

    def _on_message(self, text: str) -> None:
        self.link.capture_note(text)
        self.note.emit(text)
        self.log.emit(f"capture: {text}")

    def _on_done(self, report: Any) -> None:
        self.status_text = "complete"
        self.action.setText(completion_text(report.taken, report.skipped, len(report.recoveries), report.elapsed_s))
        self.log.emit(f"capture complete: {self.action.text()}")

    def _on_failed(self, text: str, exc: Any) -> None:
        reason = getattr(exc, "reason", "error")
        if reason == "not started":         # the session could not be created or opened: nothing was captured
            self.status_text = "not started"
            self.progress.setRange(0, 1)        # no longer busy: nothing to count
            self.progress.setValue(0)
            self.action.setText(f"not started: {text.splitlines()[0]}")
            self.error.emit(text)
            return
        self.status_text = "cancelled" if reason == "cancelled" else "interrupted"
        # the window resumes with Start, not with the command line the engine's message names
        text = re.sub(r"fix the cause and run: kogei capture --resume \S+", "fix the cause and press Start to "
                      "resume", text)
        first = text.splitlines()[0]
        if reason == "cancelled":
            pr = self.last_progress
            done = f" after {pr.done} of {pr.total} steps" if pr is not None else ""
            self.action.setText(f"stopped at your request{done}. The session is intact: press Start to resume.")
            self.notice.emit(f"capture stopped at your request{done}; the session {self._root} is intact: press "
                           "Start to resume")
            return
        self.action.setText(f"stopped: {first}\nThe session is intact: fix the cause and press Start to resume.")
        self.error.emit(text)

    def _on_finished(self) -> None:
        self._timer.stop()
        self._refresh_plots(both=True)
        self.prompt.hide()
        self.paused_label.hide()
        self.pause.setText("Pause  (F6)")
        self.position.setText("table: – (its position is confirmed at the next move)")
        self._set_running(False)
        # a capture that never started left the turntable where it was: it is simply reconnected
        self.link.capture_finished(self._reconnect, interrupted=self.status_text not in ("complete", "not started"))
        self.capture_stopped.emit(self.status_text)

    # ------------------------------------------------------------ plots
    # Both figures are drawn in the drawing process (app.gui.plots.FigureDrawer); the GUI thread only reads the
    # newest profile back from the session and hands copies of the arrays to the drawing.
    def _draw_empty(self) -> None:
        self.profile_plot.plot(empty_figure, title="Live profile", hint="starts with the capture")
        self.cloud_plot.plot(empty_figure, title="Point cloud of the pass", hint="starts with the capture")

    def _refresh_plots(self, both: bool = False) -> None:
        """Hand the newest profile (2 Hz) and the pass's cloud (every 4th tick) to the drawings."""
        self._ticks += 1
        cid = self._pending_profile
        if cid is not None and self._root is not None and (both or not self.profile_plot.busy):
            self._pending_profile = None
            p = int(cid[1:3])
            idx = int(cid.rsplit("/", 1)[1])
            rows = self._pass_profiles.setdefault(p, {})
            last = max(rows) if rows else -1
            for i in range(last + 1, idx + 1):         # this profile and any the ticks skipped
                try:
                    with np.load(self._root / f"passes/p{p:02d}/profiles/{i:04d}.npz") as z:
                        rows[i] = (float(z["angle_deg"]), z["x_mm"].astype(np.float64),
                                   z["z_mm"].astype(np.float64))
                except (OSError, ValueError, KeyError):
                    continue           # a profile being replaced; the next tick shows it
            if idx in rows:
                angle, x, zz = rows[idx]
                self.profile_caption = f"pass {p}, step {idx}"
                self.profile_plot.plot(profile_figure, p=p, idx=idx, angle=angle, x=x, z=zz)
                self._cloud_pass_no = p
                self._cloud_dirty = True
        p = self._cloud_pass_no
        if self._cloud_dirty and p is not None and (both or (not self.cloud_plot.busy and self._ticks % 4 == 0)):
            self._cloud_dirty = False
            rows = self._pass_profiles[p]
            keys = sorted(rows)
            width = max(rows[k][1].size for k in keys)
            xs = np.full((len(keys), width), np.nan)
            zs = np.full((len(keys), width), np.nan)
            for i, k in enumerate(keys):
                xs[i, :rows[k][1].size], zs[i, :rows[k][2].size] = rows[k][1], rows[k][2]
            angles = np.array([rows[k][0] for k in keys])
            self.cloud_caption = f"pass {p}, {len(keys)} profiles"
            self.cloud_plot.plot(cloud_figure, p=p, angles=angles, x=xs, z=zs, cal=self._calibration())

    def _calibration(self) -> Any:
        src = self.calibration()
        root = self._root
        if src is None and root is not None and (root / "calibration.json").exists():
            src = str(root)
        if src is None:
            return None
        if self._cal_cache is not None and self._cal_cache[0] == src:
            return self._cal_cache[1]
        from app.workflows.calibration import load_calibration_source
        from processing.geometry.calibration import ScannerCalibration

        try:
            cal = ScannerCalibration.from_dict(load_calibration_source(src))
        except ValueError as exc:
            self.log.emit(f"live point cloud: calibration {src} unusable ({exc}); showing the range image")
            cal = None
        self._cal_cache = (src, cal)
        return cal


class CaptureNotStarted(RuntimeError):
    """Start's session could not be created or opened (the message says what to change); nothing was captured."""

    reason = "not started"


def open_capture_session(request: dict[str, Any]) -> tuple[Any, Any, dict[str, Any]]:
    """Create the session of a :meth:`CapturePanel._capture_request`, or open it to resume.

    Returns the open session, its plan and the device configuration the capture runs with; a
    :class:`app.errors.UsageError` names what to change.  Runs on any thread (it touches no widget).
    """
    from app.capture.runner import open_for_resume
    from app.errors import UsageError
    from app.session import Session, SessionError

    root = request["root"]
    if request["resume"]:
        session, plan, settings, config = open_for_resume(root)
        for name, port in request["ports"].items():
            if port and name in config:
                config[name]["port"] = port
        if request["camera"] is not None:
            config["camera"] = dict(request["camera"])
        _refuse_foreign_commands(session, root, settings, config, camera_chosen=request["camera"] is not None)
        settings["device_config"] = config
        session.update("settings", settings)
        return session, plan, config
    plan, config = request["plan"], request["config"]
    try:
        session = Session.create(root, plan=plan.to_dict(), object_info=request["object"],
                                 settings={"unattended": False, "device_config": config, "station": "gui"},
                                 devices={k: dict(v) for k, v in config.items()})
    except SessionError as exc:
        raise UsageError(str(exc)) from None
    return session, plan, config


def _refuse_foreign_commands(session: Any, root: Path, settings: dict[str, Any], config: dict[str, Any], *,
                             camera_chosen: bool) -> None:
    """Close ``session`` and refuse when resuming would run commands stored by another user or machine.

    The window asks before each pass itself, so a stored before-pass hook never runs here; a stored
    shutter command, gphoto2 program or hot folder would, unless a camera is chosen on the Devices tab.
    """
    from app.capture.devices import created_here, stored_commands
    from app.errors import UsageError

    stored = stored_commands(settings, config, before_pass="(asked by the window)",
                             camera="(chosen on the Devices tab)" if camera_chosen else None)
    if stored and not created_here(settings.get("created_by")):
        session.close()
        raise UsageError(f"session {root} was created by another user or machine and resuming it would run "
                         f"its stored {'; '.join(stored)}; choose the camera on the Devices tab, or resume it "
                         f"from a terminal with 'kogei capture --resume {root} --trust-hooks' after checking them")
