"""``kogei gui``: the capture station's desktop window (:mod:`app.gui`).

``--mock`` starts a simulated station in the window (the same
:class:`mocks.station.SimulatedStation` as ``kogei mock``) and points the
Devices tab at it, so a whole session can be run without instruments.
"""

from __future__ import annotations

import argparse
import sys

from app.errors import UsageError

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("gui", help="the capture station's desktop window (devices, capture, processing, preview)",
                       description="Open the capture station window (PySide6).")
    p.add_argument("--mock", action="store_true",
                   help="start a simulated station (turntable, profiler, gphoto2) in the window")
    p.add_argument("--mock-triangles", type=int, default=4000, metavar="N",
                   help="triangle count of the simulated hawk (default 4000)")
    p.add_argument("--session", default=None, metavar="SESSION", help="open this session")


def run(args: argparse.Namespace) -> int:
    try:
        from PySide6.QtWidgets import QApplication
    except ImportError as exc:
        raise UsageError(f"the window needs PySide6 ({exc}); install it with: pip install 'kogei[gui]'") from None
    if args.mock_triangles < 100:
        raise UsageError(f"--mock-triangles must be at least 100, got {args.mock_triangles}")
    from app.gui.main_window import MainWindow

    app = QApplication.instance() or QApplication(sys.argv[:1])
    app.setApplicationName("kogei capture station")
    window = MainWindow()
    if args.mock:
        window.start_simulated_station(triangles=args.mock_triangles)
        window.devices.connect_all()
    if args.session:
        window.run_safely(lambda: window.session.open_session(args.session))
    window.show()
    return int(app.exec())
