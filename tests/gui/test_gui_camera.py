"""The camera panel: a RAW frame shot through the fake gphoto2 of the simulated station, decoded, with the
chart found and outlined; a saturated shot raises the clipping warning and marks clipped patches.

Ground truth: the simulated world's chart placement (:func:`mocks.chart_scene.chart_corners` gives the
chart's outer corners in sensor pixels) and the camera fault switch that saturates the sensor.
"""

from __future__ import annotations

import pytest

pytest.importorskip("PySide6.QtWidgets", reason="the GUI tests need PySide6 (pip install 'kogei[gui]')")

import numpy as np
from PySide6.QtCore import Qt

from mocks.chart_scene import chart_corners
from mocks.world import World
from processing.camera.chart_layout import chart_layout
from tests.gui.helpers import make_window

W, H = 600, 400


def test_shot_shows_the_chart_its_patches_and_the_clipping(qtbot, tmp_path):
    w = make_window(qtbot, tmp_path)
    world = World.hawk(2000, width=W, height=H, chart_layout="classic24")
    st = w.start_simulated_station(world=world, seed=2, n_points=96)
    w.tabs.setCurrentWidget(w.camera)
    # the first frame after a placement shows the chart (the station's convention)
    qtbot.mouseClick(w.camera.shoot_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: w.camera.frame is not None and w.camera.image_plot.draws >= 1
                    and w.camera.hist_plot.draws >= 1 and not w.camera.image_plot.busy
                    and not w.camera.hist_plot.busy, timeout=60_000)
    view = w.camera.frame
    assert view.chart is not None, view.chart_problem
    truth = chart_corners(chart_layout("classic24"), W, H, world.chart_placement)
    np.testing.assert_allclose(view.chart.corners, truth, atol=3.0)
    assert view.quads.shape == (24, 4, 2) and len(view.qualities) == 24
    assert "clipped" not in view.qualities
    assert w.camera.clip_warning.text() == ""
    assert w.camera.image_plot.rgba is not None and w.camera.hist_plot.rgba is not None

    # a saturated sensor: the warning names the clipped share; the white patch (19) is marked clipped
    st.apply_faults({"camera": {"saturate": True}})
    st.place(1)                                    # the chart again in the next frame
    w.camera.frame = None
    qtbot.mouseClick(w.camera.shoot_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: w.camera.frame is not None and not w.camera.image_plot.busy, timeout=60_000)
    view = w.camera.frame
    clipped = float(view.saturated.mean())
    assert clipped > 0.001
    assert f"{100 * clipped:.2f}% of the pixels are clipped" in w.camera.clip_warning.text()
    if view.chart is not None:
        assert view.qualities[18] == "clipped"
        # the chart's own patches are clipped: a warning that names them (not the note about object highlights)
        assert w.camera.clip_level == "warn" and "19" in w.camera.clip_warning.text().split("among them")[0]
    else:                                          # or the chart cannot be found at all in a blown-out frame
        assert view.chart_problem


def test_camera_without_a_camera_chosen_is_a_readable_error(qtbot, tmp_path):
    w = make_window(qtbot, tmp_path)
    w.devices.camera_kind.setCurrentText("none")
    w.devices.apply()
    qtbot.mouseClick(w.camera.shoot_button, Qt.MouseButton.LeftButton)
    assert "no camera chosen" in w.error_line.text()
    w.devices.camera_kind.setCurrentText("gphoto2")
    w.devices.camera_path.setText(str(tmp_path / "missing-gphoto2"))
    w.devices.apply()
    qtbot.mouseClick(w.camera.shoot_button, Qt.MouseButton.LeftButton)
    assert "was not found" in w.error_line.text() and "missing-gphoto2" in w.error_line.text()
