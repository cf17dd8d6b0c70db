"""Spectral environment maps: the light arriving at the table from every direction.

An :class:`EnvironmentMap` holds equirectangular radiance around the table
as ``K`` coefficients per pixel of a small spectral basis: the spectral
radiance along a direction is ``coefficients(d) @ basis``.  A light probe
shot with the station's camera carries the basis of the camera's own chart
calibration (so the environment is spectral as measured, not RGB
upsampled); an HDR file from elsewhere carries linear sRGB (Rec. 709
primaries, D65 white), upsampled by the three basis spectra of Mallett and
Yuksel (2019) times D65, so that a pixel (1, 1, 1) is D65 light of
luminance ``Y = 1``.

Frame and layout (the table frame T: z along the turntable axis, up):
row ``i`` of an ``H x 2H`` map is the polar angle
``theta = pi (i + 0.5) / H`` from +z (row 0 is the zenith), column ``j``
the azimuth ``phi = 2 pi (j + 0.5) / W`` from +x towards +y, so the pixel's
direction is ``(sin theta cos phi, sin theta sin phi, cos theta)``.  A
rotation ``rotation_deg`` turns the map about +z (counter-clockwise seen
from above); ``intensity`` scales it.  Radiance is relative (the renderer
and the probe agree on one scale: a map of constant coefficient ``c``
whose spectrum has luminance ``Y`` gives a white Lambertian surface facing
up the luminance ``c Y``).

Files: OpenEXR (``.exr``, float RGB, linear) and Radiance (``.hdr``).
:func:`write_environment` stores linear sRGB in the RGB channels (any
viewer shows the map) and the spectral basis matched to those channels in
the header attribute ``kogeiSpectralBasis`` (JSON: ``wavelengths_nm`` and
three rows ``basis``; a map with colours outside sRGB stores its own
coefficients and basis instead, ``channels: "coefficients"``; a map of
``K != 3`` basis spectra stores its coefficients in channels ``kogei.c0``
... beside sRGB clipped at 0, ``channels: "coefficient channels"``);
:func:`read_environment` uses that basis when the attribute is there and
Mallett-Yuksel upsampling otherwise.

References
----------
Mallett, I., & Yuksel, C. (2019). Spectral Primary Decomposition for
Rendering with sRGB Reflectance. Eurographics Symposium on Rendering -
DL-only and Industry Track. doi:10.2312/sr.20191216

Debevec, P. (1998). Rendering synthetic objects into real scenes.
Proceedings of SIGGRAPH 98, 189-198. doi:10.1145/280814.280864

Examples
--------
>>> import numpy as np
>>> env = uniform_environment(2.0, height=8)
>>> env.coefficients.shape
(8, 16, 3)
>>> round(float(env.solid_angles().sum() * env.width / (4 * np.pi)), 6)
1.0
>>> round(float(env.luminance(np.array([[0.0, 0.0, 1.0]]))[0]), 6)
2.0
"""

from __future__ import annotations

import functools
import json
import math
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.common.files import JSONFileError, parse_json
from processing.errors import InputError
from processing.spectral.display import spectra_to_xyz
from processing.spectral.spectra import REFERENCE_GRID, SpectralGrid, light_spectrum, resample

__all__ = [
    "EnvironmentMapError",
    "EnvironmentMap",
    "HEADER_KEY",
    "srgb_basis",
    "uniform_environment",
    "pixel_directions",
    "direction_pixels",
    "read_environment",
    "write_environment",
]

#: OpenEXR header attribute holding the spectral basis of the RGB channels.
HEADER_KEY = "kogeiSpectralBasis"
#: Name stem of the channels of a map of K != 3 basis spectra (``kogei.c0`` ...).
COEFFICIENT_CHANNEL = "kogei.c"

# Linear sRGB (Rec. 709 primaries, D65) from CIE XYZ, IEC 61966-2-1.
_XYZ_TO_SRGB = np.array([[3.2406, -1.5372, -0.4986], [-0.9689, 1.8758, 0.0415], [0.0557, -0.2040, 1.0570]])


class EnvironmentMapError(InputError):
    """An environment map or file that cannot be used (one line naming it and the remedy)."""


def _finite_nonnegative(name: str, a: NDArray[np.floating]) -> None:
    bad = ~np.isfinite(a)
    if bad.any():
        raise EnvironmentMapError(f"{name}: {int(bad.sum())} values are NaN or infinite; "
                                  "export the map again as finite linear radiance")
    if (a < 0).any():
        raise EnvironmentMapError(f"{name}: {int((a < 0).sum())} values are negative (lowest {float(a.min()):.3g}); "
                                  "radiance cannot be negative, export the map again without negative values")


def pixel_directions(height: int, width: int, rotation_deg: float = 0.0) -> NDArray[np.float64]:
    """Unit directions ``(H, W, 3)`` of the pixel centres of an equirectangular map.

    Parameters
    ----------
    height, width
        Map size in pixels (``width = 2 height``).
    rotation_deg
        Turn of the map about +z, counter-clockwise seen from above.

    Returns
    -------
    ndarray
        ``(height, width, 3)`` unit vectors in the table frame.

    Examples
    --------
    >>> d = pixel_directions(2, 4)
    >>> [round(float(x), 3) for x in d[0, 0]]
    [0.5, 0.5, 0.707]
    """
    theta = np.pi * (np.arange(height) + 0.5) / height
    phi = 2.0 * np.pi * (np.arange(width) + 0.5) / width + math.radians(rotation_deg)
    st = np.sin(theta)[:, None]
    return np.stack(np.broadcast_arrays(st * np.cos(phi)[None, :], st * np.sin(phi)[None, :],
                                        np.cos(theta)[:, None] + 0.0 * phi[None, :]), axis=-1)


def direction_pixels(directions: ArrayLike, height: int, width: int,
                     rotation_deg: float = 0.0) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Continuous pixel coordinates ``(row, column)`` of unit directions (inverse of :func:`pixel_directions`).

    Parameters
    ----------
    directions
        ``(..., 3)`` unit vectors in the table frame.
    height, width
        Map size in pixels.
    rotation_deg
        Turn of the map about +z.

    Returns
    -------
    tuple of ndarray
        ``row`` in ``[-0.5, H - 0.5]`` and ``column`` in ``[-0.5, W - 0.5)``; pixel
        ``(i, j)`` has its centre at ``(i, j)``.

    Examples
    --------
    >>> r, c = direction_pixels(pixel_directions(4, 8)[1, 5], 4, 8)
    >>> round(float(r), 6), round(float(c), 6)
    (1.0, 5.0)
    """
    d = np.asarray(directions, dtype=np.float64)
    theta = np.arccos(np.clip(d[..., 2], -1.0, 1.0))
    phi = np.mod(np.arctan2(d[..., 1], d[..., 0]) - math.radians(rotation_deg), 2.0 * np.pi)
    return theta / np.pi * height - 0.5, np.mod(phi / (2.0 * np.pi) * width, width) - 0.5


@functools.lru_cache(maxsize=8)
def _srgb_basis_cached(start: float, stop: float, step: float) -> NDArray[np.float64]:
    import colour

    grid = SpectralGrid(start, stop, step)
    b = colour.recovery.MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019
    basis = resample(b.wavelengths, b.values.T, grid)                     # (3, n) reflectance basis
    d65 = light_spectrum("D65", grid)
    emission = basis * d65[None, :]
    white_y = float(spectra_to_xyz(emission.sum(axis=0), grid)[1])
    out = emission / white_y
    out.setflags(write=False)
    return out


def srgb_basis(grid: SpectralGrid = REFERENCE_GRID) -> NDArray[np.float64]:
    """Spectral radiance of a unit linear-sRGB coefficient: ``(3, n)`` on ``grid``.

    Mallett and Yuksel's (2019) reflectance basis times D65, normalised so
    that (1, 1, 1) has luminance ``Y = 1``; its sRGB is the coefficient itself
    (to the accuracy of their decomposition).

    Parameters
    ----------
    grid
        Wavelength grid.

    Returns
    -------
    ndarray
        ``(3, n)`` read-only.

    Examples
    --------
    >>> b = srgb_basis()
    >>> b.shape
    (3, 61)
    >>> round(float(spectra_to_xyz(b.sum(axis=0))[1]), 6)
    1.0
    """
    return _srgb_basis_cached(grid.start, grid.stop, grid.step)


@dataclass(frozen=True, eq=False)
class EnvironmentMap:
    """Radiance around the table as spectral-basis coefficients on an equirectangular grid.

    Parameters
    ----------
    coefficients
        ``(H, W, K)`` finite, non-negative, ``W = 2 H``, ``H >= 2``.
    basis
        ``(K, n)`` spectral radiance of a unit coefficient on ``grid``.
    grid
        The wavelength grid of ``basis``.
    source
        Where the map came from (a file name, ``"probe"``, ``"sky ..."``), for messages.
    rotation_deg
        Turn about +z (counter-clockwise seen from above).
    intensity
        Scale (> 0).
    white
        ``(n,)`` on ``grid``: the spectrum that renders white when the map lights a scene alone (it
        sets the white balance and the exposure: a white Lambertian surface lit by radiance ``white``
        from the whole upper hemisphere renders with ``Y`` of ``white``), e.g. a probe's chart white;
        None: the basis rows together (D65 of ``Y = 1`` for an sRGB map).

    Raises
    ------
    EnvironmentMapError
        A wrong shape or aspect ratio, NaN / infinite / negative values, a
        basis that does not match, a non-positive intensity, a white without
        luminance.
    """

    coefficients: NDArray[np.float32]
    basis: NDArray[np.float64]
    grid: SpectralGrid = REFERENCE_GRID
    source: str = "environment"
    rotation_deg: float = 0.0
    intensity: float = 1.0
    white: NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        c = np.asarray(self.coefficients, dtype=np.float32)
        if c.ndim == 2:
            c = c[..., None]
        if c.ndim != 3 or c.shape[0] < 2:
            raise EnvironmentMapError(f"{self.source}: an environment map must be an image of H x 2H pixels, "
                                      f"got shape {np.shape(self.coefficients)}")
        if c.shape[1] != 2 * c.shape[0]:
            raise EnvironmentMapError(
                f"{self.source}: an equirectangular environment map is twice as wide as high, got "
                f"{c.shape[1]} x {c.shape[0]} pixels; give a latitude-longitude (2:1) map")
        _finite_nonnegative(self.source, c)
        b = np.asarray(self.basis, dtype=np.float64)
        if b.ndim != 2 or b.shape != (c.shape[2], self.grid.size) or not np.isfinite(b).all():
            raise EnvironmentMapError(f"{self.source}: the spectral basis must be finite with shape "
                                      f"({c.shape[2]}, {self.grid.size}), got {b.shape}")
        for name in ("rotation_deg", "intensity"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) \
                    or not math.isfinite(float(v)):
                raise EnvironmentMapError(f"{self.source}: {name} must be a finite number, got {v!r}")
        if float(self.intensity) <= 0.0:
            raise EnvironmentMapError(f"{self.source}: intensity must be > 0, got {self.intensity!r}")
        if self.white is not None:
            wh = np.asarray(self.white, dtype=np.float64)
            if wh.shape != (self.grid.size,) or not np.isfinite(wh).all() or (wh < 0).any() \
                    or not float(spectra_to_xyz(wh, self.grid)[1]) > 0:
                raise EnvironmentMapError(f"{self.source}: the white must be {self.grid.size} finite values >= 0 "
                                          f"with luminance, got shape {wh.shape}")
            wh.setflags(write=False)
            object.__setattr__(self, "white", wh)
        c.setflags(write=False)
        b.setflags(write=False)
        object.__setattr__(self, "coefficients", c)
        object.__setattr__(self, "basis", b)
        object.__setattr__(self, "rotation_deg", float(self.rotation_deg))
        object.__setattr__(self, "intensity", float(self.intensity))

    @property
    def height(self) -> int:
        """Rows H."""
        return int(self.coefficients.shape[0])

    @property
    def width(self) -> int:
        """Columns W = 2 H."""
        return int(self.coefficients.shape[1])

    def with_(self, *, rotation_deg: float | None = None, intensity: float | None = None) -> EnvironmentMap:
        """The same map turned to ``rotation_deg`` and/or scaled to ``intensity``."""
        return replace(self, rotation_deg=self.rotation_deg if rotation_deg is None else rotation_deg,
                       intensity=self.intensity if intensity is None else intensity)

    def directions(self) -> NDArray[np.float64]:
        """``(H, W, 3)`` unit directions of the pixel centres (rotation applied)."""
        return pixel_directions(self.height, self.width, self.rotation_deg)

    def solid_angles(self) -> NDArray[np.float64]:
        """``(H, 1)`` solid angle of one pixel of each row in sr (they sum to 4 pi over the map)."""
        edges = np.pi * np.arange(self.height + 1) / self.height
        return ((np.cos(edges[:-1]) - np.cos(edges[1:])) * (2.0 * np.pi / self.width))[:, None]

    def white_spectrum(self) -> NDArray[np.float64]:
        """``(n,)``: :attr:`white`, or the basis rows together when the map gives none."""
        return np.asarray(self.basis.sum(axis=0) if self.white is None else self.white, dtype=np.float64)

    def pixel_luminance(self) -> NDArray[np.float64]:
        """``(H, W)`` luminance Y of every pixel (intensity applied), e.g. for importance sampling."""
        y_of_basis = spectra_to_xyz(self.basis, self.grid)[:, 1]
        return self.intensity * (self.coefficients.astype(np.float64) @ y_of_basis)

    def lookup(self, directions: ArrayLike) -> NDArray[np.float64]:
        """Coefficients ``(..., K)`` along unit ``directions`` (bilinear, wrapping in azimuth; intensity applied).

        Examples
        --------
        >>> env = uniform_environment(0.5, height=4)
        >>> env.lookup([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]).round(6).tolist()
        [[0.5, 0.5, 0.5], [0.5, 0.5, 0.5]]
        """
        d = np.asarray(directions, dtype=np.float64)
        r, c = direction_pixels(d, self.height, self.width, self.rotation_deg)
        r = np.clip(r, 0.0, self.height - 1.0)
        r0 = np.floor(r).astype(np.intp)
        r1 = np.minimum(r0 + 1, self.height - 1)
        fr = (r - r0)[..., None]
        c0f = np.floor(c)
        fc = (c - c0f)[..., None]
        c0 = np.mod(c0f.astype(np.intp), self.width)
        c1 = np.mod(c0 + 1, self.width)
        m = self.coefficients
        top = m[r0, c0] * (1.0 - fc) + m[r0, c1] * fc
        bottom = m[r1, c0] * (1.0 - fc) + m[r1, c1] * fc
        return self.intensity * (top * (1.0 - fr) + bottom * fr)

    def spectral_radiance(self, directions: ArrayLike) -> NDArray[np.float64]:
        """Spectral radiance ``(..., n)`` along unit ``directions`` on :attr:`grid`."""
        return self.lookup(directions) @ self.basis

    def luminance(self, directions: ArrayLike) -> NDArray[np.float64]:
        """Luminance ``(...)`` along unit ``directions``."""
        return self.lookup(directions) @ spectra_to_xyz(self.basis, self.grid)[:, 1]

    def mean_radiance_spectrum(self) -> NDArray[np.float64]:
        """Solid-angle mean spectral radiance ``(n,)`` over the whole sphere (intensity applied)."""
        w = self.solid_angles() / (4.0 * np.pi)
        mean_c = (self.coefficients.astype(np.float64) * w[..., None]).sum(axis=(0, 1))
        return self.intensity * (mean_c @ self.basis)

    def to_linear_srgb(self) -> NDArray[np.float32]:
        """``(H, W, 3)`` linear sRGB of the map (intensity applied; no rotation), for viewers and files."""
        m = _coefficients_to_srgb(self.basis, self.grid)                 # (K, 3)
        return (self.intensity * (self.coefficients.astype(np.float64) @ m)).astype(np.float32)


def _coefficients_to_srgb(basis: NDArray[np.float64], grid: SpectralGrid) -> NDArray[np.float64]:
    """``(K, 3)``: linear sRGB of a unit coefficient of each basis spectrum."""
    xyz = spectra_to_xyz(basis, grid)                                     # (K, 3), Y of the emission
    return xyz @ _XYZ_TO_SRGB.T


def uniform_environment(radiance_y: float, height: int = 16, spectrum: str = "D65",
                        grid: SpectralGrid = REFERENCE_GRID) -> EnvironmentMap:
    """A constant environment of luminance ``radiance_y`` with the relative spectrum of a named light.

    Parameters
    ----------
    radiance_y
        Luminance of every direction (>= 0).
    height
        Rows of the map.
    spectrum
        Any light :func:`processing.spectral.spectra.light_spectrum` accepts.
    grid
        Wavelength grid.

    Returns
    -------
    EnvironmentMap
        ``K = 3`` coefficients (all ``radiance_y``) on a basis whose three rows sum to
        ``spectrum`` scaled to ``Y = 1``, one third each.
    """
    s = light_spectrum(spectrum, grid)
    s = s / float(spectra_to_xyz(s, grid)[1])
    basis = np.repeat(s[None, :] / 3.0, 3, axis=0)
    coeff = np.full((height, 2 * height, 3), float(radiance_y), dtype=np.float32)
    return EnvironmentMap(coeff, basis, grid, source=f"uniform {spectrum}")


def _coefficient_channels(raw: Any) -> list[str] | None:
    """The coefficient channels a kogei header names (``coefficient_channels``), or None."""
    try:
        meta = None if raw is None else parse_json(raw if isinstance(raw, str) else raw.decode(), HEADER_KEY,
                                                   "write the map again with kogei")
    except (ValueError, UnicodeDecodeError, AttributeError):          # JSONFileError is a ValueError
        return None                                                   # reported by the caller
    names = meta.get("coefficient_channels") if isinstance(meta, dict) else None
    if names is None:
        return None
    if not isinstance(names, list) or not 1 <= len(names) <= 64 or not all(isinstance(n, str) for n in names):
        return []
    return names


def _read_exr(path: Path) -> tuple[NDArray[np.float32], dict | None]:
    import OpenEXR

    try:
        with OpenEXR.File(str(path)) as f:
            # the header's attributes are copied while the file is open: closing it empties the dict
            raw = f.header().get(HEADER_KEY)
            channels = f.channels()
            names = _coefficient_channels(raw)
            if names == []:
                raise EnvironmentMapError(f"{path}: header attribute {HEADER_KEY} names its coefficient channels "
                                          "wrongly; write the map again with kogei")
            if names is not None:
                missing = [n for n in names if n not in channels]
                if missing:
                    raise EnvironmentMapError(f"{path}: the header names coefficient channels the file lacks "
                                              f"({', '.join(missing[:3])}); write the map again with kogei")
                rgb = np.stack([np.asarray(channels[n].pixels, dtype=np.float32) for n in names], axis=-1)
            elif "RGB" in channels:
                rgb = np.asarray(channels["RGB"].pixels, dtype=np.float32)
            elif all(k in channels for k in "RGB"):
                rgb = np.stack([np.asarray(channels[k].pixels, dtype=np.float32) for k in "RGB"], axis=-1)
            elif "Y" in channels:
                y = np.asarray(channels["Y"].pixels, dtype=np.float32)
                rgb = np.repeat(y[..., None], 3, axis=-1)
            else:
                raise EnvironmentMapError(f"{path}: no R, G, B (or Y) channels in this OpenEXR file "
                                          f"(it has {', '.join(sorted(channels)) or 'none'}); export RGB")
    except EnvironmentMapError:
        raise
    except Exception as exc:                                              # OpenEXR raises bare exceptions
        raise EnvironmentMapError(f"{path}: not a readable OpenEXR file ({exc}); "
                                  "export the map again as .exr or .hdr") from None
    meta = None
    if raw is not None:
        try:
            meta = parse_json(raw if isinstance(raw, str) else raw.decode(), HEADER_KEY,
                              "write the map again with kogei")
            if not isinstance(meta, dict):
                raise ValueError("not an object")
        except (ValueError, UnicodeDecodeError) as exc:
            why = exc.reason if isinstance(exc, JSONFileError) else exc
            raise EnvironmentMapError(f"{path}: header attribute {HEADER_KEY} is not valid JSON ({why}); "
                                      "write the map again with kogei") from None
    return rgb, meta


def _read_hdr(path: Path) -> NDArray[np.float32]:
    import cv2

    try:
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    except cv2.error:       # a header declaring more pixels than OpenCV's limit (an image bomb), or damaged data
        raise EnvironmentMapError(f"{path}: OpenCV refuses to read it (a header declaring more pixels than it "
                                  "reads, or damaged data); export the map again as .hdr or .exr") from None
    if img is None or img.ndim != 3 or img.shape[2] < 3:
        raise EnvironmentMapError(f"{path}: not a readable Radiance HDR image; export the map again as .hdr or .exr")
    return np.ascontiguousarray(img[..., 2::-1], dtype=np.float32)


def read_environment(path: str | os.PathLike[str], grid: SpectralGrid = REFERENCE_GRID) -> EnvironmentMap:
    """Read an environment map from an OpenEXR (``.exr``) or Radiance (``.hdr``) file.

    Parameters
    ----------
    path
        The file: equirectangular (2:1), linear, in the table frame's layout.
    grid
        Wavelength grid of the returned basis.

    Returns
    -------
    EnvironmentMap
        With the spectral basis stored by kogei in the file's header, else the
        sRGB upsampling of :func:`srgb_basis`.

    Raises
    ------
    EnvironmentMapError
        A missing or unreadable file, another extension, a wrong aspect ratio,
        NaN / infinite / negative values, a malformed basis.
    """
    p = Path(path)
    if not p.is_file():
        raise EnvironmentMapError(f"{p}: no such environment map; give an existing .exr or .hdr file")
    ext = p.suffix.lower()
    meta = None
    if ext == ".exr":
        rgb, meta = _read_exr(p)
    elif ext == ".hdr":
        rgb = _read_hdr(p)
    else:
        raise EnvironmentMapError(f"{p}: environment maps are read from .exr or .hdr files, not {ext or 'no extension'}")
    basis = srgb_basis(grid)
    white = None
    if meta is not None:
        try:
            wl = np.asarray(meta["wavelengths_nm"], dtype=np.float64)
            rows = np.asarray(meta["basis"], dtype=np.float64)
            if wl.ndim != 1 or rows.ndim != 2 or rows.shape != (rgb.shape[2], wl.size) or wl.size < 2:
                raise ValueError(f"basis shape {rows.shape} for {wl.size} wavelengths")
            if not (np.isfinite(wl).all() and np.isfinite(rows).all()):
                raise ValueError("NaN or infinite values")
            basis = resample(wl, rows, grid)
            if meta.get("white") is not None:
                white_rows = np.asarray(meta["white"], dtype=np.float64)
                if white_rows.shape != (wl.size,) or not np.isfinite(white_rows).all():
                    raise ValueError(f"white of shape {white_rows.shape} for {wl.size} wavelengths")
                white = resample(wl, white_rows[None, :], grid)[0]
        except (KeyError, TypeError, ValueError) as exc:
            raise EnvironmentMapError(f"{p}: the spectral basis in header {HEADER_KEY} is malformed ({exc}); "
                                      "write the map again with kogei") from None
    return EnvironmentMap(rgb, basis, grid, source=str(p), white=white)


def write_environment(path: str | os.PathLike[str], env: EnvironmentMap) -> Path:
    """Write ``env`` as OpenEXR: linear sRGB channels plus the matching spectral basis in the header.

    The RGB channels are the map's linear sRGB (any viewer shows it); the
    header's basis ``B'`` satisfies ``rgb @ B' = coefficients @ basis``, so
    :func:`read_environment` gives back the same spectra.  A map with colours
    outside sRGB (negative sRGB somewhere) is stored as its own coefficients
    and basis instead (header ``channels``: ``"coefficients"``), which
    kogei reads back exactly.  The map's
    intensity is applied; its rotation is not (it is a viewing setting).

    Parameters
    ----------
    path
        Output ``.exr`` file (its folder must exist).
    env
        The map: ``K = 3`` coefficients with an invertible sRGB matrix, or any other ``K`` (stored
        in channels of their own).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    EnvironmentMapError
        Not ``.exr``, a missing folder, a basis whose sRGB matrix is singular.
    """
    import OpenEXR

    p = Path(path)
    if p.suffix.lower() != ".exr":
        raise EnvironmentMapError(f"{p}: environment maps are written as .exr; give a file name ending in .exr")
    if not p.parent.is_dir():
        raise EnvironmentMapError(f"{p}: the folder {p.parent} does not exist; create it first")
    m = _coefficients_to_srgb(env.basis, env.grid)                      # (K, 3)
    k = m.shape[0]
    extra: dict[str, np.ndarray] = {}
    if k != 3:
        # K basis spectra (a probe of two bracket sets): the K coefficients in channels of their own, and
        # the map's sRGB (clipped at 0) in R, G, B for viewers
        rgb = np.maximum(env.to_linear_srgb(), 0.0)
        names = [f"{COEFFICIENT_CHANNEL}{i}" for i in range(k)]
        extra = {n: np.ascontiguousarray(env.intensity * env.coefficients[..., i], dtype=np.float32)
                 for i, n in enumerate(names)}
        meta = {"wavelengths_nm": env.grid.wavelengths.tolist(), "basis": env.basis.tolist(), "source": env.source,
                "channels": "coefficient channels", "coefficient_channels": names}
        if env.white is not None:
            meta["white"] = env.white.tolist()
    else:
        if abs(np.linalg.det(m)) < 1e-12 * max(1.0, float(np.abs(m).max()) ** 3):
            raise EnvironmentMapError(f"{env.source}: its spectral basis has no invertible sRGB matrix; "
                                      "it cannot be stored as RGB")
        rgb = env.to_linear_srgb()
        basis_rgb = np.linalg.solve(m, env.basis)                        # rgb @ B' = c @ B
        channels = "linear sRGB"
        if float(rgb.min()) < 0.0:
            # colours outside sRGB (a saturated wall in a probe) have negative sRGB, which no reader accepts as
            # radiance: store the map's own non-negative coefficients and basis instead (kogei reads them
            # exactly; other viewers show them as if they were sRGB)
            rgb = (env.intensity * env.coefficients).astype(np.float32)
            basis_rgb = env.basis
            channels = "coefficients"
        meta = {"wavelengths_nm": env.grid.wavelengths.tolist(), "basis": basis_rgb.tolist(), "source": env.source,
                "channels": channels}
        if env.white is not None:
            meta["white"] = env.white.tolist()
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, HEADER_KEY: json.dumps(meta)}
    with OpenEXR.File(header, {"RGB": np.ascontiguousarray(rgb), **extra}) as f:
        f.write(str(p))
    return p
