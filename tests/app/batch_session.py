"""Tiny simulated sessions for the batch and report tests, built once per test process.

A reference-sphere scan calibrates the simulated station; a one-pass scan of a small hawk (24
profiles, one 240 x 160 RAW frame after the chart frame, a ColorChecker Classic that ``cv2.mcc``
finds) gives a session that ``kogei process`` can mesh in about two seconds.  The session is left unprocessed and uncalibrated (as ``kogei capture`` leaves
it), so tests choose what to run; copy it before changing it.

The sessions are captured once per test run: under xdist the first worker to need them builds them while
the others wait on a file lock (:mod:`tests._shared_build`), and every test process works on its own copy.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

from app.capture.devices import build_devices
from app.capture.runner import CaptureHooks, CapturePlan, run_capture
from app.session import Session
from app.workflows.calibration import calibrate_session
from mocks.station import SimulatedStation
from mocks.world import World
from tests._shared_build import built_once, copy_tree

__all__ = ["built_sessions", "copy_session", "materials_session", "MATERIALS_WORLD"]

_BUILT: dict[str, SimpleNamespace] = {}


def _capture(world: World, root: Path, plan: CapturePlan, camera: bool, seed: int) -> None:
    with SimulatedStation(world, root=root.parent / f"{root.name}-station", seed=seed) as st:
        config = {"turntable": {"port": str(st.turntable_path)}, "profiler": {"port": str(st.profiler_path)}}
        if camera:
            config["camera"] = {"kind": "gphoto2", "executable": str(st.gphoto2_path)}
        s = Session.create(root, plan=plan.to_dict(), object_info={"name": "hawk head (test)", "collection": "T-1"},
                           settings={"unattended": True, "device_config": config})
        try:
            run_capture(s, plan, build_devices(config, s.root), CaptureHooks(before_pass=lambda p, n: st.place(p)))
        finally:
            s.close()


def _built_once(tmp_path_factory, name: str, build, sessions: tuple[str, ...]) -> Path:
    """A folder of this process holding copies of ``sessions``, which ``build(folder)`` captured once per run
    (:func:`tests._shared_build.built_once`).  The simulated stations' folders are not copied (their device
    files belong to the station that made them)."""
    built = built_once(tmp_path_factory, f"shared-{name}", build)
    local = tmp_path_factory.mktemp(name)
    for session in sessions:
        copy_session(built / session, local / session)
    return local


def _build_batch_sessions(tmp: Path) -> None:
    _capture(World.calibration_sphere(25.0, 60.0), tmp / "cal", CapturePlan("scan", steps=36, passes=1,
                                                                            camera=False), False, 5)
    calibrate_session(tmp / "cal", 25.0)
    _capture(World.hawk(4_000, width=240, height=160, chart_layout="classic24"), tmp / "raw",
             CapturePlan("scan", steps=24, passes=1, camera_angles_deg=(0.0,)), True, 3)


def built_sessions(tmp_path_factory) -> SimpleNamespace:
    """``cal`` (a calibrated sphere session) and ``raw`` (a captured, unprocessed hawk session)."""
    if "s" not in _BUILT:
        tmp = _built_once(tmp_path_factory, "batch-sessions", _build_batch_sessions, ("cal", "raw"))
        _BUILT["s"] = SimpleNamespace(cal=tmp / "cal", raw=tmp / "raw")
    return _BUILT["s"]


def copy_session(src: Path, dst: Path) -> Path:
    """A copy of a session folder (without its lock files)."""
    return copy_tree(src, dst)


#: Head and beak of distinct materials, the light 15 deg from the camera (as in app.demo.colour) so that
#: metal highlights face the camera: the materials step's test world.
MATERIALS_WORLD = {"materials": {"head": "gold", "beak": "urushi-red"}, "light_direction": (0.2, -0.93, 0.45)}


def materials_session(tmp_path_factory) -> Path:
    """A captured, unprocessed one-pass session of :data:`MATERIALS_WORLD` (240 x 160, classic24 chart)."""
    if "m" not in _BUILT:
        def build(tmp: Path) -> None:
            _capture(materials_world(), tmp / "raw", CapturePlan("scan", steps=24, passes=1,
                                                                  camera_angles_deg=(0.0,)), True, 3)

        root = _built_once(tmp_path_factory, "materials-session", build, ("raw",)) / "raw"
        _BUILT["m"] = SimpleNamespace(root=root)
    return _BUILT["m"].root


def materials_world() -> World:
    """The world of :func:`materials_session` (its truth: region labels per pixel, materials per region)."""
    return World.hawk(4_000, width=240, height=160, chart_layout="classic24", **MATERIALS_WORLD)
