"""Instruments for a capture, built from a JSON-able configuration (stored in the session for ``--resume``).

The configuration names ports and the camera, never live objects, so a
resumed capture (another process, perhaps another day) rebuilds the same
devices; ports may be overridden when the cable ended up elsewhere.

Camera specifications (``--camera``)::

    gphoto2                 the gphoto2 program on PATH
    gphoto2:/path/to/gphoto2
    hotfolder:/path/to/dir  a folder a tethering program fills
    none                    no camera (profiles only, e.g. a calibration scan)

Examples
--------
>>> parse_camera_spec("hotfolder:/data/hot")
{'kind': 'hotfolder', 'folder': '/data/hot'}
>>> parse_camera_spec("gphoto2")
{'kind': 'gphoto2', 'executable': 'gphoto2'}
"""

from __future__ import annotations

import getpass
import os
import shlex
import socket
from collections.abc import Callable
from pathlib import Path
from typing import Any

from app.capture import defaults
from app.capture.runner import CaptureDevices
from app.errors import UsageError
from drivers.process import run_bounded

__all__ = [
    "parse_camera_spec",
    "run_hook_command",
    "Gphoto2Shooter",
    "HotFolderShooter",
    "build_devices",
    "check_device_config",
    "check_command",
    "creator_record",
    "created_here",
    "stored_commands",
]


def parse_camera_spec(spec: str) -> dict[str, Any]:
    """The camera part of a device configuration from a ``--camera`` value (see the module docstring)."""
    text = (spec or "").strip()
    if text == "none":
        return {"kind": "none"}
    if text == "gphoto2" or text.startswith("gphoto2:"):
        exe = text.split(":", 1)[1] if ":" in text else "gphoto2"
        if not exe:
            raise UsageError("--camera gphoto2: give the program after the colon, e.g. gphoto2:/usr/bin/gphoto2")
        return {"kind": "gphoto2", "executable": exe}
    if text.startswith("hotfolder:"):
        folder = text.split(":", 1)[1]
        if not folder:
            raise UsageError("--camera hotfolder: give the folder, e.g. hotfolder:/data/tether")
        return {"kind": "hotfolder", "folder": folder}
    raise UsageError(f"--camera {spec!r}: use gphoto2, gphoto2:PATH, hotfolder:DIR or none")


def run_hook_command(command: str, what: str, env: dict[str, str], timeout_s: float = 600.0) -> None:
    """Run a user hook (``--before-pass``, ``--shutter``) without a shell; raise RuntimeError if it fails.

    The hook runs in its own process group with output to temporary files
    (:func:`drivers.process.run_bounded`): a process it leaves in the
    background does not block the capture, and at the deadline the whole
    group is killed.
    """
    try:
        argv = shlex.split(command)
    except ValueError as exc:
        raise RuntimeError(f"{what} command {command!r} cannot be parsed: {exc}") from None
    if not argv:
        raise RuntimeError(f"{what} command is empty")
    try:
        proc = run_bounded(argv, timeout_s=timeout_s, env={**os.environ, **env})
    except FileNotFoundError:
        raise RuntimeError(f"{what} command {argv[0]!r} was not found; check the command line") from None
    except OSError as exc:
        raise RuntimeError(f"{what} command {argv[0]!r} cannot be started: {exc.strerror or exc}") from None
    if proc.timed_out:
        raise RuntimeError(f"{what} command {command!r} did not finish within {timeout_s:g} s and was stopped "
                           "(with everything it started)")
    if proc.returncode != 0:
        out = (proc.stderr or proc.stdout).strip().splitlines()
        raise RuntimeError(f"{what} command {command!r} failed with status {proc.returncode}: "
                           f"{out[-1] if out else '(no output)'}")


class Gphoto2Shooter:
    """A :class:`app.capture.runner.Shooter` over :class:`drivers.camera_gphoto2.Gphoto2Camera`."""

    def __init__(self, staging: Path, executable: str = "gphoto2", timeout_s: float = defaults.CAMERA_TIMEOUT_S) -> None:
        from drivers.camera_gphoto2 import Gphoto2Camera

        self.camera = Gphoto2Camera(staging, executable=executable, timeout_s=timeout_s)

    def shoot(self, name: str, shutter: str | None = None) -> Path:
        return self.camera.capture(name, shutter=shutter)


class HotFolderShooter:
    """A :class:`app.capture.runner.Shooter` over :class:`drivers.camera_hotfolder.HotFolderCamera`.

    ``shutter`` fires the camera (a tethering tool's command, a prompt);
    None waits for whatever fires it (an intervalometer, the operator).
    """

    def __init__(self, staging: Path, folder: str, shutter: Callable[[], None] | None = None,
                 stable_s: float = defaults.HOTFOLDER_STABLE_S, timeout_s: float = defaults.CAMERA_TIMEOUT_S) -> None:
        from drivers.camera_hotfolder import HotFolderCamera

        self.camera = HotFolderCamera(folder, staging, stable_s=stable_s, timeout_s=timeout_s,
                                      poll_s=min(0.1, stable_s / 4))
        self.shutter = shutter

    def shoot(self, name: str, shutter: str | None = None) -> Path:
        # a hot folder cannot set the exposure: the camera brackets on its own, and each file says its exposure
        if self.shutter is not None:
            self.shutter()
        return self.camera.wait_for_new(name)


def build_devices(config: dict[str, Any], session_root: Path | None,
                  shutter: Callable[[], None] | None = None) -> CaptureDevices:
    """Drivers (not yet connected) for a device configuration, wire-logged into the session.

    ``config``: ``{"turntable": {"port", "steps_per_degree", "speed_deg_s"},
    "profiler": {"port", "exposure_us"}, "camera": {"kind", ...}}``; a
    missing entry means the plan does not use that device.  ``session_root``
    None builds them without wire logs (see :func:`check_device_config`).
    """
    from drivers.profiler import LaserProfiler
    from drivers.transport import SerialTransport, WireLog
    from drivers.turntable import Turntable

    def log(name: str) -> WireLog | None:
        return None if session_root is None else WireLog(session_root / "wire" / f"{name}.log")

    devices = CaptureDevices()
    tt = config.get("turntable")
    if tt:
        t = SerialTransport(tt["port"], 115200, wire_log=log("turntable"), label="turntable",
                            open=False)
        devices.turntable = Turntable(t, steps_per_degree=float(tt.get("steps_per_degree", defaults.STEPS_PER_DEGREE)),
                                      speed_deg_s=float(tt.get("speed_deg_s", defaults.SPEED_DEG_S)))
    pr = config.get("profiler")
    if pr:
        t = SerialTransport(pr["port"], int(pr.get("baudrate", 921600)), wire_log=log("profiler"),
                            label="profiler", open=False)
        devices.profiler = LaserProfiler(t, exposure_us=int(pr.get("exposure_us", defaults.EXPOSURE_US)))
    cam = config.get("camera") or {"kind": "none"}
    if cam["kind"] == "gphoto2":
        exe, timeout = cam.get("executable", "gphoto2"), float(cam.get("timeout_s", defaults.CAMERA_TIMEOUT_S))
        devices.camera = lambda staging: Gphoto2Shooter(staging, exe, timeout)
    elif cam["kind"] == "hotfolder":
        folder, stable, timeout = cam["folder"], float(cam.get("stable_s", defaults.HOTFOLDER_STABLE_S)), float(cam.get("timeout_s", defaults.CAMERA_TIMEOUT_S))
        devices.camera = lambda staging: HotFolderShooter(staging, folder, shutter, stable, timeout)
    devices.info = {"camera": cam}
    return devices


#: Which command-line options set each part of a device configuration (named in errors).
_OPTIONS = {"turntable": "--turntable / --speed / --steps-per-degree", "profiler": "--laser / --exposure-us",
            "camera": "--camera / --camera-timeout / --hotfolder-stable"}


def _check_port(name: str, part: dict[str, Any]) -> None:
    port = part.get("port")
    if not isinstance(port, str) or not port.strip() or "\x00" in port or len(port) > 4096:
        raise ValueError(f"port {port!r} is not a device path or pyserial URL (e.g. /dev/ttyUSB0, "
                         "socket://host:port)")


def check_device_config(config: Any) -> None:
    """Raise :class:`UsageError` (naming the options) if ``config`` cannot build its drivers.

    Builds every driver without opening a port, writing a wire log or running
    a program, so options are checked before a session folder is created.
    """
    from drivers.camera_gphoto2 import Gphoto2Camera
    from drivers.camera_hotfolder import HotFolderCamera

    if not isinstance(config, dict) or not all(isinstance(v, dict) for v in config.values()):
        raise UsageError(f"device configuration {config!r} is not a table of devices; give the ports again")
    for name in ("turntable", "profiler", "camera"):
        part = config.get(name)
        if not part:
            continue
        try:
            if name == "camera":
                cam = build_devices({"camera": part}, None).info["camera"]
                if cam["kind"] == "gphoto2":
                    Gphoto2Camera(".", executable=cam.get("executable", "gphoto2"),
                                  timeout_s=cam.get("timeout_s", defaults.CAMERA_TIMEOUT_S))
                elif cam["kind"] == "hotfolder":
                    HotFolderCamera(cam["folder"], ".", stable_s=cam.get("stable_s", defaults.HOTFOLDER_STABLE_S),
                                    timeout_s=cam.get("timeout_s", defaults.CAMERA_TIMEOUT_S))
                elif cam["kind"] != "none":
                    raise ValueError(f"camera kind {cam['kind']!r} is not gphoto2, hotfolder or none")
            else:
                _check_port(name, part)
                build_devices({name: part}, None)
        except (ValueError, TypeError, KeyError) as exc:
            text = str(exc).strip() or type(exc).__name__
            raise UsageError(f"{_OPTIONS[name]}: {text}") from None


def check_command(command: Any, what: str) -> None:
    """Raise :class:`UsageError` if a hook ``command`` (``--before-pass``, ``--shutter``) cannot be parsed."""
    if command is None:
        return
    try:
        argv = shlex.split(command) if isinstance(command, str) else None
    except ValueError as exc:
        raise UsageError(f"{what} {command!r} cannot be parsed: {exc}") from None
    if not argv:
        raise UsageError(f"{what} {command!r} is empty or not a command line; give the program and its arguments")


def creator_record() -> dict[str, Any]:
    """Who creates a session here: user name, user id and host (stored as ``settings.created_by``)."""
    try:
        user = getpass.getuser()
    except (KeyError, OSError):
        user = ""
    return {"user": user, "uid": os.getuid() if hasattr(os, "getuid") else None, "host": socket.gethostname()}


def created_here(stored: Any) -> bool:
    """True if ``stored`` (a session's ``settings.created_by``) names this user id on this host."""
    here = creator_record()
    return isinstance(stored, dict) and stored.get("uid") == here["uid"] and stored.get("host") == here["host"]


def stored_commands(settings: dict[str, Any], config: dict[str, Any], *, before_pass: str | None = None,
                    shutter: str | None = None, camera: str | None = None) -> list[str]:
    """The commands (and the hot folder) resuming would use from the session itself, as command-line options.

    A command given again (``before_pass``, ``shutter``, ``camera`` as typed
    now) replaces the stored one and is not listed.  A session not
    :func:`created_here` must not run the listed ones without the user's
    explicit trust (``kogei capture --resume --trust-hooks``).
    """
    given = {"before_pass": before_pass, "shutter": shutter}
    found = [f"--{key.replace('_', '-')} {settings[key]}" for key in ("before_pass", "shutter")
             if settings.get(key) and not given[key]]
    cam = config.get("camera") if isinstance(config.get("camera"), dict) else {}
    if not camera and cam.get("kind") == "gphoto2" and cam.get("executable", "gphoto2") != "gphoto2":
        found.append(f"--camera gphoto2:{cam['executable']}")
    if not camera and cam.get("kind") == "hotfolder":          # new RAW files are moved out of that folder
        found.append(f"--camera hotfolder:{cam.get('folder')}")
    return found
