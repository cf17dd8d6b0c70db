"""From the candidates' fits to a :class:`RegionFit` (private helper of :mod:`.forward_fit`).

The choice and confidence come from :func:`processing.materials.confidence.decide`; the answer's
parameters, 1-sigma uncertainties and a renderable material spec are read off its fit.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from processing.materials._forward_fit_core import Basis, CandidateFit
from processing.materials.alloys import ALLOY_COMPOSITIONS
from processing.materials.confidence import NEUTRAL_METAL, NO_FIT, decide

__all__ = ["region_fit", "spec_of", "MAX_MISFIT_POOLED"]

#: Largest reduced chi-square of a region's answer.  A region pools hundreds of independent
#: observations (the scaled degrees of freedom are ~1000), so a model that misses them by more than
#: twice the stated noise and model error (reduced chi-square 4) does not fit: on the demo's scanned
#: mesh, whose normals are a median 2.6 degrees off the true surface, the head's best fit (a free
#: alloy, Ag 0.81) has 10-12 and is reported as "no candidate fits" instead of named at 1.00; with
#: the true normals the same observations fit nami-shibuichi (Ag 0.24) at 3.1.
MAX_MISFIT_POOLED = 4.0

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
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    names = (*_ALLOY_METALS, "gloss", "roughness")
    vals = (*w, total, fit.roughness)
    return dict(zip(names, map(float, vals))), dict(zip(names, map(float, sd)))


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
               independent: float):
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

    Returns
    -------
    RegionFit
    """
    from processing.materials.forward_fit import RegionFit

    names = [f.name for f in fits]
    f_ind = min(1.0, float(independent) / max(n_obs, 1))
    d = decide(names, [f.chi2 * f_ind for f in fits], [max(f.dof * f_ind, 1.0) for f in fits],
               [f.n_params for f in fits], neutral=neutral, max_misfit=MAX_MISFIT_POOLED)
    base, i = _answer_fit(names, d, fits, bases)
    p, u = _values(fits[i], bases[i])
    u = {k: v / np.sqrt(f_ind) for k, v in u.items()}
    material = d.answer if d.answer in (NEUTRAL_METAL, NO_FIT, "alloy") else base
    cands = tuple({"name": n, "chi2": float(f.chi2), "dof": int(f.dof), "posterior": float(q)}
                  for n, f, q in zip(names, fits, d.posterior))
    return RegionFit(material, float(d.confidence), tuple(d.group), spec_of(base, p), p, u,
                     float(fits[d.best].chi2 / fits[d.best].dof), n_obs, n_lit, cands, "")
