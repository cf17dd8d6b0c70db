"""Compositions of the alloys of Japanese metalwork and their materials (Matsuda et al., eq. (3)-(4)).

The colour signal of an alloy is the weighted sum of the colour signals of
its constituent metals, C_alloy = sum_j w_j C(n_j, k_j) with sum_j w_j = 1.
The compositions (the five shibuichi grades of Matsuda et al., Table 1;
shakudo after Oguchi 1983; tin bronze after Scott 1991) and the limits of
the model (no patina) are in docs/materials.md, section "Presets".

References
----------
.. [1] Matsuda, Tanaka, Ichikawa, Mochizuki, Muroya, Kitamura, "CG
   reproduction of a craft object based on a light reflection model", IPSJ
   technical report (no DOI), eq. (3)-(4) and Table 1.
.. [2] Oguchi, "Japanese shakudo: its history, properties and production
   from gold-containing alloys", Gold Bulletin 16(4), 125-132 (1983).
.. [3] Scott, "Metallography and Microstructure of Ancient and Historic
   Metals", Getty Conservation Institute (1991).
"""

from __future__ import annotations

from types import MappingProxyType
from typing import Any

from processing.errors import InputError
from processing.materials.lobes import Material
from processing.materials.metal_model import metal_material, normalise_composition

__all__ = ["ALLOY_COMPOSITIONS", "ALLOY_SOURCES", "alloy_weights", "alloy_names", "alloy_material"]

_TABLE1 = "Matsuda et al., Table 1"

#: Alloy name -> {chemical symbol: percent by mass}, as published.
ALLOY_COMPOSITIONS: MappingProxyType[str, MappingProxyType[str, float]] = MappingProxyType(
    {
        name: MappingProxyType(comp)
        for name, comp in {
            "nami-shibuichi": {"Ag": 25.0, "Cu": 74.9, "Au": 0.1},
            "shiro-shibuichi": {"Ag": 59.4, "Cu": 39.6, "Au": 1.0},
            "jo-shibuichi": {"Ag": 39.6, "Cu": 59.4, "Au": 1.0},
            "nami-shibuichi-uchi-sanbu": {"Ag": 29.7, "Cu": 69.3, "Au": 1.0},
            "nami-shibuichi-soto-sanbu": {"Ag": 22.7, "Cu": 76.2, "Au": 1.0},
            "shakudo": {"Cu": 96.0, "Au": 4.0},
            "bronze": {"Cu": 88.0, "Sn": 12.0},
        }.items()
    }
)

#: Alloy name -> source of its composition.
ALLOY_SOURCES: MappingProxyType[str, str] = MappingProxyType(
    {
        "nami-shibuichi": _TABLE1 + " (eq. 4)",
        "shiro-shibuichi": _TABLE1,
        "jo-shibuichi": _TABLE1,
        "nami-shibuichi-uchi-sanbu": _TABLE1,
        "nami-shibuichi-soto-sanbu": _TABLE1,
        "shakudo": "Oguchi, Gold Bulletin 16, 125-132 (1983): Cu with about 4 % Au",
        "bronze": "Scott, Metallography and Microstructure of Ancient and Historic Metals "
        "(Getty, 1991): tin bronze Cu 88 / Sn 12",
    }
)


def alloy_names() -> list[str]:
    """Names of the alloys in :data:`ALLOY_COMPOSITIONS`.

    Returns
    -------
    list of str
        The alloy names, in table order.

    Examples
    --------
    >>> "shakudo" in alloy_names()
    True
    """
    return list(ALLOY_COMPOSITIONS)


def _canonical(name: str) -> str:
    if not isinstance(name, str):
        raise InputError(f"alloy name must be a string, got {name!r}")
    key = "-".join(name.strip().lower().replace("_", " ").replace("-", " ").split())
    if key not in ALLOY_COMPOSITIONS:
        raise InputError(f"unknown alloy {name!r}; known alloys: {', '.join(ALLOY_COMPOSITIONS)}")
    return key


def alloy_weights(name: str) -> dict[str, float]:
    """Weights w_j of eq. (3) for a named alloy, normalised to sum 1.

    Parameters
    ----------
    name
        An alloy of :data:`ALLOY_COMPOSITIONS`; case, spaces and underscores
        are ignored ("Nami shibuichi uchi sanbu" works).

    Returns
    -------
    dict
        Chemical symbol -> weight.

    Raises
    ------
    ValueError
        Not a string, or an unknown alloy (the message lists the known ones).

    Examples
    --------
    >>> alloy_weights("nami-shibuichi")
    {'Ag': 0.25, 'Cu': 0.749, 'Au': 0.001}
    """
    weights = normalise_composition(ALLOY_COMPOSITIONS[_canonical(name)])
    return {sym: round(w, 15) for sym, w in weights.items()}


def alloy_material(name: str, composition: dict[str, float] | None = None, **params: Any) -> Material:
    """Material of a named alloy (eq. 2-4), optionally with another composition.

    Parameters
    ----------
    name
        Alloy name (see :func:`alloy_weights`).
    composition
        Symbol -> weight replacing the published composition (normalised).
    **params
        gloss, mirror, roughness, mirror_roughness, shadowing, description:
        passed to :func:`processing.materials.metal_model.metal_material`.

    Returns
    -------
    Material
        Family ``"alloy"`` (``"metal"`` for a one-metal composition).

    Raises
    ------
    ValueError
        An unknown alloy, a bad composition or a parameter out of range.

    References
    ----------
    .. [1] Matsuda et al., eq. (2)-(4) (no DOI).

    Examples
    --------
    >>> m = alloy_material("bronze")
    >>> m.family, round(m.parameters["Sn"], 2)
    ('alloy', 0.12)
    """
    key = _canonical(name)
    metals = alloy_weights(key) if composition is None else composition
    params.setdefault("description", f"{key}: {ALLOY_SOURCES[key]}")
    return metal_material(key, metals, **params)
