"""Spectral estimation by method name, calibrated to the chart; spectral images and region spectra.

:func:`fit_estimator` fits one of :data:`METHODS` (Matsuda et al., section 4.1,
eq. (6)-(10), and the better estimators after it) and, given the chart shot
with the object, composes it with the chart transform M2 (eq. (9),
:mod:`processing.camera.transfer`); :func:`spectral_image` applies it to an
image; :func:`region_spectra` gives each region's mean spectrum with its
uncertainty.  docs/colour-pipeline.md, "Estimators" and "Regions", describes
the methods and the uncertainty.

References
----------
Matsuda, Tanaka, Ichikawa, Mochizuki, Muroya, Kitamura, "CG reproduction of a
craft object based on a light reflection model", IPSJ technical report
(no DOI), section 4.1, eq. (6)-(10).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.camera.response import camera_rgb
from processing.camera.transfer import MAX_CONDITION, fit_chart_transform
from processing.spectral.estimation.fit import (
    SpectralEstimationError,
    SpectralFit,
    checked_channels,
    checked_spectra,
    with_transform,
)
from processing.spectral.estimation.pca_matsuda import fit_paper
from processing.spectral.estimation.root_polynomial_finlayson import fit_more_basis, fit_rootpoly
from processing.spectral.estimation.two_light import fit_two_light
from processing.spectral.estimation.wiener import fit_wiener
from processing.spectral.spectra import SpectralGrid

__all__ = [
    "METHODS",
    "fit_estimator",
    "SpectralImage",
    "spectral_image",
    "reflectance_from_weights",
    "RegionSpectra",
    "region_spectra",
]

_BLOCK = 1 << 20   # pixels per float64 block in region statistics

#: The fit of each method of :func:`fit_estimator`, by name, in the order the command line lists them:
#: 'paper' (PCA p = 3 and the 3 x 3 M), 'wiener' (Wiener / Tikhonov with known sensitivities),
#: 'rootpoly' (root-polynomial regression onto 8 PCA weights), 'more-basis' (linear regression onto
#: 8 PCA weights with ridge) and 'twolight' (two exposures under two lights, six channels).
METHODS: dict[str, Callable[..., SpectralFit]] = {
    "paper": fit_paper,
    "wiener": fit_wiener,
    "rootpoly": fit_rootpoly,
    "more-basis": fit_more_basis,
    "twolight": fit_two_light,
}

#: Basis size of each method when ``p`` is not given (Wiener has one vector per channel, always).
_DEFAULT_P = {"paper": 3, "rootpoly": 8, "more-basis": 8, "twolight": 10}


def fit_estimator(
    method: str,
    database: ArrayLike,
    sensitivities: ArrayLike,
    lights: ArrayLike,
    grid: SpectralGrid,
    *,
    noise: float = 0.01,
    p: int | None = None,
    chart_rgb: ArrayLike | None = None,
    chart_reflectance: ArrayLike | None = None,
    max_condition: float = MAX_CONDITION,
) -> SpectralFit:
    """Fit a spectral estimator for the model camera, optionally calibrated to an object camera's chart.

    Parameters
    ----------
    method
        One of :data:`METHODS`.
    database
        Training reflectances ``(n, L)`` on ``grid``.
    sensitivities
        ``(L, 3)`` model-camera sensitivities (known, or from
        :func:`processing.camera.from_chart.estimate_sensitivities`).
    lights
        ``(L,)`` light of the shot (relative spectral power); ``(2, L)`` for 'twolight'.
    grid
        The wavelength grid.
    noise
        Relative noise level of the camera values (0.01 = 1 %); not used by 'paper'.
    p
        Basis size (defaults: paper 3, rootpoly and more-basis 8, twolight 10;
        Wiener always uses as many as there are channels).
    chart_rgb
        ``(n, c)`` object-camera values of the chart patches shot with the object.
    chart_reflectance
        ``(n, L)`` the patches' reflectances (required with ``chart_rgb``).
    max_condition
        Largest accepted condition number of the chart transform.

    Returns
    -------
    SpectralFit
        With ``condition['chart']`` and ``details['chart_residual']`` when calibrated.

    Raises
    ------
    SpectralEstimationError
        Unknown method; lights of the wrong shape for the method; ``p`` with
        'wiener'; only one of ``chart_rgb`` and ``chart_reflectance``; chart
        values that do not match the reflectances; the method's own input
        errors; a singular system (degenerate training reflectances).
    ChartConditionError
        The chart patches do not fix the transform (a
        :class:`SpectralEstimationError`).
    CameraResponseError
        Bad sensitivities, lights or chart reflectances.

    References
    ----------
    Matsuda et al., IPSJ technical report (no DOI), section 4.1, eq. (6)-(10).

    Examples
    --------
    >>> from processing.spectral.reflectance_database import load_reflectances
    >>> from processing.camera.response import camera_sensitivities
    >>> from processing.spectral.spectra import light_spectrum
    >>> g = SpectralGrid(400, 700, 10)
    >>> db = load_reflectances("training", g).spectra
    >>> fit = fit_estimator("wiener", db, camera_sensitivities(g), light_spectrum("D65", g), g)
    >>> fit.method, fit.p
    ('wiener', 3)
    """
    if method not in METHODS:
        raise SpectralEstimationError(f"unknown spectral estimation method {method!r}; choose one of {', '.join(METHODS)}")
    e = _checked_lights(method, lights)
    if chart_rgb is None and chart_reflectance is not None:
        raise SpectralEstimationError("chart_reflectance was given without chart_rgb")
    if chart_rgb is not None and chart_reflectance is None:
        raise SpectralEstimationError("chart_rgb needs chart_reflectance: the patches' reflectances on the grid")
    try:
        fit = METHODS[method](database, sensitivities, e, grid, **_options(method, noise, p))
        if chart_rgb is None:
            return fit
        return _calibrated(fit, e, sensitivities, grid, chart_rgb, chart_reflectance, max_condition)
    except np.linalg.LinAlgError:
        n = np.shape(database)[0] if np.ndim(database) == 2 else "the"
        raise SpectralEstimationError(
            f"the {method} estimator's system is singular: the {n} training reflectances as the camera sees them "
            "under the light are degenerate (all zero, all alike or too few); use a training set of distinct, "
            "non-zero reflectances (--database training)"
        ) from None


def _checked_lights(method: str, lights: ArrayLike) -> NDArray[np.float64]:
    """The lights as float64: two ``(2, L)`` for 'twolight', one ``(L,)`` for every other method."""
    e = np.asarray(lights, dtype=np.float64)
    if method == "twolight":
        if e.ndim != 2 or e.shape[0] != 2:
            raise SpectralEstimationError(f"'twolight' needs two lights (2, L), got shape {e.shape}")
    elif e.ndim != 1:
        raise SpectralEstimationError(f"method {method!r} takes one light (L,), got shape {e.shape}; use 'twolight' for two")
    return e


def _options(method: str, noise: float, p: int | None) -> dict[str, float | int]:
    """The keyword arguments of the method's fit for :func:`fit_estimator`'s ``noise`` and ``p``."""
    if method == "wiener":
        if p is not None:
            raise SpectralEstimationError("the Wiener estimate has as many basis vectors as channels; do not give p")
        return {"noise": noise}
    options: dict[str, float | int] = {"p": p or _DEFAULT_P[method]}
    if method != "paper":          # the paper's least-squares M has no noise model
        options["noise"] = noise
    return options


def _calibrated(
    fit: SpectralFit,
    lights: NDArray[np.float64],
    sensitivities: ArrayLike,
    grid: SpectralGrid,
    chart_rgb: ArrayLike,
    chart_reflectance: ArrayLike,
    max_condition: float,
) -> SpectralFit:
    """``fit`` after the chart transform from the object camera's patch values to the model camera's."""
    refl = checked_spectra("chart_reflectance", chart_reflectance, grid)
    model = camera_rgb(refl, lights, sensitivities, grid)
    obj = checked_channels("chart_rgb", chart_rgb, fit.channels)
    if obj.ndim != 2 or obj.shape[0] != refl.shape[0]:
        raise SpectralEstimationError(
            f"chart_rgb must be (patches, {fit.channels}) with one row per chart reflectance ({refl.shape[0]}), got {obj.shape}"
        )
    transform = fit_chart_transform(obj, model, max_condition=max_condition)
    calibrated = with_transform(fit, transform.matrix)
    return replace(
        calibrated,
        condition={**fit.condition, "chart": transform.condition},
        details={**fit.details, "chart_residual": transform.residual},
    )


@dataclass(frozen=True)
class SpectralImage:
    """An image as basis weights, never ``(H, W, L)`` spectra.

    Parameters
    ----------
    weights, basis, grid, mask, method
        The attributes below.

    Attributes
    ----------
    weights
        ``(H, W, p)`` float32 basis weights; 0 where ``mask`` is False.
    basis
        ``(L, p)`` basis spectra (reflectance per unit weight).
    grid
        Wavelength grid of the basis.
    mask
        ``(H, W)`` True where the pixel was estimated (False: saturated, dead or
        otherwise excluded by the caller).
    method
        The estimator's name.
    """

    weights: NDArray[np.float32]
    basis: NDArray[np.float64]
    grid: SpectralGrid
    mask: NDArray[np.bool_]
    method: str


def spectral_image(fit: SpectralFit, rgb: ArrayLike, mask: ArrayLike | None = None) -> SpectralImage:
    """Basis weights of a linear camera image ``(H, W, c)``; pixels outside ``mask`` are skipped.

    Masked pixels may hold anything (NaN from a decoder, clipped values);
    they get zero weights.  Unmasked pixels must be finite and >= 0.

    Parameters
    ----------
    fit
        The (calibrated) estimator.
    rgb
        ``(H, W, c)`` linear camera values of the object camera.
    mask
        ``(H, W)`` boolean, True where a pixel is estimated; None: every pixel.

    Returns
    -------
    SpectralImage
        Weights ``(H, W, p)`` float32, the basis, grid, mask and method.

    Raises
    ------
    SpectralEstimationError
        ``rgb`` not ``(H, W, c)``, a mask of another shape or not boolean, a
        mask excluding every pixel, or bad unmasked values.

    Examples
    --------
    >>> from processing.spectral.estimation.fit import SpectralFit
    >>> fit = SpectralFit("demo", np.eye(3), np.eye(3), SpectralGrid(400, 700, 150), 3)
    >>> img = np.ones((1, 2, 3)); img[0, 1] = np.nan
    >>> out = spectral_image(fit, img, mask=[[True, False]])
    >>> out.weights.tolist(), out.mask.tolist()
    ([[[1.0, 1.0, 1.0], [0.0, 0.0, 0.0]]], [[True, False]])
    """
    a = np.asarray(rgb)
    if a.ndim != 3 or a.shape[2] != fit.channels:
        raise SpectralEstimationError(f"rgb must be an (H, W, {fit.channels}) image, got shape {a.shape}")
    if mask is None:
        m = np.ones(a.shape[:2], dtype=bool)
    else:
        m = np.asarray(mask)
        if m.shape != a.shape[:2] or m.dtype != bool:
            raise SpectralEstimationError(f"mask must be a boolean (H, W) = {a.shape[:2]} image, got {m.shape} {m.dtype}")
    if not m.any():
        raise SpectralEstimationError("the mask excludes every pixel; nothing to estimate")
    if not m.all():
        a = np.where(m[..., None], a, 0).astype(np.float32, copy=False)
    weights = fit.estimate_weights(a)
    weights[~m] = 0.0
    return SpectralImage(weights, fit.basis, fit.grid, m, fit.method)


def reflectance_from_weights(weights: ArrayLike, basis: ArrayLike) -> NDArray[np.float64]:
    """Spectra ``(..., L)`` from basis weights ``(..., p)`` and the basis ``(L, p)``: ``s = B w`` (eq. (7)).

    Meant for regions, patches and single pixels; images stay as weights.

    Parameters
    ----------
    weights
        ``(..., p)`` basis weights.
    basis
        ``(L, p)`` basis spectra.

    Returns
    -------
    ndarray
        ``(..., L)`` float64 reflectance.

    Raises
    ------
    SpectralEstimationError
        A basis that is not a finite ``(L, p)`` array, weights of another
        ``p``, empty, NaN or infinite weights.

    References
    ----------
    Matsuda et al., IPSJ technical report (no DOI), section 4.1, eq. (7).

    Examples
    --------
    >>> reflectance_from_weights([[1.0, 2.0]], [[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]]).tolist()
    [[1.0, 2.0, 3.0]]
    """
    b = np.asarray(basis, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    if b.ndim != 2 or b.size == 0 or not np.isfinite(b).all():
        raise SpectralEstimationError(f"basis must be a finite (L, p) array, got shape {b.shape}")
    if w.ndim == 0 or w.size == 0 or w.shape[-1] != b.shape[1]:
        raise SpectralEstimationError(f"weights must be (..., {b.shape[1]}) for a basis of {b.shape[1]} vectors, got {w.shape}")
    if not np.isfinite(w).all():
        raise SpectralEstimationError("weights contain NaN or infinite values")
    return w @ b.T


@dataclass(frozen=True)
class RegionSpectra:
    """Mean reflectance per region with its spread and uncertainty.

    Parameters
    ----------
    labels, count, mean, std, uncertainty, mean_weights
        The attributes below.

    Attributes
    ----------
    labels
        ``(k,)`` region labels (> 0) present in the label image.
    count
        ``(k,)`` pixels per region.
    mean
        ``(k, L)`` mean reflectance.
    std
        ``(k, L)`` standard deviation of the pixels' reflectance.
    uncertainty
        ``(k, L)`` ``sqrt(std^2 + method_error^2)``.
    mean_weights
        ``(k, p)`` mean basis weights.
    """

    labels: NDArray[np.int64]
    count: NDArray[np.int64]
    mean: NDArray[np.float64]
    std: NDArray[np.float64]
    uncertainty: NDArray[np.float64]
    mean_weights: NDArray[np.float64]


def region_spectra(
    weights: ArrayLike, labels: ArrayLike, basis: ArrayLike, method_error: float
) -> RegionSpectra:
    """Mean spectrum, pixel spread and uncertainty of each labelled region.

    The spread is the standard deviation of the pixels' reflectance per
    wavelength, ``sqrt(diag(B C B^T))`` with ``C`` the covariance of the
    region's weights; the uncertainty adds the method's held-out error in
    quadrature (the first says how uniform the region is, the second how far
    any single estimate may be from the truth).

    Parameters
    ----------
    weights
        ``(H, W, p)`` basis weights (:meth:`SpectralFit.estimate_weights`).
    labels
        ``(H, W)`` integer region labels; 0 is background (the mask).
    basis
        ``(L, p)`` basis of the weights.
    method_error
        RMS reflectance error of the method on held-out spectra (>= 0).

    Returns
    -------
    RegionSpectra
        One row per label > 0 present, in increasing label order.

    Raises
    ------
    SpectralEstimationError
        Weights not float ``(H, W, p)`` for the basis, labels not an integer
        image of the same size, negative labels, no region, NaN or infinite
        weights, a negative or non-finite ``method_error``.

    Examples
    --------
    >>> w = np.zeros((2, 2, 1)); w[0] = 1.0; w[1] = 3.0
    >>> r = region_spectra(w, np.ones((2, 2), int), np.ones((2, 1)), 0.0)
    >>> r.mean.tolist(), r.std.tolist()
    ([[2.0, 2.0]], [[1.0, 1.0]])
    """
    b = np.asarray(basis, dtype=np.float64)
    w = np.asarray(weights)                      # float32 images stay float32; sums are float64
    lab = np.asarray(labels)
    _check_region_inputs(w, lab, b, method_error)
    lab = lab.ravel()
    if lab.dtype.kind == "i" and np.any(lab < 0):
        raise SpectralEstimationError("labels must be >= 0 (0 = background)")
    pos = np.flatnonzero(lab > 0)
    if pos.size == 0:
        raise SpectralEstimationError("the label image has no region (every label is 0)")
    present, idx = _region_index(lab[pos].astype(np.int64))
    count = np.bincount(idx, minlength=present.size)
    mean_w, cov = _region_moments(w.reshape(-1, w.shape[2]), pos, idx, count)
    var = np.einsum("lp,kpq,lq->kl", b, cov, b)
    std = np.sqrt(np.maximum(var, 0.0))
    return RegionSpectra(
        labels=present,
        count=count.astype(np.int64),
        mean=mean_w @ b.T,
        std=std,
        uncertainty=np.sqrt(std**2 + float(method_error) ** 2),
        mean_weights=mean_w,
    )


def _check_region_inputs(w: NDArray, lab: NDArray, b: NDArray[np.float64], method_error: float) -> None:
    """Refuse weights, labels and a method error :func:`region_spectra` cannot use."""
    if w.ndim != 3 or b.ndim != 2 or w.shape[2] != b.shape[1] or w.dtype.kind != "f":
        raise SpectralEstimationError(
            f"weights must be float (H, W, p) with p = {b.shape[1] if b.ndim == 2 else '?'} basis vectors, "
            f"got {w.shape} {w.dtype}"
        )
    if lab.shape != w.shape[:2] or lab.dtype.kind not in "iub":
        raise SpectralEstimationError(f"labels must be an integer (H, W) = {w.shape[:2]} image, got {lab.shape} {lab.dtype}")
    if not np.isfinite(w).all():
        raise SpectralEstimationError("weights contain NaN or infinite values")
    if not (isinstance(method_error, (int, float, np.floating)) and math.isfinite(method_error) and method_error >= 0):
        raise SpectralEstimationError(f"method_error must be an RMS reflectance >= 0, got {method_error!r}")


def _region_index(lab_in: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The labels present, increasing, and each pixel's index among them."""
    top = int(lab_in.max())
    if top < (1 << 24):                       # small labels: a lookup table instead of a sort
        present = np.flatnonzero(np.bincount(lab_in, minlength=top + 1))
        lut = np.zeros(top + 1, dtype=np.int64)
        lut[present] = np.arange(present.size)
        idx = lut[lab_in]
    else:
        present, idx = np.unique(lab_in, return_inverse=True)
    return present, idx


def _region_moments(
    wflat: NDArray, pos: NDArray[np.int64], idx: NDArray[np.int64], count: NDArray[np.int64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Mean ``(k, p)`` and covariance ``(k, p, p)`` of the weights of each region, in float64."""
    k, p = count.size, wflat.shape[1]
    # pixels grouped by region (radix sort for fewer than 65536 regions), then per region the sum and
    # the sum of outer products about the region's first pixel, in float64 blocks (no (n, p) float64 copy)
    order = np.argsort(idx.astype(np.uint16) if k < (1 << 16) else idx, kind="stable")
    rows = pos[order]
    bounds = np.concatenate([[0], np.cumsum(count)])
    mean_w = np.zeros((k, p))
    cov = np.zeros((k, p, p))
    for r in range(k):
        ref = wflat[rows[bounds[r]]].astype(np.float64)
        s1, s2 = np.zeros(p), np.zeros((p, p))
        for lo in range(bounds[r], bounds[r + 1], _BLOCK):
            x = wflat[rows[lo:min(lo + _BLOCK, bounds[r + 1])]].astype(np.float64) - ref
            s1 += x.sum(axis=0)
            s2 += x.T @ x
        m = s1 / count[r]
        mean_w[r] = m + ref
        cov[r] = s2 / count[r] - np.outer(m, m)
    return mean_w, cov
