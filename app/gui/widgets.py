"""Small widgets shared by the panels: a status light, a labelled group, a banner.

Examples
--------
>>> LIGHT_COLOURS["connected"], LIGHT_COLOURS["lost"]
('#2e9e44', '#d0312d')
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from PySide6.QtCore import Qt, Signal
from PySide6.QtWidgets import QHBoxLayout, QLabel, QLineEdit, QPushButton, QWidget

__all__ = ["LIGHT_COLOURS", "StatusLight", "Banner", "Panel", "browse_row"]

#: Colour of each instrument state.
LIGHT_COLOURS = {
    "disconnected": "#9a9a9a",
    "connecting": "#e0a800",
    "connected": "#2e9e44",
    "capture": "#2f6fd0",
    "lost": "#d0312d",
    "ready": "#2e9e44",
    "problem": "#d0312d",
}


class StatusLight(QLabel):
    """A round light with a tooltip naming the state."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setFixedSize(16, 16)
        self.state = ""
        self.set_state("disconnected")

    def set_state(self, state: str, detail: str = "") -> None:
        self.state = state
        colour = LIGHT_COLOURS.get(state, "#9a9a9a")
        self.setStyleSheet(f"background:{colour}; border-radius:8px; border:1px solid #555;")
        self.setToolTip(f"{state}{': ' + detail if detail else ''}")


class Banner(QLabel):
    """A strip for warnings that must not be missed (a device that dropped out); hidden when empty."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setWordWrap(True)
        self.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.setStyleSheet("background:#fbe3e2; color:#7a1512; border:1px solid #d0312d; padding:6px;"
                           "font-weight:bold;")
        self.hide()

    def show_text(self, text: str) -> None:
        self.setText(text)
        self.setVisible(bool(text))


class Panel(QWidget):
    """Base of the panels: ``error``, ``notice`` and ``log`` signals, and :meth:`safe` for button handlers.

    ``notice`` is for what the user asked for and should know about but is not
    a fault (a capture or a processing run stopped at the user's request).

    A handler wrapped by :meth:`safe` never lets an exception escape into
    Qt's event loop: its readable message goes to ``error`` (the window shows
    it and writes it to the log panel).
    """

    error = Signal(str)
    notice = Signal(str)
    log = Signal(str)

    def safe(self, fn: Callable[..., Any]) -> Callable[..., None]:
        def slot(*args: Any) -> None:
            try:
                fn()
            except Exception as exc:  # noqa: BLE001 - shown in the window, never lost
                import logging
                import traceback

                from app.gui.workers import describe_error

                logging.getLogger("kogei.gui").info("handler failed:\n%s", traceback.format_exc())
                self.error.emit(describe_error(exc))
        return slot


def browse_row(field: QLineEdit, browse: Callable[[], None]) -> QHBoxLayout:
    """A path field with a "Browse…" button after it that calls ``browse``."""
    button = QPushButton("Browse…")
    button.clicked.connect(browse)
    row = QHBoxLayout()
    row.addWidget(field, 1)
    row.addWidget(button)
    return row
