"""The capture tab offers the light-probe plan: picking it shows its defaults and gives the brackets' plan."""

from __future__ import annotations

import pytest

pytest.importorskip("PySide6.QtWidgets", reason="the GUI tests need PySide6 (pip install 'kogei[gui]')")

from app.capture.runner import PROBE_BRACKETS
from tests.gui.helpers import make_window


def test_probe_plan_from_the_capture_tab(qtbot, tmp_path):
    w = make_window(qtbot, tmp_path)
    w.capture.link.camera = {"kind": "gphoto2", "executable": "gphoto2"}      # a probe takes only RAW frames
    w.capture.kind.setCurrentText("probe")
    assert w.capture.kind.currentText() == "probe"
    assert (w.capture.steps.value(), w.capture.passes.value(), w.capture.chart.isChecked()) == (1, 1, True)
    plan = w.capture.plan()
    assert plan.kind == "probe" and plan.brackets == PROBE_BRACKETS
    assert [a.kind for a in plan.actions()] == ["chart"] + ["frame"] * len(PROBE_BRACKETS)
