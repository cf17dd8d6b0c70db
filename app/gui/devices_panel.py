"""Devices panel: ports (discovered, with USB VID:PID), connect / disconnect, firmware banners and lights.

The rows come from :func:`drivers.discovery.list_ports` (as ``kogei
devices``); a port can also be typed (a simulated station's pty links are
not USB devices).  The camera is a gphoto2 program or a hot folder, as
``kogei capture --camera``.  A simulated station can be started here (the
same :class:`mocks.station.SimulatedStation` as ``kogei mock``) or an
external ``kogei mock`` named by its control folder, so the window works the
same against the simulator and the hardware.

Examples
--------
>>> port_label("/dev/ttyUSB0", "1a86:7523", None, "USB-Serial")
'/dev/ttyUSB0  (1a86:7523, USB-Serial)'
"""

from __future__ import annotations

from typing import Any

from PySide6.QtCore import Signal
from PySide6.QtWidgets import (
    QComboBox,
    QFileDialog,
    QFormLayout,
    QFrame,
    QGridLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QPushButton,
    QScrollArea,
    QVBoxLayout,
    QWidget,
)

from app.gui.station_link import INSTRUMENTS, StationLink
from app.gui.widgets import StatusLight, browse_row

__all__ = ["DevicesPanel", "port_label", "SIMULATED_OBJECTS"]

#: What the simulated station can have on its table: the piece; the reference sphere for the scanner
#: calibration (its radius is the Processing tab's default sphere radius); the ChArUco board for the camera
#: calibration (the capture plan's default board, flat then on two wedges); the chrome (mirror) sphere for the
#: lamp calibration (the Capture tab's default mirror-sphere radius).  The board and the chrome sphere are
#: the worlds ``kogei demo`` and ``kogei mock --world board|mirror-sphere`` calibrate from.
SIMULATED_OBJECTS = ("hawk head", "calibration sphere (radius 25 mm, 60 mm off the axis)",
                     "ChArUco board (7 x 5 squares of 8 mm, flat then on two wedges)",
                     "chrome sphere (radius 20 mm, 25 mm off the axis)")

_TITLES = {"turntable": "Turntable (Horus)", "profiler": "Laser profiler"}


def port_label(device: str, vid_pid: str | None, serial: str | None, description: str | None) -> str:
    """How a discovered port is listed."""
    extra = [x for x in (vid_pid, f"S/N {serial}" if serial else None, description) if x]
    return f"{device}  ({', '.join(extra)})" if extra else device


class DevicesPanel(QWidget):
    """Ports and lights of the instruments (see the module docstring)."""

    simulated_requested = Signal()
    object_requested = Signal(str)        # one of SIMULATED_OBJECTS

    def __init__(self, link: StationLink, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.link = link
        self.port_boxes: dict[str, QComboBox] = {}
        self.lights: dict[str, StatusLight] = {}
        self.banners: dict[str, QLabel] = {}
        self.connect_buttons: dict[str, QPushButton] = {}
        self.disconnect_buttons: dict[str, QPushButton] = {}
        # the content scrolls when the window is too short for it (1024 x 700 with the log), never squeezed
        inner = QWidget()
        outer = QVBoxLayout(inner)
        scroll = QScrollArea()
        scroll.setWidget(inner)
        scroll.setWidgetResizable(True)
        scroll.setFrameShape(QFrame.Shape.NoFrame)
        page = QVBoxLayout(self)
        page.setContentsMargins(0, 0, 0, 0)
        page.addWidget(scroll)

        serial = QGroupBox("Serial instruments")
        grid = QGridLayout(serial)
        for c, head in enumerate(("", "Instrument", "Port", "", "", "Firmware / status")):
            grid.addWidget(QLabel(f"<b>{head}</b>"), 0, c)
        for r, name in enumerate(INSTRUMENTS, start=1):
            light = StatusLight()
            box = QComboBox()
            box.setEditable(True)
            box.setMinimumContentsLength(34)
            box.setToolTip("a discovered port (with USB VID:PID) or a path / pyserial URL typed here")
            con = QPushButton("Connect")
            con.setToolTip(f"open the port and check that the {_TITLES[name].lower()} answers")
            dis = QPushButton("Disconnect")
            dis.setToolTip("close the port (the instrument keeps its state)")
            banner = QLabel("not connected")
            banner.setWordWrap(True)
            con.clicked.connect(lambda _=False, n=name: self.connect_clicked(n))
            dis.clicked.connect(lambda _=False, n=name: link.disconnect_device(n))
            for c, w in enumerate((light, QLabel(_TITLES[name]), box, con, dis, banner)):
                grid.addWidget(w, r, c)
            self.port_boxes[name], self.lights[name], self.banners[name] = box, light, banner
            self.connect_buttons[name], self.disconnect_buttons[name] = con, dis
        grid.setColumnStretch(2, 3)           # a pty or by-id path is long: the port column takes the width
        grid.setColumnStretch(5, 2)
        refresh = QPushButton("Refresh ports")
        refresh.setToolTip("look for serial ports again (after plugging an instrument in)")
        refresh.clicked.connect(self.refresh_ports)
        grid.addWidget(refresh, len(INSTRUMENTS) + 1, 2)
        grid.setColumnStretch(5, 1)
        outer.addWidget(serial)

        cam = QGroupBox("Camera")
        form = QFormLayout(cam)
        self.camera_kind = QComboBox()
        self.camera_kind.addItems(["none", "gphoto2", "hotfolder"])
        self.camera_kind.setToolTip("gphoto2: a camera tethered over USB; hotfolder: a folder the camera's own "
                                    "software writes RAW files into; none: laser profiles only")
        self.camera_path = QLineEdit()
        self.camera_path.setPlaceholderText("gphoto2 program (default: gphoto2 on PATH) or the hot folder")
        row = browse_row(self.camera_path, self._browse_camera)
        self.camera_light = StatusLight()
        self.camera_state = QLabel("no camera (profiles only)")
        check = QPushButton("Check camera")
        check.setToolTip("check that the chosen camera program or folder can be used")
        check.clicked.connect(self.check_camera)
        state_row = QHBoxLayout()
        state_row.addWidget(self.camera_light)
        state_row.addWidget(self.camera_state, 1)
        state_row.addWidget(check)
        form.addRow("Kind", self.camera_kind)
        form.addRow("Program / folder", row)
        form.addRow("State", state_row)
        outer.addWidget(cam)

        sim = QGroupBox("Simulated station")
        sform = QFormLayout(sim)
        self.control_dir = QLineEdit()
        self.control_dir.setPlaceholderText("control folder printed by 'kogei mock' (re-places the object "
                                            "between passes)")
        self.start_sim_button = start = QPushButton("Start a simulated station in this window")
        start.setToolTip("a simulated turntable, profiler and camera in this window, their ports filled in: to "
                         "learn the station or try a plan without the instruments")
        self.control_dir.setToolTip("the control folder 'kogei mock' prints: lets the window re-place the simulated "
                                    "object between passes")
        start.clicked.connect(self.simulated_requested.emit)
        self.sim_object = QComboBox()
        self.sim_object.addItems(SIMULATED_OBJECTS)
        self.sim_object.setToolTip("the object on the simulated table: scan the calibration sphere (scanner), "
                                   "photograph the ChArUco board (camera) and the chrome sphere (lamps), calibrate "
                                   "each on the Processing tab, then scan the piece")
        self.put_button = QPushButton("Put on the table")
        self.put_button.setToolTip("swap the object on the running simulated station (the instruments stay "
                                   "connected)")
        self.put_button.setEnabled(False)
        self.put_button.clicked.connect(lambda: self.object_requested.emit(self.sim_object.currentText()))
        obj_row = QHBoxLayout()
        obj_row.addWidget(self.sim_object, 1)
        obj_row.addWidget(self.put_button)
        self.sim_state = QLabel("none")
        self.sim_state.setWordWrap(True)
        sform.addRow("kogei mock control folder", self.control_dir)
        sform.addRow(start)
        sform.addRow("Object on the table", obj_row)
        sform.addRow("Station", self.sim_state)
        outer.addWidget(sim)
        outer.addStretch(1)

        link.state.connect(self.show_state)
        self.refresh_ports()

    # ------------------------------------------------------------ ports
    def refresh_ports(self) -> None:
        """List the serial ports present now (keeping what is typed or chosen)."""
        from drivers.discovery import list_ports

        try:
            rows = list_ports()
        except OSError as exc:
            rows = []
            self.link.log.emit(f"cannot list serial ports: {exc}")
        for name, box in self.port_boxes.items():
            current = self.port(name)
            box.blockSignals(True)
            box.clear()
            for r in rows:
                box.addItem(port_label(r.device, r.vid_pid, r.serial_number, r.description), r.device)
            self.set_port(name, current)
            box.blockSignals(False)

    def port(self, name: str) -> str:
        """The chosen port's path (the text up to the first blank, the list's label stripped)."""
        box = self.port_boxes[name]
        text = box.currentText().strip()
        idx = box.findText(text)
        if idx >= 0 and box.itemData(idx):
            return str(box.itemData(idx))
        return text.split("  (")[0].strip()

    def set_port(self, name: str, path: str) -> None:
        box = self.port_boxes[name]
        idx = box.findData(path)
        if idx >= 0:
            box.setCurrentIndex(idx)
        else:
            box.setEditText(path)

    def camera_config(self) -> dict[str, Any]:
        kind = self.camera_kind.currentText()
        path = self.camera_path.text().strip()
        if kind == "gphoto2":
            return {"kind": "gphoto2", "executable": path or "gphoto2"}
        if kind == "hotfolder":
            return {"kind": "hotfolder", "folder": path, "stable_s": 0.3}
        return {"kind": "none"}

    def apply(self) -> None:
        """Copy the chosen ports and camera into the link."""
        for name in INSTRUMENTS:
            self.link.ports[name] = self.port(name)
        self.link.camera = self.camera_config()
        self.link.control_dir = self.control_dir.text().strip()

    # ------------------------------------------------------------ actions
    def connect_clicked(self, name: str) -> None:
        self.apply()
        self.link.connect_device(name)

    def connect_all(self) -> None:
        self.apply()
        for name in INSTRUMENTS:
            if self.link.ports.get(name):
                self.link.connect_device(name)
        self.check_camera()

    def check_camera(self) -> None:
        self.apply()
        problem = self.link.camera_problem()
        kind = self.link.camera.get("kind")
        if problem:
            self.camera_light.set_state("problem", problem)
            self.camera_state.setText(problem)
            self.link.log.emit(problem)
        elif kind == "none":
            self.camera_light.set_state("disconnected")
            self.camera_state.setText("no camera (profiles only)")
        else:
            self.camera_light.set_state("ready")
            what = self.link.camera.get("executable") or self.link.camera.get("folder")
            self.camera_state.setText(f"ready: {kind} ({what})")

    def _browse_camera(self) -> None:
        if self.camera_kind.currentText() == "hotfolder":
            path = QFileDialog.getExistingDirectory(self, "Hot folder")
        else:
            path, _ = QFileDialog.getOpenFileName(self, "gphoto2 program")
        if path:
            self.camera_path.setText(path)

    def show_state(self, name: str, state: str, detail: str) -> None:
        if name not in self.lights:
            return
        self.lights[name].set_state(state, detail)
        text = {"disconnected": "not connected", "connecting": f"connecting to {detail}…",
                "connected": detail or "connected", "lost": f"DROPPED OUT: {detail}",
                "capture": detail}.get(state, detail)
        if state == "disconnected" and detail:
            text = detail
        self.banners[name].setText(text)
        self.connect_buttons[name].setEnabled(state in ("disconnected", "lost"))
        self.disconnect_buttons[name].setEnabled(state in ("connected", "lost"))
