"""Mesh loading and validation: formats, errors with the file named, degenerate
triangles, area-weighted normals."""

from __future__ import annotations

import json
import struct
import warnings

import numpy as np
import pytest
from hypothesis import given
from hypothesis import settings as hsettings
from hypothesis import strategies as st

from render.errors import MeshError, MeshWarning
from render.meshio import face_normals, load_mesh, make_mesh, smooth_vertex_normals

TETRA_V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
TETRA_T = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])     # outward


def write_ply(path, vertices, triangles, normals=None):
    head = ["ply", "format ascii 1.0", f"element vertex {len(vertices)}",
            "property float x", "property float y", "property float z"]
    if normals is not None:
        head += ["property float nx", "property float ny", "property float nz"]
    head += [f"element face {len(triangles)}", "property list uchar int vertex_indices", "end_header"]
    rows = []
    for i, v in enumerate(vertices):
        vals = list(v) + (list(normals[i]) if normals is not None else [])
        rows.append(" ".join(repr(float(x)) for x in vals))
    rows += ["3 " + " ".join(str(int(i)) for i in t) for t in triangles]
    path.write_text("\n".join(head + rows) + "\n")
    return path


def write_glb(path, vertices, triangles):
    v = np.asarray(vertices, np.float32)
    t = np.asarray(triangles, np.uint32).ravel()
    binary = v.tobytes() + t.tobytes()
    doc = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "buffers": [{"byteLength": len(binary)}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": v.nbytes},
                        {"buffer": 0, "byteOffset": v.nbytes, "byteLength": t.nbytes}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": len(v), "type": "VEC3",
             "min": v.min(0).tolist(), "max": v.max(0).tolist()},
            {"bufferView": 1, "componentType": 5125, "count": t.size, "type": "SCALAR"},
        ],
    }
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    binary += b"\0" * (-len(binary) % 4)
    total = 12 + 8 + len(js) + 8 + len(binary)
    path.write_bytes(struct.pack("<III", 0x46546C67, 2, total) + struct.pack("<II", len(js), 0x4E4F534A) + js
                     + struct.pack("<II", len(binary), 0x004E4942) + binary)
    return path


def o3d_mesh(vertices, triangles):
    import open3d as o3d

    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(triangles))
    return m


# --------------------------------------------------------------------------- formats
@pytest.mark.parametrize("suffix", [".ply", ".obj", ".stl", ".off", ".gltf", ".glb"])
def test_every_supported_format_loads_the_same_tetrahedron(tmp_path, suffix):
    import open3d as o3d

    path = tmp_path / f"tetra{suffix}"
    if suffix == ".glb":
        write_glb(path, TETRA_V, TETRA_T)
    else:
        m = o3d_mesh(TETRA_V, TETRA_T)
        if suffix == ".stl":
            m.compute_triangle_normals()
        assert o3d.io.write_triangle_mesh(str(path), m)
    mesh = load_mesh(path)
    assert mesh.n_vertices == 4 and mesh.n_triangles == 4     # STL vertices merged back to 4
    assert mesh.source == str(path)
    # the same geometry: every triangle's vertex set maps to one of the original faces
    got = {tuple(sorted(map(tuple, np.round(mesh.vertices[t], 6)))) for t in mesh.triangles}
    want = {tuple(sorted(map(tuple, TETRA_V[t]))) for t in TETRA_T}
    assert got == want
    # outward normals at the origin corner point into the negative octant
    corner = int(np.argmin(np.linalg.norm(mesh.vertices, axis=1)))
    assert np.all(mesh.vertex_normals[corner] < 0)
    np.testing.assert_allclose(np.linalg.norm(mesh.vertex_normals, axis=1), 1.0)


def test_normals_in_the_file_are_kept_and_normalised(tmp_path):
    normals = np.array([[0.0, 0.0, 2.0]] * 4)
    mesh = load_mesh(write_ply(tmp_path / "n.ply", TETRA_V, TETRA_T, normals))
    assert not mesh.normals_computed
    np.testing.assert_allclose(mesh.vertex_normals, np.tile([0.0, 0.0, 1.0], (4, 1)), atol=1e-7)


def test_obj_material_groups_become_a_per_triangle_index(tmp_path):
    (tmp_path / "two.mtl").write_text("newmtl a\nKd 1 0 0\nnewmtl b\nKd 0 1 0\n")
    obj = ["mtllib two.mtl"] + [f"v {x} {y} {z}" for x, y, z in TETRA_V]
    obj += ["usemtl a", "f 1 3 2", "f 1 2 4", "usemtl b", "f 1 4 3", "f 2 3 4"]
    (tmp_path / "two.obj").write_text("\n".join(obj) + "\n")
    mesh = load_mesh(tmp_path / "two.obj")
    assert mesh.material_index_on == "triangle"
    assert sorted(np.bincount(mesh.material_index).tolist()) == [2, 2]


# --------------------------------------------------------------------------- errors
def test_missing_empty_unreadable_and_wrong_files(tmp_path):
    with pytest.raises(MeshError, match=r"'.*nope\.ply' does not exist"):
        load_mesh(tmp_path / "nope.ply")
    (tmp_path / "empty.ply").write_bytes(b"")
    with pytest.raises(MeshError, match=r"empty\.ply' is empty \(0 bytes\)"):
        load_mesh(tmp_path / "empty.ply")
    (tmp_path / "garbage.ply").write_bytes(b"\x00\x01 not a ply file" * 10)
    with pytest.raises(MeshError, match=r"garbage\.ply' could not be read as PLY"):
        load_mesh(tmp_path / "garbage.ply")
    (tmp_path / "mesh.xyz").write_text("1 2 3\n")
    with pytest.raises(MeshError, match="supported formats are"):
        load_mesh(tmp_path / "mesh.xyz")
    with pytest.raises(MeshError, match="is not a file"):
        load_mesh(tmp_path)


def test_unreadable_permission(tmp_path, monkeypatch):
    import render.meshio as meshio

    path = write_ply(tmp_path / "locked.ply", TETRA_V, TETRA_T)
    monkeypatch.setattr(meshio.os, "access", lambda p, mode: False)     # as for a file without read permission
    with pytest.raises(MeshError, match=r"locked\.ply' is not readable"):
        load_mesh(path)


def test_point_cloud_and_header_only_files(tmp_path):
    cloud = tmp_path / "cloud.ply"
    cloud.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                     "property float z\nend_header\n0 0 0\n1 0 0\n0 1 0\n")
    with pytest.raises(MeshError, match="no triangles.*point cloud"):
        load_mesh(cloud)
    header = write_ply(tmp_path / "zero.ply", np.zeros((0, 3)), np.zeros((0, 3), int))
    with pytest.raises(MeshError, match="zero.ply"):
        load_mesh(header)


def test_nan_vertices_are_reported_with_the_vertex(tmp_path):
    v = TETRA_V.copy()
    v[2, 1] = np.nan
    with pytest.raises(MeshError, match=r"nan\.ply: 1 vertices have NaN.*vertex 2"):
        load_mesh(write_ply(tmp_path / "nan.ply", v, TETRA_T))
    v[2, 1] = np.inf
    with pytest.raises(MeshError, match="infinite"):
        make_mesh(v, TETRA_T)


def test_out_of_range_indices(tmp_path):
    t = TETRA_T.copy()
    t[3, 2] = 9
    with pytest.raises(MeshError, match=r"triangle 3 uses vertex index \[1, 2, 9\] outside 0\.\.3"):
        load_mesh(write_ply(tmp_path / "oor.ply", TETRA_V, t))
    t[3, 2] = -1
    with pytest.raises(MeshError, match="outside"):
        make_mesh(TETRA_V, t)


def test_degenerate_triangles_are_dropped_and_counted():
    v = np.vstack([TETRA_V, [[2.0, 2.0, 2.0], [3.0, 3.0, 3.0]]])
    t = np.vstack([TETRA_T, [[0, 0, 1], [0, 4, 5], [1, 1, 1]]])      # repeated index, collinear, all same
    mat = np.array([0, 1, 0, 1, 1, 1, 1])
    with pytest.warns(MeshWarning, match="dropped 3 zero-area triangles of 7"):
        mesh = make_mesh(v, t, material_index=mat, material_index_on="triangle")
    assert mesh.dropped_triangles == 3 and mesh.n_triangles == 4
    np.testing.assert_array_equal(mesh.material_index, [0, 1, 0, 1])
    with pytest.raises(MeshError, match="all 2 triangles have zero area"):
        make_mesh(v, [[0, 0, 1], [0, 4, 5]])


def test_degenerate_triangles_in_a_file(tmp_path):
    t = np.vstack([TETRA_T, [[2, 2, 3]]])
    with pytest.warns(MeshWarning, match="dropped 1"):
        mesh = load_mesh(write_ply(tmp_path / "deg.ply", TETRA_V, t))
    assert mesh.n_triangles == 4


def test_shape_and_material_index_errors():
    with pytest.raises(MeshError, match=r"vertices must have shape \(V, 3\)"):
        make_mesh(np.zeros((4, 2)), TETRA_T)
    with pytest.raises(MeshError, match=r"triangles must have shape \(T, 3\)"):
        make_mesh(TETRA_V, [[0, 1, 2, 3]])
    with pytest.raises(MeshError, match="whole numbers"):
        make_mesh(TETRA_V, TETRA_T + 0.5)
    with pytest.raises(MeshError, match="say material_index_on"):
        make_mesh(TETRA_V, TETRA_T, material_index=[0, 1, 0, 1])         # V == T == 4
    with pytest.raises(MeshError, match="expected one per vertex"):
        make_mesh(TETRA_V, TETRA_T, material_index=[0, 1, 0])
    with pytest.raises(MeshError, match=">= 0"):
        make_mesh(TETRA_V, TETRA_T, material_index=[0, -1, 0, 1], material_index_on="vertex")
    with pytest.raises(MeshError, match=r"vertex_normals must have shape"):
        make_mesh(TETRA_V, TETRA_T, vertex_normals=np.ones((3, 3)))


def test_bad_file_normals_are_recomputed_with_a_warning():
    normals = np.tile([0.0, 0.0, 1.0], (4, 1))
    normals[1] = 0.0
    with pytest.warns(MeshWarning, match="recomputing"):
        mesh = make_mesh(TETRA_V, TETRA_T, vertex_normals=normals)
    assert mesh.normals_computed
    np.testing.assert_allclose(mesh.vertex_normals, smooth_vertex_normals(TETRA_V, TETRA_T))


# --------------------------------------------------------------------------- normals
def test_area_weighted_normal_of_a_corner_weights_faces_by_area():
    """Two faces at a shared vertex: areas 2 (normal +z) and 0.5 (normal +x)."""
    v = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0], [0, 0, 1], [0, 1, 0]], float)
    t = np.array([[0, 1, 2], [0, 4, 3]])
    n = smooth_vertex_normals(v, t)
    expected = np.array([0.5, 0.0, 2.0]) / np.hypot(0.5, 2.0)
    np.testing.assert_allclose(n[0], expected)
    np.testing.assert_allclose(face_normals(v, t, unit=False), [[0, 0, 4], [1, 0, 0]])


def test_vertex_of_two_opposite_faces_and_unused_vertices_get_a_unit_normal():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5]], float)
    n = smooth_vertex_normals(v, [[0, 1, 2], [0, 2, 1]])
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0)
    assert abs(n[0, 2]) == pytest.approx(1.0)
    np.testing.assert_allclose(n[3], [0, 0, 1])


@hsettings(max_examples=25, deadline=None)
@given(subdivisions=st.integers(1, 3), radius=st.floats(1e-3, 1e3), centre=st.tuples(*[st.floats(-1e3, 1e3)] * 3))
def test_sphere_vertex_normals_are_radial(subdivisions, radius, centre):
    import open3d as o3d

    m = o3d.geometry.TriangleMesh.create_icosahedron(1.0).subdivide_midpoint(subdivisions)
    unit = np.asarray(m.vertices) / np.linalg.norm(np.asarray(m.vertices), axis=1, keepdims=True)
    mesh = make_mesh(unit * radius + np.asarray(centre), np.asarray(m.triangles))
    assert mesh.normals_computed
    cos = np.sum(mesh.vertex_normals * unit, axis=1)
    assert cos.min() > np.cos(np.radians(1.1))          # area weighting: within ~1 degree of radial
    lo, hi = mesh.bounds()
    np.testing.assert_allclose(hi - lo, 2 * radius, rtol=1e-9)


def test_bounds_ignore_unused_vertices():
    v = np.vstack([TETRA_V, [[100.0, 100.0, 100.0]]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mesh = make_mesh(v, TETRA_T)
    lo, hi = mesh.bounds()
    np.testing.assert_array_equal(lo, [0, 0, 0])
    np.testing.assert_array_equal(hi, [1, 1, 1])
