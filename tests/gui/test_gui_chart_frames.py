"""The chart frames of a session captured on the default simulated station (the one of ``kogei gui --mock``:
240 x 160 frames, a ColorChecker Classic on the backdrop): the Camera tab lists them by pass and finds the
chart in every one; the Spectra tab calibrates with the chart frame of the object frame's own pass; the chart's
four corners clicked on the Camera tab's frame place the patches, and the Spectra tab calibrates with them.

Ground truth: the simulated world's chart placement (:func:`mocks.chart_scene.chart_corners`, the chart's
outer corners in sensor pixels) -- the chart lies on the backdrop, so it is the same in every pass.
"""

from __future__ import annotations

import pytest

pytest.importorskip("PySide6.QtWidgets", reason="the GUI tests need PySide6 (pip install 'kogei[gui]')")

import numpy as np
from PySide6.QtCore import QPoint, Qt

from mocks.chart_scene import chart_corners
from mocks.world import STATION_FRAME_SIZE
from processing.camera.chart_layout import chart_layout
from tests.gui.helpers import connect_instruments, make_window, wait_capture

LEFT = Qt.MouseButton.LeftButton


def _wait_frame(qtbot, w):
    qtbot.waitUntil(lambda: w.camera.frame is not None and not w.camera.image_plot.busy
                    and w.camera.image_plot.rgba is not None and not w.work_lane.busy, timeout=60_000)


def test_every_pass_chart_is_found_listed_by_pass_and_corners_can_be_clicked(qtbot, tmp_path):
    w = make_window(qtbot, tmp_path)
    st = w.start_simulated_station(triangles=2000, n_points=96)          # the --mock station's camera and chart
    assert (st.world.width, st.world.height) == STATION_FRAME_SIZE
    connect_instruments(qtbot, w, camera=True)
    w.session.folder.setText(str(tmp_path / "s"))
    qtbot.mouseClick(w.session.new_button, LEFT)
    w.capture.steps.setValue(6)
    w.capture.passes.setValue(3)
    w.capture.camera_angles.setText("0")
    qtbot.mouseClick(w.capture.start, LEFT)
    wait_capture(qtbot, w, timeout_s=300)
    assert w.capture.status_text == "complete", w.error_line.text()
    truth = chart_corners(chart_layout("classic24"), *STATION_FRAME_SIZE, st.world.chart_placement)

    w.tabs.setCurrentWidget(w.camera)
    w.camera.refresh_charts()
    labels = [w.camera.chart_frames.itemText(i) for i in range(w.camera.chart_frames.count())]
    assert labels == ["pass 1 chart frame", "pass 2 chart frame", "pass 3 chart frame"]
    assert w.camera.chart_frames.currentIndex() == 0                   # pass 1's first, as the Spectra tab
    for i in range(3):
        w.camera.chart_frames.setCurrentIndex(i)
        w.camera.frame = None
        qtbot.mouseClick(w.camera.chart_frame_button, LEFT)
        _wait_frame(qtbot, w)
        view = w.camera.frame
        assert view.path.parent.parent.name == f"p0{i + 1}"
        assert view.chart is not None, f"pass {i + 1}: {view.chart_problem}"
        # 3 sensor px: the refined homography's corners on a 168 px wide card in a 2x2-binned preview
        np.testing.assert_allclose(view.chart.corners, truth, atol=3.0)
        assert view.chart.confidence >= 0.9 and "clipped" not in view.qualities

    # the four corners clicked on pass 2's frame: the patches are placed from them
    w.camera.chart_frames.setCurrentIndex(1)
    qtbot.mouseClick(w.camera.chart_frame_button, LEFT)
    _wait_frame(qtbot, w)
    view = w.camera.frame
    qtbot.mouseClick(w.camera.corners_button, LEFT)
    assert "top-left" in w.camera.state.text()
    preview_truth = view.raw.from_sensor(truth)
    for k, (x, y) in enumerate(preview_truth):
        px, py = w.camera.image_plot.widget_point("frame", x, y)
        qtbot.mouseClick(w.camera.image_plot, LEFT, pos=QPoint(round(px), round(py)))
        if k < 3:
            assert f"corner {k + 1} of 4 marked" in w.camera.state.text()
            qtbot.waitUntil(lambda: not w.camera.image_plot.busy, timeout=30_000)
    qtbot.waitUntil(lambda: w.camera.frame is not view and w.camera.frame.chart is not None
                    and w.camera.frame.chart.method == "manual", timeout=60_000)
    # a click lands on a whole widget pixel: within one preview pixel (2 sensor px) of the true corner
    np.testing.assert_allclose(w.camera.frame.chart.corners, truth, atol=2.0)
    chart2 = str(view.path)
    assert chart2 in w.camera.manual_corners and chart2 in w.spectra.manual_corners

    # the Spectra tab: each object frame is calibrated with its own pass's chart frame
    w.tabs.setCurrentWidget(w.spectra)
    qtbot.mouseClick(w.spectra.list_button, LEFT)
    assert w.spectra.frames.currentText().startswith("p01/") and w.spectra.chart_frames.currentText() == labels[0]
    qtbot.mouseClick(w.spectra.load_button, LEFT)
    qtbot.waitUntil(lambda: w.spectra.scene is not None, timeout=60_000)
    assert "pass 1 chart frame" in w.spectra.state.text() and w.spectra.scene.usable_patches >= 20
    second = next(i for i in range(w.spectra.frames.count()) if w.spectra.frames.itemText(i).startswith("p02/"))
    w.spectra.frames.setCurrentIndex(second)
    assert w.spectra.chart_frames.currentText() == labels[1]
    w.spectra.scene = None
    qtbot.mouseClick(w.spectra.load_button, LEFT)
    qtbot.waitUntil(lambda: w.spectra.scene is not None, timeout=60_000)
    assert "pass 2 chart frame (corners marked by hand)" in w.spectra.state.text()
    assert w.error_line.text() == ""
