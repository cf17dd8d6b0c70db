"""From spectra to display colour: XYZ, white normalisation, sRGB, gamut policy.

``X, Y, Z = k sum_lambda C(lambda) xbar/ybar/zbar(lambda) step`` with the CIE
1931 2 degree colour-matching functions of
:func:`processing.spectral.spectra.cmfs` and k such that a perfect white
Lambertian diffuser lit at normal incidence has Y = 1; its XYZ (the scene
white) is adapted to the D65 white of sRGB, the sRGB matrix gives linear RGB,
a stated gamut policy brings it into [0, 1] and the sRGB transfer curve
encodes it.  docs/materials.md, "From spectra to the display" and
"Out-of-gamut policy", describes each step.

References
----------
CIE 015:2018 Colorimetry, 4th edition, section 7. doi:10.25039/TR.015.2018

IEC 61966-2-1:1999, Multimedia systems and equipment -- Colour measurement
and management -- Default RGB colour space -- sRGB (no DOI).
"""

from __future__ import annotations

import functools

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.errors import InputError
from processing.spectral.spectra import REFERENCE_GRID, SpectralGrid, cmfs

__all__ = [
    "spectra_to_xyz",
    "xyz_scale",
    "white_xyz",
    "xyz_to_linear_srgb",
    "gamut_map",
    "encode_srgb8",
    "xyz_to_srgb8",
    "delta_e00",
    "GAMUT_POLICIES",
    "SRGB_LUMINANCE",
    "adaptation_methods",
]

#: Out-of-gamut policies of :func:`gamut_map`: 'desaturate' (towards the grey of equal luminance) and 'clip'.
GAMUT_POLICIES: tuple[str, ...] = ("desaturate", "clip")

#: Luminance Y of the linear sRGB primaries (IEC 61966-2-1, rounded to 4 decimals).
SRGB_LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def _finite(name: str, a: ArrayLike) -> NDArray[np.floating]:
    """``a`` as a floating array (float64 unless already floating), refused if not finite."""
    arr = np.asarray(a)
    if not np.issubdtype(arr.dtype, np.floating):
        arr = arr.astype(np.float64)
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name} contains NaN or infinite values")
    return arr


def _check_grid(grid: object) -> SpectralGrid:
    """``grid`` if it is a SpectralGrid."""
    if not isinstance(grid, SpectralGrid):
        raise InputError(f"grid must be a processing.spectral.spectra.SpectralGrid, got {type(grid).__name__}")
    return grid


def _out_dtype(arr: NDArray[np.floating]) -> type:
    """float32 for float32 input, else float64."""
    return np.float32 if arr.dtype == np.float32 else np.float64


def spectra_to_xyz(spectra: ArrayLike, grid: SpectralGrid = REFERENCE_GRID) -> NDArray[np.floating]:
    """Unscaled tristimulus values sum C(lambda) cmf(lambda) d_lambda.

    Parameters
    ----------
    spectra
        Spectral radiance (or any spectral quantity), shape ``(..., L)``.
    grid
        The wavelength grid of the last axis.

    Returns
    -------
    ndarray
        Shape ``(..., 3)``: X, Y, Z in units of ``spectra`` times nm
        (float32 for float32 input, else float64).

    Raises
    ------
    ValueError
        ``grid`` is not a SpectralGrid, ``spectra`` not finite or not on it.

    References
    ----------
    CIE 015:2018 Colorimetry, 4th edition, section 7. doi:10.25039/TR.015.2018

    Examples
    --------
    >>> round(float(spectra_to_xyz(np.ones(61))[1]), 3)   # integral of ybar
    106.857
    """
    _check_grid(grid)
    s = _finite("spectra", spectra)
    if s.ndim == 0 or s.shape[-1] != grid.size:
        raise InputError(
            f"spectra must have the {grid.size} wavelengths of the grid "
            f"({grid.start:g}-{grid.stop:g} nm, step {grid.step:g}) on the last axis, got shape {s.shape}"
        )
    out = s @ (cmfs(grid) * grid.step)
    return out.astype(_out_dtype(s), copy=False)


def _check_light(light: ArrayLike, grid: SpectralGrid) -> NDArray[np.float64]:
    """A finite, non-negative ``(L,)`` light on ``grid`` as float64."""
    _check_grid(grid)
    e = np.asarray(_finite("light", light), dtype=np.float64)
    if e.shape != (grid.size,):
        raise InputError(f"light must have shape ({grid.size},) for this grid, got {e.shape}")
    if np.any(e < 0):
        raise InputError("light spectral power must be >= 0")
    return e


def xyz_scale(light: ArrayLike, grid: SpectralGrid = REFERENCE_GRID) -> float:
    """Factor k with ``k * spectra_to_xyz(light / pi)`` having Y = 1.

    A perfect white Lambertian diffuser (BRDF 1/pi) lit at normal incidence
    by ``light`` reflects radiance ``light / pi``; with this k it appears with
    Y = 1.  Multiply the XYZ of rendered radiance by k.

    Parameters
    ----------
    light
        ``(L,)`` spectral power of the light (any units, >= 0).
    grid
        The wavelength grid of ``light``.

    Returns
    -------
    float
        k, in inverse units of ``light`` times nm.

    Raises
    ------
    ValueError
        A bad grid or light, or a light with no luminance on the grid.

    Examples
    --------
    >>> from processing.spectral.spectra import light_spectrum
    >>> e = light_spectrum("D65")
    >>> k = xyz_scale(e)
    >>> round(float(k * spectra_to_xyz(e / np.pi)[1]), 12)
    1.0
    """
    e = _check_light(light, grid)
    y = float(spectra_to_xyz(e / np.pi, grid)[1])
    if not y > 0:
        raise InputError("light has no luminance on this grid (Y = 0); check the light spectrum")
    return 1.0 / y


def white_xyz(light: ArrayLike, grid: SpectralGrid = REFERENCE_GRID) -> NDArray[np.float64]:
    """XYZ of the perfect white diffuser under ``light`` (Y = 1): the scene white.

    Parameters
    ----------
    light
        ``(L,)`` spectral power of the light (any units, >= 0).
    grid
        The wavelength grid of ``light``.

    Returns
    -------
    ndarray
        ``(3,)`` float64 X, Y, Z with Y = 1.

    Raises
    ------
    ValueError
        As :func:`xyz_scale`.

    Examples
    --------
    >>> from processing.spectral.spectra import light_spectrum
    >>> w = white_xyz(light_spectrum("D65"))
    >>> [round(float(v), 2) for v in w]     # D65: (0.9505, 1, 1.0888)
    [0.95, 1.0, 1.09]
    """
    e = _check_light(light, grid)
    return xyz_scale(e, grid) * np.asarray(spectra_to_xyz(e / np.pi, grid), dtype=np.float64)


@functools.lru_cache(maxsize=1)
def _srgb() -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The XYZ -> linear sRGB matrix and the XYZ of the D65 white of sRGB."""
    import colour

    cs = colour.RGB_COLOURSPACES["sRGB"]
    # The matrix derived from the primaries and the D65 white point (the
    # 4-decimal matrix printed in IEC 61966-2-1 maps white to 1 +- 2e-4).
    npm = colour.normalised_primary_matrix(cs.primaries, cs.whitepoint)
    return np.linalg.inv(np.asarray(npm, dtype=np.float64)), np.asarray(
        colour.xy_to_XYZ(cs.whitepoint), dtype=np.float64
    )


@functools.lru_cache(maxsize=1)
def _cat_names() -> dict[str, str]:
    """colour-science's chromatic adaptation transforms by lower-case name."""
    import colour

    return {k.lower(): k for k in colour.CHROMATIC_ADAPTATION_TRANSFORMS}


def adaptation_methods() -> list[str]:
    """Chromatic adaptation transforms accepted by :func:`xyz_to_linear_srgb`.

    Returns
    -------
    list of str
        Names of colour-science's ``CHROMATIC_ADAPTATION_TRANSFORMS``, sorted
        (matched case-insensitively).

    Examples
    --------
    >>> {"CAT02", "Bradford"} <= set(adaptation_methods())
    True
    """
    return sorted(_cat_names().values())


def _check_white(source_white: ArrayLike) -> NDArray[np.float64]:
    """A white's XYZ as three positive float64 values."""
    w = np.asarray(_finite("source_white", source_white), dtype=np.float64)
    if w.shape != (3,) or np.any(w <= 0):
        raise InputError(
            f"source_white must be the XYZ (3 positive values) of the scene white, e.g. "
            f"white_xyz(light, grid); got {w.tolist() if w.size <= 6 else w.shape}"
        )
    return w


def _xyz_to_rgb_matrix(source_white: NDArray[np.float64], adapt: bool, method: str) -> NDArray[np.float64]:
    """Scene XYZ -> linear sRGB, through the adaptation from ``source_white`` to D65 when ``adapt``."""
    m_rgb, d65 = _srgb()
    if not adapt:
        return m_rgb
    key = _cat_names().get(str(method).lower())
    if key is None:
        raise InputError(
            f"unknown chromatic adaptation method {method!r}; use one of: {', '.join(adaptation_methods())}"
        )
    import colour

    m_cat = colour.adaptation.matrix_chromatic_adaptation_VonKries(source_white, d65, transform=key)
    return m_rgb @ np.asarray(m_cat, dtype=np.float64)


def xyz_to_linear_srgb(
    xyz: ArrayLike,
    source_white: ArrayLike,
    *,
    adapt: bool = True,
    method: str = "CAT02",
) -> NDArray[np.floating]:
    """Linear sRGB of scene XYZ, adapted from the scene white to D65.

    Parameters
    ----------
    xyz
        Shape ``(..., 3)``, scaled so the scene white has Y = 1.
    source_white
        XYZ of the scene white (:func:`white_xyz`).
    adapt
        Apply the chromatic adaptation (von Kries form, colour-science's
        ``matrix_chromatic_adaptation_VonKries``); without it the XYZ go
        straight through the sRGB matrix and a non-D65 light shows its cast.
    method
        ``"CAT02"`` (default), ``"Bradford"`` or another transform of
        :func:`adaptation_methods`.

    Returns
    -------
    ndarray
        Linear sRGB, shape ``(..., 3)``, unbounded (see :func:`gamut_map`).

    Raises
    ------
    ValueError
        ``xyz`` not finite or without X, Y, Z on the last axis, a bad
        ``source_white``, or an unknown adaptation method.

    References
    ----------
    IEC 61966-2-1:1999, default RGB colour space -- sRGB (no DOI).

    Examples
    --------
    >>> from processing.spectral.spectra import light_spectrum
    >>> w = white_xyz(light_spectrum("A"))
    >>> [round(float(v), 6) for v in xyz_to_linear_srgb(w, w)]
    [1.0, 1.0, 1.0]
    """
    x = _finite("xyz", xyz)
    if x.ndim == 0 or x.shape[-1] != 3:
        raise InputError(f"xyz must have X, Y, Z on the last axis, got shape {x.shape}")
    m = _xyz_to_rgb_matrix(_check_white(source_white), adapt, method)
    return (x @ m.T).astype(_out_dtype(x), copy=False)


def gamut_map(linear_rgb: ArrayLike, policy: str = "desaturate") -> NDArray[np.floating]:
    """Bring linear sRGB into [0, 1] with a stated out-of-gamut policy.

    Parameters
    ----------
    linear_rgb
        Shape ``(..., 3)``, finite.
    policy
        ``"desaturate"``: negative components are removed by moving towards
        the grey of equal luminance (hue and luminance kept; Y <= 0 becomes
        black), then values above 1 are clipped.  ``"clip"``: clip each
        component to [0, 1].

    Returns
    -------
    ndarray
        Same shape, every value in [0, 1] (float32 for float32 input, else
        float64).

    Raises
    ------
    ValueError
        Values not finite, not ``(..., 3)``, or an unknown policy.

    Examples
    --------
    >>> rgb = gamut_map([0.5, -0.1, 0.2])
    >>> float(rgb.min()) >= 0.0, round(float(rgb @ SRGB_LUMINANCE), 6) == round(0.5 * 0.2126 - 0.1 * 0.7152 + 0.2 * 0.0722, 6)
    (True, True)
    """
    rgb = _finite("linear_rgb", linear_rgb)
    if rgb.ndim == 0 or rgb.shape[-1] != 3:
        raise InputError(f"linear_rgb must have R, G, B on the last axis, got shape {rgb.shape}")
    if policy not in GAMUT_POLICIES:
        raise InputError(f"unknown gamut policy {policy!r}; use one of: {', '.join(GAMUT_POLICIES)}")
    dtype = _out_dtype(rgb)
    rgb = rgb.astype(np.float64)
    if policy == "desaturate":
        y = (rgb @ SRGB_LUMINANCE)[..., None]
        lo = rgb.min(axis=-1, keepdims=True)
        neg = lo < 0
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(neg & (y > 0), y / np.where(neg, y - lo, 1.0), 1.0)
        rgb = np.where(neg & (y <= 0), 0.0, y + t * (rgb - y))
    return np.clip(rgb, 0.0, 1.0).astype(dtype, copy=False)


def encode_srgb8(linear: ArrayLike) -> NDArray[np.uint8]:
    """SRGB transfer curve (IEC 61966-2-1) and 8-bit quantisation.

    Values are clipped to [0, 1] first (use :func:`gamut_map` to choose how).

    Parameters
    ----------
    linear
        Linear sRGB values of any shape (1 = white).

    Returns
    -------
    ndarray
        uint8 codes of the same shape, rounded to nearest.

    Raises
    ------
    ValueError
        Values not finite.

    References
    ----------
    IEC 61966-2-1:1999, default RGB colour space -- sRGB (no DOI).

    Examples
    --------
    >>> encode_srgb8([0.0, 0.18, 1.0]).tolist()
    [0, 118, 255]
    """
    v = np.clip(np.asarray(_finite("linear", linear), dtype=np.float64), 0.0, 1.0)
    encoded = np.where(v <= 0.0031308, 12.92 * v, 1.055 * np.power(v, 1.0 / 2.4) - 0.055)
    return np.round(encoded * 255.0).astype(np.uint8)


def xyz_to_srgb8(
    xyz: ArrayLike,
    source_white: ArrayLike,
    *,
    adapt: bool = True,
    method: str = "CAT02",
    policy: str = "desaturate",
) -> NDArray[np.uint8]:
    """XYZ -> adapted linear sRGB -> gamut policy -> 8-bit sRGB.

    Parameters
    ----------
    xyz
        Shape ``(..., 3)``, scaled so the scene white has Y = 1.
    source_white
        XYZ of the scene white (:func:`white_xyz`).
    adapt, method
        As :func:`xyz_to_linear_srgb`.
    policy
        One of :data:`GAMUT_POLICIES` (:func:`gamut_map`).

    Returns
    -------
    ndarray
        ``(..., 3)`` uint8 sRGB.

    Raises
    ------
    ValueError
        As :func:`xyz_to_linear_srgb` and :func:`gamut_map`.

    Examples
    --------
    >>> from processing.spectral.spectra import light_spectrum
    >>> w = white_xyz(light_spectrum("D65"))
    >>> xyz_to_srgb8(w, w).tolist()
    [255, 255, 255]
    """
    rgb = xyz_to_linear_srgb(xyz, source_white, adapt=adapt, method=method)
    return encode_srgb8(gamut_map(rgb, policy))


def delta_e00(xyz_a: ArrayLike, xyz_b: ArrayLike, white: ArrayLike) -> NDArray[np.float64]:
    """CIEDE2000 colour difference of two XYZ arrays relative to ``white``.

    Parameters
    ----------
    xyz_a, xyz_b
        Shape ``(..., 3)``, broadcastable.
    white
        XYZ of the reference white (CIELAB is computed with Y scaled so the
        white has Y = 1, and its chromaticity as the illuminant).

    Returns
    -------
    ndarray
        Shape ``broadcast(...)`` (colour-science ``delta_E``, "CIE 2000").

    Raises
    ------
    ValueError
        Values not finite or without X, Y, Z on the last axis, or a bad white.

    References
    ----------
    CIE 015:2018 Colorimetry, 4th edition (the CIEDE2000 formula).
    doi:10.25039/TR.015.2018

    Examples
    --------
    >>> w = np.array([0.9505, 1.0, 1.089])
    >>> float(delta_e00(0.5 * w, 0.5 * w, w))
    0.0
    """
    import colour

    w = _check_white(white)
    a = np.asarray(_finite("xyz_a", xyz_a), dtype=np.float64) / w[1]
    b = np.asarray(_finite("xyz_b", xyz_b), dtype=np.float64) / w[1]
    if a.shape[-1:] != (3,) or b.shape[-1:] != (3,):
        raise InputError(f"xyz_a and xyz_b must have X, Y, Z on the last axis, got {a.shape}, {b.shape}")
    xy = colour.XYZ_to_xy(w)
    lab_a = colour.XYZ_to_Lab(a, xy)
    lab_b = colour.XYZ_to_Lab(b, xy)
    return np.asarray(colour.delta_E(lab_a, lab_b, method="CIE 2000"), dtype=np.float64)
