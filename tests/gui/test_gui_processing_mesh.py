"""The Processing tab's mesh view: the session's mesh rendered (in a worker process) once it exists, a line
saying there is none before.

Ground truth: the geometry of the view.  A sphere of radius r has a bounding box of half-diagonal r * sqrt(3);
the view frames that at distance d = r sqrt(3) / sin(17.5 deg) * 1.05 with a 35 deg vertical field of view, so the
sphere's outline is a disc of angular radius asin(r / d) = 9.52 deg, i.e. tan(9.52 deg) / tan(17.5 deg) = 0.532
of the half-height: at 360 x 270 px it covers pi (0.532 * 135)^2 / (360 * 270) = 16.7 % of the image.
"""

from __future__ import annotations

import math

import pytest

pytest.importorskip("PySide6.QtWidgets", reason="the GUI tests need PySide6 (pip install 'kogei[gui]')")

from PySide6.QtCore import Qt

from app.gui.processing_panel import MESH_VIEW_SIZE
from app.session import Session
from tests.gui.helpers import make_window

LEFT = Qt.MouseButton.LeftButton


def _session_with_a_sphere_mesh(root):
    import open3d as o3d

    Session.create(root, plan={"kind": "scan", "steps": 4, "passes": 1}).close()
    (root / "products").mkdir()
    m = o3d.geometry.TriangleMesh.create_sphere(radius=20.0, resolution=60)
    m.compute_vertex_normals()
    o3d.io.write_triangle_mesh(str(root / "products" / "mesh.ply"), m)
    return root


def test_the_mesh_view_shows_the_sessions_mesh(qtbot, tmp_path):
    w = make_window(qtbot, tmp_path)
    p = w.processing
    assert "no mesh yet" in p.mesh_view.text()                      # the empty view says what fills it
    Session.create(tmp_path / "bare", plan={"kind": "scan", "steps": 4, "passes": 1}).close()
    w.session.folder.setText(str(tmp_path / "bare"))
    qtbot.mouseClick(w.session.open_button, LEFT)
    assert "no mesh yet" in p.mesh_view.text() and p.mesh_image is None

    root = _session_with_a_sphere_mesh(tmp_path / "s")
    w.session.folder.setText(str(root))
    qtbot.mouseClick(w.session.open_button, LEFT)
    assert not p.mesh_busy.isHidden() or p.mesh_image is not None    # busy while the worker renders
    qtbot.waitUntil(lambda: p.mesh_image is not None, timeout=180_000)
    assert w.error_line.isHidden() or w.message_kind != "error", w.error_line.text()
    assert p.mesh_shown == str(root / "products" / "mesh.ply") and p.mesh_busy.isHidden()
    assert p.mesh_image.shape == (MESH_VIEW_SIZE[1], MESH_VIEW_SIZE[0], 3)
    assert not p.mesh_view.pixmap().isNull()
    # the sphere's outline covers the fraction of the image the view's geometry gives (see the docstring);
    # 1 % for the tessellation (a 60-ring sphere is 0.2 % smaller in area) and the outline's antialiasing
    # (measured: 0.16644 against 0.16654)
    covered = float(p.mesh_mask.mean())                          # the render's own coverage of each pixel
    alpha = math.asin(math.sin(math.radians(17.5)) / (math.sqrt(3) * 1.05))
    radius_px = math.tan(alpha) / math.tan(math.radians(17.5)) * MESH_VIEW_SIZE[1] / 2
    expected = math.pi * radius_px ** 2 / (MESH_VIEW_SIZE[0] * MESH_VIEW_SIZE[1])
    assert covered == pytest.approx(expected, rel=0.01), (covered, expected)
    assert "triangles" in p.mesh_view.toolTip()
