"""Tests of the procedural hawk's head (mocks/procedural_hawk.py).

Topology is checked with NumPy edge counts and, independently, with Open3D's
manifold / watertight / self-intersection tests and its ray casting; geometry
against the requirements (size, placement, regions, hooked beak).
"""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mocks.procedural_hawk import (
    DEFAULT_MATERIALS,
    HAWK_PRESET_TRIANGLES,
    REGION_NAMES,
    HawkMesh,
    hawk_head,
)


@pytest.fixture(scope="module")
def draft() -> HawkMesh:
    return hawk_head(HAWK_PRESET_TRIANGLES["draft"])


@pytest.fixture(scope="module")
def small() -> HawkMesh:
    return hawk_head(12_000)


# ---------------------------------------------------------------------------
# helpers, written independently of the module under test
# ---------------------------------------------------------------------------
def directed_edges(tris: np.ndarray) -> np.ndarray:
    return np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]).astype(np.int64)


def face_normals(mesh: HawkMesh) -> np.ndarray:
    v = mesh.vertices
    t = mesh.triangles
    return np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])


def triangle_areas(mesh: HawkMesh) -> np.ndarray:
    return 0.5 * np.linalg.norm(face_normals(mesh), axis=1)


def min_angles_deg(mesh: HawkMesh) -> np.ndarray:
    p = mesh.vertices[mesh.triangles]
    angles = []
    for k in range(3):
        u = p[:, (k + 1) % 3] - p[:, k]
        w = p[:, (k + 2) % 3] - p[:, k]
        c = np.einsum("ij,ij->i", u, w) / (np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1))
        angles.append(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))
    return np.min(angles, axis=0)


def assert_closed_oriented_manifold(mesh: HawkMesh) -> None:
    tris = mesh.triangles
    nv = len(mesh.vertices)
    assert tris.min() >= 0 and tris.max() < nv
    # no triangle repeats a vertex
    assert np.all(tris[:, [0, 1, 2]] != tris[:, [1, 2, 0]])
    d = directed_edges(tris)
    keys = np.sort(d[:, 0] * nv + d[:, 1])
    # consistent orientation: each directed edge occurs once ...
    assert np.all(np.diff(keys) > 0)
    # ... and so does its reverse: every edge is shared by exactly two
    # triangles that traverse it in opposite directions (closed, edge-manifold)
    reverse = d[:, 1] * nv + d[:, 0]
    pos = np.minimum(np.searchsorted(keys, reverse), len(keys) - 1)
    assert np.array_equal(keys[pos], reverse)
    n_edges = len(d) // 2
    # every vertex used; a closed genus-0 surface has V - E + F = 2
    assert np.all(np.bincount(tris.ravel(), minlength=nv) > 0)
    assert nv - n_edges + len(tris) == 2


# ---------------------------------------------------------------------------
# topology
# ---------------------------------------------------------------------------
def test_draft_is_closed_consistently_oriented_two_manifold(draft):
    assert_closed_oriented_manifold(draft)


def test_no_two_vertices_coincide(draft):
    # a watertight index structure is only watertight in space if no two
    # distinct vertices sit at the same place
    rounded = np.round(draft.vertices, 6)
    assert np.unique(rounded, axis=0).shape[0] == len(draft.vertices)


def test_open3d_agrees_watertight_and_not_self_intersecting(small):
    mesh = small.to_open3d()
    assert mesh.is_edge_manifold(allow_boundary_edges=False)
    assert mesh.is_vertex_manifold()
    assert mesh.is_orientable()
    # Open3D's is_watertight includes its triangle-triangle intersection test
    assert mesh.is_watertight()


def test_signed_volume_is_positive_and_matches_ray_casting(draft):
    v = draft.vertices[draft.triangles]
    volume = np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0
    assert volume > 0.0  # outward normals
    # independent estimate: count grid points inside (Open3D ray-parity occupancy)
    lo, hi = draft.vertices.min(axis=0), draft.vertices.max(axis=0)
    step = 0.5
    axes = [np.arange(a + step / 2, b, step) for a, b in zip(lo, hi)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(draft.vertices.astype(np.float32), draft.triangles.astype(np.uint32))
    inside = scene.compute_occupancy(o3d.core.Tensor(grid.astype(np.float32))).numpy()
    assert volume == pytest.approx(inside.sum() * step**3, rel=0.01)
    # a head of this size: between a 30 mm and a 60 mm cube
    assert 30.0**3 < volume < 60.0**3


def test_face_normals_point_out_of_the_solid(small):
    """Just outside every triangle is outside the solid, just inside is inside."""
    fn = face_normals(small)
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    centroids = small.vertices[small.triangles].mean(axis=1)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(small.vertices.astype(np.float32), small.triangles.astype(np.uint32))
    eps = 0.02  # mm; well below the thinnest feature (beak tip radius about 0.5 mm)
    outside = scene.compute_occupancy(o3d.core.Tensor((centroids + eps * fn).astype(np.float32)))
    inside = scene.compute_occupancy(o3d.core.Tensor((centroids - eps * fn).astype(np.float32)))
    assert np.all(outside.numpy() == 0.0)
    assert np.all(inside.numpy() == 1.0)


def test_no_degenerate_or_sliver_triangles(draft):
    area = triangle_areas(draft)
    assert area.min() > 0.02 * area.mean()
    assert min_angles_deg(draft).min() > 2.0
    # areas are evenly spread over the surface
    lo, hi = np.percentile(area / area.mean(), [5, 95])
    assert lo > 0.3 and hi < 2.5


# ---------------------------------------------------------------------------
# triangle counts and presets
# ---------------------------------------------------------------------------
def test_presets():
    assert HAWK_PRESET_TRIANGLES == {"draft": 60_000, "standard": 250_000, "reference": 1_000_000}


@pytest.mark.parametrize("request_count", [2_000, 5_000, 12_345, HAWK_PRESET_TRIANGLES["draft"]])
def test_triangle_count_within_ten_percent(request_count):
    mesh = hawk_head(request_count)
    assert abs(mesh.n_triangles - request_count) <= 0.10 * request_count


def test_reference_preset_once():
    """The 1M-triangle preset: count, closedness, placement."""
    mesh = hawk_head(HAWK_PRESET_TRIANGLES["reference"])
    assert abs(mesh.n_triangles - 1_000_000) <= 0.01 * 1_000_000
    assert_closed_oriented_manifold(mesh)
    assert mesh.vertices[:, 2].min() == 0.0
    assert np.allclose(np.linalg.norm(mesh.vertex_normals, axis=1), 1.0, atol=1e-12)
    assert triangle_areas(mesh).min() > 0.0


@settings(max_examples=6, deadline=None)
@given(st.integers(min_value=2_000, max_value=20_000), st.integers(min_value=0, max_value=2**31))
def test_any_size_and_seed_gives_a_closed_mesh_on_the_table(count, seed):
    mesh = hawk_head(count, seed=seed)
    assert abs(mesh.n_triangles - count) <= 0.10 * count
    assert_closed_oriented_manifold(mesh)
    assert mesh.vertices[:, 2].min() == 0.0
    assert np.isfinite(mesh.vertices).all()
    assert triangle_areas(mesh).min() > 0.0


# ---------------------------------------------------------------------------
# size and placement
# ---------------------------------------------------------------------------
def test_size_and_placement(draft):
    v = draft.vertices
    lo, hi = v.min(axis=0), v.max(axis=0)
    length, width, height = hi - lo
    assert 60.0 <= length <= 80.0  # beak tip to back of the neck
    assert 30.0 <= width <= 50.0
    assert 60.0 <= height <= 85.0
    assert lo[2] == 0.0  # sits on the table
    # centred on the turntable axis
    assert abs(lo[0] + hi[0]) < 1e-9 and abs(lo[1] + hi[1]) < 1e-9


def test_neck_cut_is_a_flat_disc_facing_down(draft):
    v = draft.vertices
    t = draft.triangles
    flat = np.all(v[t][:, :, 2] < 1e-6, axis=1)
    area = triangle_areas(draft)[flat].sum()
    assert area > np.pi * 12.0**2  # a neck of more than 24 mm across
    fn = face_normals(draft)[flat]
    assert np.all(fn[:, 2] < 0.0)
    # the cut lies under the neck, near the turntable axis
    centre = v[np.unique(t[flat])].mean(axis=0)
    assert np.hypot(centre[0], centre[1]) < 15.0


# ---------------------------------------------------------------------------
# regions
# ---------------------------------------------------------------------------
def test_region_names_and_materials(draft):
    assert draft.region_names == REGION_NAMES
    assert {"head", "beak", "cere", "eye"} <= set(REGION_NAMES)
    assert set(DEFAULT_MATERIALS) == set(REGION_NAMES)
    assert DEFAULT_MATERIALS["head"] == "nami-shibuichi"
    assert DEFAULT_MATERIALS["beak"] == "gold"
    assert DEFAULT_MATERIALS["eye"] == "copper"
    assert "urushi" in DEFAULT_MATERIALS["cere"]
    assert draft.region.shape == (draft.n_triangles,)
    assert draft.region.max() < len(REGION_NAMES)
    for name in REGION_NAMES:
        assert draft.region_mask(name).any(), name


def test_head_is_most_of_the_surface(draft):
    area = triangle_areas(draft)
    assert area[draft.region_mask("head")].sum() > 0.8 * area.sum()


def test_beak_tip_is_the_most_forward_point_and_is_beak(draft):
    front = np.argmax(draft.vertices[:, 0])
    touching = np.any(draft.triangles == front, axis=1)
    assert np.all(draft.region[touching] == REGION_NAMES.index("beak"))


def region_centroid(mesh: HawkMesh, names: tuple[str, ...], side: float) -> np.ndarray:
    mask = np.isin(mesh.region, [REGION_NAMES.index(n) for n in names])
    c = mesh.vertices[mesh.triangles[mask]].mean(axis=1)
    a = triangle_areas(mesh)[mask]
    keep = np.sign(c[:, 1]) == side
    return (c[keep] * a[keep, None]).sum(axis=0) / a[keep].sum()


def test_eyes_on_both_sides_mirror_symmetric(draft):
    area = triangle_areas(draft)
    for names in (("eye", "pupil"), ("pupil",)):
        mask = np.isin(draft.region, [REGION_NAMES.index(n) for n in names])
        y = draft.vertices[draft.triangles[mask]].mean(axis=1)[:, 1]
        left, right = area[mask][y < 0].sum(), area[mask][y > 0].sum()
        assert left > 0 and right > 0
        assert left == pytest.approx(right, rel=0.1)
        c_left = region_centroid(draft, names, -1.0)
        c_right = region_centroid(draft, names, 1.0)
        assert np.allclose(c_left * [1, -1, 1], c_right, atol=0.5)
    eye = region_centroid(draft, ("eye", "pupil"), 1.0)
    pupil = region_centroid(draft, ("pupil",), 1.0)
    beak = draft.vertices[draft.triangles[draft.region_mask("beak")]].reshape(-1, 3)
    # the pupil sits in the eye, which sits behind the beak, on the side of the head
    assert np.linalg.norm(pupil - eye) < 2.0
    assert eye[0] < beak[:, 0].mean()
    assert eye[1] > 8.0
    assert beak[:, 2].min() < eye[2] < draft.vertices[:, 2].max()


def test_eyes_sit_under_a_brow_ridge(draft):
    """Above each eye, the head bulges further out sideways than the eye's top."""
    v = draft.vertices
    eye_mask = np.isin(draft.region, [REGION_NAMES.index("eye"), REGION_NAMES.index("pupil")])
    eye_v = v[np.unique(draft.triangles[eye_mask])]
    right = eye_v[eye_v[:, 1] > 0]
    top = right[np.argmax(right[:, 2])]
    x0, x1 = right[:, 0].min(), right[:, 0].max()
    above = v[(v[:, 1] > 0) & (v[:, 0] > x0) & (v[:, 0] < x1)
              & (v[:, 2] > top[2]) & (v[:, 2] < top[2] + 8.0)]
    assert above[:, 1].max() > top[1] + 0.5


def test_cere_lies_between_face_and_beak(draft):
    beak_i = REGION_NAMES.index("beak")
    cere_i = REGION_NAMES.index("cere")
    head_i = REGION_NAMES.index("head")
    d = directed_edges(draft.triangles)
    tri_of_edge = np.tile(np.arange(draft.n_triangles), 3)
    nv = len(draft.vertices)
    key = d[:, 0] * nv + d[:, 1]
    order = np.argsort(key)
    twin = order[np.searchsorted(key[order], d[:, 1] * nv + d[:, 0])]
    across = np.stack([draft.region[tri_of_edge], draft.region[tri_of_edge[twin]]], axis=1)
    pairs = {(int(a), int(b)) for a, b in np.unique(across, axis=0)}
    assert (cere_i, beak_i) in pairs and (cere_i, head_i) in pairs
    cere = region_centroid(draft, ("cere",), 1.0)
    assert cere[0] < draft.vertices[:, 0].max() - 8.0


def test_beak_is_hooked_with_the_upper_mandible_overhanging(draft):
    v = draft.vertices
    beak = np.unique(draft.triangles[draft.region_mask("beak")])
    front = beak[np.argmax(v[beak, 0])]
    near_front = beak[v[beak, 0] > v[front, 0] - 8.0]
    tip = near_front[np.argmin(v[near_front, 2])]
    # the beak curves down steeply and its tip curls back under the culmen
    assert v[front, 2] - v[tip, 2] > 4.0
    assert v[front, 0] - v[tip, 0] > 1.0
    # a ray cast backwards just above the hook tip goes through the hook, then
    # through air, then into the lower mandible / face: the hook overhangs
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(v.astype(np.float32), draft.triangles.astype(np.uint32))
    ray = np.array([[v[front, 0] + 5.0, v[tip, 1], v[tip, 2] + 1.0, -1.0, 0.0, 0.0]], np.float32)
    hits = scene.list_intersections(o3d.core.Tensor(ray))
    t_hit = hits["t_hit"].numpy()
    regions = draft.region[hits["primitive_ids"].numpy()]
    assert len(t_hit) >= 4
    assert regions[0] == regions[1] == REGION_NAMES.index("beak")
    assert t_hit[2] - t_hit[1] > 1.0  # a gap of air between the hook and what lies behind


# ---------------------------------------------------------------------------
# normals, relief, determinism
# ---------------------------------------------------------------------------
def test_vertex_normals_are_unit_and_agree_with_faces(draft):
    n = draft.vertex_normals
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    fn = face_normals(draft)
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    cos = np.einsum("tkj,tj->tk", n[draft.triangles], fn)
    assert cos.min() > 0.0
    assert np.median(cos) > np.cos(np.radians(10.0))
    # the same definition computed by Open3D (area-weighted face normals)
    ref = draft.to_open3d()
    ref.compute_vertex_normals(normalized=True)
    assert np.allclose(np.asarray(ref.vertex_normals), n, atol=1e-6)


def test_same_seed_same_mesh_and_seed_only_moves_feathers():
    a = hawk_head(8_000, seed=5)
    b = hawk_head(8_000, seed=5)
    c = hawk_head(8_000, seed=6)
    for field in ("vertices", "triangles", "vertex_normals", "region"):
        assert np.array_equal(getattr(a, field), getattr(b, field)), field
    assert np.array_equal(a.triangles, c.triangles)
    assert np.array_equal(a.region, c.region)
    moved = np.linalg.norm(a.vertices - c.vertices, axis=1)
    assert moved.max() > 0.01  # the feathers differ ...
    assert moved.max() < 0.6  # ... by a relief of a few tenths of a millimetre
    # no feathers on beak and eyes: there the meshes differ only by the common
    # shift that re-centres them on the turntable axis
    bare = np.isin(a.region, [REGION_NAMES.index(n) for n in ("beak", "eye", "pupil")])
    delta = (a.vertices - c.vertices)[np.unique(a.triangles[bare])]
    assert np.abs(delta - delta[0]).max() < 1e-9
    assert np.abs(delta[0]).max() < 0.05


def test_feather_relief_roughens_the_crown(draft):
    """Dihedral angles between neighbouring triangles.  The crown is much less
    curved than the eyeball (radius ~15 mm against ~7 mm), so a smooth crown
    would bend less from triangle to triangle than the eye; the feather steps
    make it bend far more."""
    d = directed_edges(draft.triangles)
    nv = len(draft.vertices)
    key = d[:, 0] * nv + d[:, 1]
    order = np.argsort(key)
    twin = order[np.searchsorted(key[order], d[:, 1] * nv + d[:, 0])]
    t = np.tile(np.arange(draft.n_triangles), 3)
    fn = face_normals(draft)
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    bend = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", fn[t], fn[t[twin]]), -1, 1)))
    z = draft.vertices[draft.triangles].mean(axis=1)[t, 2]
    crown = (draft.region[t] == 0) & (z > draft.vertices[:, 2].max() - 10.0)
    eye = draft.region[t] == REGION_NAMES.index("eye")
    assert np.percentile(bend[crown], 95) > 3.0 * np.percentile(bend[eye], 95)


def test_to_open3d(draft):
    mesh = draft.to_open3d()
    assert isinstance(mesh, o3d.geometry.TriangleMesh)
    assert np.array_equal(np.asarray(mesh.triangles), draft.triangles)
    assert np.array_equal(np.asarray(mesh.vertices), draft.vertices)
    assert np.array_equal(np.asarray(mesh.vertex_normals), draft.vertex_normals)


# ---------------------------------------------------------------------------
# bad input
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("bad", ["draft", 60_000.0, True, None])
def test_triangles_of_wrong_type(bad):
    with pytest.raises(TypeError, match="triangles"):
        hawk_head(bad)


@pytest.mark.parametrize("bad", [0, -5, 100, 1_999, 10**9])
def test_triangles_out_of_range(bad):
    with pytest.raises(ValueError, match="triangles"):
        hawk_head(bad)


def test_bad_seed():
    with pytest.raises(ValueError, match="seed"):
        hawk_head(5_000, seed=-1)
    with pytest.raises(TypeError, match="seed"):
        hawk_head(5_000, seed=1.5)


def test_unknown_region_name(draft):
    with pytest.raises(ValueError, match="unknown region 'wing'"):
        draft.region_mask("wing")
