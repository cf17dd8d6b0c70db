"""The Preview tab's orbit drafts keep the mesh's ray tracer; a changed mesh file is never drawn stale.

Truth: the same view rendered in a fresh process state (a new geometry cache), and the silhouette of a
sphere whose radius the test sets.
"""

from __future__ import annotations

import pytest

pytest.importorskip("PySide6.QtWidgets", reason="the GUI tests need PySide6 (pip install 'kogei[gui]')")

import numpy as np


def _sphere(path, radius: float):
    import open3d as o3d

    m = o3d.geometry.TriangleMesh.create_sphere(radius=radius, resolution=30)
    m.compute_vertex_normals()
    o3d.io.write_triangle_mesh(str(path), m)
    return path


def _view(mesh, **kw):
    from app.gui.preview_panel import render_view

    bounds = (np.array([-20.0, -20.0, -20.0]), np.array([20.0, 20.0, 20.0]))
    args = dict(mesh=str(mesh), material="gold", illuminant="D65", light=(0.3, -0.6, 0.7), azimuth_deg=30.0,
                elevation_deg=20.0, size=(64, 48), preset="draft", bounds=bounds)
    args.update(kw)
    return render_view(**args)


def test_drafts_of_one_mesh_reuse_its_tracer_and_match_a_fresh_render(tmp_path, monkeypatch):
    import app.gui.preview_panel as pp

    mesh = _sphere(tmp_path / "ball.ply", 15.0)
    monkeypatch.setattr(pp, "_GEOMETRY", pp._SameGeometry())
    first = _view(mesh)
    turned = _view(mesh, azimuth_deg=60.0, material="copper")     # the orbit moves, another material
    assert not first["geometry_reused"] and turned["geometry_reused"]
    monkeypatch.setattr(pp, "_GEOMETRY", pp._SameGeometry())       # a fresh state draws the same image
    fresh = _view(mesh, azimuth_deg=60.0, material="copper")
    assert not fresh["geometry_reused"]
    np.testing.assert_array_equal(turned["srgb8"], fresh["srgb8"])


def test_a_rewritten_mesh_file_gets_a_new_tracer(tmp_path, monkeypatch):
    import app.gui.preview_panel as pp

    mesh = tmp_path / "ball.ply"
    monkeypatch.setattr(pp, "_GEOMETRY", pp._SameGeometry())
    big = _view(_sphere(mesh, 15.0))
    small = _view(_sphere(mesh, 7.0))                                 # same path, new content
    assert not small["geometry_reused"]
    # a sphere of half the radius covers about a quarter of the pixels (perspective: a little more)
    ratio = small["mask"].sum() / big["mask"].sum()
    assert 0.18 < ratio < 0.35, ratio
