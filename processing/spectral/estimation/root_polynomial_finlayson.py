"""Root-polynomial regression from camera values to the weights of a larger PCA basis.

The camera values are expanded into root-polynomial terms, each of degree one
in the exposure (Finlayson, Mackiewicz & Hurlbert 2015), and a ridge-regularised
linear map from the terms to the weights of the database's first ``p``
principal components is fitted on noisy copies of the training values;
``degree=1`` is plain linear regression onto the larger basis
(:func:`fit_more_basis`).  docs/colour-pipeline.md, "Root-polynomial
regression", gives the training and regularisation in full.

References
----------
Finlayson, G. D., Mackiewicz, M., Hurlbert, A. (2015). Color correction using
root-polynomial regression. IEEE Transactions on Image Processing 24(5),
1460-1470. doi:10.1109/TIP.2015.2405336
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

__all__ = ["fit_rootpoly", "fit_more_basis"]

_RIDGE = np.logspace(-8, 0, 17)
_COPIES = 5


def _ridge(x: NDArray[np.float64], y: NDArray[np.float64], lam: float) -> NDArray[np.float64]:
    """Ridge solution of ``x a = y`` with weight ``lam`` in units of the mean squared feature."""
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

    The training camera values get noise of the stated relative level (five
    noisy copies of the database, seeded; one clean copy when ``noise`` is 0)
    and the ridge weight is chosen by five-fold cross-validation of the
    spectral RMSE over 1e-8 .. 1 (in units of the mean squared feature).
    Scaling the camera values scales the weights by the same factor.

    Parameters
    ----------
    database
        Training reflectances ``(n, L)`` on ``grid``.
    sensitivities
        ``(L, 3)`` camera sensitivities (relative units).
    lights
        ``(L,)`` light (relative spectral power) or ``(k, L)`` for k exposures.
    grid
        The wavelength grid.
    p
        Basis size.
    degree
        1 (linear), 2 or 3 (root-polynomial degree).
    noise
        Relative noise added to the training camera values (0.01 = 1 %).
    ridge
        Ridge weight (relative to the mean squared feature); None: five-fold
        cross-validation.
    seed
        Seed of the training noise and folds.
    method
        Name recorded in the result (default 'rootpoly', or 'more-basis' for degree 1).

    Returns
    -------
    SpectralFit
        Expansion 'linear', 'rootpoly2' or 'rootpoly3'; ``details`` holds
        ``noise``, ``degree``, ``ridge`` and ``cross_validated`` (1 when the
        ridge weight was chosen); ``condition`` the features' and the camera
        values' condition numbers.

    Raises
    ------
    SpectralEstimationError
        Bad database, degree, noise, ``p`` or ridge weight, or fewer training
        values than root-polynomial terms.
    CameraResponseError
        Bad sensitivities or lights.

    References
    ----------
    Finlayson, G. D., Mackiewicz, M., Hurlbert, A. (2015). Color correction
    using root-polynomial regression. IEEE Transactions on Image Processing
    24(5), 1460-1470. doi:10.1109/TIP.2015.2405336

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
    rho_train, target_spectra, copies = _noisy_training_set(db, rho, noise, rng)
    x = expand_features(rho_train, expansion)
    y = target_spectra @ basis
    if x.shape[0] <= x.shape[1]:
        raise SpectralEstimationError(
            f"the database has {db.shape[0]} spectra, too few for {x.shape[1]} root-polynomial terms"
        )
    details: dict[str, float] = {"noise": float(noise), "degree": float(degree)}
    if ridge is None:
        ridge = _cross_validated_ridge(x, y, basis, target_spectra, db.shape[0], copies, rng)
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


def _noisy_training_set(
    db: NDArray[np.float64], rho: NDArray[np.float64], noise: float, rng: np.random.Generator
) -> tuple[NDArray[np.float64], NDArray[np.float64], int]:
    """Camera values with relative noise (five copies; one when noise is 0), their spectra, and the copies."""
    copies = 1 if noise == 0 else _COPIES
    rho_train = np.concatenate([rho * (1.0 + noise * rng.standard_normal(rho.shape)) for _ in range(copies)])
    rho_train = np.maximum(rho_train, 0.0)
    target_spectra = np.tile(db, (copies, 1))
    return rho_train, target_spectra, copies


def _cross_validated_ridge(
    x: NDArray[np.float64],
    y: NDArray[np.float64],
    basis: NDArray[np.float64],
    target_spectra: NDArray[np.float64],
    n: int,
    copies: int,
    rng: np.random.Generator,
) -> float:
    """The ridge weight of :data:`_RIDGE` with the least five-fold spectral error (copies of a spectrum share a fold)."""
    groups = np.tile(np.arange(n), copies)
    fold_of = rng.permutation(n) % 5
    errors = np.zeros(_RIDGE.size)
    for f in range(5):
        test = fold_of[groups] == f
        for j, lam in enumerate(_RIDGE):
            a = _ridge(x[~test], y[~test], lam)
            errors[j] += np.sum((x[test] @ a @ basis.T - target_spectra[test]) ** 2)
    return float(_RIDGE[int(np.argmin(errors))])


def fit_more_basis(
    database: ArrayLike,
    sensitivities: ArrayLike,
    lights: ArrayLike,
    grid: SpectralGrid,
    *,
    p: int = 8,
    noise: float = 0.01,
    ridge: float | None = None,
    seed: int = 0,
) -> SpectralFit:
    """Fit linear regression onto ``p`` PCA weights with ridge: :func:`fit_rootpoly` of degree 1.

    More basis vectors than the paper's three, kept from fitting noise by the
    ridge weight; the method 'more-basis' of
    :func:`processing.spectral.estimation.estimator.fit_estimator`.

    Parameters
    ----------
    database, sensitivities, lights, grid, p, noise, ridge, seed
        As :func:`fit_rootpoly`.

    Returns
    -------
    SpectralFit
        Method 'more-basis', linear features.

    Raises
    ------
    SpectralEstimationError, CameraResponseError
        As :func:`fit_rootpoly`.

    Examples
    --------
    >>> from processing.spectral.reflectance_database import load_reflectances
    >>> from processing.camera.response import camera_sensitivities
    >>> g = SpectralGrid(400, 700, 10)
    >>> fit = fit_more_basis(load_reflectances("training", g).spectra, camera_sensitivities(g), np.ones(g.size), g)
    >>> fit.method, fit.expansion, fit.p
    ('more-basis', 'linear', 8)
    """
    return fit_rootpoly(database, sensitivities, lights, grid, p=p, degree=1, noise=noise, ridge=ridge, seed=seed)
