"""The window on a posed session: the Camera tab draws the mesh's outline, projected with the calibrated
camera, over a frame, and the Processing tab shows the session's camera and lamp calibration.

Ground truth: the session is built with the simulated camera's true intrinsics and pose and the
object's own mesh (:mod:`tests.integration.posed_session`), so the drawn outline must be the outline
of the object the simulation rendered.
"""

from __future__ import annotations

import pytest

pytest.importorskip("PySide6.QtWidgets", reason="the GUI tests need PySide6 (pip install 'kogei[gui]')")

import numpy as np
from PySide6.QtCore import Qt

from processing.appearance.silhouette import silhouette_check
from tests.gui.helpers import make_window
from tests.integration.posed_session import ANGLES_DEG, build_posed_session


def test_camera_tab_draws_the_mesh_outline_on_a_posed_frame(qtbot, tmp_path):
    import cv2

    from app.workflows.posed_frames import project_session

    root = tmp_path / "session"
    built = build_posed_session(root)
    project_session(root)
    w = make_window(qtbot, tmp_path)
    w.session.open_session(str(root))
    qtbot.waitUntil(lambda: w.camera.posed_list.count() == len(ANGLES_DEG), timeout=30_000)
    assert "reprojection rms 0.050 px" in w.processing.station_state.text()
    assert "lamps: 1 located" in w.processing.station_state.text()
    w.tabs.setCurrentWidget(w.camera)
    w.camera.posed_list.setCurrentIndex(2)
    qtbot.mouseClick(w.camera.posed_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: w.camera.frame is not None and w.camera.frame.mesh_outlines is not None
                    and w.camera.image_plot.draws >= 1 and not w.camera.image_plot.busy, timeout=60_000)
    view = w.camera.frame
    assert "p01/frame/02" in w.camera.state.text() and "silhouette IoU" in w.camera.state.text()
    # the outline drawn (in the 2x2-binned preview's pixels) encloses the object the simulation rendered
    (line,) = view.mesh_outlines
    h, w_ = view.preview.shape[:2]
    drawn = np.zeros((h, w_), np.uint8)
    cv2.fillPoly(drawn, [np.round(line).astype(np.int32)], 1)
    labels = built["world"].frame("object", ANGLES_DEG[2]).labels >= 0
    truth = cv2.resize(labels.astype(np.uint8), (w_, h), interpolation=cv2.INTER_AREA) > 0
    assert silhouette_check(drawn.astype(bool), truth)["iou"] > 0.95
