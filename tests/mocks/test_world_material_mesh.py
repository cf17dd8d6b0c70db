"""The simulated world from a mesh file with per-face materials: the truth per triangle and a frame.

A sphere of 30 mm radius centred where the station's camera looks, gold above its equator and
urushi-red below, written as a PLY with a material per face and as a two-primitive glTF (trimesh,
metres).  The world's region per triangle must be the file's, its materials the file's specs, and a
frame must show both: gold's highlight yellow (linear sRGB R > G > B) and the lacquer red (R > 2 G).
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from mocks.world import World, WorldError
from processing.spectral.display import spectra_to_xyz, white_xyz, xyz_to_linear_srgb
from render.material_mesh import write_material_ply

CENTRE_MM = np.array([0.0, 0.0, 37.0])


@pytest.fixture(scope="module")
def sphere():
    s = trimesh.creation.icosphere(3, radius=30.0)
    v = np.asarray(s.vertices) + CENTRE_MM
    t = np.asarray(s.faces, dtype=np.int64)
    upper = v[t].mean(axis=1)[:, 2] > CENTRE_MM[2] + 0.5     # some centroids lie on the equator
    return v, t, np.asarray(s.vertex_normals), np.where(upper, 0, 1)


def test_two_region_ply_round_trips_into_world_truth(sphere, tmp_path):
    v, t, n, fm = sphere
    path = tmp_path / "two.ply"
    write_material_ply(path, v, t, n, fm, ["gold", "urushi-red"])
    w = World.from_mesh_file(path)
    assert w.region_names == ("region-0", "region-1")
    assert w.materials == {"region-0": "gold", "region-1": "urushi-red"}
    assert np.array_equal(w.region, fm) and np.allclose(w.vertices, v, atol=1e-4)
    again = World.from_dict(w.to_dict())
    assert again.materials == w.materials and np.array_equal(again.region, fm)


def test_faces_without_a_spec_take_the_material_argument(sphere, tmp_path):
    v, t, n, fm = sphere
    fm = fm.copy()
    fm[:10] = -1
    path = tmp_path / "partial.ply"
    write_material_ply(path, v, t, n, fm, ["gold", None])
    w = World.from_mesh_file(path, "copper")
    assert w.region_names == ("region-0", "region-1", "no region")
    assert w.materials == {"region-0": "gold", "region-1": "copper", "no region": "copper"}
    assert np.all(w.region[:10] == 2) and np.array_equal(w.region[10:], fm[10:])
    w = World.from_mesh_file(path, "copper", region_materials={"region-1": "silver"})
    assert w.materials["region-1"] == "silver"
    with pytest.raises(WorldError, match="no region.*beak"):
        World.from_mesh_file(path, region_materials={"beak": "gold"})


def test_two_primitive_glb_round_trips_into_world_truth(sphere, tmp_path):
    v, t, n, fm = sphere
    scene = trimesh.Scene()
    for region, name in enumerate(["gold", "urushi-red"]):
        part = trimesh.Trimesh(v / 1000.0, t[fm == region], vertex_normals=n, process=False)
        part.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.PBRMaterial(name=name))
        scene.add_geometry(part, geom_name=name)
    path = tmp_path / "two.glb"
    path.write_bytes(trimesh.exchange.gltf.export_glb(scene))
    w = World.from_mesh_file(path)
    assert w.region_names == ("gold", "urushi-red") and w.materials == {"gold": "gold", "urushi-red": "urushi-red"}
    # metres -> millimetres; the upper half is the gold region
    centres = w.vertices[w.triangles].mean(axis=1)
    assert np.allclose(np.linalg.norm(w.vertices - CENTRE_MM, axis=1), 30.0, atol=1e-3)
    assert np.array_equal(w.region, np.where(centres[:, 2] > CENTRE_MM[2] + 0.5, 0, 1))


def test_a_frame_shows_both_materials(sphere, tmp_path):
    v, t, n, fm = sphere
    path = tmp_path / "two.ply"
    write_material_ply(path, v, t, n, fm, ["gold", "urushi-red"])
    w = World.from_mesh_file(path, width=192, height=128)
    f = w.frame("object")
    counts = np.bincount(f.labels[f.labels >= 0].ravel(), minlength=2)
    assert counts.min() > 500, counts
    xyz = spectra_to_xyz(f.radiance, f.grid) * (1.0 / spectra_to_xyz(f.light / np.pi, f.grid)[1])
    rgb = xyz_to_linear_srgb(xyz, white_xyz(f.light, f.grid))
    gold = rgb[f.labels == 0]
    highlight = gold[np.argsort(gold.sum(axis=1))[-20:]].mean(axis=0)      # gold is dark off its highlight
    red = rgb[f.labels == 1].mean(axis=0)
    assert highlight[0] > highlight[1] > highlight[2] and highlight[2] < 0.75 * highlight[0], highlight
    assert red[0] > 2 * red[1] and red[0] > 2 * red[2], red


def test_kogei_mock_world_option_keeps_the_file_materials(sphere, tmp_path):
    import argparse

    from app.cli.mock import _build_world, add_parser

    v, t, n, fm = sphere
    path = tmp_path / "object-mesh.ply"
    fm = fm.copy()
    fm[:4] = -1
    write_material_ply(path, v, t, n, fm, ["gold", "urushi-red"])
    parser = argparse.ArgumentParser()
    add_parser(parser.add_subparsers(dest="command"))
    w = _build_world(parser.parse_args(["mock", "--world", str(path), "--material", "silver"]))
    assert w.materials == {"region-0": "gold", "region-1": "urushi-red", "no region": "silver"}
    assert np.bincount(w.region).tolist() == [int(np.sum(fm == 0)), int(np.sum(fm == 1)), 4]
