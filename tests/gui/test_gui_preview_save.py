"""The Preview tab's "Save image…": the shown image written as a PNG off the window's thread, named in the log;
a place it cannot be written is one line naming it.

Ground truth: the PNG read back is the panel's image pixel for pixel, and the write is observed on a thread other
than the window's (a disk's wait there would freeze the window)."""

from __future__ import annotations

import threading

import pytest

pytest.importorskip("PySide6.QtWidgets", reason="the GUI tests need PySide6 (pip install 'kogei[gui]')")

import numpy as np
from PIL import Image
from PySide6.QtCore import Qt

from tests.gui.helpers import make_window


def _rendered(qtbot, tmp_path):
    import open3d as o3d

    m = o3d.geometry.TriangleMesh.create_sphere(radius=20.0, resolution=20)
    m.compute_vertex_normals()
    o3d.io.write_triangle_mesh(str(tmp_path / "sphere.ply"), m)
    w = make_window(qtbot, tmp_path)
    p = w.preview
    p.preset.setCurrentText("draft")
    p.size.setCurrentText("160x120")
    p.set_mesh(str(tmp_path / "sphere.ply"))
    qtbot.waitUntil(lambda: p.last_kind == "final" and not p._busy, timeout=120_000)
    return w, p


def test_save_writes_the_shown_image_off_the_window_thread_or_says_why_not(qtbot, tmp_path, monkeypatch):
    from PySide6.QtWidgets import QFileDialog

    import render.image_io as image_io

    w, p = _rendered(qtbot, tmp_path)
    threads, real = [], image_io.write_png

    def recording(*args, **kwargs):
        threads.append(threading.current_thread())
        return real(*args, **kwargs)

    monkeypatch.setattr(image_io, "write_png", recording)
    logged = []
    p.log.connect(logged.append)
    target = tmp_path / "out" / "shot.png"
    target.parent.mkdir()
    monkeypatch.setattr(QFileDialog, "getSaveFileName", lambda *a, **k: (str(target), "PNG (*.png)"))
    shown = p.image.copy()
    qtbot.mouseClick(p.save_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: any("preview saved to" in line for line in logged), timeout=10_000)
    assert threads and threads[0] is not threading.main_thread()
    assert np.array_equal(np.asarray(Image.open(target).convert("RGB")), shown[..., :3])
    assert str(target) in next(line for line in logged if "preview saved to" in line)
    assert w.message_kind != "error", w.error_line.text()

    # a place it cannot write is one line naming it (the same render: each costs a worker's start)
    target = tmp_path / "no such folder" / "shot.png"
    monkeypatch.setattr(QFileDialog, "getSaveFileName", lambda *a, **k: (str(target), "PNG (*.png)"))
    qtbot.mouseClick(p.save_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: w.message_kind == "error", timeout=10_000)
    line = w.error_line.text()
    assert line.startswith("preview: not saved to") and str(target) in line and "\n" not in line
    assert "Traceback" not in line and not target.parent.exists()
    # a cancelled dialog writes nothing and says nothing
    monkeypatch.setattr(QFileDialog, "getSaveFileName", lambda *a, **k: ("", ""))
    w.show_error("")
    qtbot.mouseClick(p.save_button, Qt.MouseButton.LeftButton)
    p.lane.wait(5_000)
    qtbot.wait(50)
    assert w.message_kind == ""
