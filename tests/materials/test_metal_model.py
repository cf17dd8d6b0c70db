"""The metal model (Matsuda eq. 1-2) against an independent rough-conductor BRDF
(Walter et al. 2007), and its spectral factor at the extremes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.special import erf

from processing.materials.lobes import SpectralFactor, material_brdf
from processing.materials.metal_model import ConductorFresnel, metal_material, normalise_composition
from processing.materials.optical_constants import METALS, complex_index
from processing.spectral.spectra import SpectralGrid

WL = SpectralGrid(400, 700, 20).wavelengths


# --- independent reference: Walter et al. 2007, vector form -----------------------------


def _fresnel_nk(cos_i: np.ndarray, n: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Unpolarised conductor reflectance, real n, k form (pbrt-v3 FrConductor)."""
    c2 = cos_i * cos_i
    s2 = 1.0 - c2
    t0 = n * n - k * k - s2
    a2b2 = np.sqrt(t0 * t0 + 4 * n * n * k * k)
    t1 = a2b2 + c2
    a = np.sqrt(0.5 * (a2b2 + t0))
    t2 = 2 * cos_i * a
    rs = (t1 - t2) / (t1 + t2)
    t3 = c2 * a2b2 + s2 * s2
    t4 = t2 * s2
    rp = rs * (t3 - t4) / (t3 + t4)
    return 0.5 * (rs + rp)


def _walter_rough_conductor(i, o, n_vec, alpha, n, k) -> np.ndarray:
    """f_r(i, o) = F(i.h) D(h) G1(i, h) G1(o, h) / (4 |i.n| |o.n|), Walter eq. (20), (25), (27)."""
    h = i + o
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    cos_h = h @ n_vec
    tan2_h = (1 - cos_h**2) / cos_h**2
    d = np.exp(-tan2_h / alpha**2) / (np.pi * alpha**2 * cos_h**4) * (cos_h > 0)

    def g1(v):
        cos_v = v @ n_vec
        tan_v = np.sqrt(1 - cos_v**2) / cos_v
        a = 1 / (alpha * tan_v)
        chi = ((v * h).sum(-1) / cos_v) > 0
        return chi * 2 / (1 + erf(a) + np.exp(-a * a) / (a * np.sqrt(np.pi)))

    cos_i, cos_o = i @ n_vec, o @ n_vec
    f = _fresnel_nk((i * h).sum(-1)[:, None], n[None, :], k[None, :])
    return (f * (d * g1(i) * g1(o) / (4 * cos_i * cos_o))[:, None])


def _random_directions(rng: np.random.Generator, count: int) -> np.ndarray:
    v = rng.normal(size=(count, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[:, 2] = np.abs(v[:, 2]) + 1e-3  # upper hemisphere, not exactly grazing
    return v / np.linalg.norm(v, axis=1, keepdims=True)


@pytest.mark.parametrize("metal, alpha", [("Au", 0.15), ("Cu", 0.05), ("Al", 0.4), ("Fe", 0.8)])
def test_matches_walter_rough_conductor(metal: str, alpha: float) -> None:
    rng = np.random.default_rng(7)
    i, o = _random_directions(rng, 300), _random_directions(rng, 300)
    normal = np.array([0.0, 0.0, 1.0])
    eta = complex_index(metal, WL)
    expected = _walter_rough_conductor(i, o, normal, alpha, eta.real, eta.imag)

    mat = metal_material(metal, {metal: 1.0}, gloss=1.0, mirror=0.0, roughness=alpha, shadowing="smith")
    h = (i + o) / np.linalg.norm(i + o, axis=1, keepdims=True)
    got = material_brdf(mat, i[:, 2], o[:, 2], h[:, 2], (i * h).sum(1), WL)
    assert got.shape == (300, WL.size)
    assert np.allclose(got, expected, rtol=1e-9, atol=1e-12)
    assert expected.max() > 0.5  # the comparison covers the specular peak


def test_alloy_fresnel_is_weighted_sum() -> None:
    f = ConductorFresnel({"Ag": 0.3, "Cu": 0.7})
    cos = np.array([0.0, 0.2, 0.7, 1.0])
    expected = sum(
        w * _fresnel_nk(cos[:, None], complex_index(m, WL).real[None], complex_index(m, WL).imag[None])
        for m, w in (("Ag", 0.3), ("Cu", 0.7))
    )
    # the real n, k form is exact except at cos = 0, where both are 1
    assert np.allclose(f.reflectance(cos, WL), expected, atol=1e-12)


# --- spectral factor properties ---------------------------------------------------------

COS = st.one_of(st.just(0.0), st.just(1.0), st.floats(0.0, 1.0))


@settings(max_examples=60, deadline=None)
@given(cos=COS, metal=st.sampled_from(METALS))
def test_reflectance_bounded_and_unity_at_grazing(cos: float, metal: str) -> None:
    f = ConductorFresnel({metal: 1.0})
    r = f.reflectance(cos, WL)
    assert r.shape == (WL.size,)
    assert np.all(np.isfinite(r)) and np.all((r >= 0) & (r <= 1))
    if cos == 0.0:
        assert np.all(r == 1.0)


def test_exactly_90_degrees_from_angles() -> None:
    f = ConductorFresnel({"Au": 1.0})
    r = f.reflectance(np.cos(np.radians([0.0, 89.9, 90.0])), WL)
    assert np.allclose(r[2], 1.0) and np.all(r[1] > r[0])


def test_gold_colour_shift_towards_white_at_grazing() -> None:
    r = ConductorFresnel({"Au": 1.0}).reflectance(np.array([1.0, 0.05]), [450.0, 650.0])
    assert r[0, 1] / r[0, 0] > 2.0  # yellow at normal incidence
    assert r[1, 1] / r[1, 0] < 1.2  # nearly white near grazing


def test_protocol_and_eta_cache() -> None:
    f = ConductorFresnel({"Au": 1.0})
    assert isinstance(f, SpectralFactor) and f.angle_dependent
    assert f.eta(WL) is f.eta(WL.copy())
    assert f.eta(WL).shape == (1, WL.size)


def test_reflectance_shape_over_images() -> None:
    r = ConductorFresnel({"Cu": 0.5, "Au": 0.5}).reflectance(np.full((4, 5), 0.6), WL)
    assert r.shape == (4, 5, WL.size)


# --- metal_material ------------------------------------------------------------------------


def test_metal_material_lobes_and_parameters() -> None:
    m = metal_material("gold", {"au": 2.0}, gloss=0.6, mirror=0.4, roughness=0.2, mirror_roughness=0.02)
    gloss, mirror = m.lobes
    assert (gloss.weight, gloss.roughness, gloss.mirror) == (0.6, 0.2, False)
    assert (mirror.weight, mirror.roughness, mirror.mirror) == (0.4, 0.02, True)
    assert m.family == "metal"
    assert m.parameters == {
        "gloss": 0.6, "mirror": 0.4, "roughness": 0.2, "mirror_roughness": 0.02, "shadowing": "smith", "Au": 1.0,
    }
    assert metal_material("x", {"Cu": 1, "Sn": 1}).family == "alloy"


def test_normalise_composition() -> None:
    assert normalise_composition({"Cu": 88, "Sn": 12}) == pytest.approx({"Cu": 0.88, "Sn": 0.12})
    assert normalise_composition({"Cu": 1, "Au": 0}) == {"Cu": 1.0}


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"gloss": 0.8, "mirror": 0.4}, "gloss \\+ mirror = 1.2 exceeds 1"),
        ({"roughness": 0.0}, "roughness must be in \\(0, 1\\]"),
        ({"roughness": 1.5}, "roughness must be in \\(0, 1\\]"),
        ({"mirror_roughness": -0.1}, "mirror_roughness"),
        ({"gloss": float("nan")}, "gloss must be in \\[0, 1\\]"),
        ({"gloss": "shiny"}, "gloss must be a number"),
        ({"shadowing": "ggx"}, "smith, torrance-sparrow"),
    ],
)
def test_metal_material_errors(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        metal_material("gold", {"Au": 1.0}, **kwargs)


@pytest.mark.parametrize(
    "metals, match",
    [
        ({}, "non-empty"),
        ({"Xx": 1.0}, "unknown metal 'Xx'"),
        ({"Au": -1.0}, "weight of Au must be finite and >= 0"),
        ({"Au": 0.0}, "sum to 0"),
        ({"Au": 1.0, "au": 1.0}, "given twice"),
    ],
)
def test_composition_errors(metals: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        metal_material("m", metals)


def test_torrance_sparrow_shadowing_is_used() -> None:
    m = metal_material("gold", {"Au": 1.0}, shadowing="torrance-sparrow")
    assert all(lobe.shadowing == "torrance-sparrow" for lobe in m.lobes)
    a = material_brdf(m, 0.3, 0.3, 0.95, 0.5, [550.0])
    b = material_brdf(metal_material("gold", {"Au": 1.0}), 0.3, 0.3, 0.95, 0.5, [550.0])
    assert not np.allclose(a, b)


def test_tiny_roughness_and_tiny_cosines_stay_finite() -> None:
    m = metal_material("gold", {"Au": 1.0}, roughness=1e-5, mirror=0.0)
    for cos_h in (1.0, 0.999999, 0.9):
        v = material_brdf(m, 0.7, 0.7, cos_h, 0.7, WL)
        assert np.all(np.isfinite(v))
    assert math.isfinite(float(material_brdf(m, 1e-9, 1e-9, 1.0, 1e-9, [550.0])[0]))
