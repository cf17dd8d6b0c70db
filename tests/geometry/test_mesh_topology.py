"""Mesh topology checks against Open3D's predicates and a per-edge count written here."""

from __future__ import annotations

from collections import Counter

import numpy as np
import open3d as o3d
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from processing.geometry.mesh_topology import boundary_edges, mesh_topology, triangle_components

ICO = o3d.geometry.TriangleMesh.create_icosahedron(1.0).subdivide_midpoint(1)
ICO_T = np.asarray(ICO.triangles, dtype=np.int64)
ICO_V = np.asarray(ICO.vertices)


def o3d_mesh(t, v=ICO_V):
    return o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(np.asarray(t, np.int32)))


def reference_counts(t):
    """Boundary / non-manifold / misoriented edge counts by a plain loop."""
    undirected = Counter()
    directed = Counter()
    for tri in np.asarray(t).tolist():
        for k in range(3):
            a, b = tri[k], tri[(k + 1) % 3]
            undirected[(min(a, b), max(a, b))] += 1
            directed[(a, b)] += 1
    boundary = sum(1 for c in undirected.values() if c == 1)
    nonmanifold = sum(1 for c in undirected.values() if c > 2)
    mis = sum(1 for (a, b), c in undirected.items() if c == 2 and (directed[(a, b)] == 2 or directed[(b, a)] == 2))
    return boundary, nonmanifold, mis


def test_closed_icosphere_is_watertight():
    top = mesh_topology(ICO_T)
    assert top.watertight and top.closed and top.edge_manifold
    assert top.euler_characteristic == 2
    assert top.n_edges == 3 * ICO_T.shape[0] // 2
    assert top.n_components == 1


def test_two_cones_touching_at_a_vertex_are_not_vertex_manifold():
    # two tetrahedra sharing vertex 0 only
    tet = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    twin = np.where(tet == 0, 0, tet + 3)
    top = mesh_topology(np.vstack([tet, twin]))
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [-1, 0, 0], [0, -1, 0], [0, 0, -1]], float)
    assert top.closed and top.n_misoriented_edges == 0
    assert top.n_nonmanifold_vertices == 1 and not top.watertight
    assert not o3d_mesh(np.vstack([tet, twin]), v).is_vertex_manifold()


def test_an_edge_of_three_triangles_is_non_manifold():
    t = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    top = mesh_topology(t)
    assert top.n_nonmanifold_edges == 1 and not top.edge_manifold and not top.watertight


def test_boundary_edges_run_with_their_triangle():
    t = ICO_T[1:]  # one triangle removed
    b = boundary_edges(t)
    removed = ICO_T[0]
    expected = {(int(removed[(k + 1) % 3]), int(removed[k])) for k in range(3)}  # reversed in the neighbours
    assert {tuple(e) for e in b.tolist()} == expected


def test_components_are_separated():
    shifted = ICO_T + ICO_V.shape[0]
    n, labels = triangle_components(np.vstack([ICO_T, shifted]))
    assert n == 2
    assert set(labels[: ICO_T.shape[0]]) == {0} and set(labels[ICO_T.shape[0]:]) == {1}
    n, labels = triangle_components(ICO_T, mask=np.arange(ICO_T.shape[0]) < 3)
    assert (labels[3:] == -1).all() and n >= 1


def test_bad_triangles_are_rejected():
    with pytest.raises(ValueError, match=r"shape \(T, 3\)"):
        mesh_topology(np.zeros((4, 2), int))
    with pytest.raises(ValueError, match="integer"):
        mesh_topology(np.zeros((4, 3)))
    with pytest.raises(ValueError, match="negative"):
        mesh_topology([[0, 1, -1]])
    assert mesh_topology(np.zeros((0, 3), int)).n_triangles == 0
    assert not mesh_topology(np.zeros((0, 3), int)).watertight


def test_a_flipped_triangle_is_misoriented_but_still_vertex_manifold():
    t = ICO_T.copy()
    t[69] = t[69][::-1]
    t = np.delete(t, [25, 72], axis=0)
    top = mesh_topology(t)
    assert top.n_misoriented_edges > 0 and top.n_nonmanifold_vertices == 0
    assert o3d_mesh(t).is_vertex_manifold()


@settings(max_examples=40, deadline=None)
@given(
    drop=st.lists(st.integers(0, ICO_T.shape[0] - 1), max_size=6),
    flip=st.lists(st.integers(0, ICO_T.shape[0] - 1), max_size=4),
)
def test_counts_agree_with_a_per_edge_loop_and_open3d(drop, flip):
    t = ICO_T.copy()
    t[flip] = t[flip][:, ::-1]
    t = np.delete(t, sorted(set(drop)), axis=0)
    top = mesh_topology(t)
    boundary, nonmanifold, mis = reference_counts(t)
    assert (top.n_boundary_edges, top.n_nonmanifold_edges, top.n_misoriented_edges) == (boundary, nonmanifold, mis)
    mesh = o3d_mesh(t)
    assert top.edge_manifold == mesh.is_edge_manifold(allow_boundary_edges=True)
    assert top.closed == mesh.is_edge_manifold(allow_boundary_edges=False)
    assert (top.n_nonmanifold_vertices == 0) == mesh.is_vertex_manifold()
    assert top.watertight == (not drop and not flip)
