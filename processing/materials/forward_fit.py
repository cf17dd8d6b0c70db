"""A region of the mesh fitted by forward modelling at its observations' true angles.

Every observation of a region (a vertex seen in one frame, lit by the lamp) is predicted by

    m_c = k * irr * cos_i * pi * sum_l f_r(l; cos_i, cos_o, cos_h, cos_d) E(l) s_c(l) / sum_l E(l) s_c(l)

(the chart-normalised camera signal of docs/appearance.md), with ``f_r`` the candidate material's
BRDF (:func:`processing.materials.lobes.material_brdf`).  Each candidate of
:data:`SURFACE_CANDIDATES` -- the pure metals, the named alloys, a free Ag/Cu/Au alloy and the two
urushi lacquers -- is fitted with its gloss roughness (Beckmann RMS slope, a bounded 1-D search)
and its lobe amplitudes (linear at fixed roughness: NNLS), the amplitudes absorbing the lamp scale
``k``.  The Fresnel term's change of colour with ``cos_d`` over all observations is what separates
the neutral metals.  The choice among candidates and its confidence come from
:func:`processing.materials.confidence.decide`; a region without highlight observations is
:data:`NOT_MEASURED` with a reason saying what to capture.  docs/materials.md, section "Fitting a
region on the mesh", states the model, the weights and the limits.

References
----------
.. [1] Matsuda, Tanaka, Ichikawa, Mochizuki, Muroya, Kitamura, "CG reproduction of a craft object
   based on a light reflection model", IPSJ technical report (no DOI), eq. (1)-(5).
.. [2] Lawson, C. L., Hanson, R. J. (1974). Solving Least Squares Problems, Prentice-Hall, ch. 23
   (NNLS). doi:10.1137/1.9781611971217
.. [3] Schwarz, G. (1978). Estimating the dimension of a model. Ann. Statist. 6(2), 461-464.
   doi:10.1214/aos/1176344136
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from threadpoolctl import threadpool_limits

from processing.materials._forward_fit_core import (
    CAUCHY_SCALE,
    MIRROR_EXCLUDE_DEG,
    Basis,
    Whitener,
    _columns,
    _geometry,
    common_mode_error,
    common_mode_of,
    fit_candidate,
    robust_weights,
)
from processing.materials._forward_fit_samples import HIGHLIGHT_DEG, FitError, RegionSamples, region_samples
from processing.materials.confidence import NOT_MEASURED
from processing.materials.lobes import Material, lobe_geometry, material_brdf
from processing.materials.metal_model import ConductorFresnel
from processing.materials.presets import get_material
from processing.spectral.spectra import SpectralGrid

__all__ = ["SURFACE_CANDIDATES", "ALLOY", "ForwardModel", "RegionFit", "RegionSamples", "FitError",
           "region_samples", "fit_region", "highlight_colour_scatter", "prepared_observations", "grouped_observations", "MIN_HIGHLIGHTS", "HIGHLIGHT_DEG", "INDEPENDENT"]

#: The free Ag/Cu/Au alloy candidate.
ALLOY = "alloy"
#: Candidates of a surface fit: pure metals, named alloys, the free alloy, the lacquers.
SURFACE_CANDIDATES: tuple[str, ...] = (
    "gold", "silver", "copper", "aluminium", "platinum", "iron", "zinc", "lead", "tin",
    "nami-shibuichi", "shiro-shibuichi", "jo-shibuichi", "nami-shibuichi-uchi-sanbu", "nami-shibuichi-soto-sanbu",
    "shakudo", "bronze", ALLOY, "urushi-black", "urushi-red",
)
#: Observations of a region counted as independent evidence (tuned on bench/surface_fit_bench.py).
INDEPENDENT = 400.0
#: Fewest lit observations within :data:`HIGHLIGHT_DEG` of the mirror direction a fit needs.
MIN_HIGHLIGHTS = 12
_ALLOY_METALS = ("Ag", "Cu", "Au")
_NEUTRAL_RATIO = 1.10
_TABLE = np.linspace(0.0, 1.0, 257)
#: Smallest noise standard deviation (relative to the chart's white) an observation is trusted to.
_SIGMA_FLOOR = 1e-4


class ForwardModel:
    """The camera and the lamp that turn a BRDF into chart-normalised camera RGB.

    Parameters
    ----------
    sensitivities
        ``(L, 3)`` camera sensitivities on ``grid``.
    light
        ``(L,)`` lamp spectrum on ``grid``.
    grid
        The :class:`processing.spectral.spectra.SpectralGrid`.

    Raises
    ------
    FitError
        Shapes that do not match the grid, or a channel with no signal under the light.

    Examples
    --------
    >>> from processing.camera.response import camera_sensitivities
    >>> from processing.spectral.spectra import light_spectrum
    >>> g = SpectralGrid(400, 700, 10)
    >>> fm = ForwardModel(camera_sensitivities(g), light_spectrum("D65", g), g)
    >>> fm.colour(ConductorFresnel({"Au": 1.0}), [1.0]).round(2).tolist()   # gold at normal incidence
    [[0.86, 0.66, 0.45]]
    """

    def __init__(self, sensitivities: ArrayLike, light: ArrayLike, grid: SpectralGrid) -> None:
        s = np.asarray(sensitivities, dtype=np.float64)
        e = np.asarray(light, dtype=np.float64).reshape(-1)
        self.grid, self.wavelengths = grid, np.asarray(grid.wavelengths, dtype=np.float64)
        if s.shape != (self.wavelengths.size, 3) or e.shape != (self.wavelengths.size,):
            raise FitError(f"sensitivities must be ({self.wavelengths.size}, 3) and light ({self.wavelengths.size},) "
                           f"on the grid, got {s.shape} and {e.shape}")
        white = e @ s
        if not np.all(np.isfinite(white)) or np.any(white <= 0):
            raise FitError("a camera channel sees nothing of the light: check the sensitivities and the spectrum")
        self._weights = e[:, None] * s / white[None, :]
        self._tables: dict[str, NDArray[np.float64]] = {}

    def colour(self, spectral, cos_d: ArrayLike) -> NDArray[np.float64]:
        """Camera colour ``(n, 3)`` of a spectral factor at ``cos_d`` (white = 1).

        Parameters
        ----------
        spectral
            A :class:`processing.materials.lobes.SpectralFactor`.
        cos_d
            ``(n,)`` cosines between light and half vector.

        Returns
        -------
        ndarray
            ``(n, 3)``.
        """
        c = np.asarray(cos_d, dtype=np.float64).reshape(-1)
        return spectral.reflectance(c, self.wavelengths) @ self._weights

    def table_colour(self, key: str, spectral, cos_d: NDArray[np.float64]) -> NDArray[np.float64]:
        """:meth:`colour` through a cached table over cos_d (linear interpolation, 257 nodes).

        Parameters
        ----------
        key
            Cache key naming ``spectral``.
        spectral
            The spectral factor.
        cos_d
            ``(n,)`` cosines.

        Returns
        -------
        ndarray
            ``(n, 3)``.
        """
        if key not in self._tables:
            self._tables[key] = self.colour(spectral, _TABLE)
        return _on_table(self._tables[key], cos_d)

    def predict(self, material: Material, samples: RegionSamples) -> NDArray[np.float64]:
        """Predicted chart-normalised signal ``(n, 3)`` of ``material`` at the samples (k = 1).

        Parameters
        ----------
        material
            The material (e.g. ``get_material(fit.spec)``).
        samples
            The observations' geometry.

        Returns
        -------
        ndarray
            ``(n, 3)``.
        """
        s = samples
        if any(lobe.kind == "anisotropic" for lobe in material.lobes):
            f = material_brdf(material, s.cos_i, s.cos_o, s.cos_h, s.cos_d, self.wavelengths)
            return (f @ self._weights) * (np.pi * s.irradiance * s.cos_i)[:, None]
        # each lobe is a geometric factor times a spectral factor of cos_d alone: the spectral factor's camera
        # colour on the 257-node table, interpolated, instead of the spectrum at every observation (a metal's
        # complex Fresnel reflectance there is most of the cost); within 1e-4 of it (tests/materials)
        cd = np.asarray(s.cos_d, dtype=np.float64)
        total = np.zeros((cd.size, 3))
        colours: dict[int, NDArray[np.float64]] = {}
        for lobe in material.lobes:
            if lobe.weight == 0.0:
                continue
            key = id(lobe.spectral)
            if key not in colours:
                colours[key] = _on_table(self.colour(lobe.spectral, _TABLE), cd)
            g = np.broadcast_to(lobe_geometry(lobe, s.cos_i, s.cos_o, s.cos_h, cd, None), cd.shape)
            total += lobe.weight * g[:, None] * colours[key]
        return total * (np.pi * s.irradiance * s.cos_i)[:, None]


def _on_table(table: NDArray[np.float64], cos_d: ArrayLike) -> NDArray[np.float64]:
    """``(n, 3)`` colours of a ``(257, 3)`` table over ``cos_d`` (:data:`_TABLE`), linearly interpolated."""
    return np.stack([np.interp(cos_d, _TABLE, table[:, c]) for c in range(3)], axis=1)


@dataclass(frozen=True)
class RegionFit:
    """The material of one region, its parameters and how sure the fit is.

    Attributes
    ----------
    material
        A preset name, ``"alloy"``, ``"neutral metal"``, ``"no candidate fits"`` or ``"not measured"``.
    confidence
        Probability the answer is right (0 when not measured).
    group
        The candidates the answer stands for.
    spec
        A :func:`processing.materials.presets.get_material` spec reproducing the fit (None when not
        measured); gloss, mirror and diffuse are relative to the chart's white.
    parameters, uncertainties
        Fitted parameters and their 1-sigma uncertainties.
    chi2_per_dof
        Reduced chi-square of the answer's fit.
    n_observations
        Observations fitted.
    n_lit
        Lit, unclipped observations within :data:`HIGHLIGHT_DEG` of the mirror direction.
    candidates
        Per candidate: name, chi2, dof, posterior.
    reason
        Why not measured and what to capture ("" otherwise).
    colour_scatter
        How many times their noise variance the highlight observations' colours scatter about their
        median (:func:`highlight_colour_scatter`; 1 when within the noise).
    """

    material: str
    confidence: float
    group: tuple[str, ...]
    spec: str | None
    parameters: dict[str, float] = field(default_factory=dict)
    uncertainties: dict[str, float] = field(default_factory=dict)
    chi2_per_dof: float = float("nan")
    n_observations: int = 0
    n_lit: int = 0
    candidates: tuple[dict, ...] = ()
    reason: str = ""
    colour_scatter: float = 1.0

    def to_dict(self) -> dict:
        """A JSON-ready dict of every field (NaN as None, tuples as lists).

        Returns
        -------
        dict
        """
        d = asdict(self)
        d["group"], d["candidates"] = list(self.group), [dict(c) for c in self.candidates]
        if not np.isfinite(d["chi2_per_dof"]):
            d["chi2_per_dof"] = None
        return d


def _preset(name: str) -> Material:
    return get_material(name)


def _basis(name: str, model: ForwardModel, cos_d: NDArray[np.float64]) -> tuple[Basis, bool]:
    """A candidate's linear structure and whether it is a neutral metal."""
    if name == ALLOY:
        cols = np.stack([model.table_colour(m, ConductorFresnel({m: 1.0}), cos_d) for m in _ALLOY_METALS])
        return Basis(ALLOY, cols, None, 0.3 / 0.7, 0.01), False
    mat = _preset(name)
    p = mat.parameters
    ratio = float(p["mirror"]) / max(float(p["gloss"]), 1e-9)
    if mat.family == "dielectric":
        diff, gl = mat.lobes[0].spectral, mat.lobes[1].spectral
        col = model.table_colour(f"{name}:fresnel", gl, cos_d)[None]
        dc = model.colour(diff, [0.5])[0]
        return Basis(name, col, dc, ratio, float(p["mirror_roughness"])), False
    spectral = mat.lobes[0].spectral
    col = model.table_colour(name, spectral, cos_d)
    c1 = model.colour(spectral, [1.0])[0]
    return Basis(name, col[None], None, ratio, float(p["mirror_roughness"])), bool(c1.max() <= _NEUTRAL_RATIO * c1.min())


def _not_measured(samples: RegionSamples, n_hl: int, n_fit: int) -> RegionFit | None:
    """A NOT_MEASURED answer with what to capture, or None when the region can be fitted."""
    if n_hl >= MIN_HIGHLIGHTS:
        return None
    if samples.n_gathered == 0:
        why = "no observation: no frame saw the region; add table angles or a placement that shows it"
    elif len(samples) == 0 and samples.clipped_share >= 0.999:
        why = "every lit observation clipped: lower the exposure"
    elif len(samples) == 0:
        why = ("no lit observation: the lamp never reaches the region (facing away or shadowed); "
               "add a second placement or lamp")
    elif samples.clipped_highlight >= max(MIN_HIGHLIGHTS - n_hl, 1) and samples.clipped_highlight > n_hl:
        why = f"every highlight clipped ({samples.clipped_highlight} clipped, {n_hl} usable): lower the exposure"
    elif float(np.median(samples.cos_o)) < np.cos(np.radians(70.0)):
        why = "seen only at grazing angles (median view over 70 deg from the normal): add a placement facing it"
    else:
        why = (f"no observation within {HIGHLIGHT_DEG:g} deg of the mirror direction ({n_hl} < {MIN_HIGHLIGHTS}): "
               "add table angles or a second placement so its highlights are seen")
    return RegionFit(NOT_MEASURED, 0.0, (), None, n_observations=n_fit, n_lit=n_hl, reason=why)


def _subsample(samples: RegionSamples, max_samples: int, seed: int) -> RegionSamples:
    """All samples within 25 deg of the mirror direction plus a random share of the rest, at most max_samples."""
    keep = samples.cos_h < np.cos(np.radians(MIRROR_EXCLUDE_DEG))
    idx = np.flatnonzero(keep)
    if idx.size <= max_samples:
        return samples.subset(idx)
    rng = np.random.default_rng(seed)
    near = idx[samples.cos_h[idx] >= np.cos(np.radians(25.0))]
    rest = np.setdiff1d(idx, near)
    if near.size >= max_samples:
        return samples.subset(np.sort(rng.choice(near, max_samples, replace=False)))
    pick = rng.choice(rest, max_samples - near.size, replace=False)
    return samples.subset(np.sort(np.concatenate([near, pick])))


def _whitened(fitted: RegionSamples, model: ForwardModel, model_error: float, normal_error_deg: float,
              robust: bool) -> tuple[RegionSamples, NDArray[np.float64], Whitener]:
    """The fitted samples, their flattened signal and its whitener (noise, model error, normals, robust weights)."""
    y = fitted.signal.reshape(-1)
    var = np.maximum(fitted.sigma, _SIGMA_FLOOR) ** 2 + (model_error * np.maximum(fitted.signal, 0.0)) ** 2
    provisional = [_basis(c, model, fitted.cos_d)[0] for c in (ALLOY, "urushi-black")]
    first = robust_weights(provisional, fitted, y, Whitener.of(var, np.zeros_like(var))) if robust else None
    common = common_mode_error(provisional, fitted, y, var, np.radians(normal_error_deg), weights=first)
    w = Whitener.of(var, common)
    if robust:
        w = w.scaled(np.sqrt(robust_weights(provisional, fitted, y, w)))
    return fitted, y, w


def prepared_observations(samples: RegionSamples, model: ForwardModel, *, model_error: float = 0.02,
                          normal_error_deg: float = 0.5, max_samples: int = 20_000, seed: int = 0,
                          robust: bool = True) -> tuple[RegionSamples, NDArray[np.float64], Whitener] | None:
    """The observations as :func:`fit_region` weighs them, for scoring fixed materials on them.

    Parameters
    ----------
    samples
        The observations (:func:`region_samples`).
    model
        Camera and lamp.
    model_error, normal_error_deg, max_samples, seed, robust
        As in :func:`fit_region`.

    Returns
    -------
    tuple or None
        The subsampled observations, their ``(n * 3,)`` signal and the whitener ``w`` (so that
        ``|w(signal - prediction)|^2`` is a chi-square), or None when there is no observation.
    """
    if not (np.isfinite(model_error) and model_error >= 0):
        raise FitError(f"model_error must be >= 0 (relative), got {model_error!r}")
    fitted = _subsample(samples, int(max_samples), seed)
    if len(fitted) == 0:
        return None
    return _whitened(fitted, model, model_error, normal_error_deg, robust)


def _grouped_subsample(samples: RegionSamples, group: NDArray[np.int64], max_samples: int,
                       seed: int) -> NDArray[np.int64]:
    """Indices of :func:`_subsample` applied to each group on its own (same seed), in group order."""
    keep = np.flatnonzero(samples.cos_h < np.cos(np.radians(MIRROR_EXCLUDE_DEG)))
    keep = keep[np.argsort(group[keep], kind="stable")]
    ids, start, count = np.unique(group[keep], return_index=True, return_counts=True)
    parts = [keep]
    for g, s0, c in zip(ids, start, count):
        if c > max_samples:                 # the few large groups: the exact per-group draw
            idx = keep[s0:s0 + c]
            rng = np.random.default_rng(seed)
            near = idx[samples.cos_h[idx] >= np.cos(np.radians(25.0))]
            if near.size >= max_samples:
                pick = np.sort(rng.choice(near, max_samples, replace=False))
            else:
                pick = np.sort(np.concatenate([near, rng.choice(np.setdiff1d(idx, near), max_samples - near.size,
                                                                 replace=False)]))
            parts[0] = parts[0][group[parts[0]] != g]
            parts.append(pick)
    out = np.concatenate(parts)
    return out[np.lexsort((out, group[out]))]


def _group_median(x: NDArray[np.float64], group: NDArray[np.int64]) -> NDArray[np.float64]:
    """Per element the median of ``x`` over its group (``group`` sorted, 0..G-1 dense)."""
    order = np.lexsort((x, group))
    xs, counts = x[order], np.bincount(group)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    lo, hi = start + (counts - 1) // 2, start + counts // 2
    med = 0.5 * (xs[np.minimum(lo, len(xs) - 1)] + xs[np.minimum(hi, len(xs) - 1)])
    return med[group]


def grouped_observations(samples: RegionSamples, group: ArrayLike, model: ForwardModel, *,
                         model_error: float = 0.02, normal_error_deg: float = 0.5, max_samples: int = 4000,
                         fit_samples: int = 4000, seed: int = 0, robust: bool = True,
                         ) -> tuple[RegionSamples, NDArray[np.int64], NDArray[np.float64], Whitener] | None:
    """Observations of many groups (a region's pieces) weighed as :func:`fit_region` weighs one, in one pass.

    Each group keeps the observations :func:`prepared_observations` would keep for it alone
    (``max_samples`` each, the same draw).  The noise and model error are per observation, as in the
    fit.  The provisional fits that set the common-mode (normal) error and the robust weights are made
    once, on up to ``fit_samples`` of all the groups' observations, instead of once per group; the
    robust weights' scale (the median misfit) and their normalisation to a mean of 1 stay per group,
    so a group that the provisional fit misses as a whole keeps its weight and its misfit.

    Parameters
    ----------
    samples
        The observations (:func:`region_samples`).
    group
        ``(n,)`` group of each observation (>= 0).
    model
        Camera and lamp.
    model_error, normal_error_deg, seed, robust
        As in :func:`fit_region`.
    max_samples
        Most observations kept per group.
    fit_samples
        Most observations of the provisional fits (drawn as :func:`fit_region` draws its own: the
        observations near the mirror direction first).

    Returns
    -------
    tuple or None
        The kept observations (in group order), the ``(n,)`` group of each, their ``(n * 3,)``
        signal and the whitener, or None when no observation is kept.
    """
    if not (np.isfinite(model_error) and model_error >= 0):
        raise FitError(f"model_error must be >= 0 (relative), got {model_error!r}")
    g_all = np.asarray(group, dtype=np.int64).reshape(-1)
    if g_all.size != len(samples) or (g_all.size and g_all.min() < 0):
        raise FitError(f"group must give a group >= 0 for each of the {len(samples)} observations, "
                       f"got {g_all.size} values")
    keep = _grouped_subsample(samples, g_all, int(max_samples), seed)
    if keep.size == 0:
        return None
    fitted = samples.subset(keep)
    _, g = np.unique(g_all[keep], return_inverse=True)
    n = len(fitted)
    y = fitted.signal.reshape(-1)
    var = np.maximum(fitted.sigma, _SIGMA_FLOOR) ** 2 + (model_error * np.maximum(fitted.signal, 0.0)) ** 2
    sub = _grouped_subsample(fitted, np.zeros(n, dtype=np.int64), int(fit_samples), seed)
    few = fitted.subset(sub)
    y_few = few.signal.reshape(-1)
    full = [_basis(c, model, fitted.cos_d)[0] for c in (ALLOY, "urushi-black")]
    part = [dataclasses.replace(b, gloss_colours=b.gloss_colours[:, sub]) for b in full]
    w0 = Whitener.of(var[sub], np.zeros((len(sub), 3)))
    if robust:                               # as _whitened: the provisional lobe fitted robustly
        w0 = w0.scaled(np.sqrt(robust_weights(part, few, y_few, w0)))
    fits = [fit_candidate(b, few, w0(y_few), w0) for b in part]
    k = int(np.argmin([f.chi2 for f in fits]))
    w = Whitener.of(var, common_mode_of(full[k], fits[k], fitted, np.radians(normal_error_deg)))
    if not robust:
        return fitted, g_all[keep], y, w
    weights = np.ones(n)
    for _ in range(2):                       # as robust_weights: two reweighting passes
        ws = w.scaled(np.sqrt(weights)).take(sub)
        fits = [fit_candidate(b, few, ws(y_few), ws) for b in part]
        k = int(np.argmin([f.chi2 for f in fits]))
        x = _columns(full[k], _geometry(fitted, fits[k].roughness, full[k]),
                     np.pi * fitted.irradiance * fitted.cos_i)
        e = (w(y - x @ fits[k].amplitudes).reshape(n, 3) ** 2).mean(axis=1)
        weights = 1.0 / (1.0 + e / (CAUCHY_SCALE ** 2 * np.maximum(_group_median(e, g), 1e-12)))
        weights /= (np.bincount(g, weights=weights) / np.bincount(g))[g]
    return fitted, g_all[keep], y, w.scaled(np.sqrt(weights))


def highlight_colour_scatter(samples: RegionSamples, model_error: float = 0.02) -> float:
    """How many times their noise variance the colours of a region's highlight observations scatter.

    With one lamp and one camera every highlight of a material is seen at about the same angle
    between light and half vector, so its chromaticity ``(r, b) = (R, B) / (R + G + B)`` is the same
    in every view up to noise.  The spread about the median, against the noise of each observation
    (its sigma and ``model_error`` of the signal, propagated to first order), is a variance ratio
    ``median(z^2) / 0.455`` (0.455 is the median of a chi-square with one degree of freedom) averaged
    over ``r`` and ``b``.  Well above 1 it says the region's colours disagree among themselves: the
    false colour a demosaic gives a highlight narrower than the colour filter's cell, or materials
    mixed in the region.  Such errors do not average down over the observations (they repeat
    along an edge), so :func:`fit_region` weighs the region's evidence by its inverse (the Birge
    ratio: Birge, R. T. (1932). The calculation of errors by the method of least squares. Phys. Rev.
    40(2), 207-227. doi:10.1103/PhysRev.40.207).

    Parameters
    ----------
    samples
        The region's observations.
    model_error
        Relative error of the signal beyond its noise.

    Returns
    -------
    float
        The ratio, at least 1; 1 with fewer than :data:`MIN_HIGHLIGHTS` highlight observations.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> n = 400
    >>> sig = np.tile([0.5, 0.4, 0.3], (n, 1)) + rng.normal(0.0, 0.001, (n, 3))
    >>> s = RegionSamples(sig, np.full((n, 3), 0.001), *np.ones((5, n)), np.zeros(n, np.int64),
    ...                   np.zeros(n, np.int64), 0.0)
    >>> highlight_colour_scatter(s, 0.0) < 1.5                 # within the noise
    True
    >>> fringed = s.subset(np.arange(n))
    >>> fringed.signal[:, 0] *= 1.0 + rng.normal(0.0, 0.2, n)  # red +-20 %: a demosaic's false colour
    >>> highlight_colour_scatter(fringed, 0.0) > 100
    True
    """
    hl = samples.cos_h >= np.cos(np.radians(HIGHLIGHT_DEG))
    x = np.maximum(samples.signal[hl], 0.0)
    ok = x.sum(axis=1) > 0.0
    if int(ok.sum()) < MIN_HIGHLIGHTS:
        return 1.0
    from processing.appearance._surface_features import chromaticity, chromaticity_sd

    x = x[ok]
    var = np.maximum(samples.sigma[hl][ok], _SIGMA_FLOOR) ** 2 + (float(model_error) * x) ** 2
    rb = chromaticity(x, 0.0)
    z = (rb - np.median(rb, axis=0)) / chromaticity_sd(x, var)
    return max(1.0, float(np.mean(np.median(z * z, axis=0))) / 0.4549)


def fit_region(samples: RegionSamples, model: ForwardModel, *, candidates: Sequence[str] = SURFACE_CANDIDATES,
               model_error: float = 0.02, normal_error_deg: float = 0.5, independent: float = INDEPENDENT,
               max_samples: int = 20_000, seed: int = 0, robust: bool = True) -> RegionFit:
    """The region's material among ``candidates``, its parameters and an honest confidence.

    Parameters
    ----------
    samples
        The region's observations (:func:`region_samples`).
    model
        Camera and lamp (:class:`ForwardModel`).
    candidates
        Preset names and/or :data:`ALLOY` (at least two).
    model_error
        Relative model error added to every observation's noise: ``sigma^2 = sigma_obs^2 +
        (model_error * signal)^2``.
    normal_error_deg
        RMS error of the mesh normals: a common-mode (same in every channel) brightness error
        ``normal_error * d ln D / d theta_h`` of the gloss lobe is added to each observation's covariance.
    independent
        Observations counted as independent evidence (:data:`INDEPENDENT`): beyond it the errors of
        the normals, the colour calibration and the camera, which are shared across a region, stop
        averaging down, so the chi-squares given to ``decide`` are scaled by ``independent / n``, and
        further by the inverse of :func:`highlight_colour_scatter`.
    max_samples
        Largest number of observations fitted (all within 25 deg of the mirror direction are kept
        first, the rest sampled at random with ``seed``).
    seed
        Seed of that sampling.
    robust
        Weigh the observations by their Cauchy weights against a provisional fit
        (:func:`processing.materials._forward_fit_core.robust_weights`), so that a few observations
        of a neighbouring material or of geometry the mesh lacks do not pull the fit.

    Returns
    -------
    RegionFit

    Raises
    ------
    FitError
        Fewer than two candidates, an unknown candidate or a negative model error.
    """
    if len(candidates) < 2:
        raise FitError("candidates: give at least two materials to choose among")
    if not (np.isfinite(model_error) and model_error >= 0):
        raise FitError(f"model_error must be >= 0 (relative), got {model_error!r}")
    fitted = _subsample(samples, int(max_samples), seed)
    n_hl = int((fitted.cos_h >= np.cos(np.radians(HIGHLIGHT_DEG))).sum())
    early = _not_measured(samples, n_hl, len(fitted))
    if early is not None:
        return early
    # one BLAS thread: the products have an inner dimension of 1-9, and OpenBLAS's spinning threads made
    # the fit 4-5 times slower in CPU on a shared 2-core machine (measured on the demo session's largest region)
    with threadpool_limits(limits=1, user_api="blas"):
        fitted, y, w = _whitened(fitted, model, model_error, normal_error_deg, robust)
        bases = [_basis(c, model, fitted.cos_d) for c in candidates]
        fits = [fit_candidate(b, fitted, w(y), w) for b, _ in bases]
    from processing.materials._forward_fit_report import region_fit

    return region_fit(fits, [b for b, _ in bases], [n for _, n in bases], len(fitted), n_hl, independent,
                      highlight_colour_scatter(fitted, model_error))
