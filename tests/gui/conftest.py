"""GUI tests run offscreen (no display needed), and never read or write the user's settings."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")


@pytest.fixture(autouse=True, scope="session")
def _settings_in_a_temporary_folder(tmp_path_factory):
    """Point QSettings' default locations at a temporary folder: a window made without a settings file of its
    own (``MainWindow()``) stores nothing in the user's configuration."""
    try:
        from PySide6.QtCore import QSettings
    except ImportError:                  # the GUI tests skip themselves without PySide6
        yield None
        return
    folder = tmp_path_factory.mktemp("qsettings")
    for fmt in (QSettings.Format.NativeFormat, QSettings.Format.IniFormat):
        for scope in (QSettings.Scope.UserScope, QSettings.Scope.SystemScope):
            QSettings.setPath(fmt, scope, str(folder))
    yield folder
