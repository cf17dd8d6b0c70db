"""Two exposures under two lights: six camera channels for spectral estimation.

A trichromatic camera confuses metamers: reflectances that differ but give
the same three values under one light.  A second exposure of the same view
under a light of another spectral power distribution (e.g. daylight D65 and
incandescent A) gives three more channels, ``rho = s [E_1 S, E_2 S]``, that
separate most such pairs (Shen, Cai, Shao & Xin, "Reflectance reconstruction
for multispectral imaging by adaptive Wiener estimation", Optics Express 15,
2007, use the same idea with filters; Matsuda et al. section 5 name more
channels as the way past p = 3).

The six channels go through the same estimators as one exposure: root-
polynomial regression onto a ten-vector PCA basis (default; see
:mod:`processing.spectral.estimation.root_polynomial_finlayson`) or Wiener (:mod:`processing.spectral.estimation.wiener`).
The two exposures must be registered pixel to pixel (a fixed camera on a
tripod) and each exposure's chart transform is fitted separately.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from processing.spectral.estimation.fit import SpectralEstimationError, SpectralFit
from processing.spectral.estimation.root_polynomial_finlayson import fit_rootpoly
from processing.spectral.estimation.wiener import fit_wiener
from processing.spectral.spectra import SpectralGrid

__all__ = ["fit_two_light"]


def fit_two_light(
    database: ArrayLike,
    sensitivities: ArrayLike,
    lights: ArrayLike,
    grid: SpectralGrid,
    *,
    estimator: str = "rootpoly",
    p: int = 10,
    noise: float = 0.01,
) -> SpectralFit:
    """Fit an estimator of reflectance from two exposures (six channels).

    Parameters
    ----------
    database
        Training reflectances ``(n, L)``.
    sensitivities
        ``(L, 3)`` camera sensitivities.
    lights
        ``(2, L)``: the two lights, in the order of the channels (first
        exposure's R, G, B, then the second's).
    grid
        The wavelength grid.
    estimator
        'rootpoly' (degree 2, ``p`` basis vectors) or 'wiener'.
    p
        Basis size for 'rootpoly'.
    noise
        Relative noise level of each channel.

    Examples
    --------
    >>> from processing.spectral.reflectance_database import load_reflectances
    >>> from processing.camera.response import camera_sensitivities
    >>> from processing.spectral.spectra import light_spectrum
    >>> g = SpectralGrid(400, 700, 10)
    >>> lights = np.stack([light_spectrum("D65", g), light_spectrum("A", g)])
    >>> fit = fit_two_light(load_reflectances("training", g).spectra, camera_sensitivities(g), lights, g)
    >>> fit.channels, fit.p, fit.method
    (6, 10, 'twolight')
    """
    e = np.asarray(lights, dtype=np.float64)
    if e.ndim != 2 or e.shape[0] != 2:
        raise SpectralEstimationError(f"two-light estimation needs lights of shape (2, L), got {e.shape}")
    if np.allclose(e[0] / max(float(e[0].max()), 1e-300), e[1] / max(float(e[1].max()), 1e-300)):
        raise SpectralEstimationError("the two lights have the same spectrum; the second exposure adds nothing")
    if estimator == "rootpoly":
        return fit_rootpoly(database, sensitivities, e, grid, p=p, degree=2, noise=noise, method="twolight")
    if estimator == "wiener":
        return fit_wiener(database, sensitivities, e, grid, noise=noise, method="twolight")
    raise SpectralEstimationError(f"unknown two-light estimator {estimator!r}; use 'rootpoly' or 'wiener'")
