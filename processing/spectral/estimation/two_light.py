"""Two exposures under two lights: six camera channels for spectral estimation.

A second exposure of the same view under a light of another spectral power
distribution (e.g. D65 and A) gives three more channels,
``rho = s [E_1 S, E_2 S]``, that separate most metamers of one light; the six
channels go through root-polynomial regression (default) or Wiener
estimation.  docs/colour-pipeline.md, "Two lights", says why and what the
shots need.

References
----------
Matsuda, Tanaka, Ichikawa, Mochizuki, Muroya, Kitamura, "CG reproduction of a
craft object based on a light reflection model", IPSJ technical report
(no DOI), section 5 (more channels as the way past p = 3).

Shen, H.-L., Cai, P.-Q., Shao, S.-J., Xin, J. H. (2007). Reflectance
reconstruction for multispectral imaging by adaptive Wiener estimation.
Optics Express 15.
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
        ``(L, 3)`` camera sensitivities (relative units).
    lights
        ``(2, L)`` (relative spectral power): the two lights, in the order
        of the channels (first exposure's R, G, B, then the second's).
    grid
        The wavelength grid.
    estimator
        'rootpoly' (degree 2, ``p`` basis vectors) or 'wiener'.
    p
        Basis size for 'rootpoly'.
    noise
        Relative noise level of each channel (0.01 = 1 %).

    Returns
    -------
    SpectralFit
        Method 'twolight', ``channels == 6``.

    Raises
    ------
    SpectralEstimationError
        Lights not ``(2, L)``, two lights of the same spectrum (up to scale),
        an unknown ``estimator``, or the estimator's own input errors.
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
