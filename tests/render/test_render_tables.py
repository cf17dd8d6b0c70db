"""Angular XYZ tables against direct spectral evaluation, and the albedo tables of sky light.

The reference for every table is the same spectral sum evaluated directly
(spectral factor at the exact angle, times the light, summed against the
colour-matching functions) or processing.materials.albedo's quadrature; the error
bound is the linear-interpolation bound h^2/8 max|f''|.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import settings as hsettings
from hypothesis import strategies as st

from processing.materials.albedo import directional_albedo
from processing.materials.dielectric_model import DielectricFresnel, urushi_red_reflectance
from processing.materials.metal_model import ConductorFresnel
from processing.materials.presets import get_material
from processing.spectral.display import spectra_to_xyz, xyz_scale
from processing.spectral.spectra import SpectralGrid, light_spectrum
from render.backends import ALBEDO_GRAZING_COS, ALBEDO_TABLE_SIZE, _albedo_spectra
from render.tables import AngleTable, spectral_factor_table, table_error, table_index

GRID = SpectralGrid(400, 700, 5)
D65 = light_spectrum("D65", GRID)
K = xyz_scale(D65, GRID)


def direct(spectral, light, cos):
    """k * sum S(cos, lambda) E(lambda) cmf(lambda) dlambda, evaluated at each cos."""
    return K * spectra_to_xyz(spectral.reflectance(cos, GRID.wavelengths) * light, GRID)


FACTORS = {
    "gold": ConductorFresnel({"Au": 1.0}),
    "shakudo": ConductorFresnel({"Cu": 0.96, "Au": 0.04}),
    "silver": ConductorFresnel({"Ag": 1.0}),
    "lacquer n=1.5": DielectricFresnel(1.5),
}


@pytest.mark.parametrize("name", FACTORS)
@pytest.mark.parametrize("light", ["D65", "A", "F2"])
def test_fresnel_tables_match_direct_evaluation(name, light):
    e = light_spectrum(light, GRID)
    factor = FACTORS[name]
    errors = {}
    for size in (256, 1024):
        table = spectral_factor_table(factor, e, GRID, K, size)
        assert table.values.shape == (size, 3)
        err, rel = table_error(table, lambda c: direct(factor, e, c), n_test=4001)
        errors[size] = err
        assert rel < (2e-4 if size == 256 else 2e-5)
    # linear interpolation: error ~ h^2, so 4x the nodes gives ~16x less error
    assert 8.0 < errors[256] / max(errors[1024], 1e-12) < 32.0


def test_constant_factor_needs_one_row_and_is_exact():
    pigment = urushi_red_reflectance()
    table = spectral_factor_table(pigment, D65, GRID, K, 512)
    assert table.constant and table.values.shape == (1, 3)
    cos = np.array([0.0, 0.3, 1.0])
    np.testing.assert_allclose(table.lookup(cos), direct(pigment, D65, cos), rtol=1e-6)


def test_white_lambert_normalisation_in_table_units():
    """k XYZ(E / pi) has Y = 1, so the table of a white factor has Y = pi."""

    class White:
        angle_dependent = False

        def reflectance(self, cos, wl):
            return np.ones(np.shape(cos) + (len(wl),))

    table = spectral_factor_table(White(), D65, GRID, K, 256)
    assert table.values[0, 1] == pytest.approx(np.pi, rel=1e-12)


class FlatFresnel:
    """Fresnel reflectance of one complex index at every wavelength."""

    angle_dependent = True

    def __init__(self, eta):
        self.eta = eta

    def reflectance(self, cos, wl):
        from processing.materials.fresnel import fresnel_conductor

        f = fresnel_conductor(np.asarray(cos, float), self.eta)
        return np.repeat(f[..., None], len(wl), axis=-1)


@hsettings(max_examples=40, deadline=None)
@given(eta=st.one_of(
    st.builds(complex, st.floats(1.05, 5.0), st.floats(0.0, 200.0)),      # dielectrics, k -> 0, absorbing
    st.builds(complex, st.floats(0.02, 1.0), st.floats(1.0, 200.0)),      # metals (n < 1), up to huge k
))
def test_tables_stay_accurate_from_dielectrics_to_huge_k(eta):
    factor = FlatFresnel(eta)
    table = spectral_factor_table(factor, D65, GRID, K, 512)
    err, rel = table_error(table, lambda c: direct(factor, D65, c), n_test=2049)
    assert np.all(np.isfinite(table.values))
    # in units of reflectance (a white table has Y = pi): below 2e-3 even for k = 200,
    # whose F drops steeply within cos < 0.01 of grazing
    assert err / np.pi < 2e-3
    # grazing incidence: F = 1 for every index, the table row equals the light's white * pi
    np.testing.assert_allclose(table.values[0], K * spectra_to_xyz(D65, GRID), rtol=1e-9)


def test_table_index_clamps_and_hits_the_last_node():
    ix = table_index(np.array([-0.5, 0.0, 0.25, 1.0, 1.5], dtype=np.float32), 5)
    assert ix.row.tolist() == [0, 0, 1, 3, 3]
    np.testing.assert_allclose(ix.frac, [0.0, 0.0, 0.0, 1.0, 1.0])


def test_linear_function_is_reproduced_exactly_and_tables_add():
    f = lambda c: np.stack([2 * c + 1, -c, 0.5 * np.ones_like(c)], axis=-1)
    t = AngleTable.from_function(f, 7)
    c = np.random.default_rng(0).random(100)
    np.testing.assert_allclose(t.lookup(c), f(c), atol=1e-6)
    np.testing.assert_allclose((t + t).lookup(c), 2 * f(c), atol=2e-6)
    const = AngleTable(np.array([[1.0, 2.0, 3.0]]))
    np.testing.assert_allclose((t + const).lookup(c), f(c) + [1, 2, 3], atol=2e-6)
    np.testing.assert_allclose(t.lookup_channels(c), f(c).T, atol=1e-6)
    with pytest.raises(ValueError, match="cannot add"):
        t + AngleTable.from_function(f, 9)


@pytest.mark.parametrize("spec", ["gold", "urushi-red", "shakudo:roughness=1", "silver:roughness=0.03"])
def test_albedo_tables_of_sky_light_match_the_quadrature(spec):
    """The renderer's sky-light albedo table (65 nodes over cos_o) against processing.materials.albedo."""
    grid = SpectralGrid(400, 700, 20)
    nodes = np.linspace(0.0, 1.0, ALBEDO_TABLE_SIZE)
    nodes[0] = ALBEDO_GRAZING_COS
    cos = np.concatenate([np.geomspace(1e-3, 0.05, 12), np.linspace(0.05, 1.0, 60)])
    for lobe in get_material(spec).lobes:
        if lobe.mirror or lobe.weight == 0:
            continue
        table = AngleTable(_albedo_spectra(lobe, nodes, grid))
        exact = directional_albedo(lobe, cos, grid.wavelengths)
        err = np.abs(table.lookup(cos) - exact)
        assert err[cos > 0.05].max() < 1e-3
        assert err.max() < 0.02
        assert np.all(table.values <= lobe.weight + 1e-6)      # energy: albedo <= weight
