"""The paper's spectral estimator: PCA basis with p = 3 and a 3 x 3 camera-to-weights matrix.

Matsuda et al., section 4.1, eq. (6)-(10): the database's reflectances in their
first principal components ``B``, the camera values regressed onto the
weights by least squares, ``w = M rho`` (eq. (8)); docs/colour-pipeline.md,
"The paper's estimator", gives the derivation.

References
----------
Matsuda, Tanaka, Ichikawa, Mochizuki, Muroya, Kitamura, "CG reproduction of a
craft object based on a light reflection model", IPSJ technical report
(no DOI), section 4.1, eq. (6)-(10).
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

    The weights are ``w = B^T s`` in the uncentred PCA basis ``B (L, p)`` of
    the database, and ``M`` is the least-squares map from the database's
    camera values ``rho = s K`` to them (eq. (8)), so a pixel's reflectance is
    ``s = B M rho``.  When every database spectrum lies in the span of the
    basis the estimate reproduces the database exactly.

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

    Raises
    ------
    SpectralEstimationError
        Bad database, fewer spectra than ``max(p, c)``, bad ``p``, or camera
        values of rank below c.
    CameraResponseError
        Bad sensitivities or light (:func:`processing.camera.response.channel_matrix`).

    References
    ----------
    Matsuda et al., IPSJ technical report (no DOI), section 4.1, eq. (6)-(8).

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
