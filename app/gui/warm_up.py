"""Load, before the window is shown, what would otherwise be loaded by a worker thread holding the interpreter lock.

Measured while a simulated session ran through the window (see the
"Capture station window" section of docs/BENCHMARKS.md): the event loop's longest stalls
while the machine was running the process (120-150 ms) came from
first uses in worker threads, during which a single C call holds the
interpreter lock, such as the import of colour-science's dataset modules
(unmarshalling their large code objects, on the preview's render thread:
125 ms).  Importing them once on the GUI thread before the window is shown
moves that time to start-up, where nothing waits for the event loop.
(Matplotlib's first text layout, 120-150 ms, was the other; the window's
figures are now drawn in their own process, :class:`app.gui.plots.FigureDrawer`,
which lays out text once when it starts.)

The imports leave about 160,000 objects that Python's cyclic garbage
collector walks in full whenever its oldest generation is due (73 ms for
them alone on the two-core test machine): on
whichever thread happens to allocate, holding the interpreter lock for
about 110 ms (measured with :data:`gc.callbacks` during the first simulated
session in a process: one full collection of 109.6 ms, a 121 ms stall of
the event loop).  :func:`freeze_heap` collects once and moves everything
alive into the collector's permanent generation (:func:`gc.freeze`, the
standard library's way to keep a long-lived start-up heap out of later
collections), so later full collections walk only what the session made.

Examples
--------
>>> warm_up() is warm_up()
True
"""

from __future__ import annotations

import functools
import gc
import importlib

__all__ = ["HEAVY_MODULES", "warm_up", "freeze_heap"]

#: Modules the window's worker threads import on first use, in the order a session needs them.
HEAVY_MODULES = ("colour", "open3d", "scipy.spatial", "app.capture.runner", "app.capture.devices",
                 "processing.geometry.scan_points", "render.renderer", "app.workflows.scene_build")


@functools.cache
def warm_up() -> tuple[str, ...]:
    """Import :data:`HEAVY_MODULES` once (per process); returns the modules."""
    for name in HEAVY_MODULES:
        importlib.import_module(name)
    return HEAVY_MODULES


def freeze_heap() -> int:
    """Collect garbage, then keep every object alive now out of later collections; returns how many were frozen.

    Called by the window after :func:`warm_up`, before it is shown (see the
    module docstring).  Objects frozen here are still freed by reference
    counting when they are released; only cycles among them are no longer
    looked for.
    """
    gc.collect()
    gc.freeze()
    return gc.get_freeze_count()
