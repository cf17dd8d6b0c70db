"""The luminances a trichromatic camera's values allow: bounds over the camera's metamer set.

Three camera values do not fix a spectrum.  Every spectrum with the same camera values (a
*metamer* of the camera) is an equally good answer to "what was in front of the lens", and the
metamers' luminances differ.  The smallest and largest luminance over the metamer set bound what
any estimator can claim from the three values alone: an answer outside the bounds is impossible,
and an accuracy target narrower than the bounds can only be met with knowledge of the spectrum
that the camera does not give (a prior that happens to suit the surface).  The bounds are widest
for strongly coloured light and collapse for a camera whose sensitivities span the CIE
colour-matching functions (the Luther condition).

The metamer set here is the set of spectra ``rho = a B`` over a linear basis ``B`` (default: every
spectrum on the grid; or the first principal components of a reflectance set, for smooth
"natural" spectra) with ``0 <= rho <= upper`` (``upper`` None: no upper bound, for light
sources), seen under light ``E``: ``sum_l rho_l E_l S_lc step = c_c``.  The luminance
``sum_l rho_l E_l ybar_l step`` is minimised and maximised by two linear programmes (SciPy's
HiGHS), a few milliseconds per camera value.

References
----------
Finlayson, G. D., Morovic, P. (2005). Metamer sets. Journal of the Optical Society of America A
22(5), 810-819. doi:10.1364/JOSAA.22.000810

Examples
--------
>>> from processing.spectral.spectra import SpectralGrid, cmfs
>>> g = SpectralGrid(400, 700, 10)
>>> flat = np.ones(g.size)
>>> xyz_camera = cmfs(g)                       # a camera that sees X, Y, Z meets the Luther condition
>>> lo, hi = luminance_range(flat @ xyz_camera * g.step, xyz_camera, flat, g)
>>> truth = float(flat @ cmfs(g)[:, 1] * g.step)
>>> round(float(lo) / truth, 6), round(float(hi) / truth, 6)
(1.0, 1.0)
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linprog

from processing.spectral.checks import SpectralEstimationError
from processing.spectral.spectra import SpectralGrid, cmfs

__all__ = ["luminance_range"]


def luminance_range(camera_values: ArrayLike, sensitivities: ArrayLike, light: ArrayLike, grid: SpectralGrid,
                    *, basis: ArrayLike | None = None, upper: float | None = None
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Smallest and largest luminance of the spectra that give ``camera_values``, relative to a reference.

    Parameters
    ----------
    camera_values
        ``(..., 3)`` (or any number of channels) camera values ``sum rho E S step`` of the spectra in
        question.
    sensitivities
        ``(L, c)`` the camera's spectral sensitivities on ``grid``.
    light
        ``(L,)`` the light the spectra are seen under (a flat spectrum for radiance itself).
    grid
        The wavelength grid.
    basis
        ``(p, L)`` spectra the metamers are combinations of (None: the ``L`` unit spectra, every
        spectrum on the grid).
    upper
        Upper bound of the metamers on every wavelength (1 for reflectances; None: no bound).

    Returns
    -------
    tuple of ndarray
        ``(lowest, highest)``, each ``(...)``: the luminance ``sum rho E ybar step`` of the darkest and of
        the brightest metamer, in the units of ``light`` times the basis' units times nm (the units of
        :func:`processing.spectral.display.spectra_to_xyz`).  NaN where the camera values have no
        metamer in the set (values the basis and bounds cannot produce).

    Raises
    ------
    SpectralEstimationError
        Shapes that do not agree, values that are not finite.

    Examples
    --------
    >>> from processing.spectral.spectra import SpectralGrid, cmfs
    >>> g = SpectralGrid(400, 700, 10)
    >>> rgb_camera = cmfs(g)[:, [0, 1, 2]] @ np.diag([1.0, 0.8, 1.2])      # XYZ, rescaled: still Luther
    >>> red = np.where(g.wavelengths > 600, 0.8, 0.05)
    >>> lo, hi = luminance_range(red @ rgb_camera * g.step, rgb_camera, np.ones(g.size), g, upper=1.0)
    >>> bool(np.isclose(lo, hi, rtol=1e-6)), bool(np.isclose(lo, red @ cmfs(g)[:, 1] * g.step, rtol=1e-6))
    (True, True)
    """
    s = np.asarray(sensitivities, dtype=np.float64)
    e = np.asarray(light, dtype=np.float64)
    c = np.asarray(camera_values, dtype=np.float64)
    b = np.eye(grid.size) if basis is None else np.asarray(basis, dtype=np.float64)
    if s.ndim != 2 or s.shape[0] != grid.size:
        raise SpectralEstimationError(f"sensitivities must be ({grid.size}, channels) on the grid, got {s.shape}")
    if e.shape != (grid.size,) or b.ndim != 2 or b.shape[1] != grid.size:
        raise SpectralEstimationError(f"light must be ({grid.size},) and basis (p, {grid.size}); got {e.shape}, "
                                      f"{b.shape}")
    if c.shape[-1:] != (s.shape[1],):
        raise SpectralEstimationError(f"camera values must end in {s.shape[1]} channels, got shape {c.shape}")
    if not (np.isfinite(c).all() and np.isfinite(s).all() and np.isfinite(e).all() and np.isfinite(b).all()):
        raise SpectralEstimationError("camera values, sensitivities, light and basis must be finite")
    seen = b * e * grid.step                                  # (p, L): each basis spectrum as light at the lens
    a_eq = (seen @ s).T                                       # (c, p): camera values of each basis spectrum
    y = seen @ cmfs(grid)[:, 1]                               # (p,): luminance of each basis spectrum
    rows = np.abs(a_eq).max(axis=1, keepdims=True)
    if not np.all(rows > 0):
        raise SpectralEstimationError("a camera channel sees none of the basis spectra under this light")
    a_eq = a_eq / rows                                        # channels of one size, for the solver's tolerances
    flat = c.reshape(-1, c.shape[-1]) / rows[:, 0]
    out = np.full((2, len(flat)), np.nan)
    for i, values in enumerate(flat):
        # solve for a / k with values / k of size 1: the solver's absolute tolerances then hold at any scale
        k = float(np.abs(values).max()) or 1.0
        a_ub, b_ub = _bounds(b, None if upper is None else float(upper) / k)
        for j, sign in enumerate((1.0, -1.0)):
            res = linprog(sign * y, A_ub=a_ub, b_ub=b_ub, A_eq=a_eq, b_eq=values / k, bounds=(None, None),
                          method="highs")
            if res.status == 0:
                out[j, i] = sign * res.fun * k
    return out[0].reshape(c.shape[:-1]), out[1].reshape(c.shape[:-1])

def _bounds(b: NDArray[np.float64], upper: float | None) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``A_ub a <= b_ub`` for ``0 <= a B <= upper`` on every wavelength (``upper`` None: no upper bound)."""
    n = b.shape[1]
    if upper is None:
        return -b.T, np.zeros(n)
    return np.vstack([-b.T, b.T]), np.concatenate([np.zeros(n), np.full(n, float(upper))])
