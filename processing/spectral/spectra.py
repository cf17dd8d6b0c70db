"""Wavelength grids, colour-matching functions, light spectra and resampling.

A :class:`SpectralGrid` fixes how spectra are sampled (400-700 nm at 5 nm,
:data:`REFERENCE_GRID`, is the reference); a sampled spectrum is read as the
piecewise-linear function through its samples, held constant beyond the
ends; :func:`cmfs` integrates that function against the 1-nm CIE 1931 2 degree
tables, :func:`resample` brings user spectra onto a grid (hat averages for
lamps) and :func:`light_spectrum` gives CIE illuminants, Planckian and
daylight sources or measured CSV spectra.  docs/materials.md, "From spectra
to the display", gives the sampling rules and their accuracy.

References
----------
CIE 015:2018 Colorimetry, 4th edition. doi:10.25039/TR.015.2018
(colour-matching functions; Planck's law, eq. 1; the daylight locus,
section 4.1).
"""

from __future__ import annotations

import functools
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.errors import InputError

__all__ = [
    "SpectralGrid",
    "REFERENCE_GRID",
    "CMF_RANGE",
    "cmfs",
    "light_spectrum",
    "resample",
    "illuminant_names",
    "transmission_spectrum",
]

#: Wavelength range (nm) of the CIE 1931 2 degree tables used here.
CMF_RANGE: tuple[float, float] = (360.0, 830.0)

_CMFS_NAME = "CIE 1931 2 Degree Standard Observer"
#: Second radiation constant (m K) of CIE 015:2018 and of the ITS-90 scale.
_C2 = 1.4388e-2
#: The CIE daylight formula was defined with c2 = 1.4380e-2 m K; nominal
#: temperatures are rescaled by this factor so that "6500K" is D65 (6504 K).
_DAYLIGHT_C2_RATIO = 1.4388 / 1.4380
_NORMALISATION_NM = 560.0
_CCT_RANGE = (1000.0, 25000.0)
_PLANCK_BELOW = 4000.0


@dataclass(frozen=True)
class SpectralGrid:
    """A regular wavelength grid in nm, inclusive of both ends.

    Parameters
    ----------
    start, stop
        First and last wavelength in nm, within 360-830 nm (the range of
        the CIE colour-matching functions), ``start < stop``.
    step
        Spacing in nm (> 0), dividing ``stop - start`` exactly.

    Raises
    ------
    ValueError
        A bound or step that is not a finite number, a range outside
        360-830 nm or empty, or a step that does not divide it.

    Examples
    --------
    >>> SpectralGrid().size
    61
    >>> SpectralGrid(400, 700, 20).wavelengths[:3].tolist()
    [400.0, 420.0, 440.0]
    """

    start: float = 400.0
    stop: float = 700.0
    step: float = 5.0

    def __post_init__(self) -> None:
        for name in ("start", "stop", "step"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
                raise InputError(f"SpectralGrid {name} must be a number in nm, got {value!r}")
            if not math.isfinite(float(value)):
                raise InputError(f"SpectralGrid {name} must be finite, got {value!r}")
            object.__setattr__(self, name, float(value))
        lo, hi = CMF_RANGE
        if not (lo <= self.start < self.stop <= hi):
            raise InputError(
                f"SpectralGrid needs {lo:g} <= start < stop <= {hi:g} nm (the range of the "
                f"CIE colour-matching functions), got start={self.start:g}, stop={self.stop:g}"
            )
        if self.step <= 0:
            raise InputError(f"SpectralGrid step must be > 0 nm, got {self.step:g}")
        count = (self.stop - self.start) / self.step
        if abs(count - round(count)) > 1e-9 * max(1.0, count):
            raise InputError(
                f"SpectralGrid step {self.step:g} nm does not divide the range "
                f"{self.start:g}-{self.stop:g} nm; choose a step such as 5, 10 or 20 nm"
            )

    @property
    def size(self) -> int:
        """Number of samples L."""
        return int(round((self.stop - self.start) / self.step)) + 1

    @property
    def wavelengths(self) -> NDArray[np.float64]:
        """Sample wavelengths in nm, shape ``(size,)``, float64."""
        return self.start + self.step * np.arange(self.size, dtype=np.float64)


#: The reference grid: 400-700 nm at 5 nm, 61 samples.
REFERENCE_GRID = SpectralGrid()


# ---------------------------------------------------------------------------
# piecewise-linear resampling machinery


def _interp_matrix(knots: NDArray[np.float64], x: NDArray[np.float64]) -> NDArray[np.float64]:
    """Matrix M (len(x), len(knots)) with ``M @ v`` the linear interpolant of ``v`` at ``x``.

    ``v`` is sampled at ``knots``; the interpolant is held constant outside them.
    """
    n = knots.size
    xc = np.clip(x, knots[0], knots[-1])
    idx = np.clip(np.searchsorted(knots, xc, side="right") - 1, 0, n - 2)
    t = (xc - knots[idx]) / (knots[idx + 1] - knots[idx])
    m = np.zeros((x.size, n))
    rows = np.arange(x.size)
    m[rows, idx] = 1.0 - t
    m[rows, idx + 1] += t
    return m


def _hat_average_matrix(
    src: NDArray[np.float64], centres: NDArray[np.float64], half_width: float
) -> NDArray[np.float64]:
    """Matrix W (len(centres), len(src)): row i averages the source under a hat centred on ``centres[i]``.

    The source is piecewise linear.  The hat's half width is ``half_width``, narrowed near the ends of the
    source so that it stays symmetric (a linear spectrum is then reproduced
    exactly; a centre on the boundary is point-sampled).  Both factors are
    piecewise linear, so Simpson's rule on the union of their knots
    integrates the product exactly.
    """
    widths_c = np.minimum(half_width, np.minimum(centres - src[0], src[-1] - centres))
    point = widths_c <= 1e-9 * half_width
    h = np.where(point, half_width, widths_c)
    knots = np.concatenate([src, centres, centres - h, centres + h])
    knots = np.unique(np.clip(knots, src[0], src[-1]))
    mids = 0.5 * (knots[:-1] + knots[1:])
    widths = np.diff(knots)
    # Simpson weights: ends of each interval get width/6, midpoints 4 width/6.
    w_knots = np.zeros(knots.size)
    w_knots[:-1] += widths / 6.0
    w_knots[1:] += widths / 6.0
    w_mids = 4.0 * widths / 6.0

    def hats(x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Each centre's hat at ``x``: ``(len(centres), len(x))``."""
        return np.clip(1.0 - np.abs(x[None, :] - centres[:, None]) / h[:, None], 0.0, None)

    raw = (hats(knots) * w_knots) @ _interp_matrix(src, knots) + (hats(mids) * w_mids) @ _interp_matrix(
        src, mids
    )
    out = raw / raw.sum(axis=1, keepdims=True)
    if np.any(point):
        out[point] = _interp_matrix(src, centres[point])
    return out


def _as_wavelengths(name: str, wavelengths: ArrayLike) -> NDArray[np.float64]:
    """Wavelengths as a finite, strictly increasing 1-D float64 array."""
    wl = np.asarray(wavelengths, dtype=np.float64)
    if wl.ndim != 1 or wl.size < 1:
        raise InputError(f"{name} must be a 1-D array of wavelengths in nm, got shape {wl.shape}")
    if not np.all(np.isfinite(wl)):
        raise InputError(f"{name} contains NaN or infinite wavelengths")
    if wl.size > 1 and not np.all(np.diff(wl) > 0):
        raise InputError(f"{name} must be strictly increasing (nm)")
    return wl


def _regular_step(wl: NDArray[np.float64]) -> float | None:
    """The common step of regular wavelengths, or None."""
    if wl.size < 2:
        return None
    d = np.diff(wl)
    return float(d[0]) if np.allclose(d, d[0], rtol=1e-9, atol=1e-9) else None


def resample(
    wavelengths_src: ArrayLike,
    values: ArrayLike,
    grid: SpectralGrid | ArrayLike,
    *,
    method: str = "interpolate",
) -> NDArray[np.float64]:
    """Resample a spectrum (or a stack of spectra) onto a grid.

    Parameters
    ----------
    wavelengths_src
        Source wavelengths in nm, shape ``(N,)``, strictly increasing, N >= 2.
    values
        Source values, shape ``(..., N)``.
    grid
        A :class:`SpectralGrid` or a 1-D array of target wavelengths in nm,
        which must lie inside the source range.
    method
        ``"interpolate"`` (default): the linear interpolant at each target
        wavelength; it reproduces the source exactly when the grids coincide
        and is the better choice for smooth spectra (reflectances).
        ``"average"``: when the target is regular with step ``h`` and every
        source interval is at most ``h / 2``, the average of the
        (piecewise-linear) source under the hat of half width ``h`` centred on
        each sample (narrowed symmetrically where it would leave the source
        range), so the narrow lines of a lamp are not aliased on a coarse
        grid; otherwise the linear interpolant.  Light spectra use it.

    Returns
    -------
    ndarray
        Shape ``(..., L)``, float64.

    Raises
    ------
    ValueError
        An unknown method, bad wavelengths, values not matching them or not
        finite, or a grid outside the source range.

    Examples
    --------
    >>> r = resample([400, 500, 600, 700], [0.1, 0.2, 0.3, 0.4], SpectralGrid(400, 700, 50))
    >>> [round(float(v), 3) for v in r]
    [0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4]
    """
    if method not in ("interpolate", "average"):
        raise InputError(f"resample method={method!r} is not known; use 'interpolate' or 'average'")
    src = _as_wavelengths("wavelengths_src", wavelengths_src)
    if src.size < 2:
        raise InputError("wavelengths_src needs at least two samples to resample a spectrum")
    vals = np.asarray(values, dtype=np.float64)
    if vals.ndim == 0 or vals.shape[-1] != src.size:
        raise InputError(
            f"values must have the wavelengths on the last axis ({src.size} samples), "
            f"got shape {vals.shape}"
        )
    if not np.all(np.isfinite(vals)):
        raise InputError("values contains NaN or infinite entries; clean the spectrum first")
    if isinstance(grid, SpectralGrid):
        target, step = grid.wavelengths, grid.step
    else:
        target = _as_wavelengths("grid", grid)
        step = _regular_step(target)
    tol = 1e-6
    if target[0] < src[0] - tol or target[-1] > src[-1] + tol:
        raise InputError(
            f"the spectrum covers {src[0]:g}-{src[-1]:g} nm but the grid needs "
            f"{target[0]:g}-{target[-1]:g} nm; supply data over the whole grid (wavelengths in nm)"
        )
    if method == "average" and step is not None and float(np.max(np.diff(src))) <= 0.5 * step + 1e-9:
        w = _hat_average_matrix(src, target, step)
    else:
        w = _interp_matrix(src, target)
    return vals @ w.T


# ---------------------------------------------------------------------------
# colour-matching functions


@functools.lru_cache(maxsize=1)
def _cmfs_1nm() -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The 1-nm CIE 1931 2 degree tables of colour-science: wavelengths and ``(N, 3)`` values (read-only)."""
    import colour

    table = colour.MSDS_CMFS[_CMFS_NAME]
    wl = np.asarray(table.wavelengths, dtype=np.float64)
    vals = np.asarray(table.values, dtype=np.float64)
    wl.setflags(write=False)
    vals.setflags(write=False)
    return wl, vals


@functools.lru_cache(maxsize=64)
def _cmfs_cached(start: float, stop: float, step: float) -> NDArray[np.float64]:
    """:func:`cmfs` of the grid ``(start, stop, step)``, cached."""
    grid = SpectralGrid(start, stop, step)
    wl_1nm, cmf_1nm = _cmfs_1nm()
    # phi_i(lambda_j): the hat of sample i at each 1-nm wavelength, held
    # constant beyond the ends, so the rows sum to 1 (partition of unity).
    phi = _interp_matrix(grid.wavelengths, wl_1nm).T
    out = phi @ cmf_1nm * (1.0 / grid.step)
    out.setflags(write=False)
    return out


def cmfs(grid: SpectralGrid = REFERENCE_GRID) -> NDArray[np.float64]:
    """CIE 1931 2 degree colour-matching functions aligned to ``grid``.

    Row i is ``sum_j phi_i(lambda_j) cmf(lambda_j) * 1 nm / step`` over the
    1-nm table (360-830 nm), with ``phi_i`` the piecewise-linear hat of sample
    i, extended as a constant beyond the first and last sample.  Hence
    ``sum(spectrum * cmfs(grid), axis=-2) * step`` is the 1-nm Riemann sum of
    the linearly interpolated spectrum against the CIE tables; on the 1-nm
    grid 360-830 nm it is the table itself, and on any grid the columns sum
    (times ``step``) to the totals of the 1-nm table.

    Parameters
    ----------
    grid
        The wavelength grid.

    Returns
    -------
    ndarray
        Shape ``(L, 3)``: xbar, ybar, zbar (read-only).

    Raises
    ------
    ValueError
        ``grid`` is not a SpectralGrid.

    References
    ----------
    CIE 015:2018 Colorimetry, 4th edition. doi:10.25039/TR.015.2018

    Examples
    --------
    >>> c = cmfs(SpectralGrid(400, 700, 5))
    >>> c.shape
    (61, 3)
    >>> round(float(c[:, 1].sum() * 5), 3)   # the integral of ybar, 106.857 nm
    106.857
    """
    if not isinstance(grid, SpectralGrid):
        raise InputError(f"grid must be a SpectralGrid, got {type(grid).__name__}")
    return _cmfs_cached(grid.start, grid.stop, grid.step)


# ---------------------------------------------------------------------------
# light sources


@functools.lru_cache(maxsize=1)
def _illuminant_table() -> dict[str, str]:
    """Map of lower-case accepted names to colour-science illuminant keys."""
    import colour

    names: dict[str, str] = {}
    for key in colour.SDS_ILLUMINANTS:
        names[key.lower()] = key
        m = re.fullmatch(r"FL(\d+)", key)
        if m:  # the CIE names F1..F12 for the fluorescent lamps
            names[f"f{m.group(1)}"] = key
    return names


def illuminant_names() -> list[str]:
    """Illuminant names accepted by :func:`light_spectrum` (case-insensitive).

    Returns
    -------
    list of str
        colour-science's illuminant keys plus the CIE names F1 ... F12 of the
        fluorescent lamps, sorted.

    Examples
    --------
    >>> {"A", "D65", "F2"} <= set(illuminant_names())
    True
    """
    import colour

    out = list(colour.SDS_ILLUMINANTS)
    out += [f"F{k[2:]}" for k in colour.SDS_ILLUMINANTS if re.fullmatch(r"FL\d+", k)]
    return sorted(set(out))


def _illuminant_source(key: str) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Wavelengths (nm) and values of colour-science's illuminant ``key``."""
    import colour

    sd = colour.SDS_ILLUMINANTS[key]
    return np.asarray(sd.wavelengths, dtype=np.float64), np.asarray(sd.values, dtype=np.float64)


def _cct_source(kelvin: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Wavelengths (nm) and values of a Planckian (below 4000 K) or CIE daylight source at ``kelvin``."""
    lo, hi = _CCT_RANGE
    if not (math.isfinite(kelvin) and lo <= kelvin <= hi):
        raise InputError(
            f"colour temperature {kelvin:g} K is outside {lo:g}-{hi:g} K; "
            "give e.g. '3200K' (Planck) or '6500K' (CIE daylight)"
        )
    wl = np.arange(CMF_RANGE[0], CMF_RANGE[1] + 0.5, 1.0)
    if kelvin < _PLANCK_BELOW:
        x = _C2 / (wl * 1e-9 * kelvin)
        values = (wl * 1e-9) ** -5 / np.expm1(x)
        return wl, values
    import colour

    # the CIE daylight formula is defined up to 25000 K on its own scale
    xy = colour.temperature.CCT_to_xy_CIE_D(min(kelvin * _DAYLIGHT_C2_RATIO, _CCT_RANGE[1]))
    sd = colour.sd_CIE_illuminant_D_series(xy)
    return np.asarray(sd.wavelengths, dtype=np.float64), np.asarray(sd.values, dtype=np.float64)


_SPLIT = re.compile(r"[,;\s]+")


def _read_spectrum_csv(path: Path) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Wavelengths (nm) and values of a CSV light spectrum; errors name the line."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read light spectrum file '{path}': {exc}") from exc
    rows: list[tuple[float, float]] = []
    seen_data_line = False
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        fields = [f for f in _SPLIT.split(line.strip(",; \t")) if f]
        try:
            nums = [float(f) for f in fields]
        except ValueError:
            if not seen_data_line and not rows:
                seen_data_line = True  # the optional header line
                continue
            raise InputError(
                f"{path}, line {lineno}: expected two numbers 'wavelength_nm, value', got {line!r}"
            ) from None
        seen_data_line = True
        if len(nums) != 2:
            raise InputError(
                f"{path}, line {lineno}: expected two columns 'wavelength_nm, value', "
                f"got {len(nums)} in {line!r}"
            )
        if not all(math.isfinite(v) for v in nums):
            raise InputError(f"{path}, line {lineno}: NaN or infinite value in {line!r}")
        if nums[1] < 0:
            raise InputError(f"{path}, line {lineno}: spectral power must be >= 0, got {nums[1]:g}")
        if rows and nums[0] <= rows[-1][0]:
            raise InputError(
                f"{path}, line {lineno}: wavelength {nums[0]:g} nm does not increase "
                f"(previous {rows[-1][0]:g} nm); sort the rows by wavelength"
            )
        rows.append((nums[0], nums[1]))
    if len(rows) < 2:
        raise InputError(f"{path}: needs at least two '(wavelength_nm, value)' rows, found {len(rows)}")
    arr = np.asarray(rows, dtype=np.float64)
    if not np.any(arr[:, 1] > 0):
        raise InputError(f"{path}: every spectral power value is zero")
    return arr[:, 0], arr[:, 1]


def _parse_light(spec: object) -> tuple[NDArray[np.float64], NDArray[np.float64], str]:
    """Wavelengths (nm), values and a label of a light given by name, temperature or CSV path."""
    if isinstance(spec, bool):
        raise InputError(f"light spec must be a name, a temperature or a CSV path, got {spec!r}")
    if isinstance(spec, (int, float, np.integer, np.floating)):
        return (*_cct_source(float(spec)), f"{float(spec):g} K")
    if not isinstance(spec, (str, os.PathLike)):
        raise InputError(
            f"light spec must be an illuminant name, a temperature like '3200K' or a CSV path, "
            f"got {type(spec).__name__}"
        )
    text = os.fspath(spec).strip()
    m = re.fullmatch(r"(\d+(?:\.\d*)?)\s*[kK]?", text)
    if m:
        return (*_cct_source(float(m.group(1))), f"{float(m.group(1)):g} K")
    table = _illuminant_table()
    if text.lower() in table:
        key = table[text.lower()]
        return (*_illuminant_source(key), key)
    path = Path(text)
    if path.is_file():
        return (*_read_spectrum_csv(path), str(path))
    if path.suffix.lower() in (".csv", ".txt", ".tsv") or os.sep in text or "/" in text:
        raise InputError(f"light spectrum file '{text}' does not exist or is not a file")
    raise InputError(
        f"unknown light {text!r}: use a CIE illuminant ({', '.join(illuminant_names())}), "
        f"a colour temperature such as '3200K' ({_CCT_RANGE[0]:g}-{_CCT_RANGE[1]:g} K), "
        "or the path of a CSV file of (nm, value) rows"
    )


def light_spectrum(spec: str | float | os.PathLike[str], grid: SpectralGrid = REFERENCE_GRID) -> NDArray[np.float64]:
    """Relative spectral power of a light source on ``grid``.

    Parameters
    ----------
    spec
        * a CIE illuminant known to colour-science, case-insensitive
          (``"D65"``, ``"A"``, ``"D50"``, ``"F2"`` = ``"FL2"``, ...);
        * a correlated colour temperature, ``"3200K"``, ``"6500k"`` or a number
          in kelvin, 1000-25000 K: below 4000 K Planck's law, from 4000 K the
          CIE daylight locus (nominal temperature, so ``"6500K"`` is D65);
        * the path of a CSV file of measured ``wavelength_nm, value`` rows
          (comma, semicolon, tab or space separated; one header line and
          ``#`` comments allowed) covering the grid.
    grid
        Target wavelength grid (see :func:`resample` for how it is sampled).

    Returns
    -------
    ndarray
        Shape ``(L,)``, normalised to 1 at 560 nm (or at the sample nearest
        to it).  A measured spectrum with no power there is normalised to its
        maximum instead.

    Raises
    ------
    ValueError
        An unknown name, a temperature outside 1000-25000 K, a missing or
        bad CSV file (the message names the line), a spectrum that does not
        cover the grid or has no power on it.

    References
    ----------
    CIE 015:2018 Colorimetry, 4th edition, eq. 1 (Planck's law, c2 =
    1.4388e-2 m K) and section 4.1 (daylight). doi:10.25039/TR.015.2018

    Examples
    --------
    >>> e = light_spectrum("D65", SpectralGrid(400, 700, 10))
    >>> float(e[16])      # the sample at 560 nm
    1.0
    >>> a = light_spectrum("A")
    >>> bool(a[-1] > a[0])   # incandescent light is red-heavy
    True
    """
    if not isinstance(grid, SpectralGrid):
        raise InputError(f"grid must be a SpectralGrid, got {type(grid).__name__}")
    wl, values, label = _parse_light(spec)
    try:
        out = resample(wl, values, grid, method="average")
    except ValueError as exc:
        raise InputError(f"light {label}: {exc}") from None
    ref = out[int(np.argmin(np.abs(grid.wavelengths - _NORMALISATION_NM)))]
    if not ref > 0:
        ref = float(out.max())
        if not ref > 0:
            raise InputError(f"light {label} has no power on {grid.start:g}-{grid.stop:g} nm")
    return out / ref


def transmission_spectrum(path: str | os.PathLike[str], grid: SpectralGrid = REFERENCE_GRID) -> NDArray[np.float64]:
    r"""A filter's transmission (fraction 0-1) from a CSV of ``wavelength_nm, transmission`` rows, on ``grid``.

    Not normalised (a transmission is absolute).  The rows must cover the grid.

    Parameters
    ----------
    path
        The CSV file (an optional header line, then ``wavelength_nm, transmission`` rows).
    grid
        The wavelength grid to resample to.

    Returns
    -------
    ndarray
        ``(L,)`` transmission 0-1 on ``grid``.

    Raises
    ------
    InputError
        A bad CSV file (the message names the line), rows that do not cover the grid, values above
        1.05 (a data sheet in percent: divide by 100), a filter that passes less than 1 % everywhere.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "filter.csv"
    >>> _ = p.write_text("wavelength_nm,transmission\n380,0.5\n780,0.9\n")
    >>> [round(float(v), 2) for v in transmission_spectrum(p, SpectralGrid(400, 700, 150))]
    [0.52, 0.67, 0.82]
    """
    p = Path(path)
    wl, values = _read_spectrum_csv(p)
    if wl[0] > grid.start + 1e-9 or wl[-1] < grid.stop - 1e-9:
        raise InputError(f"{p}: the transmission covers {wl[0]:g}-{wl[-1]:g} nm, but {grid.start:g}-{grid.stop:g} nm "
                         "are needed; give the filter's whole data sheet")
    if float(values.max()) > 1.05:
        raise InputError(f"{p}: transmission up to {float(values.max()):g}; give it as a fraction 0-1 (a data sheet "
                         "in percent: divide by 100)")
    out = resample(wl, values, grid)
    if not float(out.max()) >= 0.01:
        raise InputError(f"{p}: the filter passes less than 1 % at every wavelength of {grid.start:g}-{grid.stop:g} nm; "
                         "no bracket set can be shot through it")
    return np.clip(out, 0.0, None)