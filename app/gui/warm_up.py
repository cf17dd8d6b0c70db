"""Load, before the window is shown, what would otherwise be loaded by a worker thread holding the interpreter lock.

Measured while a simulated session ran through the window (issue #7; see
the "gui" section of docs/BENCHMARKS.md): the event loop's longest stalls
while the machine was running the process (120-150 ms) came from
first uses in worker threads, during which a single C call holds the
interpreter lock -- Matplotlib's first text layout (its font list and
FreeType faces, on the drawing thread) and the import of colour-science's
dataset modules (unmarshalling their large code objects, on the preview's
render thread).  Doing both once on the GUI thread before the window is
shown moves that time to start-up, where nothing waits for the event loop.

Examples
--------
>>> warm_up() is warm_up()
True
"""

from __future__ import annotations

import functools
import importlib

__all__ = ["HEAVY_MODULES", "warm_up"]

#: Modules the window's worker threads import on first use, in the order a session needs them.
HEAVY_MODULES = ("colour", "open3d", "scipy.spatial", "app.capture", "app.capture_devices",
                 "processing.scan_points", "render.renderer", "app.scene_build")


@functools.cache
def warm_up() -> tuple[str, ...]:
    """Import :data:`HEAVY_MODULES` and lay out Matplotlib text once (per process); returns the modules."""
    for name in HEAVY_MODULES:
        importlib.import_module(name)
    from app.gui.plots import draw_figure

    draw_figure(lambda fig: fig.add_subplot(111).set_title("warm-up: 0.0 (mm) °"), 64, 64)
    return HEAVY_MODULES
