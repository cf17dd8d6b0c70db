"""Angular XYZ tables: a lobe's spectral integral, once per (material, light).

With fixed light spectra, the spectral part of a lobe
(Matsuda et al., eq. (2)-(5): a Fresnel reflectance of theta_d, an alloy
mixture of them, or a pigment reflectance) can be integrated against the
light spectrum E and the CIE colour-matching functions once, as a function
of the one angle it depends on:

    T(c) = k * sum_lambda S(c, lambda) E(lambda) cmf(lambda) dlambda

so that shading a sample is ``weight * geometry * cos_i * T(cos_d)``: the
exact spectral result on the chosen wavelength grid at the cost of an RGB
renderer.  Because the geometric factor (D G / (4 cos_i cos_o) or 1/pi) does
not depend on wavelength it factors out of the sum exactly; the only error is
the linear interpolation of T between the ``N`` nodes, spaced uniformly in
``c = cos`` over [0, 1], bounded by ``h^2 / 8 max|T''|`` with ``h = 1/(N-1)``
(measured by :func:`table_error`).  An angle-independent factor needs one row.
With 256 nodes the error is below 1e-4 of the white for the Fresnel factors
of metals and lacquers; it grows where the factor is not smooth in cos: a
very large extinction (k ~ 200: F falls within cos < 0.01 of grazing,
error ~5e-3 at 256 nodes, ~1e-3 at 512), an index close to 1 (a step at
grazing) and the critical angle of n < 1 without absorption (not a surface
seen from air).

The same construction tabulates a lobe's directional albedo against the sky
spectrum over cos(theta_o) (sky light for non-mirror lobes).  docs/rendering.md
("The table method") gives the measured accuracy.

References
----------
Matsuda, Tanaka, Ichikawa, Mochizuki, Muroya, Kitamura, "CG reproduction of
a craft object based on a light reflection model", IPSJ technical report
(no DOI).
CIE 015:2018 Colorimetry (the colour-matching functions),
doi:10.25039/TR.015.2018.

Examples
--------
>>> t = AngleTable.from_function(lambda c: np.stack([c, c * c, 1 - c], axis=-1), 64)
>>> [round(float(v), 5) for v in t.lookup(np.array([0.5]))[0]]   # c^2 off by h^2 / 4 midway
[0.5, 0.25006, 0.5]
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.errors import InputError
from processing.materials.lobes import SpectralFactor
from processing.spectral.spectra import SpectralGrid

__all__ = [
    "AngleTable",
    "TableIndex",
    "table_index",
    "spectral_factor_table",
    "albedo_table",
    "table_error",
]


@dataclass(frozen=True)
class TableIndex:
    """Row and fraction of a set of cosines on an ``N``-node table (shared by all tables of that size).

    Attributes
    ----------
    row
        ``(n,)`` lower node of each cosine, in ``0 .. N - 2``.
    frac
        ``(n,)`` float32 position between that node and the next, in [0, 1].
    """

    row: NDArray[np.intp]
    frac: NDArray[np.float32]


def table_index(cos: ArrayLike, size: int) -> TableIndex:
    """Locate ``cos`` (clipped to [0, 1]) on ``size`` uniform nodes.

    Parameters
    ----------
    cos
        Cosines, any shape (float32).
    size
        Number of nodes N (>= 2).

    Returns
    -------
    TableIndex
        Rows and fractions, the shape of ``cos``.

    Examples
    --------
    >>> ix = table_index(np.array([0.0, 0.5, 1.0], dtype=np.float32), 3)
    >>> ix.row.tolist(), ix.frac.tolist()
    ([0, 1, 1], [0.0, 0.0, 1.0])
    """
    c = np.asarray(cos, dtype=np.float32)
    x = np.clip(c, 0.0, 1.0) * np.float32(size - 1)
    row = np.minimum(x.astype(np.intp), size - 2)
    frac = x - row.astype(np.float32)
    return TableIndex(row, frac)


@dataclass(frozen=True, eq=False)
class AngleTable:
    """Values ``(N, C)`` at ``cos = j / (N - 1)``, linearly interpolated; one row means constant.

    Attributes
    ----------
    values
        float64 ``(N, C)`` node values.
    """

    values: NDArray[np.float64]
    _packed: NDArray[np.float32] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        v = np.atleast_2d(np.asarray(self.values, dtype=np.float64))
        object.__setattr__(self, "values", v)
        if v.shape[0] > 1:
            packed = np.concatenate([v[:-1], v[1:] - v[:-1]], axis=1)
        else:
            packed = v
        # channel-major (2C, N-1): node values then slopes, one contiguous row per channel
        object.__setattr__(self, "_packed", np.ascontiguousarray(packed.T, dtype=np.float32))

    @property
    def size(self) -> int:
        """Number of nodes N (1 for a constant)."""
        return int(self.values.shape[0])

    @property
    def channels(self) -> int:
        """Number of channels C."""
        return int(self.values.shape[1])

    @property
    def constant(self) -> bool:
        """True for a one-row (angle-independent) table."""
        return self.size == 1

    @classmethod
    def from_function(cls, fn: Callable[[NDArray[np.float64]], NDArray[np.float64]], size: int) -> AngleTable:
        """Tabulate ``fn(cos) -> (N, C)`` on ``size`` uniform nodes over [0, 1].

        Parameters
        ----------
        fn
            Function of the ``(N,)`` node cosines returning ``(N, C)``.
        size
            Number of nodes N.

        Returns
        -------
        AngleTable
            The table.
        """
        nodes = np.linspace(0.0, 1.0, size)
        return cls(np.asarray(fn(nodes), dtype=np.float64).reshape(size, -1))

    def lookup_channels(self, cos: ArrayLike | None = None, index: TableIndex | None = None) -> NDArray[np.float32]:
        """Interpolated values, channel-major (a new, writable array).

        Parameters
        ----------
        cos
            Cosines (flattened); or None with ``index``.
        index
            A precomputed :func:`table_index` of this table's size.

        Returns
        -------
        ndarray
            float32 ``(C, n)``.
        """
        c = self.channels
        if index is None:
            flat = np.ravel(np.asarray(cos, dtype=np.float32))
            if self.constant:
                out = np.empty((c, flat.size), dtype=np.float32)
                out[:] = self._packed[:, :1]
                return out
            index = table_index(flat, self.size)
        n = len(index.row)
        if self.constant:
            out = np.empty((c, n), dtype=np.float32)
            out[:] = self._packed[:, :1]
            return out
        rows = np.take(self._packed, index.row, axis=1)
        out = rows[:c]
        out += rows[c:] * index.frac
        return out

    def lookup(self, cos: ArrayLike | None = None, index: TableIndex | None = None) -> NDArray[np.float32]:
        """Interpolated values at ``cos`` (or at a precomputed ``index``).

        Parameters
        ----------
        cos, index
            As for :meth:`lookup_channels`.

        Returns
        -------
        ndarray
            float32 ``(n, C)``.
        """
        return self.lookup_channels(cos, index).T

    def __add__(self, other: AngleTable) -> AngleTable:
        if self.constant and other.constant or self.size == other.size:
            return AngleTable(self.values + other.values)
        if self.constant:
            return AngleTable(other.values + self.values)
        if other.constant:
            return AngleTable(self.values + other.values)
        raise InputError(f"cannot add tables of {self.size} and {other.size} nodes")

    def scaled(self, factor: float) -> AngleTable:
        """The table times a constant.

        Parameters
        ----------
        factor
            The constant.

        Returns
        -------
        AngleTable
            A new table.
        """
        return AngleTable(self.values * factor)


def _spectra_to_xyz(spectra: NDArray[np.float64], grid: SpectralGrid) -> NDArray[np.float64]:
    from processing.spectral.display import spectra_to_xyz

    return spectra_to_xyz(spectra, grid)


def spectral_factor_table(
    spectral: SpectralFactor,
    light: ArrayLike,
    grid: SpectralGrid,
    scale: float,
    size: int,
) -> AngleTable:
    """Tabulate ``scale * XYZ(S(cos_d, lambda) * E(lambda))`` over cos_d.

    Parameters
    ----------
    spectral
        The lobe's spectral factor.
    light
        Light spectrum E on ``grid``, ``(L,)``.
    grid
        Wavelength grid.
    scale
        The renderer's XYZ normalisation k.
    size
        Nodes N over cos_d in [0, 1]; ignored (one row) when the factor is
        not angle dependent.

    Returns
    -------
    AngleTable
        ``(N, 3)`` or ``(1, 3)``.

    Examples
    --------
    A white factor: k XYZ(E / pi) has Y = 1, so the table holds Y = pi.

    >>> from processing.spectral.display import xyz_scale
    >>> from processing.spectral.spectra import light_spectrum
    >>> class White:
    ...     angle_dependent = False
    ...     def reflectance(self, cos_d, wl):
    ...         return np.ones(np.shape(cos_d) + (len(wl),))
    >>> grid = SpectralGrid(400, 700, 10)
    >>> e = light_spectrum("A", grid)
    >>> t = spectral_factor_table(White(), e, grid, xyz_scale(e, grid), 256)
    >>> t.values.shape, round(float(t.values[0, 1] / np.pi), 9)
    ((1, 3), 1.0)
    """
    e = np.asarray(light, dtype=np.float64)
    wl = grid.wavelengths
    if not getattr(spectral, "angle_dependent", True):
        s = np.asarray(spectral.reflectance(np.array([1.0]), wl), dtype=np.float64).reshape(1, -1)
        return AngleTable(scale * _spectra_to_xyz(s * e, grid))
    nodes = np.linspace(0.0, 1.0, size)
    s = np.asarray(spectral.reflectance(nodes, wl), dtype=np.float64).reshape(size, -1)
    return AngleTable(scale * _spectra_to_xyz(s * e, grid))


def albedo_table(
    albedo: Callable[[NDArray[np.float64]], NDArray[np.float64]],
    sky: ArrayLike,
    grid: SpectralGrid,
    scale: float,
    size: int,
) -> AngleTable:
    """Tabulate ``scale * XYZ(albedo(cos_o, lambda) * sky(lambda))`` over cos_o.

    Parameters
    ----------
    albedo
        ``albedo(nodes) -> (N, L)``, a directional albedo on ``grid``.
    sky
        Sky spectrum on ``grid``, ``(L,)``.
    grid
        Wavelength grid.
    scale
        The renderer's XYZ normalisation k.
    size
        Nodes N over cos_o in [0, 1].

    Returns
    -------
    AngleTable
        ``(N, 3)``.

    Examples
    --------
    >>> grid = SpectralGrid(400, 700, 100)
    >>> t = albedo_table(lambda c: np.outer(c, np.ones(4)), np.ones(4), grid, 1.0, 3)
    >>> t.values[:, 1].round(6).tolist() == (np.array([0.0, 0.5, 1.0]) * t.values[-1, 1]).round(6).tolist()
    True
    """
    nodes = np.linspace(0.0, 1.0, size)
    a = np.asarray(albedo(nodes), dtype=np.float64).reshape(size, -1)
    return AngleTable(scale * _spectra_to_xyz(a * np.asarray(sky, dtype=np.float64), grid))


def table_error(
    table: AngleTable,
    exact: Callable[[NDArray[np.float64]], NDArray[np.float64]],
    n_test: int = 4097,
) -> tuple[float, float]:
    """Largest absolute and relative (to the table's largest value) interpolation error.

    Parameters
    ----------
    table
        The table.
    exact
        The tabulated function, ``exact(cos) -> (n, C)``.
    n_test
        Number of test cosines, uniform over [0, 1] (on and between the
        nodes when ``n_test - 1`` is a multiple of ``2 (N - 1)``).

    Returns
    -------
    tuple of float
        Largest absolute error, and that error over the largest ``|exact|``.

    Examples
    --------
    >>> f = lambda c: np.stack([c * c] * 3, axis=-1)
    >>> err, rel = table_error(AngleTable.from_function(f, 11), f, n_test=201)
    >>> round(err, 6)            # h^2 f'' / 8 = 0.01 * 2 / 8 at the mid-points
    0.0025
    """
    c = np.linspace(0.0, 1.0, n_test)
    got = table.lookup(c).astype(np.float64)
    want = np.asarray(exact(c), dtype=np.float64).reshape(n_test, -1)
    err = float(np.max(np.abs(got - want)))
    peak = float(np.max(np.abs(want)))
    return err, err / peak if peak > 0 else err
