"""The instruments the window talks to: ports, connect / disconnect, status lights, drop-out and re-handshake.

The instruments' protocols and recovery: docs/protocols.md.  Every serial operation runs on one
:class:`app.gui.workers.Lane` of a single thread, so the drivers (which are
not thread-safe) are used by one thread at a time and in order: a jog, a
status poll and a capture never interleave.  While idle, :class:`StationLink`
polls each connected instrument once a second (the turntable's ``?`` status,
the profiler's ``GET,LAS``); a vanished port or a silent device turns its light
red, raises a banner naming the device and the port, and is re-handshaken
(:meth:`drivers.turntable.Turntable.reconnect`,
:meth:`drivers.profiler.LaserProfiler.reconnect`) as soon as it answers again.
During a capture :func:`app.capture.runner.run_capture` owns the instruments and
does its own recovery; its notes drive the same lights and banner
(:meth:`StationLink.capture_note`).

The camera has no connection: a gphoto2 program or a hot folder is checked
for presence.  A simulated station (``kogei mock`` or one started by the
window) is told to re-place the object between passes through its control
folder (:func:`mocks.station.request_place`).

Examples
--------
>>> parse_note("laser profiler on /tmp/st/profiler: port vanished (closed); reconnecting")
('profiler', 'lost')
>>> parse_note("turntable: reconnected at 30 deg")
('turntable', 'connected')
>>> parse_note("camera: busy; retrying in 1 s (1/3)") is None
True
"""

from __future__ import annotations

import logging
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

from PySide6.QtCore import QObject, QTimer, Signal

from app.gui.workers import JobContext, Lane

__all__ = ["INSTRUMENTS", "StationLink", "parse_note", "camera_spec_text"]

#: The serial instruments, in display order.
INSTRUMENTS = ("turntable", "profiler")
_LABEL = {"turntable": "turntable", "profiler": "laser profiler", "camera": "camera"}


def parse_note(text: str) -> tuple[str, str] | None:
    """Which instrument a capture note is about and the state it implies (``lost`` / ``connected``), if any."""
    low = text.lower()
    dev = "profiler" if low.startswith("laser profiler") or low.startswith("profiler") else (
        "turntable" if low.startswith("turntable") else None)
    if dev is None:
        return None
    if "port vanished" in low or "stopped answering" in low or "did not come back" in low:
        return dev, "lost"
    if "reconnected" in low:
        return dev, "connected"
    return None


def camera_spec_text(spec: dict[str, Any]) -> str:
    """The ``--camera`` form of a camera configuration (for the log and the session).

    >>> camera_spec_text({"kind": "hotfolder", "folder": "/data/hot"})
    'hotfolder:/data/hot'
    """
    kind = spec.get("kind", "none")
    if kind == "gphoto2":
        return f"gphoto2:{spec.get('executable', 'gphoto2')}"
    if kind == "hotfolder":
        return f"hotfolder:{spec.get('folder', '')}"
    return "none"


class StationLink(QObject):
    """Ports, live drivers and their states (see the module docstring).

    Signals
    -------
    state(device, state, detail)
        ``state`` is ``disconnected``, ``connecting``, ``connected``,
        ``lost`` or ``capture`` (owned by a running capture).
    banner(text)
        A drop-out banner ('' clears it).
    log(text)
        A line for the log panel.
    """

    state = Signal(str, str, str)
    banner = Signal(str)
    log = Signal(str)

    def __init__(self, lane: Lane, wire_dir: Path, parent: QObject | None = None, poll_ms: int = 1000) -> None:
        super().__init__(parent)
        self.lane = lane
        self.wire_dir = Path(wire_dir)
        self.ports: dict[str, str] = {"turntable": "", "profiler": ""}
        self.camera: dict[str, Any] = {"kind": "none"}
        self.control_dir: str = ""
        self.placer: Callable[[int], None] | None = None   # an in-process simulated station's place()
        self.shutter: Callable[[], None] | None = None     # fires a hot-folder camera (simulated station)
        self.drivers: dict[str, Any] = {}
        self.states: dict[str, str] = {n: "disconnected" for n in INSTRUMENTS}
        self.firmware: dict[str, str] = {}
        self.capturing = False
        self._lost: dict[str, str] = {}
        self._left: set[str] = set()        # left disconnected by an interrupted capture, to reconnect after
        self._timer = QTimer(self)
        self._timer.setInterval(poll_ms)
        self._timer.timeout.connect(self.poll)
        self._timer.start()

    # ------------------------------------------------------------ configuration
    def device_config(self) -> dict[str, Any]:
        """The configuration :func:`app.capture.devices.build_devices` takes (ports, camera)."""
        config: dict[str, Any] = {}
        if self.ports.get("turntable"):
            config["turntable"] = {"port": self.ports["turntable"]}
        if self.ports.get("profiler"):
            config["profiler"] = {"port": self.ports["profiler"]}
        config["camera"] = dict(self.camera)
        return config

    def camera_problem(self) -> str | None:
        """Why the configured camera cannot shoot (None if it can, or if there is none)."""
        kind = self.camera.get("kind", "none")
        if kind == "gphoto2":
            exe = self.camera.get("executable", "gphoto2")
            if not (shutil.which(exe) or (os.path.isfile(exe) and os.access(exe, os.X_OK))):
                return f"camera: the gphoto2 program {exe!r} was not found; install gphoto2 or give its path"
        elif kind == "hotfolder":
            if not Path(self.camera.get("folder", "")).is_dir():
                return (f"camera: the hot folder {self.camera.get('folder')!r} does not exist; create it and point "
                        "the tethering program at it")
        return None

    def _set(self, name: str, state: str, detail: str = "") -> None:
        self.states[name] = state
        self.state.emit(name, state, detail)

    def _build(self, name: str) -> Any:
        from app.capture.devices import build_devices

        port = self.ports.get(name, "")
        if not port:
            raise ValueError(f"{_LABEL[name]}: choose its port first (the list shows the ports found, with USB "
                             "VID:PID; a simulated station prints its ports)")
        devices = build_devices({name: {"port": port}}, self.wire_dir)
        return devices.turntable if name == "turntable" else devices.profiler

    # ------------------------------------------------------------ connect / disconnect
    def connect_device(self, name: str) -> None:
        """Open the port and handshake (on the device lane); the light turns green with the firmware banner."""
        if self.capturing:
            self.log.emit(f"{_LABEL[name]}: the capture owns the instruments until it stops")
            return
        self._set(name, "connecting", self.ports.get(name, ""))

        def work(ctx: JobContext) -> str:
            old = self.drivers.pop(name, None)
            if old is not None:
                old.close()
            drv = self._build(name)
            try:
                version = drv.connect()
            except BaseException:
                drv.close()
                raise
            self.drivers[name] = drv
            return version

        def ok(version: str) -> None:
            self.firmware[name] = self._banner(name)
            self._lost.pop(name, None)
            self._update_banner()
            self._set(name, "connected", self.firmware[name])
            self.log.emit(f"{_LABEL[name]} on {self.ports[name]}: connected, {self.firmware[name]}")

        def bad(text: str, exc: Any) -> None:
            self._set(name, "disconnected", text)
            self.log.emit(f"{_LABEL[name]}: could not connect: {text}")

        self.lane.run(work, f"connect {name}", succeeded=ok, failed=bad)

    def _banner(self, name: str) -> str:
        drv = self.drivers.get(name)
        if drv is None:
            return ""
        if name == "turntable":
            return f"firmware {drv.firmware_version}"
        return f"{drv.model} #{drv.serial_number}, firmware {drv.firmware_version}"

    def disconnect_device(self, name: str) -> None:
        """Close the port (lasers off, motor released: the drivers' own close)."""
        def work(ctx: JobContext) -> None:
            drv = self.drivers.pop(name, None)
            if drv is not None:
                drv.close()

        def done(_: Any) -> None:
            self._lost.pop(name, None)
            self._update_banner()
            self._set(name, "disconnected", "")
            self.log.emit(f"{_LABEL[name]}: disconnected")

        self.lane.run(work, f"disconnect {name}", succeeded=done)

    def connected(self, name: str) -> bool:
        return self.states.get(name) == "connected"

    # ------------------------------------------------------------ capture hand-over
    def release_for_capture(self) -> list[str]:
        """Close the live drivers (on the lane, before the capture job queued after this) and mark them owned."""
        names = [n for n in INSTRUMENTS if n in self.drivers or self.states[n] == "lost" or n in self._left]
        self._left.clear()
        drivers = dict(self.drivers)
        self.drivers.clear()
        self.capturing = True

        def work(ctx: JobContext) -> None:
            for drv in drivers.values():
                drv.close()

        self.lane.run(work, "release for capture")
        for n in INSTRUMENTS:
            if self.ports.get(n):
                self._set(n, "capture", "driven by the capture")
        return names

    def capture_note(self, text: str) -> None:
        """A note of the running capture: update the lights and the drop-out banner."""
        parsed = parse_note(text)
        if parsed is None:
            return
        name, st = parsed
        if st == "lost":
            self._lost[name] = (f"{_LABEL[name]} on {self.ports.get(name, '?')} dropped out; waiting for it to "
                                "come back (check the cable and the power)")
            self._set(name, "lost", text)
        else:
            self._lost.pop(name, None)
            self._set(name, "capture", "re-handshaken, driven by the capture")
            self.log.emit(f"{_LABEL[name]}: back, re-handshaken")
        self._update_banner()

    def capture_finished(self, reconnect: list[str], interrupted: bool = False) -> None:
        """The capture released the instruments: reconnect those that were connected before.

        After an interrupted capture the turntable is left alone: connecting resets the board's
        position counter, which a resumed capture reads to learn where the table stands.
        """
        self.capturing = False
        for n in INSTRUMENTS:
            if interrupted and n == "turntable" and n not in self._lost:
                self._set(n, "disconnected", "left as the capture stopped, so that resuming reads the board's "
                                             "position; connect it only to move the table by hand")
                if n in reconnect:
                    self._left.add(n)           # the capture that resumes reconnects it when it ends
                continue
            if n in self._lost and self.ports.get(n):
                # it dropped out and the capture gave up on it: watch it and re-handshake when it returns
                try:
                    self.drivers[n] = self._build(n)
                except ValueError:
                    continue
                self._set(n, "lost", "waiting for the port to return")
            elif n in reconnect and self.ports.get(n):
                self.connect_device(n)
            else:
                self._set(n, "disconnected", "")
        self._update_banner()

    # ------------------------------------------------------------ drop-out watch
    def _update_banner(self) -> None:
        self.banner.emit("\n".join(self._lost.values()))

    def poll(self) -> None:
        """Check the connected instruments and re-handshake lost ones (skipped while the lane is busy)."""
        if self.capturing or self.lane.busy:
            return
        watched = {n: d for n, d in self.drivers.items() if self.states.get(n) in ("connected", "lost")}
        if not watched:
            return
        states = dict(self.states)

        def work(ctx: JobContext) -> dict[str, tuple[str, str]]:
            from drivers.errors import DriverError

            out: dict[str, tuple[str, str]] = {}
            for name, drv in watched.items():
                if states[name] == "lost":
                    port = self.ports.get(name, "")
                    if "://" not in port and not os.path.exists(port):
                        continue
                    try:
                        drv.reconnect(timeout_s=0.3)
                        out[name] = ("connected", "re-handshaken")
                    except (DriverError, OSError) as exc:
                        out[name] = ("lost", str(exc))
                    continue
                try:
                    if name == "turntable":
                        drv.status()
                    else:
                        drv.get("LAS")
                except (DriverError, OSError) as exc:
                    out[name] = ("lost", str(exc))
            return out

        self.lane.run(work, "poll", succeeded=self._polled)

    def _polled(self, result: dict[str, tuple[str, str]]) -> None:
        for name, (st, detail) in result.items():
            if st == "lost" and self.states.get(name) != "lost":
                self._lost[name] = (f"{_LABEL[name]} on {self.ports.get(name, '?')} dropped out ({detail}); "
                                    "waiting for it to come back (check the cable and the power)")
                self._set(name, "lost", detail)
                self.log.emit(f"{_LABEL[name]}: dropped out: {detail}")
            elif st == "connected":
                self._lost.pop(name, None)
                self.firmware[name] = self._banner(name)
                self._set(name, "connected", self.firmware[name])
                self.log.emit(f"{_LABEL[name]}: back on {self.ports.get(name)}, re-handshaken ({self.firmware[name]})")
        self._update_banner()

    # ------------------------------------------------------------ jog
    def jog(self, action: str, value: float = 0.0, done: Callable[[Any], None] | None = None) -> None:
        """Turntable ``move`` (absolute degrees), ``zero``, ``laser`` (value 1/0), on the device lane."""
        if self.capturing:
            self.log.emit("the capture owns the turntable until it stops")
            return
        if "turntable" not in self.drivers or self.states.get("turntable") != "connected":
            self.log.emit("turntable: connect it first (Devices)")
            return
        tt = self.drivers["turntable"]
        pr = self.drivers.get("profiler")

        def work(ctx: JobContext) -> float:
            if action == "move":
                tt.motor(True)
                return tt.move_to(float(value))
            if action == "zero":
                tt.zero()
                return tt.position_deg
            if action == "laser":
                on = bool(value)
                tt.laser(1, on)
                if pr is not None:
                    pr.laser(on)
                return tt.position_deg
            raise ValueError(f"unknown turntable action {action!r}")

        def failed(text: str, exc: Any) -> None:
            self.log.emit(f"turntable: {action} failed: {text}")

        self.lane.run(work, f"jog {action}", succeeded=done, failed=failed)

    def place(self, pass_no: int) -> str:
        """Tell a simulated station to re-place the object (in-process or through its control folder)."""
        if self.placer is not None:
            self.placer(pass_no)
            return "the simulated station placed the object"
        if self.control_dir:
            from mocks.station import request_place

            request_place(self.control_dir, pass_no)
            return f"the simulated station at {self.control_dir} placed the object"
        return ""

    def shutdown(self) -> None:
        """Stop polling and close every driver (window closing)."""
        self._timer.stop()
        self.lane.wait(10_000)
        for drv in self.drivers.values():
            try:
                drv.close()
            except Exception as exc:  # noqa: BLE001 - best effort on exit: say so and go on closing
                logging.getLogger("kogei.gui").warning("closing %s on exit: %s", type(drv).__name__, exc)
        self.drivers.clear()
