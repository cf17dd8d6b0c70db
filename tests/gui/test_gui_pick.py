"""The manual registration dialog picks by clicking on a bitmap drawn in the drawing process: the click is
mapped back through the drawing's axes to the projection's coordinates, and the nearest measured point is
picked (or none, away from the cloud)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("PySide6.QtWidgets", reason="the GUI tests need PySide6 (pip install 'kogei[gui]')")

from PySide6.QtCore import QPoint, Qt

from app.gui.pick_dialog import PROJECTIONS, PickDialog
from app.gui.plots import FigureDrawer
from app.gui.workers import Lane

LEFT = Qt.MouseButton.LeftButton


@pytest.fixture
def dialog(qtbot, tmp_path: Path):
    drawer = FigureDrawer()
    dlg = PickDialog(tmp_path, None, Lane(1), drawer)
    qtbot.addWidget(dlg)
    dlg.show()
    rng = np.random.default_rng(7)
    dlg.clouds = {"a": rng.uniform(-50, 50, (150, 3)), "b": rng.uniform(-50, 50, (150, 3)) + [5.0, 0.0, 0.0]}
    yield dlg
    drawer.shutdown()


def _drawn(qtbot, dlg, draws: int) -> None:
    qtbot.waitUntil(lambda: dlg.plot.draws >= draws and not dlg.plot.busy, timeout=30_000)
    assert dlg.plot.failure == ""


def _loneliest(pts: np.ndarray, i: int, j: int) -> int:
    """The point whose nearest neighbour in the projection is farthest (a click on it is unambiguous)."""
    p = pts[:, [i, j]]
    d = np.sqrt(((p[:, None, :] - p[None, :, :]) ** 2).sum(axis=2))
    np.fill_diagonal(d, np.inf)
    return int(np.argmax(d.min(axis=1)))


@pytest.mark.parametrize("view", ["top (x, y)", "side (y, z)"])
def test_a_click_on_a_drawn_point_picks_that_point(qtbot, dialog, view):
    dialog.view.setCurrentText(view)          # redraws
    dialog.draw()
    _drawn(qtbot, dialog, 1)
    i, j = PROJECTIONS[view]
    for side, n_draws in (("a", 2), ("b", 3)):
        pts = dialog.clouds[side]
        k = _loneliest(pts, i, j)
        x, y = dialog.plot.widget_point(side, pts[k, i], pts[k, j])
        qtbot.mouseClick(dialog.plot, LEFT, pos=QPoint(round(x), round(y)))
        assert len(dialog.picks[side]) == 1
        np.testing.assert_array_equal(dialog.picks[side][0], pts[k])
        _drawn(qtbot, dialog, n_draws)                # the pick is drawn, numbered
    assert dialog.state.text().startswith("1 picks on A, 1 on B")


def test_a_click_away_from_the_cloud_picks_nothing_and_says_so(qtbot, dialog):
    dialog.draw()
    _drawn(qtbot, dialog, 1)
    ax = dialog.plot.axes_named("a")
    i, j = PROJECTIONS[dialog.view.currentText()]
    far_x = ax["xlim"][0] + 0.02 * (ax["xlim"][1] - ax["xlim"][0])     # a corner of the axes, outside the cloud
    far_y = ax["ylim"][1] - 0.02 * (ax["ylim"][1] - ax["ylim"][0])
    pts = dialog.clouds["a"]
    gap = np.sqrt((pts[:, i] - far_x) ** 2 + (pts[:, j] - far_y) ** 2).min()
    assert gap > 8 * dialog.plot.data_per_pixel("a")                   # really away from every point
    x, y = dialog.plot.widget_point("a", far_x, far_y)
    qtbot.mouseClick(dialog.plot, LEFT, pos=QPoint(round(x), round(y)))
    assert dialog.picks == {"a": [], "b": []}
    assert "no point of A there" in dialog.state.text()
