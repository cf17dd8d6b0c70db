"""A GeometryCache reuses the ray tracer of the same meshes and never serves another mesh's.

The reference for every cached render is the same render built afresh: they must agree exactly (same
seeds, same rays, the same triangles in the tracer), and a different mesh must give its own image.
"""

from __future__ import annotations

import numpy as np
import pytest

from render.camera import Camera
from render.errors import RenderInputError
from render.meshio import make_mesh
from render.presets import PRESETS
from render.renderer import GeometryCache, render
from render.scene import Light, Scene, SceneObject, Sky

CAMERA = Camera((0.0, -5.0, 2.0), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 30.0, 48, 40)


def _sphere(radius: float = 1.0, n: int = 24):
    """A UV sphere (its own vertex normals) and a ground square, as two meshes."""
    theta, phi = np.meshgrid(np.linspace(0.0, np.pi, n), np.linspace(0.0, 2 * np.pi, 2 * n, endpoint=False),
                             indexing="ij")
    unit = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1).reshape(-1, 3)
    tris = []
    for i in range(n - 1):
        for j in range(2 * n):
            a, b = i * 2 * n + j, i * 2 * n + (j + 1) % (2 * n)
            c, d = a + 2 * n, b + 2 * n
            tris += [[a, c, b], [b, c, d]]
    t = np.array(tris)
    area = np.linalg.norm(np.cross(unit[t[:, 1]] - unit[t[:, 0]], unit[t[:, 2]] - unit[t[:, 0]]), axis=1)
    return make_mesh(radius * unit, t[area > 1e-12], unit)


GROUND = make_mesh([[-3, -3, -1], [3, -3, -1], [3, 3, -1], [-3, 3, -1]], [[0, 1, 2], [0, 2, 3]])


def _scene(mesh, material: str = "gold", light=(0.3, -0.5, 1.0)) -> Scene:
    return Scene([SceneObject(mesh, [material]), SceneObject(GROUND, ["urushi-red"])],
                 [Light("directional", light)], Sky("none"))


def test_a_cached_render_equals_the_render_built_afresh():
    mesh, cache = _sphere(), GeometryCache()
    fresh = render(_scene(mesh), CAMERA, PRESETS["draft"])
    first = render(_scene(mesh), CAMERA, PRESETS["draft"], geometry_cache=cache)
    again = render(_scene(mesh), CAMERA, PRESETS["draft"], geometry_cache=cache)
    assert not first.stats["geometry_reused"] and again.stats["geometry_reused"]
    assert again.timings["bvh_build"] == 0.0
    np.testing.assert_array_equal(again.xyz, fresh.xyz)       # shadows of the sphere on the ground included
    np.testing.assert_array_equal(again.mask, fresh.mask)


def test_materials_light_and_view_may_change_the_geometry_stays():
    mesh, cache = _sphere(), GeometryCache()
    render(_scene(mesh), CAMERA, PRESETS["draft"], geometry_cache=cache)
    other_view = Camera((4.0, 1.0, 1.0), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 35.0, 40, 32)
    changed = _scene(mesh, material="copper", light=(-0.6, 0.2, 0.8))
    cached = render(changed, other_view, PRESETS["draft"], geometry_cache=cache)
    fresh = render(changed, other_view, PRESETS["draft"])
    assert cached.stats["geometry_reused"]
    np.testing.assert_array_equal(cached.xyz, fresh.xyz)


def test_another_mesh_is_never_served_the_cached_tracer():
    cache = GeometryCache()
    render(_scene(_sphere(1.0)), CAMERA, PRESETS["draft"], geometry_cache=cache)
    small = _sphere(0.5)                      # a different mesh object: a new tracer
    cached = render(_scene(small), CAMERA, PRESETS["draft"], geometry_cache=cache)
    fresh = render(_scene(small), CAMERA, PRESETS["draft"])
    assert not cached.stats["geometry_reused"]
    np.testing.assert_array_equal(cached.xyz, fresh.xyz)
    # the smaller sphere covers fewer pixels than the first one did: the image really is of the new mesh
    big = render(_scene(_sphere(1.0)), CAMERA, PRESETS["draft"])
    assert cached.mask.sum() < big.mask.sum()
    # equal content in a new Mesh object is a new geometry too (identity is the key)
    again = render(_scene(_sphere(0.5)), CAMERA, PRESETS["draft"], geometry_cache=cache)
    assert not again.stats["geometry_reused"]


def test_a_cleared_cache_builds_again_and_bad_caches_are_refused():
    mesh, cache = _sphere(), GeometryCache()
    render(_scene(mesh), CAMERA, PRESETS["draft"], geometry_cache=cache)
    cache.clear()
    assert not render(_scene(mesh), CAMERA, PRESETS["draft"], geometry_cache=cache).stats["geometry_reused"]
    with pytest.raises(RenderInputError, match="geometry_cache must be a render.renderer.GeometryCache"):
        render(_scene(mesh), CAMERA, PRESETS["draft"], geometry_cache={})
