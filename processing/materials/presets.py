"""The registry of material presets: metals, alloys, lacquers and cloths, built from spec strings.

The object of Matsuda et al. ("Twelve Hawks", Suzuki Chokichi, 1893) is
bronze inlaid with gold, silver, shakudo and oborogin (shibuichi), with an
urushi-lacquered beak; these presets cover it, a few more metals and the
cloths of Yasuda et al.  A spec string names a preset and overrides its
parameters::

    gold
    gold:roughness=0.2,gloss=1,mirror=0,shadowing=smith
    bronze:Cu=0.9,Sn=0.1
    urushi-red:n=1.52,mirror=0.1

Parameters, their defaults and sources are listed in docs/materials.md,
sections "Using a preset", "Parameters" and "Presets".

References
----------
.. [1] Matsuda, Tanaka, Ichikawa, Mochizuki, Muroya, Kitamura, "CG
   reproduction of a craft object based on a light reflection model", IPSJ
   technical report (no DOI).
.. [2] Yasuda, Yokoi, Toriwaki, Inagaki, "A shading model for cloth
   objects", IEEE Computer Graphics and Applications 12(6), 15-24 (1992),
   doi:10.1109/38.163621.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

from processing.cloth.presets import CLOTH_PARAMETERS, CLOTH_PRESETS, CLOTH_SOURCES, build_cloth
from processing.errors import InputError
from processing.materials.alloys import ALLOY_SOURCES, alloy_weights
from processing.materials.dielectric_model import (
    PigmentReflectance,
    dielectric_material,
    urushi_black_reflectance,
    urushi_red_reflectance,
)
from processing.materials.lobes import Material
from processing.materials.metal_model import SHADOWING_MODELS, metal_material, normalise_composition
from processing.materials.microfacet import MIN_ROUGHNESS, check_roughness
from processing.materials.optical_constants import METALS, metal_source

__all__ = [
    "MaterialError",
    "ParameterInfo",
    "check_material_spec",
    "list_materials",
    "material_parameters",
    "get_material",
    "parse_material_spec",
    "preset_source",
]


class MaterialError(InputError):
    """A material spec names an unknown material or parameter, or a bad value.

    An :class:`processing.errors.InputError` (a ``ValueError``); the message
    lists the valid names, the valid parameters or the valid range.
    """


@dataclass(frozen=True)
class ParameterInfo:
    """One named parameter of a material model.

    Attributes
    ----------
    value
        Current value (float, or a string for ``shadowing``).
    unit
        Unit (``"1"`` for dimensionless weights).
    description
        What the parameter is, with the equation of Matsuda et al.
    valid
        The accepted values, e.g. ``"[0, 1]"``.
    """

    value: Any
    unit: str
    description: str
    valid: str


@dataclass(frozen=True)
class _Preset:
    family: str  # "metal" (pure metals and alloys), "dielectric" or "cloth"
    defaults: dict[str, Any]
    composition: dict[str, float] | None = None
    pigment: Callable[[], PigmentReflectance] | None = None
    source: str = ""


# (gloss, mirror, roughness): a polished craft surface keeps a sharp mirror
# image (mirror lobe, sigma1 = 0.01) over a soft gloss lobe; softer and
# less polished metals get more gloss and a rougher lobe.
def _metal(sym: str, gloss: float, mirror: float, roughness: float) -> _Preset:
    return _Preset(
        "metal",
        {"gloss": gloss, "mirror": mirror, "roughness": roughness, "mirror_roughness": 0.01,
         "shadowing": "smith"},
        composition={sym: 1.0},
        source=metal_source(sym),
    )


def _alloy(name: str, gloss: float, mirror: float, roughness: float) -> _Preset:
    return _Preset(
        "metal",
        {"gloss": gloss, "mirror": mirror, "roughness": roughness, "mirror_roughness": 0.01,
         "shadowing": "smith"},
        composition=alloy_weights(name),
        source=ALLOY_SOURCES[name],
    )


def _lacquer(pigment: Callable[[], PigmentReflectance], diffuse: float, gloss: float,
             mirror: float, source: str) -> _Preset:
    return _Preset(
        "dielectric",
        {"n": 1.5, "diffuse": diffuse, "gloss": gloss, "roughness": 0.08, "mirror": mirror,
         "mirror_roughness": 0.01, "shadowing": "smith"},
        pigment=pigment,
        source=source,
    )


_PRESETS: MappingProxyType[str, _Preset] = MappingProxyType(
    {
        "gold": _metal("Au", 0.6, 0.4, 0.10),
        "silver": _metal("Ag", 0.6, 0.4, 0.10),
        "copper": _metal("Cu", 0.6, 0.4, 0.10),
        "aluminium": _metal("Al", 0.7, 0.3, 0.12),
        "platinum": _metal("Pt", 0.6, 0.4, 0.10),
        "iron": _metal("Fe", 0.8, 0.2, 0.20),
        "zinc": _metal("Zn", 0.8, 0.2, 0.20),
        "lead": _metal("Pb", 0.9, 0.1, 0.25),
        "tin": _metal("Sn", 0.8, 0.2, 0.15),
        "nami-shibuichi": _alloy("nami-shibuichi", 0.7, 0.3, 0.15),
        "shiro-shibuichi": _alloy("shiro-shibuichi", 0.7, 0.3, 0.15),
        "jo-shibuichi": _alloy("jo-shibuichi", 0.7, 0.3, 0.15),
        "nami-shibuichi-uchi-sanbu": _alloy("nami-shibuichi-uchi-sanbu", 0.7, 0.3, 0.15),
        "nami-shibuichi-soto-sanbu": _alloy("nami-shibuichi-soto-sanbu", 0.7, 0.3, 0.15),
        "shakudo": _alloy("shakudo", 0.6, 0.4, 0.10),
        "bronze": _alloy("bronze", 0.7, 0.3, 0.15),
        "urushi-black": _lacquer(
            urushi_black_reflectance, 0.5, 0.25, 0.25,
            "black urushi: parametric body reflectance 1-2 % (docs/materials.md), n = 1.5",
        ),
        "urushi-red": _lacquer(
            urushi_red_reflectance, 0.7, 0.15, 0.15,
            "red urushi (vermilion): parametric body reflectance with the HgS band edge "
            "at 600 nm (docs/materials.md), n = 1.5",
        ),
        **{name: _Preset("cloth", dict(values), source=CLOTH_SOURCES[name])
           for name, values in CLOTH_PRESETS.items()},
    }
)

_COMMON_INFO: dict[str, tuple[str, str, str]] = {
    "gloss": ("1", "weight of the gloss lobe (alpha in Matsuda eq. 2, beta in eq. 5)", "[0, 1]"),
    "mirror": ("1", "weight of the mirror lobe, which also reflects the environment "
               "(beta in eq. 2, gamma in eq. 5)", "[0, 1]"),
    "roughness": ("RMS slope", "Beckmann RMS slope sigma0 of the gloss lobe", f"[{MIN_ROUGHNESS:g}, 1]"),
    "mirror_roughness": ("RMS slope", "Beckmann RMS slope sigma1 of the mirror lobe "
                         "(-> 1e-05: perfect mirror)", f"[{MIN_ROUGHNESS:g}, 1]"),
    "shadowing": ("", "shadowing-masking term G", " | ".join(SHADOWING_MODELS)),
    "n": ("1", "real refractive index of the binder (Fresnel term of eq. 5)", "[1, 3]"),
    "diffuse": ("1", "weight of the Lambert lobe with the pigment reflectance S "
                "(alpha in eq. 5)", "[0, 1]"),
}

_RANGES: dict[str, tuple[float, float, bool]] = {
    # name: (low, high, low_is_open)
    "gloss": (0.0, 1.0, False),
    "mirror": (0.0, 1.0, False),
    "roughness": (0.0, 1.0, True),          # and >= MIN_ROUGHNESS (1e-5): _parameter_value
    "mirror_roughness": (0.0, 1.0, True),
    "n": (1.0, 3.0, False),
    "diffuse": (0.0, 1.0, False),
}


def list_materials() -> list[str]:
    """Names of all presets, in registry order.

    Returns
    -------
    list of str
        Metals, alloys, lacquers, then cloths.

    Examples
    --------
    >>> list_materials()[:3]
    ['gold', 'silver', 'copper']
    """
    return list(_PRESETS)


def preset_source(name: str) -> str:
    """Source of a preset's optical data or composition.

    Parameters
    ----------
    name
        A preset name (case, spaces and underscores ignored).

    Returns
    -------
    str
        The citation or description of the source.

    Raises
    ------
    MaterialError
        Unknown preset (the message lists the valid names).

    Examples
    --------
    >>> "Table 1" in preset_source("jo-shibuichi")
    True
    """
    return _PRESETS[_canonical_name(name)].source


def _canonical_name(name: str) -> str:
    key = "-".join(str(name).strip().lower().replace("_", " ").replace("-", " ").split())
    if key not in _PRESETS:
        raise MaterialError(f"unknown material {name!r}; valid materials: {', '.join(_PRESETS)}")
    return key


def _valid_keys(preset: _Preset) -> list[str]:
    keys = list(preset.defaults)
    if preset.family == "metal":
        keys += list(METALS)
    return keys


def parse_material_spec(spec: str) -> tuple[str, dict[str, str]]:
    """Split ``"name:key=value,..."`` into the preset name and raw overrides.

    Parameters
    ----------
    spec
        ``"name"`` or ``"name:key=value,key=value"``.

    Returns
    -------
    name : str
        The canonical preset name.
    overrides : dict of str to str
        Parameter names as spelt in the spec, values as strings (unchecked).

    Raises
    ------
    MaterialError
        An empty spec, an unknown preset, an item that is not ``key=value``,
        or a parameter given twice.

    Examples
    --------
    >>> parse_material_spec("gold: roughness=0.2, gloss=1")
    ('gold', {'roughness': '0.2', 'gloss': '1'})
    """
    if not isinstance(spec, str) or not spec.strip():
        raise MaterialError(
            f"material spec must be a non-empty string such as 'gold' or 'gold:roughness=0.2', "
            f"got {spec!r}; valid materials: {', '.join(_PRESETS)}"
        )
    head, _, tail = spec.partition(":")
    name = _canonical_name(head)
    overrides: dict[str, str] = {}
    for item in tail.split(","):
        item = item.strip()
        if not item:
            continue
        key, eq, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if not eq or not key or not value:
            raise MaterialError(
                f"{name}: cannot read {item!r}; write parameters as key=value, "
                f"e.g. {name}:roughness=0.2"
            )
        if key.lower() in (k.lower() for k in overrides):
            raise MaterialError(f"{name}: parameter {key!r} is given twice")
        overrides[key] = value
    return name, overrides


def _ranges(preset: _Preset) -> dict[str, tuple[float, float, bool]]:
    if preset.family == "cloth":
        return {k: v[3] for k, v in CLOTH_PARAMETERS.items() if v[3] is not None}
    return _RANGES


def _metal_fraction(name: str, canon: str, text: str) -> float:
    """The metal fraction ``text`` of an override as a float >= 0."""
    try:
        value = float(text)
    except ValueError:
        hint = "a metal fraction must be a number >= 0"
        raise MaterialError(f"{name}: {canon}={text!r} is not a number; {hint}") from None
    if not (math.isfinite(value) and value >= 0):
        raise MaterialError(
            f"{name}: {canon}={text} is not valid; a metal fraction must be >= 0 "
            "(fractions or percent, normalised to sum 1)"
        )
    return value


def _parameter_value(name: str, preset: _Preset, canon: str, text: str) -> Any:
    """The value of the model parameter ``canon`` given as ``text``, checked against its range."""
    if preset.family == "cloth" and CLOTH_PARAMETERS[canon][3] is None:
        return text        # yarn kinds and colours: checked by the builder
    if canon == "shadowing":
        if text.lower() not in SHADOWING_MODELS:
            raise MaterialError(
                f"{name}: shadowing={text!r} is not valid; use one of: {', '.join(SHADOWING_MODELS)}"
            )
        return text.lower()
    try:
        value = float(text)
    except ValueError:
        lo, hi, open_low = _ranges(preset)[canon]
        hint = f"valid range is {'(' if open_low else '['}{lo:g}, {hi:g}]"
        raise MaterialError(f"{name}: {canon}={text!r} is not a number; {hint}") from None
    lo, hi, open_low = _ranges(preset)[canon]
    ok = math.isfinite(value) and (value > lo if open_low else value >= lo) and value <= hi
    if not ok:
        rng = f"({lo:g}, {hi:g}]" if open_low else f"[{lo:g}, {hi:g}]"
        raise MaterialError(f"{name}: {canon}={text} is out of range; valid range is {rng}")
    if canon in ("roughness", "mirror_roughness") and preset.family != "cloth":
        try:
            check_roughness(canon, value)       # the floor below which the microfacet lobe is not evaluated
        except InputError as exc:
            raise MaterialError(f"{name}: {exc}") from None
    return value


def _check_energy(name: str, preset: _Preset, params: dict[str, Any]) -> None:
    """Refuse lobe weights whose sum exceeds 1 (energy conservation)."""
    energy_keys = {"dielectric": ("diffuse", "gloss", "mirror"), "cloth": ("specular", "internal", "diffuse")}.get(
        preset.family, ("gloss", "mirror"))
    total = sum(float(params[k]) for k in energy_keys)
    if total > 1.0 + 1e-12:
        terms = " + ".join(f"{k}={params[k]:g}" for k in energy_keys)
        raise MaterialError(
            f"{name}: {terms} = {total:g} exceeds 1 (energy conservation); valid range of the sum "
            f"is [0, 1], e.g. lower {energy_keys[-1]}"
        )


def _check_composition(name: str, composition: dict[str, float]) -> None:
    """Refuse a composition whose shares cannot be normalised to sum 1 (all zero)."""
    if not any(w > 0 for w in composition.values()):
        raise MaterialError(f"{name}: the metal fractions sum to 0; give at least one positive fraction")
    try:
        shares = normalise_composition(composition)
    except ValueError as exc:
        raise MaterialError(f"{name}: {exc}") from None
    if not all(0.0 < w <= 1.0 for w in shares.values()):      # cannot happen with finite weights >= 0
        raise MaterialError(f"{name}: the metal fractions {composition} do not normalise to shares in [0, 1]")


def _resolve(spec: str) -> tuple[str, _Preset, dict[str, Any], dict[str, float] | None]:
    """Preset name, preset, parameter values and composition override of ``spec``, all checked."""
    name, raw = parse_material_spec(spec)
    preset = _PRESETS[name]
    valid = _valid_keys(preset)
    lookup = {k.lower(): k for k in valid}
    params = dict(preset.defaults)
    composition: dict[str, float] | None = None
    for key, text in raw.items():
        canon = lookup.get(key.lower())
        if canon is None:
            raise MaterialError(
                f"{name}: unknown parameter {key!r}; valid parameters: {', '.join(valid)}"
            )
        if canon in METALS:
            composition = {} if composition is None else composition
            composition[canon] = _metal_fraction(name, canon, text)
            continue
        params[canon] = _parameter_value(name, preset, canon, text)
    if composition is not None:
        _check_composition(name, composition)
    _check_energy(name, preset, params)
    return name, preset, params, composition


def check_material_spec(spec: str) -> str:
    """Check ``spec`` as :func:`get_material` does, without building the material.

    The one check of a spec for every reader of one (``kogei materials``, ``render --material``, the
    object-materials document): a known preset, known parameters, values in range (roughness in
    [1e-5, 1], see :data:`processing.materials.microfacet.MIN_ROUGHNESS`), metal fractions finite, >= 0
    and with a positive sum (normalised to shares in [0, 1] without overflow), lobe weights summing to at
    most 1.

    Parameters
    ----------
    spec
        ``"name"`` or ``"name:key=value,key=value"``.

    Returns
    -------
    str
        The canonical preset name.

    Raises
    ------
    MaterialError
        As :func:`get_material`.

    Examples
    --------
    >>> check_material_spec("Nami shibuichi:Ag=1e308,Cu=1e308")
    'nami-shibuichi'
    """
    return _resolve(spec)[0]


def get_material(spec: str) -> Material:
    """Build the material named by ``spec``.

    Parameters
    ----------
    spec
        ``"name"`` or ``"name:key=value,key=value"`` with a name of
        :func:`list_materials` and keys of :func:`material_parameters`.
        Metals and alloys accept a composition in chemical symbols (fractions
        or percent, normalised): when any symbol is given, the composition is
        exactly the symbols given (``bronze:Cu=0.9,Sn=0.1``).

    Returns
    -------
    Material
        With ``parameters`` holding every parameter's value.

    Raises
    ------
    MaterialError
        Unknown material (the message lists the valid names), unknown
        parameter (lists the valid parameters) or a value out of range
        (states the range).

    References
    ----------
    .. [1] Matsuda et al., eq. (2)-(5) (no DOI).
    .. [2] Yasuda, Yokoi, Toriwaki, Inagaki, IEEE CG&A 12(6), 15-24 (1992),
       doi:10.1109/38.163621.

    Examples
    --------
    >>> m = get_material("gold:roughness=0.2,gloss=1,mirror=0")
    >>> m.parameters["roughness"], m.lobes[0].weight, m.lobes[1].weight
    (0.2, 1.0, 0.0)
    """
    name, preset, params, composition = _resolve(spec)
    try:
        if preset.family == "cloth":
            return build_cloth(name, params, description=preset.source)
        if preset.family == "metal":
            metals = composition if composition is not None else dict(preset.composition or {})
            return metal_material(name, metals, description=preset.source, **params)
        assert preset.pigment is not None
        return dielectric_material(name, preset.pigment(), description=preset.source, **params)
    except MaterialError:
        raise
    except ValueError as exc:
        raise MaterialError(f"{name}: {exc}") from None


def material_parameters(name: str) -> dict[str, ParameterInfo]:
    """Every named parameter of a preset (or of a spec with overrides).

    Parameters
    ----------
    name
        A preset name or a spec as accepted by :func:`get_material`.

    Returns
    -------
    dict
        Parameter name -> :class:`ParameterInfo`; the same keys as
        ``get_material(name).parameters``.

    Raises
    ------
    MaterialError
        As :func:`get_material`.

    Examples
    --------
    >>> p = material_parameters("gold")
    >>> p["roughness"].value, p["roughness"].unit, p["Au"].value
    (0.1, 'RMS slope', 1.0)
    """
    material = get_material(name)
    out: dict[str, ParameterInfo] = {}
    for key, value in material.parameters.items():
        if key in METALS:
            out[key] = ParameterInfo(
                value, "mass fraction",
                f"weight w of {key} in Matsuda eq. (3)-(4), normalised to sum 1",
                ">= 0; any metal of " + ", ".join(METALS),
            )
        elif material.family == "cloth":
            unit, desc, valid, _ = CLOTH_PARAMETERS[key]
            if key in ("specular", "internal", "diffuse"):
                valid += ", specular + internal + diffuse <= 1"
            out[key] = ParameterInfo(value, unit, desc, valid)
        else:
            unit, desc, valid = _COMMON_INFO[key]
            if key in ("gloss", "mirror") and material.family != "dielectric":
                valid += ", gloss + mirror <= 1"
            if key in ("diffuse", "gloss", "mirror") and material.family == "dielectric":
                valid += ", diffuse + gloss + mirror <= 1"
            out[key] = ParameterInfo(value, unit, desc, valid)
    return out
