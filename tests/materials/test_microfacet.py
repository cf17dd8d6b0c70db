"""Beckmann distribution and shadowing terms: normalisation, Smith's
projected-area identity, closed forms and numerical extremes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate

from processing.materials.microfacet import (
    SmithLobe,
    beckmann_d,
    microfacet_lobe,
    smith_g,
    smith_g1_beckmann,
    torrance_sparrow_g,
)

ROUGH = st.one_of(st.just(1e-5), st.just(1.0), st.floats(1e-5, 1.0))
COS = st.one_of(st.just(0.0), st.just(1.0), st.floats(0.0, 1.0))
SETTINGS = settings(max_examples=150, deadline=None)


@pytest.mark.parametrize("sigma", [1e-3, 1e-2, 0.05, 0.1, 0.3, 0.6, 1.0])
def test_d_is_normalised(sigma: float) -> None:
    # integral of D(h) cos(theta_h) over the hemisphere = 1, by adaptive quadrature
    def f(theta: float) -> float:
        return float(beckmann_d(math.cos(theta), sigma)) * math.cos(theta) * math.sin(theta) * 2 * math.pi

    points = [min(s * sigma, 1.5) for s in (0.5, 1, 2, 4, 8)]
    value, err = integrate.quad(f, 0.0, math.pi / 2, points=points, limit=400, epsabs=1e-12)
    assert value == pytest.approx(1.0, abs=1e-6)


@pytest.mark.parametrize("sigma", [0.05, 0.3, 1.0])
def test_d_closed_form(sigma: float) -> None:
    theta = np.linspace(0, 1.4, 9)
    expected = np.exp(-np.tan(theta) ** 2 / sigma**2) / (np.pi * sigma**2 * np.cos(theta) ** 4)
    assert np.allclose(beckmann_d(np.cos(theta), sigma), expected, rtol=1e-12, atol=0)


def _projected_area(cos_o: float, sigma: float) -> float:
    """integral of max(0, o.m) D(m) d omega_m: the phi integral in closed form,
    the theta integral by adaptive quadrature."""
    sin_o = math.sqrt(1 - cos_o * cos_o)

    def f(theta: float) -> float:
        a, b = math.sin(theta) * sin_o, math.cos(theta) * cos_o
        # integral over phi in [0, 2 pi] of max(0, a cos(phi) + b)
        if b >= a:
            ring = 2 * math.pi * b
        else:
            phi0 = math.acos(-b / a)
            ring = 2 * (a * math.sin(phi0) + b * phi0)
        return ring * float(beckmann_d(math.cos(theta), sigma)) * math.sin(theta)

    val, _ = integrate.quad(f, 0.0, math.pi / 2, points=[sigma, 3 * sigma], limit=400, epsabs=1e-12)
    return val


@pytest.mark.parametrize("sigma", [0.1, 0.3, 0.7])
@pytest.mark.parametrize("theta_deg", [30.0, 60.0, 80.0])
def test_smith_g1_satisfies_projected_area_identity(sigma: float, theta_deg: float) -> None:
    # Heitz 2014, eq. (2): G1(o) * integral <o, m> D(m) dm = cos(theta_o) for Smith masking
    cos_o = math.cos(math.radians(theta_deg))
    g1 = float(smith_g1_beckmann(cos_o, sigma))
    assert g1 * _projected_area(cos_o, sigma) == pytest.approx(cos_o, rel=2e-4)


@SETTINGS
@given(cos=COS, sigma=ROUGH)
def test_smith_g1_finite_and_bounded(cos: float, sigma: float) -> None:
    g = float(smith_g1_beckmann(cos, sigma))
    assert math.isfinite(g) and 0.0 <= g <= 1.0
    if cos == 0.0:
        assert g == 0.0
    if cos == 1.0:
        assert g == 1.0


def test_smith_g1_monotone_in_angle_and_roughness() -> None:
    cos = np.linspace(0.0, 1.0, 101)
    g = smith_g1_beckmann(cos, 0.4)
    assert np.all(np.diff(g) >= -1e-15)
    assert np.all(smith_g1_beckmann(0.3, 0.2) >= smith_g1_beckmann(0.3, 0.8))


def test_smith_g1_walter_form() -> None:
    # Walter et al. 2007, eq. (27): G1 = 2 / (1 + erf(a) + exp(-a^2) / (a sqrt(pi)))
    for cos, sigma in [(0.2, 0.3), (0.5, 0.5), (0.05, 0.1)]:
        a = cos / (sigma * math.sqrt(1 - cos * cos))
        expected = 2 / (1 + math.erf(a) + math.exp(-a * a) / (a * math.sqrt(math.pi)))
        assert float(smith_g1_beckmann(cos, sigma)) == pytest.approx(expected, rel=1e-12)


def test_smith_g_is_product() -> None:
    assert float(smith_g(0.3, 0.8, 0.25)) == pytest.approx(
        float(smith_g1_beckmann(0.3, 0.25) * smith_g1_beckmann(0.8, 0.25))
    )


@SETTINGS
@given(ci=COS, co=COS, ch=COS, cd=COS)
def test_torrance_sparrow_bounded(ci: float, co: float, ch: float, cd: float) -> None:
    g = float(torrance_sparrow_g(ci, co, ch, cd))
    assert math.isfinite(g) and 0.0 <= g <= 1.0


def test_torrance_sparrow_closed_form() -> None:
    # symmetric configuration: theta_i = theta_o = 60 deg in the plane, h = n
    assert float(torrance_sparrow_g(0.5, 0.5, 1.0, 0.5)) == 1.0
    # off-specular: G = 2 (n.h)(n.o)/(o.h)
    assert float(torrance_sparrow_g(0.9, 0.1, 0.8, 0.7)) == pytest.approx(2 * 0.8 * 0.1 / 0.7)


@SETTINGS
@given(ci=COS, co=COS, ch=COS, cd=COS, sigma=ROUGH, shadowing=st.sampled_from(["smith", "torrance-sparrow"]))
def test_lobe_finite_non_negative(ci, co, ch, cd, sigma, shadowing) -> None:
    v = float(microfacet_lobe(ci, co, ch, cd, sigma, shadowing))
    assert math.isfinite(v) and v >= 0.0
    if ci == 0.0 or co == 0.0:
        assert v == 0.0


def test_exp_underflow_gives_zero_not_nan() -> None:
    d = beckmann_d(np.array([0.0, 1e-9, 0.5, 0.999]), 1e-5)
    assert np.all(np.isfinite(d)) and np.all(d == 0.0)
    assert float(beckmann_d(1.0, 1e-5)) == pytest.approx(1 / (math.pi * 1e-10))


def test_lobe_below_horizon_is_zero() -> None:
    assert float(microfacet_lobe(-0.2, 0.5, 0.9, 0.7, 0.3)) == 0.0
    assert float(microfacet_lobe(0.5, -0.2, 0.9, 0.7, 0.3)) == 0.0


def test_bad_roughness_and_shadowing() -> None:
    with pytest.raises(ValueError, match="roughness"):
        beckmann_d(0.9, 0.0)
    with pytest.raises(ValueError, match="roughness"):
        smith_g1_beckmann(0.9, -0.1)
    with pytest.raises(ValueError, match="shadowing='ggx'"):
        microfacet_lobe(0.5, 0.5, 0.9, 0.8, 0.2, "ggx")


def test_smith_lobe_is_d_g_over_4_cos_cos_to_the_bit() -> None:
    # SmithLobe keeps the roughness-free terms of many evaluations; its values must be those of the
    # lobe's definition D G / (4 cos_i cos_o) from beckmann_d and smith_g exactly (the fit's roughness
    # search compares chi-squares of these values), including the edge cases: grazing, normal
    # incidence, below the horizon, a half vector at 90 deg, tiny and large roughness.
    rng = np.random.default_rng(3)
    ci, co, ch = (rng.uniform(-0.2, 1.0, 4000) for _ in range(3))
    ci[:5], co[5:10], ch[10:15], ch[15:20], co[20:25], ci[25:30] = 0.0, 1.0, 0.0, 1.0, -0.0, 1e-200
    lobe = SmithLobe(ci, co, ch)
    valid = (ci > 0) & (co > 0)
    for sigma in (1e-3, 0.02, 0.1537, 0.8, 1.3):
        with np.errstate(under="ignore", over="ignore", divide="ignore", invalid="ignore"):
            expected = np.where(valid, beckmann_d(ch, sigma) * smith_g(ci, co, sigma)
                                / (4.0 * np.where(valid, ci * co, 1.0)), 0.0)
        expected = np.nan_to_num(expected, nan=0.0, posinf=0.0)
        np.testing.assert_array_equal(lobe(sigma), expected)
        np.testing.assert_array_equal(microfacet_lobe(ci, co, ch, 0.5, sigma), expected)
    with pytest.raises(ValueError, match="roughness"):
        lobe(0.0)
