"""The fitted spectral estimator shared by every method, and the least-squares pieces the methods share.

Every estimator of :mod:`processing.spectral.estimation` ends in the form
``w = phi(rho T) A`` of :class:`SpectralFit` (camera channels ``rho``, an
optional chart transform ``T``, a feature expansion ``phi`` and the fitted map
``A`` to the weights of a basis ``B (L, p)``; Matsuda et al., section 4.1,
eq. (6)-(10)); docs/colour-pipeline.md, "The common form of the estimators",
derives it.  This module holds that result type, its per-pixel application,
the uncentred PCA basis and the root-polynomial features (Finlayson,
Mackiewicz & Hurlbert 2015), and re-exports the input checks of
:mod:`processing.spectral.checks`.

References
----------
Matsuda, Tanaka, Ichikawa, Mochizuki, Muroya, Kitamura, "CG reproduction of a
craft object based on a light reflection model", IPSJ technical report
(no DOI), section 4.1.

Finlayson, G. D., Mackiewicz, M., Hurlbert, A. (2015). Color correction using
root-polynomial regression. IEEE Transactions on Image Processing 24(5),
1460-1470. doi:10.1109/TIP.2015.2405336

Maloney, L. T. (1986). Evaluation of linear models of surface spectral
reflectance with small numbers of parameters. JOSA A 3(10), 1673-1683.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from itertools import combinations_with_replacement

import numpy as np
from numpy.typing import ArrayLike, NDArray
from threadpoolctl import threadpool_limits

from processing.spectral.checks import SpectralEstimationError, checked_channels, checked_spectra
from processing.spectral.spectra import SpectralGrid

__all__ = [
    "SpectralEstimationError",
    "SpectralFit",
    "pca_basis",
    "checked_channels",
    "checked_spectra",
    "feature_names",
    "expand_features",
    "with_transform",
]

_CHUNK_PIXELS = 1 << 15   # pixels per block: the features (up to 21 x 128 kB) stay in cache
_SINGLE_THREAD_FROM = 1 << 16   # below this, setting the thread limit costs more than the product


def pca_basis(spectra: ArrayLike, p: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The first ``p`` principal directions ``(L, p)`` of spectra and their singular values.

    Uncentred (second-moment) PCA, as in Maloney (1986): no mean is removed,
    so an estimate in this basis is linear in the camera response and scales
    with exposure.  The first vector is made positive.

    Parameters
    ----------
    spectra
        ``(n, L)`` spectra (reflectance, a fraction).
    p
        Number of directions, ``1 <= p <= min(n, L)``.

    Returns
    -------
    basis : ndarray
        ``(L, p)`` orthonormal columns, float64.
    singular_values : ndarray
        ``(min(n, L),)`` every singular value of ``spectra``, descending.

    Raises
    ------
    SpectralEstimationError
        Bad spectra (:func:`checked_spectra`) or ``p`` out of range.

    Examples
    --------
    >>> b, sv = pca_basis(np.array([[1.0, 1.0], [2.0, 2.0]]), 1)
    >>> np.round(b[:, 0], 4).tolist()
    [0.7071, 0.7071]
    """
    s = checked_spectra("spectra", spectra)
    if isinstance(p, bool) or not isinstance(p, (int, np.integer)) or not 1 <= p <= min(s.shape):
        raise SpectralEstimationError(
            f"basis size p must be an integer in [1, {min(s.shape)}] (spectra and wavelengths available), got {p!r}"
        )
    _, sv, vt = np.linalg.svd(s, full_matrices=False)
    basis = vt[:p].T.copy()
    if basis[:, 0].sum() < 0:
        basis[:, 0] *= -1
    return basis, sv


def feature_names(channels: int, expansion: str) -> list[str]:
    """Names of the features of ``expansion`` for ``channels`` inputs.

    Parameters
    ----------
    channels
        Number of camera channels c.
    expansion
        ``'linear'``, ``'rootpoly2'`` or ``'rootpoly3'``.

    Returns
    -------
    list of str
        ``'c0'`` ... for the channels, ``'sqrt(c0*c1)'`` / ``'cbrt(c0*c1*c2)'``
        for the root terms, in the order of :func:`expand_features`.

    Raises
    ------
    SpectralEstimationError
        Unknown expansion.

    Examples
    --------
    >>> feature_names(3, "rootpoly2")
    ['c0', 'c1', 'c2', 'sqrt(c0*c1)', 'sqrt(c0*c2)', 'sqrt(c1*c2)']
    """
    return [n for n, _ in _terms(channels, expansion)]


def _terms(channels: int, expansion: str) -> list[tuple[str, tuple[int, ...]]]:
    """Name and channel indices of each feature of ``expansion``."""
    if expansion not in ("linear", "rootpoly2", "rootpoly3"):
        raise SpectralEstimationError(f"unknown feature expansion {expansion!r}; use linear, rootpoly2 or rootpoly3")
    degree = {"linear": 1, "rootpoly2": 2, "rootpoly3": 3}[expansion]
    out: list[tuple[str, tuple[int, ...]]] = []
    for d in range(1, degree + 1):
        for combo in combinations_with_replacement(range(channels), d):
            if d > 1 and len(set(combo)) == 1:
                continue          # (r^2)^(1/2) = r repeats a linear term
            if d == 1:
                out.append((f"c{combo[0]}", combo))
            else:
                root = "sqrt" if d == 2 else "cbrt"
                out.append((f"{root}({'*'.join(f'c{i}' for i in combo)})", combo))
    return out


def _expand_leading(xt: NDArray[np.floating], expansion: str) -> NDArray[np.floating]:
    """Features along axis 0 of channels along axis 0 (contiguous rows: fast for images).

    A term is the product of the channels' own roots (``sqrt(r) sqrt(g)``, not
    ``sqrt(r g)``), so it neither overflows nor underflows where the channels
    themselves do not (float32 holds 1e-30 .. 1e30 values exactly scaled).
    """
    terms = _terms(xt.shape[0], expansion)
    if expansion == "linear":
        return xt
    degree = max(len(c) for _, c in terms)
    roots = {2: np.sqrt(xt)}
    if degree == 3:
        roots[3] = np.cbrt(xt)
    out = np.empty((len(terms),) + xt.shape[1:], dtype=xt.dtype)
    for k, (_, combo) in enumerate(terms):
        if len(combo) == 1:
            out[k] = xt[combo[0]]
            continue
        r = roots[len(combo)]
        np.multiply(r[combo[0]], r[combo[1]], out=out[k])
        for i in combo[2:]:
            out[k] *= r[i]
    return out


def expand_features(rgb: NDArray[np.floating], expansion: str) -> NDArray[np.floating]:
    """Root-polynomial features of camera channels.

    Each term is a product of d channels raised to 1/d (Finlayson et al.
    2015), so every feature scales linearly with exposure.

    Parameters
    ----------
    rgb
        Camera channels ``(..., c)``, >= 0.
    expansion
        ``'linear'`` (the channels themselves), ``'rootpoly2'`` or
        ``'rootpoly3'`` (terms of :func:`feature_names`).

    Returns
    -------
    ndarray
        ``(..., f)`` features, the dtype of ``rgb``; ``rgb`` itself for
        ``'linear'``.

    Raises
    ------
    SpectralEstimationError
        Unknown expansion.

    References
    ----------
    Finlayson, G. D., Mackiewicz, M., Hurlbert, A. (2015). Color correction
    using root-polynomial regression. IEEE Transactions on Image Processing
    24(5), 1460-1470. doi:10.1109/TIP.2015.2405336

    Examples
    --------
    >>> expand_features(np.array([[1.0, 4.0, 9.0]]), "rootpoly2").tolist()
    [[1.0, 4.0, 9.0, 2.0, 3.0, 6.0]]
    """
    if expansion == "linear":
        _terms(rgb.shape[-1], expansion)
        return rgb
    return np.moveaxis(_expand_leading(np.moveaxis(rgb, -1, 0), expansion), 0, -1)


@dataclass(frozen=True)
class SpectralFit:
    """A fitted estimator from camera channels to basis weights: ``w = phi(rho T) @ matrix``.

    Parameters
    ----------
    method, basis, matrix, grid, channels, expansion, transform, training_rmse, condition, details
        The attributes below.

    Attributes
    ----------
    method
        Name of the method ('paper', 'wiener', 'rootpoly', 'twolight', ...).
    basis
        ``(L, p)`` basis spectra (columns), float64.
    matrix
        ``(f, p)`` map from the features to the weights, row-vector form
        ``w = phi(rho T) @ matrix``.
    grid
        The wavelength grid of the basis.
    channels
        Number of camera channels c (3, or 6 for two exposures).
    expansion
        Feature expansion: 'linear', 'rootpoly2' or 'rootpoly3'.
    transform
        Optional ``(c, c)`` chart transform applied before the expansion
        (None once folded into a linear ``matrix``).
    training_rmse
        RMS spectral error of the fit on its training spectra (reflectance).
    condition
        Condition numbers of the fitted systems, by name.
    details
        Method-specific figures (regularisation chosen, noise level...).
    """

    method: str
    basis: NDArray[np.float64]
    matrix: NDArray[np.float64]
    grid: SpectralGrid
    channels: int
    expansion: str = "linear"
    transform: NDArray[np.float64] | None = None
    training_rmse: float = math.nan
    condition: dict[str, float] = field(default_factory=dict)
    details: dict[str, float] = field(default_factory=dict)

    @property
    def wavelengths(self) -> NDArray[np.float64]:
        """Wavelengths of the basis in nm."""
        return self.grid.wavelengths

    @property
    def p(self) -> int:
        """Number of basis vectors."""
        return int(self.basis.shape[1])

    def estimate_weights(self, rgb: ArrayLike) -> NDArray[np.float32]:
        """Basis weights ``(..., p)`` float32 of camera channels ``(..., c)``.

        Done in blocks of 2^15 pixels, each one matrix product (plus the
        root-polynomial terms), in float32.

        Parameters
        ----------
        rgb
            Linear camera values ``(..., c)`` in the units the estimator was
            fitted in (finite, >= 0).

        Returns
        -------
        ndarray
            ``(..., p)`` float32 weights of :attr:`basis`.

        Raises
        ------
        SpectralEstimationError
            Wrong number of channels, empty, NaN, infinite or negative values.

        Examples
        --------
        >>> fit = SpectralFit("demo", np.eye(3), np.eye(3), SpectralGrid(400, 700, 150), 3)
        >>> fit.estimate_weights([[1.0, 2.0, 3.0]]).tolist()
        [[1.0, 2.0, 3.0]]
        """
        a = checked_channels("camera channels", rgb, self.channels, check_values=False)
        flat = a.reshape(-1, self.channels)
        out = np.empty((flat.shape[0], self.p), dtype=np.float32)
        # channels-first blocks: the features are built as contiguous rows and the product reads them
        # transposed, writing the (n, p) result in place (several times faster than row-major features)
        mat = np.ascontiguousarray(self.matrix, dtype=np.float32)
        tr_t = None if self.transform is None else np.ascontiguousarray(self.transform.T, dtype=np.float32)
        # one BLAS thread: with an inner dimension of 3-21 the product is memory-bound, and on a shared
        # machine OpenBLAS's spinning threads made it 2-20 times slower and erratic (measured)
        with threadpool_limits(limits=1, user_api="blas") if flat.shape[0] >= _SINGLE_THREAD_FROM else _no_limit():
            for i in range(0, flat.shape[0], _CHUNK_PIXELS):
                block = flat[i:i + _CHUNK_PIXELS]
                checked_channels("camera channels", block)
                bt = np.ascontiguousarray(block.T, dtype=np.float32)
                if tr_t is not None:
                    bt = np.maximum(tr_t @ bt, 0.0)     # the chart map can push a dark pixel below 0
                np.matmul(_expand_leading(bt, self.expansion).T, mat, out=out[i:i + bt.shape[1]])
        return out.reshape(a.shape[:-1] + (self.p,))

    def estimate_spectra(self, rgb: ArrayLike) -> NDArray[np.float64]:
        """Reflectance spectra ``(..., L)`` of a few camera values (for charts and regions, not images).

        Parameters
        ----------
        rgb
            Linear camera values ``(..., c)`` (finite, >= 0).

        Returns
        -------
        ndarray
            ``(..., L)`` float64 reflectance on :attr:`grid`.

        Raises
        ------
        SpectralEstimationError
            As :meth:`estimate_weights`.

        Examples
        --------
        >>> fit = SpectralFit("demo", np.eye(3), np.eye(3), SpectralGrid(400, 700, 150), 3)
        >>> fit.estimate_spectra([0.1, 0.2, 0.3]).round(3).tolist()
        [0.1, 0.2, 0.3]
        """
        return self.estimate_weights(rgb).astype(np.float64) @ self.basis.T


@contextlib.contextmanager
def _no_limit() -> Iterator[None]:
    """A context that changes nothing (no thread limit for small products)."""
    yield


def with_transform(fit: SpectralFit, transform: ArrayLike) -> SpectralFit:
    """The estimator applied after a ``(c, c)`` chart transform (row form ``rho T``).

    For linear features the transform is folded into the matrix.

    Parameters
    ----------
    fit
        A fitted estimator.
    transform
        ``(c, c)`` map from the object camera's channels to the model
        camera's (:func:`processing.camera.transfer.fit_chart_transform`);
        it acts before any transform ``fit`` already has.

    Returns
    -------
    SpectralFit
        A copy of ``fit`` with the transform folded in or attached.

    Raises
    ------
    SpectralEstimationError
        ``transform`` is not a finite ``(c, c)`` matrix.

    Examples
    --------
    >>> fit = SpectralFit("demo", np.eye(3), np.eye(3), SpectralGrid(400, 700, 150), 3)
    >>> with_transform(fit, 2 * np.eye(3)).estimate_weights([[1.0, 1.0, 1.0]]).tolist()
    [[2.0, 2.0, 2.0]]
    """
    t = np.asarray(transform, dtype=np.float64)
    if t.shape != (fit.channels, fit.channels) or not np.isfinite(t).all():
        raise SpectralEstimationError(
            f"chart transform must be a finite ({fit.channels}, {fit.channels}) matrix, got shape {t.shape}"
        )
    if fit.transform is not None:
        t = t @ fit.transform      # the new transform acts first on the incoming channels
    if fit.expansion == "linear":
        return replace(fit, matrix=t @ fit.matrix, transform=None)
    return replace(fit, transform=t)
