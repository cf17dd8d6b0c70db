"""A session from elsewhere whose session.json holds a field of the wrong kind, opened in the window.

Each field below made a slot of the window fail when the session was opened (a traceback on the console,
the panels half filled); now :meth:`app.session.Session.read` refuses the manifest and the window shows its
one line naming the field, with nothing half shown.
"""

from __future__ import annotations

import json

import pytest

pytest.importorskip("PySide6.QtWidgets", reason="the GUI tests need PySide6 (pip install 'kogei[gui]')")

from PySide6.QtCore import Qt

from app.session import MANIFEST, Session
from tests.gui.helpers import make_window

LEFT = Qt.MouseButton.LeftButton


@pytest.mark.parametrize("change, named", [
    (lambda m: m["object"].update(name=7), "object.name"),
    (lambda m: m["plan"].update(steps=None), "plan.steps"),
    (lambda m: m["captures"].update({"p01/chart": {"kind": "chart", "pass": "one", "file": "c.dng"}}),
     "captures.p01/chart.pass"),
    (lambda m: m["captures"].update({"p01/frame/00": {"kind": "frame", "pass": 1, "angle_deg": "ninety",
                                                       "file": "f.dng"}}), "captures.p01/frame/00.angle_deg"),
    (lambda m: m.update(camera_calibration={"rms_px": 0.1, "image_size": [960, 640], "source": "board"}),
     "camera_calibration.source"),
])
def test_a_wrong_kind_of_field_is_one_line_in_the_window(qtbot, tmp_path, change, named):
    root = tmp_path / "elsewhere"
    Session.create(root, plan={"kind": "scan", "steps": 4, "passes": 1}, object_info={"name": "bowl"}).close()
    manifest = json.loads((root / MANIFEST).read_text())
    change(manifest)
    (root / MANIFEST).write_text(json.dumps(manifest))
    errors: list[BaseException] = []
    import sys

    hook, sys.excepthook = sys.excepthook, lambda t, v, tb: errors.append(v)
    try:
        w = make_window(qtbot, tmp_path)
        w.session.folder.setText(str(root))
        qtbot.mouseClick(w.session.open_button, LEFT)
        qtbot.wait(50)
    finally:
        sys.excepthook = hook
    assert not errors, errors
    text = w.error_line.text()
    assert named in text and str(root) in text and "\n" not in text, text
    assert w.session.root is None                       # the session was not opened half-way
