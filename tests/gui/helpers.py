"""Shared helpers of the GUI tests: a window on temporary settings, the simulated station, waiting."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np


def make_window(qtbot, tmp_path: Path, name: str = "settings.ini"):
    from PySide6.QtCore import QSettings

    from app.gui.main_window import MainWindow

    settings = QSettings(str(tmp_path / name), QSettings.Format.IniFormat)
    w = MainWindow(settings)
    qtbot.addWidget(w)
    w.show()
    return w


def connect_instruments(qtbot, w, camera: bool = False) -> None:
    """Connect the turntable and the profiler from the Devices tab (without the camera unless ``camera``)."""
    if not camera:
        w.devices.camera_kind.setCurrentText("none")
    w.devices.connect_all()
    qtbot.waitUntil(lambda: all(w.link.states[n] == "connected" for n in ("turntable", "profiler")), timeout=10_000)


def station_window(qtbot, tmp_path: Path, *, camera: bool = False, name: str = "settings.ini", **station):
    """A window with a simulated station (``station``: its arguments) and both instruments connected."""
    w = make_window(qtbot, tmp_path, name)
    st = w.start_simulated_station(**station)
    connect_instruments(qtbot, w, camera)
    return w, st


def wait_capture(qtbot, w, timeout_s: float = 60.0, answer_prompts: bool = True) -> list[str]:
    """Run the event loop until the capture job ends, pressing Continue at each prompt; returns the prompts."""
    prompts: list[str] = []
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        qtbot.wait(20)
        if answer_prompts and not w.capture.prompt.isHidden():
            prompts.append(w.capture.prompt_text.text())
            qtbot.mouseClick(w.capture.prompt_go, _left())
        if w.capture.job is not None and w.capture.job.done:
            break
    qtbot.waitUntil(lambda: w.capture.start.isEnabled(), timeout=10_000)
    return prompts


def _left():
    from PySide6.QtCore import Qt

    return Qt.MouseButton.LeftButton


def same_profiles(a: list[dict], b: list[dict]) -> None:
    for pa, pb in zip(a, b, strict=True):
        np.testing.assert_allclose(pa["angles_deg"], pb["angles_deg"], rtol=0, atol=1e-9)
        np.testing.assert_array_equal(pa["x_mm"], pb["x_mm"])
        np.testing.assert_array_equal(pa["z_mm"], pb["z_mm"])



def library_capture(world, folder: Path, *, steps: int, passes: int, seed: int, **station) -> Path:
    """The plan captured through :func:`app.capture.runner.run_capture` alone, without the window: the ground truth
    the GUI tests compare with (a station's profiles are deterministic per seed, placement and table angle).
    The station lives in ``folder / "station"``; returns the session folder ``folder / "s"``."""
    from app.capture.devices import build_devices
    from app.capture.runner import CaptureHooks, CapturePlan, run_capture
    from app.session import Session
    from mocks.station import SimulatedStation

    plan = CapturePlan("scan", steps=steps, passes=passes, camera=False)
    with SimulatedStation(world, root=folder / "station", seed=seed, **station) as st:
        config = {"turntable": {"port": str(st.turntable_path)}, "profiler": {"port": str(st.profiler_path)}}
        s = Session.create(folder / "s", plan=plan.to_dict())
        try:
            run_capture(s, plan, build_devices(config, s.root), CaptureHooks(before_pass=lambda p, n: st.place(p)))
        finally:
            s.close()
    return folder / "s"


#: What a one-image material map of the simulated hawk may name besides the world's materials: the alloys the
#: head's nami-shibuichi cannot be told from in one image.
HAWK_LOOKALIKES = frozenset({"nami-shibuichi", "shiro-shibuichi", "jo-shibuichi", "shakudo", "bronze",
                             "nami-shibuichi-uchi-sanbu", "nami-shibuichi-soto-sanbu"})


def every_chart_found(qtbot, w, passes: int) -> None:
    """Open each pass's chart frame on the Camera tab: found where the world put it (3 px), verdict pass."""
    from PySide6.QtCore import Qt

    from mocks.chart_scene import chart_corners
    from processing.camera.chart_layout import chart_layout

    world = w.station.world
    truth = chart_corners(chart_layout("classic24"), world.width, world.height, world.chart_placement)
    w.tabs.setCurrentWidget(w.camera)
    w.camera.refresh_charts()
    assert w.camera.chart_frames.count() == passes
    for i in range(passes):
        w.camera.chart_frames.setCurrentIndex(i)
        w.camera.frame = None
        assert w.camera.chart_frame_button.isEnabled()
        qtbot.mouseClick(w.camera.chart_frame_button, Qt.MouseButton.LeftButton)
        qtbot.waitUntil(lambda: w.camera.frame is not None, timeout=60_000)
        assert w.camera.frame.chart is not None, w.camera.frame.chart_problem
        np.testing.assert_allclose(w.camera.frame.chart.corners, truth, atol=3.0)
        assert w.camera.chart_verdict.level == "pass"
