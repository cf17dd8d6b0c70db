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

__all__ = ["LIGHT_COLOURS", "StatusLight", "Banner", "Panel", "browse_row", "StepStrip", "WrapLabel"]

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

                logging.getLogger("kogei.gui").info("details of the message above:\n%s", traceback.format_exc())
                self.error.emit(describe_error(exc))
        return slot


def browse_row(field: QLineEdit, browse: Callable[[], None]) -> QHBoxLayout:
    """A path field with a "Browse…" button after it that calls ``browse``; the field's tooltip is its
    placeholder text unless it has one."""
    button = QPushButton("Browse…")
    button.setToolTip("choose it in a file dialog")
    if not field.toolTip():
        field.setToolTip(field.placeholderText())
    button.clicked.connect(browse)
    row = QHBoxLayout()
    row.addWidget(field, 1)
    row.addWidget(button)
    return row


class StepStrip(QWidget):
    """The station's steps in a row, the next one highlighted, and one line on what to do there.

    ``step_clicked(name)`` is emitted when a step is clicked (the window shows its tab).
    """

    step_clicked = Signal(str)

    def __init__(self, steps: tuple[str, ...], parent: QWidget | None = None) -> None:
        super().__init__(parent)
        row = QHBoxLayout(self)
        row.setContentsMargins(0, 0, 0, 0)
        self.buttons: dict[str, QPushButton] = {}
        for i, name in enumerate(steps):
            if i:
                row.addWidget(QLabel("→"))
            b = QPushButton(name)
            b.setFlat(True)
            b.setToolTip(f"show the tab of the {name} step")
            b.clicked.connect(lambda _=False, n=name: self.step_clicked.emit(n))
            row.addWidget(b)
            self.buttons[name] = b
        self.hint = QLabel("")
        self.hint.setWordWrap(True)
        row.addWidget(self.hint, 1)
        self.current = ""

    def set_current(self, step: str, hint: str) -> None:
        self.current = step
        for name, b in self.buttons.items():
            b.setStyleSheet("background:#1f5fa8; color:white; font-weight:bold; border-radius:3px; padding:2px 6px;"
                            if name == step else "color:#444; padding:2px 6px;")
        self.hint.setText(hint)


class WrapLabel(QLabel):
    """A word-wrapped label that is always as tall as its text at its width (a plain wrapped QLabel in a
    column can be given less height than its lines need, and then shows them cut)."""

    def __init__(self, text: str = "", parent: QWidget | None = None) -> None:
        super().__init__(text, parent)
        self.setWordWrap(True)
        self.setAlignment(Qt.AlignmentFlag.AlignLeft | Qt.AlignmentFlag.AlignTop)

    def _fit(self) -> None:
        height = self.heightForWidth(self.width()) if self.width() > 0 else -1
        if height > 0:
            self.setMinimumHeight(height)

    def setText(self, text: str) -> None:  # noqa: N802 - Qt's name
        super().setText(text)
        self._fit()

    def resizeEvent(self, e: Any) -> None:  # noqa: N802 - Qt's name
        super().resizeEvent(e)
        self._fit()
