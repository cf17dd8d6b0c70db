"""Reflection model of metals and alloys: Matsuda et al., eq. (1)-(4).

The specular colour of a metal is the unpolarised Fresnel reflectance of its
complex index eta(lambda) = n + i k, evaluated at theta_d, the angle between
the light and the half vector.  The colour signal (eq. 2) is

    [ alpha F(theta_d) D(h; sigma0) G / (4 cos_i cos_o)
      + beta F(theta_d) mirror(sigma1) ] E(lambda) cos_i

with a gloss lobe (alpha = ``gloss``) and a mirror lobe (beta = ``mirror``,
sigma1 -> 0) that also reflects the environment.  An alloy (eq. 3-4)
replaces F by sum_j w_j F(eta_j), sum_j w_j = 1.  With ``gloss=1,
mirror=0`` and Smith G this is the rough-conductor BRDF of Walter et al.
(docs/materials.md, introduction).

References
----------
.. [1] Matsuda, Tanaka, Ichikawa, Mochizuki, Muroya, Kitamura, "CG
   reproduction of a craft object based on a light reflection model", IPSJ
   technical report (no DOI), eq. (1)-(4).
.. [2] Walter, Marschner, Li, Torrance, "Microfacet models for refraction
   through rough surfaces", EGSR 2007, doi:10.2312/EGWR/EGSR07/195-206.
.. [3] Torrance & Sparrow, "Theory for off-specular reflection from
   roughened surfaces", JOSA 57(9), 1105-1114 (1967),
   doi:10.1364/JOSA.57.001105.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.errors import InputError
from processing.materials.fresnel import fresnel_conductor
from processing.materials.lobes import Lobe, Material, checked_parameter, checked_roughness
from processing.materials.optical_constants import canonical_metal, complex_index

__all__ = [
    "ConductorFresnel",
    "metal_material",
    "SHADOWING_MODELS",
    "normalise_composition",
    "check_shadowing",
]

#: Shadowing terms accepted by the material builders (both keep the
#: directional albedo <= 1).
SHADOWING_MODELS: tuple[str, ...] = ("smith", "torrance-sparrow")

_MAX_CACHED_GRIDS = 8


def normalise_composition(metals: Mapping[str, float]) -> dict[str, float]:
    """Validate metal weights and normalise them to sum 1 (eq. 4).

    Parameters
    ----------
    metals
        Chemical symbol (any case) -> weight (fraction or percent), >= 0,
        with a positive sum.

    Returns
    -------
    dict
        Symbol -> weight, each in (0, 1], summing to 1; zero weights are dropped.  Weights whose
        sum overflows (1e308 each) are divided by the largest first, so they keep their shares.

    Raises
    ------
    ValueError
        An empty or non-mapping argument, an unknown metal, a weight that is
        not a finite number >= 0, a metal given twice, or a zero sum.

    Examples
    --------
    >>> normalise_composition({"cu": 88, "Sn": 12})
    {'Cu': 0.88, 'Sn': 0.12}
    """
    if not isinstance(metals, Mapping) or not metals:
        raise InputError("metals must be a non-empty mapping such as {'Au': 1.0}")
    out: dict[str, float] = {}
    for name, weight in metals.items():
        sym = canonical_metal(name)
        try:
            w = float(weight)
        except (TypeError, ValueError):
            raise InputError(f"weight of {sym} must be a number, got {weight!r}") from None
        if not math.isfinite(w) or w < 0:
            raise InputError(f"weight of {sym} must be finite and >= 0, got {weight!r}")
        if sym in out:
            raise InputError(f"metal {sym} is given twice in the composition")
        out[sym] = w
    total = sum(out.values())
    if not math.isfinite(total):        # weights near the float limit: share by the largest first
        top = max(out.values())
        out = {sym: w / top for sym, w in out.items()}
        total = sum(out.values())
    if total <= 0:
        raise InputError("the metal weights sum to 0; give at least one positive weight")
    return {sym: w / total for sym, w in out.items() if w > 0}


class ConductorFresnel:
    """Spectral factor of a metal or alloy: sum_j w_j F(eta_j(lambda), cos_d).

    Implements :class:`processing.materials.lobes.SpectralFactor`.

    Parameters
    ----------
    metals
        Chemical symbol -> weight; normalised to sum 1 (Matsuda eq. 4).

    Raises
    ------
    ValueError
        A bad composition (:func:`normalise_composition`).

    References
    ----------
    .. [1] Matsuda et al., eq. (1) and (3)-(4) (no DOI).
    .. [2] Johnson & Christy, "Optical constants of the noble metals", Phys.
       Rev. B 6, 4370-4379 (1972), doi:10.1103/PhysRevB.6.4370.

    Examples
    --------
    >>> f = ConductorFresnel({"Au": 1.0})
    >>> r = f.reflectance(1.0, [450.0, 650.0])
    >>> bool(r[1] > r[0])    # gold reflects red better than blue
    True
    """

    angle_dependent = True

    def __init__(self, metals: Mapping[str, float]) -> None:
        self._weights = normalise_composition(metals)
        self._eta_cache: dict[bytes, NDArray[np.complex128]] = {}

    @property
    def weights(self) -> dict[str, float]:
        """Normalised weights by chemical symbol (a copy)."""
        return dict(self._weights)

    def __repr__(self) -> str:
        parts = ", ".join(f"{k}={v:.4g}" for k, v in self._weights.items())
        return f"ConductorFresnel({parts})"

    def eta(self, wavelengths: ArrayLike) -> NDArray[np.complex128]:
        """Complex indices of the metals, cached per wavelength array.

        Parameters
        ----------
        wavelengths
            Wavelengths in nm, L of them (flattened).

        Returns
        -------
        ndarray
            complex128, shape ``(n_metals, L)``, read-only.

        Raises
        ------
        ValueError
            Wavelengths outside a metal's table.
        """
        wl = np.ascontiguousarray(np.asarray(wavelengths, dtype=np.float64).reshape(-1))
        key = wl.tobytes()
        cached = self._eta_cache.get(key)
        if cached is None:
            cached = np.stack([complex_index(m, wl) for m in self._weights])
            cached.setflags(write=False)
            if len(self._eta_cache) >= _MAX_CACHED_GRIDS:
                self._eta_cache.pop(next(iter(self._eta_cache)))
            self._eta_cache[key] = cached
        return cached

    def reflectance(self, cos_d: ArrayLike, wavelengths: ArrayLike) -> NDArray[np.float64]:
        """Weighted Fresnel reflectance sum_j w_j F(eta_j, cos_d).

        Parameters
        ----------
        cos_d
            Cosine of the angle between the light and the half vector.
        wavelengths
            1-D wavelengths in nm, L of them.

        Returns
        -------
        ndarray
            Shape ``shape(cos_d) + (L,)``, in [0, 1].

        Raises
        ------
        ValueError
            Wavelengths that are not 1-D or outside a metal's table.
        """
        wl = np.asarray(wavelengths, dtype=np.float64)
        if wl.ndim != 1:
            raise InputError(f"wavelengths must be 1-D (nm), got shape {wl.shape}")
        eta = self.eta(wl)
        c = np.asarray(cos_d, dtype=np.float64)[..., None]
        out = np.zeros(c.shape[:-1] + (wl.size,))
        for w, eta_j in zip(self._weights.values(), eta):
            out += w * fresnel_conductor(c, eta_j)
        return np.clip(out, 0.0, 1.0)


def check_shadowing(shadowing: str) -> str:
    """Validate the shadowing model name.

    Parameters
    ----------
    shadowing
        ``"smith"`` or ``"torrance-sparrow"``.

    Returns
    -------
    str
        The name.

    Raises
    ------
    ValueError
        Any other name.

    Examples
    --------
    >>> check_shadowing("smith")
    'smith'
    """
    if shadowing not in SHADOWING_MODELS:
        raise InputError(
            f"shadowing={shadowing!r} is not known; use one of: {', '.join(SHADOWING_MODELS)}"
        )
    return shadowing


def metal_material(
    name: str,
    metals: dict[str, float],
    *,
    gloss: float = 1.0,
    mirror: float = 0.0,
    roughness: float = 0.15,
    mirror_roughness: float = 0.01,
    shadowing: str = "smith",
    description: str = "",
) -> Material:
    """A metal or alloy (Matsuda et al., eq. (2)-(4)).

    Parameters
    ----------
    name
        Material name.
    metals
        Chemical symbol -> weight (normalised to sum 1); one metal for a pure
        metal, several for an alloy.
    gloss
        alpha, weight of the gloss lobe, in [0, 1].
    mirror
        beta, weight of the mirror lobe, in [0, 1]; ``gloss + mirror <= 1``
        (with F <= 1 and an energy-conserving G this keeps the directional
        albedo <= 1).
    roughness
        sigma0, Beckmann RMS slope of the gloss lobe, in [1e-5, 1] (MIN_ROUGHNESS to 1).
    mirror_roughness
        sigma1, RMS slope of the mirror lobe, in [1e-5, 1] (-> 1e-5: perfect mirror).
    shadowing
        ``"smith"`` (Walter et al. 2007) or ``"torrance-sparrow"`` (V-cavity).
    description
        Free text.

    Returns
    -------
    Material
        Lobes ``(gloss, mirror)``, family ``"metal"`` (one metal) or
        ``"alloy"``; ``parameters`` holds gloss, mirror, roughness,
        mirror_roughness, shadowing and the weight of every metal.

    Raises
    ------
    ValueError
        A parameter out of range, an unknown shadowing model, ``gloss +
        mirror > 1`` or a bad composition.

    References
    ----------
    .. [1] Matsuda et al., eq. (2)-(4) (no DOI).
    .. [2] Walter et al. (2007), doi:10.2312/EGWR/EGSR07/195-206.

    Examples
    --------
    >>> m = metal_material("gold", {"Au": 1.0}, gloss=0.7, mirror=0.3)
    >>> [lobe.mirror for lobe in m.lobes], m.parameters["Au"]
    ([False, True], 1.0)
    """
    gloss = checked_parameter("gloss", gloss)
    mirror = checked_parameter("mirror", mirror)
    roughness = checked_roughness("roughness", roughness)
    mirror_roughness = checked_roughness("mirror_roughness", mirror_roughness)
    check_shadowing(shadowing)
    if gloss + mirror > 1.0 + 1e-12:
        raise InputError(
            f"gloss + mirror = {gloss + mirror:g} exceeds 1 (energy conservation); "
            "lower one of them, e.g. gloss=0.7, mirror=0.3"
        )
    spectral = ConductorFresnel(metals)
    weights = spectral.weights
    lobes = (
        Lobe("microfacet", gloss, spectral, roughness, shadowing, mirror=False),
        Lobe("microfacet", mirror, spectral, mirror_roughness, shadowing, mirror=True),
    )
    parameters: dict[str, object] = {
        "gloss": gloss,
        "mirror": mirror,
        "roughness": roughness,
        "mirror_roughness": mirror_roughness,
        "shadowing": shadowing,
    }
    parameters.update(weights)
    family = "metal" if len(weights) == 1 else "alloy"
    return Material(name, lobes, family=family, description=description, parameters=parameters)
