"""Manual 3-point registration: pick corresponding points on two passes' clouds.

The fallback of :func:`processing.geometry.registration.register_passes` (``picks``:
three or more corresponding points per pair, Kabsch / Umeyama without scale,
refined by ICP and verified).  Each pass's points come from its profiles and
the scanner calibration (:func:`processing.geometry.scan_points.profiles_to_points`),
as :func:`app.workflows.process_session.process_session` makes them; a click picks the
nearest *measured* point within a few pixels of the click, so a pick is
always a real 3-D point of the cloud, whichever projection is shown.  The
two clouds are drawn in the window's drawing process
(:class:`app.gui.plots.FigureDrawer`; a redraw of two scatters of thousands
of points takes 150-300 ms, too long for the event loop) and a click on the
bitmap is mapped back to the projection's coordinates
(:class:`app.gui.plots.PlotImage`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PySide6.QtCore import Signal
from PySide6.QtWidgets import (
    QComboBox,
    QDialog,
    QDialogButtonBox,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QSpinBox,
    QVBoxLayout,
    QWidget,
)

from app.gui.figures import pick_figure
from app.gui.plots import FigureDrawer, PlotImage
from app.gui.workers import JobContext, Lane

__all__ = ["PickDialog", "pass_points", "PROJECTIONS"]

#: Projections offered: label -> the two coordinate axes shown.
PROJECTIONS = {"top (x, y)": (0, 1), "front (x, z)": (0, 2), "side (y, z)": (1, 2)}
#: How far from a click (bitmap pixels) the nearest point may be to be picked.
PICK_RADIUS_PX = 6.0


def pass_points(root: Path, calibration: str | None, pass_no: int, max_points: int = 6000) -> np.ndarray:
    """The pass's points in its table frame (mm), evenly thinned to ``max_points``."""
    from app.capture.runner import load_pass_profiles
    from app.errors import UsageError
    from app.session import Session
    from app.workflows.calibration import load_calibration_source, session_calibration
    from processing.geometry.calibration import ScannerCalibration
    from processing.geometry.scan_points import profiles_to_points

    if calibration:
        cal = ScannerCalibration.from_dict(load_calibration_source(calibration))
    else:
        cal = session_calibration(root, Session.read(root))
    try:
        prof = load_pass_profiles(root, pass_no)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    z = prof["z_mm"]
    finite = z[np.isfinite(z)]
    if finite.size == 0:
        raise UsageError(f"pass {pass_no} has no valid point")
    lo, hi = float(finite.min()), float(finite.max())
    pad = 0.02 * max(hi - lo, 1.0)
    sp = profiles_to_points(prof["x_mm"], z, prof["angles_deg"], cal, range_mm=(max(lo - pad, 0.0), hi + pad))
    pts = sp.points[sp.confidence > 0]
    if len(pts) > max_points:
        pts = pts[np.linspace(0, len(pts) - 1, max_points).astype(int)]
    return pts


class PickDialog(QDialog):
    """Pick >= 3 corresponding points on pass A and pass B (see the module docstring)."""

    error = Signal(str)

    def __init__(self, root: Path, calibration: str | None, lane: Lane, drawer: FigureDrawer,
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setWindowTitle("Manual 3-point registration")
        self.root = root
        self.calibration = calibration
        self.lane = lane
        self.clouds: dict[str, np.ndarray] = {}
        self.picks: dict[str, list[np.ndarray]] = {"a": [], "b": []}
        v = QVBoxLayout(self)
        top = QHBoxLayout()
        self.pass_a = QSpinBox()
        self.pass_b = QSpinBox()
        for sb, val in ((self.pass_a, 1), (self.pass_b, 2)):
            sb.setRange(1, 99)
            sb.setValue(val)
        self.view = QComboBox()
        self.view.addItems(list(PROJECTIONS))
        load = QPushButton("Load passes")
        load.clicked.connect(self.load)
        undo = QPushButton("Undo last pick")
        undo.clicked.connect(self.undo)
        for w in (QLabel("Pass A"), self.pass_a, QLabel("Pass B"), self.pass_b, QLabel("View"), self.view, load, undo):
            top.addWidget(w)
        top.addStretch(1)
        v.addLayout(top)
        self.help = QLabel("Click the same feature on A and on B, in the same order; three or more well apart "
                           "points (not on a line).")
        self.help.setWordWrap(True)
        v.addWidget(self.help)
        self.plot = PlotImage(drawer, self, min_size=(600, 360))
        self.plot.clicked.connect(self.pick_at)
        v.addWidget(self.plot, 1)
        self.state = QLabel("load the passes")
        v.addWidget(self.state)
        self.buttons = QDialogButtonBox(QDialogButtonBox.StandardButton.Ok | QDialogButtonBox.StandardButton.Cancel)
        self.buttons.accepted.connect(self.accept)
        self.buttons.rejected.connect(self.reject)
        v.addWidget(self.buttons)
        self.view.currentTextChanged.connect(lambda _: self.draw())
        self.resize(1000, 640)
        self._update()

    @property
    def pair(self) -> tuple[int, int]:
        a, b = int(self.pass_a.value()), int(self.pass_b.value())
        return (a, b) if a < b else (b, a)

    def picked(self) -> tuple[np.ndarray, np.ndarray]:
        """``(points_on_lower_pass, points_on_higher_pass)`` as process_session takes them."""
        a, b = np.array(self.picks["a"]), np.array(self.picks["b"])
        return (a, b) if self.pass_a.value() < self.pass_b.value() else (b, a)

    def load(self) -> None:
        if self.pass_a.value() == self.pass_b.value():
            self.error.emit("choose two different passes")
            return
        root, cal, pa, pb = self.root, self.calibration, int(self.pass_a.value()), int(self.pass_b.value())

        def work(ctx: JobContext) -> dict[str, np.ndarray]:
            return {"a": pass_points(root, cal, pa), "b": pass_points(root, cal, pb)}

        self.state.setText("loading…")
        self.lane.run(work, "load passes", succeeded=self._loaded,
                      failed=lambda text, exc: (self.state.setText(text), self.error.emit(text)))

    def _loaded(self, clouds: dict[str, np.ndarray]) -> None:
        self.clouds = clouds
        self.picks = {"a": [], "b": []}
        self.draw()
        self._update()

    def set_picks(self, a: np.ndarray, b: np.ndarray) -> None:
        """Set the picks directly (scripted use)."""
        self.picks = {"a": [np.asarray(p, float) for p in a], "b": [np.asarray(p, float) for p in b]}
        self.draw()
        self._update()

    def undo(self) -> None:
        side = "a" if len(self.picks["a"]) > len(self.picks["b"]) else "b"
        if self.picks[side]:
            self.picks[side].pop()
        self.draw()
        self._update()

    def draw(self) -> None:
        """Draw both passes with their picks (in the drawing process)."""
        i, j = PROJECTIONS[self.view.currentText()]
        empty = np.zeros((0, 3))
        self.plot.plot(pick_figure, a=self.clouds.get("a", empty), b=self.clouds.get("b", empty),
                       picks_a=np.array(self.picks["a"]).reshape(-1, 3),
                       picks_b=np.array(self.picks["b"]).reshape(-1, 3), i=i, j=j, label_a=f"pass {self.pass_a.value()}", label_b=f"pass {self.pass_b.value()}")

    def pick_at(self, side: str, x: float, y: float) -> None:
        """Pick the point of pass ``side`` ('a' or 'b') nearest to ``(x, y)`` of the projection shown.

        Nothing is picked when no point lies within :data:`PICK_RADIUS_PX`
        pixels of the click.
        """
        pts = self.clouds.get(side)
        if pts is None or not len(pts):
            return
        i, j = PROJECTIONS[self.view.currentText()]
        d2 = (pts[:, i] - x) ** 2 + (pts[:, j] - y) ** 2
        best = int(np.argmin(d2))
        if np.sqrt(d2[best]) > PICK_RADIUS_PX * self.plot.data_per_pixel(side):
            self.state.setText(f"no point of {'A' if side == 'a' else 'B'} there: click on the cloud")
            return
        self.picks[side].append(pts[best].copy())
        self.draw()
        self._update()

    def _update(self) -> None:
        na, nb = len(self.picks["a"]), len(self.picks["b"])
        ok = na == nb and na >= 3
        self.buttons.button(QDialogButtonBox.StandardButton.Ok).setEnabled(ok)
        if self.clouds:
            self.state.setText(f"{na} picks on A, {nb} on B" + ("" if ok else " (need the same number, at least 3)"))
