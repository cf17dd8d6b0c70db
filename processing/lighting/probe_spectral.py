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
``.exr`` stores exactly that basis.

Three camera values leave most of a saturated wall's spectrum to the estimator's prior.  A second
bracket set shot through a colour filter of known transmission ``T`` is, for the estimator, a second
light ``E T``: six channels, read by the root-polynomial estimator of two lights
(:func:`processing.spectral.estimation.two_light.fit_two_light`, calibrated by the chart shot through
the filter too).  That estimator is not linear in the camera values, so
:func:`two_set_environment` estimates each direction's spectrum and then finds a few non-negative
spectra the map's pixels mix (:func:`processing.lighting.nmf_lee2001.nonnegative_basis`): the map
keeps :data:`COMPONENTS` coefficients per pixel, and says how far that mix is from the estimated
spectra.

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

__all__ = ["ProbeSpectralError", "radiance_basis", "probe_environment", "two_set_environment", "COMPONENTS"]

#: Basis spectra of a map made from two bracket sets (:func:`two_set_environment`).
COMPONENTS = 6


class ProbeSpectralError(InputError):
    """The probe cannot be made spectral; the one-line message says why and what to use."""


def _chart_white(chart_light: NDArray[np.float64], grid) -> NDArray[np.float64]:
    """The map's white: a white diffuser where the chart lay, ``E / pi`` scaled to luminance 1 (the map's unit)."""
    white = np.asarray(chart_light, dtype=np.float64) / math.pi
    y = float(spectra_to_xyz(white, grid)[1])
    if not y > 0:
        raise ProbeSpectralError("the chart's light has no luminance; give its spectrum (e.g. D65, A or a CCT)")
    return white / y


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
    white = _chart_white(e, fit.grid)
    m = np.asarray(fit.matrix, dtype=np.float64)
    if fit.transform is not None:
        m = np.asarray(fit.transform, dtype=np.float64) @ m
    reflectance = m @ np.asarray(fit.basis, dtype=np.float64).T          # (3, L) per unit camera value
    return reflectance * white[None, :]


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
        Coefficients: the camera RGB (clipped at 0); basis: :func:`radiance_basis`; white: the
        chart's white (a white diffuser under ``chart_light``, luminance 1).

    Raises
    ------
    ProbeSpectralError
        As :func:`radiance_basis`.
    """
    basis = radiance_basis(fit, chart_light)
    c = np.maximum(np.asarray(rgb, dtype=np.float32), 0.0)
    return EnvironmentMap(c, basis, fit.grid, source=source,
                          white=_chart_white(np.asarray(chart_light, dtype=np.float64), fit.grid))


def two_set_environment(rgb6: ArrayLike, fit, chart_light: ArrayLike, *, components: int = COMPONENTS,
                        weights: ArrayLike | None = None, source: str = "probe") -> tuple[EnvironmentMap, dict]:
    """The map of two bracket sets' six camera values as a spectral :class:`EnvironmentMap`.

    Parameters
    ----------
    rgb6
        ``(H, 2H, 6)``: the unfiltered set's camera RGB, then the filtered set's, per direction (the
        units the estimator's chart values were given in).
    fit
        The two-light estimator calibrated by the chart shot through no filter and through the filter.
    chart_light
        ``(L,)`` the unfiltered light's spectrum on the fit's grid (the map's radiance is in units of a
        white diffuser under it).
    components
        Basis spectra the map keeps (1-6; the renderer's cost grows with them).
    weights
        ``(H, 2H)`` how much each pixel counts when the basis is found (default: its solid angle).
    source
        Name of the map for messages.

    Returns
    -------
    tuple
        The map, and what its basis loses against the estimated spectra: ``components``, the 99th
        percentile over pixels of the xy distance (``projection_dxy_p99``) and the median relative
        spectral error (``projection_spectral_median``).

    Raises
    ------
    ProbeSpectralError
        Not six channels, a light without luminance, a map without light.
    """
    from processing.lighting.nmf_lee2001 import NonnegativeBasisError, nonnegative_basis, nonnegative_coefficients

    x = np.asarray(rgb6, dtype=np.float32)
    if x.ndim != 3 or x.shape[2] != 6 or fit.channels != 6:
        raise ProbeSpectralError(f"two bracket sets give six camera values per direction and a six-channel "
                                 f"estimator; got shape {x.shape} and {fit.channels} channels")
    white = _chart_white(chart_light, fit.grid)
    h, w = x.shape[:2]
    flat = np.maximum(x.reshape(-1, 6), 0.0)
    radiance = np.maximum(fit.estimate_weights(flat).astype(np.float64) @ np.asarray(fit.basis, np.float64).T, 0.0)
    radiance *= white[None, :]
    if weights is None:
        edges = np.pi * np.arange(h + 1) / h
        weights = np.broadcast_to((np.cos(edges[:-1]) - np.cos(edges[1:]))[:, None], (h, w))
    try:
        basis = nonnegative_basis(radiance, int(components), fit.grid, weights=np.asarray(weights).ravel())
        coeff = nonnegative_coefficients(radiance, basis, fit.grid)
    except NonnegativeBasisError as exc:
        raise ProbeSpectralError(f"{source}: {exc}") from None
    kept = coeff.astype(np.float64) @ basis
    xyz_e, xyz_k = spectra_to_xyz(radiance, fit.grid), spectra_to_xyz(kept, fit.grid)
    lit = xyz_e.sum(axis=1) > 1e-12 * max(float(xyz_e.sum(axis=1).max()), 1e-300)
    dxy = np.linalg.norm(xyz_e[lit, :2] / xyz_e[lit].sum(axis=1, keepdims=True)
                         - xyz_k[lit, :2] / np.maximum(xyz_k[lit].sum(axis=1, keepdims=True), 1e-300), axis=1)
    rel = np.abs(kept[lit] - radiance[lit]).sum(axis=1) / radiance[lit].sum(axis=1)
    figures = {"components": int(len(basis)), "projection_dxy_p99": float(np.quantile(dxy, 0.99)) if lit.any() else 0.0,
               "projection_spectral_median": float(np.median(rel)) if lit.any() else 0.0}
    env = EnvironmentMap(coeff.reshape(h, w, len(basis)), basis, fit.grid, source=source,
                         white=white)
    return env, figures