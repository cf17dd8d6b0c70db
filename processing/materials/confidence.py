"""From the candidates' misfits to one answer and a confidence that means what it says.

Every identification in kogei -- one image's region (:mod:`processing.materials.identification`)
or a region of the mesh fitted at its observations' true angles
(:mod:`processing.materials.forward_fit`) -- ends with the same question: given each candidate
material's chi-square ``chi2_i`` on its ``dof_i`` degrees of freedom after fitting its ``k_i`` free
parameters, which material is it, and how sure is that?  :func:`decide` answers it once:

1. **Parameters cost evidence.**  Candidates are compared by the Bayesian information criterion
   ``b_i = chi2_i + k_i ln n`` (n data values), so an alloy with free weights does not win over a
   named alloy merely by having more knobs (Schwarz 1978).
2. **A misfit widens the posterior.**  When even the best candidate misses the data by more than the
   stated noise (reduced chi-square ``s2 = chi2_best / dof_best > 1``), the noise was understated or
   the model is incomplete; the quasi-likelihood answer is to scale every chi-square by ``s2``
   (McCullagh & Nelder 1989, section 4.5, overdispersion), so a 30 000 chi-square no longer reads as
   certainty.  The posterior is ``p_i ~ exp(-(b_i - b_best) / (2 s2))`` (equal priors).
3. **No candidate fits.**  When ``s2`` exceeds :data:`MAX_MISFIT` the answer is
   :data:`NO_FIT` with the best candidates listed; its confidence is the tempered posterior of the
   best candidate, and it names no material.
4. **Indistinguishable candidates.**  Candidates within a likelihood ratio of :data:`AMBIGUOUS_LR` of
   the best form a group.  A group of neutral metals (silver, aluminium, tin, platinum, ... which
   differ mainly in brightness) is answered :data:`NEUTRAL_METAL` with the group's posterior; a
   mixed group answers the best candidate with its own (low) posterior and lists the others.

Whether the confidences are calibrated is measured, not assumed: ``bench/reliability.py`` draws
many simulated regions under varied cameras and noise and tabulates stated confidence against
observed accuracy (docs/BENCHMARKS.md, "Material confidence").

References
----------
.. [1] Schwarz, G. (1978). Estimating the dimension of a model. The Annals of Statistics 6(2),
   461-464. doi:10.1214/aos/1176344136
.. [2] McCullagh, P., Nelder, J. A. (1989). Generalized Linear Models, 2nd ed., Chapman & Hall,
   section 4.5 (over-dispersion). doi:10.1007/978-1-4899-3242-6
.. [3] Guo, C., Pleiss, G., Sun, Y., Weinberger, K. Q. (2017). On calibration of modern neural
   networks. ICML, PMLR 70, 1321-1330 (reliability diagrams, expected calibration error).
   doi:10.48550/arXiv.1706.04599
.. [4] Gelman, A., Carlin, J. B., Stern, H. S., Dunson, D. B., Vehtari, A., Rubin, D. B. (2013).
   Bayesian Data Analysis, 3rd ed., CRC Press, section 3.2 (normal data with unknown variance:
   the Student-t marginal). doi:10.1201/b16018

Examples
--------
>>> d = decide(["gold", "copper", "silver"], [3.1, 40.0, 900.0], [2, 2, 2], [1, 1, 1])
>>> d.answer, round(d.confidence, 3)
('gold', 1.0)
>>> d = decide(["gold", "copper"], [30_000.0, 31_000.0], [2, 2], [1, 1])     # nothing fits
>>> d.answer, d.group, d.confidence < 0.9
('no candidate fits', ('gold', 'copper'), True)
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.errors import InputError

__all__ = ["Decision", "decide", "NEUTRAL_METAL", "NO_FIT", "NOT_MEASURED", "MAX_MISFIT", "AMBIGUOUS_LR",
           "is_right", "reliability_table", "Reliability", "ConfidenceError", "SINGLE_IMAGE_ERROR_DOF"]

#: The answer when neutral metals cannot be told apart.
NEUTRAL_METAL = "neutral metal"
#: The answer when the best candidate misses the data by more than :data:`MAX_MISFIT`.
NO_FIT = "no candidate fits"
#: The answer for a region without the observations a fit needs.
NOT_MEASURED = "not measured"
#: Largest reduced chi-square (misfit in units of the stated noise variance) of an accepted answer: the best
#: candidate may miss by up to 5 times the stated error.  Measured (``bench/reliability.py``, 4000 simulated
#: single-image regions): answers whose misfit lay between 9 and 25 were right 76 % of the time at a stated
#: 75 % -- the tempered posterior stays calibrated there, so refusing them only lost answers; the colours no
#: candidate makes (a monochromatic green, a region of mixed materials) miss by far more.
MAX_MISFIT = 25.0
#: Degrees of freedom of the model error's own size for one image's identification (``decide(error_dof=...)``):
#: chosen by measurement (``bench/reliability.py``, 1000 regions / 600 clicked patches): expected calibration
#: error 0.045 / 0.039 at 8, against 0.051 / 0.038 at 4, 0.047 / 0.046 at 16 and 0.053 / 0.051 for the
#: Gaussian likelihood; right among answers stated >= 0.9: 98.0 / 94.7 % at 8, 96.9 / 90.0 % Gaussian.
SINGLE_IMAGE_ERROR_DOF = 8.0
#: Candidates within this likelihood ratio of the best are indistinguishable from it.
AMBIGUOUS_LR = 20.0
#: How many candidates a "no candidate fits" answer lists.
_LISTED = 3


class ConfidenceError(InputError):
    """The candidates' figures given to :func:`decide` are inconsistent; the message names the array."""


@dataclass(frozen=True)
class Decision:
    """An identification's answer and how sure it is.

    Attributes
    ----------
    answer
        A candidate name, :data:`NEUTRAL_METAL` or :data:`NO_FIT`.
    confidence
        Probability that ``answer`` is right (for :data:`NEUTRAL_METAL`: that the material is one of
        ``group``; for :data:`NO_FIT`: the tempered posterior of the best candidate).
    group
        The candidates the answer stands for: ``(answer,)``, the neutral metals, the contenders of a
        mixed group (best first), or the best few when nothing fits.
    best
        Index of the best candidate (lowest information criterion).
    posterior
        ``(m,)`` tempered posterior of every candidate, in the order given.
    misfit
        Reduced chi-square of the best candidate (1: fits to the stated noise).
    """

    answer: str
    confidence: float
    group: tuple[str, ...]
    best: int
    posterior: NDArray[np.float64]
    misfit: float

    @property
    def fits(self) -> bool:
        """True unless the answer is :data:`NO_FIT`."""
        return self.answer != NO_FIT


def _checked(name: str, values: ArrayLike, m: int) -> NDArray[np.float64]:
    a = np.asarray(values, dtype=np.float64).reshape(-1)
    if a.size != m or not np.all(np.isfinite(a)) or np.any(a < 0):
        raise ConfidenceError(f"{name} must hold {m} finite values >= 0 (one per candidate), got {a.size} values")
    return a


def decide(names: Sequence[str], chi2: ArrayLike, dof: ArrayLike, n_params: ArrayLike, *,
           neutral: ArrayLike | None = None, max_misfit: float = MAX_MISFIT,
           error_dof: float | None = None) -> Decision:
    """The answer and an honest confidence from every candidate's chi-square.

    Parameters
    ----------
    names
        Candidate names (at least two).
    chi2
        ``(m,)`` chi-square of each candidate after fitting its free parameters, with the noise
        and the model error in the weights.
    dof
        ``(m,)`` degrees of freedom (data values minus the candidate's free parameters), >= 1 for
        the best candidate.
    n_params
        ``(m,)`` free parameters of each candidate (the brightness counts).
    neutral
        ``(m,)`` True for neutral metals (their colour within 10 % of the light's); None: none is.
    max_misfit
        Largest reduced chi-square of an answer (:data:`MAX_MISFIT` for one image's three channels; a
        fit pooling hundreds of independent observations states its own, smaller one).
    error_dof
        None: the Gaussian likelihood ``exp(-chi2 / (2 s2))``.  A number ``nu``: the stated error's
        own size is uncertain, known as if from ``nu`` degrees of freedom (a scaled inverse
        chi-square prior on the error variance, centred on the stated one); integrating it out gives
        the Student-t likelihood ``(1 + chi2 / (nu s2))^(-(nu + dof) / 2)``, whose candidates differ
        by powers rather than exponentials of their misfits (Gelman et al. 2013, section 3.2).  For
        one image's three channels, where two degrees of freedom cannot estimate the error's size
        (:data:`SINGLE_IMAGE_ERROR_DOF`).

    Returns
    -------
    Decision

    Raises
    ------
    ConfidenceError
        Fewer than two candidates, arrays of the wrong length, or non-finite or negative values.

    References
    ----------
    .. [1] Schwarz (1978), doi:10.1214/aos/1176344136.
    .. [2] McCullagh & Nelder (1989), section 4.5, doi:10.1007/978-1-4899-3242-6.

    Examples
    --------
    >>> d = decide(["silver", "aluminium", "gold"], [2.0, 2.5, 500.0], [2, 2, 2], [1, 1, 1],
    ...            neutral=[True, True, False])
    >>> d.answer, d.group, round(d.confidence, 3)
    ('neutral metal', ('silver', 'aluminium'), 1.0)
    """
    m = len(names)
    if m < 2:
        raise ConfidenceError("an identification needs at least two candidate materials")
    c2, dofs, k = _checked("chi2", chi2, m), _checked("dof", dof, m), _checked("n_params", n_params, m)
    neu = np.zeros(m, dtype=bool) if neutral is None else np.asarray(neutral, dtype=bool).reshape(-1)
    if neu.size != m:
        raise ConfidenceError(f"neutral must hold {m} flags (one per candidate), got {neu.size}")
    n_data = np.maximum(dofs + k, 1.0)
    bic = c2 + k * np.log(n_data)
    best = int(np.argmin(bic))
    misfit = float(c2[best] / max(dofs[best], 1.0))
    s2 = max(1.0, misfit)
    if error_dof is None:
        delta = (bic - bic[best]) / (2.0 * s2)
    else:
        if not (isinstance(error_dof, (int, float, np.floating)) and 0 < float(error_dof) < math.inf):
            raise ConfidenceError(f"error_dof must be a number of degrees of freedom > 0, got {error_dof!r}")
        nu = float(error_dof)
        t = 0.5 * (nu + dofs) * np.log1p(c2 / (nu * s2)) + 0.5 * k * np.log(n_data)
        delta = t - t[best]
    post = np.exp(-np.minimum(delta, 700.0))
    post /= post.sum()
    order = [int(i) for i in np.argsort(delta, kind="stable")]
    if misfit > max_misfit:
        return Decision(NO_FIT, float(post[best]), tuple(names[i] for i in order[:_LISTED]), best, post, misfit)
    close = [i for i in order if delta[i] < math.log(AMBIGUOUS_LR)]
    if len(close) > 1 and all(neu[i] for i in close):
        return Decision(NEUTRAL_METAL, float(post[close].sum()), tuple(names[i] for i in close), best, post, misfit)
    return Decision(names[best], float(post[best]), tuple(names[i] for i in close), best, post, misfit)


def is_right(decision: Decision, truth: str) -> bool:
    """Whether an answer is right about the true material ``truth`` (a candidate name).

    A named material is right when it is the truth; :data:`NEUTRAL_METAL` when the truth is in its
    group; :data:`NO_FIT` names nothing and is never right (count it as an abstention).

    Parameters
    ----------
    decision
        The answer of :func:`decide`.
    truth
        The true material's candidate name.

    Returns
    -------
    bool
        True when the answer is right.

    Examples
    --------
    >>> d = decide(["silver", "aluminium", "gold"], [2.0, 2.5, 500.0], [2, 2, 2], [1, 1, 1],
    ...            neutral=[True, True, False])
    >>> is_right(d, "aluminium"), is_right(d, "gold")
    (True, False)
    """
    if decision.answer == NO_FIT:
        return False
    if decision.answer == NEUTRAL_METAL:
        return truth in decision.group
    return decision.answer == truth


@dataclass(frozen=True)
class Reliability:
    """Stated confidence against observed accuracy (a reliability diagram's numbers).

    Attributes
    ----------
    edges
        ``(B + 1,)`` bin edges of the stated confidence.
    count
        ``(B,)`` answers per bin.
    stated
        ``(B,)`` mean stated confidence per bin (NaN for an empty bin).
    observed
        ``(B,)`` share of right answers per bin (NaN for an empty bin).
    ece
        Expected calibration error: ``sum_b count_b / N * |observed_b - stated_b|``.
    high_accuracy
        Share right among answers stated at >= 0.9 (NaN when there are none).
    high_count
        Answers stated at >= 0.9.
    """

    edges: NDArray[np.float64]
    count: NDArray[np.int64]
    stated: NDArray[np.float64]
    observed: NDArray[np.float64]
    ece: float
    high_accuracy: float
    high_count: int


def reliability_table(confidence: ArrayLike, right: ArrayLike, bins: int = 10) -> Reliability:
    """Bin answers by stated confidence and compare with how often they were right.

    Parameters
    ----------
    confidence
        ``(N,)`` stated confidences in [0, 1] of answers that name a material (leave abstentions out).
    right
        ``(N,)`` whether each answer was right (:func:`is_right`).
    bins
        Equal-width bins over [0, 1].

    Returns
    -------
    Reliability

    References
    ----------
    .. [1] Guo et al. (2017), doi:10.48550/arXiv.1706.04599 (reliability diagram, ECE).

    Examples
    --------
    >>> r = reliability_table([0.95, 0.95, 0.45, 0.45], [True, True, True, False], bins=2)
    >>> r.count.tolist(), r.observed.tolist(), round(r.ece, 3), r.high_accuracy
    ([2, 2], [0.5, 1.0], 0.05, 1.0)
    """
    c = np.asarray(confidence, dtype=np.float64).reshape(-1)
    ok = np.asarray(right, dtype=bool).reshape(-1)
    if c.size != ok.size or c.size == 0 or not np.all((c >= 0) & (c <= 1)):
        raise ConfidenceError(f"confidence ({c.size}) and right ({ok.size}) must be equally long, non-empty, "
                              "with confidences in [0, 1]")
    if not (isinstance(bins, int) and bins >= 1):
        raise ConfidenceError(f"bins must be a positive integer, got {bins!r}")
    edges = np.linspace(0.0, 1.0, bins + 1)
    idx = np.clip(np.searchsorted(edges, c, side="right") - 1, 0, bins - 1)
    count = np.bincount(idx, minlength=bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        stated = np.bincount(idx, weights=c, minlength=bins) / count
        observed = np.bincount(idx, weights=ok.astype(np.float64), minlength=bins) / count
    filled = count > 0
    ece = float(np.sum(count[filled] / c.size * np.abs(observed[filled] - stated[filled])))
    high = c >= 0.9
    acc = float(ok[high].mean()) if high.any() else float("nan")
    return Reliability(edges, count.astype(np.int64), stated, observed, ece, acc, int(high.sum()))
