"""Material identification by forward-modelling candidate materials into the camera, and alloy weights.

Matsuda et al., section 4.2, eq. (11): a region's material is the known
material whose colour signal is nearest to the measured one, and alloy
compositions follow eq. (3)-(4), ``C_alloy = sum_j w_j C_j``.  Here the
comparison is made in camera space with a free brightness per candidate and
a relative Gaussian noise model plus a relative model error
(:data:`DEFAULT_MODEL_ERROR` unless told otherwise).  The answer and its
confidence come from :func:`processing.materials.confidence.decide`: a
posterior tempered by the best candidate's misfit, "no candidate fits" when
even the best misses the region by more than the noise allows, and "neutral
metal" for neutral metals one view cannot tell apart.  docs/materials.md, section
"Identifying a material", states the geometry, the noise model and the
calibration the camera values need.

References
----------
.. [1] Matsuda, Tanaka, Ichikawa, Mochizuki, Muroya, Kitamura, "CG
   reproduction of a craft object based on a light reflection model", IPSJ
   technical report (no DOI), section 4.2, eq. (3)-(4) and (11).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import nnls
from scipy.special import erfc

from processing.camera.response import channel_matrix
from processing.materials.confidence import NEUTRAL_METAL, NO_FIT, SINGLE_IMAGE_ERROR_DOF, decide
from processing.materials.lobes import material_brdf
from processing.materials.metal_model import ConductorFresnel
from processing.materials.presets import get_material
from processing.spectral.estimation.fit import SpectralEstimationError, checked_channels
from processing.spectral.spectra import SpectralGrid

__all__ = [
    "DEFAULT_CANDIDATES",
    "DEFAULT_MODEL_ERROR",
    "FRINGE_SLACK",
    "FringeOnlyError",
    "MAX_COLOUR_ERROR",
    "NEUTRAL_METAL",
    "NO_FIT",
    "CandidateSet",
    "Identification",
    "AlloyEstimate",
    "candidate_set",
    "identify_material",
    "identify_regions",
    "estimate_alloy_weights",
]

#: Candidates of the paper's object and the neutral metals that can be confused with silver.
DEFAULT_CANDIDATES: tuple[str, ...] = (
    "silver", "copper", "gold",
    "nami-shibuichi", "shiro-shibuichi", "jo-shibuichi", "nami-shibuichi-uchi-sanbu", "nami-shibuichi-soto-sanbu",
    "shakudo", "bronze", "urushi-black", "urushi-red",
    "aluminium", "platinum", "tin", "zinc", "lead", "iron",
)
#: Relative error of the candidates' forward model (0.0175 = 1.75 % of each channel of a region's mean), added
#: in quadrature to the noise of the mean: one geometry and a model camera stand for a region seen over a range
#: of angles through a real camera after the chart transform.  ``kogei identify``, the batch's materials step,
#: the colour demo and the spectra panel all use it.  Chosen by measurement (``bench/reliability.py``, 3 x 4000
#: simulated regions): expected calibration error 0.031-0.036 and 96.5-97.1 % right among answers stated at
#: >= 0.9, against 0.050-0.054 and 97.7-98.3 % at 0.02 (under-confident) and 0.037-0.043 and 95.4-95.6 % at
#: 0.015 (measured with the Gaussian likelihood; with the Student-t one of :func:`identify_material`: 0.035 and
#: 98.5 % over 4000 regions).
DEFAULT_MODEL_ERROR = 0.0175
_NEUTRAL_RATIO = 1.10


class FringeOnlyError(SpectralEstimationError):
    """Every pixel of a region is predicted off by more than :data:`MAX_COLOUR_ERROR`: no colour to identify."""


@dataclass(frozen=True)
class CandidateSet:
    """Candidate materials forward-modelled into the camera.

    Attributes
    ----------
    names
        Material names.
    responses
        ``(m, c)`` camera values of each candidate at the geometry.
    neutral
        ``(m,)`` True for metals whose colour is within 10 % of the light's.
    light_deg
        Angle of the light from the normal (degrees); the view is along it.
    cos_d
        Cosine of the angle between the light and the half vector.
    """

    names: tuple[str, ...]
    responses: NDArray[np.float64]
    neutral: NDArray[np.bool_]
    light_deg: float
    cos_d: float

    @property
    def channels(self) -> int:
        """Camera channels c."""
        return int(self.responses.shape[1])


def _geometry(light_deg: float) -> tuple[float, float, float, float]:
    if not (isinstance(light_deg, (int, float, np.floating)) and 0.0 <= float(light_deg) < 90.0):
        raise SpectralEstimationError(f"light_deg must be an angle in [0, 90) degrees from the normal, got {light_deg!r}")
    t = math.radians(float(light_deg))
    cos_i, cos_o = math.cos(t), 1.0
    cos_h = cos_d = math.cos(t / 2)     # half vector halfway between light and view
    return cos_i, cos_o, cos_h, cos_d


def candidate_set(
    sensitivities: ArrayLike,
    lights: ArrayLike,
    grid: SpectralGrid,
    *,
    names: Sequence[str] = DEFAULT_CANDIDATES,
    light_deg: float = 30.0,
) -> CandidateSet:
    """Forward-model material presets (:func:`processing.materials.presets.get_material`) into the camera.

    Parameters
    ----------
    sensitivities
        ``(L, 3)`` model-camera sensitivities.
    lights
        ``(L,)`` light, or ``(k, L)`` for k exposures under different lights.
    grid
        The wavelength grid.
    names
        Material specs (preset names, optionally with parameters).
    light_deg
        Angle of the light from the surface normal, in [0, 90); the camera
        looks along the normal.

    Returns
    -------
    CandidateSet
        The candidates' camera responses and which of them are neutral metals.

    Raises
    ------
    SpectralEstimationError
        Fewer than two candidates, a bad spec or a cloth candidate, a
        candidate without signal in some channel, or a bad ``light_deg``.

    References
    ----------
    .. [1] Matsuda et al., section 4.2 (no DOI).

    Examples
    --------
    >>> from processing.camera.response import camera_sensitivities
    >>> g = SpectralGrid(400, 700, 10)
    >>> c = candidate_set(camera_sensitivities(g), np.ones(g.size), g, names=["gold", "silver"])
    >>> c.responses.shape, c.neutral.tolist()
    ((2, 3), [False, True])
    """
    if len(names) < 2:
        raise SpectralEstimationError("identification needs at least two candidate materials")
    k = channel_matrix(sensitivities, lights, grid)
    cos_i, cos_o, cos_h, cos_d = _geometry(light_deg)
    wl = grid.wavelengths
    rows, neutral = [], []
    white = np.ones(grid.size) @ k
    for name in names:
        try:
            mat = get_material(name)
        except ValueError as exc:
            raise SpectralEstimationError(f"candidate material {name!r}: {exc}") from None
        if any(lobe.kind == "anisotropic" for lobe in mat.lobes):
            raise SpectralEstimationError(f"candidate {name!r} is a cloth (anisotropic); identification covers metals and lacquers")
        signal = material_brdf(mat, cos_i, cos_o, cos_h, cos_d, wl) * (np.pi * cos_i)
        resp = signal @ k
        if not np.all(resp > 0):
            raise SpectralEstimationError(f"candidate {name!r} gives no signal in some channel at light_deg={light_deg}")
        rows.append(resp)
        ratio = resp / white
        neutral.append(mat.family in ("metal", "alloy") and float(ratio.max() / ratio.min()) <= _NEUTRAL_RATIO)
    return CandidateSet(tuple(names), np.array(rows), np.array(neutral), float(light_deg), cos_d)


@dataclass(frozen=True)
class Identification:
    """The material of one region.

    Attributes
    ----------
    material
        Best candidate, :data:`NEUTRAL_METAL`, or :data:`NO_FIT` when no candidate fits.
    confidence
        Probability that ``material`` is right (:func:`processing.materials.confidence.decide`:
        the posterior tempered by the misfit; for "neutral metal": of the group; for
        "no candidate fits": the best candidate's tempered posterior).
    runner_up
        Second-best candidate (for "neutral metal": the best outside the group).
    likelihood_ratio
        Tempered likelihood of the best over the runner-up.
    group
        The candidates the answer stands for: ``(material,)``, the indistinguishable contenders
        (best first), or for "no candidate fits" the best few.
    chi2
        ``(m,)`` chi-square of every candidate, in :attr:`CandidateSet.names` order.
    scale
        Fitted brightness of the best candidate.
    misfit
        Reduced chi-square of the best candidate (chi-square over c - 1 degrees of freedom for c
        channels; about 1 when it fits to the noise and model error).
    """

    material: str
    confidence: float
    runner_up: str
    likelihood_ratio: float
    group: tuple[str, ...]
    chi2: NDArray[np.float64]
    scale: float
    misfit: float


#: Pixels whose predicted decode colour error (``colour_error``) exceeds this in some channel are left out of a
#: region: their colour is mostly the fringe, and the prediction is least reliable where it is largest.
MAX_COLOUR_ERROR = 0.5
#: Share of a predicted decode colour error (``colour_error``) taken as independent per channel on top of
#: its predicted direction: the prediction is first order (a highlight's curvature is not in it).
FRINGE_SLACK = 0.5


def _dark_covariance(px: NDArray[np.float64], dark: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(c, c)`` covariance of a region mean's error from the sensor's absolute noise and its clipping at 0.

    The absolute noise ``dark`` of one pixel averages down over the ``n`` pixels; the bias of values
    clipped at zero does not: every dark pixel is off the same way.  A value ``mu`` with Gaussian noise
    ``s`` clipped at 0 reads on average ``mu + s (phi(t) - t Phi(-t))``, ``t = mu / s`` (0.40 s at the
    floor, 0.08 s one noise level above it, 0.01 s at two).  Each pixel's bias is taken at its darkest
    channel (``t`` its value over that channel's noise) and the region's mean of it scales ``dark``.
    """
    n = px.shape[0]
    sd = np.sqrt(np.maximum(np.diag(dark), 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(sd > 0, px / np.where(sd > 0, sd, 1.0), np.inf)
    t = np.clip(np.min(t, axis=1), 0.0, 40.0)
    bias = float((np.exp(-0.5 * t**2) / math.sqrt(2.0 * math.pi) - 0.5 * t * erfc(t / math.sqrt(2.0))).mean())
    return dark / n + bias**2 * dark


def _relative_covariance(mean: NDArray[np.float64], level: float,
                         transform: NDArray[np.float64] | None) -> NDArray[np.float64]:
    """``(c, c)`` covariance of an error of relative size ``level`` in every channel of the object camera.

    Without ``transform`` the pixels are the object camera's own values: ``diag((level * mean)^2)``.  With a
    row-form chart transform ``M`` the error arises before it, in the channels ``r = mean M^-1`` the sensor
    recorded, and reaches the model camera as ``M.T diag((level r)^2) M``: where ``M`` takes a difference of
    large channels (a model blue of ``1.6 B - 1.5 G``), a per cent of error in each is many per cent of
    the difference.
    """
    if transform is None:
        return np.diag((level * mean) ** 2)
    raw = np.abs(mean @ np.linalg.inv(transform))
    return transform.T @ np.diag((level * raw) ** 2) @ transform


def _region_covariance(px: NDArray[np.float64], noise: float, model_error: float,
                       colour_error: NDArray[np.float64] | None,
                       dark: NDArray[np.float64] | None = None,
                       transform: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """``(c, c)`` covariance of a region's mean colour: noise, pixel scatter, model and decode error."""
    n, c = px.shape
    mean = px.mean(axis=0)
    bright = np.maximum(px.sum(axis=1), 0.0)
    total = float(bright.sum())
    n_eff = total**2 / float((bright**2).sum()) if total > 0 else float(n)
    cov = _relative_covariance(mean, noise / math.sqrt(max(n_eff, 1.0)), transform)
    if n > 1:                                 # colour scatter among the pixels (brightness taken out)
        a = px @ mean / max(float(mean @ mean), 1e-300)
        d = px - a[:, None] * mean[None, :]
        scatter = (d**2).sum(axis=0) / (n * (n - 1))
        stated = np.diag(cov)
        grow = np.where(stated > 0, np.sqrt(np.maximum(scatter, stated) / np.where(stated > 0, stated, 1.0)), 0.0)
        cov = cov * np.outer(grow, grow) + np.diag(np.where(stated > 0, 0.0, scatter))
        # the larger of the stated noise and the scatter, per channel
    cov = cov + _relative_covariance(mean, model_error, transform)
    if colour_error is not None:
        w = bright / total if total > 0 else np.full(n, 1.0 / n)
        f = (w @ colour_error) * mean         # the region's predicted colour offset (signed)
        spread = (w @ np.abs(colour_error)) * mean
        cov = cov + np.outer(f, f) + np.diag((FRINGE_SLACK * spread) ** 2)
    if dark is not None:
        cov = cov + _dark_covariance(px, dark)
    floor = (1e-6 * float(mean.max())) ** 2   # a channel at exactly 0 keeps a finite weight
    return cov + np.eye(c) * max(floor, 1e-300)


def _region_sigma(mean: NDArray[np.float64], n: int, noise: float, model_error: float) -> NDArray[np.float64]:
    rel = math.sqrt(noise**2 / n + model_error**2)
    floor = 1e-6 * float(mean.max())      # a channel at exactly 0 keeps a finite weight
    return np.maximum(rel * mean, max(floor, 1e-300))


def _check_noise(noise: float, model_error: float) -> None:
    for name, v in (("noise", noise), ("model_error", model_error)):
        if not (isinstance(v, (int, float, np.floating)) and math.isfinite(v) and v >= 0):
            raise SpectralEstimationError(f"{name} must be a relative level >= 0 (0.01 = 1 %), got {v!r}")
    if noise == 0 and model_error == 0:
        raise SpectralEstimationError("noise and model_error are both 0: the likelihood is undefined; give the noise level")


def _dark_matrix(dark_noise: ArrayLike | None, c: int) -> NDArray[np.float64] | None:
    """``dark_noise`` as a ``(c, c)`` covariance (None stays None)."""
    if dark_noise is None:
        return None
    d = np.asarray(dark_noise, dtype=np.float64)
    if d.shape == (c,) and np.all(np.isfinite(d)) and np.all(d >= 0):
        return np.diag(d**2)
    if d.shape == (c, c) and np.all(np.isfinite(d)) and np.allclose(d, d.T) and np.all(np.diag(d) >= 0):
        return 0.5 * (d + d.T)
    raise SpectralEstimationError(f"dark_noise must be {c} standard deviations >= 0 or a symmetric {c} x {c} "
                                  f"covariance in the pixels' units, got shape {d.shape}")


def _transform_matrix(transform: ArrayLike | None, c: int) -> NDArray[np.float64] | None:
    """``transform`` as an invertible ``(c, c)`` matrix (None stays None)."""
    if transform is None:
        return None
    m = np.asarray(transform, dtype=np.float64)
    if m.shape != (c, c) or not np.all(np.isfinite(m)) or abs(float(np.linalg.det(m))) < 1e-12:
        raise SpectralEstimationError(f"transform must be the invertible {c} x {c} chart transform that brought the "
                                      f"pixels to the model camera, got shape {m.shape}")
    return m


def identify_material(
    pixels: ArrayLike, candidates: CandidateSet, *, noise: float = 0.01, model_error: float = DEFAULT_MODEL_ERROR,
    colour_error: ArrayLike | None = None, error_dof: float | None = SINGLE_IMAGE_ERROR_DOF,
    dark_noise: ArrayLike | None = None, transform: ArrayLike | None = None,
) -> Identification:
    """Identify the material of one region from its pixels' camera values ``(n, c)`` (or one ``(c,)``).

    Every candidate is fitted with a free brightness to the region's mean by generalised least
    squares under the covariance of that mean, giving its chi-square on ``c - 1`` degrees of
    freedom; :func:`processing.materials.confidence.decide` turns the chi-squares into the answer
    and its confidence.  The covariance holds, per channel ``c`` of the mean ``m``:

    * the pixel noise, ``noise^2 / n_eff`` relative, with ``n_eff = (sum b)^2 / sum b^2`` the
      effective pixel count of a mean dominated by its brightest pixels ``b`` (a highlight's
      25 pixels may weigh like 3), or the pixels' own colour scatter about the region's colour
      (brightness taken out) when that is larger;
    * the model error, ``model_error^2`` relative;
    * with ``colour_error``: the colour error the decode predicts (e.g. the CFA fringe of a
      binned Bayer image, :func:`processing.camera.cfa_fringe.cfa_fringe`), brightness-weighted
      over the pixels, as a full-strength error along its predicted direction plus
      :data:`FRINGE_SLACK` of its size independent per channel.  It is not divided by the pixel
      count: every pixel of one highlight's flank is off the same way.  Pixels predicted off by
      more than :data:`MAX_COLOUR_ERROR` are left out;
    * with ``dark_noise``: the sensor's absolute noise (read noise after black subtraction), which
      the relative ``noise`` misses where the signal is low, divided by the pixel count, plus the
      bias of values clipped at 0, which is not (:func:`_dark_covariance`).  Pixels at the noise
      floor have no colour of their own: their clipped noise, equal in the RAW channels, reads
      after the chart transform as the colour the transform gives a RAW grey (for a camera whose
      red and blue are weaker than its green, a strong red), which a red lacquer fits well.

    Parameters
    ----------
    pixels
        Linear camera values in the model camera's units (after the chart
        transform), ``(n, c)`` with c the candidates' channels; finite, >= 0.
    candidates
        The forward-modelled candidates (:func:`candidate_set`).
    noise
        Relative noise of one pixel's channel (0.01 = 1 %).
    model_error
        Relative error of the forward model, added in quadrature to the
        region mean's noise (default :data:`DEFAULT_MODEL_ERROR`; 0 only for
        data made by the candidates' own model).
    colour_error
        ``(n, c)`` (or ``(c,)``) signed relative colour error each pixel's values may carry from
        the decode (a channel reads ``1 + e`` times the truth); None: none.
    error_dof
        How well the error's own size is known (:func:`processing.materials.confidence.decide`,
        Student-t likelihood); default :data:`processing.materials.confidence.SINGLE_IMAGE_ERROR_DOF`;
        None: the Gaussian likelihood.
    dark_noise
        Absolute noise of one pixel in the units of ``pixels``: ``(c,)`` standard deviations or a
        ``(c, c)`` covariance (a RAW's read noise ``s`` per channel carried by a row-form chart
        transform ``M`` is ``M.T @ diag(s**2) @ M``); None: none.
    transform
        ``(c, c)`` row-form chart transform that brought the pixels from the object camera to the model
        camera (:attr:`processing.camera.transfer.ChartTransform.matrix`); given, the relative noise
        and model error are taken in the object camera's channels and carried through it
        (:func:`_relative_covariance`); None: the pixels' own channels.

    Returns
    -------
    Identification
        Material (or "neutral metal", or "no candidate fits"), confidence,
        runner-up, likelihood ratio, group, chi-square per candidate,
        brightness and misfit.

    Raises
    ------
    SpectralEstimationError
        Bad noise levels, pixels of the wrong shape or non-finite, or a
        region black in every channel.

    References
    ----------
    .. [1] Matsuda et al., section 4.2, eq. (11) (no DOI).
    .. [2] McCullagh & Nelder (1989), section 4.5, doi:10.1007/978-1-4899-3242-6.

    Examples
    --------
    >>> from processing.camera.response import camera_sensitivities
    >>> from processing.spectral.spectra import light_spectrum
    >>> g = SpectralGrid(400, 700, 10)
    >>> cands = candidate_set(camera_sensitivities(g), light_spectrum("D65", g), g)
    >>> gold = cands.responses[cands.names.index("gold")]
    >>> r = identify_material(np.tile(0.3 * gold, (50, 1)), cands)
    >>> r.material, r.confidence > 0.99
    ('gold', True)
    >>> identify_material([0.0, 1.0, 0.0], cands).material       # pure green: no material makes it
    'no candidate fits'

    Grey shibuichi whose red and blue a highlight's fringe moved toward gold's colour: told as
    certain gold without the fringe, and not with it.

    >>> nami = cands.responses[cands.names.index("nami-shibuichi")]
    >>> fringe = np.tile([0.25, 0.0, -0.25], (25, 1))
    >>> seen = np.tile(0.3 * nami * (1 + fringe[0]), (25, 1))
    >>> blind = identify_material(seen, cands)
    >>> told = identify_material(seen, cands, colour_error=fringe)
    >>> blind.material != "nami-shibuichi", told.confidence < 0.9
    (True, True)

    Pixels at the noise floor: read noise clipped at 0, equal in the RAW channels, through a chart
    transform that lifts red above green and blue.  Taken at its face value it reads as the red
    lacquer; told the read noise, nothing is certain.

    >>> m = np.array([[2.4, -0.3, -0.2], [-0.6, 1.2, -0.3], [-0.2, -0.4, 1.9]])
    >>> raw = np.maximum(np.random.default_rng(1).normal(0.0, 5e-4, (100, 3)), 0.0)
    >>> dark = np.maximum(raw @ m, 0.0)
    >>> blind = identify_material(dark, cands)
    >>> told = identify_material(dark, cands, dark_noise=m.T @ np.diag(np.full(3, 5e-4**2)) @ m)
    >>> blind.material, blind.confidence > 0.9, told.confidence < 0.9
    ('urushi-red', True, True)
    """
    _check_noise(noise, model_error)
    px = np.asarray(checked_channels("region pixels", pixels, candidates.channels), dtype=np.float64)
    px = px.reshape(-1, candidates.channels)
    mean = px.mean(axis=0)
    if not np.any(mean > 0):
        raise SpectralEstimationError("the region is black in every channel; nothing to identify")
    fringe = None
    if colour_error is not None:
        fringe = np.asarray(colour_error, dtype=np.float64).reshape(-1, candidates.channels) \
            if np.size(colour_error) == px.size else None
        if fringe is None or not np.all(np.isfinite(fringe)):
            raise SpectralEstimationError(f"colour_error must hold one finite relative error per pixel and channel "
                                          f"({px.shape[0]} x {candidates.channels}), got {np.shape(colour_error)}")
        usable = np.abs(fringe).max(axis=1) <= MAX_COLOUR_ERROR
        if not usable.any():
            raise FringeOnlyError(
                f"the region's colour is the sensor's colour-filter fringe (every pixel's predicted colour error "
                f"exceeds {100 * MAX_COLOUR_ERROR:.0f}%, a highlight or edge a pixel or two wide): nothing to "
                "identify; choose a broader lit part")
        px, fringe = px[usable], fringe[usable]
        mean = px.mean(axis=0)
        if not np.any(mean > 0):
            raise SpectralEstimationError("the region is black in every channel; nothing to identify")
    cov = _region_covariance(px, noise, model_error, fringe, _dark_matrix(dark_noise, candidates.channels),
                             _transform_matrix(transform, candidates.channels))
    p = np.linalg.inv(cov)
    m = candidates.responses
    pm = m @ p                                               # (k, c)
    scale = np.maximum((pm @ mean) / np.maximum(np.einsum("kc,kc->k", pm, m), 1e-300), 0.0)
    r = mean[None, :] - scale[:, None] * m
    chi2 = np.maximum(np.einsum("kc,cd,kd->k", r, p, r), 0.0)
    n = len(candidates.names)
    c = candidates.channels
    d = decide(candidates.names, chi2, np.full(n, c - 1.0), np.ones(n), neutral=candidates.neutral,
               error_dof=error_dof)
    inside = set(d.group) if d.answer == NEUTRAL_METAL else {candidates.names[d.best]}
    outside = [i for i in np.argsort(-d.posterior, kind="stable") if candidates.names[i] not in inside]
    runner = int(outside[0]) if outside else int(np.argsort(chi2)[1])
    ratio = float(d.posterior[d.best] / max(float(d.posterior[runner]), 1e-300))
    return Identification(d.answer, min(float(d.confidence), 1.0), candidates.names[runner], min(ratio, 1e300),
                          tuple(d.group), chi2, float(scale[d.best]), float(d.misfit))


def identify_regions(
    rgb: ArrayLike, labels: ArrayLike, candidates: CandidateSet, *, noise: float = 0.01,
    model_error: float = DEFAULT_MODEL_ERROR, colour_error: ArrayLike | None = None,
    dark_noise: ArrayLike | None = None, transform: ArrayLike | None = None,
) -> dict[int, Identification]:
    """Identify every labelled region (label > 0) of an image.

    Parameters
    ----------
    rgb
        ``(H, W, c)`` linear camera values, as for :func:`identify_material`.
    labels
        Integer ``(H, W)`` image, 0 for pixels to leave out (the mask).
    candidates
        The forward-modelled candidates (:func:`candidate_set`).
    noise, model_error
        As for :func:`identify_material`.
    colour_error
        ``(H, W, c)`` per-pixel relative colour error (as for :func:`identify_material`); None: none.
    dark_noise
        The sensor's absolute noise of one pixel (as for :func:`identify_material`); None: none.
    transform
        The chart transform the pixels went through (as for :func:`identify_material`); None: none.

    Returns
    -------
    dict
        Label -> :class:`Identification`; a region whose every pixel is mostly CFA fringe
        (:class:`FringeOnlyError`) is left out.

    Raises
    ------
    SpectralEstimationError
        Mismatched shapes, a non-integer label image, no region, or an error
        of :func:`identify_material`.

    Examples
    --------
    >>> from processing.camera.response import camera_sensitivities
    >>> g = SpectralGrid(400, 700, 10)
    >>> cands = candidate_set(camera_sensitivities(g), np.ones(g.size), g, names=["gold", "urushi-red"])
    >>> img = np.stack([np.tile(cands.responses[0], (2, 1)), np.tile(cands.responses[1], (2, 1))])
    >>> {k: v.material for k, v in identify_regions(img, np.array([[1, 1], [2, 2]]), cands).items()}
    {1: 'gold', 2: 'urushi-red'}
    """
    img = checked_channels("rgb", rgb, candidates.channels)
    lab = np.asarray(labels)
    if img.ndim != 3 or lab.shape != img.shape[:2] or lab.dtype.kind not in "iu":
        raise SpectralEstimationError(
            f"rgb must be (H, W, c) and labels an integer (H, W) image of the same size, got {img.shape} and {lab.shape}"
        )
    flat = img.reshape(-1, img.shape[2])
    err = None
    if colour_error is not None:
        err = np.asarray(colour_error, dtype=np.float64)
        if err.shape != img.shape:
            raise SpectralEstimationError(f"colour_error must be {img.shape} like rgb, got {err.shape}")
        err = err.reshape(-1, img.shape[2])
    lab = lab.ravel()
    ids = np.unique(lab[lab > 0])
    if ids.size == 0:
        raise SpectralEstimationError("the label image has no region (every label is 0)")
    order = np.argsort(lab, kind="stable")
    bounds = np.searchsorted(lab[order], np.concatenate([ids, [ids[-1] + 1]]))
    found = {}
    for i, r in enumerate(ids):
        part = order[bounds[i]:bounds[i + 1]]
        try:
            found[int(r)] = identify_material(flat[part], candidates, noise=noise, model_error=model_error,
                                              colour_error=None if err is None else err[part],
                                              dark_noise=dark_noise, transform=transform)
        except FringeOnlyError:
            continue                      # no pixel with a colour of its own: the caller reports it unjudged
    return found


@dataclass(frozen=True)
class AlloyEstimate:
    """Alloy composition from camera values.

    Attributes
    ----------
    metals
        Chemical symbols.
    weights
        ``(k,)`` non-negative weights summing to 1.
    std
        ``(k,)`` linearised standard deviation of the weights under the noise model.
    residual
        Weighted RMS residual (in noise standard deviations).
    """

    metals: tuple[str, ...]
    weights: NDArray[np.float64]
    std: NDArray[np.float64]
    residual: float

    def as_dict(self) -> dict[str, float]:
        """Weights by symbol.

        Returns
        -------
        dict
            Chemical symbol -> weight.
        """
        return {m: float(w) for m, w in zip(self.metals, self.weights)}


def estimate_alloy_weights(
    pixels: ArrayLike,
    sensitivities: ArrayLike,
    lights: ArrayLike,
    grid: SpectralGrid,
    *,
    metals: Sequence[str] = ("Ag", "Cu", "Au"),
    light_deg: float = 30.0,
    noise: float = 0.01,
) -> AlloyEstimate:
    """Weights of the alloy model ``C = sum_j w_j C_j`` from a region's camera values.

    The pure metals' Fresnel reflectances at the geometry's half-angle go
    through the camera; ``rho ~= sum_j v_j r_j`` with ``v >= 0`` is solved by
    weighted NNLS, and ``w = v / sum(v)`` (the brightness is free).  The
    standard deviation propagates the noise model through the active set.

    Parameters
    ----------
    pixels
        ``(n, c)`` (or ``(c,)``) linear camera values of the region.
    sensitivities
        ``(L, c)`` model-camera sensitivities.
    lights
        ``(L,)`` light, or ``(k, L)`` for k exposures.
    grid
        The wavelength grid.
    metals
        Chemical symbols of the constituents (at least two).
    light_deg
        Angle of the light from the normal, in [0, 90); the view is along it.
    noise
        Relative noise of one pixel's channel (> 0; 0.01 = 1 %).

    Returns
    -------
    AlloyEstimate
        Weights summing to 1, their standard deviations and the residual.

    Raises
    ------
    SpectralEstimationError
        A bad noise level or ``light_deg``, bad pixels, a black region, fewer
        than two metals, an unknown metal, or no non-negative mixture.

    References
    ----------
    .. [1] Matsuda et al., eq. (3)-(4) (no DOI).

    Examples
    --------
    >>> from processing.camera.response import camera_sensitivities, camera_rgb
    >>> from processing.spectral.spectra import light_spectrum
    >>> g = SpectralGrid(400, 700, 10)
    >>> s, e = camera_sensitivities(g), light_spectrum("D65", g)
    >>> refl = ConductorFresnel({"Ag": 0.4, "Cu": 0.6}).reflectance(np.cos(np.radians(15)), g.wavelengths)
    >>> est = estimate_alloy_weights(0.2 * camera_rgb(refl, e, s, g), s, e, g)
    >>> {k: round(v, 3) for k, v in est.as_dict().items()}
    {'Ag': 0.4, 'Cu': 0.6, 'Au': 0.0}
    """
    if noise is None or not (math.isfinite(noise) and noise > 0):
        raise SpectralEstimationError(f"noise must be a relative level > 0, got {noise!r}")
    k = channel_matrix(sensitivities, lights, grid)
    px = np.asarray(checked_channels("region pixels", pixels, k.shape[1]), dtype=np.float64).reshape(-1, k.shape[1])
    mean = px.mean(axis=0)
    if not np.any(mean > 0):
        raise SpectralEstimationError("the region is black in every channel; nothing to fit")
    if len(metals) < 2:
        raise SpectralEstimationError("an alloy needs at least two metals")
    _, _, _, cos_d = _geometry(light_deg)
    try:
        refl = np.stack([ConductorFresnel({m: 1.0}).reflectance(cos_d, grid.wavelengths) for m in metals])
    except ValueError as exc:
        raise SpectralEstimationError(f"alloy metals {tuple(metals)}: {exc}") from None
    r = refl @ k                                            # (k, c)
    sigma = _region_sigma(mean, px.shape[0], noise, 0.0)
    sw = 1.0 / sigma
    v, _ = nnls((r * sw).T, mean * sw)
    total = float(v.sum())
    if total <= 0:
        raise SpectralEstimationError("no non-negative mixture of the metals explains the region")
    w = v / total
    active = v > 0
    ra = (r[active] * sw).T                                 # (c, a) weighted
    dv_do = np.linalg.pinv(ra) * sw[None, :]                # (a, c): d v_active / d rho
    jac_v = np.zeros((len(metals), r.shape[1]))
    jac_v[active] = dv_do
    jac_w = (np.eye(len(metals)) - w[:, None]) @ jac_v / total
    cov = jac_w @ np.diag(sigma**2) @ jac_w.T
    resid = (mean - v @ r) * sw
    return AlloyEstimate(tuple(metals), w, np.sqrt(np.maximum(np.diag(cov), 0.0)), float(np.sqrt(np.mean(resid**2))))
