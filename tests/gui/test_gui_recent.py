"""Reopening: the window reopens the last session on start, File > Recent sessions lists the sessions opened,
and a session moved or deleted since is said so in the window and taken off the list.

Ground truth: the session folders on disk (created, then moved away by the test) and the settings file the
test gives each window (a temporary ini file; the default locations point at a temporary folder too, see
conftest.py, so no test reads or writes the user's settings).
"""

from __future__ import annotations

import pytest

pytest.importorskip("PySide6.QtWidgets", reason="the GUI tests need PySide6 (pip install 'kogei[gui]')")

from PySide6.QtCore import QSettings, Qt

from app.gui.main_window import SETTINGS_APP, SETTINGS_ORG
from app.session import Session
from tests.gui.helpers import make_window

LEFT = Qt.MouseButton.LeftButton


def _session(root):
    Session.create(root, plan={"kind": "scan", "steps": 4, "passes": 1}, object_info={"name": root.name}).close()
    return root


def _open(qtbot, w, root) -> None:
    w.session.folder.setText(str(root))
    qtbot.mouseClick(w.session.open_button, LEFT)
    assert w.session.root == root, w.error_line.text()


def _recent_actions(w) -> list[str]:
    w._fill_recent_menu()
    return [a.text() for a in w.recent_menu.actions() if a.text() and not a.isSeparator()]


def test_the_last_session_reopens_and_recent_sessions_are_listed(qtbot, tmp_path):
    a, b = _session(tmp_path / "tsuba"), _session(tmp_path / "kogai")
    w = make_window(qtbot, tmp_path)
    assert w.session.root is None and w.message_kind == ""          # nothing to reopen the first time
    assert _recent_actions(w) == ["(none yet)"]
    _open(qtbot, w, a)
    _open(qtbot, w, b)
    assert w.recent_sessions() == [str(b), str(a)]                  # the latest first
    w.close()

    # a new window reopens the last session (kogai) and lists both
    w2 = make_window(qtbot, tmp_path)
    assert w2.session.root == b and w2.session.meta_edits["name"].text() == "kogai"
    assert w2.message_kind == "info" and "reopened the last session" in w2.error_line.text()
    assert _recent_actions(w2)[:2] == [str(b), str(a)]
    # the first one is moved away: the list says so, choosing it says what happened and takes it off
    a.rename(tmp_path / "tsuba-moved")
    assert _recent_actions(w2)[1] == f"{a}  (not found)"
    w2.recent_menu.actions()[1].trigger()
    assert w2.message_kind == "error" and "no longer there" in w2.error_line.text()
    assert "File > Open session" in w2.error_line.text()
    assert w2.recent_sessions() == [str(b)] and w2.session.root == b  # the open session stays open
    # a session of the list opens from the menu
    c = _session(tmp_path / "fuchi")
    _open(qtbot, w2, c)
    w2.recent_menu.actions()[1].trigger()                           # [fuchi, kogai]: kogai
    assert w2.session.root == b
    w2.close()

    # the last session itself deleted: the next window says so, opens nothing and forgets it
    b.rename(tmp_path / "kogai-moved")
    w3 = make_window(qtbot, tmp_path)
    assert w3.session.root is None
    assert w3.message_kind == "info" and "no longer there" in w3.error_line.text()
    assert w3.recent_sessions() == [str(c)]


def test_the_tests_never_touch_the_users_settings(tmp_path_factory):
    # conftest.py points QSettings' default locations at a temporary folder for the whole run
    default = QSettings(SETTINGS_ORG, SETTINGS_APP).fileName()
    assert default.startswith(str(tmp_path_factory.getbasetemp())), default
