"""A whole session with the camera and the lamps calibrated, on the default simulated station (``kogei gui
--mock``), through the window's own widgets only: connect; the reference sphere scanned with photos and the
scanner calibrated; the ChArUco board put on the table, photographed and the camera calibrated; the chrome sphere
put on the table, photographed and the lamps located; the hawk captured with photos; processed with its photos
posed on the mesh; every pass's chart found (Camera tab) and a frame's spectra and material map (Spectra tab);
*Measure materials on the mesh*; the Preview showing the measured materials.  The step strip
says what comes next at each calibration.

Ground truth: the simulated worlds (:mod:`mocks.board_world`, :mod:`mocks.mirror_world`, :mod:`mocks.world`):

* the camera: its focal length and pose against the simulated camera's.  Tolerances: focal within 0.5 %, pose
  within 0.1 deg and 2 mm.  The board's frames are the demo's (960 x 640), but the pose's gauge is fixed by
  three photos of the reference sphere at the station's 240 x 160 frames, four times coarser than the demo's
  (tolerances 0.2 %, 0.05 deg, 0.2 mm; tests/app/test_demo.py): the sphere's centre along the line of sight
  comes from its outline's size, about 52 px across, so a quarter-pixel error in that size moves it
  260 mm * 0.25 / 52 = 1.25 mm; 2 mm allows that with a margin (measured: 1.19 mm);
* the lamp: its direction against the simulated distant lamp's, within 0.5 deg (the demo: 0.2 deg, from twice
  as many chrome-sphere photos);
* the materials: the largest region measured on the mesh is the hawk's head (most of the simulated hawk's
  surface), read as nami-shibuichi (or a group naming it), as tests/app/test_object_materials.py reads it.

The plans are kept small (6 photos of each calibration target per placement, 2 passes of 48 steps of the
hawk); the board and the chrome sphere are rendered at 960 x 640, which makes this the GUI's longest test
(marked slow).  Each phase's seconds are printed (``-s``).
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

pytest.importorskip("PySide6.QtWidgets", reason="the GUI tests need PySide6 (pip install 'kogei[gui]')")

from PySide6.QtCore import Qt

from app.gui.devices_panel import SIMULATED_OBJECTS
from app.session import Session
from processing.materials.confidence import NEUTRAL_METAL, NO_FIT
from tests.gui.helpers import HAWK_LOOKALIKES, every_chart_found, make_window, wait_capture

pytestmark = pytest.mark.slow

LEFT = Qt.MouseButton.LeftButton
HAWK, SPHERE, BOARD, CHROME = SIMULATED_OBJECTS


class _Phases:
    """Seconds per phase of the session, printed at the end."""

    def __init__(self) -> None:
        self.t = time.perf_counter()
        self.rows: list[str] = []

    def __call__(self, name: str) -> None:
        now = time.perf_counter()
        self.rows.append(f"{name} {now - self.t:.1f} s")
        self.t = now


def _click(qtbot, button) -> None:
    assert button.isEnabled(), button.text()
    qtbot.mouseClick(button, LEFT)


def _put(qtbot, w, name: str) -> None:
    w.tabs.setCurrentWidget(w.devices)
    w.devices.sim_object.setCurrentText(name)
    _click(qtbot, w.devices.put_button)
    qtbot.waitUntil(lambda: w.devices.put_button.isEnabled(), timeout=120_000)
    assert w.message_kind != "error", w.error_line.text()


def _capture(qtbot, w, folder, kind: str, *, steps: int, passes: int, angles: str = "", chart: bool = False):
    w.tabs.setCurrentWidget(w.session)
    w.session.folder.setText(str(folder))
    _click(qtbot, w.session.new_button)
    w.tabs.setCurrentWidget(w.capture)
    assert w.capture.kind.currentText() == kind            # putting the object on the table chose its plan
    w.capture.steps.setValue(steps)
    w.capture.passes.setValue(passes)
    if w.capture.camera_angles.isEnabled():
        w.capture.camera_angles.setText(angles)
    if w.capture.chart.isEnabled():
        w.capture.chart.setChecked(chart)
    _click(qtbot, w.capture.start)
    wait_capture(qtbot, w, timeout_s=900)
    assert w.capture.status_text == "complete", w.error_line.text()
    qtbot.waitUntil(lambda: Session.read(folder)["status"] == "complete", timeout=20_000)
    qtbot.waitUntil(lambda: w.session.manifest is not None and w.session.manifest.get("status") == "complete",
                    timeout=20_000)


def test_camera_and_lamps_calibrated_then_materials_on_the_mesh(qtbot, tmp_path):
    from app.gui.preview_panel import MEASURED
    from app.workflows.object_materials import read_object_materials
    from app.workflows.station_calibration import session_camera_calibration, session_lamp_calibration
    from processing.geometry.registration import pose_difference

    t0 = time.perf_counter()
    phase = _Phases()
    w = make_window(qtbot, tmp_path)
    _click(qtbot, w.devices.start_sim_button)
    qtbot.waitUntil(lambda: w.station is not None, timeout=120_000)
    w.devices.camera_kind.setCurrentText("gphoto2")
    for name in ("turntable", "profiler"):
        _click(qtbot, w.devices.connect_buttons[name])
    qtbot.waitUntil(lambda: all(w.link.states[n] == "connected" for n in ("turntable", "profiler")), timeout=20_000)
    p = w.processing

    # the scanner: the reference sphere, one pass with 3 photos where the whole sphere is in view (60 mm off the
    # axis it leaves the 240 x 160 frame at most table angles); they tie the camera to the turntable
    _put(qtbot, w, SPHERE)
    _capture(qtbot, w, tmp_path / "sphere", "sphere-calibration", steps=72, passes=1, angles="60,90,120")
    w.tabs.setCurrentWidget(p)
    p.radius.setValue(25.0)
    _click(qtbot, p.calibrate_button)
    qtbot.waitUntil(lambda: p.calibration.text() == str(tmp_path / "sphere"), timeout=120_000)
    assert p.calibration_verdict.level == "pass", p.cal_state.text()
    assert "ChArUco board" in w.steps.hint.text()                # the strip says the camera comes next
    phase("connect + sphere scan + scanner calibration")

    # the camera: the board, flat then on two wedges, 6 photos per placement
    _put(qtbot, w, BOARD)
    board_world = w.station.world
    assert (board_world.width, board_world.height) == (960, 640)     # the sensor's full resolution
    _capture(qtbot, w, tmp_path / "board", "camera-calibration", steps=6, passes=3)
    phase("board capture")
    assert w.steps.current == "Calibrate" and "Calibrate the camera" in w.steps.hint.text()
    w.tabs.setCurrentWidget(p)
    _click(qtbot, p.camera_button)
    qtbot.waitUntil(lambda: p.camera_cal.text() == str(tmp_path / "board") or w.message_kind == "error",
                    timeout=300_000)
    assert p.camera_cal.text() == str(tmp_path / "board"), w.error_line.text()
    assert p.camera_verdict.level == "pass", p.station_state.text()
    calib = session_camera_calibration(tmp_path / "board", Session.read(tmp_path / "board"))
    k_true = board_world.camera_intrinsics()
    focal_pct = 100.0 * (calib.K[0, 0] / k_true[0, 0] - 1.0)
    rot_deg, shift_mm = pose_difference(np.linalg.inv(calib.room_to_camera), np.linalg.inv(board_world.room_to_camera()))
    print(f"camera vs truth: focal {focal_pct:+.3f} %, pose {rot_deg:.4f} deg / {shift_mm:.3f} mm, "
          f"rms {calib.rms_px:.3f} px")
    assert abs(focal_pct) <= 0.5 and rot_deg <= 0.1 and shift_mm <= 2.0
    assert "chrome sphere" in w.steps.hint.text()
    phase("camera calibration")

    # the lamps: the chrome sphere at 6 table angles
    _put(qtbot, w, CHROME)
    mirror_world = w.station.world
    assert w.capture.mirror_radius.value() == mirror_world.sphere_radius_mm
    _capture(qtbot, w, tmp_path / "lamp", "lamp-calibration", steps=6, passes=1)
    phase("chrome sphere capture")
    assert w.steps.current == "Calibrate" and "Calibrate the lamps" in w.steps.hint.text()
    w.tabs.setCurrentWidget(p)
    _click(qtbot, p.lamp_button)
    qtbot.waitUntil(lambda: p.lamp_cal.text() == str(tmp_path / "lamp") or w.message_kind == "error",
                    timeout=300_000)
    assert p.lamp_cal.text() == str(tmp_path / "lamp"), w.error_line.text()
    lamps = session_lamp_calibration(tmp_path / "lamp", Session.read(tmp_path / "lamp"))
    truth = mirror_world.lamp_truth()
    assert truth["kind"] == "distant" and len(lamps.lamps) == 1 and lamps.lamps[0].kind == "distant"
    d = np.asarray(truth["direction"], dtype=float) / np.linalg.norm(truth["direction"])
    lamp_deg = math.degrees(math.acos(float(np.clip(d @ lamps.lamps[0].direction, -1.0, 1.0))))
    print(f"lamp vs truth: direction {lamp_deg:.4f} deg")
    assert lamp_deg <= 0.5
    assert w.steps.current == "Session"                        # every calibration done: the piece's session next
    phase("lamp calibration")

    # the piece: 2 passes with photos every 45 degrees, the chart first in each
    _put(qtbot, w, HAWK)
    hawk_world = w.station.world
    assert (hawk_world.width, hawk_world.height) == (240, 160)       # back to the station's binned frames
    _capture(qtbot, w, tmp_path / "hawk", "scan", steps=48, passes=2, angles="0,45,90,135,180,225,270,315",
             chart=True)
    phase("hawk capture")

    # every pass's chart is found where the world put it (3 px: sub-pixel corners on 240 x 160)
    every_chart_found(qtbot, w, 2)
    phase("charts")

    # processed with the camera and lamps named: the photos are posed on the mesh
    w.tabs.setCurrentWidget(p)
    p.preset.setCurrentText("draft")
    _click(qtbot, p.run_button)
    qtbot.waitUntil(lambda: not p.running, timeout=900_000)
    assert p.report is not None and p.report.get("projection") is not None, w.error_line.text()
    qtbot.waitUntil(lambda: p.materials_button.isEnabled(), timeout=30_000)
    phase("processing with posed photos")

    # spectra: a frame calibrated with its own pass's chart; the map names only what the world holds (or the
    # alloys the head's nami-shibuichi cannot be told from in one image), or says it cannot tell
    w.tabs.setCurrentWidget(w.spectra)
    _click(qtbot, w.spectra.list_button)
    _click(qtbot, w.spectra.load_button)
    qtbot.waitUntil(lambda: w.spectra.scene is not None, timeout=120_000)
    assert "pass 1 chart frame" in w.spectra.state.text() and w.spectra.scene.usable_patches >= 20
    _click(qtbot, w.spectra.map_button)
    qtbot.waitUntil(lambda: w.spectra.map is not None or "material map:" in w.error_line.text(), timeout=120_000)
    assert w.spectra.map is not None, w.error_line.text()
    named = set(w.spectra.map[1].values()) - {"uncertain", NO_FIT, NEUTRAL_METAL}
    assert named <= set(hawk_world.materials.values()) | HAWK_LOOKALIKES, named
    assert "of the object" in w.spectra.state.text()
    phase("spectra")

    # materials on the mesh (no held-out validation: tests/app/test_object_materials.py checks it)
    p.materials_validate.setChecked(False)
    _click(qtbot, p.materials_button)
    qtbot.waitUntil(lambda: not p.measuring, timeout=600_000)
    assert w.message_kind != "error", w.error_line.text()
    doc = read_object_materials(tmp_path / "hawk")
    head = hawk_world.region_names.index("head")
    v, t = hawk_world.vertices, hawk_world.triangles
    areas = 0.5 * np.linalg.norm(np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]), axis=1)
    assert areas[hawk_world.region == head].sum() > 0.5 * areas.sum()      # the head is most of the surface
    big = max(doc["regions"], key=lambda r: r["area_mm2"])
    print(f"largest region: {big['material']} {big['group']}, {big['area_mm2']:.0f} of {doc['area_mm2']:.0f} mm2")
    assert big["material"] == "nami-shibuichi" or "nami-shibuichi" in big["group"], big
    phase("materials on the mesh")

    # the Preview shows the measured materials
    qtbot.waitUntil(lambda: w.preview.object_mesh is not None, timeout=20_000)
    w.tabs.setCurrentWidget(w.preview)
    assert w.preview.material.currentText() == MEASURED
    qtbot.waitUntil(lambda: w.preview.last is not None and not w.preview._busy, timeout=300_000)
    assert w.preview.last["mask"].mean() > 0.02
    assert w.message_kind != "error", w.error_line.text()
    phase("preview")
    print(f"whole posed session: {time.perf_counter() - t0:.1f} s ({'; '.join(phase.rows)})")
