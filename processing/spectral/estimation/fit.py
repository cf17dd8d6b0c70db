"""The fitted spectral estimator shared by every method, and its per-pixel application.

Matsuda et al., section 4.1, eq. (6)-(10): a reflectance is written in a basis,
``s(lambda) = sum_i w_i b_i(lambda)`` (eq. (7)), and the weights follow from
the camera response by a matrix, ``w = M M2 rho`` (eq. (8)-(10)).  Every
estimator of this package (the paper's PCA, Wiener, root-polynomial, two
lights) ends in the same form, held by :class:`SpectralFit`:

``w = phi(rho T) A``

with ``rho`` the camera channels as a row vector, ``T`` an optional chart
transform into the model camera (eq. (9), :mod:`processing.camera.transfer`),
``phi`` the feature expansion (identity, or the root-polynomial terms of
Finlayson et al. 2015) and ``A`` the fitted map to the weights of the basis
``B (L, p)``.  For linear features ``T`` is folded into ``A``, so a whole
image is one matrix product.  Images become ``(H, W, p)`` weights, never
``(H, W, L)`` spectra.

Principal components here are of the second-moment matrix (no mean removed),
as in Maloney's linear models of surface reflectance (JOSA A 3, 1986), so the
estimate is linear in the camera response and scales with exposure.
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

from processing.errors import InputError
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


class SpectralEstimationError(InputError):
    """An input to spectral estimation is not valid; the message names it and what to do."""


def checked_channels(
    name: str, rgb: ArrayLike, channels: int | None = None, *, check_values: bool = True
) -> NDArray[np.floating]:
    """Validate camera channels ``(..., c)``: non-empty, finite, >= 0, ``c == channels`` when given.

    ``check_values=False`` checks only type and shape (the values are then
    checked block by block by the caller).

    Examples
    --------
    >>> checked_channels("rgb", [[0.1, 0.2, 0.3]], 3).shape
    (1, 3)
    """
    a = np.asarray(rgb)
    if a.dtype.kind not in "fiu":
        raise SpectralEstimationError(f"{name} must be a numeric array, got dtype {a.dtype}")
    if a.ndim == 0 or a.size == 0:
        raise SpectralEstimationError(f"{name} is empty (shape {a.shape}); give camera values (..., channels)")
    if channels is not None and a.shape[-1] != channels:
        raise SpectralEstimationError(
            f"{name} must have {channels} channels on its last axis, got shape {a.shape}"
        )
    if check_values and a.dtype.kind in "fi":
        if a.dtype.kind == "f" and not np.isfinite(a).all():
            raise SpectralEstimationError(f"{name} contains NaN or infinite values; mask those pixels first")
        if (a < 0).any():
            raise SpectralEstimationError(
                f"{name} has negative values (min {float(a.min()):.3g}); clip the black-subtracted image at 0"
            )
    return a


def checked_spectra(name: str, spectra: ArrayLike, grid: SpectralGrid | None = None) -> NDArray[np.float64]:
    """Validate spectra ``(n, L)``: non-empty, finite, on ``grid`` when given.

    Examples
    --------
    >>> checked_spectra("s", [[0.1, 0.2]]).shape
    (1, 2)
    """
    s = np.asarray(spectra, dtype=np.float64)
    if s.ndim != 2 or s.shape[0] == 0 or s.shape[1] == 0:
        raise SpectralEstimationError(f"{name} must be a non-empty (n, L) array of spectra, got shape {s.shape}")
    if grid is not None and s.shape[1] != grid.size:
        raise SpectralEstimationError(f"{name} has {s.shape[1]} wavelengths, the grid {grid.size}")
    if not np.isfinite(s).all():
        raise SpectralEstimationError(f"{name} contains NaN or infinite values")
    return s


def pca_basis(spectra: ArrayLike, p: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The first ``p`` principal directions ``(L, p)`` of spectra and their singular values.

    Uncentred (second-moment) PCA; the first vector is made positive.

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
    """Names of the features of ``expansion`` for ``channels`` inputs ('linear', 'rootpoly2', 'rootpoly3').

    Examples
    --------
    >>> feature_names(3, "rootpoly2")
    ['c0', 'c1', 'c2', 'sqrt(c0*c1)', 'sqrt(c0*c2)', 'sqrt(c1*c2)']
    """
    return [n for n, _ in _terms(channels, expansion)]


def _terms(channels: int, expansion: str) -> list[tuple[str, tuple[int, ...]]]:
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
    """Root-polynomial features (Finlayson, Mackiewicz, Hurlbert, IEEE TIP 24(5), 2015).

    Each term is a product of d channels raised to 1/d, so every feature
    scales linearly with exposure.

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
    """A fitted estimator from camera channels to basis weights.

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

        Examples
        --------
        >>> fit = SpectralFit("demo", np.eye(3), np.eye(3), SpectralGrid(400, 700, 150), 3)
        >>> fit.estimate_spectra([0.1, 0.2, 0.3]).round(3).tolist()
        [0.1, 0.2, 0.3]
        """
        return self.estimate_weights(rgb).astype(np.float64) @ self.basis.T


@contextlib.contextmanager
def _no_limit() -> Iterator[None]:
    yield


def with_transform(fit: SpectralFit, transform: ArrayLike) -> SpectralFit:
    """The estimator applied after a ``(c, c)`` chart transform (row form ``rho T``).

    For linear features the transform is folded into the matrix.

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
