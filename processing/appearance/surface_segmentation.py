"""Regions of one material on the scanned surface, from every view of every vertex.

A metal is dark away from its highlights and a black lacquer is dark except in
its highlight, so one photo cannot tell materials apart: :func:`vertex_features`
summarises *all* the observations of a vertex in a few numbers that a material
fixes and the geometry does not (docs/appearance.md, "Regions of one material
on the surface"):

* ``body_asinh`` and ``body_r``, ``body_b``: the level and chromaticity of the
  median signal / (cos_i * irradiance) of the lit observations away from the
  highlight (half angle > ``body_half_deg``) -- the diffuse albedo; the level as
  ``asinh(level / 1e-3)``, linear near black (where a metal and a black lacquer
  differ by a few noise standard deviations, which the mixture takes into account
  per vertex) and logarithmic above;
* ``colour_r``, ``colour_b``: chromaticity of the sum of the unclipped lit
  signals less the body (``cos_i * body``) where that excess is 4 times the
  body's part; the brightest views dominate it -- the colour of the specular
  reflection (a metal's colour, a dielectric's lamp-white) even where only the
  tail of the lobe was seen;
* ``spec_r``, ``spec_b``: chromaticity of the brightest unclipped observation near
  the mirror direction (half angle < ``spec_half_deg``) less the body, where
  that excess is 4 times the body under it;
* ``peak_log``: log10 of the largest lit signal / irradiance less the body
  (clipped ones included): the highlight's strength (reported, not clustered on:
  how close a view came to the mirror direction depends on the geometry).

A feature is NaN where it is not measured: no lit observation, or a signal
below ``5`` noise standard deviations (a chromaticity of noise is no colour).
Every feature carries its noise standard deviation (first-order propagation of
the observations' sigma), which the mixture adds to a component's variance: a
faint highlight's colour is weak evidence, a bright one strong; each view's
channels also carry a 3 % error beyond the noise (demosaicing a highlight a few
pixels wide), so no colour is known better than ~1 %.

:func:`segment_surface` clusters these features with a diagonal Gaussian
mixture that marginalises missing features (EM, Dempster et al. 1977, started
from k-means++ and from a greedy split of the k-1 fit, Verbeek et al. 2003; the
number of components by BIC, Schwarz 1978), merges components closer than a
Bhattacharyya distance, labels the vertices whose colour decides it (with a
neighbour of the same label; a label needs 8 such seeds, the body level judged
on its linear scale keeps metals and black lacquers apart), gives every other vertex the label of the
geodesically nearest such vertex that its own features allow, relaxes a Potts
model on the mesh's edge graph by iterated conditional modes (Besag 1986), and
merges regions smaller than ``min_region_share`` of the measured area into the
neighbour they share most edges with.  A camera's lens spreads each point over
about a photosite, so along the edge between two materials every view sees a
mix of both: where such a band comes out as a region of its own -- every
vertex within ``BAND_PX`` photo pixels (on the surface, from the frames'
cameras) of both of the two regions it borders, its mean features between
theirs -- it is their shared edge, not a material, and each of its vertices
joins the geodesically nearer of the two (with ``frames`` only).  Vertices
without a lit observation are -1 ("not measured").

References
----------
Besag, J. (1986). On the statistical analysis of dirty pictures. J. R. Stat.
Soc. B 48(3), 259-302. doi:10.1111/j.2517-6161.1986.tb01412.x

Dempster, A. P., Laird, N. M., Rubin, D. B. (1977). Maximum likelihood from
incomplete data via the EM algorithm. J. R. Stat. Soc. B 39(1), 1-22.
doi:10.1111/j.2517-6161.1977.tb01600.x

Schwarz, G. (1978). Estimating the dimension of a model. Ann. Statist. 6(2),
461-464. doi:10.1214/aos/1176344136

Verbeek, J. J., Vlassis, N., Kröse, B. (2003). Efficient greedy learning of
Gaussian mixture models. Neural Computation 15(2), 469-485.
doi:10.1162/089976603762553004

Lensch, H. P. A., Kautz, J., Goesele, M., Heidrich, W., Seidel, H.-P. (2003).
Image-based reconstruction of spatial appearance and geometric detail. ACM
TOG 22(2), 234-257. doi:10.1145/636886.636891
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.appearance import _surface_features as sf
from processing.errors import InputError

__all__ = ["SegmentationError", "SurfaceSegmentation", "VertexFeatures", "vertex_features", "segment_surface",
           "FEATURE_NAMES"]

#: Names of the columns of :attr:`VertexFeatures.values`.
FEATURE_NAMES = ("body_asinh", "body_r", "body_b", "colour_r", "colour_b", "spec_r", "spec_b", "peak_log")
_LEVEL_FLOOR = 1e-3      # body level below which the asinh scale is linear
_MIN_COS_I = 0.1         # lit: the lamp at most ~84 deg from the normal
_SIGNIFICANT = 5.0       # a signal counts when it exceeds this many noise standard deviations
_CHROMA_ERROR = 0.03     # relative error of a view's channels beyond the noise (demosaicing a small highlight)
_OVER_BODY = 4.0         # a highlight's colour counts when it is this many times the body under it


class SegmentationError(InputError):
    """Observations or mesh unusable for the segmentation; the message names the argument."""


@dataclass(frozen=True)
class VertexFeatures:
    """Per-vertex summaries of all the observations of each vertex.

    Attributes
    ----------
    values
        ``(V, F)`` float64; NaN where not available (no lit observation; ``spec_*``: no highlight seen).
    names
        Column names (:data:`FEATURE_NAMES`).
    measured
        ``(V,)`` bool: the vertex has at least one lit observation.
    n_lit
        ``(V,)`` int64 lit observations per vertex.
    body_sd
        ``(V,)`` noise standard deviation of ``body_asinh`` (NaN where it is NaN).
    sd
        ``(V, F)`` noise standard deviation of every feature (NaN where the feature is NaN; ``peak_log``: 0).
    """

    values: NDArray[np.float64]
    names: tuple[str, ...]
    measured: NDArray[np.bool_]
    n_lit: NDArray[np.int64]
    body_sd: NDArray[np.float64]
    sd: NDArray[np.float64]


@dataclass(frozen=True)
class SurfaceSegmentation:
    """Regions of one material on the mesh.

    Attributes
    ----------
    vertex_region
        ``(V,)`` int32 region 0..R-1 (by decreasing area), -1 = not measured (no lit observation).
    face_region
        ``(T,)`` int32: the majority of the measured corners; -1 only when no corner is measured.
    n_regions
        R.
    features
        ``(V, F)`` float32 features (NaN where unmeasured).
    feature_names
        Names of the feature columns.
    method
        One line: features, clustering and smoothing used.
    """

    vertex_region: NDArray[np.int32]
    face_region: NDArray[np.int32]
    n_regions: int
    features: NDArray[np.float32]
    feature_names: tuple[str, ...]
    method: str


def _check_inputs(obs, vertices: ArrayLike, triangles: ArrayLike | None) -> tuple[NDArray, NDArray | None]:
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or not np.all(np.isfinite(v)):
        raise SegmentationError(f"vertices: shape {v.shape}; give finite (V, 3) millimetres")
    if not hasattr(obs, "offsets") or not hasattr(obs, "signal"):
        raise SegmentationError("obs: not an Observations; give processing.appearance.observations.Observations")
    if obs.n_vertices != len(v):
        raise SegmentationError(f"vertices: {len(v)} rows but obs covers {obs.n_vertices} vertices; "
                                "give the mesh the observations were made on")
    if len(obs.vertex) == 0:
        raise SegmentationError("obs: no observations; observe the mesh in at least one frame first")
    if triangles is None:
        return v, None
    t = np.asarray(triangles)
    if t.ndim != 2 or t.shape[1] != 3 or t.size == 0 or not np.issubdtype(t.dtype, np.integer) \
            or t.min() < 0 or t.max() >= len(v):
        raise SegmentationError(f"triangles: shape {t.shape}; give (T, 3) integer indices into vertices, T >= 1")
    return v, t.astype(np.int64)


def vertex_features(obs, vertices: ArrayLike, *, frames: Sequence | None = None, lamp: int = 0,
                    body_half_deg: float = 25.0, spec_half_deg: float = 12.0) -> VertexFeatures:
    """Summaries of every vertex's observations that a material fixes (see the module docstring).

    Parameters
    ----------
    obs
        :class:`processing.appearance.observations.Observations` of the mesh.
    vertices
        ``(V, 3)`` mesh vertices in M (mm), V = ``obs.n_vertices``.
    frames
        The frames' :class:`~processing.appearance.frame_poses.FramePose` (for the point lamp's
        ``1/d^2`` irradiance); None: irradiance 1 (the chromaticities do not depend on it).
    lamp
        Which lamp's geometry (``light_dir``, ``half_angle_deg``) to use.
    body_half_deg
        Half angle (deg) beyond which an observation counts as "away from the highlight".
    spec_half_deg
        Half angle (deg) below which an observation counts as "in the highlight".

    Returns
    -------
    VertexFeatures
    """
    v, _ = _check_inputs(obs, vertices, None)
    if not 0 <= int(lamp) < obs.light_dir.shape[1]:
        raise SegmentationError(f"lamp: {lamp!r} out of range; the observations have {obs.light_dir.shape[1]} lamp(s)")
    if frames is not None and len(frames) != len(obs.frame_names):
        raise SegmentationError(f"frames: {len(frames)} given for {len(obs.frame_names)} observed frames; "
                                "give the poses the observations were made with")
    nv, vert = obs.n_vertices, obs.vertex.astype(np.intp)
    cos_i = np.einsum("ij,ij->i", obs.normal, obs.light_dir[:, lamp]).astype(np.float64)
    half = obs.half_angle_deg[:, lamp].astype(np.float64)
    irr = sf.irradiance(v[vert], obs.frame, frames, lamp)
    sig = obs.signal.astype(np.float64) / irr[:, None]
    var = (obs.sigma.astype(np.float64) / irr[:, None]) ** 2
    lit = cos_i > _MIN_COS_I
    n_lit = np.bincount(vert[lit], minlength=nv)
    measured = n_lit > 0
    out = np.full((nv, len(FEATURE_NAMES)), np.nan)
    sd = np.full_like(out, np.nan)
    ok = lit & ~obs.clipped
    body = ok & (half > body_half_deg)
    out[:, 0:3], sd[:, 0:3], body_rgb = _body_features(sig[body] / cos_i[body, None],
                                                        var[body] / cos_i[body, None] ** 2, vert[body], nv)
    excess = sig - np.maximum(cos_i, 0.0)[:, None] * np.nan_to_num(body_rgb)[vert]   # the highlight alone
    out[:, 3:5], sd[:, 3:5] = _highlight_colour(excess, sig, var, vert, ok, nv)
    for cols, rows in (((5, 6), ok & (half < spec_half_deg)), ((7,), lit)):
        best = sf.group_argmax(excess[rows].sum(axis=1), vert[rows], nv)
        seen = best >= 0
        value, value_var = excess[rows][best[seen]], var[rows][best[seen]]
        body_part = sig[rows][best[seen]].mean(axis=1) - value.mean(axis=1)
        keep = (value.mean(axis=1) > _SIGNIFICANT * np.sqrt(value_var.mean(axis=1))) \
            & (value.mean(axis=1) > _OVER_BODY * body_part)
        seen[seen] = keep
        out[seen, cols[0]:cols[-1] + 1] = (sf.chromaticity(value[keep], 0.0) if len(cols) == 2
                                           else np.log10(value[keep].mean(axis=1))[:, None])
        sd[seen, cols[0]:cols[-1] + 1] = (sf.chromaticity_sd(value[keep], value_var[keep]
                                                             + (_CHROMA_ERROR * np.maximum(value[keep], 0.0)) ** 2)
                                          if len(cols) == 2 else 0.0)
    out[~measured] = np.nan
    sd[~measured] = np.nan
    return VertexFeatures(out, FEATURE_NAMES, measured, n_lit.astype(np.int64), sd[:, 0].copy(), sd)


def _highlight_colour(excess: NDArray[np.float64], sig: NDArray[np.float64], var: NDArray[np.float64],
                      vert: NDArray[np.intp], rows: NDArray[np.bool_], nv: int) -> tuple[NDArray, NDArray]:
    """``(nv, 2)`` chromaticity of the summed excess over the body of ``rows`` and its noise sd.

    NaN unless significant and dominant.
    """
    s_ex, s_var = sf.group_sum(excess[rows], vert[rows], nv), sf.group_sum(var[rows], vert[rows], nv)
    level = s_ex.mean(axis=1)
    s_body = sf.group_sum(sig[rows].mean(axis=1), vert[rows], nv) - level
    strong = (level > _SIGNIFICANT * np.sqrt(s_var.mean(axis=1))) & (level > _OVER_BODY * s_body)
    out, sd = np.full((nv, 2), np.nan), np.full((nv, 2), np.nan)
    out[strong] = sf.chromaticity(s_ex[strong], 0.0)
    s_model = sf.group_sum((_CHROMA_ERROR * np.maximum(excess[rows], 0.0)) ** 2, vert[rows], nv)
    sd[strong] = sf.chromaticity_sd(s_ex[strong], s_var[strong] + s_model[strong])
    return out, sd


def _body_features(diffuse: NDArray[np.float64], var: NDArray[np.float64], vert: NDArray[np.intp],
                   nv: int) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Asinh level, chromaticity (NaN unless significant), the level's noise sd and the median diffuse RGB."""
    rgb = np.stack([sf.group_median(diffuse[:, c], vert, nv) for c in range(3)], axis=1)
    n = np.bincount(vert, minlength=nv)
    noise = 1.25 * np.sqrt(sf.group_sum(var.mean(axis=1), vert, nv) / np.maximum(n, 1) ** 2)
    out = np.full((nv, 3), np.nan)
    has = n > 0
    level = rgb[has].mean(axis=1)
    out[has, 0] = np.arcsinh(level / _LEVEL_FLOOR)
    sd = np.full(nv, np.nan)
    sd[has] = noise[has] / _LEVEL_FLOOR / np.sqrt(1.0 + (level / _LEVEL_FLOOR) ** 2)
    strong = np.zeros(nv, bool)
    strong[has] = level > _SIGNIFICANT * noise[has]
    out[strong, 1:3] = sf.chromaticity(rgb[strong], 0.0)
    sds = np.full((nv, 3), np.nan)
    sds[:, 0] = sd
    noise_var = np.repeat((noise[strong] ** 2)[:, None], 3, axis=1)
    sds[strong, 1:3] = sf.chromaticity_sd(rgb[strong], noise_var)
    return out, sds, rgb


#: Features the mixture clusters on and their scales (one scale unit ~ a just-relevant difference).
_CLUSTER_FEATURES = (0, 1, 2, 3, 4, 5, 6)
_SCALES = np.array([0.5, 0.02, 0.02, 0.02, 0.02, 0.02, 0.02])
_VAR_FLOOR = 0.25        # (scale units)^2: features closer than half a scale unit are not told apart
_CONFIDENT_NATS = 2.0    # a vertex's own features decide its label when the runner-up is this much less likely
_UNARY_CAP_NATS = 4.0    # at most this much data cost per vertex, so neighbours can overrule an outlier
_MERGE_BHATTACHARYYA = 1.5  # mixture components closer than this are one material
_MIN_COMPONENT_WEIGHT = 0.01  # share of the fitted vertices below which a component is dropped
_MIN_SEEDS = 8           # confident vertices a region needs: fewer are a few off-colour views, no material
_DROPPED = 1e6           # data cost of a forbidden label
_KMEANS_STARTS = 6       # k-means++ starts per k (besides the greedy one): EM's local optima vary with the start
_FIT_SAMPLE = 200_000    # the mixture is fitted on every informative vertex up to this many (then a seeded subset):
                         # a material with about 1 % of them is near _MIN_COMPONENT_WEIGHT, and a subset's draw
                         # decided whether it was found
#: Width (photo pixels, on the surface) within which a region touching two others counts as their mixed edge: a
#: point spread of up to 1.5 px mixes the two materials over about +-3 px of their boundary.
BAND_PX = 6.0
_BAND_SHARE = 0.95       # share of a band's vertices that must lie that close to both of its neighbours
_BAND_OFF_LINE = 0.5     # a band's mean features lie within this share of its neighbours' distance of the line


def _component_loglik(x: NDArray[np.float64], mask: NDArray[np.bool_], extra: NDArray[np.float64],
                      mu: NDArray[np.float64], var: NDArray[np.float64],
                      weight: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(n, K)`` log(weight_k * N(x | mu_k, diag(var_k + extra))) over each row's available features.

    ``extra`` is each row's own measurement variance (the convolution of the component with the noise).
    """
    out = np.empty((len(x), len(mu)))
    for k in range(len(mu)):
        v = var[k] + extra
        d2 = np.where(mask, (x - mu[k]) ** 2 / v + np.log(2 * np.pi * v), 0.0)
        out[:, k] = -0.5 * d2.sum(axis=1) + np.log(weight[k])
    return out


def _fit_mixture(x: NDArray[np.float64], mask: NDArray[np.bool_], extra: NDArray[np.float64],
                 resp: NDArray[np.float64], iterations: int = 60) -> tuple[NDArray, NDArray, NDArray, float]:
    """Diagonal Gaussian mixture with missing features (EM, Dempster et al. 1977) from responsibilities ``resp``."""
    m = mask.astype(np.float64)
    xz = np.where(mask, x, 0.0)
    ll_total = -np.inf
    for _ in range(iterations):
        nk = resp.sum(axis=0) + 1e-9
        wsum = resp.T @ m + 1e-9
        mu = (resp.T @ xz) / wsum
        var = np.maximum((resp.T @ (xz ** 2 - extra * m)) / wsum - mu ** 2, _VAR_FLOOR)
        var[:, 0] = _VAR_FLOOR      # one material has one body level: its spread is the vertices' own noise
        ll = _component_loglik(x, mask, extra, mu, var, nk / nk.sum())
        top = ll.max(axis=1, keepdims=True)
        lse = top[:, 0] + np.log(np.exp(ll - top).sum(axis=1))
        resp = np.exp(ll - lse[:, None])
        new_total = float(lse.sum())
        if new_total - ll_total < 1e-4 * len(x):
            break
        ll_total = new_total
    nk = resp.sum(axis=0) + 1e-9
    return mu, var, nk / nk.sum(), float(lse.sum())


def _starts(x: NDArray[np.float64], mask: NDArray[np.bool_], extra: NDArray[np.float64], k: int, previous,
            seed: int) -> list[NDArray[np.float64]]:
    """Initial responsibilities for k components: k-means++ (:data:`_KMEANS_STARTS` seeds) and a greedy split.

    The greedy start keeps the k-1 fit and gives a new component the vertices it explains worst (greedy
    mixture learning, Verbeek et al. 2003).
    """
    import warnings

    from scipy.cluster.vq import kmeans2

    m = mask.astype(np.float64)
    fill = np.where(mask, x, (np.where(mask, x, 0.0).sum(axis=0) / np.maximum(m.sum(axis=0), 1.0)))
    out = []
    for s in range(seed, seed + _KMEANS_STARTS):
        with warnings.catch_warnings():              # an empty k-means cluster only weakens the start
            warnings.simplefilter("ignore", UserWarning)
            _, lab = kmeans2(fill, k, minit="++", seed=np.random.default_rng(s), iter=20)
        out.append(np.eye(k)[lab])
    if previous is not None:
        mu, var, w = previous
        ll = _component_loglik(x, mask, extra, mu, var, w)
        lab = np.argmax(ll, axis=1)
        worst = ll.max(axis=1) <= np.quantile(ll.max(axis=1), 0.02)
        lab[worst] = k - 1
        out.append(np.eye(k)[lab])
    return out


def _select_mixture(x: NDArray[np.float64], mask: NDArray[np.bool_], extra: NDArray[np.float64], max_k: int,
                    seed: int) -> tuple[NDArray, NDArray, NDArray]:
    """The mixture with the smallest BIC for k = 1..max_k, then components closer than the merge distance joined."""
    best, previous = None, None
    n_obs = float(mask.sum())
    for k in range(1, min(max_k, len(x)) + 1):
        fits = [_fit_mixture(x, mask, extra, r) for r in _starts(x, mask, extra, k, previous, seed)]
        mu, var, w, ll = max(fits, key=lambda f: f[3])
        previous = (mu, var, w)
        bic = -2.0 * ll + (k * 2 * x.shape[1] + k - 1) * np.log(max(n_obs, 2.0))
        if best is None or bic < best[0]:
            best = (bic, mu, var, w)
    mu, var, w = _merge_components(*best[1:])
    keep = w >= _MIN_COMPONENT_WEIGHT                # an outlier component (broad, a few vertices) is no material
    if not keep.any():
        keep = w == w.max()
    return mu[keep], var[keep], w[keep] / w[keep].sum()


def _body_block(body: NDArray[np.float64], has: NDArray[np.bool_], extra: NDArray[np.float64],
                mu: NDArray[np.float64], centre: float) -> NDArray[np.float64]:
    """``(n, K)`` cost cap where a vertex's body level is 2 nats from a component's, judged in linear units.

    ``body``, ``extra`` and ``mu`` are the scaled asinh level, its noise variance and the components'
    levels; ``centre`` the asinh level subtracted before scaling.  The asinh scale compresses a black
    lacquer's level (a few 1e-3) while a metal vertex's noise is taken at its level near 0, so the distance
    is measured on the linear level: a vertex's noise (its asinh sd times cosh) plus the component's spread
    at the floor variance.  A black metal is never taken for a black lacquer by its neighbours, nor the
    reverse, even where the asinh distance alone would not decide.
    """
    half = 0.5 * _SCALES[0]
    level = body * _SCALES[0] + centre
    level_mu = mu * _SCALES[0] + centre
    noise = np.sqrt(extra) * _SCALES[0] * np.cosh(level)
    spread = np.sqrt(_VAR_FLOOR) * half * 2.0 * np.cosh(level_mu)
    d = 0.5 * (np.sinh(level)[:, None] - np.sinh(level_mu)[None, :]) ** 2 / (noise[:, None] ** 2 + spread[None, :] ** 2)
    d -= d.min(axis=1, keepdims=True)
    return np.where(has[:, None] & (d >= _CONFIDENT_NATS), _UNARY_CAP_NATS, 0.0)


def _merge_components(mu: NDArray, var: NDArray, w: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """Join the closest pair (Bhattacharyya distance) while it is below the merge distance; moment-matched."""
    mu, var, w = list(mu), list(var), list(w)
    while len(mu) > 1:
        best = (np.inf, 0, 0)
        for i in range(len(mu)):
            for j in range(i + 1, len(mu)):
                v = 0.5 * (var[i] + var[j])
                d = 0.125 * np.sum((mu[i] - mu[j]) ** 2 / v) + 0.5 * np.sum(np.log(v / np.sqrt(var[i] * var[j])))
                best = min(best, (d, i, j))
        d, i, j = best
        if d >= _MERGE_BHATTACHARYYA:
            break
        wi, wj = w[i], w[j]
        m = (wi * mu[i] + wj * mu[j]) / (wi + wj)
        s = (wi * (var[i] + mu[i] ** 2) + wj * (var[j] + mu[j] ** 2)) / (wi + wj) - m ** 2
        mu[i], var[i], w[i] = m, np.maximum(s, _VAR_FLOOR), wi + wj
        del mu[j], var[j], w[j]
    return np.array(mu), np.array(var), np.array(w)


def _neighbour_votes(adj, labels: NDArray[np.intp], k: int) -> NDArray[np.float64]:
    """``(V, k)`` number of neighbours carrying each label (-1 labels do not vote)."""
    from scipy import sparse

    has = labels >= 0
    onehot = sparse.csr_matrix((np.ones(int(has.sum())), (np.flatnonzero(has), labels[has])),
                               shape=(len(labels), k))
    return np.asarray((adj @ onehot).todense())


def _nearest_seed_labels(cost: NDArray[np.float64], labels: NDArray[np.intp], lengths) -> NDArray[np.intp]:
    """Labels for the undecided vertices (-1) from the geodesically nearest confident vertex (Dijkstra).

    Only labels the vertex's own data cost allows (cost 0) are candidates; an island without any confident
    vertex takes its cheapest label.
    """
    from scipy.sparse.csgraph import dijkstra

    v, k = cost.shape
    dist = np.full((v, k), np.inf)
    for lab in range(k):
        seeds = np.flatnonzero(labels == lab)
        if len(seeds):
            dist[:, lab] = dijkstra(lengths, directed=False, indices=seeds, min_only=True)
    score = np.where(cost > 0.0, np.inf, dist)
    score = np.where(np.isfinite(score).any(axis=1, keepdims=True), score, dist + cost)
    todo = labels < 0
    reach = np.isfinite(score).any(axis=1)
    out = labels.copy()
    out[todo & reach] = np.argmin(score[todo & reach], axis=1)
    out[todo & ~reach] = np.argmin(cost[todo & ~reach], axis=1)
    return out


def _drop_unfounded(cost: NDArray[np.float64], seeds: NDArray[np.intp]) -> NDArray[np.float64]:
    """Forbid (cost :data:`_DROPPED`) every label with fewer than :data:`_MIN_SEEDS` seeds.

    A handful of confident vertices (a few off-colour views) cannot found a material of their own; the
    label with the most seeds is always kept.
    """
    k = cost.shape[1]
    count = np.bincount(seeds[seeds >= 0], minlength=k)
    weak = count < _MIN_SEEDS
    weak[np.argmax(count)] = False
    out = cost.copy()
    out[:, weak] = _DROPPED
    return out


def _spatial_labels(cost: NDArray[np.float64], informative: NDArray[np.bool_], lengths, smoothness: float,
                    rng: np.random.Generator, sweeps: int = 20) -> NDArray[np.intp]:
    """Potts labels: confident vertices keep their best label, the rest take the nearest one's, then ICM.

    ``cost`` is ``(V, K)`` data cost in nats (0 for the best and any label within the confidence margin,
    capped); only ``informative`` vertices (a significant colour) can be confident; ``lengths`` is the
    measured vertices' edge graph weighted by edge length (mm).  ICM: Besag (1986).
    """
    v, k = cost.shape
    adj = lengths.copy()
    adj.data[:] = 1.0
    second = np.sort(cost, axis=1)[:, 1] if k > 1 else np.full(v, np.inf)
    labels = np.where((second >= _CONFIDENT_NATS) & informative, np.argmin(cost, axis=1), -1)
    # a highlight lights a patch: a confident vertex without a confident neighbour of its label is noise
    support = np.take_along_axis(_neighbour_votes(adj, labels, k), np.maximum(labels, 0)[:, None], 1)[:, 0]
    labels[support < 1] = -1
    cost = _drop_unfounded(cost, labels)
    labels[(labels >= 0) & (cost[np.arange(v), np.maximum(labels, 0)] >= _DROPPED)] = -1
    labels = _nearest_seed_labels(cost, labels, lengths)
    for _ in range(sweeps):                              # iterated conditional modes, half the vertices a sweep
        total = cost - smoothness * _neighbour_votes(adj, labels, k)
        new = np.argmin(total, axis=1)
        better = np.take_along_axis(total, new[:, None], 1)[:, 0] < np.take_along_axis(total, labels[:, None], 1)[:, 0]
        if not better.any():
            break
        change = better & (rng.random(v) < 0.5)
        labels[change] = new[change]
    return labels


def _merge_small(labels: NDArray[np.intp], area: NDArray[np.float64], adj, share: float,
                 k: int) -> NDArray[np.intp]:
    """Give every region smaller than ``share`` of the area to the neighbour it shares most edges with."""
    labels = labels.copy()
    total = float(area.sum())
    while True:
        sizes = np.bincount(labels, weights=area, minlength=k)
        small = np.flatnonzero((sizes > 0) & (sizes < share * total))
        if len(small) == 0 or np.count_nonzero(sizes) <= 1:
            return labels
        lab = small[np.argmin(sizes[small])]
        members = labels == lab
        votes = _neighbour_votes(adj, labels, k)[members].sum(axis=0)
        votes[lab] = -1.0
        if votes.max() <= 0:                             # an isolated part: the largest region takes it
            votes = np.where(np.arange(k) == lab, -1.0, sizes)
        labels[members] = int(np.argmax(votes))


def _footprint_mm(obs, frames: Sequence) -> NDArray[np.float64]:
    """``(V,)`` median size (mm) of a photo pixel on the surface at each vertex over its views (NaN: none)."""
    focal = np.array([0.5 * (float(f.K[0][0]) + float(f.K[1][1])) for f in frames])
    size = np.asarray(obs.distance_mm, dtype=np.float64) / focal[np.asarray(obs.frame)]
    out = np.full(obs.n_vertices, np.nan)
    counts = np.diff(obs.offsets)
    has = np.flatnonzero(counts > 0)
    key = np.lexsort((size, np.asarray(obs.vertex)))       # rows grouped by vertex, each group by size
    out[has] = size[key][obs.offsets[has] + (counts[has] - 1) // 2]
    return out


def _dissolve_bands(labels: NDArray[np.intp], x: NDArray[np.float64], area: NDArray[np.float64], adj, lengths,
                    width_mm: NDArray[np.float64], k: int) -> NDArray[np.intp]:
    """Regions that are the lens-mixed edge between two others, handed to the geodesically nearer of the two."""
    from scipy.sparse.csgraph import dijkstra

    labels = labels.copy()
    reach = float(np.nanmax(width_mm)) if np.isfinite(width_mm).any() else 0.0
    if reach <= 0:
        return labels
    for c in np.argsort(np.bincount(labels, weights=area, minlength=k)):
        members = np.flatnonzero(labels == c)
        if members.size == 0 or np.count_nonzero(np.bincount(labels, minlength=k)) < 3:
            continue
        votes = _neighbour_votes(adj, labels, k)[members].sum(axis=0)
        votes[c] = 0.0
        a, b = np.argsort(-votes)[:2]
        if votes[b] <= 0 or not _between(x, labels, c, a, b):
            continue
        near = np.stack([dijkstra(lengths, indices=np.flatnonzero(labels == r), min_only=True, limit=reach)[members]
                         for r in (a, b)], axis=1)
        close = np.all(near <= width_mm[members, None], axis=1)
        if close.mean() >= _BAND_SHARE:
            labels[members] = np.where(near[:, 0] <= near[:, 1], a, b)
    return labels


def _between(x: NDArray[np.float64], labels: NDArray[np.intp], c: int, a: int, b: int) -> bool:
    """Region ``c``'s mean features lie between ``a``'s and ``b``'s (a mix of the two), on their common features."""
    mean = []
    for r in (c, a, b):
        rows = x[labels == r]
        seen = np.isfinite(rows)
        n = seen.sum(axis=0)
        mean.append(np.where(n > 0, np.where(seen, rows, 0.0).sum(axis=0) / np.maximum(n, 1), np.nan))
    ok = np.all(np.isfinite(mean), axis=0)
    if not ok.any():
        return False
    mc, ma, mb = (m[ok] for m in mean)
    d = mb - ma
    span = float(d @ d)
    if span == 0:
        return False
    alpha = float((mc - ma) @ d) / span
    off = float(np.linalg.norm(mc - (ma + alpha * d)))
    return 0.0 < alpha < 1.0 and off <= _BAND_OFF_LINE * np.sqrt(span)


def _face_labels(vertex_region: NDArray[np.int32], triangles: NDArray[np.int64]) -> NDArray[np.int32]:
    """Majority label of each face's measured corners (the first measured corner breaks a three-way tie)."""
    c = vertex_region[triangles]
    out = np.where(c[:, 0] >= 0, c[:, 0], np.where(c[:, 1] >= 0, c[:, 1], c[:, 2]))
    pair = (c[:, 1] == c[:, 2]) & (c[:, 1] >= 0)
    out = np.where(pair, c[:, 1], out)
    return out.astype(np.int32)


def _data_cost(feats: VertexFeatures, meas: NDArray[np.intp], max_regions: int, seed: int,
               rng: np.random.Generator) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """``(n, K)`` data cost (nats) of the measured vertices per mixture component, and which have a colour."""
    x = feats.values[meas][:, _CLUSTER_FEATURES]
    mask = np.isfinite(x)
    centre = [float(np.median(col[ok])) if ok.any() else 0.0 for col, ok in zip(x.T, mask.T)]
    x = np.nan_to_num((x - np.array(centre)) / _SCALES)
    extra = np.nan_to_num(feats.sd[meas][:, _CLUSTER_FEATURES] / _SCALES) ** 2
    informative = mask[:, 1:].any(axis=1)
    pool = np.flatnonzero(informative) if informative.any() else np.arange(len(x))
    fit = pool if len(pool) <= _FIT_SAMPLE else np.sort(rng.choice(pool, _FIT_SAMPLE, replace=False))
    mu, var, w = _select_mixture(x[fit], mask[fit], extra[fit], max_regions, seed)
    # the mixture's posterior where a colour was measured; the likelihood alone (a flat prior) where only the
    # body level was: there a large material's weight must not claim what the features cannot tell apart
    ll = _component_loglik(x, mask, extra, mu, var, w)
    ll[~informative] -= np.log(w)
    cost = np.minimum(ll.max(axis=1, keepdims=True) - ll, _UNARY_CAP_NATS)
    cost[cost < _CONFIDENT_NATS] = 0.0        # within the margin the features do not decide: the neighbours do
    return np.maximum(cost, _body_block(x[:, 0], mask[:, 0], extra[:, 0], mu[:, 0], centre[0])), informative


def segment_surface(obs, vertices: ArrayLike, triangles: ArrayLike, *, max_regions: int = 8,
                    min_region_share: float = 0.002, smoothness: float = 1.0, seed: int = 0,
                    frames: Sequence | None = None) -> SurfaceSegmentation:
    """Regions of one material on the mesh from all the observations of every vertex.

    Parameters
    ----------
    obs
        :class:`processing.appearance.observations.Observations` of the mesh.
    vertices, triangles
        The mesh in M: ``(V, 3)`` mm (V = ``obs.n_vertices``) and ``(T, 3)`` indices.
    max_regions
        Most mixture components (materials) tried; the BIC picks the number, close ones are merged.
    min_region_share
        Regions smaller than this share of the measured area join the neighbour they share most edges with.
    smoothness
        Potts weight (nats per disagreeing neighbour); 0 labels every vertex by its own features.
    seed
        Seed of the mixture's start and of the ICM's random half-sweeps.
    frames
        Optional frame poses for the point lamp's ``1/d^2`` (see :func:`vertex_features`).

    Returns
    -------
    SurfaceSegmentation
        Regions numbered by decreasing area; -1 where no lit observation exists.
    """
    v, t = _check_inputs(obs, vertices, triangles)
    if not (isinstance(max_regions, (int, np.integer)) and max_regions >= 1):
        raise SegmentationError(f"max_regions: {max_regions!r}; give an integer >= 1")
    if not (0.0 <= min_region_share < 1.0 and smoothness >= 0.0):
        raise SegmentationError(f"min_region_share {min_region_share!r} / smoothness {smoothness!r}; "
                                "give a share in [0, 1) and a weight >= 0")
    feats = vertex_features(obs, v, frames=frames)
    meas = np.flatnonzero(feats.measured)
    if len(meas) == 0:
        raise SegmentationError("obs: no vertex is lit in any observation; capture with the lamp on the object")
    rng = np.random.default_rng(seed)
    cost, informative = _data_cost(feats, meas, int(max_regions), seed, rng)
    lengths = sf.adjacency(t, len(v), v)[meas][:, meas]
    adj = lengths.copy()
    adj.data[:] = 1.0
    labels = _spatial_labels(cost, informative, lengths, float(smoothness), rng)
    area = sf.vertex_areas(v, t)[meas]
    k = cost.shape[1]
    labels = _merge_small(labels, area, adj, float(min_region_share), k)
    if frames is not None:
        width_mm = BAND_PX * _footprint_mm(obs, frames)[meas]
        labels = _dissolve_bands(labels, feats.values[meas][:, _CLUSTER_FEATURES] / _SCALES, area, adj, lengths,
                                 width_mm, k)
    sizes = np.bincount(labels, weights=area, minlength=k)
    used = np.flatnonzero(sizes > 0)
    rank = np.full(k, -1)
    rank[used[np.argsort(-sizes[used], kind="stable")]] = np.arange(len(used))
    vertex_region = np.full(len(v), -1, dtype=np.int32)
    vertex_region[meas] = rank[labels]
    method = (f"features {', '.join(FEATURE_NAMES[i] for i in _CLUSTER_FEATURES)} from all lit views; "
              f"diagonal Gaussian mixture (EM, BIC over k<={max_regions}, {k} after merging); "
              f"seeds filled geodesically, Potts ICM smoothness {smoothness:g}; "
              f"regions < {min_region_share:g} of the area merged")
    return SurfaceSegmentation(vertex_region, _face_labels(vertex_region, t), len(used),
                               feats.values.astype(np.float32), feats.names, method)
