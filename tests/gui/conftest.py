"""GUI tests run offscreen; they skip (with the reason) only where PySide6 cannot be imported."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

try:
    import PySide6  # noqa: F401
except ImportError as exc:           # pragma: no cover - PySide6 is a dependency; this guards odd machines
    collect_ignore_glob = ["test_*.py"]
    _REASON = f"PySide6 cannot be imported ({exc})"

    def pytest_collection_modifyitems(config, items):  # noqa: D103
        for item in items:
            item.add_marker(pytest.mark.skip(reason=_REASON))
