"""The cloth model (Yasuda et al.): the ellipsoid as a distribution, its masking, the
internal layers, the dye, warp/weft symmetry and energy (albedo <= 1) at the extremes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate, optimize

from processing.cloth.anisotropic_albedo import anisotropic_lobe_albedo, material_albedo
from processing.cloth.anisotropic_microfacet import (
    anisotropic_lobe,
    ellipsoid_distance,
    ellipsoid_ndf,
    smith_lambda,
)
from processing.cloth.model import (
    Dye,
    InternalLayerReflectance,
    Yarn,
    cloth_material,
    kubelka_munk_ratio,
    kubelka_munk_reflectance,
    layer_normaliser,
)
from processing.materials.dielectric_model import PigmentReflectance
from processing.materials.fresnel import fresnel_dielectric
from processing.materials.lobes import Lobe, material_brdf
from processing.materials.presets import MaterialError, get_material

WHITE = PigmentReflectance([400, 700], [1.0, 1.0])
CLEAR = Dye(np.array([400.0, 700.0]), np.zeros(2))


def _sph(theta, phi):
    return np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)


def test_ellipsoid_distance_is_the_distance_to_the_ellipsoid():
    rng = np.random.default_rng(3)
    for _ in range(5):
        h = rng.normal(size=3)
        h[2] = abs(h[2])
        h /= np.linalg.norm(h)
        a_t, a_b = rng.uniform(0.05, 2.0, 2)
        # the point s h lies on x^2/a_t^2 + y^2/a_b^2 + z^2 = 1: solved by root finding
        s = optimize.brentq(lambda s, h=h, a_t=a_t, a_b=a_b: (s * h[0] / a_t) ** 2 + (s * h[1] / a_b) ** 2
                            + (s * h[2]) ** 2 - 1, 0, 1e3)
        assert float(ellipsoid_distance(*h, a_t, a_b)) == pytest.approx(s, rel=1e-9)
        assert float(ellipsoid_ndf(*h, a_t, a_b)) == pytest.approx(s ** 4 / (math.pi * a_t * a_b), rel=1e-9)


@pytest.mark.parametrize("a_t, a_b", [(0.2, 0.6), (0.5, 0.5), (1.0, 3.0), (0.05, 0.3)])
def test_distribution_is_normalised(a_t, a_b):
    # integral of D(h) cos(theta_h) over the hemisphere, in plain spherical coordinates
    def f(theta, phi):
        return float(ellipsoid_ndf(*_sph(theta, phi), a_t, a_b)) * math.cos(theta) * math.sin(theta)

    val, _ = integrate.dblquad(f, 0.0, 2 * math.pi, 0.0, math.pi / 2, epsabs=1e-7, epsrel=1e-7)
    assert val == pytest.approx(1.0, abs=2e-4)


def test_isotropic_axes_give_the_ggx_distribution():
    a = 0.3
    theta = np.linspace(0.0, 1.5, 20)
    d = ellipsoid_ndf(*_sph(theta, 0.7), a, a)
    ggx = a * a / (math.pi * np.cos(theta) ** 4 * (a * a + np.tan(theta) ** 2) ** 2)   # Walter et al. 2007 eq. 33
    np.testing.assert_allclose(d, ggx, rtol=1e-12)


@pytest.mark.parametrize("a_t, a_b, theta_o, phi_o", [(0.2, 0.8, 1.0, 0.3), (0.6, 0.1, 1.3, 1.2), (0.4, 0.4, 0.5, 0.0)])
def test_smith_masking_projects_the_facets_onto_the_view(a_t, a_b, theta_o, phi_o):
    # Heitz 2014 eq. (2): integral G1(o) <o.h> D(h) d omega_h = cos(theta_o)
    o = np.array(_sph(theta_o, phi_o))
    g1 = 1.0 / (1.0 + float(smith_lambda(*o, a_t, a_b)))

    def f(theta, phi):
        h = _sph(theta, phi)
        return max(0.0, float(np.dot(o, h))) * float(ellipsoid_ndf(*h, a_t, a_b)) * math.sin(theta)

    val, _ = integrate.dblquad(f, 0.0, 2 * math.pi, 0.0, math.pi / 2, epsabs=1e-6, epsrel=1e-5)
    assert g1 * val == pytest.approx(math.cos(theta_o), rel=2e-4)


def test_albedo_quadrature_matches_a_brute_force_integral_over_the_light():
    lobe = Lobe("anisotropic", 1.0, WHITE, 0.3, roughness_b=0.7)
    o = np.array(_sph(0.9, 0.4))

    def f(theta, phi):
        i = np.array(_sph(theta, phi))
        h = (i + o) / np.linalg.norm(i + o)
        val = anisotropic_lobe(i[2], o[2], h[2], float(i @ h), i[0], i[1], o[0], o[1], 0.3, 0.7)
        return float(val) * i[2] * math.sin(theta)

    want, _ = integrate.dblquad(f, 0.0, 2 * math.pi, 0.0, math.pi / 2, epsabs=1e-7, epsrel=1e-6)
    got = anisotropic_lobe_albedo(lobe, [o[2]], 0.4, [550.0])[0, 0]
    assert got == pytest.approx(want, rel=2e-3)


def test_internal_layer_factor_is_r_to_the_m_t_to_the_n_with_absorption():
    dye = Dye(np.array([400.0, 700.0]), np.array([0.3, 0.05]))
    n, k = 1.55, 3
    f = InternalLayerReflectance(n, dye, k, 1.0)
    cd = np.array([1.0, 0.6, 0.2])
    r = fresnel_dielectric(cd, n)
    cos_t = np.sqrt(1 - (1 - cd ** 2) / n ** 2)
    want = (r * (1 - r) ** (2 * k))[:, None] * np.exp(-np.outer(2 * k / cos_t, [0.3, 0.05]))
    np.testing.assert_allclose(f.reflectance(cd, [400.0, 700.0]), want, rtol=1e-12)


def test_layer_factors_sum_to_at_most_one_at_every_angle_up_to_fifty_layers():
    cd = np.concatenate([[0.0, 1e-12, 1e-6], np.linspace(0.0, 1.0, 2001)])
    for layers in (1, 3, 10, 50):
        norm = layer_normaliser(layers, 1.55)
        total = sum(InternalLayerReflectance(1.55, CLEAR, k, norm).reflectance(cd, [500.0]) for k in range(1, layers + 1))
        assert np.all(np.isfinite(total)) and total.max() <= 1.0 + 1e-12
    # deep layers with strong absorption underflow to 0, never to NaN
    dark = Dye(np.array([400.0, 700.0]), np.array([500.0, 500.0]))
    out = InternalLayerReflectance(1.55, dark, 50, 1.0).reflectance(cd, [400.0, 700.0])
    assert np.all(out == 0.0)


def test_kubelka_munk_round_trip_and_limits():
    r = np.array([1e-6, 0.01, 0.3, 0.9, 1.0])
    np.testing.assert_allclose(kubelka_munk_reflectance(kubelka_munk_ratio(r)), r, rtol=1e-9)
    assert float(kubelka_munk_reflectance(1e300)) == pytest.approx(0.5e-300, rel=1e-6)
    with pytest.raises(ValueError, match="Kubelka-Munk"):
        kubelka_munk_ratio([0.0])


def test_dye_from_srgb_reproduces_the_colour_under_d65():
    import colour

    for hexa in ("#a01830", "#1f8a5a", "#d8c8a0"):
        dye = Dye.from_srgb(hexa)
        refl = kubelka_munk_reflectance(dye.absorbance)
        sd = colour.SpectralDistribution(dict(zip(dye.wavelengths, refl)))
        cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(sd.shape)
        xyz = colour.sd_to_XYZ(sd, cmfs, colour.SDS_ILLUMINANTS["D65"].copy().align(sd.shape), method="Integration") / 100.0
        lab = colour.XYZ_to_Lab(xyz)
        target = colour.XYZ_to_Lab(colour.sRGB_to_XYZ(np.array([int(hexa[i:i + 2], 16) for i in (1, 3, 5)]) / 255))
        assert float(colour.delta_E(lab, target, method="CIE 2000")) < 1.0


def _local(theta_i, phi_i, theta_o, phi_o):
    i = np.array(_sph(theta_i, phi_i))
    o = np.array(_sph(theta_o, phi_o))
    h = (i + o) / np.linalg.norm(i + o, axis=0)
    return i[2], o[2], h[2], np.sum(i * h, axis=0), (i[0], i[1], o[0], o[1])


def test_weft_is_the_warp_turned_by_ninety_degrees():
    dye = Dye.from_srgb("#a01830")
    yarn = Yarn("filament", 0.05, 0.4, dye)
    warp_only = cloth_material("w", yarn, yarn, warp_fraction=1.0, layers=2)
    weft_only = cloth_material("f", yarn, yarn, warp_fraction=0.0, layers=2)
    rng = np.random.default_rng(1)
    ti, to = rng.uniform(0, 1.4, (2, 50))
    pi, po = rng.uniform(0, 2 * math.pi, (2, 50))
    wl = np.array([450.0, 600.0])
    a = material_brdf(warp_only, *_local(ti, pi, to, po)[:4], wl, _local(ti, pi, to, po)[4])
    b = material_brdf(weft_only, *_local(ti, pi + math.pi / 2, to, po + math.pi / 2)[:4], wl,
                      _local(ti, pi + math.pi / 2, to, po + math.pi / 2)[4])
    np.testing.assert_allclose(a, b, rtol=1e-9)


def test_filament_highlight_is_narrow_along_the_yarn_and_wide_across_it():
    silk = get_material("silk")
    wl = np.array([550.0])
    # mirror geometry tilted 20 degrees along t vs along b, warp only
    along = _local(0.35, 0.0, 0.35, math.pi)     # light and view in the t-n plane: h = n
    tilt_t = _local(0.35 + 0.35, 0.0, 0.35 - 0.35 + 1e-9, math.pi)
    tilt_b = _local(0.7, math.pi / 2, 1e-9, 3 * math.pi / 2)
    m = cloth_material("warp", Yarn("filament", 0.05, 0.45, CLEAR), Yarn("filament", 0.05, 0.45, CLEAR),
                       warp_fraction=1.0, specular=1.0, internal=0.0, diffuse=0.0, layers=0)
    peak, t, b = (float(material_brdf(m, *g[:4], wl, g[4])[0]) for g in (along, tilt_t, tilt_b))
    assert t < 0.05 * b < 0.05 * peak            # h tilted along t falls off much faster
    assert silk.anisotropic


@pytest.mark.parametrize("spec", ["silk", "cotton", "tamamushi", "satin", "silk:layers=50",
                                  "silk:a_t=0.001,a_b=1", "silk:a_t=1,a_b=0.001", "silk:a_t=0.1,a_b=100",
                                  "cotton:specular=1,internal=0,diffuse=0", "silk:specular=0,internal=1,diffuse=0"])
def test_directional_albedo_is_at_most_one_at_every_incidence(spec):
    m = get_material(spec)
    cos_o = np.array([1e-6, 0.01, 0.05, 0.2, 0.5, 0.8, 1.0])
    wl = np.array([420.0, 550.0, 680.0])
    for phi in (0.0, 0.6, math.pi / 2):
        a = material_albedo(m, cos_o, phi, wl, n_q=48, n_phi=64)
        assert np.all(np.isfinite(a)) and np.all(a >= 0)
        assert a.max() <= 1.0 + 2e-3, (spec, phi, a.max())


@pytest.mark.parametrize("a", [0.02, 0.2, 0.5, 1.0])
def test_albedo_at_normal_incidence_matches_a_one_dimensional_integral(a):
    # isotropic axes, view along n: the light is the mirror of n about h, theta_i = 2 theta_h, so
    # E = integral_0^{pi/4} 2 pi sin cos D(theta_h) / (1 + Lambda(2 theta_h)) d theta_h, with the
    # GGX D and Lambda of Walter et al. 2007, eq. (33) and (72), written out here
    def f(t):
        d = a * a / (math.pi * math.cos(t) ** 4 * (a * a + math.tan(t) ** 2) ** 2)
        lam = (-1 + math.sqrt(1 + a * a * math.tan(2 * t) ** 2)) / 2
        return 2 * math.pi * math.sin(t) * math.cos(t) * d / (1 + lam)

    want, _ = integrate.quad(f, 0.0, math.pi / 4, limit=200, epsabs=1e-11)
    got = anisotropic_lobe_albedo(Lobe("anisotropic", 1.0, WHITE, a, roughness_b=a), [1.0], 0.3, [550.0])[0, 0]
    assert got == pytest.approx(want, rel=1e-3)


@settings(max_examples=80, deadline=None, derandomize=True)
@given(
    ti=st.floats(0.0, math.pi / 2), to=st.floats(0.0, math.pi / 2), pi=st.floats(0.0, 2 * math.pi),
    po=st.floats(0.0, 2 * math.pi), lt=st.floats(-3.0, 0.0), lb=st.floats(-3.0, 2.0),
    f32=st.booleans(),
)
def test_lobe_is_finite_at_grazing_angles_and_extreme_axes(ti, to, pi, po, lt, lb, f32):
    ci, co, ch, cd, tang = _local(ti, pi, to, po)
    dtype = np.float32 if f32 else np.float64
    args = [np.asarray(x, dtype=dtype) for x in (ci, co, ch, cd, *tang)]
    v = anisotropic_lobe(*args, 10.0 ** lt, 10.0 ** lb)
    assert np.isfinite(v) and v >= 0 and v.dtype == dtype


def test_bad_parameters_are_refused_with_their_names():
    with pytest.raises(ValueError, match="a_t"):
        Lobe("anisotropic", 1.0, WHITE, 0.0, roughness_b=0.3)
    with pytest.raises(ValueError, match="tangent-frame"):
        material_brdf(get_material("silk"), 1.0, 1.0, 1.0, 1.0, [500.0])
    with pytest.raises(ValueError, match="layers"):
        cloth_material("x", Yarn("spun", 0.3, 0.5, CLEAR), Yarn("spun", 0.3, 0.5, CLEAR), layers=51)
    with pytest.raises(MaterialError, match="specular.*exceeds 1"):
        get_material("silk:specular=0.5,internal=0.5")
    with pytest.raises(MaterialError, match="warp_colour"):
        get_material("silk:warp_colour=notacolour")
    with pytest.raises(ValueError, match="absorbance"):
        Dye(np.array([400.0, 700.0]), np.array([0.1, -1.0]))
