"""The material registry: names, parameters, spec parsing, overrides and errors."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from processing.materials.alloys import alloy_weights
from processing.materials.lobes import Material
from processing.materials.presets import (
    MaterialError,
    ParameterInfo,
    get_material,
    list_materials,
    material_parameters,
    parse_material_spec,
    preset_source,
)
from processing.spectral.spectra import SpectralGrid

PRESETS = [
    "gold", "silver", "copper", "aluminium", "platinum", "iron", "zinc", "lead", "tin",
    "nami-shibuichi", "shiro-shibuichi", "jo-shibuichi", "nami-shibuichi-uchi-sanbu",
    "nami-shibuichi-soto-sanbu", "shakudo", "bronze", "urushi-black", "urushi-red",
]
CLOTH_PRESETS = ["silk", "cotton", "tamamushi", "satin"]   # tested in tests/cloth/test_cloth_model.py
WL = SpectralGrid(400, 700, 20).wavelengths


def test_list_materials_is_exactly_the_presets() -> None:
    assert list_materials() == PRESETS + CLOTH_PRESETS


@pytest.mark.parametrize("name", PRESETS)
def test_every_preset_builds_with_named_parameters(name: str) -> None:
    m = get_material(name)
    assert isinstance(m, Material) and m.name == name
    params = material_parameters(name)
    assert set(params) == set(m.parameters)
    for key, info in params.items():
        assert isinstance(info, ParameterInfo)
        assert info.value == m.parameters[key]
        assert info.description and info.valid
    assert m.family in ("metal", "alloy", "dielectric")
    assert any(lobe.mirror for lobe in m.lobes)  # every preset reflects its surroundings
    assert preset_source(name)


def test_alloy_presets_use_published_compositions() -> None:
    for name in ("nami-shibuichi", "shakudo", "bronze"):
        comp = {k: v for k, v in get_material(name).parameters.items() if k[0].isupper()}
        assert comp == pytest.approx(alloy_weights(name))


def test_tin_preset_states_its_extrapolation() -> None:
    assert "extrapolated" in preset_source("tin")


# --- parsing and overrides ------------------------------------------------------------------


def test_overrides_apply() -> None:
    m = get_material("gold:roughness=0.2,gloss=1,mirror=0,shadowing=smith")
    assert m.parameters["roughness"] == 0.2
    assert (m.lobes[0].weight, m.lobes[0].roughness, m.lobes[1].weight) == (1.0, 0.2, 0.0)
    m = get_material("  Gold : Mirror_Roughness = 0.05 , shadowing=Torrance-Sparrow ,")
    assert m.lobes[1].roughness == 0.05
    assert all(lobe.shadowing == "torrance-sparrow" for lobe in m.lobes)


def test_composition_override_replaces_composition() -> None:
    m = get_material("bronze:Cu=0.9,Sn=0.1")
    assert m.parameters["Cu"] == pytest.approx(0.9) and m.parameters["Sn"] == pytest.approx(0.1)
    m = get_material("bronze:cu=85,sn=10,pb=5")  # percent, symbols in any case, a third metal
    assert m.parameters["Pb"] == pytest.approx(0.05)
    m = get_material("shakudo:Cu=1")
    assert "Au" not in m.parameters and m.family == "metal"


def test_dielectric_overrides() -> None:
    m = get_material("urushi-red:n=1.52,mirror=0.1")
    assert m.parameters["n"] == 1.52 and m.lobes[2].weight == 0.1
    assert m.lobes[1].spectral.reflectance(1.0, [550.0])[0] == pytest.approx(((1.52 - 1) / 2.52) ** 2)


def test_material_parameters_accepts_spec() -> None:
    p = material_parameters("silver:roughness=0.3")
    assert p["roughness"].value == 0.3 and p["roughness"].unit == "RMS slope"
    assert "gloss + mirror <= 1" in p["gloss"].valid
    assert "diffuse + gloss + mirror <= 1" in material_parameters("urushi-black")["diffuse"].valid


def test_parse_material_spec() -> None:
    assert parse_material_spec("urushi_red") == ("urushi-red", {})
    assert parse_material_spec("gold:a=1,,b=2") == ("gold", {"a": "1", "b": "2"})


# --- errors ---------------------------------------------------------------------------------


def test_unknown_material_lists_valid_names() -> None:
    with pytest.raises(MaterialError) as exc:
        get_material("brass:roughness=0.1")
    msg = str(exc.value)
    assert "unknown material 'brass'" in msg and all(name in msg for name in PRESETS)
    assert isinstance(exc.value, ValueError)


def test_unknown_parameter_lists_valid_parameters() -> None:
    with pytest.raises(MaterialError, match=r"gold: unknown parameter 'shine'; valid parameters: "
                                            r"gloss, mirror, roughness, mirror_roughness, shadowing, Ag"):
        get_material("gold:shine=1")
    with pytest.raises(MaterialError, match=r"valid parameters: n, diffuse, gloss"):
        get_material("urushi-black:Cu=0.5")  # no composition for lacquer


@pytest.mark.parametrize(
    "spec, match",
    [
        ("gold:roughness=0", r"roughness=0 is out of range; valid range is \(0, 1\]"),
        ("gold:roughness=2", r"valid range is \(0, 1\]"),
        ("gold:gloss=-0.1", r"gloss=-0.1 is out of range; valid range is \[0, 1\]"),
        ("gold:gloss=nan", r"valid range is \[0, 1\]"),
        ("urushi-red:n=0.9", r"n=0.9 is out of range; valid range is \[1, 3\]"),
        ("gold:gloss=1", r"gloss=1 \+ mirror=0.4 = 1.4 exceeds 1"),
        ("urushi-red:diffuse=1", r"diffuse=1 \+ gloss=0.15 \+ mirror=0.15 = 1.3 exceeds 1"),
        ("gold:roughness=abc", r"roughness='abc' is not a number; valid range is \(0, 1\]"),
        ("bronze:Cu=lots", r"Cu='lots' is not a number; a metal fraction must be a number >= 0"),
        ("gold:roughness", r"cannot read 'roughness'; write parameters as key=value"),
        ("gold:=0.2", r"cannot read '=0.2'"),
        ("gold:roughness=0.1,Roughness=0.2", r"parameter 'Roughness' is given twice"),
        ("gold:shadowing=ggx", r"shadowing='ggx' is not valid; use one of: smith, torrance-sparrow"),
        ("bronze:Cu=-1", r"Cu=-1 is not valid; a metal fraction must be >= 0"),
        ("bronze:Cu=0,Sn=0", r"metal fractions sum to 0"),
        ("", r"non-empty string"),
        ("   ", r"non-empty string"),
    ],
)
def test_bad_values_state_the_problem(spec: str, match: str) -> None:
    with pytest.raises(MaterialError, match=match):
        get_material(spec)


# --- every preset's lobes stay physical ----------------------------------------------------------


@settings(max_examples=40, deadline=None)
@given(
    name=st.sampled_from(PRESETS),
    cos=st.one_of(st.just(0.0), st.just(1.0), st.floats(0.0, 1.0)),
)
def test_preset_lobe_reflectances_in_unit_interval(name: str, cos: float) -> None:
    for lobe in get_material(name).lobes:
        r = lobe.spectral.reflectance(cos, WL)
        assert r.shape == (WL.size,)
        assert np.all(np.isfinite(r)) and np.all((r >= 0) & (r <= 1))
        if cos == 0.0 and lobe.spectral.angle_dependent:
            assert np.all(r == pytest.approx(1.0, abs=1e-12))  # F -> 1 at 90 degrees


@settings(max_examples=40, deadline=None)
@given(
    name=st.sampled_from([p for p in PRESETS if not p.startswith("urushi")]),
    roughness=st.one_of(st.just(1e-5), st.just(1.0), st.floats(1e-5, 1.0)),
    gloss=st.floats(0.0, 1.0),
)
def test_overridden_metal_brdf_finite(name: str, roughness: float, gloss: float) -> None:
    from processing.materials.lobes import material_brdf

    m = get_material(f"{name}:roughness={roughness!r},gloss={gloss!r},mirror=0")
    cos = np.array([0.0, 1e-12, 0.3, 1.0])
    v = material_brdf(m, cos[:, None], cos[None, :], 0.99, 0.5, WL)
    assert np.all(np.isfinite(v)) and np.all(v >= 0)
    assert np.all(v[0] == 0) and np.all(v[:, 0] == 0)
