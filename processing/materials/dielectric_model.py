"""Reflection model of inhomogeneous dielectrics (lacquer): Matsuda et al., eq. (5).

    C(lambda) = alpha cos_i S(lambda) E(lambda)                              [diffuse]
              + beta F(n, theta_d) D(h; sigma0) G / (4 cos_i cos_o) E cos_i   [gloss]
              + gamma F(n, theta_d) mirror(sigma1) E cos_i                    [mirror]

The body colour S(lambda) of the pigment is independent of angle; the
surface terms use the Fresnel reflectance of the real index n of the binder
(urushi: about 1.5), so highlights have the colour of the light.  The two
urushi pigment spectra are parametric curves; docs/materials.md, section
"Lacquer pigment spectra", gives their shapes and sources.

References
----------
.. [1] Matsuda, Tanaka, Ichikawa, Mochizuki, Muroya, Kitamura, "CG
   reproduction of a craft object based on a light reflection model", IPSJ
   technical report (no DOI), eq. (5).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.errors import InputError
from processing.materials.fresnel import fresnel_dielectric
from processing.materials.lobes import Lobe, Material, checked_parameter, checked_roughness
from processing.materials.metal_model import check_shadowing
from processing.spectral.spectra import resample

__all__ = [
    "DielectricFresnel",
    "PigmentReflectance",
    "dielectric_material",
    "urushi_black_reflectance",
    "urushi_red_reflectance",
    "URUSHI_INDEX",
]

#: Refractive index of cured urushi lacquer (urushiol polymer), about 1.5.
URUSHI_INDEX = 1.5

_MAX_CACHED_GRIDS = 8


class DielectricFresnel:
    """Spectral factor of a dielectric surface: unpolarised Fresnel F(n, cos_d).

    Implements :class:`processing.materials.lobes.SpectralFactor`.

    Parameters
    ----------
    n
        Real refractive index (> 0), or an array of indices at ``wavelengths``.
    wavelengths
        Wavelengths in nm of a dispersive index (then linearly interpolated);
        ``None`` for a constant index.

    Raises
    ------
    ValueError
        A non-finite or non-positive index, an array of indices without
        wavelengths, or wavelengths that are not strictly increasing or do
        not match the indices.

    Examples
    --------
    >>> f = DielectricFresnel(1.5)
    >>> [round(float(v), 4) for v in f.reflectance(1.0, [450.0, 650.0])]
    [0.04, 0.04]
    """

    angle_dependent = True

    def __init__(self, n: float | ArrayLike, wavelengths: ArrayLike | None = None) -> None:
        n_arr = np.asarray(n, dtype=np.float64)
        if not np.all(np.isfinite(n_arr)) or np.any(n_arr <= 0):
            raise InputError(f"refractive index n must be finite and > 0, got {n!r}")
        if wavelengths is None:
            if n_arr.ndim != 0:
                raise InputError(
                    "an array of indices needs the matching wavelengths: "
                    "DielectricFresnel(n_values, wavelengths=wavelengths_nm)"
                )
            self._wl: NDArray[np.float64] | None = None
        else:
            wl = np.asarray(wavelengths, dtype=np.float64)
            if wl.ndim != 1 or wl.size < 2 or n_arr.shape != wl.shape:
                raise InputError(
                    f"wavelengths (shape {wl.shape}) and n (shape {n_arr.shape}) must be 1-D "
                    "arrays of the same length >= 2"
                )
            if not np.all(np.isfinite(wl)) or not np.all(np.diff(wl) > 0):
                raise InputError("wavelengths of the index must be finite and strictly increasing (nm)")
            self._wl = wl
        self._n = n_arr

    @property
    def constant_index(self) -> float | None:
        """The index if it does not depend on wavelength, else None."""
        return float(self._n) if self._wl is None else None

    def index(self, wavelengths: ArrayLike) -> NDArray[np.float64]:
        """Refractive index at ``wavelengths``.

        Parameters
        ----------
        wavelengths
            Wavelengths in nm, L of them (flattened).

        Returns
        -------
        ndarray
            Shape ``(L,)``.

        Raises
        ------
        ValueError
            Wavelengths outside the range of a dispersive index.
        """
        wl = np.asarray(wavelengths, dtype=np.float64).reshape(-1)
        if self._wl is None:
            return np.full(wl.shape, float(self._n))
        if wl.size and (wl.min() < self._wl[0] - 1e-9 or wl.max() > self._wl[-1] + 1e-9):
            raise InputError(
                f"the refractive index is given for {self._wl[0]:g}-{self._wl[-1]:g} nm, "
                f"asked for {wl.min():g}-{wl.max():g} nm"
            )
        return np.interp(wl, self._wl, self._n)

    def reflectance(self, cos_d: ArrayLike, wavelengths: ArrayLike) -> NDArray[np.float64]:
        """Fresnel reflectance F(n, cos_d).

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
            Wavelengths that are not 1-D.
        """
        wl = np.asarray(wavelengths, dtype=np.float64)
        if wl.ndim != 1:
            raise InputError(f"wavelengths must be 1-D (nm), got shape {wl.shape}")
        c = np.asarray(cos_d, dtype=np.float64)
        if self._wl is None:
            f = fresnel_dielectric(c, float(self._n))
            return np.repeat(f[..., None], wl.size, axis=-1)
        return fresnel_dielectric(c[..., None], self.index(wl))


class PigmentReflectance:
    """Angle-independent body reflectance S(lambda) of a pigment.

    Implements :class:`processing.materials.lobes.SpectralFactor` with
    ``angle_dependent = False``.

    Parameters
    ----------
    wavelengths
        Wavelengths in nm, strictly increasing, at least two.
    values
        Reflectance factors in [0, 1] at those wavelengths; linearly
        interpolated onto any grid inside their range.

    Raises
    ------
    ValueError
        Mismatched or too short arrays, wavelengths not strictly increasing,
        or values outside [0, 1].

    Examples
    --------
    >>> s = PigmentReflectance([400, 700], [0.2, 0.5])
    >>> [round(float(v), 3) for v in s.reflectance(0.3, [400.0, 550.0, 700.0])]
    [0.2, 0.35, 0.5]
    """

    angle_dependent = False

    def __init__(self, wavelengths: ArrayLike, values: ArrayLike) -> None:
        wl = np.asarray(wavelengths, dtype=np.float64)
        vals = np.asarray(values, dtype=np.float64)
        if wl.ndim != 1 or wl.size < 2 or vals.shape != wl.shape:
            raise InputError(
                f"pigment wavelengths (shape {wl.shape}) and values (shape {vals.shape}) must be "
                "1-D arrays of the same length >= 2"
            )
        if not np.all(np.isfinite(wl)) or not np.all(np.diff(wl) > 0):
            raise InputError("pigment wavelengths must be finite and strictly increasing (nm)")
        if not np.all(np.isfinite(vals)) or np.any(vals < 0) or np.any(vals > 1):
            raise InputError("pigment reflectance values must be in [0, 1] (a reflectance factor)")
        wl.setflags(write=False)
        vals.setflags(write=False)
        self.wavelengths = wl
        self.values = vals
        self._cache: dict[bytes, NDArray[np.float64]] = {}

    def __repr__(self) -> str:
        return f"PigmentReflectance({self.wavelengths[0]:g}-{self.wavelengths[-1]:g} nm, {self.wavelengths.size} samples)"

    def on(self, wavelengths: ArrayLike) -> NDArray[np.float64]:
        """S(lambda) at ``wavelengths``, cached.

        Parameters
        ----------
        wavelengths
            Wavelengths in nm, L of them (flattened), inside the table's range.

        Returns
        -------
        ndarray
            Shape ``(L,)``, read-only.

        Raises
        ------
        ValueError
            Wavelengths the table cannot be resampled onto.
        """
        wl = np.ascontiguousarray(np.asarray(wavelengths, dtype=np.float64).reshape(-1))
        key = wl.tobytes()
        s = self._cache.get(key)
        if s is None:
            try:
                s = np.clip(resample(self.wavelengths, self.values, wl), 0.0, 1.0)
            except ValueError as exc:
                raise InputError(f"pigment reflectance: {exc}") from None
            s.setflags(write=False)
            if len(self._cache) >= _MAX_CACHED_GRIDS:
                self._cache.pop(next(iter(self._cache)))
            self._cache[key] = s
        return s

    def reflectance(self, cos_d: ArrayLike, wavelengths: ArrayLike) -> NDArray[np.float64]:
        """S(lambda), independent of ``cos_d``.

        Parameters
        ----------
        cos_d
            Cosine of the angle between the light and the half vector (only its shape is used).
        wavelengths
            1-D wavelengths in nm, L of them.

        Returns
        -------
        ndarray
            S broadcast to ``shape(cos_d) + (L,)`` (a read-only view).

        Raises
        ------
        ValueError
            Wavelengths that are not 1-D.
        """
        wl = np.asarray(wavelengths, dtype=np.float64)
        if wl.ndim != 1:
            raise InputError(f"wavelengths must be 1-D (nm), got shape {wl.shape}")
        return np.broadcast_to(self.on(wl), np.shape(cos_d) + (wl.size,))


def _logistic(x: NDArray[np.float64]) -> NDArray[np.float64]:
    return 0.5 * (1.0 + np.tanh(0.5 * x))


_PIGMENT_WL = np.arange(360.0, 830.0 + 0.5, 5.0)


def urushi_black_reflectance() -> PigmentReflectance:
    """Body reflectance of black urushi (kuro-urushi), 360-830 nm.

    A nearly flat, very low reflectance rising from 1.0 % in the blue to
    2.0 % in the near infrared (the brownish tint of the urushiol binder);
    a parametric curve, not a measurement (docs/materials.md).

    Returns
    -------
    PigmentReflectance
        Sampled every 5 nm.

    Examples
    --------
    >>> s = urushi_black_reflectance().on([400.0, 700.0])
    >>> bool(0.005 < s[0] < s[1] < 0.03)
    True
    """
    values = 0.010 + 0.010 * _logistic((_PIGMENT_WL - 620.0) / 60.0)
    return PigmentReflectance(_PIGMENT_WL, values)


def urushi_red_reflectance() -> PigmentReflectance:
    """Body reflectance of red urushi (shu-urushi, vermilion HgS), 360-830 nm.

    About 5 % below 560 nm and a steep rise at the band edge of vermilion
    (inflection at 600 nm, 10-90 % over about 60 nm) to about 55 %; a
    parametric curve, not a measurement (docs/materials.md).

    Returns
    -------
    PigmentReflectance
        Sampled every 5 nm.

    Examples
    --------
    >>> s = urushi_red_reflectance().on([500.0, 600.0, 700.0])
    >>> bool(s[0] < 0.07 and 0.25 < s[1] < 0.35 and s[2] > 0.5)
    True
    """
    values = 0.05 + 0.50 * _logistic((_PIGMENT_WL - 600.0) / 14.0)
    return PigmentReflectance(_PIGMENT_WL, values)


def dielectric_material(
    name: str,
    reflectance: PigmentReflectance,
    *,
    n: float | DielectricFresnel = URUSHI_INDEX,
    diffuse: float = 0.9,
    gloss: float = 0.05,
    roughness: float = 0.1,
    mirror: float = 0.05,
    mirror_roughness: float = 0.01,
    shadowing: str = "smith",
    description: str = "",
) -> Material:
    """A lacquer-like dielectric (Matsuda et al., eq. (5)).

    Parameters
    ----------
    name
        Material name.
    reflectance
        Body reflectance S(lambda) of the pigment.
    n
        Real refractive index of the binder in [1, 3], or a
        :class:`DielectricFresnel` for a dispersive index.
    diffuse, gloss, mirror
        alpha, beta, gamma of eq. (5), each in [0, 1] with
        ``diffuse + gloss + mirror <= 1`` (energy: every lobe's albedo is at
        most its weight).
    roughness, mirror_roughness
        Beckmann RMS slopes sigma0 and sigma1 in [1e-5, 1] (MIN_ROUGHNESS to 1).
    shadowing
        ``"smith"`` or ``"torrance-sparrow"``.
    description
        Free text.

    Returns
    -------
    Material
        Lobes ``(lambert, gloss, mirror)``, family ``"dielectric"``.

    Raises
    ------
    ValueError
        A reflectance that is not a :class:`PigmentReflectance`, a parameter
        out of range, an unknown shadowing model, or weights summing above 1.

    References
    ----------
    .. [1] Matsuda et al., eq. (5) (no DOI).
    .. [2] Walter, Marschner, Li, Torrance, "Microfacet models for refraction
       through rough surfaces", EGSR 2007, doi:10.2312/EGWR/EGSR07/195-206.

    Examples
    --------
    >>> m = dielectric_material("urushi-red", urushi_red_reflectance())
    >>> [lobe.kind for lobe in m.lobes], m.parameters["n"]
    (['lambert', 'microfacet', 'microfacet'], 1.5)
    """
    if not isinstance(reflectance, PigmentReflectance):
        raise InputError(
            "reflectance must be a PigmentReflectance(wavelengths_nm, values), "
            f"got {type(reflectance).__name__}"
        )
    if isinstance(n, DielectricFresnel):
        fresnel = n
        n_value: float | str = n.constant_index if n.constant_index is not None else "dispersive"
    else:
        n_value = checked_parameter("n", n, open_zero=True, upper=3.0)
        if n_value < 1.0:
            raise InputError(f"n must be in [1, 3] for a lacquer or glaze, got {n!r}")
        fresnel = DielectricFresnel(n_value)
    diffuse = checked_parameter("diffuse", diffuse)
    gloss = checked_parameter("gloss", gloss)
    mirror = checked_parameter("mirror", mirror)
    roughness = checked_roughness("roughness", roughness)
    mirror_roughness = checked_roughness("mirror_roughness", mirror_roughness)
    check_shadowing(shadowing)
    total = diffuse + gloss + mirror
    if total > 1.0 + 1e-12:
        raise InputError(
            f"diffuse + gloss + mirror = {total:g} exceeds 1 (energy conservation); "
            "lower one of them"
        )
    lobes = (
        Lobe("lambert", diffuse, reflectance),
        Lobe("microfacet", gloss, fresnel, roughness, shadowing, mirror=False),
        Lobe("microfacet", mirror, fresnel, mirror_roughness, shadowing, mirror=True),
    )
    parameters: dict[str, object] = {
        "n": n_value,
        "diffuse": diffuse,
        "gloss": gloss,
        "roughness": roughness,
        "mirror": mirror,
        "mirror_roughness": mirror_roughness,
        "shadowing": shadowing,
    }
    return Material(name, lobes, family="dielectric", description=description, parameters=parameters)
