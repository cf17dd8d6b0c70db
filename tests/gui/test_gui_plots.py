"""Figures drawn in the drawing process (app.gui.plots.FigureDrawer): the same pixels as drawn in this
process, failures as readable messages, a process that dies or hangs replaced by a new one."""

from __future__ import annotations

import os

import numpy as np
import pytest

pytest.importorskip("PySide6.QtCore", reason="the GUI tests need PySide6 (pip install 'kogei[gui]')")

from app.gui.figures import cloud_figure, draw_figure, empty_figure, profile_figure, spectrum_figure
from app.gui.plots import FigureDrawer


class _ExitOnArrival:
    """Unpickling this in the drawing process ends that process at once with exit code 3."""

    def __reduce__(self):
        return (os._exit, (3,))


@pytest.fixture
def drawer():
    d = FigureDrawer(timeout_s=60.0)
    yield d
    d.shutdown()


def _profile_data() -> dict:
    x = np.linspace(-40.0, 40.0, 320)
    z = 150.0 + 10.0 * np.cos(x / 20.0)
    z[::7] = np.nan                                        # no return at some points
    return {"p": 2, "idx": 17, "angle": 34.0, "x": x, "z": z}


def test_a_figure_drawn_in_the_drawing_process_is_the_figure_drawn_here(drawer):
    for build, data in ((profile_figure, _profile_data()),
                        (cloud_figure, {"p": 1, "angles": np.arange(12.0), "x": np.tile(np.arange(50.0), (12, 1)),
                                        "z": np.full((12, 50), 120.0), "cal": None})):
        there = drawer.draw(build, data, 400, 300)
        here = draw_figure(build, data, 400, 300)
        assert there.shape == (300, 400, 4) and there.dtype == np.uint8
        np.testing.assert_array_equal(there, here)
    assert drawer.pid is not None and drawer.pid != os.getpid()
    assert drawer.processes_started == 1                  # one process serves every drawing


def test_a_builder_that_fails_is_reported_readably_and_the_process_serves_on(drawer):
    wl = np.arange(400.0, 710.0, 10.0)
    with pytest.raises(RuntimeError, match=r"drawing the figure failed: ValueError"):
        drawer.draw(spectrum_figure, {"wavelengths": wl, "mean": np.ones(5), "uncertainty": np.ones(5),
                                      "model": np.ones(5), "model_name": "gold", "pixels": 4, "title": "t"},
                    300, 200)
    pid = drawer.pid
    rgba = drawer.draw(empty_figure, {"title": "Reflectance", "hint": "click"}, 300, 200)
    assert rgba.shape == (200, 300, 4) and drawer.pid == pid and drawer.processes_started == 1


def test_a_drawing_process_that_dies_fails_that_figure_only(drawer):
    drawer.draw(empty_figure, {"title": "a", "hint": "b"}, 100, 100)
    first = drawer.pid
    with pytest.raises(RuntimeError, match=r"figure-drawing process stopped \(exit code 3"):
        drawer.draw(empty_figure, {"title": "a", "hint": _ExitOnArrival()}, 100, 100)
    rgba = drawer.draw(empty_figure, {"title": "a", "hint": "b"}, 100, 100)
    assert rgba.shape == (100, 100, 4)
    assert drawer.processes_started == 2 and drawer.pid not in (None, first)


def test_a_drawing_past_the_time_limit_is_abandoned_and_the_next_one_gets_a_new_process(drawer):
    drawer.draw(empty_figure, {"title": "a", "hint": "b"}, 100, 100)
    drawer.timeout_s = 1e-4                                # no drawing returns this fast
    with pytest.raises(RuntimeError, match=r"took over .* s and was abandoned"):
        drawer.draw(profile_figure, _profile_data(), 400, 300)
    drawer.timeout_s = 60.0
    np.testing.assert_array_equal(drawer.draw(profile_figure, _profile_data(), 400, 300),
                                  draw_figure(profile_figure, _profile_data(), 400, 300))
    assert drawer.processes_started == 2


def test_a_closed_drawer_refuses_readably_and_starts_no_process():
    d = FigureDrawer()
    d.shutdown()
    with pytest.raises(RuntimeError, match="the window is closing"):
        d.draw(empty_figure, {"title": "a", "hint": "b"}, 100, 100)
    assert d.processes_started == 0 and d.pid is None


def test_a_plot_given_up_at_closing_is_no_logged_failure(caplog):
    """A plot job still queued when the window closes fails quietly: no traceback in the log."""
    import logging

    from app.gui.workers import Job

    d = FigureDrawer()
    d.shutdown()
    failures = []
    job = Job(lambda ctx: d.draw(empty_figure, {"title": "a", "hint": "b"}, 100, 100), "plot")
    job.signals.failed.connect(lambda text, exc: failures.append(text))
    with caplog.at_level(logging.DEBUG, logger="kogei.gui"):
        job.run()
    assert [r for r in caplog.records if r.levelno >= logging.ERROR] == []
    assert job.done and "Traceback" not in caplog.text


def test_figures_of_nothing_draw_without_warnings():
    """A pass with no laser return, an empty histogram, a flat spectrum, passes not loaded yet: each draws."""
    import warnings

    from app.gui.figures import histogram_figure, pick_figure

    nan = np.full(320, np.nan)
    empty = np.zeros((0, 3))
    cases = [
        (profile_figure, {"p": 1, "idx": 0, "angle": 0.0, "x": nan, "z": nan}),
        (cloud_figure, {"p": 1, "angles": np.zeros(1), "x": nan[None], "z": nan[None], "cal": None}),
        (histogram_figure, {"counts": np.zeros((3, 128)), "clipped": 0.0}),
        (spectrum_figure, {"wavelengths": np.arange(400.0, 710.0, 10.0), "mean": np.zeros(31),
                           "uncertainty": np.zeros(31), "model": np.zeros(31), "model_name": "gold", "pixels": 1,
                           "title": "flat"}),
        (pick_figure, {"a": empty, "b": empty, "picks_a": empty, "picks_b": empty, "i": 0, "j": 1,
                       "label_a": "pass 1", "label_b": "pass 2"}),
    ]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for build, data in cases:
            rgba = draw_figure(build, data, 320, 240)
            assert rgba.shape == (240, 320, 4) and rgba[..., :3].std() > 0     # drawn, not blank


def test_a_plot_is_redrawn_at_any_new_size_and_scaled_never_cropped_meanwhile(qtbot, drawer):
    """A change of height alone (an error line appearing) redraws the figure at the new size, once, after the
    debounce; until then, and below the smallest drawing size, the bitmap shown fits inside the widget."""
    from app.gui.plots import MIN_DRAW_SIZE, PlotImage

    plot = PlotImage(drawer)
    qtbot.addWidget(plot)
    plot.resize(500, 400)
    plot.show()
    plot.plot(profile_figure, **_profile_data())
    qtbot.waitUntil(lambda: plot.draws == 1 and not plot.busy, timeout=30_000)
    qtbot.wait(2 * PlotImage.RESIZE_DEBOUNCE_MS)
    assert plot.rgba.shape[:2] == (400, 500)
    draws = plot.draws
    for h in (390, 380, 370):                  # a few small steps: the old rule (width off by > 40 px) ignored all
        plot.resize(500, h)
        pix = plot.pixmap()
        assert pix.width() <= plot.width() and pix.height() <= plot.height()      # scaled, not cropped
    qtbot.waitUntil(lambda: plot.draws > draws and not plot.busy, timeout=30_000)
    qtbot.wait(2 * PlotImage.RESIZE_DEBOUNCE_MS)
    assert plot.rgba.shape[:2] == (370, 500) and plot.draws == draws + 1          # debounced: one redraw
    plot.resize(280, 210)                        # below the smallest drawing: drawn at it, shown scaled down
    qtbot.waitUntil(lambda: plot.rgba.shape[:2] == MIN_DRAW_SIZE[::-1] and not plot.busy, timeout=30_000)
    pix = plot.pixmap()
    assert (plot.width(), plot.height()) == (280, 210)
    assert pix.width() <= 280 and pix.height() <= 210 and plot.scale < 1


def test_a_finished_jobs_result_is_not_lost_when_another_job_is_queued_before_it_is_handled(qtbot):
    """A job is done on its pool thread before the window handles its queued result; queueing another job in
    between must not drop the first one (and its result) from the lane."""
    import gc

    from app.gui.workers import Lane

    lane = Lane(2)
    got = []
    lane.run(lambda ctx: 41, "first", succeeded=got.append)
    assert lane.wait(10_000)                       # done on its thread; its result is still queued
    lane.run(lambda ctx: 42, "second", succeeded=got.append)
    assert lane.wait(10_000)
    gc.collect()
    assert lane.busy                               # results not handled yet
    qtbot.waitUntil(lambda: not lane.busy, timeout=10_000)
    assert sorted(got) == [41, 42]


def test_the_point_cloud_figure_keeps_its_axis_labels_inside_at_a_small_size():
    """The live cloud's 3-D axes: their titles and labels lie inside the figure at the size the Capture tab gives
    it in a 1024 x 700 window (583 x 205 px), which the constrained layout does not arrange for 3-D axes.
    Ground truth: each text's drawn extent against the figure's own box."""
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from app.gui.figures import cloud_figure
    from processing.geometry.calibration import ScannerCalibration, ideal_sensor_to_room

    cal = ScannerCalibration(ideal_sensor_to_room(200.0, 30.0), 25.0, np.zeros(3), 0.0, 0.0, 0, 0, 0, 0.0, 25.0,
                             np.zeros(0, np.int64), np.zeros(0))
    angles = np.linspace(0.0, 356.0, 90)
    x = np.tile(np.linspace(-30.0, 30.0, 200), (90, 1))
    z = np.full_like(x, 200.0) + 10 * np.sin(np.radians(angles))[:, None]
    for w, h in ((583, 205), (910, 300)):
        fig = Figure(figsize=(w / 100, h / 100), dpi=100, layout="constrained")
        canvas = FigureCanvasAgg(fig)
        cloud_figure(fig, p=1, angles=angles, x=x, z=z, cal=cal)
        canvas.draw()
        ax = fig.axes[0]
        assert ax.name == "3d"
        box = fig.bbox
        for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
            e = axis.label.get_window_extent(canvas.get_renderer())
            assert box.x0 - 1 <= e.x0 and e.x1 <= box.x1 + 1 and box.y0 - 1 <= e.y0 and e.y1 <= box.y1 + 1, \
                (w, h, axis.label.get_text(), e, box)
