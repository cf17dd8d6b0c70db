"""A whole session on the default simulated station (``kogei gui --mock``: 240 x 160 frames, the ColorChecker
on the backdrop) driven through the window's own widgets only: the reference sphere put on the table, scanned and
calibrated; the hawk put back, captured in three passes with photos; processed; every pass's chart found; a
frame's spectra calibrated and its material map made; the mesh previewed.  The step strip follows along.

Ground truth: the session store (status, products), the sphere calibration's verdict thresholds, the world's
chart placement (:func:`mocks.chart_scene.chart_corners`) and the world's materials (the map may name only
materials of the simulated hawk, or say that none fits).
"""

from __future__ import annotations

import pytest

pytest.importorskip("PySide6.QtWidgets", reason="the GUI tests need PySide6 (pip install 'kogei[gui]')")

from PySide6.QtCore import Qt

from app.gui.devices_panel import SIMULATED_OBJECTS
from app.session import Session
from mocks.world import STATION_FRAME_SIZE
from processing.materials.confidence import NEUTRAL_METAL, NO_FIT
from tests.gui.helpers import HAWK_LOOKALIKES, every_chart_found, make_window, wait_capture

LEFT = Qt.MouseButton.LeftButton


def _click(qtbot, button) -> None:
    assert button.isEnabled(), button.text()
    qtbot.mouseClick(button, LEFT)


def _put(qtbot, w, name: str) -> None:
    w.tabs.setCurrentWidget(w.devices)
    w.devices.sim_object.setCurrentText(name)
    _click(qtbot, w.devices.put_button)
    qtbot.waitUntil(lambda: w.devices.put_button.isEnabled(), timeout=120_000)


def _capture(qtbot, w, folder, *, steps: int, passes: int, angles: str, chart: bool) -> None:
    w.tabs.setCurrentWidget(w.session)
    w.session.folder.setText(str(folder))
    _click(qtbot, w.session.new_button)
    w.tabs.setCurrentWidget(w.capture)
    w.capture.steps.setValue(steps)
    w.capture.passes.setValue(passes)
    w.capture.camera_angles.setText(angles)
    w.capture.chart.setChecked(chart)
    _click(qtbot, w.capture.start)
    wait_capture(qtbot, w, timeout_s=600)
    assert w.capture.status_text == "complete", w.error_line.text()


def test_a_whole_session_through_the_window(qtbot, tmp_path):
    w = make_window(qtbot, tmp_path)
    _click(qtbot, w.devices.start_sim_button)                       # the --mock station, from its button
    qtbot.waitUntil(lambda: w.station is not None, timeout=120_000)
    assert (w.station.world.width, w.station.world.height) == STATION_FRAME_SIZE
    w.devices.camera_kind.setCurrentText("gphoto2")
    for name in ("turntable", "profiler"):
        _click(qtbot, w.devices.connect_buttons[name])
    qtbot.waitUntil(lambda: all(w.link.states[n] == "connected" for n in ("turntable", "profiler")), timeout=20_000)
    assert w.steps.current == "Calibrate"

    # calibration: the sphere on the table, one pass without photos, calibrated on the Processing tab
    _put(qtbot, w, SIMULATED_OBJECTS[1])
    _capture(qtbot, w, tmp_path / "sphere", steps=72, passes=1, angles="", chart=False)
    w.tabs.setCurrentWidget(w.processing)
    w.processing.radius.setValue(25.0)
    _click(qtbot, w.processing.calibrate_button)
    qtbot.waitUntil(lambda: w.processing.calibration.text() == str(tmp_path / "sphere"), timeout=120_000)
    assert w.processing.calibration_verdict.level == "pass", w.processing.cal_state.text()

    # the piece: three passes with a photo at 0 and 180 degrees, the chart first in each
    _put(qtbot, w, SIMULATED_OBJECTS[0])
    _capture(qtbot, w, tmp_path / "hawk", steps=72, passes=3, angles="0,180", chart=True)
    assert Session.read(tmp_path / "hawk")["status"] == "complete"
    qtbot.waitUntil(lambda: w.steps.current == "Process", timeout=20_000)     # the session re-read, complete

    # every pass's chart is found where the world put it (3 px: sub-pixel corners on 240 x 160)
    every_chart_found(qtbot, w, 3)

    # processing: registered and meshed
    w.tabs.setCurrentWidget(w.processing)
    w.processing.preset.setCurrentText("draft")
    _click(qtbot, w.processing.run_button)
    qtbot.waitUntil(lambda: not w.processing.running, timeout=900_000)
    assert w.processing.report is not None, w.error_line.text()
    assert (tmp_path / "hawk" / "products" / "mesh.ply").exists()
    qtbot.waitUntil(lambda: w.processing.mesh_image is not None, timeout=300_000)    # the mesh view shows it
    assert w.processing.mesh_mask.mean() > 0.02
    qtbot.waitUntil(lambda: w.steps.current == "Materials", timeout=20_000)

    # spectra: a frame calibrated with its own pass's chart, the map made with what can be judged
    w.tabs.setCurrentWidget(w.spectra)
    _click(qtbot, w.spectra.list_button)
    _click(qtbot, w.spectra.load_button)
    qtbot.waitUntil(lambda: w.spectra.scene is not None, timeout=120_000)
    assert "pass 1 chart frame" in w.spectra.state.text() and w.spectra.scene.usable_patches >= 20
    _click(qtbot, w.spectra.map_button)
    qtbot.waitUntil(lambda: w.spectra.map is not None or "material map:" in w.error_line.text(), timeout=120_000)
    if w.spectra.map is not None:
        truth_materials = set(w.station.world.materials.values())
        named = set(w.spectra.map[1].values()) - {"uncertain", NO_FIT, NEUTRAL_METAL}
        assert named <= truth_materials | HAWK_LOOKALIKES, named
        assert "of the object" in w.spectra.state.text()
        assert w.steps.current == "Preview"

    # preview: the mesh rendered
    w.tabs.setCurrentWidget(w.preview)
    qtbot.waitUntil(lambda: w.preview.last is not None and not w.preview._busy, timeout=300_000)
    assert w.preview.last["mask"].mean() > 0.02
    assert w.message_kind != "error", w.error_line.text()
