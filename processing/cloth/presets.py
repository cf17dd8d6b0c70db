"""Cloth presets after Yasuda et al.: silk, cotton, tamamushi (shot silk), satin.

Silk and satin are filament yarns (elongated ellipsoids), cotton a spun yarn
(a rounder one), tamamushi a filament warp and a spun weft of two colours;
satin is a warp-faced weave.  The parameters (names as in
:func:`processing.cloth.model.cloth_material`) are chosen to give the looks
of the paper's figures; they are not measured values.  docs/cloth.md,
section "Presets", lists them and explains the tamamushi weights.

References
----------
.. [1] Yasuda, Yokoi, Toriwaki, Inagaki, "A shading model for cloth
   objects", IEEE Computer Graphics and Applications 12(6), 15-24 (1992),
   doi:10.1109/38.163621.
"""

from __future__ import annotations

from types import MappingProxyType
from typing import Any

from processing.cloth.model import Dye, Yarn, cloth_material
from processing.errors import InputError
from processing.materials.lobes import Material

__all__ = ["CLOTH_PRESETS", "CLOTH_PARAMETERS", "CLOTH_SOURCES", "build_cloth"]

_SILK = {"a_t": 0.05, "a_b": 0.45, "weft_a_t": 0.05, "weft_a_b": 0.45, "warp_kind": "filament",
         "weft_kind": "filament", "warp_fraction": 0.5, "specular": 0.2, "internal": 0.35, "diffuse": 0.45,
         "layers": 4, "rounding": 0.35, "n": 1.55, "scattering": 0.25,
         "warp_colour": "#a01830", "weft_colour": "#a01830",
         "weft_specular": "warp", "weft_internal": "warp", "weft_diffuse": "warp"}

#: Preset name -> every cloth parameter's default value (colours as sRGB hex strings).
CLOTH_PRESETS: MappingProxyType[str, dict[str, Any]] = MappingProxyType({
    "silk": dict(_SILK),
    "cotton": dict(_SILK, a_t=0.35, a_b=0.55, weft_a_t=0.35, weft_a_b=0.55, warp_kind="spun", weft_kind="spun",
                   specular=0.06, internal=0.12, diffuse=0.82, rounding=0.7),
    "tamamushi": dict(_SILK, a_b=0.5, weft_a_t=0.4, weft_a_b=0.55, weft_kind="spun", warp_colour="#10a040",
                      weft_colour="#c01070", specular=0.05, internal=0.9, diffuse=0.05, rounding=0.15,
                      weft_specular=0.04, weft_internal=0.16, weft_diffuse=0.8),
    "satin": dict(_SILK, a_t=0.03, a_b=0.3, weft_a_t=0.03, weft_a_b=0.3, warp_fraction=0.8, specular=0.3,
                  internal=0.35, diffuse=0.35, warp_colour="#d8c8a0", weft_colour="#d8c8a0"),
})

#: Preset name -> where its look comes from in Yasuda et al.
CLOTH_SOURCES: MappingProxyType[str, str] = MappingProxyType({
    "silk": "Yasuda et al. sec. 4: filament yarn, plain weave (Fig. 17)",
    "cotton": "Yasuda et al. sec. 4: spun yarn, plain weave (Fig. 17)",
    "tamamushi": "Yasuda et al. sec. 4: shot silk, filament warp and spun weft of two colours (Fig. 18)",
    "satin": "Yasuda et al. sec. 5: warp-faced weave of filament yarn (warp fraction 0.8)",
})

#: name -> (unit, description, valid range text, (low, high, low_open) or None for text values)
CLOTH_PARAMETERS: MappingProxyType[str, tuple[str, str, str, Any]] = MappingProxyType({
    "a_t": ("1", "warp ellipsoid semi-axis along the yarn (Yasuda eq. 1)", "[0.0001, 100]", (1e-4, 100.0, False)),
    "a_b": ("1", "warp ellipsoid semi-axis across the yarn", "[0.0001, 100]", (1e-4, 100.0, False)),
    "weft_a_t": ("1", "weft ellipsoid semi-axis along the weft yarn", "[0.0001, 100]", (1e-4, 100.0, False)),
    "weft_a_b": ("1", "weft ellipsoid semi-axis across the weft yarn", "[0.0001, 100]", (1e-4, 100.0, False)),
    "warp_kind": ("", "warp yarn: filament or spun", "filament | spun", None),
    "weft_kind": ("", "weft yarn: filament or spun", "filament | spun", None),
    "warp_fraction": ("1", "visible fraction of warp (plain weave 0.5)", "[0, 1]", (0.0, 1.0, False)),
    "specular": ("1", "weight of the specular (surface) term", "[0, 1]", (0.0, 1.0, False)),
    "internal": ("1", "weight of the internal (fibre-layer) term, eq. 4", "[0, 1]", (0.0, 1.0, False)),
    "diffuse": ("1", "weight of the diffuse (Lambert, dyed) term, eq. 5", "[0, 1]", (0.0, 1.0, False)),
    "layers": ("1", "number K of internal fibre layers", "integer 0..50", (0.0, 50.0, False)),
    "rounding": ("1", "how fast the layer ellipsoids grow round with depth", "[0, 1]", (0.0, 1.0, False)),
    "n": ("1", "refractive index of the fibre", "[1, 3]", (1.0, 3.0, False)),
    "scattering": ("1/layer", "Kubelka-Munk scattering per layer thickness", "(0, 1000]", (0.0, 1e3, True)),
    "warp_colour": ("sRGB", "warp dye, as the sRGB colour of its diffuse reflectance", "#rrggbb", None),
    "weft_colour": ("sRGB", "weft dye, as the sRGB colour of its diffuse reflectance", "#rrggbb", None),
    "weft_specular": ("1", "weft's specular weight (warp: as the warp's)", "[0, 1] | warp", None),
    "weft_internal": ("1", "weft's internal weight (warp: as the warp's)", "[0, 1] | warp", None),
    "weft_diffuse": ("1", "weft's diffuse weight (warp: as the warp's)", "[0, 1] | warp", None),
})

_WEFT_WEIGHTS = ("weft_specular", "weft_internal", "weft_diffuse")


def _weft_weights(params: dict[str, Any]) -> tuple[float, float, float] | None:
    """The weft's own (specular, internal, diffuse), or None when all three follow the warp's."""
    values = [params.get(key, "warp") for key in _WEFT_WEIGHTS]
    if all(str(v).strip().lower() == "warp" for v in values):
        return None
    out = []
    for key, v, warp in zip(_WEFT_WEIGHTS, values, ("specular", "internal", "diffuse")):
        if str(v).strip().lower() == "warp":
            out.append(float(params[warp]))
            continue
        try:
            out.append(float(v))
        except (TypeError, ValueError):
            raise InputError(f"{key}={v!r} is not valid; give a number in [0, 1] or 'warp' (as the warp's)") from None
    return (out[0], out[1], out[2])


def build_cloth(name: str, params: dict[str, Any], description: str = "") -> Material:
    """The cloth material of checked parameter values.

    Parameters
    ----------
    name
        Material name.
    params
        Every key of a preset (:data:`CLOTH_PRESETS`); numbers already range
        checked, colours as sRGB (hex or three numbers), weft weights as
        numbers or ``"warp"``.
    description
        Free text.

    Returns
    -------
    Material
        Built by :func:`processing.cloth.model.cloth_material`, with
        ``parameters`` holding ``params``.

    Raises
    ------
    ValueError
        A bad colour, yarn kind, weft weight or layer count, or values the
        cloth builder refuses.

    References
    ----------
    .. [1] Yasuda et al. (1992), doi:10.1109/38.163621.

    Examples
    --------
    >>> m = build_cloth("silk", CLOTH_PRESETS["silk"])
    >>> m.family, m.parameters["layers"], len(m.lobes)
    ('cloth', 4, 12)
    """
    scattering = float(params["scattering"])
    dyes = {}
    for key in ("warp_colour", "weft_colour"):
        try:
            dyes[key] = Dye.from_srgb(params[key], scattering)
        except ValueError as exc:
            raise InputError(f"{key}: {exc}") from None
    warp = Yarn(str(params["warp_kind"]), float(params["a_t"]), float(params["a_b"]), dyes["warp_colour"])
    weft = Yarn(str(params["weft_kind"]), float(params["weft_a_t"]), float(params["weft_a_b"]), dyes["weft_colour"])
    layers = float(params["layers"])
    if not layers.is_integer():
        raise InputError(f"layers must be a whole number 0..50, got {params['layers']!r}")
    return cloth_material(
        name, warp, weft, warp_fraction=float(params["warp_fraction"]), specular=float(params["specular"]),
        internal=float(params["internal"]), diffuse=float(params["diffuse"]), layers=int(layers),
        rounding=float(params["rounding"]), n=float(params["n"]), scattering=scattering,
        weft_weights=_weft_weights(params), description=description, parameters={**params, "layers": int(layers)},
    )
