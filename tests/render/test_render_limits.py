"""The renderer's own classes refuse what float32 ray casting cannot resolve (render/limits.py)."""

from __future__ import annotations

import numpy as np
import pytest

from processing.lighting.environment_map import EnvironmentMap, EnvironmentMapError, srgb_basis
from render.camera import Camera
from render.environment import check_environment_light
from render.errors import MeshError, RenderInputError
from render.limits import MIN_FOV_DEG
from render.meshio import make_mesh
from render.scene import Light, Scene, SceneObject, Sky

_V = np.array([[10.0, 0, 0], [-10, 10, 0], [-10, -10, 0], [0, 0, 10]])
_T = np.array([[0, 1, 2], [0, 3, 1], [1, 3, 2], [2, 3, 0]])


def test_make_mesh_refuses_coordinates_beyond_the_range():
    with pytest.raises(MeshError, match=r"^part.ply: coordinates reach 1e\+16 mm; .* within \+-1e\+07 mm"):
        make_mesh(_V * 1e15, _T, source="part.ply")


@pytest.mark.parametrize("factor,offset,fragment", [
    (1e-12, 0.0, "spans only 2e-11 mm; the renderer takes meshes of at least 0.001 mm"),
    (1.0, 1e6, "lies 1e\\+06 mm from the origin"),
])
def test_scene_object_refuses_unresolvable_meshes(factor, offset, fragment):
    mesh = make_mesh(_V * factor + offset, _T, source="part.ply")
    with pytest.raises(MeshError, match=fragment) as info:
        SceneObject(mesh, ["gold"])
    assert str(info.value).startswith("part.ply: ")


def test_scene_object_keeps_normal_meshes():
    assert SceneObject(make_mesh(_V * 1e-2 + 5.0, _T), ["gold"]).name == "<arrays>"


def test_camera_fov_and_position_limits():
    Camera((0, -50, 0), (0, 0, 0), (0, 0, 1), MIN_FOV_DEG, 8, 6)
    with pytest.raises(RenderInputError, match="from 0.1"):
        Camera((0, -50, 0), (0, 0, 0), (0, 0, 1), 1e-6, 8, 6)
    with pytest.raises(RenderInputError, match="camera eye .* beyond"):
        Camera((0, 0, 1e300), (0, 0, 0), (0, 1, 0), 35, 8, 6)


def test_light_and_sky_limits():
    with pytest.raises(RenderInputError, match="point light position"):
        Light("point", (0, 0, 1e300))
    with pytest.raises(RenderInputError, match="at most 1e\\+12"):
        Light("directional", (0, 0, 1), intensity=1e300)
    with pytest.raises(RenderInputError, match="zenith radiance scale"):
        Sky("gradient", zenith=1e300)


def _map(coefficients, basis):
    return EnvironmentMap(np.asarray(coefficients, np.float32), basis, source="room.exr")


@pytest.mark.parametrize("env,fragment", [
    (lambda: _map(np.zeros((8, 16, 3)), srgb_basis()), "gives no light"),
    (lambda: _map(np.ones((8, 16, 3)), srgb_basis()).with_(intensity=1e-9), "gives no light"),
    (lambda: _map(np.ones((8, 16, 3)), -srgb_basis()), "radiance is negative"),
    (lambda: _map(np.full((8, 16, 3), 3e38), srgb_basis()), "above 1e\\+15"),
])
def test_environment_light_is_checked_when_the_scene_is_built(env, fragment):
    obj = SceneObject(make_mesh(_V, _T), ["gold"])
    with pytest.raises(EnvironmentMapError, match=fragment) as info:
        Scene([obj], [], Sky("none"), environment=env())
    assert str(info.value).startswith("room.exr: ")


def test_ordinary_environment_passes():
    check_environment_light(_map(np.full((8, 16, 3), 0.6), srgb_basis()))


def test_a_measured_maps_noise_below_zero_passes():
    """A basis fitted to measured spectra may dip below zero (here the blue one by 0.2 of the green), so a
    dark pixel's luminance can be slightly negative (-4e-4 of the lamp's): that is not negative light, and the
    map is kept (it was refused at -1e-6 of the brightest)."""
    basis = srgb_basis().copy()
    basis[2] = basis[2] - 0.2 * basis[1]
    c = np.zeros((8, 16, 3))
    c[..., 0] = 0.01
    c[0, 0] = 10.0                          # the lamp
    c[5, 3] = [0.0, 0.0, 0.05]              # a dark pixel seen through the blue basis only
    check_environment_light(_map(c, basis))
