"""Woven cloth: specular, internal and diffuse reflection of warp and weft (Yasuda et al.).

Per yarn direction (warp along the tangent t, weft across it) a cloth is a
specular lobe (the yarn ellipsoid with the fibre's Fresnel reflectance,
eq. (1)), K internal fibre-layer lobes (eq. (2)-(4)) and a Lambert lobe in
the Kubelka-Munk colour of the dye (eq. (5)); the two yarn directions are
weighted by their visible fractions.  A dye is an absorption spectrum
c(lambda) per layer thickness, given directly or derived from an sRGB
colour.  docs/cloth.md, section "The model", states it as implemented.

References
----------
.. [1] Yasuda, Yokoi, Toriwaki, Inagaki, "A shading model for cloth
   objects", IEEE Computer Graphics and Applications 12(6), 15-24 (1992),
   doi:10.1109/38.163621.
.. [2] Kubelka & Munk, "Ein Beitrag zur Optik der Farbanstriche",
   Zeitschrift fur technische Physik 12, 593-601 (1931) (no DOI).
.. [3] Mallett & Yuksel, "Spectral primary decomposition for rendering
   with sRGB reflectance", EGSR 2019, doi:10.2312/SR.20191216.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.cloth.anisotropic_microfacet import check_axes
from processing.errors import InputError
from processing.materials.dielectric_model import DielectricFresnel, PigmentReflectance
from processing.materials.fresnel import fresnel_dielectric
from processing.materials.lobes import Lobe, Material, checked_parameter

__all__ = [
    "FIBRE_INDEX",
    "MAX_LAYERS",
    "Dye",
    "Yarn",
    "InternalLayerReflectance",
    "kubelka_munk_reflectance",
    "kubelka_munk_ratio",
    "layer_axes",
    "layer_normaliser",
    "parse_colour",
    "cloth_material",
]

#: Refractive index of the fibre: silk fibroin about 1.54-1.59, cotton
#: cellulose about 1.53-1.58 (Morton & Hearle, "Physical Properties of
#: Textile Fibres", 4th ed., ch. 22).
FIBRE_INDEX = 1.55

#: Most internal layers accepted.
MAX_LAYERS = 50

_DYE_WL = np.arange(380.0, 780.0 + 0.5, 5.0)


def kubelka_munk_reflectance(ratio: ArrayLike) -> NDArray[np.float64]:
    """Reflectance of an opaque layer from ``K/S`` (Kubelka & Munk 1931).

    ``R = 1 + x - sqrt(x^2 + 2 x)``, written as ``1 / (1 + x + sqrt(x^2 + 2x))``
    so that large x loses no digits.

    Parameters
    ----------
    ratio
        ``x = K/S`` >= 0, the absorption over the scattering coefficient.

    Returns
    -------
    ndarray
        Reflectance R in (0, 1], same shape.

    References
    ----------
    .. [1] Kubelka & Munk (1931) (no DOI).

    Examples
    --------
    >>> kubelka_munk_reflectance([0.0, 0.25]).round(6).tolist()
    [1.0, 0.5]
    """
    x = np.asarray(ratio, dtype=np.float64)
    with np.errstate(over="ignore"):
        return 1.0 / (1.0 + x + np.sqrt(x * x + 2.0 * x))


def kubelka_munk_ratio(reflectance: ArrayLike) -> NDArray[np.float64]:
    """``K/S = (1 - R)^2 / (2 R)``, the inverse of :func:`kubelka_munk_reflectance`.

    Parameters
    ----------
    reflectance
        Reflectance R of an opaque layer, in (0, 1].

    Returns
    -------
    ndarray
        K/S >= 0, same shape.

    Raises
    ------
    ValueError
        A reflectance that is not finite or outside (0, 1].

    References
    ----------
    .. [1] Kubelka & Munk (1931) (no DOI).

    Examples
    --------
    >>> kubelka_munk_ratio([1.0, 0.5]).tolist()
    [0.0, 0.25]
    """
    r = np.asarray(reflectance, dtype=np.float64)
    if np.any(~np.isfinite(r)) or np.any(r <= 0) or np.any(r > 1):
        raise InputError("a Kubelka-Munk reflectance must be in (0, 1]")
    return (1.0 - r) ** 2 / (2.0 * r)


def parse_colour(text: str | tuple | list, what: str = "colour") -> tuple[float, float, float]:
    """An sRGB colour from ``"#rrggbb"`` / ``"rrggbb"`` or three numbers in [0, 1].

    Parameters
    ----------
    text
        A hex string or a sequence of three numbers.
    what
        What the colour is, for the message.

    Returns
    -------
    tuple of float
        ``(r, g, b)`` in [0, 1] (gamma-encoded sRGB).

    Raises
    ------
    ValueError
        Not a six-digit hex colour or three numbers in [0, 1].

    Examples
    --------
    >>> parse_colour("#ff8000")
    (1.0, 0.5019607843137255, 0.0)
    """
    if isinstance(text, str):
        s = text.strip().lstrip("#")
        if len(s) != 6 or any(ch not in "0123456789abcdefABCDEF" for ch in s):
            raise InputError(f"{what} must be an sRGB hex colour such as '#8c1a2b', got {text!r}")
        return tuple(int(s[i:i + 2], 16) / 255.0 for i in (0, 2, 4))  # type: ignore[return-value]
    try:
        rgb = tuple(float(v) for v in text)
    except (TypeError, ValueError):
        raise InputError(f"{what} must be a hex colour or three numbers in [0, 1], got {text!r}") from None
    if len(rgb) != 3 or not all(math.isfinite(v) and 0.0 <= v <= 1.0 for v in rgb):
        raise InputError(f"{what} must be three numbers in [0, 1] (sRGB), got {text!r}")
    return rgb  # type: ignore[return-value]


@functools.lru_cache(maxsize=64)
def _srgb_reflectance(rgb: tuple[float, float, float]) -> NDArray[np.float64]:
    """Reflectance spectrum (Mallett & Yuksel 2019) of an sRGB colour on the dye wavelengths, read-only."""
    import colour
    from colour.recovery import RGB_to_sd_Mallett2019

    linear = np.asarray(colour.cctf_decoding(np.asarray(rgb, dtype=np.float64), function="sRGB"))
    sd = RGB_to_sd_Mallett2019(linear)
    values = np.interp(_DYE_WL, sd.wavelengths, sd.values)
    values.setflags(write=False)
    return values


@dataclass(frozen=True, eq=False)
class Dye:
    """Absorption of the dyed fibre, c(lambda), per layer thickness.

    Attributes
    ----------
    wavelengths
        nm, strictly increasing.
    absorbance
        c(lambda) >= 0 (natural-log absorption per layer thickness) at those
        wavelengths.
    name
        For messages and reports.

    Raises
    ------
    ValueError
        Mismatched or too short arrays, wavelengths not strictly increasing,
        or a negative or non-finite absorbance.
    """

    wavelengths: NDArray[np.float64]
    absorbance: NDArray[np.float64]
    name: str = ""

    def __post_init__(self) -> None:
        wl = np.asarray(self.wavelengths, dtype=np.float64)
        c = np.asarray(self.absorbance, dtype=np.float64)
        if wl.ndim != 1 or wl.size < 2 or c.shape != wl.shape:
            raise InputError(
                f"dye wavelengths (shape {wl.shape}) and absorbance (shape {c.shape}) must be 1-D arrays "
                "of the same length >= 2"
            )
        if not np.all(np.isfinite(wl)) or not np.all(np.diff(wl) > 0):
            raise InputError("dye wavelengths must be finite and strictly increasing (nm)")
        if not np.all(np.isfinite(c)) or np.any(c < 0):
            raise InputError("dye absorbance c(lambda) must be finite and >= 0 (per layer thickness)")
        object.__setattr__(self, "wavelengths", wl)
        object.__setattr__(self, "absorbance", c)

    @classmethod
    def from_srgb(cls, colour_: str | tuple | list, scattering: float = 1.0) -> Dye:
        """The dye whose Kubelka-Munk body reflectance has the sRGB colour ``colour_``.

        Parameters
        ----------
        colour_
            ``"#rrggbb"`` or three sRGB values in [0, 1].
        scattering
            Scattering per layer thickness S (> 0); c = S * K/S.

        Returns
        -------
        Dye
            Absorbance on 380-780 nm every 5 nm, named by the hex colour.

        Raises
        ------
        ValueError
            A bad colour, or a scattering outside (0, 1000].

        References
        ----------
        .. [1] Mallett & Yuksel (2019), doi:10.2312/SR.20191216.
        .. [2] Kubelka & Munk (1931) (no DOI).

        Examples
        --------
        >>> red = Dye.from_srgb("#b01020")
        >>> bool(red.at([450.0])[0] > 5 * red.at([650.0])[0])   # absorbs blue, not red
        True
        """
        rgb = parse_colour(colour_, "dye colour")
        s = checked_parameter("scattering", scattering, open_zero=True, upper=1e3)
        r = np.clip(_srgb_reflectance(rgb), 1e-4, 1.0)
        hexa = "#" + "".join(f"{round(v * 255):02x}" for v in rgb)
        return cls(_DYE_WL, s * kubelka_munk_ratio(r), name=hexa)

    def at(self, wavelengths: ArrayLike) -> NDArray[np.float64]:
        """c(lambda) at ``wavelengths``, interpolated linearly, held constant outside.

        Parameters
        ----------
        wavelengths
            Wavelengths in nm, L of them (flattened).

        Returns
        -------
        ndarray
            ``(L,)`` absorbance per layer thickness.
        """
        wl = np.asarray(wavelengths, dtype=np.float64).reshape(-1)
        return np.interp(wl, self.wavelengths, self.absorbance)


@dataclass(frozen=True)
class Yarn:
    """One yarn direction: its ellipsoid axes and dye.

    Attributes
    ----------
    kind
        ``"filament"`` (untwisted, e.g. silk: an elongated ellipsoid) or
        ``"spun"`` (twisted staple fibres, e.g. cotton: a rounder one).
    a_t, a_b
        Ellipsoid semi-axes along the yarn and across it (the normal axis is 1).
    dye
        The yarn's :class:`Dye`.

    Raises
    ------
    ValueError
        An unknown kind, or axes outside
        :data:`processing.cloth.anisotropic_microfacet.AXIS_RANGE`.
    """

    kind: str
    a_t: float
    a_b: float
    dye: Dye

    def __post_init__(self) -> None:
        if self.kind not in ("filament", "spun"):
            raise InputError(f"yarn kind must be 'filament' or 'spun', got {self.kind!r}")
        check_axes(self.a_t, self.a_b, f"{self.kind} yarn ellipsoid")


def layer_axes(a_t: float, a_b: float, k: int, rounding: float) -> tuple[float, float]:
    """Ellipsoid axes of internal layer ``k``: rounder with depth (Yasuda et al., Fig. 12).

    The axes move geometrically toward the larger one,
    ``a_k = a^(1 - w_k) a_max^w_k`` with ``w_k = 1 - (1 - rounding)^k``.

    Parameters
    ----------
    a_t, a_b
        Semi-axes of the yarn's surface ellipsoid.
    k
        Layer number (1-based).
    rounding
        How fast the layers grow round with depth, in [0, 1].

    Returns
    -------
    tuple of float
        ``(a_t, a_b)`` of layer k.

    References
    ----------
    .. [1] Yasuda et al. (1992), doi:10.1109/38.163621.

    Examples
    --------
    >>> [round(v, 6) for v in layer_axes(0.05, 0.5, 1, 0.0)]
    [0.05, 0.5]
    >>> [round(v, 6) for v in layer_axes(0.05, 0.5, 1, 1.0)]
    [0.5, 0.5]
    """
    w = 1.0 - (1.0 - rounding) ** k
    top = max(a_t, a_b)
    # clipped to [a, top]: exp(log) may round past the largest accepted axis
    return (min(top, max(a_t, math.exp((1.0 - w) * math.log(a_t) + w * math.log(top)))),
            min(top, max(a_b, math.exp((1.0 - w) * math.log(a_b) + w * math.log(top)))))


def layer_normaliser(layers: int, n: float) -> float:
    """``sum_k max_{r in [F(n, 0 deg), 1]} r (1 - r)^(2k)``, k = 1..layers.

    The maximum of ``r (1 - r)^(2k)`` is at ``r = 1 / (2k + 1)`` (or at the
    normal-incidence reflectance when that is larger).  Dividing the layer
    factors by it keeps their sum at or below 1 at every angle.

    Parameters
    ----------
    layers
        Number K of internal layers.
    n
        Fibre refractive index.

    Returns
    -------
    float
        The normaliser N (0 for no layers).

    Examples
    --------
    >>> round(layer_normaliser(1, 1.5), 6)   # r = 1/3: (1/3)(2/3)^2
    0.148148
    """
    r0 = float(fresnel_dielectric(1.0, n))
    k = np.arange(1, layers + 1, dtype=np.float64)
    r = np.maximum(r0, 1.0 / (2.0 * k + 1.0))
    return float(np.sum(r * (1.0 - r) ** (2.0 * k)))


class InternalLayerReflectance:
    """Spectral factor of internal layer k: ``r t^(2k) exp(-c(lambda) 2k / cos theta_t) / N``.

    Implements :class:`processing.materials.lobes.SpectralFactor`: layer k
    reflects once after crossing 2k boundaries (t = 1 - r, r the fibre's
    Fresnel reflectance at theta_d) and travels ``2k / cos theta_t`` layer
    thicknesses through dyed fibre (Yasuda et al., eq. (2)-(4)).  Computed in
    log space, so r^m t^n with large m, n and exp of large absorptions
    underflow cleanly to 0.

    Parameters
    ----------
    n
        Fibre refractive index (>= 1).
    dye
        The yarn's dye.
    k
        Layer number, 1..:data:`MAX_LAYERS`.
    normaliser
        N of :func:`layer_normaliser` for the material's layer count.

    Raises
    ------
    ValueError
        A layer number outside 1..:data:`MAX_LAYERS`, n < 1, or a
        non-positive normaliser.

    References
    ----------
    .. [1] Yasuda et al. (1992), eq. (2)-(4), doi:10.1109/38.163621.

    Examples
    --------
    >>> clear = Dye(np.array([400.0, 700.0]), np.zeros(2))
    >>> f = InternalLayerReflectance(1.5, clear, 1, 1.0)
    >>> [round(float(v), 6) for v in f.reflectance(1.0, [500.0])]   # 0.04 * 0.96^2
    [0.036864]
    """

    angle_dependent = True

    def __init__(self, n: float, dye: Dye, k: int, normaliser: float) -> None:
        if not (isinstance(k, (int, np.integer)) and 1 <= k <= MAX_LAYERS):
            raise InputError(f"layer number k must be an integer in 1..{MAX_LAYERS}, got {k!r}")
        if not (math.isfinite(n) and n >= 1.0):
            raise InputError(f"fibre index n must be >= 1, got {n!r}")
        if not (math.isfinite(normaliser) and normaliser > 0):
            raise InputError(f"layer normaliser must be > 0, got {normaliser!r}")
        self.n, self.dye, self.k, self.normaliser = float(n), dye, int(k), float(normaliser)

    def reflectance(self, cos_d: ArrayLike, wavelengths: ArrayLike) -> NDArray[np.float64]:
        """The layer's factor at ``cos_d`` and ``wavelengths``.

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
        c = np.clip(np.asarray(cos_d, dtype=np.float64), 0.0, 1.0)
        r = fresnel_dielectric(c, self.n)
        # refraction angle in the fibre; for n >= 1 it stays above sqrt(1 - 1/n^2) (0 only for n = 1)
        cos_t = np.sqrt(1.0 - (1.0 - c * c) / (self.n * self.n))
        with np.errstate(divide="ignore", over="ignore", under="ignore", invalid="ignore"):
            log_rt = np.log(r) + 2.0 * self.k * np.log1p(-r) - math.log(self.normaliser)
            path = 2.0 * self.k / np.maximum(cos_t, 1e-300)
            out = np.exp(log_rt[..., None] - path[..., None] * self.dye.at(wl))
        return np.clip(np.nan_to_num(out, nan=0.0, posinf=0.0), 0.0, 1.0)


def _yarn_lobes(yarn: Yarn, fraction: float, swap: bool, *, specular: float, internal: float, diffuse: float,
                layers: int, rounding: float, n: float, scattering: float) -> list[Lobe]:
    """The lobes of one yarn direction; ``swap`` puts the yarn along b (the weft)."""
    if fraction <= 0.0:
        return []
    fresnel = DielectricFresnel(n)
    norm = layer_normaliser(layers, n)

    def axes(a_t: float, a_b: float) -> tuple[float, float]:
        return (a_b, a_t) if swap else (a_t, a_b)

    at, ab = axes(yarn.a_t, yarn.a_b)
    lobes = [Lobe("anisotropic", specular * fraction, fresnel, at, roughness_b=ab)]
    for k in range(1, layers + 1):
        kt, kb = axes(*layer_axes(yarn.a_t, yarn.a_b, k, rounding))
        lobes.append(Lobe("anisotropic", internal * fraction, InternalLayerReflectance(n, yarn.dye, k, norm),
                          kt, roughness_b=kb))
    body = kubelka_munk_reflectance(yarn.dye.absorbance / scattering)
    lobes.append(Lobe("lambert", diffuse * fraction, PigmentReflectance(yarn.dye.wavelengths, body)))
    return lobes


def cloth_material(
    name: str,
    warp: Yarn,
    weft: Yarn,
    *,
    warp_fraction: float = 0.5,
    specular: float = 0.2,
    internal: float = 0.3,
    diffuse: float = 0.5,
    layers: int = 4,
    rounding: float = 0.4,
    n: float = FIBRE_INDEX,
    scattering: float = 1.0,
    weft_weights: tuple[float, float, float] | None = None,
    description: str = "",
    parameters: dict | None = None,
) -> Material:
    """A woven cloth (Yasuda et al.): specular + K internal layers + diffuse, per yarn direction.

    Parameters
    ----------
    name
        Material name.
    warp, weft
        The yarns along the tangent t (warp) and across it (weft).
    warp_fraction
        Visible fraction of warp in [0, 1] (plain weave 0.5, satin ~0.8).
    specular, internal, diffuse
        Weights of the three components, each in [0, 1], sum <= 1.
    layers
        Number K of internal layers, 0..:data:`MAX_LAYERS` (0: no internal term).
    rounding
        How fast the layer ellipsoids grow round with depth, in [0, 1].
    n
        Fibre refractive index in [1, 3].
    scattering
        Kubelka-Munk scattering per layer thickness (> 0): the diffuse body
        reflectance is ``KM(c / scattering)``.
    weft_weights
        ``(specular, internal, diffuse)`` of the weft when it differs from the
        warp (default: the same weights).  A filament yarn of parallel
        transparent fibres sends its dyed light mostly into the internal lobe;
        a spun yarn of twisted staple fibres scatters it in all directions
        (mostly diffuse); shot silk weaves one of each.
    description
        Free text.
    parameters
        Parameter record stored on the material (default: the arguments).

    Returns
    -------
    Material
        Family ``"cloth"``; lobes of the warp then of the weft, each:
        one specular, ``layers`` internal (anisotropic), one Lambert.

    Raises
    ------
    ValueError
        Yarns that are not :class:`Yarn`, a parameter out of range, a bad
        layer count, or weights summing above 1.

    References
    ----------
    .. [1] Yasuda et al. (1992), eq. (1)-(5), doi:10.1109/38.163621.
    .. [2] Kubelka & Munk (1931) (no DOI).

    Examples
    --------
    >>> dye = Dye.from_srgb("#b01020")
    >>> m = cloth_material("silk", Yarn("filament", 0.05, 0.4, dye), Yarn("filament", 0.05, 0.4, dye), layers=2)
    >>> [lobe.kind for lobe in m.lobes][:4], len(m.lobes), m.lobes[0].roughness_b, m.lobes[4].roughness_b
    (['anisotropic', 'anisotropic', 'anisotropic', 'lambert'], 8, 0.4, 0.05)
    """
    for what, yarn in (("warp", warp), ("weft", weft)):
        if not isinstance(yarn, Yarn):
            raise InputError(f"{what} must be a processing.cloth.model.Yarn, got {type(yarn).__name__}")
    warp_fraction = checked_parameter("warp_fraction", warp_fraction)
    specular = checked_parameter("specular", specular)
    internal = checked_parameter("internal", internal)
    diffuse = checked_parameter("diffuse", diffuse)
    rounding = checked_parameter("rounding", rounding)
    n = checked_parameter("n", n, open_zero=True, upper=3.0)
    if n < 1.0:
        raise InputError(f"n must be in [1, 3] for a fibre, got {n!r}")
    scattering = checked_parameter("scattering", scattering, open_zero=True, upper=1e3)
    if isinstance(layers, bool) or not isinstance(layers, (int, np.integer)) or not 0 <= layers <= MAX_LAYERS:
        raise InputError(f"layers must be an integer in 0..{MAX_LAYERS}, got {layers!r}")
    if weft_weights is None:
        weft_weights = (specular, internal, diffuse)
    if len(weft_weights) != 3:
        raise InputError(f"weft_weights must be (specular, internal, diffuse), got {weft_weights!r}")
    weft_weights = tuple(checked_parameter(f"weft_{what}", v)
                         for what, v in zip(("specular", "internal", "diffuse"), weft_weights))
    for who, weights in (("", (specular, internal, diffuse)), ("weft_", weft_weights)):
        total = sum(weights)
        if total > 1.0 + 1e-12:
            raise InputError(
                f"{who}specular + {who}internal + {who}diffuse = {total:g} exceeds 1 (energy conservation); "
                "lower one of them"
            )
    common = dict(layers=int(layers), rounding=rounding, n=n, scattering=scattering)
    warp_w = dict(specular=specular, internal=internal, diffuse=diffuse)
    weft_w = dict(zip(("specular", "internal", "diffuse"), weft_weights))
    lobes = (_yarn_lobes(warp, warp_fraction, False, **warp_w, **common)
             + _yarn_lobes(weft, 1.0 - warp_fraction, True, **weft_w, **common))
    if parameters is None:
        parameters = {"warp_fraction": warp_fraction, **warp_w, **common, "a_t": warp.a_t, "a_b": warp.a_b,
                      "weft_a_t": weft.a_t, "weft_a_b": weft.a_b,
                      **{f"weft_{k}": v for k, v in weft_w.items()}}
    return Material(name, tuple(lobes), family="cloth", description=description, parameters=dict(parameters))
