"""Scene files whose mesh carries per-face materials render them region by region.

A sphere of 20 mm split at its equator (upper half gold, lower half urushi-red, a band of faces of no
region around the equator) is rendered at 64 x 48 with a light from the camera and a uniform sky.
Expectations are the materials' known colours, not the renderer's output: gold is yellow (linear sRGB
R > G > B, blue below 0.75 of red), urushi-red is red (R above twice G and B), the grey of faces
without a material is neutral (channels within 10 % of each other).
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from app.errors import UsageError
from app.workflows.scene_build import build_job
from app.workflows.scene_spec import load_scene_file
from processing.geometry.mesh_ply import write_mesh_ply
from processing.spectral.display import xyz_to_linear_srgb
from render.material_mesh import write_material_ply
from render.renderer import render

SCENE = """
[render]
size = "64x48"
preset = "draft"
[camera]
eye = [0.0, -150.0, 0.0]
target = [0.0, 0.0, 0.0]
fov = 20.0
[sky]
kind = "uniform"
zenith = 0.6
[[light]]
kind = "directional"
direction = [0.3, -1.0, 0.3]
[[object]]
mesh = "{mesh}"
{extra}
"""


def _sphere():
    s = trimesh.creation.icosphere(3, radius=20.0)
    v, t = np.asarray(s.vertices), np.asarray(s.faces)
    z = v[t].mean(axis=1)[:, 2]
    fm = np.where(z > 0, 0, 1)
    fm[np.abs(z) < 4.0] = -1
    return v, t, np.asarray(s.vertex_normals), fm


def _halves(tmp_path, mesh_name, extra=""):
    """Mean linear sRGB of the object's upper rows, lower rows and middle rows (the equator band)."""
    scene = tmp_path / f"scene-{len(extra)}.toml"
    scene.write_text(SCENE.format(mesh=mesh_name, extra=extra))
    job = build_job(load_scene_file(scene))
    result = render(job.scene, job.camera, job.settings)
    rgb = xyz_to_linear_srgb(result.xyz.astype(np.float64), result.white)
    mask = result.mask > 0.99
    rows = np.arange(mask.shape[0])[:, None] * np.ones(mask.shape[1])[None, :]
    top, bottom = rows < 24 - 5, rows > 24 + 4
    mid = (rows >= 23) & (rows <= 24)
    return [rgb[mask & sel].mean(axis=0) for sel in (top, bottom, mid)]


@pytest.fixture(scope="module")
def ply(tmp_path_factory):
    root = tmp_path_factory.mktemp("facemat")
    v, t, n, fm = _sphere()
    write_material_ply(root / "two.ply", v, t, n, fm, ["gold", "urushi-red"])
    write_mesh_ply(root / "plain.ply", v, t, n)
    return root


def _yellow(c):
    return c[0] > c[1] > c[2] and c[2] < 0.75 * c[0]


def _red(c):
    return c[0] > 2 * c[1] and c[0] > 2 * c[2]


def test_per_face_materials_render_region_by_region(ply):
    top, bottom, mid = _halves(ply, "two.ply")
    assert _yellow(top), top
    assert _red(bottom), bottom
    assert np.ptp(mid) < 0.1 * mid.mean(), mid          # the band of no region: neutral grey


def test_materials_table_overrides_regions_by_index_or_name(ply):
    top, bottom, _ = _halves(ply, "two.ply", 'materials = { "0" = "urushi-red", "region-1" = "gold" }')
    assert _red(top), top
    assert _yellow(bottom), bottom
    with pytest.raises(UsageError, match="no region"):
        _halves(ply, "two.ply", 'materials = { "beak" = "gold" }')


def test_mesh_without_face_materials_keeps_the_object_material(ply):
    top, bottom, _ = _halves(ply, "plain.ply", 'material = "urushi-red"')
    assert _red(top) and _red(bottom), (top, bottom)


def test_glb_primitives_render_with_their_materials(ply, tmp_path):
    v, t, n, fm = _sphere()
    fm = np.where(fm < 0, 1, fm)                        # no faces of no region: a closed sphere
    scene = trimesh.Scene()
    for region, name in enumerate(["gold", "urushi-red"]):
        sel = np.flatnonzero(fm == region)
        part = trimesh.Trimesh(v / 1000.0, t[sel], vertex_normals=n, process=False)
        part.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.PBRMaterial(name=name))
        scene.add_geometry(part, geom_name=name)
    (ply / "two.glb").write_bytes(trimesh.exchange.gltf.export_glb(scene))
    top, bottom, _ = _halves(ply, "two.glb")
    assert _yellow(top), top
    assert _red(bottom), bottom


def test_dropped_zero_area_triangles_take_their_region_with_them(tmp_path):
    v, t, n, fm = _sphere()
    t2 = np.vstack([[0, 0, 1], t])                      # a zero-area triangle first, region 1
    fm2 = np.concatenate([[1], fm])
    write_material_ply(tmp_path / "degenerate.ply", v, t2, n, fm2, ["gold", "urushi-red"])
    scene = tmp_path / "s.toml"
    scene.write_text(SCENE.format(mesh="degenerate.ply", extra=""))
    with pytest.warns(UserWarning, match="dropped 1 zero-area"):
        job = build_job(load_scene_file(scene))
    obj = job.scene.objects[0]
    assert obj.mesh.n_triangles == len(t)
    # regions 0, 1 and the grey (index 2) of the faces of no region, in the file's order
    assert np.array_equal(obj.material_index, np.where(fm < 0, 2, fm))
    assert [m.name for m in obj.materials][-1].startswith("not measured")
