"""The simulated world: chart radiance, object frames on the turntable, serialisation, errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mocks.world import BACKDROP_REFLECTANCE, World, WorldError, chart_reflectances
from processing.materials.lobes import material_brdf
from processing.materials.presets import get_material
from processing.spectral.display import spectra_to_xyz


@pytest.fixture(scope="module")
def hawk():
    return World.hawk(2_000, width=48, height=32, spectral_step=20.0)


def _plate(material="gold", **kwargs):
    """A 200 mm square facing the camera's side (-y), standing on the table."""
    v = np.array([[-100, 0, -100], [100, 0, -100], [100, 0, 100], [-100, 0, 100]], float)
    t = np.array([[0, 2, 1], [0, 3, 2]])
    return World(v, t, np.zeros(2, int), ("plate",), {"plate": material}, camera_elevation_deg=0.0,
                 mesh_source="", **kwargs)


def test_white_diffuser_has_luminance_one(hawk):
    e = hawk.light_spectrum()
    assert spectra_to_xyz(e / math.pi, hawk.grid)[1] == pytest.approx(1.0, rel=1e-9)


def test_chart_frame_radiance_is_reflectance_times_light(hawk):
    f = hawk.frame("chart")
    refl = chart_reflectances(hawk.grid)
    e = hawk.light_spectrum()
    assert sorted(np.unique(f.labels).tolist()) == list(range(-1, 24))
    for patch in (0, 18, 23):
        pix = f.radiance[f.labels == patch]
        assert np.allclose(pix, refl[patch] * e / math.pi)
    assert np.allclose(f.radiance[f.labels == -1], BACKDROP_REFLECTANCE * e / math.pi)


def test_missing_chart_fault():
    w = World.hawk(2_000, width=48, height=32, spectral_step=20.0, chart_present=False)
    f = w.frame("chart")
    assert np.all(f.labels == -1)


def test_object_frame_turns_with_the_table(hawk):
    a, b, c = (hawk.frame("object", angle) for angle in (0.0, 90.0, 360.0))
    assert {"head", "beak"} <= {hawk.region_names[i] for i in np.unique(a.labels[a.labels >= 0])}
    assert np.allclose(a.radiance, c.radiance, atol=1e-9)
    assert not np.array_equal(a.labels, b.labels)
    assert np.all(np.isfinite(a.radiance)) and np.all(a.radiance >= 0)


def test_plate_radiance_is_the_brdf_in_closed_form():
    light = (0.0, -0.6, 0.8)
    w = _plate("urushi-black", light_direction=light, width=24, height=24, fov_deg=10.0)
    f = w.frame("object")
    assert np.all(f.labels == 0)                        # the plate fills the view
    e = w.light_spectrum()
    n = np.array([0.0, -1.0, 0.0])
    l = np.array(light) / np.linalg.norm(light)
    # the centre pixel's ray: from the camera at (0, -260, 0) toward the plate's centre, within half a pixel
    v = np.array([0.0, -1.0, 0.0])
    h = (l + v) / np.linalg.norm(l + v)
    expected = material_brdf(get_material("urushi-black"), l @ n, v @ n, h @ n, h @ l, w.grid.wavelengths) * e * (l @ n)
    centre = 0.25 * (f.radiance[11, 11] + f.radiance[11, 12] + f.radiance[12, 11] + f.radiance[12, 12])
    assert np.allclose(centre, expected, rtol=0.05)


def test_light_behind_the_object_leaves_it_dark():
    w = _plate("gold", light_direction=(0.0, 1.0, 0.0), width=24, height=24, fov_deg=10.0)
    assert np.all(w.frame("object").radiance == 0)


def test_round_trip_through_dict(hawk):
    again = World.from_dict(hawk.to_dict())
    assert np.array_equal(again.vertices, hawk.vertices)
    pinhole = World.from_dict({**hawk.to_dict(), "lens_sigma_px": 0.0})
    assert pinhole.lens_sigma_px == 0.0 and World.from_dict(pinhole.to_dict()).lens_sigma_px == 0.0
    assert again.materials == hawk.materials and again.width == hawk.width


@pytest.mark.parametrize(
    "change, words",
    [
        ({"width": 21}, "width"),
        ({"height": 10}, "height"),
        ({"light_direction": (0, 0, 0)}, "light_direction"),
        ({"fov_deg": 180}, "fov_deg"),
        ({"spectral_step": 7}, "spectral_step"),
        ({"pose": np.zeros((4, 4))}, "pose"),
        ({"lens_sigma_px": -1.0}, "lens_sigma_px"),
        ({"lens_sigma_px": float("inf")}, "lens_sigma_px"),
    ],
)
def test_bad_settings(change, words):
    with pytest.raises(WorldError, match=words):
        _plate(**change)


def test_bad_frame_and_material_and_dict(hawk):
    with pytest.raises(WorldError, match="'chart' or 'object'"):
        hawk.frame("sky")
    with pytest.raises(WorldError, match="region"):
        World(hawk.vertices, hawk.triangles, hawk.region, hawk.region_names, {"head": "gold"})
    with pytest.raises(WorldError, match="unknown world setting"):
        World.from_dict({"mesh": "hawk:2000", "colour": "blue"})
    with pytest.raises(WorldError, match="no source"):
        _plate().to_dict()


def test_tabulated_brdf_matches_the_materials_brdf_for_every_isotropic_preset():
    # The world tabulates each lobe's spectral factor over cos_d (nodes 1e-4 apart); against the exact
    # per-point evaluation the linear interpolation error is h^2/8 |F''| ~ 1e-9 of the factor, so 1e-7
    # relative (plus 1e-12 1/sr absolute for the near-zero lobes) is a bound it cannot hide behind.
    from mocks.world import tabulated_brdf
    from processing.materials.lobes import material_brdf
    from processing.materials.presets import get_material, list_materials

    rng = np.random.default_rng(3)
    n = 2000
    ci, co = rng.uniform(0.05, 1.0, n), rng.uniform(0.05, 1.0, n)
    ch, cd = rng.uniform(0.5, 1.0, n), rng.uniform(0.2, 1.0, n)
    wl = np.arange(400.0, 701.0, 10.0)
    checked = 0
    for name in list_materials():
        mat = get_material(name)
        if any(lobe.kind == "anisotropic" for lobe in mat.lobes):
            continue                       # cloth: the world's object has no tangent frame
        exact = material_brdf(mat, ci, co, ch, cd, wl)
        np.testing.assert_allclose(tabulated_brdf(mat, ci, co, ch, cd, wl), exact, rtol=1e-7, atol=1e-12,
                                   err_msg=name)
        checked += 1
    assert checked >= 10


def test_object_frame_radiance_is_the_exact_brdf_to_1e_8():
    # The whole object frame against the same frame with material_brdf evaluated at every pixel.
    import mocks.world as world_module
    from processing.materials.lobes import material_brdf

    w = World.hawk(2_000, width=96, height=64)
    fast = w.frame("object", table_angle_deg=40.0).radiance
    try:
        world_module.tabulated_brdf, saved = (lambda m, ci, co, ch, cd, wl: material_brdf(m, ci, co, ch, cd, wl),
                                              world_module.tabulated_brdf)
        exact = w.frame("object", table_angle_deg=40.0).radiance
    finally:
        world_module.tabulated_brdf = saved
    assert np.abs(fast - exact).max() <= 1e-8 * exact.max()
