"""Scanner calibration without the command line: the simulated station's object swapped from the Devices tab
(the reference sphere, then the piece), the sphere scanned and the scanner calibrated from the Processing tab.

Ground truth: the simulated station's own sensor pose (``SimulatedStation.sensor_to_room``; the calibration
must recover it as ``kogei calibrate`` does in tests/app/test_calibrate_command.py), and a fresh station with the
hawk on its table from the start (the swapped station must give the same profiles: they are deterministic per
seed, placement and table angle).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("PySide6.QtWidgets", reason="the GUI tests need PySide6 (pip install 'kogei[gui]')")

from PySide6.QtCore import Qt

from app.capture.runner import load_pass_profiles
from app.gui.devices_panel import SIMULATED_OBJECTS
from app.session import Session
from app.workflows.calibration import session_calibration
from mocks.world import World
from tests.gui.helpers import connect_instruments, library_capture, make_window, same_profiles, wait_capture

SEED, N_POINTS, SIZE = 5, 400, (96, 64)
LEFT = Qt.MouseButton.LeftButton


def _put(qtbot, w, name: str) -> None:
    w.devices.sim_object.setCurrentText(name)
    qtbot.mouseClick(w.devices.put_button, LEFT)
    assert not w.devices.put_button.isEnabled()                     # busy while the world is built
    qtbot.waitUntil(lambda: w.devices.put_button.isEnabled(), timeout=60_000)
    assert w.error_line.isHidden(), w.error_line.text()


def _capture(qtbot, w, folder: Path, steps: int) -> list[str]:
    w.tabs.setCurrentWidget(w.session)
    w.session.folder.setText(str(folder))
    qtbot.mouseClick(w.session.new_button, LEFT)
    w.tabs.setCurrentWidget(w.capture)
    w.capture.steps.setValue(steps)
    w.capture.passes.setValue(1)
    qtbot.mouseClick(w.capture.start, LEFT)
    prompts = wait_capture(qtbot, w, timeout_s=90)
    assert w.capture.status_text == "complete", w.error_line.text()
    return prompts


def test_sphere_scan_calibrates_the_scanner_then_the_piece_goes_on_the_table(qtbot, tmp_path):
    w = make_window(qtbot, tmp_path)
    assert not w.devices.put_button.isEnabled()                     # no station yet
    st = w.start_simulated_station(triangles=4000, image_size=SIZE, n_points=N_POINTS, seed=SEED)
    assert "the hawk head" in w.devices.sim_state.text()
    connect_instruments(qtbot, w, camera=True)                      # the camera too: the plan must not use it
    assert w.capture.kind.currentText() == "scan" and w.capture.chart.isChecked()

    # The reference sphere goes on the table; the instruments stay connected; the plan becomes the sphere's
    _put(qtbot, w, SIMULATED_OBJECTS[1])
    assert st.world.mesh_source == "sphere:25:60" and "calibration sphere" in w.devices.sim_state.text()
    assert all(w.link.states[n] == "connected" for n in ("turntable", "profiler"))
    assert w.capture.kind.currentText() == "sphere-calibration"
    assert not w.capture.chart.isChecked() and not w.capture.chart.isEnabled()
    assert w.capture.camera_angles.text() == "" and w.capture.passes.value() == 1
    prompts = _capture(qtbot, w, tmp_path / "sphere", steps=72)
    # one placement prompt, for the sphere, that does not ask for the chart; profiles only, no RAW file
    assert len(prompts) == 1 and "reference sphere" in prompts[0] and "chart" not in prompts[0], prompts
    m = Session.read(tmp_path / "sphere")
    assert m["plan"]["kind"] == "sphere-calibration" and m["plan"]["camera"] is False
    assert {r["kind"] for r in m["captures"].values()} == {"profile", "profiles"}
    assert not [p for p in (tmp_path / "sphere").rglob("*") if p.suffix.lower() in (".cr2", ".dng", ".nef")]
    # a sphere session is not the piece's: calibrating comes next (once the instruments are back from the capture)
    qtbot.waitUntil(lambda: w.steps.current == "Calibrate", timeout=20_000)

    # Calibrate from the open session on the Processing tab
    w.tabs.setCurrentWidget(w.processing)
    assert w.processing.radius.value() == 25.0
    qtbot.mouseClick(w.processing.calibrate_button, LEFT)
    qtbot.waitUntil(lambda: "calibrated from" in w.processing.cal_state.text(), timeout=60_000)
    assert w.error_line.isHidden(), w.error_line.text()
    assert w.processing.calibration_verdict.level == "pass"        # the sphere fits to the profiler's noise
    assert w.processing.calibration_source() == str(tmp_path / "sphere")
    cal = session_calibration(tmp_path / "sphere", Session.read(tmp_path / "sphere"))
    truth = st.sensor_to_room
    rot = cal.sensor_to_room[:3, :3].T @ truth[:3, :3]
    angle = np.degrees(np.arccos(np.clip((np.trace(rot) - 1) / 2, -1, 1)))
    assert angle < 0.05 and np.linalg.norm(cal.sensor_to_room[:3, 3] - truth[:3, 3]) < 0.05, (angle, cal)
    assert np.hypot(*cal.sphere_center_mm[:2]) == pytest.approx(60.0, abs=0.05)

    # The piece goes back on the table: the same profiles as a station that had the hawk from the start
    _put(qtbot, w, SIMULATED_OBJECTS[0])
    assert "head" in st.world.region_names and "the hawk head" in w.devices.sim_state.text()
    assert w.capture.kind.currentText() == "scan"
    qtbot.waitUntil(lambda: w.steps.current == "Session", timeout=20_000)
    w.devices.camera_kind.setCurrentText("none")                    # profiles only, as the reference below
    # the table turned back to its mark (physical 0, where a fresh station's table starts) with the jog
    # controls: zero here, then go to minus the angle it stands at
    w.tabs.setCurrentWidget(w.capture)
    qtbot.waitUntil(lambda: w.capture.zero.isEnabled(), timeout=20_000)
    physical = (st.table_angle_deg + 180.0) % 360.0 - 180.0
    qtbot.mouseClick(w.capture.zero, LEFT)
    qtbot.waitUntil(lambda: "table at 0.00" in w.capture.position.text(), timeout=20_000)
    w.capture.angle.setValue(-physical)
    qtbot.mouseClick(w.capture.go, LEFT)
    qtbot.waitUntil(lambda: abs((st.table_angle_deg + 180.0) % 360.0 - 180.0) < 360 / 3200, timeout=20_000)
    _capture(qtbot, w, tmp_path / "hawk", steps=12)
    reference = library_capture(World.hawk(4000, width=SIZE[0], height=SIZE[1]), tmp_path / "ref", steps=12,
                                passes=1, seed=SEED, n_points=N_POINTS)
    same_profiles([load_pass_profiles(tmp_path / "hawk", 1)], [load_pass_profiles(reference, 1)])
    # the live cloud of the pass used the calibration just made (3-D points, not the range image)
    qtbot.waitUntil(lambda: not w.capture.cloud_plot.busy, timeout=30_000)
    assert w.capture.cloud_plot.failure == "" and w.capture.cloud_caption == "pass 1, 12 profiles"


def test_putting_an_object_needs_a_station_and_waits_for_the_capture(qtbot, tmp_path):
    from app.gui.main_window import simulated_world

    w = make_window(qtbot, tmp_path)
    w.run_safely(lambda: w.put_simulated_object(SIMULATED_OBJECTS[1]))
    assert "no simulated station runs in this window" in w.error_line.text()
    st = w.start_simulated_station(triangles=2000, image_size=(48, 32), n_points=96, seed=SEED)
    connect_instruments(qtbot, w)
    w.session.folder.setText(str(tmp_path / "s"))
    qtbot.mouseClick(w.session.new_button, LEFT)
    w.capture.steps.setValue(400)
    w.capture.passes.setValue(1)
    qtbot.mouseClick(w.capture.start, LEFT)
    qtbot.waitUntil(lambda: not w.capture.prompt.isHidden(), timeout=30_000)
    qtbot.mouseClick(w.capture.prompt_go, LEFT)
    qtbot.waitUntil(lambda: w.capture.progress.value() > 2, timeout=30_000)
    w.run_safely(lambda: w.put_simulated_object(SIMULATED_OBJECTS[1]))
    assert "a capture is running" in w.error_line.text()
    assert "head" in st.world.region_names                          # nothing was swapped
    qtbot.mouseClick(w.capture.abort, LEFT)
    qtbot.waitUntil(lambda: w.capture.start.isEnabled(), timeout=30_000)
    with pytest.raises(ValueError, match="unknown simulated object 'teapot'"):
        simulated_world("teapot")
