"""Empty panes say what will appear in them: the Camera tab's frame and histogram panes show their title and
hint as text from the moment the window opens (before the drawing process has drawn anything), then the drawn
empty figure.  Ground truth: the hint texts the panel gives its empty plots."""

from __future__ import annotations

import pytest

pytest.importorskip("PySide6.QtWidgets", reason="the GUI tests need PySide6 (pip install 'kogei[gui]')")

from tests.gui.helpers import make_window


def test_the_empty_camera_tab_says_what_its_panes_will_show(qtbot, tmp_path):
    w = make_window(qtbot, tmp_path)
    w.tabs.setCurrentWidget(w.camera)
    frame, hist = w.camera.image_plot, w.camera.hist_plot
    # at once, as text (the figures are drawn in another process, which may still be starting)
    assert "Frame" in frame.text() and "open a chart frame of the session" in frame.text()
    assert "Linear signal" in hist.text() and "histogram" in hist.text()
    # then the drawn empty figures replace the text
    qtbot.waitUntil(lambda: frame.rgba is not None and hist.rgba is not None, timeout=60_000)
    assert not frame.pixmap().isNull() and not hist.pixmap().isNull() and frame.failure == hist.failure == ""
