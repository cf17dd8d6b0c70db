"""Microfacet distribution and shadowing terms of the gloss lobe.

Matsuda et al., eq. (2) uses a Torrance-Sparrow lobe: a Beckmann
distribution D of microfacet normals (roughness = RMS slope sigma) and a
geometric attenuation G.  Both the Torrance-Sparrow V-cavity G and the Smith
G for the Beckmann distribution (Walter et al. 2007, eq. (25)-(27)) are
provided.  All functions take cosines with the surface normal and stay
finite at cos -> 0, sigma -> 0 and sigma -> 1.

References
----------
.. [1] Torrance & Sparrow, "Theory for off-specular reflection from
   roughened surfaces", JOSA 57(9), 1105-1114 (1967),
   doi:10.1364/JOSA.57.001105.
.. [2] Cook & Torrance, "A reflectance model for computer graphics", ACM
   Transactions on Graphics 1(1), 7-24 (1982), doi:10.1145/357290.357293.
.. [3] Smith, "Geometrical shadowing of a random rough surface", IEEE
   Transactions on Antennas and Propagation 15(5), 668-671 (1967),
   doi:10.1109/TAP.1967.1138991.
.. [4] Walter, Marschner, Li, Torrance, "Microfacet models for refraction
   through rough surfaces", EGSR 2007, doi:10.2312/EGWR/EGSR07/195-206.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import erfc

from processing.errors import InputError

__all__ = [
    "MIN_ROUGHNESS",
    "check_roughness",
    "beckmann_d",
    "smith_g1_beckmann",
    "smith_g",
    "torrance_sparrow_g",
    "microfacet_lobe",
    "SmithLobe",
]

_TINY = 1e-12

#: Smallest Beckmann RMS slope the lobe is evaluated at.  At 1e-5 the facets spread by about 0.0006 deg, far
#: below what any camera resolves (the presets' sharpest lobe is 0.01), and the peak 1 / (pi sigma^2) ~ 3e9 of
#: D stays finite in float32; below about 1e-160 sigma^2 underflows and D becomes 0 / 0.
MIN_ROUGHNESS: float = 1e-5


def check_roughness(name: str, value: float | ArrayLike) -> NDArray[np.float64]:
    """``value`` as a Beckmann RMS slope in [MIN_ROUGHNESS, inf), or a one-line error naming ``name``.

    Parameters
    ----------
    name
        The parameter's name, for the message (``"roughness"``, ``"mirror_roughness"``).
    value
        One roughness or an array of them.

    Returns
    -------
    ndarray
        The roughness as float64.

    Raises
    ------
    InputError
        Not a number, not finite, or below :data:`MIN_ROUGHNESS` (1e-5).

    Examples
    --------
    >>> float(check_roughness("roughness", 0.2))
    0.2
    >>> bool(check_roughness("roughness", [0.01, 1.0]).min() == 0.01)
    True
    """
    try:
        sigma = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        sigma, shown = np.asarray(np.nan), value
    else:
        shown = value if sigma.ndim else float(sigma)
    if not np.all(np.isfinite(sigma)) or np.any(sigma < MIN_ROUGHNESS):
        raise InputError(
            f"{name} (Beckmann RMS slope) must be a finite number >= {MIN_ROUGHNESS:g}, the smallest the "
            f"microfacet lobe is evaluated at, got {shown!r}; use mirror_roughness=0.01 (as the presets) "
            "for a near-perfect mirror"
        )
    return sigma


def _checked_roughness(roughness: float | ArrayLike) -> NDArray[np.float64]:
    return check_roughness("roughness", roughness)


def beckmann_d(cos_h: ArrayLike, roughness: float | ArrayLike) -> NDArray[np.float64]:
    """Beckmann distribution of microfacet normals.

    Normalised so that the integral of ``D(h) cos(theta_h)`` over the
    hemisphere is 1.

    Parameters
    ----------
    cos_h
        Cosine between the half vector and the surface normal.
    roughness
        RMS slope sigma of the microfacets (> 0).

    Returns
    -------
    ndarray
        D in 1/sr.  Zero for ``cos_h <= 0``.

    Raises
    ------
    ValueError
        A roughness that is not finite and > 0.

    References
    ----------
    .. [1] Cook & Torrance (1982), doi:10.1145/357290.357293.
    .. [2] Walter et al. (2007), eq. (25), doi:10.2312/EGWR/EGSR07/195-206.

    Examples
    --------
    >>> round(float(beckmann_d(1.0, 0.5)), 4)   # 1 / (pi sigma^2) at the peak
    1.2732
    """
    c = np.asarray(cos_h, dtype=np.float64)
    s2 = _checked_roughness(roughness) ** 2
    c2 = np.clip(c * c, _TINY, 1.0)
    tan2 = (1.0 - c2) / c2
    with np.errstate(over="ignore", under="ignore"):
        d = np.exp(-tan2 / s2) / (np.pi * s2 * c2 * c2)
    return np.where(c > 0.0, d, 0.0)


def smith_g1_beckmann(cos_v: ArrayLike, roughness: float | ArrayLike) -> NDArray[np.float64]:
    """Smith masking of one direction for the Beckmann distribution (exact form).

    G1 = 2 / (1 + erf(a) + exp(-a^2) / (a sqrt(pi))), a = cot(theta_v) / sigma.

    Parameters
    ----------
    cos_v
        Cosine of the direction with the normal (clipped to [0, 1]).
    roughness
        RMS slope sigma (> 0).

    Returns
    -------
    ndarray
        G1 in [0, 1]: 1 along the normal, 0 at grazing.

    Raises
    ------
    ValueError
        A roughness that is not finite and > 0.

    References
    ----------
    .. [1] Smith (1967), doi:10.1109/TAP.1967.1138991.
    .. [2] Walter et al. (2007), eq. (27), doi:10.2312/EGWR/EGSR07/195-206.

    Examples
    --------
    >>> float(smith_g1_beckmann(1.0, 0.3))   # seen from straight above: no masking
    1.0
    >>> float(smith_g1_beckmann(0.0, 0.3))   # at grazing everything is masked
    0.0
    """
    c = np.clip(np.asarray(cos_v, dtype=np.float64), 0.0, 1.0)
    sigma = _checked_roughness(roughness)
    sin = np.sqrt(np.clip(1.0 - c * c, 0.0, 1.0))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore", under="ignore"):
        a = c / (sigma * sin)
        # Lambda(a) = (erf(a) - 1)/2 + exp(-a^2)/(2 a sqrt(pi)); erfc keeps the
        # difference accurate for large a.
        lam = 0.5 * (np.exp(-a * a) / (a * np.sqrt(np.pi)) - erfc(a))
        g1 = 1.0 / (1.0 + lam)
    g1 = np.where(sin <= 0.0, 1.0, g1)          # normal incidence: a = inf
    g1 = np.where(c <= 0.0, 0.0, g1)            # grazing: fully masked
    return np.clip(np.nan_to_num(g1, nan=0.0), 0.0, 1.0)


def smith_g(cos_i: ArrayLike, cos_o: ArrayLike, roughness: float | ArrayLike) -> NDArray[np.float64]:
    """Separable Smith shadowing-masking G = G1(i) G1(o).

    Parameters
    ----------
    cos_i, cos_o
        Cosines of the light and view directions with the normal.
    roughness
        RMS slope sigma (> 0).

    Returns
    -------
    ndarray
        G in [0, 1].

    Raises
    ------
    ValueError
        A roughness that is not finite and > 0.

    References
    ----------
    .. [1] Smith (1967), doi:10.1109/TAP.1967.1138991.

    Examples
    --------
    >>> round(float(smith_g(0.9, 0.9, 0.2)), 6) <= 1.0
    True
    """
    return smith_g1_beckmann(cos_i, roughness) * smith_g1_beckmann(cos_o, roughness)


def torrance_sparrow_g(
    cos_i: ArrayLike, cos_o: ArrayLike, cos_h: ArrayLike, cos_d: ArrayLike
) -> NDArray[np.float64]:
    """Torrance-Sparrow V-cavity attenuation.

    G = min(1, 2 (n.h)(n.o)/(o.h), 2 (n.h)(n.i)/(o.h)), with ``cos_d = o.h = i.h``.

    Parameters
    ----------
    cos_i, cos_o, cos_h
        n.i, n.o and n.h.
    cos_d
        o.h = i.h.

    Returns
    -------
    ndarray
        G in [0, 1].

    References
    ----------
    .. [1] Torrance & Sparrow (1967), doi:10.1364/JOSA.57.001105.
    .. [2] Cook & Torrance (1982), doi:10.1145/357290.357293.

    Examples
    --------
    >>> float(torrance_sparrow_g(1.0, 1.0, 1.0, 1.0))
    1.0
    """
    ci = np.clip(np.asarray(cos_i, dtype=np.float64), 0.0, 1.0)
    co = np.clip(np.asarray(cos_o, dtype=np.float64), 0.0, 1.0)
    ch = np.clip(np.asarray(cos_h, dtype=np.float64), 0.0, 1.0)
    cd = np.maximum(np.asarray(cos_d, dtype=np.float64), _TINY)
    g = np.minimum(1.0, np.minimum(2.0 * ch * co / cd, 2.0 * ch * ci / cd))
    return np.clip(g, 0.0, 1.0)


def microfacet_lobe(
    cos_i: ArrayLike,
    cos_o: ArrayLike,
    cos_h: ArrayLike,
    cos_d: ArrayLike,
    roughness: float,
    shadowing: str = "smith",
) -> NDArray[np.float64]:
    """Wavelength-independent factor D G / (4 cos_i cos_o) of the gloss lobe.

    Multiply by the Fresnel reflectance F(cos_d) to get the BRDF.

    Parameters
    ----------
    cos_i, cos_o, cos_h, cos_d
        n.i, n.o, n.h and i.h.
    roughness
        Beckmann RMS slope sigma (> 0).
    shadowing
        ``"smith"``, ``"torrance-sparrow"`` (or ``"v-cavity"``) or ``"none"``.

    Returns
    -------
    ndarray
        The factor in 1/sr; 0 where either direction is below the surface.

    Raises
    ------
    ValueError
        A roughness that is not finite and > 0, or an unknown shadowing model.

    References
    ----------
    .. [1] Torrance & Sparrow (1967), doi:10.1364/JOSA.57.001105.
    .. [2] Cook & Torrance (1982), doi:10.1145/357290.357293.
    .. [3] Walter et al. (2007), doi:10.2312/EGWR/EGSR07/195-206.

    Examples
    --------
    >>> float(microfacet_lobe(0.0, 1.0, 0.7, 0.7, 0.3))
    0.0
    """
    if shadowing == "smith":
        return SmithLobe(cos_i, cos_o, cos_h)(roughness)
    ci = np.asarray(cos_i, dtype=np.float64)
    co = np.asarray(cos_o, dtype=np.float64)
    d = beckmann_d(cos_h, roughness)
    if shadowing in ("torrance-sparrow", "v-cavity"):
        g = torrance_sparrow_g(ci, co, cos_h, cos_d)
    elif shadowing == "none":
        g = np.ones_like(d)
    else:
        raise InputError(
            f"shadowing={shadowing!r} is not known; use 'smith', 'torrance-sparrow' or 'none'"
        )
    valid = (ci > 0.0) & (co > 0.0)
    denom = 4.0 * np.where(valid, ci * co, 1.0)
    # cos_i * cos_o below ~1e-308 underflows; such degenerate configurations give 0.
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        val = d * g / denom
    return np.where(valid, np.nan_to_num(val, nan=0.0, posinf=0.0), 0.0)


#: Smith's ``a = cot(theta) / sigma`` from which ``G1`` is 1.0 to the last bit (checked from 5 to 1e300: the
#: largest ``a`` with ``G1 != 1`` is 5.44).
_G1_IS_ONE = 6.0


class SmithLobe:
    """:func:`microfacet_lobe` with Smith shadowing at fixed directions, for many roughnesses.

    The parts that do not depend on the roughness (the clipped cosines, the tangents, the masks and
    the denominator) are computed once; each call evaluates only the roughness's terms, with the
    same operations as :func:`beckmann_d`, :func:`smith_g1_beckmann` and :func:`microfacet_lobe`, so
    the values are the same to the last bit.  A fit that searches the roughness over the same
    observations evaluates the lobe tens of times.

    Parameters
    ----------
    cos_i, cos_o, cos_h
        n.i, n.o and n.h (broadcast together as in :func:`microfacet_lobe`).

    Examples
    --------
    >>> lobe = SmithLobe([0.9, 0.5], [0.8, 0.0], [0.95, 0.7])
    >>> bool(np.array_equal(lobe(0.3), microfacet_lobe([0.9, 0.5], [0.8, 0.0], [0.95, 0.7], 0.0, 0.3,
    ...                                                 shadowing="smith")))
    True
    """

    def __init__(self, cos_i: ArrayLike, cos_o: ArrayLike, cos_h: ArrayLike) -> None:
        ci = np.asarray(cos_i, dtype=np.float64)
        co = np.asarray(cos_o, dtype=np.float64)
        c = np.asarray(cos_h, dtype=np.float64)
        self._c2 = np.clip(c * c, _TINY, 1.0)
        self._tan2 = (1.0 - self._c2) / self._c2
        self._facing = c > 0.0
        self._masking = [self._masking_terms(ci), self._masking_terms(co)]
        self._valid = (ci > 0.0) & (co > 0.0)
        self._denom = 4.0 * np.where(self._valid, ci * co, 1.0)

    @staticmethod
    def _masking_terms(cos_v: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
        c = np.clip(cos_v, 0.0, 1.0)
        sin = np.sqrt(np.clip(1.0 - c * c, 0.0, 1.0))
        fixed = sin <= 0.0
        grazing = c <= 0.0
        return c, sin, fixed | grazing, np.where(grazing, 0.0, 1.0)

    def _g1(self, terms: tuple[NDArray[np.float64], ...], sigma: NDArray[np.float64]) -> NDArray[np.float64]:
        c, sin, fixed, value = terms
        with np.errstate(divide="ignore", invalid="ignore", over="ignore", under="ignore"):
            a = c / (sigma * sin)
            # beyond _G1_IS_ONE, 1 + Lambda(a) rounds to 1 (Lambda < 1e-18): skip erfc and exp there
            near = np.flatnonzero(~(a >= _G1_IS_ONE))
            g1 = np.ones(a.shape)
            an = a.reshape(-1)[near]
            lam = 0.5 * (np.exp(-an * an) / (an * np.sqrt(np.pi)) - erfc(an))
            g1.reshape(-1)[near] = 1.0 / (1.0 + lam)
        g1 = np.where(fixed, value, g1)
        return np.clip(np.nan_to_num(g1, nan=0.0), 0.0, 1.0)

    def __call__(self, roughness: float | ArrayLike) -> NDArray[np.float64]:
        """The lobe ``D G / (4 cos_i cos_o)`` in 1/sr at ``roughness`` (Beckmann RMS slope, > 0).

        Parameters
        ----------
        roughness
            Beckmann RMS slope sigma.

        Returns
        -------
        ndarray
            As :func:`microfacet_lobe` with ``shadowing="smith"``.

        Raises
        ------
        InputError
            A roughness that is not finite and > 0.
        """
        sigma = _checked_roughness(roughness)
        s2 = sigma ** 2
        with np.errstate(over="ignore", under="ignore"):
            d = np.exp(-self._tan2 / s2) / (np.pi * s2 * self._c2 * self._c2)
        d = np.where(self._facing, d, 0.0)
        g = self._g1(self._masking[0], sigma) * self._g1(self._masking[1], sigma)
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            val = d * g / self._denom
        return np.where(self._valid, np.nan_to_num(val, nan=0.0, posinf=0.0), 0.0)
