"""Meshes with a material per face: the PLY writer/reader and the glTF reader, strict on damaged input."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh
from trimesh.visual import TextureVisuals
from trimesh.visual.material import PBRMaterial

from processing.geometry.mesh_ply import write_mesh_ply
from render.errors import MeshError
from render.material_mesh import material_mesh_or_none, read_material_mesh, write_material_ply


def _sphere():
    s = trimesh.creation.icosphere(2, radius=10.0)
    v, t = np.asarray(s.vertices), np.asarray(s.faces, dtype=np.int64)
    centre = v[t].mean(axis=1)
    fm = np.where(centre[:, 2] > 0, 0, 1)
    fm[np.abs(centre[:, 0]) < 1.5] = -1
    return v, t, np.asarray(s.vertex_normals), fm


SPECS = ["gold:roughness=0.2", "urushi-red", None]


def test_ply_round_trip_keeps_arrays_regions_and_header_lines(tmp_path):
    v, t, n, fm = _sphere()
    path = tmp_path / "obj.ply"
    write_material_ply(path, v, t, n, fm, SPECS)
    m = read_material_mesh(path)
    # float32 storage: positions of 10 mm within 1e-5 mm
    assert np.allclose(m.vertices, v, atol=1e-5) and np.array_equal(m.triangles, t)
    assert np.allclose(m.normals, n, atol=1e-6)
    assert np.array_equal(m.face_material, fm)
    assert m.specs == tuple(SPECS) and m.names == ("region-0", "region-1", "region-2")
    head = path.read_bytes().split(b"end_header")[0].decode("ascii").splitlines()
    assert head[:2] == ["ply", "format binary_little_endian 1.0"]
    assert [ln for ln in head if ln.startswith("comment")] == [
        "comment kogei material 0 gold:roughness=0.2", "comment kogei material 1 urushi-red",
        "comment kogei material 2"]
    assert "property int material" in head
    # size: header + V * 24 + T * 17 bytes, nothing else
    assert path.stat().st_size == len("\n".join(head)) + len("end_header\n") + 1 + 24 * len(v) + 17 * len(t)


def test_plain_ply_with_a_material_property_and_no_comments(tmp_path):
    v, t, n, fm = _sphere()
    fm = np.where(fm < 0, 2, fm)              # regions 0..2, no -1
    head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(v)}\nproperty double x\nproperty double y\n"
            f"property double z\nelement face {len(t)}\nproperty list uchar uint vertex_indices\n"
            "property int material\nend_header\n").encode("ascii")
    frec = np.empty(len(t), dtype=[("n", "u1"), ("i", "<u4", (3,)), ("m", "<i4")])
    frec["n"], frec["i"], frec["m"] = 3, t, fm
    path = tmp_path / "plain.ply"
    path.write_bytes(head + v.astype("<f8").tobytes() + frec.tobytes())
    m = read_material_mesh(path)
    assert m.specs == (None, None, None) and np.array_equal(m.face_material, fm)
    assert np.allclose(m.vertices, v)
    # computed normals of a sphere point outward: within 10 degrees of the radius
    radial = v / np.linalg.norm(v, axis=1, keepdims=True)
    assert np.min(np.einsum("ij,ij->i", m.normals, radial)) > np.cos(np.radians(10))


def test_a_ply_without_face_materials_is_none_or_an_error(tmp_path):
    v, t, n, _ = _sphere()
    path = tmp_path / "plain.ply"
    write_mesh_ply(path, v, t, n)
    assert material_mesh_or_none(path) is None
    with pytest.raises(MeshError, match="no 'material' property"):
        read_material_mesh(path)
    text = tmp_path / "vertexmat.ply"                  # ASCII, 'material' on the vertices: not per-face
    text.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                    "property float z\nproperty int material\nelement face 1\n"
                    "property list uchar int vertex_indices\nend_header\n0 0 0 1\n1 0 0 1\n0 1 0 1\n3 0 1 2\n")
    assert material_mesh_or_none(text) is None


def _damage(tmp_path, edit):
    v, t, n, fm = _sphere()
    path = tmp_path / "obj.ply"
    write_material_ply(path, v, t, n, fm, SPECS)
    data = bytearray(path.read_bytes())
    body = data.index(b"end_header\n") + len(b"end_header\n")
    path.write_bytes(bytes(edit(data, body, len(v), len(t))))
    return path


def _set_face(data, body, nv, k, field_offset, value):
    start = body + 24 * nv + 17 * k + field_offset
    data[start:start + 4] = np.int32(value).tobytes()
    return data


@pytest.mark.parametrize("edit, message", [
    (lambda d, b, nv, nt: d[:-5], "truncated"),
    (lambda d, b, nv, nt: d + b"xx", "truncated, damaged"),
    (lambda d, b, nv, nt: d.replace(f"element vertex {nv}".encode(), b"element vertex 2000000000"), "vertices"),
    (lambda d, b, nv, nt: _set_face(d, b, nv, 3, 1, nv + 7), "index vertices outside"),
    (lambda d, b, nv, nt: _set_face(d, b, nv, 5, 13, 3), "outside -1..2"),
    (lambda d, b, nv, nt: _set_face(d, b, nv, 5, 13, -2), "outside -1..2"),
    (lambda d, b, nv, nt: d.replace(b"material 1 urushi-red", b"material 1 unobtainium"), "region 1"),
    (lambda d, b, nv, nt: d.replace(b"material 1 urushi-red", b"material 0 urushi-red"), "declared twice"),
    (lambda d, b, nv, nt: d.replace(b"binary_little_endian", b"binary_big_endian___"), "binary_little_endian"),
    (lambda d, b, nv, nt: d[:body_index(d)] + b"\x04" + d[body_index(d) + 1:], "not triangles"),
])
def test_damaged_ply_files_are_refused_with_one_line_naming_the_file(tmp_path, edit, message):
    path = _damage(tmp_path, edit)
    with pytest.raises(MeshError, match=message) as info:
        read_material_mesh(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def body_index(data):
    """Offset of the first face record's count byte (first face of the test sphere)."""
    body = data.index(b"end_header\n") + len(b"end_header\n")
    nv = int(data.split(b"element vertex ")[1].split(b"\n")[0])
    return body + 24 * nv


def test_writer_refuses_bad_input(tmp_path):
    v, t, n, fm = _sphere()
    with pytest.raises(MeshError, match="face_material"):
        write_material_ply(tmp_path / "a.ply", v, t, n, np.full(len(t), 3), SPECS)
    with pytest.raises(MeshError, match="region 0"):
        write_material_ply(tmp_path / "a.ply", v, t, n, fm, ["no-such-metal", None, None])
    with pytest.raises(MeshError, match=".ply"):
        write_material_ply(tmp_path / "a.obj", v, t, n, fm, SPECS)
    assert not list(tmp_path.iterdir())


def _glb(path, names, extras=None, translate=(0.0, 0.0, 0.0)):
    """A glb of two hemispheres (metres) written by trimesh, with material extras added to the JSON."""
    s = trimesh.creation.icosphere(2, radius=0.01)
    centre = s.triangles_center
    scene = trimesh.Scene()
    parts = []
    for k, name in enumerate(names):
        sel = np.flatnonzero((centre[:, 2] > 0) == (k == 0))
        part = s.submesh([sel], append=True)
        part.visual = TextureVisuals(material=PBRMaterial(name=name, baseColorFactor=[0.5, 0.5, 0.5 + 0.1 * k, 1]))
        scene.add_geometry(part, geom_name=f"part{k}", transform=trimesh.transformations.translation_matrix(translate))
        parts.append(len(sel))

    def post(tree):
        for k, mat in enumerate(tree["materials"]):
            if extras is not None:
                mat["extras"] = {"kogei": extras[k]}

    path.write_bytes(trimesh.exchange.gltf.export_glb(scene, tree_postprocessor=post))
    return parts


def test_glb_primitives_become_regions_named_by_their_materials(tmp_path):
    path = tmp_path / "two.glb"
    counts = _glb(path, ["gold", "urushi-red"], translate=(0.1, 0.0, 0.0))
    m = read_material_mesh(path)
    assert m.names == ("gold", "urushi-red") and m.specs == ("gold", "urushi-red")
    assert np.bincount(m.face_material).tolist() == counts
    # metres -> millimetres, node translation applied: centre at x = 100 mm, radius 10 mm
    assert np.allclose(m.vertices.mean(axis=0), [100.0, 0.0, 0.0], atol=0.5)
    assert np.allclose(np.linalg.norm(m.vertices - [100.0, 0, 0], axis=1), 10.0, atol=1e-4)
    # upper hemisphere is region 0
    assert np.all(m.vertices[m.triangles[m.face_material == 0]].mean(axis=1)[:, 2] > 0)


def test_glb_spec_from_extras_overrides_the_name(tmp_path):
    path = tmp_path / "extras.glb"
    _glb(path, ["alloy", "not measured"], extras=[{"spec": "nami-shibuichi:Ag=0.3,Cu=0.7"},
                                                  {"spec": None, "measured": False}])
    m = read_material_mesh(path)
    assert m.specs == ("nami-shibuichi:Ag=0.3,Cu=0.7", None) and m.names == ("alloy", "not measured")
    _glb(path, ["a", "b"], extras=[{"spec": "gold"}, {"spec": "no-such"}])
    with pytest.raises(MeshError, match="material 1"):
        read_material_mesh(path)


def test_damaged_glb_is_refused(tmp_path):
    path = tmp_path / "two.glb"
    _glb(path, ["gold", "urushi-red"])
    data = bytearray(path.read_bytes())
    (tmp_path / "cut.glb").write_bytes(bytes(data[:-100]))
    with pytest.raises(MeshError, match="cut.glb"):
        read_material_mesh(tmp_path / "cut.glb")
    chunk = int.from_bytes(data[12:16], "little")
    doc = json.loads(bytes(data[20:20 + chunk]))
    doc["meshes"][0]["primitives"][0]["material"] = 9
    text = json.dumps(doc, separators=(",", ":")).encode().ljust(chunk)
    assert len(text) == chunk
    (tmp_path / "bad.glb").write_bytes(bytes(data[:20]) + text + bytes(data[20 + chunk:]))
    with pytest.raises(MeshError, match="bad.glb': a primitive uses a material beyond"):
        read_material_mesh(tmp_path / "bad.glb")


@pytest.mark.parametrize("uri", ["../secret.bin", "/etc/passwd", "http://example.com/a.bin", "a/../../b.bin"])
def test_gltf_buffers_outside_the_folder_are_refused(tmp_path, uri):
    path = tmp_path / "ext.gltf"
    path.write_text(json.dumps({"asset": {"version": "2.0"}, "buffers": [{"uri": uri, "byteLength": 36}],
                                "meshes": [], "materials": []}))
    with pytest.raises(MeshError, match="points outside the file's folder"):
        read_material_mesh(path)


def test_gltf_with_a_sibling_buffer_is_read(tmp_path):
    s = trimesh.creation.box(extents=(0.01, 0.02, 0.03))
    s.visual = TextureVisuals(material=PBRMaterial(name="copper"))
    files = trimesh.exchange.gltf.export_gltf(trimesh.Scene(s))
    for fname, data in files.items():
        (tmp_path / fname).write_bytes(data)
    m = read_material_mesh(tmp_path / "model.gltf")
    assert m.specs == ("copper",) and len(m.triangles) == 12
    assert np.allclose(m.vertices.max(axis=0) - m.vertices.min(axis=0), [10.0, 20.0, 30.0], atol=1e-4)


def test_random_damage_is_a_mesh_error_or_a_valid_mesh(tmp_path):
    """300 PLY and 300 GLB files with 1-3 random bytes changed (and some cut short): never another exception."""
    v, t, n, fm = _sphere()
    write_material_ply(tmp_path / "a.ply", v, t, n, fm, SPECS)
    _glb(tmp_path / "a.glb", ["gold", "urushi-red"])
    rng = np.random.default_rng(7)
    outcomes = {"ok": 0, "error": 0}
    for suffix in (".ply", ".glb"):
        base = (tmp_path / f"a{suffix}").read_bytes()
        for _ in range(300):
            data = bytearray(base)
            for k in rng.integers(0, min(len(data), 2500), size=rng.integers(1, 4)):
                data[k] = int(rng.integers(0, 256))
            if rng.random() < 0.2:
                data = data[: int(rng.integers(0, len(data)))]
            path = tmp_path / f"x{suffix}"
            path.write_bytes(bytes(data))
            try:
                m = read_material_mesh(path)
            except MeshError as exc:
                assert "\n" not in str(exc) and str(path) in str(exc)
                outcomes["error"] += 1
            else:
                assert m.face_material.min() >= -1 and m.face_material.max() < m.n_regions
                assert m.triangles.max() < len(m.vertices) and np.all(np.isfinite(m.vertices))
                outcomes["ok"] += 1
    assert outcomes["error"] > 100
