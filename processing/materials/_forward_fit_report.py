"""From the candidates' fits to a :class:`RegionFit` (private helper of :mod:`.forward_fit`).

The choice and confidence come from :func:`processing.materials.confidence.decide`; the answer's
parameters, 1-sigma uncertainties and a renderable material spec are read off its fit.

The named Ag/Cu/Au alloys (the shibuichi family, shakudo) differ only in their composition, a few
percentage points of silver apart, and the composition this instrument reads carries a systematic
error of that size (the camera's sensitivities, the mesh's normals: :data:`COMPOSITION_SD`).  Fitted
one by one at their nominal composition, the thousands of observations of a large region would pick
one of two neighbouring alloys with a confidence near 1 either way.  Instead each named alloy is
judged by the free alloy's fit: its composition ``w`` (Ag and Au) with covariance ``C`` (scaled like
the chi-squares) against the alloy's nominal ``w_i``, with ``COMPOSITION_SD^2`` added to each variance
of ``C`` (``C'``).  The systematic error is independent of the fit's statistics, so the two add: taken as
a floor under the variance instead, it vanished for a small region whose own statistics were already that
wide, and a region of 24 lit views through a camera model 10 nm off was named bronze at 0.97 against
its true nami-shibuichi-soto-sanbu (the bench's seed 7).  The
Gaussian likelihood of the composition integrated over the grade's spread (Laplace's approximation;
Bishop 2006, section 4.4) gives the named alloy the chi-square

    chi2_i = chi2_alloy + (w - w_i)^T C'^-1 (w - w_i) + ln det C' - ln det C

so neighbouring alloys within the systematic error share the posterior, and the answer says so.

References
----------
.. [1] Bishop, C. M. (2006). Pattern Recognition and Machine Learning, Springer, section 4.4 (the
   Laplace approximation). ISBN 978-0-387-31073-2
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from processing.materials._forward_fit_core import Basis, CandidateFit
from processing.materials.alloys import ALLOY_COMPOSITIONS
from processing.materials.confidence import NEUTRAL_METAL, NO_FIT, decide

__all__ = ["region_fit", "spec_of", "MAX_MISFIT_POOLED", "COMPOSITION_SD"]

#: Largest reduced chi-square of a region's answer.  A region pools hundreds of independent
#: observations (the scaled degrees of freedom are ~1000), so a model that misses them by more than
#: twice the stated noise and model error (reduced chi-square 4) does not fit: on the demo's scanned
#: mesh, whose normals are a median 2.6 degrees off the true surface, the head's best fit (a free
#: alloy, Ag 0.81) has 10-12 and is reported as "no candidate fits" instead of named at 1.00; with
#: the true normals the same observations fit nami-shibuichi (Ag 0.24) at 3.1.
MAX_MISFIT_POOLED = 4.0

#: Standard deviation (weight fraction) of the systematic error of a fitted Ag or Au share, added in
#: quadrature to the fit's own statistical error (the two are independent).  Measured: the
#: nami-shibuichi Ag share's median error is 1.9-3.8 points over simulated regions seen through a camera
#: model shifted by up to 10 nm (``bench/surface_fit_bench.py``, statistics included) and 3.2 points on
#: scanned meshes; on the demo's scanned hawk the head's true-nami vertices alone read Ag 0.280 +- 0.011
#: (truth 0.250).  A median total error of 2-3 points is a standard deviation of 3-4.5, of which the
#: statistics of a region of a few dozen lit views take 2-3: 2 points of systematic error remain.
COMPOSITION_SD = 0.02
_ALLOY_METALS = ("Ag", "Cu", "Au")
#: Named alloys made of Ag, Cu and Au only: their composition is reported from the free alloy's fit.
_AG_CU_AU = tuple(n for n, c in ALLOY_COMPOSITIONS.items() if set(c) <= set(_ALLOY_METALS))


def _nearest_alloy(weights: NDArray[np.float64]) -> str:
    """The named Ag/Cu/Au alloy nearest (L1) to ``weights`` (Ag, Cu, Au)."""
    def dist(name: str) -> float:
        c = ALLOY_COMPOSITIONS[name]
        return float(sum(abs(weights[i] - c.get(m, 0.0) / 100.0) for i, m in enumerate(_ALLOY_METALS)))
    return min(_AG_CU_AU, key=dist)


def _fmt(v: float) -> str:
    return f"{v:.4g}"


def _alloy_values(fit: CandidateFit) -> tuple[dict[str, float], dict[str, float]]:
    """Composition (sum 1), gloss and roughness of the free alloy fit, with propagated 1-sigma."""
    vals, cov = _alloy_covariance(fit)
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    names = (*_ALLOY_METALS, "gloss", "roughness")
    return dict(zip(names, map(float, vals))), dict(zip(names, map(float, sd)))


def _alloy_covariance(fit: CandidateFit) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(Ag, Cu, Au, gloss, roughness)`` of the free alloy fit and their ``(5, 5)`` covariance."""
    a = fit.amplitudes
    total = float(a.sum())
    w = a / total if total > 0 else np.full(3, 1 / 3)
    jac = np.zeros((4, 4))                            # (Ag, Cu, Au, gloss, [roughness]) from (a_Ag, a_Cu, a_Au, r)
    if total > 0:
        jac[:3, :3] = (np.eye(3) - w[:, None]) / total
    jac[3, :3] = 1.0
    full = np.zeros((5, 4))
    full[:4], full[4, 3] = jac, 1.0
    cov = full @ fit.covariance @ full.T
    return np.array([*w, total, fit.roughness]), cov


def _composition_chi2(names: Sequence[str], fits: Sequence[CandidateFit], chi2: NDArray[np.float64],
                      f_ind: float) -> NDArray[np.float64]:
    """Scaled chi-squares with every named Ag/Cu/Au alloy judged by the free alloy's composition.

    ``chi2`` holds the candidates' chi-squares already scaled by ``f_ind``; the free alloy's
    composition covariance is scaled by ``1 / f_ind`` to match.  Without a free alloy among the
    candidates ``chi2`` is returned as it is.
    """
    if "alloy" not in names:
        return chi2
    a = list(names).index("alloy")
    vals, cov = _alloy_covariance(fits[a])
    pick = [0, 2]                                      # Ag and Au; Cu is the rest
    w = vals[pick]
    c = cov[np.ix_(pick, pick)] / f_ind + np.diag([1e-8, 1e-8])
    total = c + np.diag([COMPOSITION_SD ** 2] * 2)     # the systematic error adds to the statistical
    if not (np.all(np.isfinite(total)) and np.all(np.isfinite(w))):
        return chi2
    inv = np.linalg.inv(total)
    occam = float(np.linalg.slogdet(total)[1] - np.linalg.slogdet(c)[1])
    out = chi2.copy()
    for i, n in enumerate(names):
        if n in _AG_CU_AU:
            comp = ALLOY_COMPOSITIONS[n]
            d = w - np.array([comp.get("Ag", 0.0), comp.get("Au", 0.0)]) / 100.0
            out[i] = chi2[a] + float(d @ inv @ d) + occam
    return out


def _values(fit: CandidateFit, basis: Basis) -> tuple[dict[str, float], dict[str, float]]:
    """The fit's named parameters and 1-sigma uncertainties (mirror from the preset's mirror:gloss ratio)."""
    if len(basis.gloss_colours) == 3:
        p, u = _alloy_values(fit)
    else:
        sd = np.sqrt(np.clip(np.diag(fit.covariance), 0, None))
        p, u = {"gloss": float(fit.amplitudes[0]), "roughness": fit.roughness}, {"gloss": float(sd[0]),
                                                                                 "roughness": float(sd[-1])}
        if basis.diffuse_colour is not None:
            p["diffuse"], u["diffuse"] = float(fit.amplitudes[1]), float(sd[1])
    p["mirror"], u["mirror"] = p["gloss"] * basis.mirror_ratio, u["gloss"] * basis.mirror_ratio
    return p, u


def spec_of(name: str, p: dict[str, float]) -> str:
    """A :func:`get_material` spec of preset ``name`` with the fitted parameters ``p``.

    The lobe weights are scaled down together when their sum exceeds 1 (energy conservation).

    Parameters
    ----------
    name
        A preset name.
    p
        Fitted parameters (gloss, mirror, roughness, optional diffuse and Ag/Cu/Au).

    Returns
    -------
    str
    """
    keys = [k for k in ("diffuse", "gloss", "mirror") if k in p]
    total = sum(p[k] for k in keys)
    scale = 1.0 / total if total > 1.0 else 1.0
    parts = [f"{m}={_fmt(p[m])}" for m in _ALLOY_METALS if m in p]
    parts.append(f"roughness={_fmt(min(max(p['roughness'], 1e-4), 1.0))}")
    parts += [f"{k}={_fmt(np.floor(p[k] * scale * 1e4) / 1e4)}" for k in keys]
    return f"{name}:" + ",".join(parts)


def _answer_fit(names: Sequence[str], d, fits, bases) -> tuple[str, int]:
    """Preset name to build the spec from, and the index of the fit whose parameters are reported."""
    best = d.best
    alloy = [i for i, n in enumerate(names) if n == "alloy"]
    if names[best] == "alloy":
        w = fits[best].amplitudes / max(float(fits[best].amplitudes.sum()), 1e-12)
        return _nearest_alloy(w), best
    if names[best] in _AG_CU_AU and alloy:
        return names[best], alloy[0]
    return names[best], best


def region_fit(fits: Sequence[CandidateFit], bases: Sequence[Basis], neutral: Sequence[bool], n_obs: int, n_lit: int,
               independent: float, colour_scatter: float = 1.0):
    """The :class:`RegionFit` of the candidates' fits.

    Parameters
    ----------
    fits, bases
        Each candidate's fit and linear structure, in the same order.
    neutral
        Whether each candidate is a neutral metal.
    n_obs, n_lit
        Observations fitted and highlight observations among them.
    independent
        Observations counted as independent evidence: chi-squares and degrees of freedom are scaled by
        ``min(1, independent / n_obs)`` before :func:`decide`, uncertainties by its inverse square root.
    colour_scatter
        How many times their noise variance the highlights' colours scatter
        (:func:`processing.materials.forward_fit.highlight_colour_scatter`, >= 1): the scale above is
        divided by it, so colours that disagree beyond their noise weigh as little as they deserve.

    Returns
    -------
    RegionFit
    """
    from processing.materials.forward_fit import RegionFit

    names = [f.name for f in fits]
    scatter = max(float(colour_scatter), 1.0)
    f_ind = min(1.0, float(independent) / max(n_obs, 1)) / scatter
    chi2 = _composition_chi2(names, fits, np.array([f.chi2 * f_ind for f in fits]), f_ind)
    d = decide(names, chi2, [max(f.dof * f_ind, 1.0) for f in fits],
               [f.n_params for f in fits], neutral=neutral, max_misfit=MAX_MISFIT_POOLED)
    base, i = _answer_fit(names, d, fits, bases)
    p, u = _values(fits[i], bases[i])
    u = {k: v / np.sqrt(f_ind) for k, v in u.items()}
    for m in _ALLOY_METALS:                            # the composition's systematic error, in quadrature
        if m in u:
            u[m] = float(np.hypot(u[m], COMPOSITION_SD))
    material = d.answer if d.answer in (NEUTRAL_METAL, NO_FIT, "alloy") else base
    cands = tuple({"name": n, "chi2": float(f.chi2), "dof": int(f.dof), "posterior": float(q)}
                  for n, f, q in zip(names, fits, d.posterior))
    return RegionFit(material, float(d.confidence), tuple(d.group), spec_of(base, p), p, u,
                     float(fits[d.best].chi2 / fits[d.best].dof), n_obs, n_lit, cands, "", scatter)
