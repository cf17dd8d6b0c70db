"""The Processing tab's *Measure materials on the mesh*: measured in a worker process, judged, cancellable, and
offered by the Preview tab once done.

Ground truth: the session is the simulated hawk photographed with the station's true camera and lamp in two
placements at 8 table angles, its mesh the object's own (:mod:`tests.integration.object_session`, as in
test_gui_preview_measured.py).  The head's material and composition are checked against the simulated world's
truth with the tolerances of tests/app/test_object_materials.py (Ag within 3 points of 25 %, roughness within
10 % of 0.15).  Validation on the held-out photos is switched off here (the box is unticked): its renders
take most of a run's time and tests/app/test_object_materials.py checks it; this file tests the window.
"""

from __future__ import annotations

import pytest

pytest.importorskip("PySide6.QtWidgets", reason="the GUI tests need PySide6 (pip install 'kogei[gui]')")

import numpy as np
from PySide6.QtCore import Qt

from mocks.world import World
from tests.gui.helpers import make_window
from tests.integration.object_session import projected_hawk_two_placements

LEFT = Qt.MouseButton.LeftButton


@pytest.fixture(scope="module")
def posed(tmp_path_factory):
    """A session whose photos are posed on its mesh (products/observations.npz), materials not measured."""
    root = projected_hawk_two_placements(tmp_path_factory, tmp_path_factory.mktemp("posed") / "session")
    world = World.hawk(4000, width=240, height=160, chart_layout="classic24")
    return root, world


def _copy(posed, tmp_path):
    import shutil

    root, world = posed
    copy = tmp_path / "session"
    shutil.copytree(root, copy)
    return copy, world


def test_measure_materials_on_the_mesh_from_the_window(qtbot, tmp_path, posed):
    from app.gui.preview_panel import MEASURED
    from app.workflows.object_materials import read_object_materials
    from render.material_mesh import read_material_mesh

    root, world = _copy(posed, tmp_path)
    w = make_window(qtbot, tmp_path)
    w.session.open_session(str(root))
    w.tabs.setCurrentWidget(w.processing)
    p = w.processing
    assert p.materials_button.isEnabled() and "kogei fit-materials" in p.materials_button.toolTip()
    w.tabs.setCurrentWidget(w.session)
    w._show_step("Materials")                                   # the strip's Materials step leads to the button
    assert w.tabs.currentWidget() is p
    assert w.preview.object_mesh is None                         # nothing measured yet
    p.materials_validate.setChecked(False)
    qtbot.mouseClick(p.materials_button, LEFT)
    assert p.measuring and p.materials_cancel_button.isEnabled() and not p.materials_button.isEnabled()
    qtbot.waitUntil(lambda: not p.measuring, timeout=120_000)
    assert w.message_kind == "", w.error_line.text()
    doc = read_object_materials(root)
    assert (root / "products/object-materials.json").is_file() and (root / "products/object-mesh.ply").is_file()
    # the head's material against the simulated world's truth (tests/app/test_object_materials.py's tolerances)
    mesh = read_material_mesh(root / "products/object-mesh.ply")
    head = world.region_names.index("head")
    counts = [np.count_nonzero((mesh.face_material == r["index"]) & (world.region == head)) for r in doc["regions"]]
    reg = doc["regions"][int(np.argmax(counts))]
    assert reg["material"] == "nami-shibuichi" or "nami-shibuichi" in reg["group"]
    assert abs(reg["parameters"]["Ag"] - 0.25) <= 0.03                   # truth 25 % (Matsuda et al., Table 1)
    assert abs(reg["parameters"]["roughness"] - 0.15) <= 0.015           # truth 0.15: within 10 %
    # the result line: every region's answer and a verdict; a region not measured or not told apart is a warn
    from app.gui.guidance import UNMEASURED_WARN_SHARE

    text = p.materials_state.text()
    assert f"{len(doc['regions'])} region" in text and "not validated on held-out photos" in text
    undecided = any(r["material"] in ("not measured", "no candidate fits", "neutral metal")
                    or set(r["group"]) - {r["material"]} for r in doc["regions"])
    unseen = doc["not_measured"]["share"] >= UNMEASURED_WARN_SHARE     # a side never measured is a warn too
    assert p.materials_verdict.level == ("warn" if undecided or unseen else "pass")
    assert f"{100 * doc['not_measured']['share']:.1f} % of the surface not measured" in text
    assert p.materials_verdict.level.upper() in text
    # the window re-read the session: the Preview offers the measured material on the measured mesh
    qtbot.waitUntil(lambda: (w.session.manifest.get("products") or {}).get("object_materials") is not None,
                    timeout=10_000)
    assert w.preview.material.currentText() == MEASURED
    assert w.preview.object_mesh == str(root / "products/object-mesh.ply")
    assert p.materials_button.isEnabled() and not p.materials_cancel_button.isEnabled()


def test_cancel_measuring_leaves_no_partial_products(qtbot, tmp_path, posed):
    root, _ = _copy(posed, tmp_path)
    before = (root / "session.json").read_bytes()
    w = make_window(qtbot, tmp_path)
    w.session.open_session(str(root))
    w.tabs.setCurrentWidget(w.processing)
    p = w.processing
    qtbot.mouseClick(p.materials_button, LEFT)
    assert p.measuring
    qtbot.mouseClick(p.materials_cancel_button, LEFT)
    qtbot.waitUntil(lambda: not p.measuring, timeout=10_000)
    assert not p.materials_job._proc.is_alive()
    assert "cancelled by the user" in w.error_line.text() and w.message_kind == "info"
    assert p.materials_state.text().startswith("cancelled")
    assert (root / "session.json").read_bytes() == before
    for rel in ("object-materials.json", "object-mesh.ply", "object-scene.toml", "validation"):
        assert not (root / "products" / rel).exists(), rel
    assert p.materials_button.isEnabled() and w.preview.object_mesh is None


def test_cancel_during_validation_removes_what_the_run_wrote(qtbot, tmp_path, posed, monkeypatch):
    """The library writes the object's mesh and scene before it renders the held-out photos; a stop then must not
    leave them for the Preview to offer (it offers the measured material when object-mesh.ply exists).  The files
    are removed off the window's thread, and Measure waits for them."""
    import threading

    import app.gui.processing_panel as panel

    threads, real = [], panel.remove_unrecorded

    def recording(*args):
        threads.append(threading.current_thread())
        assert p.measuring                    # Measure stays unavailable until the files are gone
        return real(*args)

    monkeypatch.setattr(panel, "remove_unrecorded", recording)
    root, _ = _copy(posed, tmp_path)
    w = make_window(qtbot, tmp_path)
    w.session.open_session(str(root))
    p = w.processing
    assert p.materials_validate.isChecked()                             # the default: validated
    qtbot.mouseClick(p.materials_button, LEFT)
    qtbot.waitUntil(lambda: p.materials_state.text().startswith("validating") or not p.measuring, timeout=120_000)
    assert p.measuring and (root / "products/object-mesh.ply").is_file()   # written, not recorded yet
    qtbot.mouseClick(p.materials_cancel_button, LEFT)
    qtbot.waitUntil(lambda: not p.measuring, timeout=10_000)
    assert w.message_kind == "info" and "removed" in w.error_line.text()
    assert threads and threads[0] is not threading.main_thread()
    assert p.materials_button.isEnabled() and p.materials_state.text() == "cancelled: the session is as it was"
    for rel in ("object-materials.json", "object-mesh.ply", "object-scene.toml", "validation"):
        assert not (root / "products" / rel).exists(), rel
    w.preview.mesh_changed()
    assert w.preview.object_mesh is None


def test_button_is_disabled_without_posed_photos(qtbot, tmp_path):
    from app.session import Session

    bare = tmp_path / "bare"
    Session.create(bare, plan={"kind": "scan", "steps": 4, "passes": 1}).close()
    w = make_window(qtbot, tmp_path)
    assert not w.processing.materials_button.isEnabled()               # no session open
    w.session.open_session(str(bare))
    p = w.processing
    assert not p.materials_button.isEnabled()
    tip = p.materials_button.toolTip()
    assert "not posed" in tip and "calibrate the camera and the lamps" in tip and "Process" in tip


def test_a_failure_is_one_line_in_the_window(qtbot, tmp_path, posed):
    root, _ = _copy(posed, tmp_path)
    (root / "products/observations.npz").write_bytes(b"not an npz")      # damaged after it was recorded
    w = make_window(qtbot, tmp_path)
    w.session.open_session(str(root))
    p = w.processing
    qtbot.mouseClick(p.materials_button, LEFT)
    qtbot.waitUntil(lambda: not p.measuring, timeout=60_000)
    text = w.error_line.text()
    assert w.message_kind == "error" and "\n" not in text and "Traceback" not in text
    assert str(root) in text and "kogei project" in text and p.materials_state.text().startswith("stopped:"), text
    assert not (root / "products/object-materials.json").exists()


def test_removing_a_cancelled_runs_files_keeps_what_was_there_and_what_the_session_records(tmp_path):
    """remove_unrecorded: files and folders that did not exist before the run go; those that did stay; a result the
    session records, written by this run, stays whole (the run finished before the stop)."""
    from app.gui.processing_panel import _stamp, remove_unrecorded
    from app.session import Session

    root = tmp_path / "s"
    Session.create(root, plan={"kind": "scan", "steps": 4, "passes": 1}).close()
    (root / "products/validation/run").mkdir(parents=True)
    (root / "products/object-scene.toml").write_text("kept: it was there before the run\n")
    before = {"products/object-materials.json": None, "products/object-mesh.ply": None,
              "products/object-scene.toml": _stamp(root / "products/object-scene.toml"), "products/validation": None}
    for rel in ("products/object-materials.json", "products/object-mesh.ply", "products/validation/run/a.png",
                "products/validation/b.png"):
        (root / rel).write_text("written by the run\n")
    assert remove_unrecorded(root, before) == 4
    assert sorted(p.relative_to(root).as_posix() for p in (root / "products").rglob("*")) == [
        "products/object-scene.toml"]
    # recorded by the session (the run got that far): nothing is removed
    (root / "products/object-mesh.ply").write_text("written by the run\n")
    s = Session.open(root)
    info = s.write_file("products/object-materials.json", b"{}\n")
    s.update("products", {"object_materials": {"file": "products/object-materials.json", "sha256": info.sha256,
                                               "bytes": info.bytes}})
    s.close()
    assert remove_unrecorded(root, before) == 0 and (root / "products/object-mesh.ply").is_file()
    assert remove_unrecorded(None, before) == 0


def test_files_a_cancelled_run_could_not_remove_are_one_line_saying_what_to_do(qtbot, tmp_path):
    w = make_window(qtbot, tmp_path)
    w.processing._tidied("cancelled by the user", None, "[Errno 13] Permission denied: '/s/products/object-mesh.ply'")
    line = w.error_line.text()
    assert w.message_kind == "error" and "\n" not in line
    assert "Permission denied: '/s/products/object-mesh.ply'" in line and "remove it by hand" in line
    assert w.processing.materials_state.text().startswith("cancelled: some of what the run wrote is still there")
