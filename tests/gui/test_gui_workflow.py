"""Pausing and aborting a capture, reopening the interrupted session in a new window and resuming it there;
cancelling processing (a worker process) without touching the session.

Ground truth: the session store (what was recorded, its status and products) and the plan.
"""

from __future__ import annotations

import pytest

pytest.importorskip("PySide6.QtWidgets", reason="the GUI tests need PySide6 (pip install 'kogei[gui]')")

from pathlib import Path

from PySide6.QtCore import Qt

from app.session import Session
from mocks.world import World
from tests.gui.helpers import library_capture, make_window, station_window, wait_capture

LEFT = Qt.MouseButton.LeftButton


def _station_window(qtbot, tmp_path: Path, name: str = "settings.ini"):
    return station_window(qtbot, tmp_path, name=name, world=World.hawk(2000, width=48, height=32), seed=6,
                          n_points=96)


def test_pause_abort_reopen_and_resume(qtbot, tmp_path):
    w, st = _station_window(qtbot, tmp_path)
    w.session.folder.setText(str(tmp_path / "s"))
    w.session.meta_edits["name"].setText("tsuba")
    qtbot.mouseClick(w.session.new_button, LEFT)
    w.capture.steps.setValue(30)
    w.capture.passes.setValue(2)
    qtbot.mouseClick(w.capture.start, LEFT)
    qtbot.waitUntil(lambda: not w.capture.prompt.isHidden(), timeout=10_000)
    qtbot.mouseClick(w.capture.prompt_go, LEFT)
    qtbot.waitUntil(lambda: w.capture.progress.value() >= 5, timeout=10_000)
    qtbot.mouseClick(w.capture.pause, LEFT)
    assert w.capture.pause.text().startswith("Continue")
    assert w.capture.status_text == "paused" and not w.capture.paused_label.isHidden()   # a visible PAUSED state
    assert w.capture.paused_label.text().startswith("PAUSED")
    qtbot.wait(300)                                   # the step in flight ends, then the capture holds
    held = w.capture.progress.value()
    qtbot.wait(500)
    assert w.capture.progress.value() == held < 60    # nothing is taken while paused
    qtbot.mouseClick(w.capture.pause, LEFT)           # continue
    qtbot.waitUntil(lambda: w.capture.progress.value() > held, timeout=10_000)
    qtbot.mouseClick(w.capture.abort, LEFT)
    wait_capture(qtbot, w, timeout_s=30, answer_prompts=False)
    assert w.capture.status_text == "cancelled"
    # the user's own stop is information, and the window's way to resume is Start, not a terminal command
    assert w.message_kind == "info" and "press Start" in w.error_line.text()
    assert "kogei capture" not in w.error_line.text() and "press Start to resume" in w.capture.action.text()
    assert w.capture.paused_label.isHidden()
    m = Session.read(tmp_path / "s")
    assert m["status"] == "interrupted"
    taken = sum(1 for r in m["captures"].values() if r["kind"] == "profile")
    assert held < taken < 60
    w.station = None                   # the station outlives this window (another window resumes on it)
    w.close()

    # a new window: open the interrupted session on the Session tab; its plan and metadata come back
    w2 = make_window(qtbot, tmp_path, "settings.ini")
    w2.link.placer = st.place
    for name in ("turntable", "profiler"):
        w2.devices.set_port(name, str(getattr(st, f"{name}_path")))
    w2.devices.camera_kind.setCurrentText("none")
    assert w2.session.folder.text() == str(tmp_path / "s")          # the last session is remembered
    qtbot.mouseClick(w2.session.open_button, LEFT)
    assert "interrupted" in w2.session.status.text() and w2.session.meta_edits["name"].text() == "tsuba"
    assert w2.session.tree.topLevelItemCount() == len(m["captures"])
    assert (w2.capture.steps.value(), w2.capture.passes.value()) == (30, 2)
    qtbot.mouseClick(w2.capture.start, LEFT)
    wait_capture(qtbot, w2, timeout_s=60)
    assert w2.capture.status_text == "complete", w2.error_line.text()
    m = Session.read(tmp_path / "s")
    assert m["status"] == "complete"
    assert sum(1 for r in m["captures"].values() if r["kind"] == "profile") == 60
    assert f"{taken} kept from before the interruption" in w2.capture.action.text()
    w2.close()
    st.stop()


def test_cancel_processing_leaves_the_session_as_it_was(qtbot, tmp_path):
    library_capture(World.hawk(2000), tmp_path, steps=12, passes=2, seed=1)
    before = (tmp_path / "s" / "session.json").read_bytes()
    w = make_window(qtbot, tmp_path)
    w.session.folder.setText(str(tmp_path / "s"))
    qtbot.mouseClick(w.session.open_button, LEFT)
    qtbot.mouseClick(w.processing.run_button, LEFT)
    assert w.processing.running and w.processing.cancel_button.isEnabled()
    qtbot.mouseClick(w.processing.cancel_button, LEFT)
    qtbot.waitUntil(lambda: not w.processing.running, timeout=10_000)
    assert "cancelled by the user" in w.error_line.text() and w.message_kind == "info"
    assert not w.processing.job._proc.is_alive()
    assert w.processing.run_button.isEnabled() and w.processing.report is None
    assert (tmp_path / "s" / "session.json").read_bytes() == before
    assert not (tmp_path / "s" / "products").exists()
    # without a calibration, processing says what to do, in the window
    qtbot.mouseClick(w.processing.run_button, LEFT)
    qtbot.waitUntil(lambda: not w.processing.running, timeout=60_000)
    assert "has no scanner calibration" in w.error_line.text() and "kogei calibrate" in w.error_line.text()
    assert w.message_kind == "error"
    w.tabs.setCurrentWidget(w.preview)              # the Processing tab's error is not left above another tab
    assert w.error_line.isHidden() and w.message_kind == ""


def test_the_devices_button_starts_a_simulated_station_without_blocking(qtbot, tmp_path):
    w = make_window(qtbot, tmp_path)
    w.devices.simulated_requested.emit()
    assert "starting" in w.devices.sim_state.text()          # returned at once; the world is built meanwhile
    qtbot.waitUntil(lambda: w.station is not None, timeout=60_000)
    assert w.devices.port("turntable") == str(w.station.turntable_path)
    w.devices.simulated_requested.emit()                      # a second one is refused, readably
    assert "already running" in w.error_line.text()
    w.devices.connect_all()
    qtbot.waitUntil(lambda: w.link.states["turntable"] == "connected", timeout=10_000)


def test_nothing_stale_across_an_aborted_and_resumed_capture_in_one_window(qtbot, tmp_path):
    """The table line follows the turntable, the ETA starts afresh, and the turntable left disconnected by
    the abort (so that resuming reads the board's position) is connected again when the resumed capture ends."""
    w, st = _station_window(qtbot, tmp_path)
    assert w.capture.position.text().startswith("table: connected")          # not "(connect the turntable)"
    w.session.folder.setText(str(tmp_path / "s"))
    qtbot.mouseClick(w.session.new_button, LEFT)
    w.capture.steps.setValue(30)
    w.capture.passes.setValue(1)
    qtbot.mouseClick(w.capture.start, LEFT)
    assert w.capture.position.text() == "table: driven by the capture"
    qtbot.waitUntil(lambda: not w.capture.prompt.isHidden(), timeout=10_000)
    assert not w.capture.pause.isEnabled()                   # one Continue: the prompt's, while it waits
    qtbot.mouseClick(w.capture.prompt_go, LEFT)
    assert w.capture.pause.isEnabled()
    qtbot.waitUntil(lambda: w.capture.progress.value() >= 5, timeout=10_000)
    qtbot.waitUntil(lambda: w.capture.eta.text() != "ETA –", timeout=10_000)
    qtbot.mouseClick(w.capture.abort, LEFT)
    wait_capture(qtbot, w, timeout_s=30, answer_prompts=False)
    assert w.capture.status_text == "cancelled"
    assert w.capture.position.text() != "table: driven by the capture"
    qtbot.waitUntil(lambda: w.link.states["turntable"] == "disconnected" and not w.link.lane.busy, timeout=10_000)

    qtbot.mouseClick(w.capture.start, LEFT)                  # resume in the same window
    assert w.capture.eta.text() == "ETA –"                   # not the aborted run's
    wait_capture(qtbot, w, timeout_s=60)
    assert w.capture.status_text == "complete", w.error_line.text()
    qtbot.waitUntil(lambda: all(w.link.states[n] == "connected" for n in ("turntable", "profiler")),
                    timeout=10_000)
    assert w.capture.position.text().startswith("table: connected")
    assert sum(1 for r in Session.read(tmp_path / "s")["captures"].values() if r["kind"] == "profile") == 30


def test_start_creates_the_session_off_the_gui_thread_and_says_when_it_cannot(qtbot, tmp_path, monkeypatch):
    """Creating a session writes and syncs files, which a busy disk can hold for most of a second: Start checks the
    tabs at once and creates the session on the instruments' lane.  A folder that cannot become a session stops the
    capture before anything is taken, says so in the window, leaves the folder as it was and hands the
    instruments back."""
    import threading

    w, st = _station_window(qtbot, tmp_path)
    threads: list[str] = []
    create = Session.create.__func__

    def recording_create(cls, *args, **kwargs):
        threads.append(threading.current_thread().name)
        return create(cls, *args, **kwargs)

    monkeypatch.setattr(Session, "create", classmethod(recording_create))
    folder = tmp_path / "taken"
    w.session.folder.setText(str(folder))
    qtbot.mouseClick(w.session.new_button, LEFT)
    assert w.error_line.isHidden(), w.error_line.text()
    folder.mkdir()                                         # another program writes there before Start is pressed
    (folder / "notes.txt").write_text("someone else's")
    w.capture.steps.setValue(6)
    w.capture.passes.setValue(1)
    qtbot.mouseClick(w.capture.start, LEFT)
    wait_capture(qtbot, w, timeout_s=30)
    assert threads and threading.main_thread().name not in threads, threads
    assert w.capture.status_text == "not started"
    assert "already exists and is not an empty folder" in w.error_line.text()
    assert w.capture.action.text().startswith("not started: ")
    assert any("capture failed: " in line and "already exists" in line for line in w.log_view.toPlainText().splitlines())
    assert sorted(p.name for p in folder.iterdir()) == ["notes.txt"]
    assert (folder / "notes.txt").read_text() == "someone else's"
    qtbot.waitUntil(lambda: all(w.link.states[n] == "connected" for n in ("turntable", "profiler")), timeout=10_000)

    # the same Start into a new folder: created on the lane too, and the capture runs to the end
    w.session.folder.setText(str(tmp_path / "fresh"))
    qtbot.mouseClick(w.session.new_button, LEFT)
    qtbot.mouseClick(w.capture.start, LEFT)
    wait_capture(qtbot, w, timeout_s=60)
    assert w.capture.status_text == "complete", w.error_line.text()
    assert len(threads) == 2 and threading.main_thread().name not in threads, threads
    assert w.capture.progress.maximum() == w.capture.progress.value() == 6
    assert Session.read(tmp_path / "fresh")["status"] == "complete"


def test_start_during_a_jog_queues_the_capture_behind_it_without_waiting(qtbot, tmp_path):
    """Start pressed while the table is still turning for a jog returns at once (the window does not wait for the
    table): the capture runs after the jog on the instruments' lane, and the jog's end does not overwrite the
    capture's position line."""
    from tests.gui.helpers import connect_instruments

    w = make_window(qtbot, tmp_path)
    st = w.start_simulated_station(world=World.hawk(2000, width=48, height=32), seed=6, n_points=96,
                                   time_scale=1.0)                  # the table turns at its real speed
    connect_instruments(qtbot, w)
    w.session.folder.setText(str(tmp_path / "s"))
    qtbot.mouseClick(w.session.new_button, LEFT)
    w.capture.steps.setValue(6)
    w.capture.passes.setValue(1)
    w.capture.angle.setValue(350.0)
    qtbot.mouseClick(w.capture.go, LEFT)                           # 350 deg at 100 deg/s: about 4 s
    qtbot.waitUntil(lambda: w.link.lane.busy, timeout=5_000)
    qtbot.mouseClick(w.capture.start, LEFT)
    assert w.error_line.isHidden(), w.error_line.text()
    assert st.table_angle_deg < 349.0, st.table_angle_deg          # Start returned with the table still turning
    # the capture's first step comes after the jog (one lane, in order); the jog's end leaves its line alone
    qtbot.waitUntil(lambda: not w.capture.prompt.isHidden(), timeout=20_000)
    qtbot.wait(200)
    assert w.capture.position.text() == "table: driven by the capture"
    prompts = wait_capture(qtbot, w, timeout_s=60)
    assert w.capture.status_text == "complete", w.error_line.text()
    assert len(prompts) == 1
    m = Session.read(tmp_path / "s")
    assert sum(r["kind"] == "profile" for r in m["captures"].values()) == 6
    assert "350.00" not in w.capture.position.text()
