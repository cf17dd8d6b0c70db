"""Camera spectral sensitivities estimated from a colour chart of known reflectances under a known light.

Each channel solves ``min ||A s_c - rho_c||^2 + lambda ||D2 s_c||^2`` subject to
``s_c >= 0``, with ``A = R diag(E) step`` the chart's light-weighted
reflectances and ``D2`` the second difference (smoothness); lambda by
generalised cross-validation or, when the patch noise is known, by Morozov's
discrepancy principle.  docs/colour-pipeline.md, "Unknown camera", gives the
method, the conditioning check and when to prefer it.

References
----------
Finlayson, G., Hordley, S., Hubel, P. M. (1998). Recovering device
sensitivities with quadratic programming. IS&T/SID Color Imaging Conference
(no DOI).

Jiang, J., Liu, D., Gu, J., Susstrunk, S. (2013). What is the space of
spectral sensitivity functions for digital color cameras? IEEE Workshop on
Applications of Computer Vision (WACV), 168-179. doi:10.1109/WACV.2013.6475015

Golub, G. H., Heath, M., Wahba, G. (1979). Generalized cross-validation as a
method for choosing a good ridge parameter. Technometrics 21(2), 215-223.
doi:10.1080/00401706.1979.10489751
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import nnls

from processing.camera.response import channel_matrix
from processing.camera.transfer import ChartConditionError, condition_number
from processing.spectral.checks import SpectralEstimationError, checked_channels, checked_spectra
from processing.spectral.spectra import SpectralGrid

__all__ = ["SensitivityFit", "estimate_sensitivities"]

#: Largest accepted sigma_1 / sigma_3 of the chart's light-weighted reflectances.
MAX_CONDITION = 50.0
_LAMBDAS = np.logspace(-8, 0, 33)


@dataclass(frozen=True)
class SensitivityFit:
    """Estimated camera sensitivities.

    Parameters
    ----------
    sensitivities, condition, regularisation, residual
        The attributes below, in this order.

    Attributes
    ----------
    sensitivities
        ``(L, c)`` non-negative sensitivities on the grid (units of the chart values).
    condition
        sigma_1 / sigma_3 of the chart system ``A``.
    regularisation
        The chosen relative smoothness weight per channel.
    residual
        RMS relative residual of the patches' predicted values.
    """

    sensitivities: NDArray[np.float64]
    condition: float
    regularisation: tuple[float, ...]
    residual: float


def _second_difference(n: int) -> NDArray[np.float64]:
    """The ``(n - 2, n)`` second-difference matrix."""
    d = np.zeros((n - 2, n))
    i = np.arange(n - 2)
    d[i, i], d[i, i + 1], d[i, i + 2] = 1.0, -2.0, 1.0
    return d


def _solve(a: NDArray[np.float64], d: NDArray[np.float64], rho: NDArray[np.float64], lam: float, unit: float) -> NDArray[np.float64]:
    """Non-negative smooth sensitivities ``(L, c)``: NNLS on ``A`` stacked over ``sqrt(lam unit) D2``, per channel."""
    stacked = np.vstack([a, np.sqrt(lam * unit) * d])
    out = np.zeros((a.shape[1], rho.shape[1]))
    for c in range(rho.shape[1]):
        target = np.concatenate([rho[:, c], np.zeros(d.shape[0])])
        out[:, c] = nnls(stacked, target, maxiter=50 * a.shape[1])[0]
    return out


def _gcv_lambda(a: NDArray[np.float64], d: NDArray[np.float64], rho: NDArray[np.float64], unit: float) -> float:
    """One weight for all channels: the minimum of the GCV score summed over the channels."""
    ata, dtd = a.T @ a, d.T @ d
    n = a.shape[0]
    rho_n = rho / np.maximum(np.linalg.norm(rho, axis=0), 1e-300)      # channels count alike
    best, best_score = float(_LAMBDAS[-1]), np.inf
    for lam in _LAMBDAS:
        h = a @ np.linalg.solve(ata + lam * unit * dtd, a.T)
        resid = rho_n - h @ rho_n
        dof = n - np.trace(h)
        if dof <= 1e-9:
            continue
        score = n * float(np.sum(resid**2)) / dof**2
        if score < best_score:
            best, best_score = float(lam), score
    return best


def _discrepancy_lambda(
    a: NDArray[np.float64], d: NDArray[np.float64], rho: NDArray[np.float64], unit: float, noise: float
) -> float:
    """Morozov's discrepancy principle: the largest weight whose relative residual stays within the noise."""
    scale = np.maximum(np.abs(rho), 1e-300)
    best = float(_LAMBDAS[0])
    for lam in _LAMBDAS:
        resid = np.sqrt(np.mean(((a @ _solve(a, d, rho, lam, unit) - rho) / scale) ** 2))
        if resid <= noise:
            best = float(lam)
        else:
            break
    return best


def estimate_sensitivities(
    chart_rgb: ArrayLike,
    chart_reflectance: ArrayLike,
    light: ArrayLike,
    grid: SpectralGrid,
    *,
    regularisation: float | None = None,
    noise: float | None = None,
    max_condition: float = MAX_CONDITION,
) -> SensitivityFit:
    """Estimate smooth, non-negative camera sensitivities from chart patches.

    Parameters
    ----------
    chart_rgb
        ``(n, c)`` linear camera values of the patches (one exposure).
    chart_reflectance
        ``(n, L)`` reflectances of the same patches on ``grid``.
    light
        ``(L,)`` the light of the chart shot.
    grid
        The wavelength grid.
    regularisation
        Relative smoothness weight; None: chosen from the data (below).
    noise
        Relative noise of the patch values (0.001 for patch means of about
        100 pixels at 1 % noise); when given, the weight follows the
        discrepancy principle, otherwise generalised cross-validation.
    max_condition
        Largest accepted sigma_1 / sigma_3 of the chart system (the 24-patch
        ColorChecker under D65 gives about 5, its six greys about 330).

    Returns
    -------
    SensitivityFit
        ``(L, c)`` sensitivities in units of the chart values per unit
        reflectance, light and nm; the condition number, the weight and the
        relative residual.

    Raises
    ------
    SpectralEstimationError
        Bad chart values or reflectances, one row per patch not matched, a
        negative regularisation or a noise that is not > 0.
    ChartConditionError
        The chart spans too few colours (condition number above
        ``max_condition``).
    CameraResponseError
        Bad light.

    References
    ----------
    Jiang, J., Liu, D., Gu, J., Susstrunk, S. (2013). What is the space of
    spectral sensitivity functions for digital color cameras? IEEE WACV,
    168-179. doi:10.1109/WACV.2013.6475015

    Golub, G. H., Heath, M., Wahba, G. (1979). Generalized cross-validation
    as a method for choosing a good ridge parameter. Technometrics 21(2),
    215-223. doi:10.1080/00401706.1979.10489751

    Examples
    --------
    >>> from processing.spectral.reflectance_database import load_reflectances
    >>> from processing.camera.response import camera_sensitivities, camera_rgb
    >>> from processing.spectral.spectra import light_spectrum
    >>> g = SpectralGrid(400, 700, 10)
    >>> chart = load_reflectances("colorchecker", g).spectra
    >>> e = light_spectrum("D65", g)
    >>> fit = estimate_sensitivities(camera_rgb(chart, e, camera_sensitivities(g), g), chart, e, g)
    >>> fit.sensitivities.shape, bool(fit.condition < 10)
    ((31, 3), True)
    >>> try:
    ...     estimate_sensitivities(camera_rgb(chart[18:], e, camera_sensitivities(g), g), chart[18:], e, g)
    ... except ChartConditionError as exc:
    ...     print(exc.condition > 50, "condition number" in str(exc))
    True True
    """
    r = checked_spectra("chart_reflectance", chart_reflectance, grid)
    rho = np.asarray(checked_channels("chart_rgb", chart_rgb), dtype=np.float64)
    if rho.ndim != 2 or rho.shape[0] != r.shape[0]:
        raise SpectralEstimationError(
            f"chart_rgb must be (patches, channels) with one row per reflectance ({r.shape[0]}), got {rho.shape}"
        )
    a = r * channel_matrix(np.ones((grid.size, 1)), light, grid)[:, 0]     # (n, L): R E step
    cond = condition_number(a, rank=3)
    if not cond <= max_condition:
        raise ChartConditionError(
            f"the chart patches span too few colours to estimate the camera: condition number {cond:.2g} > "
            f"{max_condition:g}; use a chart with at least three distinct chromatic patches, not only greys",
            cond,
        )
    d = _second_difference(grid.size)
    unit = float(np.trace(a.T @ a) / np.trace(d.T @ d))
    lam = _chosen_lambda(a, d, rho, unit, regularisation, noise)
    sens = _solve(a, d, rho, lam, unit)
    chosen = [lam] * rho.shape[1]
    scale = np.maximum(np.abs(rho), 1e-12 * max(float(np.abs(rho).max()), 1e-300))
    residual = float(np.sqrt(np.mean(((a @ sens - rho) / scale) ** 2)))
    return SensitivityFit(sens, cond, tuple(chosen), residual)


def _chosen_lambda(a: NDArray[np.float64], d: NDArray[np.float64], rho: NDArray[np.float64], unit: float,
                   regularisation: float | None, noise: float | None) -> float:
    """The smoothness weight: the one given, else by the discrepancy principle with a noise, else by GCV."""
    if regularisation is not None:
        lam = float(regularisation)
        if not (np.isfinite(lam) and lam >= 0):
            raise SpectralEstimationError(f"regularisation must be >= 0, got {regularisation!r}")
    elif noise is not None:
        if not (np.isfinite(noise) and noise > 0):
            raise SpectralEstimationError(f"noise must be a relative level > 0, got {noise!r}")
        lam = _discrepancy_lambda(a, d, rho, unit, float(noise))
    else:
        lam = _gcv_lambda(a, d, rho, unit)
    return lam
