"""Whether every part of a region agrees with the material fitted to the whole of it.

A region of the segmentation may join pieces of the surface that are far apart (its connected
components): the fit pools their observations and names one material.  When a piece with highlights
of its own is explained far better by another region's fitted material than by its own region's, the
region is a mixture and its answer cannot be right for the whole of it.  :func:`mesh_components`
splits the regions into connected pieces; :func:`fixed_material_chi2` scores observations against
fixed (already fitted) materials with the fit's own noise model; :func:`disagreeing_pieces` applies
the likelihood-ratio test piece by piece, and :func:`joining_pieces` the same test the other way: a
piece whose observations do not reject a larger region's material (and which that material explains
within the fit's misfit limit) joins it -- spatial coherence decided by the photos, not by a prior.  docs/materials.md, section "Parts that disagree with
their region", says how the measurement uses it (the region's confidence is capped by the share of
its area that does not disagree).

References
----------
.. [1] Neyman, J., Pearson, E. S. (1933). On the problem of the most efficient tests of statistical
   hypotheses. Phil. Trans. R. Soc. A 231, 289-337. doi:10.1098/rsta.1933.0009
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.materials._forward_fit_samples import HIGHLIGHT_DEG, FitError, RegionSamples
from processing.materials.lobes import Material

__all__ = ["mesh_components", "face_regions", "fixed_material_chi2", "pieces_chi2", "disagreeing_pieces", "joining_pieces",
           "LIKELIHOOD_MARGIN"]

#: A piece disagrees with its region when another region's material lowers its (independence-scaled)
#: chi-square by more than this: a likelihood ratio of exp(50 / 2), far beyond the noise of the
#: comparison of two fixed models on hundreds of independent observations.
LIKELIHOOD_MARGIN = 50.0


def mesh_components(vertex_region: ArrayLike, triangles: ArrayLike) -> NDArray[np.int64]:
    """Connected piece of every vertex: vertices of one region joined by the mesh's edges.

    Parameters
    ----------
    vertex_region
        ``(V,)`` region of each vertex (negative: not measured).
    triangles
        ``(T, 3)`` vertex indices.

    Returns
    -------
    ndarray
        ``(V,)`` piece index (0..P-1), -1 where the region is negative.

    Raises
    ------
    FitError
        Triangles that are not ``(T, 3)`` indices of the vertices.

    Examples
    --------
    >>> tri = np.array([[0, 1, 2], [1, 3, 2], [3, 4, 5]])
    >>> mesh_components([0, 0, 0, 1, 0, 0], tri).tolist()
    [0, 0, 0, 1, 2, 2]
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    region = np.asarray(vertex_region, dtype=np.int64).reshape(-1)
    t = np.asarray(triangles, dtype=np.int64)
    if t.ndim != 2 or t.shape[1] != 3 or (t.size and (t.min() < 0 or t.max() >= region.size)):
        raise FitError(f"triangles must be (T, 3) indices of the {region.size} vertices, got shape {t.shape}")
    a = np.concatenate([t[:, 0], t[:, 1], t[:, 2]])
    b = np.concatenate([t[:, 1], t[:, 2], t[:, 0]])
    keep = (region[a] == region[b]) & (region[a] >= 0)
    graph = coo_matrix((np.ones(int(keep.sum())), (a[keep], b[keep])), shape=(region.size, region.size))
    _, label = connected_components(graph, directed=False)
    out = np.full(region.size, -1, dtype=np.int64)
    measured = region >= 0
    _, out[measured] = np.unique(label[measured], return_inverse=True)
    return out


def face_regions(vertex_region: ArrayLike, triangles: ArrayLike) -> NDArray[np.int32]:
    """Region of each face: the label of most of its measured corners (the first measured corner breaks a tie).

    Parameters
    ----------
    vertex_region
        ``(V,)`` region of each vertex (negative: not measured).
    triangles
        ``(T, 3)`` vertex indices.

    Returns
    -------
    ndarray
        ``(T,)`` region of each face (-1 where no corner is measured).

    Examples
    --------
    >>> face_regions([0, 1, 1, -1], [[0, 1, 2], [0, 3, 3], [3, 3, 3]]).tolist()
    [1, 0, -1]
    """
    c = np.asarray(vertex_region, dtype=np.int64)[np.asarray(triangles, dtype=np.int64)]
    out = np.where(c[:, 0] >= 0, c[:, 0], np.where(c[:, 1] >= 0, c[:, 1], c[:, 2]))
    out = np.where((c[:, 1] == c[:, 2]) & (c[:, 1] >= 0), c[:, 1], out)
    return out.astype(np.int32)


def fixed_material_chi2(samples: RegionSamples, model, materials: Sequence[Material | None], *,
                        model_error: float = 0.02, normal_error_deg: float = 0.5, max_samples: int = 4000,
                        seed: int = 0) -> tuple[NDArray[np.float64], int, int]:
    """Chi-square of the observations under each of several fixed materials, with the fit's noise model.

    The observations are weighted as :func:`processing.materials.forward_fit.fit_region` weighs them
    (noise, ``model_error`` of the signal, the common-mode error of ``normal_error_deg`` and the
    robust weights), so the figures compare with a fit's; nothing is fitted: the materials'
    parameters (and the lamp scale they carry) are used as they are.

    Parameters
    ----------
    samples
        Observations (:func:`processing.materials.forward_fit.region_samples`).
    model
        The :class:`processing.materials.forward_fit.ForwardModel`.
    materials
        Fitted materials (None: not scored, NaN).
    model_error, normal_error_deg
        As in ``fit_region``.
    max_samples
        At most this many observations are scored (those near the mirror direction first, with ``seed``).
    seed
        Seed of that sampling.

    Returns
    -------
    chi2 : ndarray
        ``(M,)`` chi-square of each material (NaN for None).
    n : int
        Observations scored.
    n_highlights : int
        Of them, within :data:`HIGHLIGHT_DEG` of the mirror direction.
    """
    from processing.materials.forward_fit import prepared_observations

    prep = prepared_observations(samples, model, model_error=model_error, normal_error_deg=normal_error_deg,
                                 max_samples=max_samples, seed=seed)
    if prep is None:
        return np.full(len(materials), np.nan), 0, 0
    fitted, y, w = prep
    out = np.full(len(materials), np.nan)
    for k, m in enumerate(materials):
        if m is not None:
            r = w(y - model.predict(m, fitted).reshape(-1))
            out[k] = float(r @ r)
    n_hl = int((fitted.cos_h >= np.cos(np.radians(HIGHLIGHT_DEG))).sum())
    return out, len(fitted), n_hl


def pieces_chi2(samples: RegionSamples, piece: ArrayLike, model, materials: Sequence[Material | None], *,
                model_error: float = 0.02, normal_error_deg: float = 0.5, max_samples: int = 4000,
                seed: int = 0, level_cap: float = np.inf) -> tuple[NDArray[np.int64], NDArray[np.float64],
                                                                  NDArray[np.int64], NDArray[np.int64]]:
    """Chi-square of every piece's observations under each of several fixed materials, in one pass.

    The observations of all pieces are weighed together
    (:func:`processing.materials.forward_fit.grouped_observations`: the noise, model error and
    normal error of the fit, robust weights scaled and normalised per piece), each material's
    prediction is evaluated once for all of them, and the whitened squared residuals are summed per
    piece.  Each piece keeps the observations :func:`fixed_material_chi2` would score for it alone.

    With a finite ``level_cap`` each observation's whitened residual is split into its level (the part
    a free brightness scale >= 0 of the prediction removes) and its colour (the rest, never more than
    the whole); the colour counts in full, the level up to ``level_cap``.  Light the model does not
    follow (a neighbour's highlight spread by the lens, a normal a few degrees off) brightens a
    surface in its own colour: far from the prediction in level, right in colour.

    Parameters
    ----------
    samples
        Observations of the pieces (:func:`processing.materials.forward_fit.region_samples`).
    piece
        ``(n,)`` piece of each observation (>= 0).
    model
        The :class:`processing.materials.forward_fit.ForwardModel`.
    materials
        Fitted materials (None: not scored, NaN).
    model_error, normal_error_deg, max_samples, seed
        As in :func:`fixed_material_chi2` (``max_samples`` per piece).
    level_cap
        Most chi-square one observation's level adds (> 0; infinity: the whole residual, as the fit).

    Returns
    -------
    ids : ndarray
        ``(P,)`` the pieces with scored observations, ascending.
    chi2 : ndarray
        ``(P, M)`` chi-square of each of them under each material (NaN for None).
    n : ndarray
        ``(P,)`` observations scored per piece.
    n_highlights : ndarray
        ``(P,)`` of them, within :data:`HIGHLIGHT_DEG` of the mirror direction.
    """
    from processing.materials.forward_fit import grouped_observations

    p_all = np.asarray(piece, dtype=np.int64).reshape(-1)
    prep = grouped_observations(samples, p_all, model, model_error=model_error, normal_error_deg=normal_error_deg,
                                max_samples=max_samples, seed=seed)
    if prep is None:
        return np.zeros(0, dtype=np.int64), np.zeros((0, len(materials))), np.zeros(0, dtype=np.int64), \
            np.zeros(0, dtype=np.int64)
    fitted, kept_piece, y, w = prep
    ids, g = np.unique(kept_piece, return_inverse=True)
    n_pieces = ids.size
    chi2 = np.full((n_pieces, len(materials)), np.nan)
    wy = w(y).reshape(-1, 3) if np.isfinite(level_cap) else None
    for k, m in enumerate(materials):
        if m is None:
            continue
        pred = model.predict(m, fitted).reshape(-1)
        r = w(y - pred).reshape(-1, 3)
        e = np.einsum("ij,ij->i", r, r)
        if wy is not None:
            wp = w(pred).reshape(-1, 3)         # whitened on its own: a prediction 1e-30 of the signal keeps its colour
            scale = np.maximum(np.einsum("ij,ij->i", wy, wp), 0.0) / np.maximum(np.einsum("ij,ij->i", wp, wp), 1e-300)
            rc = wy - scale[:, None] * wp
            colour = np.einsum("ij,ij->i", rc, rc)
            e = colour + np.minimum(e - colour, level_cap)
        chi2[:, k] = np.bincount(g, weights=e, minlength=n_pieces)
    n = np.bincount(g, minlength=n_pieces)
    n_hl = np.bincount(g, weights=fitted.cos_h >= np.cos(np.radians(HIGHLIGHT_DEG)), minlength=n_pieces)
    return ids, chi2, n, n_hl.astype(np.int64)


def disagreeing_pieces(chi2: ArrayLike, n_observations: ArrayLike, own: ArrayLike, *, independent: float = 400.0,
                       margin: float = LIKELIHOOD_MARGIN) -> tuple[NDArray[np.bool_], NDArray[np.int64]]:
    """Pieces whose observations another region's material explains far better than their own region's.

    Parameters
    ----------
    chi2
        ``(P, R)`` chi-square of each piece under each region's fitted material (NaN: not scored).
    n_observations
        ``(P,)`` observations scored per piece; the chi-squares are scaled by
        ``min(1, independent / n)`` (errors shared over a piece stop averaging down, as in the fit).
    own
        ``(P,)`` region of each piece.
    independent
        Observations counted as independent evidence
        (:data:`processing.materials.forward_fit.INDEPENDENT`).
    margin
        Least drop of the scaled chi-square (:data:`LIKELIHOOD_MARGIN`).

    Returns
    -------
    disagrees : ndarray
        ``(P,)`` True where another region's material is better by more than ``margin``.
    better : ndarray
        ``(P,)`` that region (-1 where the piece agrees or was not scored).

    Examples
    --------
    >>> chi2 = [[900.0, 3000.0], [4000.0, 1200.0], [np.nan, np.nan]]
    >>> d, b = disagreeing_pieces(chi2, [300, 300, 0], [0, 0, 0])
    >>> d.tolist(), b.tolist()
    ([False, True, False], [-1, 1, -1])
    """
    c = np.asarray(chi2, dtype=np.float64)
    n = np.asarray(n_observations, dtype=np.float64).reshape(-1)
    own_r = np.asarray(own, dtype=np.int64).reshape(-1)
    if c.ndim != 2 or c.shape[0] != n.size or own_r.size != n.size:
        raise FitError(f"chi2 must be (P, R) with P = len(n_observations) = len(own); got {c.shape}, {n.size}, "
                       f"{own_r.size}")
    scaled = c * np.minimum(1.0, independent / np.maximum(n, 1.0))[:, None]
    rows = np.arange(n.size)
    own_chi2 = scaled[rows, own_r]
    others = np.where(np.arange(c.shape[1])[None, :] == own_r[:, None], np.inf, np.nan_to_num(scaled, nan=np.inf))
    best = np.argmin(others, axis=1) if c.shape[1] > 1 else np.zeros(n.size, dtype=np.int64)
    best_chi2 = others[rows, best] if c.shape[1] > 1 else np.full(n.size, np.inf)
    disagrees = np.isfinite(own_chi2) & np.isfinite(best_chi2) & (own_chi2 - best_chi2 > margin)
    return disagrees, np.where(disagrees, best, -1)


def joining_pieces(chi2_target: ArrayLike, chi2_own: ArrayLike, n_observations: ArrayLike, *,
                   independent: float = 400.0, margin: float = LIKELIHOOD_MARGIN,
                   max_misfit: float = 4.0) -> NDArray[np.bool_]:
    """Pieces whose observations a target region's material explains as well as their own region's.

    A piece joins when its own region's material is not better than the target's by more than
    ``margin`` (scaled chi-square, as :func:`disagreeing_pieces`) and the target's material fits it
    within ``max_misfit`` (reduced, scaled chi-square: the limit beyond which a fit reads "no
    candidate fits").  A piece whose own region has no material (NaN) joins when the target's fits.
    A piece without scored observations never joins: nothing shows it belongs anywhere.

    Parameters
    ----------
    chi2_target, chi2_own
        ``(P,)`` chi-square of each piece under the target's and its own region's material.
    n_observations
        ``(P,)`` observations scored (each of three channels).
    independent
        Observations counted as independent evidence.
    margin
        Largest advantage (scaled chi-square) of the own material that still lets the piece join.
    max_misfit
        Largest reduced chi-square of the target's material on the piece
        (:data:`processing.materials._forward_fit_report.MAX_MISFIT_POOLED`).

    Returns
    -------
    ndarray
        ``(P,)`` True where the piece joins the target.

    Examples
    --------
    >>> joining_pieces([1230.0, 9000.0, 1300.0, 50.0], [1200.0, 1200.0, np.nan, np.nan], [400, 400, 400, 0]).tolist()
    [True, False, True, False]
    """
    target = np.asarray(chi2_target, dtype=np.float64).reshape(-1)
    own = np.asarray(chi2_own, dtype=np.float64).reshape(-1)
    n = np.asarray(n_observations, dtype=np.float64).reshape(-1)
    if not (target.size == own.size == n.size):
        raise FitError(f"chi2_target, chi2_own and n_observations must have one value per piece; got {target.size}, "
                       f"{own.size}, {n.size}")
    f = np.minimum(1.0, independent / np.maximum(n, 1.0))
    st, so = target * f, np.where(np.isfinite(own), own * f, np.inf)
    fits = st / np.maximum(3.0 * n * f, 1.0) <= max_misfit
    return (n > 0) & np.isfinite(st) & fits & (st - so <= margin)
