"""Per-candidate fits of the forward model (private helper of :mod:`.forward_fit`).

Every candidate's prediction is linear in its lobe amplitudes at a fixed roughness, so the
amplitudes come from non-negative least squares (NNLS) and the roughness from a bounded 1-D
search over the resulting chi-square.  The spectral factors enter through tables of their
camera-integrated colour over ``cos_d`` (exact up to the table's linear interpolation).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize_scalar, nnls

from processing.materials.microfacet import SmithLobe

__all__ = ["Basis", "CandidateFit", "Whitener", "fit_candidate", "ROUGHNESS_RANGE", "MIRROR_EXCLUDE_DEG",
           "common_mode_error", "common_mode_of", "robust_weights", "CAUCHY_SCALE"]

#: Search range of the gloss lobe's Beckmann RMS slope.
ROUGHNESS_RANGE = (0.02, 0.8)
#: Observations closer than this to the mirror direction are not fitted (the mirror spike there
#: depends on normal errors far below a scanned mesh's accuracy, and is usually clipped).
MIRROR_EXCLUDE_DEG = 5.0
#: Whether a vertex's facet angle (its normal against its triangles') counts as a normal error.  Off:
#: an object is smooth and a scanned mesh samples it finely; the term only modelled flat-shaded renders.
USE_FACETS = False
_GRID = np.geomspace(ROUGHNESS_RANGE[0], ROUGHNESS_RANGE[1], 18)
#: Scale of the Cauchy weights in units of the median observation's misfit: an observation missed by
#: 3 times the typical residual counts half.
CAUCHY_SCALE = 3.0


@dataclass(frozen=True)
class Basis:
    """One candidate's linear structure.

    Attributes
    ----------
    name
        Candidate name.
    gloss_colours
        ``(m, n, 3)`` camera colour of the specular factor of each gloss amplitude at the samples' cos_d.
    diffuse_colour
        ``(3,)`` camera colour of the Lambert lobe's pigment, or None (metals).
    mirror_ratio
        Preset mirror:gloss weight ratio (the mirror lobe rides on the gloss amplitude).
    mirror_roughness
        RMS slope of the mirror lobe.
    """

    name: str
    gloss_colours: NDArray[np.float64]
    diffuse_colour: NDArray[np.float64] | None
    mirror_ratio: float
    mirror_roughness: float

    @property
    def n_params(self) -> int:
        """Free parameters: the amplitudes and the roughness."""
        return len(self.gloss_colours) + (self.diffuse_colour is not None) + 1


@dataclass(frozen=True)
class CandidateFit:
    """A candidate's best fit.

    Attributes
    ----------
    name
        Candidate name.
    amplitudes
        Gloss amplitudes, then the diffuse amplitude (lamp scale k included).
    roughness
        Gloss lobe's Beckmann RMS slope.
    chi2, dof, n_params
        Chi-square, degrees of freedom and free parameters.
    covariance
        Of (amplitudes..., roughness), scaled by max(1, reduced chi2).
    """

    name: str
    amplitudes: NDArray[np.float64]
    roughness: float
    chi2: float
    dof: int
    n_params: int
    covariance: NDArray[np.float64]


@dataclass(frozen=True)
class Whitener:
    """Per observation ``C^(-1/2)`` of ``C = diag(d) + u u^T`` (a rank-1 update's square root).

    ``d`` is the independent channel noise, ``u`` a common-mode (achromatic) brightness error.

    Attributes
    ----------
    inv_sd
        ``(n, 3)`` ``1 / sqrt(d)``.
    v
        ``(n, 3)`` unit direction of ``u / sqrt(d)`` (0 where ``u`` is 0).
    beta
        ``(n,)`` ``1 - 1 / sqrt(1 + |u / sqrt(d)|^2)``.
    """

    inv_sd: NDArray[np.float64]
    v: NDArray[np.float64]
    beta: NDArray[np.float64]

    @classmethod
    def of(cls, var: NDArray[np.float64], common: NDArray[np.float64]) -> Whitener:
        """From ``(n, 3)`` channel variances and ``(n, 3)`` common-mode error vectors."""
        inv = 1.0 / np.sqrt(np.maximum(var, 1e-12))
        a = common * inv
        norm = np.linalg.norm(a, axis=1)
        v = a / np.maximum(norm, 1e-300)[:, None]
        return cls(inv, v, 1.0 - 1.0 / np.sqrt(1.0 + norm ** 2))

    def scaled(self, s: NDArray[np.float64]) -> Whitener:
        """The same whitening with observation ``i`` weighted by ``s[i]`` (its whitened values times ``s``)."""
        return Whitener(self.inv_sd * s[:, None], self.v, self.beta)

    def take(self, idx: NDArray[np.int64]) -> Whitener:
        """The whitening of observations ``idx`` alone (each observation is whitened on its own)."""
        return Whitener(self.inv_sd[idx], self.v[idx], self.beta[idx])

    def __call__(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Whiten ``(n * 3,)`` or ``(n * 3, p)`` flattened values."""
        n = len(self.beta)
        z = x.reshape(n, 3, -1) * self.inv_sd[:, :, None]
        proj = np.einsum("nc,ncp->np", self.v, z)
        z = z - (self.beta[:, None] * proj)[:, None, :] * self.v[:, :, None]
        return z.reshape(x.shape)


def _columns(basis: Basis, geo: NDArray[np.float64], shade: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(n * 3, p)`` unweighted design columns at one roughness."""
    cols = [(geo[:, None] * c).reshape(-1) for c in basis.gloss_colours]
    if basis.diffuse_colour is not None:
        cols.append((shade[:, None] * basis.diffuse_colour[None, :] / np.pi).reshape(-1))
    return np.stack(cols, axis=1)


_CACHE: dict[float, NDArray[np.float64]] = {}
#: The samples the cache belongs to (held, so no other object can match them), their roughness-free lobe
#: terms and their ``pi * irr * cos_i``.
_OWNER: list = [None, None, None]


def _lobe(samples, roughness: float) -> NDArray[np.float64]:
    """``pi * irr * cos_i * D G / (4 cos_i cos_o)``, cached for the samples last fitted."""
    if _OWNER[0] is not samples or len(_CACHE) > 256:
        _CACHE.clear()
        s = samples
        _OWNER[:] = [s, SmithLobe(s.cos_i, s.cos_o, s.cos_h), np.pi * s.irradiance * s.cos_i]
    key = float(roughness)
    if key not in _CACHE:
        _CACHE[key] = _OWNER[2] * _OWNER[1](roughness)
    return _CACHE[key]


def _geometry(samples, roughness: float, basis: Basis) -> NDArray[np.float64]:
    """``pi * irr * cos_i *`` (gloss + ratio * mirror) geometric factor."""
    g = _lobe(samples, roughness)
    if basis.mirror_ratio > 0:
        g = g + basis.mirror_ratio * _lobe(samples, basis.mirror_roughness)
    return g


def _solve(basis: Basis, samples, roughness: float, y: NDArray[np.float64],
           w: Whitener) -> tuple[float, NDArray[np.float64], NDArray[np.float64]]:
    shade = np.pi * samples.irradiance * samples.cos_i
    x = _columns(basis, _geometry(samples, roughness, basis), shade)
    a, chi2 = _small_nnls(w(x), y)
    return chi2, a, x


def _small_nnls(x: NDArray[np.float64], y: NDArray[np.float64]) -> tuple[NDArray[np.float64], float]:
    """NNLS through the p x p normal equations (Cholesky factor), with the full residual sum of squares."""
    return _normal_nnls(np.einsum("ij,ik->jk", x, x), np.einsum("ij,i->j", x, y), float(y @ y))


def _normal_nnls(g: NDArray[np.float64], b: NDArray[np.float64], yy: float) -> tuple[NDArray[np.float64], float]:
    """NNLS from the normal equations ``g = X^T X``, ``b = X^T y`` and ``yy = y^T y`` (Cholesky factor)."""
    p = len(b)
    scale = np.sqrt(np.maximum(np.diag(g), 1e-300))
    gs = g / np.outer(scale, scale) + 1e-12 * np.eye(p)
    r = np.linalg.cholesky(gs).T
    q = np.linalg.solve(r.T, b / scale)
    a_s, rnorm = nnls(r, q)
    chi2 = float(yy - q @ q + rnorm ** 2)
    return a_s / scale, max(chi2, 0.0)


class _NormalEquations:
    """A candidate's whitened normal equations as functions of the geometric factor alone.

    Every gloss column is ``geo * colour`` with ``geo`` one number per observation and the whitening
    per observation and linear, so ``w(geo * colour) = geo * w(colour)``: the per-observation products
    of the whitened colours (and of the diffuse column, which does not depend on the roughness) are
    formed once, and each roughness of the search costs two matrix-vector products over the
    observations instead of building, whitening and multiplying the ``(3 n, p)`` design matrix.
    """

    def __init__(self, basis: Basis, samples, y: NDArray[np.float64], w: Whitener) -> None:
        n, m = len(samples), len(basis.gloss_colours)
        cw = np.stack([w(c.reshape(-1)).reshape(n, 3) for c in basis.gloss_colours], axis=2)
        yw = y.reshape(n, 3)
        self.m, self.yy = m, float(y @ y)
        self.pgg = np.einsum("ncj,nck->njk", cw, cw).reshape(n, m * m)
        self.qg = np.einsum("ncj,nc->nj", cw, yw)
        self.diffuse = basis.diffuse_colour is not None
        if self.diffuse:
            shade = np.pi * samples.irradiance * samples.cos_i
            dw = w((shade[:, None] * basis.diffuse_colour[None, :] / np.pi).reshape(-1)).reshape(n, 3)
            self.pgd = np.einsum("ncj,nc->nj", cw, dw)
            self.gdd, self.bd = float(np.einsum("nc,nc->", dw, dw)), float(np.einsum("nc,nc->", dw, yw))

    def solve(self, geo: NDArray[np.float64]) -> tuple[NDArray[np.float64], float]:
        """Amplitudes and chi-square at the observations' geometric factor ``geo`` (``(n,)``)."""
        m = self.m
        g_gg, b_g = ((geo * geo) @ self.pgg).reshape(m, m), geo @ self.qg
        if not self.diffuse:
            return _normal_nnls(g_gg, b_g, self.yy)
        g = np.empty((m + 1, m + 1))
        g[:m, :m], g[m, m] = g_gg, self.gdd
        g[:m, m] = g[m, :m] = geo @ self.pgd
        return _normal_nnls(g, np.append(b_g, self.bd), self.yy)


def fit_candidate(basis: Basis, samples, y: NDArray[np.float64], w: Whitener) -> CandidateFit:
    """Best amplitudes and roughness of one candidate, with the parameters' covariance.

    Parameters
    ----------
    basis
        The candidate's linear structure at the samples.
    samples
        :class:`RegionSamples` (the fitted ones).
    y
        ``(n * 3,)`` whitened signal (``w(signal)``).
    w
        The observations' :class:`Whitener`.

    Returns
    -------
    CandidateFit
        Covariance of (amplitudes..., roughness) from the Jacobian, scaled by max(1, reduced chi2).
    """
    normal = _NormalEquations(basis, samples, y, w)

    def cost(log_r: float) -> float:
        return normal.solve(_geometry(samples, float(np.exp(log_r)), basis))[1]

    grid = [cost(float(np.log(r))) for r in _GRID]
    j = int(np.argmin(grid))
    lo, hi = np.log(_GRID[max(j - 1, 0)]), np.log(_GRID[min(j + 1, len(_GRID) - 1)])
    res = minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": 2e-3})
    r = float(np.exp(res.x)) if res.fun <= grid[j] else float(_GRID[j])
    chi2, a, x = _solve(basis, samples, r, y, w)
    dof = max(len(y) - basis.n_params, 1)
    step = 1e-3 * r
    x_hi = _columns(basis, _geometry(samples, r + step, basis), np.zeros(len(samples)))
    x_lo = _columns(basis, _geometry(samples, r - step, basis), np.zeros(len(samples)))
    d_r = (x_hi - x_lo) @ a / (2 * step)
    jac = w(np.concatenate([x, d_r[:, None]], axis=1))
    cov = np.linalg.pinv(jac.T @ jac) * max(1.0, chi2 / dof)
    return CandidateFit(basis.name, a, r, chi2, dof, basis.n_params, cov)


def common_mode_error(provisional: Sequence[Basis], samples, y: NDArray[np.float64], var: NDArray[np.float64],
                      normal_error_rad: float, weights: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """``(n, 3)`` achromatic error of each prediction from a normal error of ``normal_error_rad``.

    A normal off by ``delta`` moves the gloss lobe by ``delta * d ln D / d theta_h`` (Beckmann:
    ``2 tan / (s^2 cos^2) - 4 tan``) and the diffuse lobe by ``delta * tan theta_i``, in every channel alike.  The lobe's roughness ``s`` and its share of the
    signal come from the best of the ``provisional`` candidates fitted with channel noise only.

    Parameters
    ----------
    provisional
        Candidates for the provisional fit (a metal and a lacquer).
    samples
        The fitted samples.
    y
        ``(n * 3,)`` signal.
    var
        ``(n, 3)`` channel variances.
    normal_error_rad
        RMS error of the mesh normals; the samples' ``facet_rad`` (when known) is added in quadrature.
    weights
        Optional ``(n,)`` weights of the observations in the provisional fit (:func:`robust_weights`
        against the channel noise).  A few dark observations where the lobe predicts light (another
        material's vertices, a shadow the mesh misses) carry the noise of a dark pixel: fitted by
        plain squares they widen the provisional lobe (on a simulated hawk's head from 0.153 to
        0.16-0.18), the error given to every highlight follows the wrong lobe, and the alloy's
        composition moves with it (Ag 2.5 points).

    Returns
    -------
    ndarray
        ``(n, 3)``.
    """
    n = len(samples)
    w = Whitener.of(var, np.zeros((n, 3)))
    if weights is not None:
        w = w.scaled(np.sqrt(np.asarray(weights, dtype=np.float64)))
    fits = [fit_candidate(b, samples, w(y), w) for b in provisional]
    k = int(np.argmin([f.chi2 for f in fits]))
    return common_mode_of(provisional[k], fits[k], samples, normal_error_rad)


def common_mode_of(b: Basis, f: CandidateFit, samples, normal_error_rad: float) -> NDArray[np.float64]:
    """``(n, 3)`` achromatic error of :func:`common_mode_error` for a given provisional fit ``f`` of ``b``.

    Parameters
    ----------
    b
        The provisional candidate's basis at the samples.
    f
        Its fit (roughness and amplitudes; they may come from other samples of the same surface).
    samples
        The samples the error is wanted at.
    normal_error_rad
        RMS error of the mesh normals.

    Returns
    -------
    ndarray
        ``(n, 3)``.
    """
    n = len(samples)
    geo = _geometry(samples, f.roughness, b)
    x = _columns(b, geo, np.pi * samples.irradiance * samples.cos_i).reshape(n, 3, -1)
    m = len(b.gloss_colours)
    spec = x[:, :, :m] @ f.amplitudes[:m]
    diffuse = x[:, :, m:] @ f.amplitudes[m:]
    t = np.sqrt(np.maximum(1.0 - samples.cos_h ** 2, 0.0)) / np.maximum(samples.cos_h, 1e-6)
    slope = np.abs(2.0 * t / (f.roughness ** 2 * np.maximum(samples.cos_h, 1e-6) ** 2) - 4.0 * t)
    t_i = np.sqrt(np.maximum(1.0 - samples.cos_i ** 2, 0.0)) / np.maximum(samples.cos_i, 1e-6)
    facet = 0.0 if samples.facet_rad is None or not USE_FACETS else samples.facet_rad
    delta = np.sqrt(normal_error_rad ** 2 + facet ** 2)[..., None] if np.ndim(facet) else normal_error_rad
    return delta * (slope[:, None] * np.abs(spec) + np.minimum(t_i, 10.0)[:, None] * np.abs(diffuse))


def robust_weights(provisional: Sequence[Basis], samples, y: NDArray[np.float64], w: Whitener,
                   iterations: int = 2) -> NDArray[np.float64]:
    """``(n,)`` Cauchy weights of the observations against the best provisional fit (IRLS).

    A region's observations include a few from its neighbours (segmentation is never exact at a
    boundary) and a few the model cannot follow (a highlight on a crease the mesh rounds off); by
    squares they pull every candidate's fit.  Each observation's whitened residual ``r`` (three
    channels) under the best of the ``provisional`` candidates gets the weight
    ``1 / (1 + |r|^2 / (3 c^2 m))`` with ``m`` the median of ``|r|^2 / 3`` and ``c`` :data:`CAUCHY_SCALE`
    (a robust scale, so a region all of whose observations miss keeps its misfit); the provisional
    fit is repeated with the weights ``iterations`` times.  The weights are normalised to a mean of 1:
    they move trust from the outliers to the rest, and a region that no candidate fits keeps its
    misfit.

    Parameters
    ----------
    provisional
        Candidates of the provisional fit (a metal and a lacquer).
    samples
        The fitted samples.
    y
        ``(n * 3,)`` signal (not whitened).
    w
        The observations' :class:`Whitener`.
    iterations
        Reweighting passes (>= 1).

    Returns
    -------
    ndarray
        ``(n,)`` weights, mean 1.

    References
    ----------
    .. [1] Holland, P. W., Welsch, R. E. (1977). Robust regression using iteratively reweighted
       least-squares. Communications in Statistics - Theory and Methods 6(9), 813-827.
       doi:10.1080/03610927708827533
    """
    n = len(samples)
    weights = np.ones(n)
    for _ in range(max(int(iterations), 1)):
        ws = w.scaled(np.sqrt(weights))
        fits = [fit_candidate(b, samples, ws(y), ws) for b in provisional]
        k = int(np.argmin([f.chi2 for f in fits]))
        x = _columns(provisional[k], _geometry(samples, fits[k].roughness, provisional[k]),
                     np.pi * samples.irradiance * samples.cos_i)
        e = (w(y - x @ fits[k].amplitudes).reshape(n, 3) ** 2).mean(axis=1)
        scale = CAUCHY_SCALE ** 2 * max(float(np.median(e)), 1e-12)
        weights = 1.0 / (1.0 + e / scale)
        weights /= weights.mean()
    return weights
