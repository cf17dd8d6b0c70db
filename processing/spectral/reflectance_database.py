"""Reflectance databases for spectral estimation: training spectra, the ColorChecker, user CSV files.

Matsuda et al., section 4.1 (eq. (6)-(8)) learn a basis and a camera-to-weights
map from measured reflectances; this module gives the databases on a grid
(``"training"``: the 190 RAW to ACES training reflectances; ``"colorchecker"``:
N. Ohta's ColorChecker measurements; or a CSV file) and removes the training
spectra that are re-measurements of a test set.  docs/colour-pipeline.md,
"Reflectance databases", gives the sources and the near-duplicate threshold.

References
----------
Matsuda, Tanaka, Ichikawa, Mochizuki, Muroya, Kitamura, "CG reproduction of a
craft object based on a light reflection model", IPSJ technical report
(no DOI), section 4.1.

Hernandez-Andres, J., Romero, J., Nieves, J. L., Lee, R. L. (2001). Color and
spectral analysis of daylight in southern Europe. JOSA A 18 (the goodness-of-fit
coefficient).
"""

from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.errors import InputError
from processing.spectral.spectra import REFERENCE_GRID, SpectralGrid, resample

__all__ = [
    "ReflectanceDatabaseError",
    "ReflectanceSet",
    "database_names",
    "load_reflectances",
    "read_reflectance_csv",
    "near_duplicates",
    "without_near_duplicates",
    "combine",
]

#: Default near-duplicate threshold: RMS reflectance difference over the grid.
DUPLICATE_RMSE = 0.0125

_MAX_REFLECTANCE = 1.5   # fluorescent or specular samples exceed 1 a little; more is a unit error


class ReflectanceDatabaseError(InputError):
    """A reflectance database or CSV file is not valid; the message names the file, line and column."""


@dataclass(frozen=True)
class ReflectanceSet:
    """Reflectance spectra sampled on a grid.

    Parameters
    ----------
    spectra, names, grid, source
        The attributes below, in this order.

    Attributes
    ----------
    spectra
        ``(n, L)`` float64 reflectances.
    names
        One name per spectrum.
    grid
        The wavelength grid.
    source
        Where the spectra come from.
    """

    spectra: NDArray[np.float64]
    names: tuple[str, ...]
    grid: SpectralGrid
    source: str

    def __len__(self) -> int:
        return int(self.spectra.shape[0])


def database_names() -> list[str]:
    """Built-in databases.

    Returns
    -------
    list of str
        ``"colorchecker"`` (24 ColorChecker N Ohta patches) and
        ``"training"`` (the 190 reflectances of the RAW to ACES utility,
        ``colour.characterisation.read_training_data_rawtoaces_v1``).

    Examples
    --------
    >>> database_names()
    ['colorchecker', 'training']
    """
    return ["colorchecker", "training"]


@functools.lru_cache(maxsize=8)
def _builtin(name: str, start: float, stop: float, step: float) -> ReflectanceSet:
    """The built-in database ``name`` on the grid ``(start, stop, step)``, cached and read-only."""
    import colour

    grid = SpectralGrid(start, stop, step)
    if name == "training":
        msds = colour.characterisation.read_training_data_rawtoaces_v1()
        wl, values, names = msds.wavelengths, np.asarray(msds.values).T, tuple(msds.labels)
        source = "RAW to ACES v1 training reflectances (colour-science), 190 spectra"
    else:
        chart = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
        first = next(iter(chart.values()))
        wl = first.wavelengths
        values = np.stack([np.interp(wl, sd.wavelengths, sd.values) for sd in chart.values()])
        names = tuple(chart.keys())
        source = "ColorChecker N Ohta (colour-science), 24 patches"
    lo, hi = float(wl[0]), float(wl[-1])
    if grid.start < lo or grid.stop > hi:
        raise ReflectanceDatabaseError(
            f"reflectance database {name!r} covers {lo:g}-{hi:g} nm; the grid {grid.start:g}-{grid.stop:g} nm must lie inside"
        )
    spectra = resample(np.asarray(wl, dtype=np.float64), np.asarray(values, dtype=np.float64), grid)
    spectra.setflags(write=False)
    return ReflectanceSet(spectra, names, grid, source)


def load_reflectances(name: str | os.PathLike[str], grid: SpectralGrid = REFERENCE_GRID) -> ReflectanceSet:
    """A built-in database (:func:`database_names`) or a CSV file, on ``grid``.

    Parameters
    ----------
    name
        A name of :func:`database_names` (case-insensitive) or a ``.csv`` path
        (:func:`read_reflectance_csv`).
    grid
        The wavelength grid.

    Returns
    -------
    ReflectanceSet
        Reflectances (fractions) linearly interpolated onto ``grid``.

    Raises
    ------
    ReflectanceDatabaseError
        Not a SpectralGrid, an unknown name, a grid outside the database's
        range, or a bad CSV file.

    Examples
    --------
    >>> cc = load_reflectances("colorchecker", SpectralGrid(400, 700, 10))
    >>> len(cc), cc.spectra.shape[1], cc.names[0]
    (24, 31, 'dark skin')
    """
    if not isinstance(grid, SpectralGrid):
        raise ReflectanceDatabaseError(f"grid must be a processing.spectral.spectra.SpectralGrid, got {type(grid).__name__}")
    if isinstance(name, str) and name.lower() in database_names():
        return _builtin(name.lower(), grid.start, grid.stop, grid.step)
    if isinstance(name, os.PathLike) or (isinstance(name, str) and name.lower().endswith(".csv")):
        return read_reflectance_csv(name, grid)
    raise ReflectanceDatabaseError(
        f"unknown reflectance database {name!r}; choose one of {', '.join(database_names())} or a .csv file"
    )


def read_reflectance_csv(path: str | os.PathLike[str], grid: SpectralGrid = REFERENCE_GRID) -> ReflectanceSet:
    r"""Read reflectances from a CSV file: ``wavelength_nm, r_1, r_2, ...`` one row per wavelength.

    An optional first line names the columns.  Errors name the line and
    column of the first bad value.

    Parameters
    ----------
    path
        The CSV file (comma, semicolon, tab or space separated; ``#``
        comments allowed).
    grid
        The wavelength grid; the file must cover it.

    Returns
    -------
    ReflectanceSet
        One spectrum per value column, named by the header or
        ``<file stem><n>``.

    Raises
    ------
    ReflectanceDatabaseError
        Unreadable file, a bad field, a reflectance outside [0, 1.5] (percent
        given for a fraction), wavelengths that do not increase or do not
        cover the grid, or every reflectance 0 on the grid.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "mine.csv"
    >>> _ = p.write_text("nm,tile,paper\n400,0.1,0.8\n700,0.3,0.9\n")
    >>> s = read_reflectance_csv(p, SpectralGrid(400, 700, 150))
    >>> s.names, s.spectra.round(2).tolist()
    (('tile', 'paper'), [[0.1, 0.2, 0.3], [0.8, 0.85, 0.9]])
    """
    from processing.spectral.tables import read_wavelength_table

    path = Path(path)
    table = read_wavelength_table(
        path, what="reflectance", error=ReflectanceDatabaseError,
        check=lambda col, v: None if 0.0 <= v <= _MAX_REFLECTANCE else
        f"reflectance {v:g} outside [0, {_MAX_REFLECTANCE:g}]; give reflectance as a fraction, not percent")
    header = table.header
    arr = np.column_stack([table.wavelengths, table.values])
    if arr[0, 0] > grid.start or arr[-1, 0] < grid.stop:
        raise ReflectanceDatabaseError(
            f"{path}: wavelengths {arr[0, 0]:g}-{arr[-1, 0]:g} nm do not cover the grid {grid.start:g}-{grid.stop:g} nm"
        )
    n = arr.shape[1] - 1
    names = tuple(header[:n]) if header is not None and len(header) >= n else tuple(f"{path.stem}{i + 1}" for i in range(n))
    spectra = resample(arr[:, 0], arr[:, 1:].T, grid)
    if not np.any(spectra > 0):
        raise ReflectanceDatabaseError(
            f"{path}: every reflectance is 0 over {grid.start:g}-{grid.stop:g} nm; give the measured "
            "reflectances (fractions 0-1), not an empty or all-black set"
        )
    return ReflectanceSet(spectra, names, grid, str(path))


def _checked_spectra(name: str, a: ArrayLike) -> NDArray[np.float64]:
    """Spectra as a finite, non-empty ``(n, L)`` float64 array."""
    s = np.asarray(a, dtype=np.float64)
    if s.ndim != 2 or s.shape[0] == 0 or s.shape[1] == 0:
        raise ReflectanceDatabaseError(f"{name} must be a non-empty (n, L) array of spectra, got shape {s.shape}")
    if not np.all(np.isfinite(s)):
        raise ReflectanceDatabaseError(f"{name} contains NaN or infinite values")
    return s


def near_duplicates(
    train: ArrayLike, test: ArrayLike, *, rmse: float = DUPLICATE_RMSE, gfc: float | None = None
) -> NDArray[np.bool_]:
    """Mask of training spectra within ``rmse`` (or above ``gfc``) of some test spectrum.

    Parameters
    ----------
    train, test
        ``(n, L)`` and ``(m, L)`` spectra on the same grid.
    rmse
        RMS reflectance difference below which two spectra are the same sample.
    gfc
        Optional goodness-of-fit coefficient (cosine) above which they are.

    Returns
    -------
    ndarray
        ``(n,)`` bool, True for a near-duplicate.

    Raises
    ------
    ReflectanceDatabaseError
        Bad or mismatched spectra, a negative ``rmse`` or a ``gfc`` outside (0, 1].

    References
    ----------
    Hernandez-Andres, J., Romero, J., Nieves, J. L., Lee, R. L. (2001). Color
    and spectral analysis of daylight in southern Europe. JOSA A 18 (the
    goodness-of-fit coefficient).

    Examples
    --------
    >>> near_duplicates([[0.5, 0.5], [0.1, 0.9]], [[0.505, 0.5]]).tolist()
    [True, False]
    """
    a = _checked_spectra("train", train)
    b = _checked_spectra("test", test)
    if a.shape[1] != b.shape[1]:
        raise ReflectanceDatabaseError(f"train and test spectra differ in length: {a.shape[1]} vs {b.shape[1]}")
    if not (math.isfinite(rmse) and rmse >= 0):
        raise ReflectanceDatabaseError(f"rmse threshold must be >= 0, got {rmse!r}")
    d2 = (a * a).sum(1)[:, None] + (b * b).sum(1)[None, :] - 2.0 * a @ b.T
    dup = np.sqrt(np.maximum(d2, 0.0) / a.shape[1]).min(axis=1) < rmse
    if gfc is not None:
        if not (math.isfinite(gfc) and 0 < gfc <= 1):
            raise ReflectanceDatabaseError(f"gfc threshold must be in (0, 1], got {gfc!r}")
        na = np.maximum(np.linalg.norm(a, axis=1), 1e-300)[:, None]
        nb = np.maximum(np.linalg.norm(b, axis=1), 1e-300)[None, :]
        dup |= ((a @ b.T) / (na * nb)).max(axis=1) > gfc
    return dup


def without_near_duplicates(
    train: ReflectanceSet, test: ReflectanceSet, *, rmse: float = DUPLICATE_RMSE, gfc: float | None = None
) -> ReflectanceSet:
    """``train`` less its near-duplicates of ``test`` (:func:`near_duplicates`).

    On the 400-700 nm grid the 190 training spectra hold 13 within RMSE
    0.0105 of a ColorChecker N Ohta patch and the next nearest is at 0.0151,
    so the default threshold separates re-measurements of the chart from
    merely similar colours.

    Parameters
    ----------
    train, test
        Reflectance sets on the same grid.
    rmse, gfc
        Thresholds of :func:`near_duplicates`.

    Returns
    -------
    ReflectanceSet
        The training spectra kept, with a source that says how many were removed.

    Raises
    ------
    ReflectanceDatabaseError
        Sets on different grids, or every training spectrum removed.

    Examples
    --------
    >>> g = SpectralGrid(400, 700, 10)
    >>> held = without_near_duplicates(load_reflectances("training", g), load_reflectances("colorchecker", g))
    >>> 170 < len(held) < 190
    True
    """
    if train.grid != test.grid:
        raise ReflectanceDatabaseError(f"train and test are on different grids: {train.grid} vs {test.grid}")
    keep = ~near_duplicates(train.spectra, test.spectra, rmse=rmse, gfc=gfc)
    if not np.any(keep):
        raise ReflectanceDatabaseError("every training spectrum is a near-duplicate of the test set; lower the threshold")
    return ReflectanceSet(
        train.spectra[keep],
        tuple(n for n, k in zip(train.names, keep) if k),
        train.grid,
        f"{train.source} without {int((~keep).sum())} near-duplicates of {test.source}",
    )


def combine(*sets: ReflectanceSet) -> ReflectanceSet:
    """Concatenate reflectance sets on the same grid (e.g. a built-in database plus a user CSV).

    Parameters
    ----------
    *sets
        One or more reflectance sets on the same grid.

    Returns
    -------
    ReflectanceSet
        Their spectra and names in order; the sources joined by ``" + "``.

    Raises
    ------
    ReflectanceDatabaseError
        No set, or sets on different grids.

    Examples
    --------
    >>> g = SpectralGrid(400, 700, 10)
    >>> len(combine(load_reflectances("colorchecker", g), load_reflectances("colorchecker", g)))
    48
    """
    if not sets:
        raise ReflectanceDatabaseError("combine needs at least one reflectance set")
    grid = sets[0].grid
    for s in sets[1:]:
        if s.grid != grid:
            raise ReflectanceDatabaseError(f"cannot combine reflectance sets on different grids: {grid} vs {s.grid}")
    return ReflectanceSet(
        np.concatenate([s.spectra for s in sets]),
        tuple(n for s in sets for n in s.names),
        grid,
        " + ".join(s.source for s in sets),
    )
