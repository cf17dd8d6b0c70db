"""Camera spectral sensitivities estimated from a colour chart of known reflectances under a known light.

When the object camera's sensitivities are not published, they can be
estimated from the chart shot: patch j gives ``rho_jc = sum_l R_jl E_l s_cl
step``, a linear system ``A s_c = rho_c`` with ``A = R diag(E) step`` of 24
equations for L unknowns per channel.  It is under-determined and the
reflectances of a chart span few dimensions, so the solution is regularised
(Finlayson, Hordley & Hubel, "Recovering device sensitivities with quadratic
programming", IS&T/SID CIC 1998; Jiang, Liu, Gu & Susstrunk, "What is the
space of spectral sensitivity functions for digital color cameras?", WACV
2013):

``min ||A s_c - rho_c||^2 + lambda ||D2 s_c||^2  subject to  s_c >= 0``

with D2 the second difference (smoothness).  The weight lambda (relative to
``trace(A^T A) / trace(D2^T D2)``) is chosen by generalised
cross-validation of the unconstrained problem over 1e-8 .. 1, one weight for
the three channels (Golub, Heath & Wahba, Technometrics 21, 1979), or, when
the noise of the patch values is known, by Morozov's discrepancy principle
(the largest weight whose relative residual stays within the noise); the
non-negative problem is then solved with that weight
(``scipy.optimize.nnls`` on the stacked system).

Conditioning.  The number of colours the chart really holds is measured by
``sigma_1 / sigma_3`` of ``A``: a trichromatic camera needs at least three
independent spectra.  The 24-patch ColorChecker under D65 gives about 5, its
six grey patches about 330: above ``max_condition`` (default 50) a
:class:`~processing.camera.transfer.ChartConditionError` with the number is
raised.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import nnls

from processing.camera.response import channel_matrix
from processing.camera.transfer import ChartConditionError, condition_number
from processing.spectral.estimation.fit import SpectralEstimationError, checked_channels, checked_spectra
from processing.spectral.spectra import SpectralGrid

__all__ = ["SensitivityFit", "estimate_sensitivities"]

#: Largest accepted sigma_1 / sigma_3 of the chart's light-weighted reflectances.
MAX_CONDITION = 50.0
_LAMBDAS = np.logspace(-8, 0, 33)


@dataclass(frozen=True)
class SensitivityFit:
    """Estimated camera sensitivities.

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
    d = np.zeros((n - 2, n))
    i = np.arange(n - 2)
    d[i, i], d[i, i + 1], d[i, i + 2] = 1.0, -2.0, 1.0
    return d


def _solve(a: NDArray[np.float64], d: NDArray[np.float64], rho: NDArray[np.float64], lam: float, unit: float) -> NDArray[np.float64]:
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
        Largest accepted sigma_1 / sigma_3 of the chart system.

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
    sens = _solve(a, d, rho, lam, unit)
    chosen = [lam] * rho.shape[1]
    scale = np.maximum(np.abs(rho), 1e-12 * max(float(np.abs(rho).max()), 1e-300))
    residual = float(np.sqrt(np.mean(((a @ sens - rho) / scale) ** 2)))
    return SensitivityFit(sens, cond, tuple(chosen), residual)
