"""Resuming in the window never runs commands a session from another user or machine stored."""

from __future__ import annotations

import pytest

pytest.importorskip("PySide6.QtWidgets", reason="the window needs PySide6 (pip install 'kogei[gui]')")

from app.capture.devices import creator_record  # noqa: E402
from app.capture.runner import CapturePlan  # noqa: E402
from app.errors import UsageError  # noqa: E402
from app.gui.capture_panel import open_capture_session  # noqa: E402
from app.session import Session  # noqa: E402
from tests.gui.helpers import make_window  # noqa: E402

PLAN = CapturePlan(kind="scan", steps=4, passes=1, camera=True)


def _session(root, created_by):
    config = {"camera": {"kind": "gphoto2", "executable": str(root.parent / "not-a-camera.sh")}}
    settings = {"unattended": False, "device_config": config, "station": "gui", "created_by": created_by}
    Session.create(root, plan=PLAN.to_dict(), settings=settings).close()


@pytest.mark.parametrize("foreign", [True, False])
def test_a_foreign_sessions_stored_camera_program_is_refused(qtbot, tmp_path, foreign):
    here = creator_record()
    creator = {**here, "host": here["host"] + "-elsewhere"} if foreign else here
    root = tmp_path / "s"
    _session(root, creator)
    w = make_window(qtbot, tmp_path)
    w.devices.camera_kind.setCurrentText("none")
    w.session.root = root
    if foreign:
        with pytest.raises(UsageError, match="another user or machine.*not-a-camera.sh.*--trust-hooks"):
            open_capture_session(w.capture._capture_request())
        with Session.open(root):          # the window let go of the session
            pass
    else:
        session, plan, config = open_capture_session(w.capture._capture_request())
        assert config["camera"]["executable"].endswith("not-a-camera.sh")
        session.close()
