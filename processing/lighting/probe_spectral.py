"""A probe's camera RGB turned into spectral radiance by the chart calibration of the same light.

A colour chart lying in the light the probe measures is a set of surfaces of known reflectance
``rho_j`` under that light ``E``: its patches calibrate a spectral estimator (the project's own,
:func:`processing.spectral.estimation.estimator.fit_estimator`, Matsuda et al. eq. (6)-(10) and the
better methods after it) from the camera's values to reflectance.  The radiance arriving from a
direction of the room is, seen by the camera, indistinguishable from a surface of "reflectance"
``L(lambda) pi / E(lambda)`` under ``E``, so the same estimator gives the room's spectral radiance
as ``rho_est(lambda) E(lambda) / pi``, in units of the chart's white (a perfect white diffuser
where the chart lies has luminance 1).

For an estimator linear in camera RGB (``paper``, ``wiener``, ``more-basis``: weights ``w = rgb
M``, spectrum ``w B^T``) the spectrum of a pixel is ``rgb @ (M B^T)``, so the environment map keeps
the camera RGB as its three non-negative coefficients and the estimator's spectra of unit camera
R, G, B (times ``E / pi``) as its basis: the map is spectral as measured, at RGB cost, and its
``.exr`` stores exactly that basis.  A root-polynomial estimator is not linear and is refused.

The chart's values are brought to the HDR image's scale by their own exposure
(:func:`processing.lighting.hdr_merge.exposure_scale`), so the chart frame may be shot at any
exposure.

References
----------
Matsuda et al., CG reproduction of a craft object based on a light reflection model, IPSJ technical
report, section 4.1 (no DOI).

Examples
--------
>>> from processing.spectral.estimation.fit import SpectralFit
>>> from processing.spectral.spectra import SpectralGrid
>>> g = SpectralGrid(400, 700, 150)
>>> fit = SpectralFit("demo", np.eye(3), np.eye(3), g, 3)
>>> radiance_basis(fit, np.ones(3)).shape
(3, 3)
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.errors import InputError
from processing.lighting.environment_map import EnvironmentMap
from processing.spectral.display import spectra_to_xyz

__all__ = ["ProbeSpectralError", "radiance_basis", "probe_environment"]


class ProbeSpectralError(InputError):
    """The probe cannot be made spectral; the one-line message says why and what to use."""


def radiance_basis(fit, chart_light: ArrayLike) -> NDArray[np.float64]:
    """Spectral radiance ``(3, L)`` of a unit camera R, G, B in units of the chart's white.

    Parameters
    ----------
    fit
        A calibrated estimator (:class:`processing.spectral.estimation.fit.SpectralFit`) with linear
        features on 3 channels.
    chart_light
        ``(L,)`` the chart's light on the fit's grid (relative spectral power).

    Returns
    -------
    ndarray
        ``(3, L)``: row c is the estimated reflectance of camera value ``e_c`` times ``E / pi``,
        scaled so a white diffuser under ``E`` has luminance 1.

    Raises
    ------
    ProbeSpectralError
        A non-linear estimator, not 3 channels, a light without luminance.
    """
    if fit.channels != 3 or fit.expansion != "linear":
        raise ProbeSpectralError(f"the {fit.method} estimator is not linear in camera RGB (features "
                                 f"{fit.expansion}, {fit.channels} channels); use --method wiener or paper for a probe")
    e = np.asarray(chart_light, dtype=np.float64)
    if e.shape != (fit.grid.size,) or not np.isfinite(e).all() or (e < 0).any():
        raise ProbeSpectralError(f"the chart's light must be {fit.grid.size} finite non-negative values on the "
                                 f"estimator's grid, got shape {e.shape}")
    white = e / math.pi
    y = float(spectra_to_xyz(white, fit.grid)[1])
    if not y > 0:
        raise ProbeSpectralError("the chart's light has no luminance; give its spectrum (e.g. D65, A or a CCT)")
    m = np.asarray(fit.matrix, dtype=np.float64)
    if fit.transform is not None:
        m = np.asarray(fit.transform, dtype=np.float64) @ m
    reflectance = m @ np.asarray(fit.basis, dtype=np.float64).T          # (3, L) per unit camera value
    return reflectance * (white / y)[None, :]


def probe_environment(rgb: ArrayLike, fit, chart_light: ArrayLike, *, source: str = "probe") -> EnvironmentMap:
    """The probe's map of camera RGB as a spectral :class:`EnvironmentMap` in units of the chart's white.

    Parameters
    ----------
    rgb
        ``(H, 2H, 3)`` camera RGB of the light from each direction (the units the estimator's
        chart values were given in).
    fit
        The estimator calibrated by the chart shot in the same light (linear features).
    chart_light
        ``(L,)`` that light's spectrum on the fit's grid.
    source
        Name of the map for messages.

    Returns
    -------
    EnvironmentMap
        Coefficients: the camera RGB (clipped at 0); basis: :func:`radiance_basis`.

    Raises
    ------
    ProbeSpectralError
        As :func:`radiance_basis`.
    """
    basis = radiance_basis(fit, chart_light)
    c = np.maximum(np.asarray(rgb, dtype=np.float32), 0.0)
    return EnvironmentMap(c, basis, fit.grid, source=source)
