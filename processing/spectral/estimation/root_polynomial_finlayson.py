"""Root-polynomial regression from camera values to the weights of a larger PCA basis.

Finlayson, Mackiewicz & Hurlbert, "Color correction using root-polynomial
regression", IEEE TIP 24(5), 2015: the camera values are expanded into terms
``rho_i``, ``(rho_i rho_j)^(1/2)``, ``(rho_i rho_j rho_k)^(1/3)`` ...,
each of degree one in the exposure, and a linear map of the terms is fitted by
least squares.  Here the target is the weights of the database's first ``p``
principal components (``p`` = 8 by default, more than the paper's 3), so the
regression is from terms to weights, and ridge (Tikhonov) regularisation
keeps the extra basis vectors from fitting noise.

Regularisation.  The training camera values get noise of the stated relative
level (five noisy copies of the database, seeded), and the ridge weight is
chosen by five-fold cross-validation of the spectral RMSE over 1e-8 .. 1 (in
units of the mean squared feature).  With ``degree=1`` this is linear
regression onto a larger basis ("more basis vectors with regularisation").

Because every term scales with exposure and the map is linear, scaling the
camera values scales the weights by the same factor (tested).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.camera.response import channel_matrix
from processing.camera.transfer import condition_number
from processing.spectral.estimation.fit import (
    SpectralEstimationError,
    SpectralFit,
    checked_spectra,
    expand_features,
    pca_basis,
)
from processing.spectral.spectra import SpectralGrid

__all__ = ["fit_rootpoly"]

_RIDGE = np.logspace(-8, 0, 17)
_COPIES = 5


def _ridge(x: NDArray[np.float64], y: NDArray[np.float64], lam: float) -> NDArray[np.float64]:
    scale = float(np.mean(x * x))
    f = x.shape[1]
    return np.linalg.solve(x.T @ x + lam * scale * x.shape[0] * np.eye(f), x.T @ y)


def fit_rootpoly(
    database: ArrayLike,
    sensitivities: ArrayLike,
    lights: ArrayLike,
    grid: SpectralGrid,
    *,
    p: int = 8,
    degree: int = 2,
    noise: float = 0.01,
    ridge: float | None = None,
    seed: int = 0,
    method: str | None = None,
) -> SpectralFit:
    """Fit root-polynomial regression onto ``p`` PCA weights.

    Parameters
    ----------
    database
        Training reflectances ``(n, L)`` on ``grid``.
    sensitivities
        ``(L, 3)`` camera sensitivities.
    lights
        ``(L,)`` light or ``(k, L)`` for k exposures.
    grid
        The wavelength grid.
    p
        Basis size.
    degree
        1 (linear), 2 or 3 (root-polynomial degree).
    noise
        Relative noise added to the training camera values (0.01 = 1 %).
    ridge
        Ridge weight; None: five-fold cross-validation.
    seed
        Seed of the training noise and folds.
    method
        Name recorded in the result (default 'rootpoly', or 'more-basis' for degree 1).

    Examples
    --------
    >>> from processing.spectral.reflectance_database import load_reflectances
    >>> from processing.camera.response import camera_sensitivities, camera_rgb
    >>> g = SpectralGrid(400, 700, 10)
    >>> db = load_reflectances("training", g).spectra
    >>> s = camera_sensitivities(g)
    >>> fit = fit_rootpoly(db, s, np.ones(g.size), g, p=6)
    >>> fit.p, fit.expansion, fit.training_rmse < 0.1
    (6, 'rootpoly2', True)
    """
    db = checked_spectra("database", database, grid)
    if degree not in (1, 2, 3):
        raise SpectralEstimationError(f"root-polynomial degree must be 1, 2 or 3, got {degree!r}")
    if not (isinstance(noise, (int, float, np.floating)) and math.isfinite(noise) and noise >= 0):
        raise SpectralEstimationError(f"noise must be a relative level >= 0, got {noise!r}")
    k = channel_matrix(sensitivities, lights, grid)
    c = k.shape[1]
    expansion = "linear" if degree == 1 else f"rootpoly{degree}"
    basis, _ = pca_basis(db, p)
    rng = np.random.default_rng(seed)
    rho = db @ k
    copies = 1 if noise == 0 else _COPIES
    rho_train = np.concatenate([rho * (1.0 + noise * rng.standard_normal(rho.shape)) for _ in range(copies)])
    rho_train = np.maximum(rho_train, 0.0)
    target_spectra = np.tile(db, (copies, 1))
    x = expand_features(rho_train, expansion)
    y = target_spectra @ basis
    if x.shape[0] <= x.shape[1]:
        raise SpectralEstimationError(
            f"the database has {db.shape[0]} spectra, too few for {x.shape[1]} root-polynomial terms"
        )
    details: dict[str, float] = {"noise": float(noise), "degree": float(degree)}
    if ridge is None:
        groups = np.tile(np.arange(db.shape[0]), copies)
        fold_of = rng.permutation(db.shape[0]) % 5
        errors = np.zeros(_RIDGE.size)
        for f in range(5):
            test = fold_of[groups] == f
            for j, lam in enumerate(_RIDGE):
                a = _ridge(x[~test], y[~test], lam)
                errors[j] += np.sum((x[test] @ a @ basis.T - target_spectra[test]) ** 2)
        ridge = float(_RIDGE[int(np.argmin(errors))])
        details["cross_validated"] = 1.0
    if not (math.isfinite(ridge) and ridge >= 0):
        raise SpectralEstimationError(f"ridge must be >= 0, got {ridge!r}")
    details["ridge"] = float(ridge)
    a = _ridge(x, y, ridge)
    clean = expand_features(rho, expansion)
    rmse = float(np.sqrt(np.mean((clean @ a @ basis.T - db) ** 2)))
    name = method or ("more-basis" if degree == 1 else "rootpoly")
    return SpectralFit(
        name, basis, a, grid, c, expansion=expansion, training_rmse=rmse,
        condition={"features": condition_number(x, rank=x.shape[1]), "camera": condition_number(rho, rank=c)},
        details=details,
    )
