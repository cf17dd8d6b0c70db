"""The paper's spectral estimator: PCA basis with p = 3 and a 3 x 3 camera-to-weights matrix.

Matsuda et al., section 4.1, eq. (6)-(10): the reflectances of a database are
written in their first p = 3 principal components ``B (L, 3)`` (eq. (6)-(7)),
``w = B^T s``; the database's reference-camera values ``rho = K^T s`` are
regressed on the weights by least squares, ``w = M rho`` (eq. (8)),
and a pixel's reflectance is ``s = B M rho``.  The object camera
enters through the chart transform M2 (eq. (9)-(10), :mod:`processing.camera.transfer`).

When every database spectrum lies in the span of the three basis vectors
the mapping from camera values to weights is exactly linear, and the
estimate reproduces the database spectra exactly (the closed-form case the
tests check).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from processing.camera.response import channel_matrix
from processing.camera.transfer import condition_number
from processing.spectral.estimation.fit import SpectralEstimationError, SpectralFit, checked_spectra, pca_basis
from processing.spectral.spectra import SpectralGrid

__all__ = ["fit_paper"]


def fit_paper(
    database: ArrayLike,
    sensitivities: ArrayLike,
    light: ArrayLike,
    grid: SpectralGrid,
    *,
    p: int = 3,
) -> SpectralFit:
    """Fit the paper's estimator on database reflectances ``(n, L)``.

    Parameters
    ----------
    database
        Training reflectances ``(n, L)`` on ``grid``.
    sensitivities
        ``(L, 3)`` reference-camera sensitivities.
    light
        ``(L,)`` light of the shot (or ``(k, L)`` for k exposures).
    grid
        The wavelength grid.
    p
        Basis size (the paper: 3).

    Returns
    -------
    SpectralFit
        Method 'paper', linear features; ``condition['camera']`` is
        sigma_1 / sigma_c of the database's camera values.

    Examples
    --------
    >>> g = SpectralGrid(400, 700, 10)
    >>> wl = g.wavelengths
    >>> db = np.stack([0.5 + 0.3 * np.sin(wl / 40 + k) for k in range(10)])
    >>> s = np.stack([np.exp(-((wl - c) / 40) ** 2) for c in (600, 540, 450)], axis=1)
    >>> fit = fit_paper(db, s, np.ones(g.size), g)
    >>> rho = db @ (s * g.step)
    >>> float(np.abs(fit.estimate_spectra(rho) - db).max()) < 1e-4
    True
    """
    db = checked_spectra("database", database, grid)
    k = channel_matrix(sensitivities, light, grid)
    c = k.shape[1]
    if db.shape[0] < max(p, c):
        raise SpectralEstimationError(
            f"the database has {db.shape[0]} spectra; the paper's fit needs at least {max(p, c)}"
        )
    basis, _ = pca_basis(db, p)
    rho = db @ k
    weights = db @ basis
    cond = condition_number(rho, rank=c)
    if not np.isfinite(cond):
        raise SpectralEstimationError("the database's camera values are rank deficient; the matrix M cannot be fitted")
    m = np.linalg.lstsq(rho, weights, rcond=None)[0]
    rmse = float(np.sqrt(np.mean((rho @ m @ basis.T - db) ** 2)))
    return SpectralFit("paper", basis, m, grid, c, training_rmse=rmse, condition={"camera": cond})
