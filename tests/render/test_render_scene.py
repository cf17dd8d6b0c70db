"""Scene description: lights, sky radiance, objects with materials, spectra, enclosed lights."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import settings as hsettings
from hypothesis import strategies as st
from scipy import integrate

from processing.materials.lobes import Lobe, Material
from processing.spectral.spectra import SpectralGrid, light_spectrum
from render.errors import RenderInputError
from render.meshio import make_mesh
from render.scene import (
    Light,
    Scene,
    SceneObject,
    Sky,
    check_point_lights,
    hemisphere_mean_clamped_cosine,
    resolve_spectrum,
)

GRID = SpectralGrid(400, 700, 10)


class Grey:
    angle_dependent = False

    def reflectance(self, cos_d, wavelengths):
        return np.full(np.shape(cos_d) + (len(wavelengths),), 0.5)


GREY = Material("grey", (Lobe("lambert", 1.0, Grey()),))


def cube(centre=(0.0, 0.0, 0.0), size=1.0):
    import open3d as o3d

    m = o3d.geometry.TriangleMesh.create_box(size, size, size)
    v = np.asarray(m.vertices) - size / 2 + np.asarray(centre)
    return make_mesh(v, np.asarray(m.triangles))


# --------------------------------------------------------------------------- lights
def test_directional_light_is_normalised_and_point_light_keeps_its_position():
    assert Light("directional", (0, 3, 4)).vector == (0.0, 0.6, 0.8)
    assert Light("point", (0, 3, 4)).vector == (0.0, 3.0, 4.0)


@pytest.mark.parametrize(
    "args, message",
    [
        (("spot", (0, 0, 1)), "'directional' or 'point'"),
        (("directional", (0, 0, 0)), "vector is zero"),
        (("point", (0, 0)), "three finite numbers"),
        (("point", (0, np.nan, 0)), "three finite numbers"),
        (("directional", (0, 0, 1), "D65", -1.0), "intensity must be finite and >= 0"),
        (("directional", (0, 0, 1), "D65", "bright"), "intensity must be a number"),
    ],
)
def test_bad_lights(args, message):
    with pytest.raises(RenderInputError, match=message):
        Light(*args)


# --------------------------------------------------------------------------- spectra
def test_resolve_spectrum_accepts_names_temperatures_arrays_and_csv(tmp_path):
    np.testing.assert_allclose(resolve_spectrum("D65", GRID), light_spectrum("D65", GRID))
    np.testing.assert_allclose(resolve_spectrum(3200, GRID), light_spectrum("3200K", GRID))
    ref61 = light_spectrum("A")                       # 61 values on the reference grid
    np.testing.assert_allclose(resolve_spectrum(ref61, GRID), light_spectrum("A", GRID), rtol=0.02)
    flat = resolve_spectrum([[380.0, 2.0], [720.0, 2.0]], GRID)
    np.testing.assert_allclose(flat, 1.0)              # normalised to 1 at 560 nm
    csv = tmp_path / "lamp.csv"
    csv.write_text("nm,value\n400,1\n700,3\n")
    e = resolve_spectrum(str(csv), GRID)
    assert e[16] == pytest.approx(1.0) and e[-1] > e[0]


@pytest.mark.parametrize(
    "spec, message",
    [
        ("not-a-lamp", "light 0 spectrum: unknown light"),
        ("/no/such/file.csv", "does not exist"),
        ([1.0, 2.0, 3.0], "array spectrum must be"),
        ([[400, -1.0], [700, 1.0]], "finite and >= 0"),
        ([[400, 0.0], [700, 0.0]], "no power"),
        ([[500, 1.0], [600, 1.0]], "covers 500-600 nm"),
    ],
)
def test_bad_spectra_name_the_parameter(spec, message):
    with pytest.raises(RenderInputError, match=message):
        resolve_spectrum(spec, GRID, "light 0 spectrum")


# --------------------------------------------------------------------------- sky
@hsettings(max_examples=5, deadline=None)
@given(gamma=st.sampled_from([0.0, math.pi / 2, math.pi]) | st.floats(0.0, math.pi))
def test_hemisphere_mean_of_a_clamped_cosine_matches_numerical_integration(gamma):
    """(1/pi) * integral over the hemisphere of n of max(0, d.up) (d.n), up at angle gamma from n."""
    up = np.array([math.sin(gamma), 0.0, math.cos(gamma)])

    def integrand(phi, theta):
        d = np.array([math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)])
        return max(0.0, float(d @ up)) * math.cos(theta) * math.sin(theta)

    value, _ = integrate.dblquad(integrand, 0.0, math.pi / 2, 0.0, 2 * math.pi, epsabs=1e-9, epsrel=1e-7)
    assert float(hemisphere_mean_clamped_cosine(math.cos(gamma))) == pytest.approx(value / math.pi, abs=2e-6)


def test_sky_radiance_scales():
    uni = Sky("uniform", zenith=0.4, horizon=9.0)
    grad = Sky("gradient", zenith=0.2, horizon=1.0, up=(0, 0, 2))
    dirs = np.array([[0, 0, 1], [1, 0, 0], [0, 0, -1], [0, 0.6, 0.8]])
    np.testing.assert_allclose(uni.radiance_scale(dirs), 0.4)
    np.testing.assert_allclose(grad.radiance_scale(dirs), [0.2, 1.0, 1.0, 1.0 - 0.8 * 0.8])
    np.testing.assert_allclose(uni.hemisphere_mean(dirs), 0.4)
    np.testing.assert_allclose(grad.hemisphere_mean(np.array([[0, 0, 1], [0, 0, -1]])), [1.0 - 0.8 * 2 / 3, 1.0])
    assert Sky("none").radiance_scale(dirs).tolist() == [0, 0, 0, 0]
    assert Sky("none").is_black and Sky("uniform", zenith=0).is_black and not grad.is_black


@pytest.mark.parametrize(
    "kw, message",
    [
        (dict(kind="hdr"), "'uniform', 'gradient' or 'none'"),
        (dict(kind="uniform", zenith=-1), "zenith radiance scale"),
        (dict(kind="gradient", horizon=float("inf")), "horizon radiance scale"),
        (dict(kind="gradient", up=(0, 0, 0)), "sky up vector is zero"),
    ],
)
def test_bad_skies(kw, message):
    with pytest.raises(RenderInputError, match=message):
        Sky(**kw)


# --------------------------------------------------------------------------- objects and scenes
def test_scene_object_material_index_resolution():
    mesh = cube()
    one = SceneObject(mesh, [GREY], name="box")
    assert one.material_index is None and one.materials == (GREY,)
    per_tri = SceneObject(mesh, [GREY, GREY], material_index=np.arange(12) % 2)
    assert per_tri.material_index_on == "triangle"
    per_vertex = SceneObject(mesh, [GREY, GREY], material_index=np.arange(8) % 2)
    assert per_vertex.material_index_on == "vertex"
    named = SceneObject(mesh, ["gold", "silver:roughness=0.3"], material_index=np.zeros(12, int))
    assert [m.name for m in named.materials] == ["gold", "silver"]


@pytest.mark.parametrize(
    "kw, message",
    [
        (dict(materials=[]), "no materials"),
        (dict(materials=[GREY, GREY]), "2 materials but no material_index"),
        (dict(materials=[GREY], material_index=np.zeros(5, int)), "expected one per triangle"),
        (dict(materials=[GREY], material_index=np.ones(12, int)), r"values must be in 0\.\.0"),
        (dict(materials=[GREY], material_index=np.zeros(12)), "integer array"),
        (dict(materials=["unobtainium"]), "unknown material"),
        (dict(materials=[42]), "must be a processing.materials.lobes.Material"),
        (dict(materials=[Material("void", ())]), "has no lobes"),
    ],
)
def test_bad_scene_objects(kw, message):
    with pytest.raises(RenderInputError, match=message):
        SceneObject(cube(), **kw)


def test_scene_needs_objects_and_a_light_and_reports_bounds():
    box = SceneObject(cube((1.0, 2.0, 3.0)), [GREY])
    with pytest.raises(RenderInputError, match="no objects"):
        Scene([], [Light("directional", (0, 0, 1))])
    with pytest.raises(RenderInputError, match="no lights"):
        Scene([box], [])
    with pytest.raises(RenderInputError, match="must be a Light"):
        Scene([box], ["sun"])
    scene = Scene([box, SceneObject(cube((-1.0, 0.0, 0.0), 2.0), [GREY])], [Light("directional", (0, 0, 1))])
    lo, hi = scene.bounds()
    np.testing.assert_allclose(lo, [-2.0, -1.0, -1.0])
    np.testing.assert_allclose(hi, [1.5, 2.5, 3.5])


def test_point_light_inside_a_closed_box_is_found_and_outside_is_not():
    box = SceneObject(cube(), [GREY], name="box")
    check_point_lights(Scene([box], [Light("point", (2.0, 0.0, 0.0))]))          # outside: fine
    check_point_lights(Scene([box], [Light("directional", (0.0, 0.0, 1.0))]))    # not a point light
    with pytest.raises(RenderInputError, match=r"point light 1 at \[0\.1, 0\.2, -0\.3\] is inside object 'box'"):
        check_point_lights(Scene([box], [Light("directional", (0, 0, 1)), Light("point", (0.1, 0.2, -0.3))]))


def test_point_light_between_two_boxes_is_not_inside():
    a = SceneObject(cube((-1.0, 0.0, 0.0)), [GREY], name="a")
    b = SceneObject(cube((1.0, 0.0, 0.0)), [GREY], name="b")
    check_point_lights(Scene([a, b], [Light("point", (0.0, 0.0, 0.0))]))
