"""An analytic outdoor sky: CIE daylight spectra over the CIE general sky's luminance.

:func:`daylight_sky` builds an :class:`~processing.lighting.environment_map.EnvironmentMap`
of an outdoor sky in the table frame (z up):

* **luminance distribution** of the sky vault: the CIE general sky
  (CIE S 011/E:2003, ISO 15469:2004; Kittler, Perez and Darula 1998): the
  luminance of a sky element at zenith angle ``Z`` and angle ``chi`` from the
  sun, relative to the zenith, is

  ``L / Lz = f(chi) phi(Z) / (f(Zs) phi(0))``,
  ``phi(Z) = 1 + a exp(b / cos Z)`` (gradation; ``phi(pi/2) = 1``),
  ``f(chi) = 1 + c (exp(d chi) - exp(d pi / 2)) + e cos^2 chi`` (indicatrix),

  with ``Zs`` the sun's zenith angle and ``(a, b, c, d, e)`` one of the
  fifteen standard sky types (:data:`CIE_SKY_TYPES`): type 1 is the
  overcast sky (like the Moon and Spencer (1942) CIE overcast sky it is
  three times brighter at the zenith than at the horizon and gives the same
  horizontal illuminance to 0.3 %), type 12 the CIE standard clear sky (identical to the 1973 CIE
  clear-sky formula);
* **spectrum** of the sky light: the CIE daylight (D series) spectral
  distribution of correlated colour temperature ``cct`` (CIE 015:2018,
  section 4.1; colour-science's ``CCT_to_xy_CIE_D`` and
  ``sd_CIE_illuminant_D_series``);
* **sun**: a disc of 0.533 degrees diameter at elevation / azimuth
  ``sun_elevation_deg`` / ``sun_azimuth_deg`` (azimuth from +x toward +y,
  as in the map) with its own daylight spectrum of ``sun_cct``; its
  horizontal illuminance is ``sun`` times the sky's.  A map pixel is
  larger than the disc at the usual sizes, so the disc is widened to
  ``max(0.267 deg, 1.5 pixels)`` of angular radius with its illuminance
  kept exact (the sun's power is right, its size is the map's resolution);
* **ground**: below the horizon a uniform Lambertian ground of reflectance
  ``ground`` lit by the sky and the sun.

Units: the map is scaled so that a white Lambertian surface facing up,
lit by sky and sun (not the ground), has the luminance ``luminance``
(horizontal illuminance / pi); the renderer shows such a surface with that
luminance.  The map has two basis spectra: the sky's daylight (row 0) and
the sun's (row 1), each of luminance ``Y = 1``.

References
----------
CIE S 011/E:2003 (ISO 15469:2004), Spatial distribution of daylight - CIE
standard general sky.
Kittler, R., Perez, R., & Darula, S. (1998). A set of standard skies
characterizing daylight conditions for computer and energy conscious
design. Report of US-SK 92 052 project, Bratislava.
Darula, S., & Kittler, R. (2002). CIE general sky standard defining
luminance distributions. Proceedings eSim 2002, Montreal.
Moon, P., & Spencer, D. E. (1942). Illumination from a non-uniform sky.
Illuminating Engineering 37, 707-726.
CIE 015:2018 Colorimetry, section 4.1 (daylight). doi:10.25039/TR.015.2018

Examples
--------
>>> sky = daylight_sky(cct=6500, sun_elevation_deg=40, height=32)
>>> sky.coefficients.shape, sky.basis.shape
((32, 64, 2), (2, 61))
>>> round(horizontal_luminance(sky), 3)
1.0
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.lighting.environment_map import EnvironmentMap, EnvironmentMapError
from processing.spectral.display import spectra_to_xyz
from processing.spectral.spectra import REFERENCE_GRID, SpectralGrid, resample

__all__ = [
    "CIE_SKY_TYPES",
    "SKY_TYPE_NAMES",
    "SUN_RADIUS_DEG",
    "SkyParameters",
    "daylight_spectrum",
    "cie_sky_relative_luminance",
    "daylight_sky",
    "horizontal_luminance",
]

#: The fifteen CIE standard general skies: (a, b, c, d, e) of the gradation and
#: indicatrix functions (CIE S 011/E:2003, table 1; Darula and Kittler 2002).
CIE_SKY_TYPES: dict[int, tuple[float, float, float, float, float]] = {
    1: (4.0, -0.70, 0.0, -1.0, 0.00),
    2: (4.0, -0.70, 2.0, -1.5, 0.15),
    3: (1.1, -0.80, 0.0, -1.0, 0.00),
    4: (1.1, -0.80, 2.0, -1.5, 0.15),
    5: (0.0, -1.00, 0.0, -1.0, 0.00),
    6: (0.0, -1.00, 2.0, -1.5, 0.15),
    7: (0.0, -1.00, 5.0, -2.5, 0.30),
    8: (0.0, -1.00, 10.0, -3.0, 0.45),
    9: (-1.0, -0.55, 2.0, -1.5, 0.15),
    10: (-1.0, -0.55, 5.0, -2.5, 0.30),
    11: (-1.0, -0.55, 10.0, -3.0, 0.45),
    12: (-1.0, -0.32, 10.0, -3.0, 0.45),
    13: (-1.0, -0.32, 16.0, -3.0, 0.30),
    14: (-1.0, -0.15, 16.0, -3.0, 0.30),
    15: (-1.0, -0.15, 24.0, -2.8, 0.15),
}

#: Names accepted for the usual types.
SKY_TYPE_NAMES = {"overcast": 1, "clear": 12, "intermediate": 7}

#: Angular radius of the sun's disc seen from the Earth (mean), degrees.
SUN_RADIUS_DEG = 0.2666

#: Sun-to-sky horizontal illuminance ratio used when none is given: 4 for the clear
#: types (11-15, a typical clear day with the sun well up), 1 for the intermediate
#: ones (6-10) and 0 for the overcast ones (1-5, the sun hidden).
_DEFAULT_SUN_RATIO = {**{t: 0.0 for t in range(1, 6)}, **{t: 1.0 for t in range(6, 11)},
                      **{t: 4.0 for t in range(11, 16)}}


def daylight_spectrum(cct: float, grid: SpectralGrid = REFERENCE_GRID) -> NDArray[np.float64]:
    """CIE daylight (D series) spectral distribution of correlated colour temperature ``cct``, ``Y = 1``.

    Parameters
    ----------
    cct
        Correlated colour temperature in K, 4000-25000 (the range of the
        CIE daylight locus).
    grid
        Wavelength grid.

    Returns
    -------
    ndarray
        ``(n,)`` relative spectral radiance with luminance ``Y = 1``.

    Raises
    ------
    EnvironmentMapError
        ``cct`` outside 4000-25000 K or not finite.

    References
    ----------
    CIE 015:2018, section 4.1. doi:10.25039/TR.015.2018

    Examples
    --------
    >>> s = daylight_spectrum(6504)
    >>> round(float(spectra_to_xyz(s)[1]), 6)
    1.0
    """
    import colour

    if not (isinstance(cct, (int, float, np.integer, np.floating)) and not isinstance(cct, bool)
            and math.isfinite(float(cct)) and 4000.0 <= float(cct) <= 25000.0):
        raise EnvironmentMapError(f"sky: cct must be a colour temperature of 4000-25000 K (the CIE daylight "
                                  f"locus), got {cct!r}")
    xy = colour.temperature.CCT_to_xy_CIE_D(float(cct))
    sd = colour.sd_CIE_illuminant_D_series(xy)
    s = resample(sd.wavelengths, sd.values, grid)
    return s / float(spectra_to_xyz(s, grid)[1])


def _sky_coefficients(sky_type: int) -> tuple[float, float, float, float, float]:
    if isinstance(sky_type, str):
        if sky_type.strip().lower() in SKY_TYPE_NAMES:
            return CIE_SKY_TYPES[SKY_TYPE_NAMES[sky_type.strip().lower()]]
        try:
            sky_type = int(sky_type)
        except ValueError:
            sky_type = -1
    if isinstance(sky_type, bool) or not isinstance(sky_type, (int, np.integer)) or int(sky_type) not in CIE_SKY_TYPES:
        raise EnvironmentMapError(f"sky: type must be 1-15 (CIE general sky) or one of "
                                  f"{', '.join(SKY_TYPE_NAMES)}, got {sky_type!r}")
    return CIE_SKY_TYPES[int(sky_type)]


def cie_sky_relative_luminance(zenith_angle: ArrayLike, sun_angle: ArrayLike, sun_zenith_angle: float,
                               sky_type: int | str = 12) -> NDArray[np.float64]:
    """Luminance of sky elements relative to the zenith, CIE general sky.

    Parameters
    ----------
    zenith_angle
        Zenith angle ``Z`` of the elements in radians, ``[0, pi/2]``.
    sun_angle
        Angle ``chi`` between the element and the sun in radians.
    sun_zenith_angle
        Zenith angle ``Zs`` of the sun in radians.
    sky_type
        1-15, or ``"overcast"`` (1), ``"intermediate"`` (7), ``"clear"`` (12).

    Returns
    -------
    ndarray
        ``L / Lz``, the broadcast shape of the angles.

    References
    ----------
    CIE S 011/E:2003 (ISO 15469:2004).

    Examples
    --------
    The overcast sky is three times brighter at the zenith than at the horizon:

    >>> round(float(cie_sky_relative_luminance(np.pi / 2, 1.0, 0.5, "overcast")), 3)
    0.335
    """
    a, b, c, d, e = _sky_coefficients(sky_type)

    def gradation(z: NDArray[np.float64]) -> NDArray[np.float64]:
        cz = np.cos(z)
        with np.errstate(divide="ignore", over="ignore", under="ignore"):
            g = np.where(cz > 1e-9, np.exp(b / np.maximum(cz, 1e-9)), 0.0)
        return 1.0 + a * g

    def indicatrix(chi: NDArray[np.float64]) -> NDArray[np.float64]:
        return 1.0 + c * (np.exp(d * chi) - math.exp(d * math.pi / 2.0)) + e * np.cos(chi) ** 2

    z = np.asarray(zenith_angle, dtype=np.float64)
    chi = np.asarray(sun_angle, dtype=np.float64)
    return indicatrix(chi) * gradation(z) / (indicatrix(np.float64(sun_zenith_angle)) * gradation(np.float64(0.0)))


@dataclass(frozen=True)
class SkyParameters:
    """The settings of :func:`daylight_sky` (for messages and files).

    Attributes
    ----------
    cct, sun_cct
        Colour temperatures of the sky and the sun light, K.
    sun_elevation_deg, sun_azimuth_deg
        Sun position: elevation above the horizon, azimuth from +x toward +y.
    sky_type
        CIE general sky type 1-15.
    sun
        Sun-to-sky horizontal illuminance ratio.
    luminance
        Luminance of a white Lambertian surface facing up under sky and sun.
    ground
        Ground reflectance.
    """

    cct: float
    sun_cct: float
    sun_elevation_deg: float
    sun_azimuth_deg: float
    sky_type: int
    sun: float
    luminance: float
    ground: float


def _finite(name: str, value: object, low: float | None = None, high: float | None = None,
            open_low: bool = False) -> float:
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    v = float(value) if ok else math.nan
    if not math.isfinite(v) or (low is not None and (v < low or (open_low and v == low))) \
            or (high is not None and v > high):
        span = "" if low is None else (f" > {low:g}" if open_low else f" >= {low:g}") \
            if high is None else f" in {low:g}..{high:g}"
        raise EnvironmentMapError(f"sky: {name} must be a finite number{span}, got {value!r}")
    return v


def daylight_sky(cct: float = 6500.0, sun_elevation_deg: float = 40.0, sun_azimuth_deg: float = 0.0, *,
                 sky_type: int | str = "clear", sun: float | None = None, sun_cct: float = 5500.0,
                 luminance: float = 1.0, ground: float = 0.2, height: int = 128,
                 grid: SpectralGrid = REFERENCE_GRID) -> EnvironmentMap:
    """An outdoor sky as a spectral environment map (CIE general sky, CIE daylight spectra, a sun disc).

    Parameters
    ----------
    cct
        Correlated colour temperature of the sky light in K (4000-25000).
    sun_elevation_deg
        Sun elevation above the horizon, degrees (-90..90; at or below 0
        there is no sun disc and the sky's sun position still shapes it).
    sun_azimuth_deg
        Sun azimuth from +x toward +y, degrees.
    sky_type
        CIE general sky type 1-15 or ``"clear"`` (12), ``"intermediate"``
        (7), ``"overcast"`` (1).
    sun
        Horizontal illuminance of the sun relative to the sky's (>= 0);
        None: 4 for the clear types 11-15, 1 for 6-10, 0 for the overcast
        types 1-5.
    sun_cct
        Correlated colour temperature of the direct sun light in K.
    luminance
        Luminance of a white Lambertian surface facing up under sky and
        sun (> 0), the unit of the render.
    ground
        Reflectance of the Lambertian ground below the horizon, 0..1.
    height
        Rows of the map (it is ``2 height`` wide), >= 8.
    grid
        Wavelength grid of the basis.

    Returns
    -------
    EnvironmentMap
        ``K = 2`` (sky daylight, sun daylight), source ``"sky ..."``.

    Raises
    ------
    EnvironmentMapError
        A value out of range (one line naming it).

    References
    ----------
    CIE S 011/E:2003 (ISO 15469:2004); CIE 015:2018, doi:10.25039/TR.015.2018.

    Examples
    --------
    >>> sky = daylight_sky(sky_type="overcast", height=16)
    >>> float(sky.coefficients[..., 1].max())          # no sun in an overcast sky
    0.0
    """
    coeffs = _sky_coefficients(sky_type)
    type_number = next(t for t, v in CIE_SKY_TYPES.items() if v == coeffs)
    elevation = _finite("sun_elevation", sun_elevation_deg, -90.0, 90.0)
    azimuth = _finite("sun_azimuth", sun_azimuth_deg)
    ratio = _DEFAULT_SUN_RATIO[type_number] if sun is None else _finite("sun", sun, 0.0)
    lum = _finite("luminance", luminance, 0.0, open_low=True)
    rho = _finite("ground", ground, 0.0, 1.0)
    if isinstance(height, bool) or not isinstance(height, (int, np.integer)) or not 8 <= int(height) <= 4096:
        raise EnvironmentMapError(f"sky: height must be a whole number of rows in 8..4096, got {height!r}")
    h = int(height)
    w = 2 * h
    basis = np.stack([daylight_spectrum(cct, grid), daylight_spectrum(sun_cct, grid)])
    params = SkyParameters(float(cct), float(sun_cct), elevation, azimuth, type_number, ratio, lum, rho)

    theta = np.pi * (np.arange(h) + 0.5) / h
    phi = 2.0 * np.pi * (np.arange(w) + 0.5) / w
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    d = np.stack(np.broadcast_arrays(st * np.cos(phi), st * np.sin(phi), ct + 0.0 * phi), axis=-1)
    el, az = math.radians(elevation), math.radians(azimuth)
    sun_dir = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    chi = np.arccos(np.clip(d @ sun_dir, -1.0, 1.0))
    upper = (ct > 0.0) & np.ones((1, w), dtype=bool)
    zs = math.pi / 2.0 - el
    rel = np.where(upper, cie_sky_relative_luminance(np.minimum(theta[:, None], np.pi / 2), chi, zs, type_number), 0.0)
    rel = np.maximum(rel, 0.0)

    cos_weight = _cosine_weights(h, w)
    sky_e = float((rel * cos_weight).sum())                             # horizontal illuminance per unit Lz
    sky_e_target = math.pi * lum / (1.0 + ratio)
    sky = rel * (sky_e_target / sky_e)

    sun_map = np.zeros((h, w))
    sun_e = 0.0
    if ratio > 0.0 and elevation > 0.0:
        radius = max(math.radians(SUN_RADIUS_DEG), 1.5 * math.pi / h)
        disc = (chi <= radius) & upper
        if not disc.any():                                              # the nearest pixel at least
            disc = np.zeros_like(disc)
            disc[np.unravel_index(np.argmin(np.where(upper, chi, np.inf)), chi.shape)] = True
        weight = disc * cos_weight
        sun_e = sky_e_target * ratio
        sun_map = np.where(disc, sun_e / float(weight.sum()), 0.0)
    ground_radiance = rho * np.array([sky_e_target, sun_e]) / math.pi
    out = np.empty((h, w, 2), dtype=np.float32)
    out[..., 0] = np.where(upper, sky, ground_radiance[0])
    out[..., 1] = np.where(upper, sun_map, ground_radiance[1])
    source = (f"sky cct={params.cct:g} sun_elevation={elevation:g} sun_azimuth={azimuth:g} "
              f"type={type_number} sun={ratio:g}")
    return EnvironmentMap(out, basis, grid, source=source)


def horizontal_luminance(env: EnvironmentMap) -> float:
    """Luminance of a white Lambertian surface facing up (+z) under ``env``: ``E_h / pi``.

    The upper hemisphere's radiance only (the ground does not light a
    surface facing up); a numerical integral over the map's pixels.

    Parameters
    ----------
    env
        The environment.

    Returns
    -------
    float
        ``(1/pi) sum L(d) max(0, d.z) dOmega`` in luminance units.

    Examples
    --------
    >>> from processing.lighting.environment_map import uniform_environment
    >>> round(horizontal_luminance(uniform_environment(2.0, height=64)), 3)
    2.0
    """
    return float((env.pixel_luminance() * _cosine_weights(env.height, env.width)).sum() / math.pi)


def _cosine_weights(height: int, width: int) -> NDArray[np.float64]:
    """``(H, 1)``: integral of ``max(0, cos theta)`` over one pixel of each row (sr), exact per row."""
    edges = np.pi * np.arange(height + 1) / height
    c = np.clip(np.cos(edges), 0.0, 1.0)
    return (0.5 * (c[:-1] ** 2 - c[1:] ** 2) * (2.0 * np.pi / width))[:, None]
