"""A few non-negative spectra that every pixel of a spectral map is a non-negative mix of.

An :class:`~processing.lighting.environment_map.EnvironmentMap` holds ``K`` non-negative
coefficients per pixel of ``K`` basis spectra, and the renderer's cost grows with ``K``.  A map
whose spectra come from a non-linear estimator (six camera channels through a root polynomial)
has no such basis of its own: :func:`nonnegative_basis` finds one, a non-negative matrix
factorisation ``V ~ C B`` (``V`` the pixels' spectra, ``C >= 0``, ``B >= 0``) by Lee and Seung's
multiplicative updates from the map's most distinct spectra (successive projection) and a few random
starts, the coefficients solved exactly between updates, each spectrum scaled to unit luminance so a dim
wall counts as much as a bright lamp; it fits the spectra's shapes.  :func:`nonnegative_coefficients`
gives every pixel its coefficients on that basis by exact non-negative least squares of the spectrum
*and* its CIE XYZ, the latter weighted by ``colour_weight``: the renderer's output is colour, so a
pixel's colour is kept first where the basis cannot hold its spectrum exactly.  (Weighting the colour
in the basis's fit too was tried: on the simulated room's probe it kept the colours no better and the
spectra five to ten times worse.)

References
----------
Lee, D. D., & Seung, H. S. (1999). Learning the parts of objects by non-negative matrix
factorization. Nature 401, 788-791. doi:10.1038/44565

Lee, D. D., & Seung, H. S. (2001). Algorithms for non-negative matrix factorization. Advances in
Neural Information Processing Systems 13, 556-562 (no DOI).

Gillis, N., & Vavasis, S. A. (2014). Fast and robust recursive algorithms for separable nonnegative
matrix factorization. IEEE Transactions on Pattern Analysis and Machine Intelligence 36(4), 698-714.
doi:10.1109/TPAMI.2013.226

Examples
--------
>>> import numpy as np
>>> from processing.spectral.spectra import SpectralGrid
>>> g = SpectralGrid(400, 700, 10)
>>> wl = g.wavelengths
>>> parts = np.stack([np.exp(-0.5 * ((wl - c) / 40) ** 2) for c in (450, 550, 650)])
>>> mix = np.vstack([parts, np.random.default_rng(0).uniform(0, 1, (500, 3)) @ parts])
>>> b = nonnegative_basis(mix, 3, g)
>>> c = nonnegative_coefficients(mix, b, g)
>>> bool(np.abs(c @ b - mix).max() < 0.02 * mix.max()), bool((b >= 0).all() and (c >= 0).all())
(True, True)
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.errors import InputError
from processing.spectral.display import spectra_to_xyz
from processing.spectral.spectra import SpectralGrid

__all__ = ["NonnegativeBasisError", "nonnegative_basis", "nonnegative_coefficients", "COLOUR_WEIGHT", "MAX_COMPONENTS"]

#: Most basis spectra: the exact non-negative fit tries every support (2^k - 1 of them).
MAX_COMPONENTS = 6
#: Weight of the XYZ error against the spectral error (per unit of the spectra's own scale).
COLOUR_WEIGHT = 10.0
_EPS = 1e-30
#: Multiplicative updates of the basis between exact solutions for the coefficients.
_UPDATES_PER_SOLVE = 20


class NonnegativeBasisError(InputError):
    """Spectra that cannot be factorised (one line saying why)."""


def _checked(spectra: ArrayLike, grid: SpectralGrid) -> NDArray[np.float64]:
    v = np.asarray(spectra, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != grid.size or v.shape[0] == 0:
        raise NonnegativeBasisError(f"spectra must be (n >= 1, {grid.size}) on the grid, got shape {v.shape}")
    if not np.isfinite(v).all():
        raise NonnegativeBasisError("spectra hold NaN or infinite values")
    return np.maximum(v, 0.0)


def _augmented(v: NDArray[np.float64], xyz_of: NDArray[np.float64], weight: float) -> NDArray[np.float64]:
    """``[V, w V X]``: the spectra beside their (scaled) XYZ, both non-negative."""
    return np.concatenate([v, weight * (v @ xyz_of)], axis=1)


def _xyz_matrix(grid: SpectralGrid) -> NDArray[np.float64]:
    """``(L, 3)`` with ``spectra @ X`` their XYZ, scaled so a flat unit spectrum has Y = 1 per wavelength."""
    x = spectra_to_xyz(np.eye(grid.size), grid)
    return x / max(float(x[:, 1].sum()), _EPS) * grid.size


def _nnls(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Exact non-negative least squares ``min ||c b - a||, c >= 0`` for every row of ``a`` at once.

    The solution is the unconstrained least-squares one on its support, so among the supports whose
    solution is non-negative the one with the least error is it: with ``k <= 6`` basis rows the
    ``2^k - 1`` supports are tried, each one matrix product over all rows.
    """
    k = b.shape[0]
    best_c = np.zeros((a.shape[0], k))
    norm2 = np.einsum("ij,ij->i", a, a)
    best_err = norm2.copy()                                           # the empty support: c = 0
    r_all = a @ b.T                                                   # (n, k)
    gram = b @ b.T
    for mask in range(1, 1 << k):
        s = [i for i in range(k) if mask >> i & 1]
        g = gram[np.ix_(s, s)]
        w = np.linalg.eigvalsh(g)
        if not w[0] > 1e-12 * w[-1]:                                  # a support of dependent spectra
            continue
        r = r_all[:, s]
        c = r @ np.linalg.inv(g)
        err = norm2 - np.einsum("ij,ij->i", c, r)
        ok = (c.min(axis=1) >= 0) & (err < best_err)
        if ok.any():
            best_err[ok] = err[ok]
            row = np.zeros((int(ok.sum()), k))
            row[:, s] = c[ok]
            best_c[ok] = row
    return best_c


def _successive_projection(a: NDArray[np.float64], k: int) -> list[int]:
    """Rows of ``a`` at the corners of the cone they span: the successive projection algorithm.

    Each step takes the row of largest norm after projecting out the rows already taken (Gillis and
    Vavasis 2014, doi:10.1109/TPAMI.2013.226): the start of the factorisation is made of the map's most
    distinct spectra (the saturated walls, the lamps), which its other pixels mix.
    """
    r = a / np.maximum(a.sum(axis=1, keepdims=True), _EPS)               # unit sum: the corners have the largest norm
    chosen: list[int] = []
    for _ in range(min(k, len(a))):
        i = int(np.argmax(np.einsum("ij,ij->i", r, r)))
        chosen.append(i)
        q = r[i] / max(float(np.linalg.norm(r[i])), _EPS)
        r = r - np.outer(r @ q, q)
    while len(chosen) < k:                                            # fewer spectra than k: repeat one
        chosen.append(chosen[-1])
    return chosen


def nonnegative_basis(spectra: ArrayLike, k: int, grid: SpectralGrid, *, weights: ArrayLike | None = None,
                      samples: int = 4000, iterations: int = 400, restarts: int = 3,
                      colour_weight: float = 0.0, seed: int = 0) -> NDArray[np.float64]:
    """``(k, L)`` non-negative basis spectra, each of luminance 1, that mix into ``spectra``.

    Parameters
    ----------
    spectra
        ``(n, L)`` non-negative spectra (negative values are taken as 0).
    k
        Number of basis spectra (1-6).
    grid
        Their wavelength grid.
    weights
        ``(n,)`` how much each spectrum counts (e.g. the pixels' solid angles); default equal.
    samples
        At most this many spectra (drawn by weight, reproducibly) are factorised.
    iterations
        Multiplicative updates of the basis per start (the coefficients are solved exactly every 10).
    restarts
        Random starts beside the one from the most distinct spectra; the factorisation with the
        smallest error is kept.
    colour_weight
        Weight of the XYZ error beside the spectral error (default 0: the spectra's shapes alone; the
        coefficients keep the colour).
    seed
        Seed of the sample and of the starting point.

    Returns
    -------
    ndarray
        ``(k, L)``, rows sorted by dominant wavelength (reproducible order).

    Raises
    ------
    NonnegativeBasisError
        Bad shapes or values, ``k`` out of range, spectra all black.
    """
    v = _checked(spectra, grid)
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 1 <= k <= MAX_COMPONENTS:
        raise NonnegativeBasisError(f"the number of basis spectra must be 1-{MAX_COMPONENTS}, got {k!r}")
    xyz_of = _xyz_matrix(grid)
    lum = v @ xyz_of[:, 1] / grid.size
    w = np.ones(len(v)) if weights is None else np.asarray(weights, dtype=np.float64).ravel()
    if w.shape != (len(v),) or not np.isfinite(w).all() or (w < 0).any():
        raise NonnegativeBasisError(f"weights must be {len(v)} finite values >= 0")
    w = np.where(lum > 0, w, 0.0)
    if not w.sum() > 0:
        raise NonnegativeBasisError("the spectra are all black (or weigh nothing); there is nothing to factorise")
    rng = np.random.default_rng(seed)
    n = min(int(samples), int((w > 0).sum()))
    idx = rng.choice(len(v), n, replace=False, p=w / w.sum())
    u = v[idx] / lum[idx, None]                                      # unit luminance: dim and bright count alike
    a = _augmented(u, xyz_of, colour_weight)
    # the basis is spectra s, seen as s P = [s, w s X]: its colour part always the colour of its spectra
    proj = _augmented(np.eye(grid.size), xyz_of, colour_weight)       # (L, L + 3)
    pp = proj @ proj.T
    best, best_err = None, np.inf
    starts = [u[_successive_projection(a, k)]] + [u[rng.choice(n, k, replace=False)] for _ in range(restarts)]
    for s in starts:
        s = s + 1e-3 * u.mean(axis=0)                                 # no exact zeros: they could not move
        solves = int(iterations) // _UPDATES_PER_SOLVE + 1
        for step in range(solves):
            c = _nnls(a, s @ proj)
            err = float(np.sum((c @ (s @ proj) - a) ** 2))
            if err < best_err:
                best, best_err = s.copy(), err
            if step == solves - 1:
                break
            c += 1e-12
            for _ in range(_UPDATES_PER_SOLVE):
                s *= ((c.T @ a) @ proj.T) / np.maximum((c.T @ c) @ s @ pp, _EPS)
    b = best
    basis = b
    y = basis @ xyz_of[:, 1] / grid.size
    basis = basis[y > 0] / y[y > 0, None]
    order = np.argsort(grid.wavelengths[np.argmax(basis, axis=1)], kind="stable")
    return np.ascontiguousarray(basis[order])


def nonnegative_coefficients(spectra: ArrayLike, basis: ArrayLike, grid: SpectralGrid, *,
                             colour_weight: float = COLOUR_WEIGHT, block: int = 1 << 16) -> NDArray[np.float32]:
    """``(n, k)`` non-negative coefficients with ``coefficients @ basis`` closest to ``spectra`` (and their XYZ).

    Exact non-negative least squares (every support of the basis tried).

    Parameters
    ----------
    spectra
        ``(n, L)`` spectra (negative values taken as 0).
    basis
        ``(k, L)`` non-negative basis (:func:`nonnegative_basis`).
    grid
        The wavelength grid.
    colour_weight
        Weight of the XYZ error, as for :func:`nonnegative_basis`.
    block
        Spectra per block (memory).

    Returns
    -------
    ndarray
        float32 ``(n, k)``; 0 for a black spectrum.
    """
    v = _checked(spectra, grid)
    b = np.asarray(basis, dtype=np.float64)
    if b.ndim != 2 or b.shape[1] != grid.size or not np.isfinite(b).all() or (b < 0).any():
        raise NonnegativeBasisError(f"basis must be (k, {grid.size}) finite values >= 0, got shape {b.shape}")
    xyz_of = _xyz_matrix(grid)
    ba = _augmented(b, xyz_of, colour_weight)
    out = np.empty((len(v), len(b)), np.float32)
    for i in range(0, len(v), block):
        out[i:i + block] = _nnls(_augmented(v[i:i + block], xyz_of, colour_weight), ba)
    return out
