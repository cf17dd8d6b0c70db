"""Directional albedo: closed forms, an independent quadrature, and energy
conservation (albedo <= 1) for every preset at every incidence."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.special import erf

from processing.materials.albedo import directional_albedo, lobe_albedo
from processing.materials.dielectric_model import DielectricFresnel
from processing.materials.lobes import Lobe, Material
from processing.materials.metal_model import metal_material
from processing.materials.presets import get_material, list_materials
from processing.spectral.spectra import SpectralGrid

WL = SpectralGrid(400, 700, 50).wavelengths
INCIDENCE = np.array([0.0, 1e-9, 1e-3, math.cos(math.radians(89.0)), 0.1, 0.3, 0.5, 0.7, 0.9, 1.0])


class White:
    angle_dependent = False

    def reflectance(self, cos_d, wl):
        return np.ones(np.shape(cos_d) + (len(wl),))


def test_white_lambert_albedo_is_one() -> None:
    a = directional_albedo(Lobe("lambert", 1.0, White()), INCIDENCE, WL)
    assert a.shape == (INCIDENCE.size, WL.size)
    assert np.all(a[0] == 0.0)  # exactly grazing: nothing is seen
    assert np.allclose(a[1:], 1.0, atol=1e-12)


@pytest.mark.parametrize("sigma", [1e-3, 0.05, 0.3, 0.7, 1.0])
def test_unshadowed_lobe_closed_form(sigma: float) -> None:
    # G = 1, F = 1, normal view: a = integral over theta_h < 45 deg of D cos = 1 - exp(-1/sigma^2)
    a = lobe_albedo(Lobe("microfacet", 1.0, White(), sigma, "none"), 1.0, [550.0])
    assert float(a[0]) == pytest.approx(1.0 - math.exp(-1.0 / sigma**2), abs=1e-9)


def _independent_albedo(cos_o: float, sigma: float, n: float, size: int = 1200) -> float:
    """Midpoint rule over incident directions (theta_i, phi_i), Smith-Beckmann
    rough dielectric BRDF written from Walter et al. 2007."""
    theta = (np.arange(size) + 0.5) * (np.pi / 2 / size)
    phi = (np.arange(size) + 0.5) * (np.pi / size)  # half the azimuth, doubled
    t, p = np.meshgrid(theta, phi, indexing="ij")
    i = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1)
    o = np.array([math.sqrt(1 - cos_o**2), 0.0, cos_o])
    h = i + o
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    ch = h[..., 2]
    d = np.exp(-(1 - ch**2) / ch**2 / sigma**2) / (np.pi * sigma**2 * ch**4)

    def g1(c):
        a = c / (sigma * np.sqrt(1 - c**2))
        return 2 / (1 + erf(a) + np.exp(-a * a) / (a * np.sqrt(np.pi)))

    cd = (i * h).sum(-1)
    st_ = np.sqrt(np.maximum(0.0, 1 - (1 - cd**2) / n**2))
    rs = ((cd - n * st_) / (cd + n * st_)) ** 2
    rp = ((n * cd - st_) / (n * cd + st_)) ** 2
    f = 0.5 * (rs + rp) * d * g1(i[..., 2]) * g1(cos_o) / (4 * i[..., 2] * cos_o)
    integrand = f * i[..., 2] * np.sin(t)
    return float(integrand.sum() * (np.pi / 2 / size) * (np.pi / size) * 2)


@pytest.mark.parametrize("cos_o, sigma", [(0.5, 0.3), (0.15, 0.8), (0.9, 0.5)])
def test_against_independent_quadrature(cos_o: float, sigma: float) -> None:
    lobe = Lobe("microfacet", 1.0, DielectricFresnel(1.5), sigma, "smith")
    a = float(lobe_albedo(lobe, cos_o, [550.0])[0])
    assert a == pytest.approx(_independent_albedo(cos_o, sigma, 1.5), abs=1e-5)


@pytest.mark.parametrize("name", ["gold", "tin", "nami-shibuichi", "urushi-red"])
def test_default_quadrature_converged(name: str) -> None:
    m = get_material(name)
    cos = np.array([1e-3, 0.05, 0.5, 1.0])
    coarse = directional_albedo(m, cos, WL)
    fine = directional_albedo(m, cos, WL, n_theta=160, n_phi=160)
    assert np.allclose(coarse, fine, atol=2e-5)


@pytest.mark.parametrize("name", list_materials())
def test_every_preset_conserves_energy(name: str) -> None:
    a = directional_albedo(get_material(name), INCIDENCE, WL)
    assert np.all(np.isfinite(a)) and a.min() >= 0.0
    assert a.max() <= 1.0
    assert a[-1].min() > 0.0  # and reflects something at normal incidence


def test_perfectly_smooth_metal_albedo_is_fresnel() -> None:
    # a near-mirror lobe integrates to F at the mirror angle (Smith G1 -> 1 for tiny sigma)
    m = metal_material("silver", {"Ag": 1.0}, gloss=0.0, mirror=1.0, mirror_roughness=1e-4)
    from processing.materials.fresnel import fresnel_conductor
    from processing.materials.optical_constants import complex_index

    for cos_o in (1.0, 0.5):
        expected = fresnel_conductor(cos_o, complex_index("Ag", WL))
        assert np.allclose(directional_albedo(m, cos_o, WL), expected, atol=1e-4)


@settings(max_examples=25, deadline=None)
@given(
    gloss=st.floats(0.0, 1.0),
    split=st.floats(0.0, 1.0),
    roughness=st.one_of(st.just(1e-5), st.just(1.0), st.floats(1e-3, 1.0)),
    shadowing=st.sampled_from(["smith", "torrance-sparrow"]),
    metal=st.sampled_from(["Au", "Ag", "Cu", "Al", "Fe", "Sn"]),
)
def test_random_metals_conserve_energy(gloss, split, roughness, shadowing, metal) -> None:
    mirror = (1.0 - gloss) * split
    m = metal_material("m", {metal: 1.0}, gloss=gloss, mirror=mirror, roughness=roughness,
                       mirror_roughness=max(roughness / 10, 1e-5), shadowing=shadowing)
    a = directional_albedo(m, INCIDENCE, WL, n_theta=32, n_phi=32)
    assert np.all(np.isfinite(a)) and a.min() >= 0.0 and a.max() <= 1.0 + 1e-4


def test_shapes_and_empty_material() -> None:
    m = get_material("copper")
    a = directional_albedo(m, np.full((2, 3), 0.5), WL)
    assert a.shape == (2, 3, WL.size)
    assert np.allclose(a, a[0, 0])
    assert directional_albedo(Material("empty", ()), [0.5, 1.0], WL).shape == (2, WL.size)
    assert np.all(lobe_albedo(Lobe("lambert", 0.0, White()), 0.5, WL) == 0.0)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"cos_o": 1.5}, r"cos_o must be finite and in \[0, 1\]"),
        ({"cos_o": np.nan}, r"cos_o must be finite"),
        ({"n_theta": 2}, "n_theta must be an integer >= 4"),
        ({"n_phi": 8.5}, "n_phi must be an integer >= 4"),
        ({"wavelengths": [[500.0]]}, "1-D"),
    ],
)
def test_errors(kwargs, match) -> None:
    args = {"cos_o": 0.5, "wavelengths": WL, **kwargs}
    cos_o, wl = args.pop("cos_o"), args.pop("wavelengths")
    with pytest.raises(ValueError, match=match):
        directional_albedo(get_material("gold"), cos_o, wl, **args)


def test_rejects_non_material() -> None:
    with pytest.raises(ValueError, match="Material or a Lobe"):
        directional_albedo("gold", 0.5, WL)  # type: ignore[arg-type]
