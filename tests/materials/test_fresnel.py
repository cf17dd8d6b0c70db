"""Fresnel reflectance of conductors and dielectrics against closed forms and an
independent real-valued implementation (the n, k formula used by pbrt)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from processing.materials.fresnel import fresnel_conductor, fresnel_dielectric

COS = st.one_of(st.just(0.0), st.just(1.0), st.floats(0.0, 1.0))
N = st.floats(0.01, 10.0)
K = st.one_of(st.just(0.0), st.floats(0.0, 50.0))
SETTINGS = settings(max_examples=200, deadline=None)


def pbrt_conductor(cos_i: float, n: float, k: float) -> float:
    """Real-valued unpolarised conductor Fresnel (pbrt-v3 FrConductor, incident index 1)."""
    c2 = cos_i * cos_i
    s2 = 1.0 - c2
    t0 = n * n - k * k - s2
    a2b2 = math.sqrt(t0 * t0 + 4.0 * n * n * k * k)
    t1 = a2b2 + c2
    a = math.sqrt(max(0.5 * (a2b2 + t0), 0.0))
    t2 = 2.0 * cos_i * a
    rs = (t1 - t2) / (t1 + t2)
    t3 = c2 * a2b2 + s2 * s2
    t4 = t2 * s2
    rp = rs * (t3 - t4) / (t3 + t4)
    return 0.5 * (rp + rs)


@SETTINGS
@given(cos=st.floats(0.01, 1.0), n=N, k=K)
def test_conductor_matches_independent_real_formula(cos: float, n: float, k: float) -> None:
    expected = pbrt_conductor(cos, n, k)
    # the real form loses ~1e-8 to cancellation in a^2 = (|t0| + t0) / 2 when
    # n < sin(theta) and k is tiny (absorbing total internal reflection)
    assert float(fresnel_conductor(cos, n + 1j * k)) == pytest.approx(expected, abs=5e-8)
    if k > 1e-3 or n > 1.0:
        assert float(fresnel_conductor(cos, n + 1j * k)) == pytest.approx(expected, abs=1e-11)


@SETTINGS
@given(n=N, k=K)
def test_normal_incidence_closed_form(n: float, k: float) -> None:
    expected = ((n - 1) ** 2 + k * k) / ((n + 1) ** 2 + k * k)
    assert float(fresnel_conductor(1.0, n + 1j * k)) == pytest.approx(expected, rel=1e-12, abs=1e-15)


@SETTINGS
@given(cos=COS, n=N, k=K)
def test_conductor_finite_and_in_unit_interval(cos: float, n: float, k: float) -> None:
    f = float(fresnel_conductor(cos, n + 1j * k))
    assert math.isfinite(f) and 0.0 <= f <= 1.0


@SETTINGS
@given(n=N, k=K)
def test_grazing_incidence_is_a_perfect_mirror(n: float, k: float) -> None:
    # exactly 90 degrees, and the limit from just above
    assert float(fresnel_conductor(0.0, n + 1j * k)) == 1.0
    if abs(complex(n, k) - 1.0) > 1e-3:
        assert float(fresnel_conductor(1e-9, n + 1j * k)) == pytest.approx(1.0, abs=1e-5)


def test_grazing_exactly_90_degrees_from_angle() -> None:
    cos90 = math.cos(math.radians(90.0))  # 6e-17, not 0
    f = fresnel_conductor(np.array([0.0, cos90]), 0.27 + 2.78j)
    assert np.all(np.isfinite(f)) and np.allclose(f, 1.0, atol=1e-12)


@SETTINGS
@given(cos=COS, n=N)
def test_k_to_zero_reduces_to_dielectric(cos: float, n: float) -> None:
    d = float(fresnel_dielectric(cos, n))
    assert float(fresnel_conductor(cos, complex(n, 0.0))) == pytest.approx(d, abs=1e-12)
    # continuity in k, away from the one singular point n = 1 at grazing incidence,
    # where F jumps from 0 (no interface) to 1 within cos ~ sqrt(|eta^2 - 1|)
    if abs(n * n - 1.0 + cos * cos) > 1e-3:
        assert float(fresnel_conductor(cos, complex(n, 1e-9))) == pytest.approx(d, abs=1e-6)


@SETTINGS
@given(theta=st.floats(0.01, 1.55), n=st.floats(1.01, 10.0))
def test_dielectric_matches_fresnel_angle_form(theta: float, n: float) -> None:
    # Fresnel's sine and tangent laws, with Snell's law for the refraction angle
    theta_t = math.asin(math.sin(theta) / n)
    rs = math.sin(theta - theta_t) ** 2 / math.sin(theta + theta_t) ** 2
    rp = math.tan(theta - theta_t) ** 2 / math.tan(theta + theta_t) ** 2
    assert float(fresnel_dielectric(math.cos(theta), n)) == pytest.approx(0.5 * (rs + rp), abs=1e-10)


@pytest.mark.parametrize("n", [1.33, 1.5, 2.4])
def test_brewster_angle_p_vanishes(n: float) -> None:
    theta_b = math.atan(n)
    rs_b = ((n * n - 1) / (n * n + 1)) ** 2
    assert float(fresnel_dielectric(math.cos(theta_b), n)) == pytest.approx(0.5 * rs_b, rel=1e-10)


@SETTINGS
@given(cos=COS, n=N)
def test_dielectric_finite_unit_interval_and_total_internal_reflection(cos: float, n: float) -> None:
    f = float(fresnel_dielectric(cos, n))
    assert math.isfinite(f) and 0.0 <= f <= 1.0
    if n < 1.0 and (1.0 - cos * cos) > n * n * (1 + 1e-12):
        assert f == 1.0


def test_glass_values() -> None:
    assert float(fresnel_dielectric(1.0, 1.5)) == pytest.approx(0.04)
    assert float(fresnel_dielectric(0.0, 1.5)) == 1.0


def test_broadcasting_over_wavelength() -> None:
    eta = np.array([0.2 + 3j, 1.0 + 2j, 0.05 + 4j])
    f = fresnel_conductor(np.linspace(0, 1, 7)[:, None], eta)
    assert f.shape == (7, 3)


@pytest.mark.parametrize(
    "eta, match",
    [(0.5 - 2j, "k >= 0"), (-0.5 + 2j, "n >= 0"), (0j, "eta != 0"), (complex("nan"), "NaN")],
)
def test_conductor_bad_index(eta: complex, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        fresnel_conductor(0.5, eta)


def test_bad_cosine_and_dielectric_index() -> None:
    with pytest.raises(ValueError, match="cos_theta"):
        fresnel_conductor(np.array([0.5, np.nan]), 1.5 + 1j)
    with pytest.raises(ValueError, match="n must be finite and > 0"):
        fresnel_dielectric(0.5, 0.0)
    with pytest.raises(ValueError, match="cos_theta"):
        fresnel_dielectric(np.inf, 1.5)


def test_matched_index_has_no_reflection_except_the_grazing_limit() -> None:
    # eta = 1 is the one 0/0 case of the complex form at grazing incidence
    f = fresnel_conductor(np.array([0.0, 1e-12, 0.5, 1.0]), 1.0 + 0j)
    assert f[0] == 1.0
    assert np.all(f[1:] == pytest.approx(0.0, abs=1e-12))


def test_denormal_cosine_near_unit_index_stays_finite_and_matches_dielectric() -> None:
    # cos^2 underflows to 0, so both formulas see sin(theta) = 1: total reflection, F = 1.
    for n in (1.0, 1.0 + 1e-12, 1.5):
        d = float(fresnel_dielectric(5e-324, n))
        c = float(fresnel_conductor(5e-324, complex(n, 0.0)))
        assert np.isfinite(c) and c == pytest.approx(d, abs=1e-12)
