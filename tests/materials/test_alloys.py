"""Alloy compositions (Matsuda Table 1) and the weighted Fresnel of eq. (3)-(4)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from processing.materials.alloys import ALLOY_COMPOSITIONS, ALLOY_SOURCES, alloy_material, alloy_names, alloy_weights
from processing.materials.fresnel import fresnel_conductor
from processing.materials.metal_model import ConductorFresnel
from processing.materials.optical_constants import complex_index
from processing.spectral.spectra import SpectralGrid

WL = SpectralGrid(400, 700, 20).wavelengths

TABLE_1 = {  # Ag / Cu / Au percent, Matsuda et al. Table 1
    "nami-shibuichi": (25.0, 74.9, 0.1),
    "shiro-shibuichi": (59.4, 39.6, 1.0),
    "jo-shibuichi": (39.6, 59.4, 1.0),
    "nami-shibuichi-uchi-sanbu": (29.7, 69.3, 1.0),
    "nami-shibuichi-soto-sanbu": (22.7, 76.2, 1.0),
}


@pytest.mark.parametrize("name", sorted(TABLE_1))
def test_table_1(name: str) -> None:
    ag, cu, au = TABLE_1[name]
    assert dict(ALLOY_COMPOSITIONS[name]) == {"Ag": ag, "Cu": cu, "Au": au}
    w = alloy_weights(name)
    total = ag + cu + au
    assert w == pytest.approx({"Ag": ag / total, "Cu": cu / total, "Au": au / total}, abs=1e-12)
    assert sum(w.values()) == pytest.approx(1.0, abs=1e-12)
    assert "Table 1" in ALLOY_SOURCES[name]


def test_shakudo_and_bronze() -> None:
    assert alloy_weights("shakudo") == pytest.approx({"Cu": 0.96, "Au": 0.04})
    assert alloy_weights("bronze") == pytest.approx({"Cu": 0.88, "Sn": 0.12})
    assert "Oguchi" in ALLOY_SOURCES["shakudo"] and "Scott" in ALLOY_SOURCES["bronze"]


def test_equation_4_nami_shibuichi() -> None:
    cos = np.array([1.0, 0.5, 0.1, 0.0])
    expected = sum(
        w * fresnel_conductor(cos[:, None], complex_index(m, WL)[None, :])
        for m, w in (("Ag", 0.250), ("Cu", 0.749), ("Au", 0.001))
    )
    f = alloy_material("nami-shibuichi").lobes[0].spectral
    assert np.allclose(f.reflectance(cos, WL), expected, atol=1e-12)


def test_more_silver_reflects_more_blue() -> None:
    # Ag reflects blue far better than Cu, so shiro (59 % Ag) > jo (40 %) > nami (25 %)
    r = {n: alloy_material(n).lobes[0].spectral.reflectance(1.0, [450.0])[0] for n in TABLE_1}
    assert r["shiro-shibuichi"] > r["jo-shibuichi"] > r["nami-shibuichi"] > r["nami-shibuichi-soto-sanbu"]


@settings(max_examples=60, deadline=None)
@given(
    w=st.lists(st.floats(0.0, 1.0), min_size=3, max_size=3).filter(lambda v: sum(v) > 1e-6),
    cos=st.one_of(st.just(0.0), st.just(1.0), st.floats(0.0, 1.0)),
)
def test_alloy_reflectance_is_convex_combination(w: list[float], cos: float) -> None:
    metals = dict(zip(("Ag", "Cu", "Au"), w))
    r = ConductorFresnel(metals).reflectance(cos, WL)
    parts = np.stack([ConductorFresnel({m: 1.0}).reflectance(cos, WL) for m in metals])
    assert np.all(np.isfinite(r)) and np.all((r >= 0) & (r <= 1))
    assert np.all(r >= parts.min(axis=0) - 1e-12) and np.all(r <= parts.max(axis=0) + 1e-12)
    if cos == 0.0:
        assert np.all(r == pytest.approx(1.0, abs=1e-12))


def test_names_are_normalised() -> None:
    assert alloy_weights("Nami Shibuichi Uchi Sanbu") == alloy_weights("nami-shibuichi-uchi-sanbu")
    assert alloy_weights("JO_SHIBUICHI") == alloy_weights("jo-shibuichi")
    assert set(alloy_names()) == set(TABLE_1) | {"shakudo", "bronze"}


def test_unknown_alloy_lists_known() -> None:
    with pytest.raises(ValueError, match=r"unknown alloy 'brass'.*nami-shibuichi.*bronze"):
        alloy_weights("brass")


def test_alloy_material_composition_override() -> None:
    m = alloy_material("bronze", {"Cu": 90, "Sn": 10}, gloss=0.5, mirror=0.5)
    assert m.parameters["Cu"] == pytest.approx(0.9) and m.parameters["Sn"] == pytest.approx(0.1)
    assert m.family == "alloy" and m.lobes[1].weight == 0.5
