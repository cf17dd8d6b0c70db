"""Guidance in the window: every control explains itself in a tooltip, the step strip follows what has been
done, and each quality figure gets the verdict its thresholds give.

Ground truth: the controls the window holds (walked, not listed by hand), the session store's state, and the
thresholds stated in :mod:`app.gui.guidance`.
"""

from __future__ import annotations

import pytest

pytest.importorskip("PySide6.QtWidgets", reason="the GUI tests need PySide6 (pip install 'kogei[gui]')")

from PySide6.QtWidgets import QAbstractButton, QAbstractSpinBox, QComboBox, QLineEdit, QTabBar

from app.gui.guidance import calibration_hint, camera_verdict, chart_verdict, registration_verdict, sphere_verdict
from tests.gui.helpers import connect_instruments, make_window


def test_every_button_and_input_of_the_window_has_a_tooltip(qtbot, tmp_path):
    w = make_window(qtbot, tmp_path)
    controls = []
    for cls in (QAbstractButton, QLineEdit, QComboBox, QAbstractSpinBox):
        for c in w.findChildren(cls):
            if c.objectName().startswith("qt_") or isinstance(c.parent(), (QComboBox, QAbstractSpinBox, QTabBar)):
                continue                    # Qt's own parts (a dock's close button, a spin box's editor)
            controls.append(c)
    assert len(controls) > 80
    missing = [f"{type(c).__name__} {getattr(c, 'text', lambda: '')()!r} on {c.parent().__class__.__name__}"
               for c in controls if not c.toolTip().strip()]
    assert not missing, "controls without a tooltip:\n" + "\n".join(missing)


def test_the_step_strip_follows_the_session(qtbot, tmp_path):
    w = make_window(qtbot, tmp_path)
    assert w.steps.current == "Devices" and "connect the turntable" in w.steps.hint.text()
    w.start_simulated_station(triangles=2000, n_points=64)
    connect_instruments(qtbot, w)
    qtbot.waitUntil(lambda: w.steps.current == "Calibrate", timeout=10_000)
    w.processing.calibration.setText(str(tmp_path / "calibration"))
    assert w.steps.current == "Session"
    w.session.folder.setText(str(tmp_path / "s"))
    w.session.new_button.click()
    assert w.steps.current == "Capture" and "press Start" in w.steps.hint.text()
    w.steps.buttons["Materials"].click()                 # a step's button shows its tab
    assert w.tabs.currentWidget() is w.spectra


@pytest.mark.parametrize(("verdict", "level"), [
    (sphere_verdict(0.05), "pass"), (sphere_verdict(0.10), "pass"), (sphere_verdict(0.2), "warn"),
    (sphere_verdict(0.3), "fail"),
    (chart_verdict(0.96), "pass"), (chart_verdict(0.75), "warn"), (chart_verdict(0.25), "fail"),
    (chart_verdict(0.0, "manual"), "pass"),
    (registration_verdict(0.05, 0.03, True), "pass"), (registration_verdict(0.10, 0.03, True), "warn"),
    (registration_verdict(0.135, 0.03, True), "fail"), (registration_verdict(0.03, 0.03, False), "fail"),
    (registration_verdict(None, None, False), "fail"),
    (camera_verdict(0.12), "pass"), (camera_verdict(0.5), "pass"), (camera_verdict(0.8), "warn"),
    (camera_verdict(1.2), "fail"),
])
def test_each_quality_figure_gets_its_thresholds_verdict_and_a_reason(verdict, level):
    assert verdict.level == level
    assert verdict.why and "pass" in verdict.thresholds and verdict.level.upper() in verdict.html()


def test_the_window_fits_1024_by_700(qtbot, tmp_path):
    """Every tab fits a 1024 x 700 window (the tall and wide panels scroll or wrap instead of forcing a
    bigger window)."""
    w = make_window(qtbot, tmp_path)
    w.capture.prompt_text.setText("Pass 2 of 3: Re-place the object in a new orientation and put the colour chart "
                                  "in view of the camera, then press Continue.")
    w.capture.prompt.show()                       # the tallest state of the Capture tab
    w.resize(1024, 700)
    qtbot.waitUntil(lambda: w.size().width() == 1024 and w.size().height() == 700, timeout=5_000)
    for i in range(w.tabs.count()):
        w.tabs.setCurrentIndex(i)
        assert w.minimumSizeHint().width() <= 1024 and w.minimumSizeHint().height() <= 700, w.tabs.tabText(i)
    # a placement prompt is scrolled into view in the short window
    w.tabs.setCurrentWidget(w.capture)
    w.capture._show_prompt("Pass 3 of 3: Re-place the object in a new orientation, then press Continue.")
    qtbot.wait(100)
    go = w.capture.prompt_go
    top_left = go.mapTo(w.capture.controls_scroll.viewport(), go.rect().topLeft())
    bottom = top_left.y() + go.height()
    assert 0 <= top_left.y() and bottom <= w.capture.controls_scroll.viewport().height()


def test_the_help_menu_lists_the_steps_and_says_what_kogei_is(qtbot, tmp_path):
    from app.gui.guidance import STEPS

    w = make_window(qtbot, tmp_path)
    menus = [a.text() for a in w.menuBar().actions()]
    assert "&Help" in menus
    text = w.steps_help_text()
    assert all(f"{i}. {s}:" in text for i, s in enumerate(STEPS, start=1))
    assert w.about_text().startswith("kogei ")


def test_the_processing_tab_needs_no_scrolling_at_the_default_size(qtbot, tmp_path):
    """The Processing tab scrolls only when the window is short: at 1360 x 900 the residual trees take the room
    there is instead of pushing the verdicts below the fold."""
    w = make_window(qtbot, tmp_path)
    w.resize(1360, 900)
    w.tabs.setCurrentWidget(w.processing)
    qtbot.wait(100)
    area = w.processing.scroll_area
    assert area.widget().height() <= area.viewport().height()


def test_the_camera_and_lamp_calibrations_are_guided_in_order():
    """After the scanner: the board's capture, its camera calibration, the chrome sphere's capture, its lamp
    calibration; each calibration waits for what it needs (the scanner for the camera, the camera for the lamps)."""
    board = {"target": "camera-calibration"}
    chrome = {"target": "lamp-calibration"}
    assert calibration_hint({}) is None                                      # the scanner's step says it
    assert "ChArUco board" in calibration_hint({"calibrated": True})
    assert "press Start" in calibration_hint({**board, "calibrated": True})
    assert "scanner first" in calibration_hint({**board, "target_captured": True})
    assert "Calibrate the camera" in calibration_hint({**board, "target_captured": True, "calibrated": True})
    assert "chrome sphere" in calibration_hint({"calibrated": True, "camera": True})
    assert "camera first" in calibration_hint({**chrome, "target_captured": True, "calibrated": True})
    assert "Calibrate the lamps" in calibration_hint({**chrome, "target_captured": True, "calibrated": True,
                                                      "camera": True})
    assert calibration_hint({"calibrated": True, "camera": True, "lamps": True}) is None
