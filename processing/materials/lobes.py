"""A material as a sum of reflection lobes, and its spectral BRDF.

Every lobe is a wavelength-independent geometric factor (Lambert, Beckmann
microfacet, or the anisotropic yarn ellipsoid) times a spectral factor that
depends on wavelength and at most on cos_d, the cosine of the angle between
the light and the half vector.  This is the shape shared by the models of
Matsuda et al. (metals, alloys, lacquers) and Yasuda et al. (cloth);
docs/materials.md, section "Lobes and spectral factors", states it in full.

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
from dataclasses import dataclass, field
from typing import Literal, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.errors import InputError
from processing.materials.microfacet import check_roughness, microfacet_lobe

# processing.cloth.anisotropic_microfacet is imported where it is used: its package's
# front door imports cloth modules that need this module, so a module-level import
# here would make ``import processing.materials`` circular.

__all__ = ["SpectralFactor", "Lobe", "Material", "lobe_geometry", "material_brdf", "checked_parameter",
           "checked_roughness"]

LobeKind = Literal["lambert", "microfacet", "anisotropic"]


@runtime_checkable
class SpectralFactor(Protocol):
    """The wavelength-dependent factor of a lobe (a protocol).

    Attributes
    ----------
    angle_dependent : bool
        False when the factor ignores ``cos_d`` (a pigment's diffuse
        reflectance), so a renderer needs no angular table.
    """

    angle_dependent: bool

    def reflectance(self, cos_d: ArrayLike, wavelengths: ArrayLike) -> NDArray[np.float64]:
        """The factor at ``cos_d`` and ``wavelengths``.

        Parameters
        ----------
        cos_d
            Cosine of the angle between the light and the half vector, any shape.
        wavelengths
            1-D wavelengths in nm, L of them.

        Returns
        -------
        ndarray
            Shape ``np.shape(cos_d) + (L,)``, values in [0, 1].
        """
        ...


@dataclass(frozen=True)
class Lobe:
    """One term of a reflection model: a weight, a geometric factor and a spectral factor.

    Attributes
    ----------
    kind
        ``"lambert"`` (geometry 1/pi), ``"microfacet"`` (Beckmann D, G) or
        ``"anisotropic"`` (the yarn ellipsoid of Yasuda et al., eq. (1), as a
        normalised distribution with Smith G:
        :mod:`processing.cloth.anisotropic_microfacet`); an anisotropic lobe needs
        the tangent-frame components of the light and view directions.
    weight
        Non-negative weight (alpha, beta or gamma of the paper's equations).
    spectral
        The spectral factor (Fresnel of a metal, alloy or dielectric, or a
        pigment reflectance).
    roughness
        Beckmann RMS slope of a microfacet lobe; the ellipsoid semi-axis a_t
        along the tangent t of an anisotropic lobe (ignored for Lambert).
    roughness_b
        The ellipsoid semi-axis a_b across the tangent (b = n x t) of an
        anisotropic lobe (ignored otherwise).
    shadowing
        ``"smith"``, ``"torrance-sparrow"`` or ``"none"``.
    mirror
        True for the paper's mirror term: besides the light sources, the lobe
        reflects the environment / other objects along the mirrored ray.

    Raises
    ------
    ValueError
        An unknown kind, a negative or non-finite weight, a microfacet
        roughness outside (0, 1], anisotropic axes outside
        :data:`processing.cloth.anisotropic_microfacet.AXIS_RANGE`, or an
        anisotropic mirror lobe.

    References
    ----------
    .. [1] Matsuda et al., eq. (2)-(5) (no DOI).
    .. [2] Yasuda, Yokoi, Toriwaki, Inagaki, IEEE CG&A 12(6), 15-24 (1992),
       doi:10.1109/38.163621, eq. (1).
    """

    kind: LobeKind
    weight: float
    spectral: SpectralFactor
    roughness: float = 0.0
    shadowing: str = "smith"
    mirror: bool = False
    roughness_b: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in ("lambert", "microfacet", "anisotropic"):
            raise InputError(f"lobe kind {self.kind!r} is not 'lambert', 'microfacet' or 'anisotropic'")
        if self.kind == "anisotropic":
            from processing.cloth.anisotropic_microfacet import check_axes

            check_axes(self.roughness, self.roughness_b, "anisotropic lobe")
            if self.mirror:
                raise InputError("an anisotropic lobe cannot be a mirror lobe")
        if not np.isfinite(self.weight) or self.weight < 0:
            raise InputError(f"lobe weight must be finite and >= 0, got {self.weight}")
        if self.kind == "microfacet" and not (0.0 < self.roughness <= 1.0):
            raise InputError(
                f"microfacet roughness (RMS slope) must be in (0, 1], got {self.roughness}"
            )


@dataclass(frozen=True)
class Material:
    """A named material: its lobes plus the parameters that built it.

    Attributes
    ----------
    name
        Material name.
    lobes
        The lobes whose sum is the BRDF.
    family
        The builder: ``"metal"``, ``"alloy"``, ``"dielectric"`` or ``"cloth"``.
    description
        Free text (the source of the data).
    parameters
        Every model parameter name and its value, so a CLI can list and
        override them (``gold:roughness=0.2``).
    """

    name: str
    lobes: tuple[Lobe, ...]
    family: str = ""
    description: str = ""
    parameters: dict = field(default_factory=dict)

    @property
    def anisotropic(self) -> bool:
        """True when a lobe needs a tangent frame (``kind == "anisotropic"``)."""
        return any(lobe.kind == "anisotropic" for lobe in self.lobes)


def checked_parameter(name: str, value: float, *, open_zero: bool = False, upper: float = 1.0) -> float:
    """``value`` as a float in [0, upper] (or (0, upper] with ``open_zero``).

    Parameters
    ----------
    name
        Parameter name, for the message.
    value
        The value (a number or a numeric string).
    open_zero
        Exclude 0.
    upper
        Largest accepted value.

    Returns
    -------
    float
        The value.

    Raises
    ------
    ValueError
        Not a number, or outside the range (the message names the parameter).

    Examples
    --------
    >>> checked_parameter("gloss", "0.5")
    0.5
    >>> checked_parameter("roughness", 0, open_zero=True)
    Traceback (most recent call last):
    ...
    processing.errors.InputError: roughness must be in (0, 1], got 0
    """
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {value!r}") from None
    ok = math.isfinite(v) and ((0.0 < v) if open_zero else (0.0 <= v)) and v <= upper
    if not ok:
        rng = f"(0, {upper:g}]" if open_zero else f"[0, {upper:g}]"
        raise InputError(f"{name} must be in {rng}, got {value!r}")
    return v


def checked_roughness(name: str, value: float) -> float:
    """``value`` as a Beckmann RMS slope in [MIN_ROUGHNESS, 1] (1e-5 to 1).

    The one check of a lobe's roughness for the material builders and the spec parser: below
    :data:`processing.materials.microfacet.MIN_ROUGHNESS` the microfacet lobe is not evaluated.

    Parameters
    ----------
    name
        Parameter name, for the message (``"roughness"`` or ``"mirror_roughness"``).
    value
        The value (a number or a numeric string).

    Returns
    -------
    float
        The value.

    Raises
    ------
    InputError
        Not a number, not finite, below 1e-5 or above 1 (the message names the parameter and the range).

    Examples
    --------
    >>> checked_roughness("roughness", "0.2")
    0.2
    >>> checked_roughness("roughness", 2)
    Traceback (most recent call last):
    ...
    processing.errors.InputError: roughness must be in (0, 1], got 2
    """
    v = checked_parameter(name, value, open_zero=True)
    check_roughness(name, v)
    return v


def lobe_geometry(
    lobe: Lobe,
    cos_i: ArrayLike,
    cos_o: ArrayLike,
    cos_h: ArrayLike,
    cos_d: ArrayLike,
    tangential: tuple[ArrayLike, ArrayLike, ArrayLike, ArrayLike] | None = None,
) -> NDArray[np.float64]:
    """Wavelength-independent factor of ``lobe`` (without the weight).

    Parameters
    ----------
    lobe
        The lobe.
    cos_i, cos_o
        Cosines of the light and view directions with the normal.
    cos_h
        Cosine of the half vector with the normal.
    cos_d
        Cosine of the angle between the light and the half vector.
    tangential
        ``(i_t, i_b, o_t, o_b)``, the components of the unit light and view
        directions along the tangent t and along b = n x t; only anisotropic
        lobes use it, and they require it.

    Returns
    -------
    ndarray
        The factor in 1/sr, shape ``broadcast(cos_i, cos_o, ...)``; 0 where
        the light or the view is below the surface.

    Raises
    ------
    ValueError
        An anisotropic lobe without ``tangential``.

    References
    ----------
    .. [1] Cook & Torrance, "A reflectance model for computer graphics", ACM
       Transactions on Graphics 1(1), 7-24 (1982), doi:10.1145/357290.357293.

    Examples
    --------
    >>> class Grey:
    ...     angle_dependent = False
    ...     def reflectance(self, cos_d, wl):
    ...         return np.full(np.shape(cos_d) + (len(wl),), 0.5)
    >>> lam = Lobe("lambert", 1.0, Grey())
    >>> round(float(lobe_geometry(lam, 0.5, 0.5, 1.0, 0.8)), 5)   # 1/pi
    0.31831
    """
    ci = np.asarray(cos_i, dtype=np.float64)
    co = np.asarray(cos_o, dtype=np.float64)
    if lobe.kind == "lambert":
        shape = np.broadcast_shapes(ci.shape, co.shape)
        return np.where((ci > 0) & (co > 0), 1.0 / np.pi, 0.0) * np.ones(shape)
    if lobe.kind == "anisotropic":
        from processing.cloth.anisotropic_microfacet import anisotropic_lobe

        if tangential is None:
            raise InputError(
                "an anisotropic lobe needs the tangent-frame components (i_t, i_b, o_t, o_b) of the light and "
                "view directions: pass tangential=..."
            )
        return anisotropic_lobe(ci, co, cos_h, cos_d, *tangential, lobe.roughness, lobe.roughness_b)
    return microfacet_lobe(ci, co, cos_h, cos_d, lobe.roughness, lobe.shadowing)


def material_brdf(
    material: Material,
    cos_i: ArrayLike,
    cos_o: ArrayLike,
    cos_h: ArrayLike,
    cos_d: ArrayLike,
    wavelengths: ArrayLike,
    tangential: tuple[ArrayLike, ArrayLike, ArrayLike, ArrayLike] | None = None,
) -> NDArray[np.float64]:
    """Spectral BRDF of ``material``: the sum of its lobes.

    The colour signal for a light of spectral irradiance E is
    ``material_brdf(...) * E * cos_i`` (Matsuda et al., eq. (2)).

    Parameters
    ----------
    material
        The material.
    cos_i, cos_o, cos_h, cos_d
        As for :func:`lobe_geometry`, broadcast together.
    wavelengths
        1-D wavelengths in nm, L of them.
    tangential
        ``(i_t, i_b, o_t, o_b)`` as for :func:`lobe_geometry` (required when
        the material has anisotropic lobes).

    Returns
    -------
    ndarray
        BRDF in 1/sr, shape ``broadcast(cos_i, cos_o, cos_h, cos_d) + (L,)``.

    Raises
    ------
    ValueError
        An anisotropic lobe without ``tangential``.

    Examples
    --------
    >>> from processing.materials.presets import get_material
    >>> f = material_brdf(get_material("gold"), 1.0, 1.0, 1.0, 1.0, [450.0, 650.0])
    >>> f.shape, bool(f[1] > f[0])
    ((2,), True)
    """
    wl = np.asarray(wavelengths, dtype=np.float64)
    shape = np.broadcast_shapes(*(np.shape(c) for c in (cos_i, cos_o, cos_h, cos_d)))
    total = np.zeros(shape + (wl.size,))
    cd = np.broadcast_to(np.asarray(cos_d, dtype=np.float64), shape)
    spectra: dict[int, NDArray[np.float64]] = {}      # lobes sharing a spectral factor (a metal's gloss and mirror)
    for lobe in material.lobes:
        if lobe.weight == 0.0:
            continue
        g = lobe_geometry(lobe, cos_i, cos_o, cos_h, cos_d, tangential)
        key = id(lobe.spectral)
        if key not in spectra:
            spectra[key] = lobe.spectral.reflectance(cd, wl)
        total += lobe.weight * np.broadcast_to(g, shape)[..., None] * spectra[key]
    return total
