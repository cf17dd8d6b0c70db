"""The Preview tab on a session whose materials were measured on the mesh: it renders the measured object
and a click on it plots the clicked region's observations against the region's fitted model.

Ground truth: the session is the simulated hawk photographed with the station's true camera and lamp,
its mesh the object's own (:mod:`tests.integration.object_session`); the clicked pixel's face is
found independently by ray casting the same camera ray against the mesh.
"""

from __future__ import annotations

import pytest

pytest.importorskip("PySide6.QtWidgets", reason="the GUI tests need PySide6 (pip install 'kogei[gui]')")

import numpy as np

from tests.gui.helpers import make_window
from tests.integration.object_session import projected_hawk_two_placements


def test_preview_renders_the_measured_object_and_plots_a_clicked_region(qtbot, tmp_path, tmp_path_factory):
    import open3d as o3d

    from app.gui.preview_panel import MEASURED, click_ray
    from app.workflows.object_materials import measure_object, read_object_materials
    from render.material_mesh import read_material_mesh

    # projected once per run, shared with tests/gui/test_gui_materials_on_mesh.py
    root = projected_hawk_two_placements(tmp_path_factory, tmp_path / "session")
    measure_object(root, validate=False)
    w = make_window(qtbot, tmp_path)
    w.session.open_session(str(root))
    w.tabs.setCurrentWidget(w.preview)
    # opening the session is enough: the Preview takes its mesh (no "no mesh yet" beside a "mesh ready")
    assert w.preview.material.currentText() == MEASURED and w.preview.object_mesh is not None
    qtbot.waitUntil(lambda: w.preview.last_kind == "final" and not w.preview._busy, timeout=120_000)
    img, mask = w.preview.last["srgb8"], w.preview.last["mask"] > 0.99
    assert img.std() > 5 and mask.mean() > 0.05
    # click the object's middle; the face under it, found independently, names the region the panel shows
    ys, xs = np.nonzero(mask)
    k = int(np.argmin((ys - ys.mean()) ** 2 + (xs - xs.mean()) ** 2))
    origin, direction = click_ray(w.preview.last, xs[k] + 0.5, ys[k] + 0.5)
    mesh = read_material_mesh(root / "products/object-mesh.ply")
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)),
                        o3d.core.Tensor(mesh.triangles.astype(np.uint32)))
    hit = scene.cast_rays(o3d.core.Tensor(np.float32([[*origin, *direction]])))
    region = int(mesh.face_material[int(hit["primitive_ids"].numpy()[0])])
    view = w.preview.view
    h, wd = img.shape[:2]
    scale = min(view.width() / wd, view.height() / h)
    x0, y0 = (view.width() - wd * scale) / 2, (view.height() - h * scale) / 2
    w.preview._clicked(x0 + (xs[k] + 0.5) * scale, y0 + (ys[k] + 0.5) * scale)
    qtbot.waitUntil(lambda: w.preview.info.text().startswith("region"), timeout=60_000)
    qtbot.waitUntil(lambda: not w.preview.region_plot.busy and w.preview.region_plot.draws >= 2, timeout=60_000)
    assert w.preview.info.text().startswith(f"region {region}:")
    doc = read_object_materials(root)
    named = "not measured" if region < 0 else doc["regions"][region]["material"]
    assert named in w.preview.info.text()
