"""Instruments in the window: a device unplugged mid-pass (recovered by the capture, and not recovered:
reported, resumed after the cable returns, with the same data as a fault-free run), a device that drops
out while idle (banner, automatic re-handshake), readable errors, persistent settings, shortcuts.

Ground truth: a fault-free capture of the same simulated station through the library
(:func:`app.capture.runner.run_capture`); the station's profiles are deterministic per seed, placement and
angle, so every profile the window's capture records must be identical to it.
"""

from __future__ import annotations

import pytest

pytest.importorskip("PySide6.QtWidgets", reason="the GUI tests need PySide6 (pip install 'kogei[gui]')")

from pathlib import Path

from PySide6.QtCore import Qt

from app.capture.runner import load_pass_profiles
from app.session import Session
from mocks.world import World
from tests.gui.helpers import library_capture, make_window, same_profiles, station_window, wait_capture

STEPS, PASSES, SEED, N_POINTS = 12, 2, 3, 96
LEFT = Qt.MouseButton.LeftButton


def _world() -> World:
    return World.hawk(2000, width=48, height=32)


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> list[dict]:
    root = library_capture(_world(), tmp_path_factory.mktemp("gui-ref"), steps=STEPS, passes=PASSES, seed=SEED,
                           n_points=N_POINTS)
    return [load_pass_profiles(root, p) for p in range(1, PASSES + 1)]


def _window_with_station(qtbot, tmp_path: Path):
    return station_window(qtbot, tmp_path, world=_world(), seed=SEED, n_points=N_POINTS)


def test_unplug_mid_pass_recovered_then_lost_then_resumed(qtbot, tmp_path, reference):
    w, st = _window_with_station(qtbot, tmp_path)
    banners: list[str] = []
    w.link.banner.connect(banners.append)
    w.session.folder.setText(str(tmp_path / "s"))
    qtbot.mouseClick(w.session.new_button, LEFT)
    w.capture.steps.setValue(STEPS)
    w.capture.passes.setValue(PASSES)
    w.capture.reconnect_timeout_s = 2.0
    qtbot.mouseClick(w.capture.start, LEFT)
    fired: list[int] = []

    def inject(pr) -> None:
        # pass 1: the profiler's cable is pulled and comes back after 0.5 s (the capture reconnects);
        # pass 2: it is pulled and stays out (the capture stops, resumable)
        if pr.done >= 5 and not fired:
            fired.append(pr.done)
            st.profiler_faults.unplug_on_command, st.profiler_faults.replug_after_s = 1, 0.5
        elif pr.done >= 17 and len(fired) == 1:
            fired.append(pr.done)
            st.profiler_faults.unplug_on_command, st.profiler_faults.replug_after_s = 1, None

    w.capture.job.signals.progress.connect(inject)
    wait_capture(qtbot, w, timeout_s=60)
    assert len(fired) == 2
    # the first drop-out raised the banner and the reconnection cleared it, during the capture
    first = [i for i, b in enumerate(banners) if "laser profiler" in b and "dropped out" in b]
    assert first and "" in banners[first[0]:]
    # the second one stopped the capture with a readable message; the session is intact and resumable
    assert w.capture.status_text == "interrupted"
    text = w.error_line.text()
    assert "did not come back" in text and "intact" in text and "Traceback" not in text
    assert not w.banner.isHidden() and "laser profiler" in w.banner.text()
    assert w.link.states["profiler"] == "lost" and w.devices.lights["profiler"].state == "lost"
    m = Session.read(tmp_path / "s")
    assert m["status"] == "interrupted"
    held = sum(1 for r in m["captures"].values() if r["kind"] == "profile")
    assert STEPS < held < STEPS * PASSES                   # stopped in the middle of pass 2
    # the cable returns: the window re-handshakes on its own, the light turns green, the banner goes
    st.profiler.replug()
    qtbot.waitUntil(lambda: w.link.states["profiler"] == "connected", timeout=10_000)
    assert w.banner.isHidden()
    assert "re-handshaken" in w.log_view.toPlainText()
    # Start resumes the session: only the missing steps are taken, and the data equal a fault-free run
    w.show_error("")
    qtbot.mouseClick(w.capture.start, LEFT)
    wait_capture(qtbot, w, timeout_s=60)
    assert w.capture.status_text == "complete", w.error_line.text()
    assert f"{held} kept from before the interruption" in w.capture.action.text()
    assert Session.read(tmp_path / "s")["status"] == "complete"
    same_profiles([load_pass_profiles(tmp_path / "s", p) for p in range(1, PASSES + 1)], reference)


def test_idle_dropout_raises_the_banner_and_rehandshakes(qtbot, tmp_path):
    w, st = _window_with_station(qtbot, tmp_path)
    st.turntable.unplug()
    qtbot.waitUntil(lambda: w.link.states["turntable"] == "lost", timeout=10_000)
    assert not w.banner.isHidden()
    assert "turntable on" in w.banner.text() and "dropped out" in w.banner.text()
    assert w.devices.lights["turntable"].state == "lost"
    assert w.link.states["profiler"] == "connected"           # the other instrument is unaffected
    st.turntable.replug()
    qtbot.waitUntil(lambda: w.link.states["turntable"] == "connected", timeout=10_000)
    assert w.banner.isHidden()
    assert "Horus 0.2" in w.devices.banners["turntable"].text()
    # the re-handshaken turntable works: a jog reaches the firmware
    w.capture.angle.setValue(45.0)
    qtbot.mouseClick(w.capture.go, LEFT)
    qtbot.waitUntil(lambda: "45.00" in w.capture.position.text(), timeout=10_000)
    assert st.table_angle_deg == pytest.approx(45.0, abs=360 / 3200)


def test_bad_input_gives_readable_errors(qtbot, tmp_path):
    w = make_window(qtbot, tmp_path)
    qtbot.mouseClick(w.capture.start, LEFT)
    assert "choose a session first" in w.error_line.text()
    w.session.folder.setText(str(tmp_path / "new"))
    qtbot.mouseClick(w.session.new_button, LEFT)
    w.devices.set_port("turntable", "")
    w.devices.set_port("profiler", "")
    qtbot.mouseClick(w.capture.start, LEFT)
    assert "choose the turntable and the profiler port on the Devices tab" in w.error_line.text()
    assert not (tmp_path / "new").exists()                    # nothing was created
    w.devices.set_port("turntable", str(tmp_path / "no-such-port"))
    qtbot.mouseClick(w.devices.connect_buttons["turntable"], LEFT)
    qtbot.waitUntil(lambda: w.link.states["turntable"] == "disconnected" and "could not connect"
                    in w.log_view.toPlainText(), timeout=10_000)
    assert "no-such-port" in w.devices.banners["turntable"].text()
    w.session.folder.setText(str(tmp_path))                   # not a session
    qtbot.mouseClick(w.session.open_button, LEFT)
    assert str(tmp_path) in w.error_line.text()
    w.capture.camera_angles.setText("0,ninety")
    w.devices.set_port("turntable", "/dev/null")
    w.devices.set_port("profiler", "/dev/null")
    w.session.folder.setText(str(tmp_path / "new2"))
    qtbot.mouseClick(w.session.new_button, LEFT)
    qtbot.mouseClick(w.capture.start, LEFT)
    assert "camera angles '0,ninety'" in w.error_line.text()
    assert "ERROR: camera angles" in w.log_view.toPlainText()


def test_settings_persist_between_windows(qtbot, tmp_path):
    w = make_window(qtbot, tmp_path)
    w.devices.set_port("turntable", "/dev/ttyUSB7")
    w.devices.set_port("profiler", "/dev/ttyACM3")
    w.devices.camera_kind.setCurrentText("hotfolder")
    w.devices.camera_path.setText("/data/tether")
    w.processing.calibration.setText("/data/cal-2026-11")
    w.tabs.setCurrentIndex(2)
    w.resize(700, 520)
    size = (w.width(), w.height())              # as the window manager granted it
    w.close()
    w2 = make_window(qtbot, tmp_path)
    assert w2.devices.port("turntable") == "/dev/ttyUSB7" and w2.devices.port("profiler") == "/dev/ttyACM3"
    assert w2.devices.camera_kind.currentText() == "hotfolder" and w2.devices.camera_path.text() == "/data/tether"
    assert w2.processing.calibration.text() == "/data/cal-2026-11"
    assert w2.tabs.currentIndex() == 2
    assert (w2.width(), w2.height()) == size


def test_keyboard_shortcuts_drive_the_capture(qtbot, tmp_path):
    w, st = _window_with_station(qtbot, tmp_path)
    w.tabs.setCurrentWidget(w.capture)
    w.capture.angle.setValue(0.0)
    w.capture.step_size.setValue(45.0)
    qtbot.keyClick(w, Qt.Key.Key_Right, Qt.KeyboardModifier.ControlModifier)
    qtbot.waitUntil(lambda: "45.00" in w.capture.position.text(), timeout=10_000)
    assert st.table_angle_deg == pytest.approx(45.0, abs=360 / 3200)
    qtbot.keyClick(w, Qt.Key.Key_L, Qt.KeyboardModifier.ControlModifier)
    qtbot.waitUntil(lambda: st.laser_powered, timeout=10_000)
    qtbot.keyClick(w, Qt.Key.Key_L, Qt.KeyboardModifier.ControlModifier | Qt.KeyboardModifier.ShiftModifier)
    qtbot.waitUntil(lambda: not st.laser_powered, timeout=10_000)
    w.session.folder.setText(str(tmp_path / "s"))
    qtbot.mouseClick(w.session.new_button, LEFT)
    w.capture.steps.setValue(40)
    w.capture.passes.setValue(1)
    qtbot.keyClick(w, Qt.Key.Key_F5)                           # start
    qtbot.waitUntil(lambda: not w.capture.prompt.isHidden(), timeout=10_000)
    qtbot.keyClick(w, Qt.Key.Key_Return)                       # Continue at the placement prompt
    qtbot.waitUntil(lambda: w.capture.progress.value() >= 3, timeout=10_000)
    qtbot.keyClick(w, Qt.Key.Key_Escape)                       # abort
    wait_capture(qtbot, w, timeout_s=30, answer_prompts=False)
    assert w.capture.status_text == "cancelled"
    m = Session.read(tmp_path / "s")
    assert m["status"] == "interrupted" and "stopped by the user" in m["history"][-1]["detail"]
    assert 3 <= sum(1 for r in m["captures"].values() if r["kind"] == "profile") < 40


def test_gui_command_rejects_bad_options(capsys):
    from app.cli import main

    assert main(["gui", "--mock-triangles", "5"]) == 2
    assert "--mock-triangles must be at least 100" in capsys.readouterr().err
