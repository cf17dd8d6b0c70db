"""Wiener (linear minimum mean-square error) spectral estimation with known sensitivities and light.

``s_hat = rho (K^T R K + N)^-1 K^T R`` for camera values ``rho = s K + n``,
the prior second moments ``R`` of the database's reflectances and the noise
covariance ``N`` (Pratt & Mancill 1976); the noise level is given or chosen by
cross-validation as Shimano (2006) recommends when it is not measured.
docs/colour-pipeline.md, "Wiener estimation", states the model and its choices.

References
----------
Pratt, W. K., Mancill, C. E. (1976). Spectral estimation techniques for the
spectral calibration of a color image scanner. Applied Optics 15(1), 73-75.
doi:10.1364/AO.15.000073

Shimano, N. (2006). Recovery of spectral reflectances of objects being imaged
without prior knowledge. IEEE Transactions on Image Processing 15(7),
1848-1856.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.camera.response import channel_matrix
from processing.camera.transfer import condition_number
from processing.spectral.estimation.fit import SpectralEstimationError, SpectralFit, checked_spectra
from processing.spectral.spectra import SpectralGrid

__all__ = ["wiener_matrix", "fit_wiener", "cross_validated_noise"]

_CV_LEVELS = np.logspace(-4, 0, 17)


def wiener_matrix(
    second_moment: NDArray[np.float64], k: NDArray[np.float64], noise_covariance: NDArray[np.float64]
) -> NDArray[np.float64]:
    """The Wiener matrix ``G (c, L)``: ``s_hat = rho @ G = rho (K^T R K + N)^-1 K^T R``.

    Parameters
    ----------
    second_moment
        ``(L, L)`` prior second-moment matrix ``R`` of the reflectances.
    k
        ``(L, c)`` channel matrix ``K`` (:func:`processing.camera.response.channel_matrix`).
    noise_covariance
        ``(c, c)`` noise covariance ``N`` in squared camera units.

    Returns
    -------
    ndarray
        ``(c, L)`` float64: the estimate of a row of camera values is ``rho @ G``.

    References
    ----------
    Pratt, W. K., Mancill, C. E. (1976). Spectral estimation techniques for
    the spectral calibration of a color image scanner. Applied Optics 15(1),
    73-75. doi:10.1364/AO.15.000073

    Examples
    --------
    >>> r = np.eye(2); k = np.array([[1.0], [0.0]])
    >>> wiener_matrix(r, k, np.array([[1.0]])).tolist()     # half the signal on the seen wavelength
    [[0.5, 0.0]]
    """
    kr = k.T @ second_moment                     # (c, L)
    system = kr @ k + noise_covariance            # (c, c)
    return np.linalg.solve(system, kr)


def _noise_cov(second_moment: NDArray[np.float64], k: NDArray[np.float64], noise: float) -> NDArray[np.float64]:
    """The covariance ``noise^2 diag(K^T R K)`` of a noise proportional to each channel's mean signal."""
    return noise**2 * np.diag(np.diag(k.T @ second_moment @ k))


def cross_validated_noise(database: NDArray[np.float64], k: NDArray[np.float64], *, folds: int = 5, seed: int = 0) -> float:
    """Relative noise level (regularisation) that minimises the held-out spectral RMSE.

    Each fold's camera values get noise of the candidate level (seeded), so
    the choice reflects the level at which the data are trusted.  The
    candidates are 17 levels from 1e-4 to 1, evenly spaced in log.

    Parameters
    ----------
    database
        ``(n, L)`` training reflectances, ``n >= folds``.
    k
        ``(L, c)`` channel matrix.
    folds
        Number of cross-validation folds.
    seed
        Seed of the fold assignment and of the noise.

    Returns
    -------
    float
        The chosen relative noise level (0.01 = 1 %).

    Raises
    ------
    SpectralEstimationError
        Fewer spectra than folds.

    References
    ----------
    Shimano, N. (2006). Recovery of spectral reflectances of objects being
    imaged without prior knowledge. IEEE Transactions on Image Processing
    15(7), 1848-1856.

    Examples
    --------
    >>> g = SpectralGrid(400, 700, 20)
    >>> db = np.random.default_rng(1).uniform(0, 1, (40, g.size))
    >>> 1e-4 <= cross_validated_noise(db, np.ones((g.size, 3))) <= 1
    True
    """
    rng = np.random.default_rng(seed)
    n = database.shape[0]
    if n < folds:
        raise SpectralEstimationError(f"cross-validation needs at least {folds} database spectra, got {n}")
    order = rng.permutation(n)
    parts = np.array_split(order, folds)
    unit = rng.standard_normal((n, k.shape[1]))
    errors = np.zeros(_CV_LEVELS.size)
    for test in parts:
        train = np.setdiff1d(order, test)
        r = database[train].T @ database[train] / train.size
        rho = database[test] @ k
        for j, level in enumerate(_CV_LEVELS):
            g = wiener_matrix(r, k, _noise_cov(r, k, level))
            noisy = rho * (1.0 + level * unit[test])
            errors[j] += np.sum((noisy @ g - database[test]) ** 2)
    return float(_CV_LEVELS[int(np.argmin(errors))])


def fit_wiener(
    database: ArrayLike | None,
    sensitivities: ArrayLike,
    lights: ArrayLike,
    grid: SpectralGrid,
    *,
    noise: float | None = 0.01,
    second_moment: ArrayLike | None = None,
    noise_covariance: ArrayLike | None = None,
    method: str = "wiener",
) -> SpectralFit:
    """Fit the Wiener estimator.

    The estimate lies in the c-dimensional span of the rows of the Wiener
    matrix, so the basis is an orthonormal basis of that span and c weights
    per pixel represent the estimate exactly.

    Parameters
    ----------
    database
        Training reflectances ``(n, L)``: the prior is ``S^T S / n``.  None
        when ``second_moment`` is given.
    sensitivities
        ``(L, 3)`` camera sensitivities on ``grid`` (relative units).
    lights
        ``(L,)`` light (relative spectral power), or ``(k, L)`` for k
        exposures (3 k channels).
    grid
        The wavelength grid.
    noise
        Relative noise level (0.01 = 1 %): ``N = noise^2 diag(K^T R K)``;
        None: chosen by :func:`cross_validated_noise`.
    second_moment
        ``(L, L)`` prior second-moment matrix instead of a database.
    noise_covariance
        ``(c, c)`` absolute noise covariance (squared camera units),
        overriding ``noise``.
    method
        Name recorded in the result.

    Returns
    -------
    SpectralFit
        ``p = c`` basis vectors; ``details['noise']`` is the level used
        (absent with ``noise_covariance``), ``details['cross_validated']`` 1
        when it was chosen by cross-validation; ``training_rmse`` NaN
        without a database.

    Raises
    ------
    SpectralEstimationError
        Neither a database nor a second moment; a second moment that is not a
        finite symmetric ``(L, L)`` matrix; a noise covariance that is not
        positive semi-definite ``(c, c)``; a negative or non-finite noise;
        cross-validation without a database; a singular Wiener system.
    CameraResponseError
        Bad sensitivities or lights.

    References
    ----------
    Pratt, W. K., Mancill, C. E. (1976). Spectral estimation techniques for
    the spectral calibration of a color image scanner. Applied Optics 15(1),
    73-75. doi:10.1364/AO.15.000073

    Shimano, N. (2006). Recovery of spectral reflectances of objects being
    imaged without prior knowledge. IEEE Transactions on Image Processing
    15(7), 1848-1856.

    Examples
    --------
    >>> g = SpectralGrid(400, 700, 20)
    >>> fit = fit_wiener(None, np.ones((g.size, 3)), np.ones(g.size), g, second_moment=np.eye(g.size))
    >>> fit.p, fit.basis.shape
    (3, (16, 3))
    """
    k = channel_matrix(sensitivities, lights, grid)
    c = k.shape[1]
    r, db = _prior(database, second_moment, grid)
    nc, details = _noise_covariance(noise_covariance, noise, r, k, db)
    system = k.T @ r @ k + nc
    cond = _checked_condition(system)
    g = np.linalg.solve(system, k.T @ r)                    # (c, L)
    q, matrix = _span_basis(g)
    rmse = math.nan
    if db is not None:
        rmse = float(np.sqrt(np.mean((db @ k @ g - db) ** 2)))
    return SpectralFit(
        method, q, matrix, grid, c, training_rmse=rmse,
        condition={"system": cond, "camera": condition_number(k, rank=c)}, details=details,
    )


def _prior(
    database: ArrayLike | None, second_moment: ArrayLike | None, grid: SpectralGrid
) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
    """The checked prior second moments ``R (L, L)`` and the checked database (None without one)."""
    db = None
    if second_moment is not None:
        r = np.asarray(second_moment, dtype=np.float64)
        if r.shape != (grid.size, grid.size) or not np.isfinite(r).all():
            raise SpectralEstimationError(
                f"second_moment must be a finite ({grid.size}, {grid.size}) matrix, got shape {r.shape}"
            )
        if not np.allclose(r, r.T, rtol=1e-9, atol=1e-12 * max(1.0, float(np.abs(r).max()))):
            raise SpectralEstimationError("second_moment must be symmetric")
    else:
        if database is None:
            raise SpectralEstimationError("give a database of reflectances or a second_moment matrix")
        db = checked_spectra("database", database, grid)
        r = db.T @ db / db.shape[0]
    return r, db


def _noise_covariance(
    noise_covariance: ArrayLike | None,
    noise: float | None,
    r: NDArray[np.float64],
    k: NDArray[np.float64],
    db: NDArray[np.float64] | None,
) -> tuple[NDArray[np.float64], dict[str, float]]:
    """The checked noise covariance ``N (c, c)`` (given, or of the relative level) and the details to record."""
    c = k.shape[1]
    details: dict[str, float] = {}
    if noise_covariance is not None:
        nc = np.asarray(noise_covariance, dtype=np.float64)
        if nc.shape != (c, c) or not np.isfinite(nc).all() or np.any(np.linalg.eigvalsh((nc + nc.T) / 2) < 0):
            raise SpectralEstimationError(f"noise_covariance must be a finite positive semi-definite ({c}, {c}) matrix")
    else:
        if noise is None:
            if db is None:
                raise SpectralEstimationError("noise=None (cross-validation) needs a database, not a second_moment")
            noise = cross_validated_noise(db, k)
            details["cross_validated"] = 1.0
        if not (isinstance(noise, (int, float, np.floating)) and math.isfinite(noise) and noise >= 0):
            raise SpectralEstimationError(f"noise must be a relative level >= 0 (0.01 = 1 %), got {noise!r}")
        details["noise"] = float(noise)
        nc = _noise_cov(r, k, float(noise))
    return nc, details


def _checked_condition(system: NDArray[np.float64]) -> float:
    """The condition number of the Wiener system ``K^T R K + N``; refused above 1e14."""
    cond = float(np.linalg.cond(system))
    if not math.isfinite(cond) or cond > 1e14:
        raise SpectralEstimationError(
            f"the Wiener system is singular (condition number {cond:.3g}); the prior gives no signal in some channel "
            "or the channels are dependent: add noise > 0 or check the sensitivities and lights"
        )
    return cond


def _span_basis(g: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """An orthonormal basis ``Q (L, c)`` of the span of the Wiener matrix's rows and the map ``G Q (c, c)`` onto it."""
    q, _ = np.linalg.qr(g.T)                                 # orthonormal basis of the estimate's span
    if q[:, 0].sum() < 0:
        q[:, 0] *= -1
    matrix = g @ q                                           # (c, c): w = rho @ matrix
    return q, matrix
