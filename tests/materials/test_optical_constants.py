"""Optical constants against the published tables, and the tin extrapolation."""

from __future__ import annotations

import numpy as np
import pytest

from processing.materials.fresnel import fresnel_conductor
from processing.materials.optical_constants import (
    METALS,
    complex_index,
    drude_index,
    metal_source,
    metal_wavelength_range,
    tin_drude_fit,
)
from processing.spectral.spectra import REFERENCE_GRID

# Johnson & Christy, Phys. Rev. B 6, 4370 (1972), Table I, and Phys. Rev. B 9,
# 5056 (1974), Table I: the row at 2.26 eV (548.6 nm).
JC_2_26_EV = {
    "Au": (0.43, 2.455),
    "Ag": (0.059, 3.586),
    "Cu": (1.02, 2.577),
    "Fe": (2.95, 2.93),
}


@pytest.mark.parametrize("metal", sorted(JC_2_26_EV))
def test_johnson_christy_table_row(metal: str) -> None:
    n, k = JC_2_26_EV[metal]
    eta = complex_index(metal, 1239.84 / 2.26)
    assert eta.real == pytest.approx(n, abs=0.011)
    assert eta.imag == pytest.approx(k, abs=0.011)


@pytest.mark.parametrize("metal, n, k", [("Au", 0.43, 2.45), ("Ag", 0.06, 3.6), ("Cu", 1.0, 2.6)])
def test_values_at_550nm(metal: str, n: float, k: float) -> None:
    eta = complex_index(metal, 550.0)
    assert eta.real == pytest.approx(n, abs=0.03)
    assert eta.imag == pytest.approx(k, abs=0.05)


def test_gold_reflects_red_not_blue() -> None:
    # normal incidence, from J&C: R(450 nm) ~ 0.41, R(650 nm) ~ 0.95
    r = fresnel_conductor(1.0, complex_index("Au", [450.0, 650.0]))
    assert r[0] < 0.45 and r[1] > 0.93
    # silver is nearly flat and high across the visible
    r_ag = fresnel_conductor(1.0, complex_index("Ag", REFERENCE_GRID.wavelengths))
    assert r_ag.min() > 0.85 and np.ptp(r_ag) < 0.1


@pytest.mark.parametrize("metal", METALS)
def test_every_metal_covers_the_visible_with_k_positive(metal: str) -> None:
    lo, hi = metal_wavelength_range(metal)
    assert lo <= 360.0 and hi >= 830.0
    eta = complex_index(metal, np.linspace(360, 830, 95))
    assert eta.dtype == np.complex128
    assert np.all(np.isfinite(eta)) and np.all(eta.imag > 0) and np.all(eta.real > 0)
    r = fresnel_conductor(1.0, eta)
    assert np.all((r > 0.3) & (r < 1.0))  # metals reflect strongly


def test_shape_is_preserved_and_names_are_flexible() -> None:
    wl = np.full((2, 3), 550.0)
    assert complex_index("au", wl).shape == (2, 3)
    assert complex_index("gold", 550.0) == complex_index("Au", 550.0)


def test_linear_interpolation_between_table_rows() -> None:
    a, b = complex_index("Au", [548.6, 582.1])
    mid = complex_index("Au", 0.5 * (548.6 + 582.1))
    assert mid == pytest.approx(0.5 * (a + b), abs=2e-3)


def test_sources() -> None:
    assert "Johnson and R. W. Christy" in metal_source("Au")
    assert "Rakic" in metal_source("Al")
    assert "Werner" in metal_source("Pt")
    assert "extrapolated" in metal_source("Sn") and "Golovashkin" in metal_source("Sn")


def test_out_of_range_and_unit_errors() -> None:
    with pytest.raises(ValueError, match=r"Au optical constants cover 187.9-1937 nm.*in nm"):
        complex_index("Au", 150.0)
    with pytest.raises(ValueError, match="in nm"):
        complex_index("Ag", 0.55)  # micrometres by mistake
    with pytest.raises(ValueError, match="NaN"):
        complex_index("Cu", [500.0, np.nan])
    with pytest.raises(ValueError, match="unknown metal 'Ti'.*Ag, Al, Au"):
        complex_index("Ti", 500.0)


# --- tin: Drude extrapolation of Golovashkin & Motulevich (1964) ---------------------------


# Golovashkin & Motulevich 1964, 293 K (refractiveindex.info main/Sn/Golovashkin-293K)
GOLOVASHKIN = [(730.0, 2.16, 6.35), (800.0, 2.38, 6.68), (900.0, 2.94, 7.28), (1000.0, 3.46, 7.40)]


def test_tin_drude_reproduces_its_fit_window() -> None:
    fit = tin_drude_fit()
    assert fit.window_um == (0.73, 1.0) and fit.n_points == 4 and fit.eps_inf == 1.0
    assert fit.rms_relative_residual < 0.06  # about 5 % (docs/materials.md)
    for wl, n, k in GOLOVASHKIN:
        eta = complex_index("Sn", wl)
        assert eta.real == pytest.approx(n, abs=0.15)
        assert eta.imag == pytest.approx(k, abs=0.35)


def test_tin_drude_is_a_drude_metal() -> None:
    fit = tin_drude_fit()
    wl = np.array([400.0, 550.0, 700.0])
    eta = drude_index(fit, wl)
    energy = 1239.841984 / wl
    eps = 1.0 - fit.plasma_ev**2 / (energy**2 + 1j * fit.damping_ev * energy)
    assert np.allclose(eta**2, eps, rtol=1e-12)
    # free electrons: n and k both rise with wavelength below the plasma frequency
    assert np.all(np.diff(eta.real) > 0) and np.all(np.diff(eta.imag) > 0)


def test_tin_visible_reflectance_within_stated_uncertainty() -> None:
    # docs/materials.md states R(normal) = 0.82 +- 0.12 in the visible; an
    # independent visible value (Filmetrics composite, 632.8 nm: n = 2.384,
    # k = 4.727) must lie inside that band.
    n, k = 2.384, 4.727
    r_independent = ((n - 1) ** 2 + k**2) / ((n + 1) ** 2 + k**2)
    r_model = float(fresnel_conductor(1.0, complex_index("Sn", 632.8)))
    assert r_model == pytest.approx(0.82, abs=0.02)
    assert abs(r_model - r_independent) <= 0.12


def test_tin_range() -> None:
    assert metal_wavelength_range("Sn") == (300.0, 1000.0)
    with pytest.raises(ValueError, match="Sn optical constants cover 300-1000 nm"):
        complex_index("Sn", 1200.0)
