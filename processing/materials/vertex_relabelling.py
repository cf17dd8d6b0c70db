"""Every vertex given to the fitted material that explains its own observations, its neighbours agreeing.

The surface segmentation groups vertices by summaries of their observations (a body level, colours
of the highlights) before any material is known, and a vertex whose summaries are weak -- a dark
underside that never shows a highlight, a face seen only at a glancing angle -- takes the label of
its neighbours or of the nearest confident vertex, whichever region that is.  A summary cannot use
the angles: a gold seen near normal incidence is a deeper yellow than the same gold at a glancing
one, and a metal's faint lobe tail has its own colour.  Once every region has a material fitted at
the observations' true angles, the forward model itself can say which of them explains a vertex's
observations.  :func:`vertex_material_costs` scores each vertex's observations under every region's
fitted material with the fit's noise model
(:func:`processing.materials.region_consistency.pieces_chi2`, one piece per vertex).  Each
observation's whitened residual is split in two: its level (what a free brightness scale of the
prediction removes) and its colour (the rest).  Light the model does not follow -- a neighbour's
highlight spread over a photosite or two by the lens, a normal a few degrees off near a highlight --
adds brightness in the surface's own colour: far from the prediction in level, right in colour.  So
the level counts in full up to :data:`LEVEL_CAP_CHI2` (three standard deviations) per observation and
no more, and the colour always counts: the dark underside of a gold beak, never seen near its
highlight, is told from the grey alloy beside it by the colour of what little light it returns.
:func:`relabel_vertices` takes half the difference to the best material, capped, as the data term of
a Potts model on the mesh's edges, starts from the segmentation's labels and relaxes by iterated
conditional modes (Besag 1986): a vertex moves when its own observations outweigh its neighbours.
Reassigning each surface point to the basis material that explains it best and fitting the
materials again is the alternation of Lensch et al. (2003).

References
----------
Besag, J. (1986). On the statistical analysis of dirty pictures. J. R. Stat. Soc. B 48(3), 259-302.
doi:10.1111/j.2517-6161.1986.tb01412.x

Lensch, H. P. A., Kautz, J., Goesele, M., Heidrich, W., Seidel, H.-P. (2003). Image-based
reconstruction of spatial appearance and geometric detail. ACM TOG 22(2), 234-257.
doi:10.1145/636886.636891
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.materials._forward_fit_samples import FitError, RegionSamples
from processing.materials.lobes import Material

__all__ = ["vertex_material_costs", "relabel_vertices", "unexplained_pieces", "UNARY_CAP_NATS", "SMOOTHNESS_NATS",
           "LEVEL_CAP_CHI2", "DECIDED_NATS"]

#: Most data cost (nats) one vertex's observations put on a label: a single vertex's few views
#: (a demosaicing error, a view that mixes a neighbour through the lens) cannot outweigh all its
#: neighbours, several vertices that agree can.  The surface segmentation uses the same cap.
UNARY_CAP_NATS = 4.0
#: Potts weight (nats per neighbour of another label), as in the surface segmentation.
SMOOTHNESS_NATS = 1.0
#: A vertex's own observations decide its material when they favour it by this much (nats) over every other:
#: the surface segmentation's confidence margin.  Elsewhere its label is its neighbours'.
DECIDED_NATS = 2.0
#: Most chi-square one observation's level (its brightness against the prediction's, the colour aside) adds:
#: three standard deviations.  On the demo session 4 and 16 give within 0.15 points of the same share of the
#: area right, no cap 0.45 points less.
LEVEL_CAP_CHI2 = 9.0


def vertex_material_costs(samples: RegionSamples, model, materials: Sequence[Material | None], n_vertices: int, *,
                          model_error: float = 0.02, cap_nats: float = UNARY_CAP_NATS,
                          unnamed: Sequence[bool] | None = None,
                          level_cap: float = LEVEL_CAP_CHI2) -> NDArray[np.float64]:
    """``(V, M)`` data cost (nats) of giving each vertex each material, from its own observations.

    Half the chi-square of the vertex's observations under the material less that of its best
    material (the log-likelihood ratio), capped at ``cap_nats``; each observation's level part counts up
    to ``level_cap`` (see the module docstring).  A vertex without scored
    observations costs 0 for every material (its neighbours decide); a material that is None
    costs infinity (no vertex is given it).  A material flagged ``unnamed`` (its region's fit could
    not name it: a dull, dark fit that a dozen candidates explain alike) costs ``cap_nats`` more for
    every vertex: it explains dark observations of any material about as well as their own, so it
    offers no rival explanation, and its region's vertices go where their neighbours are.

    Parameters
    ----------
    samples
        The observations of the vertices (:func:`processing.materials.forward_fit.region_samples`).
    model
        The :class:`processing.materials.forward_fit.ForwardModel`.
    materials
        The regions' fitted materials (None: a region without one).
    n_vertices
        V, the mesh's vertex count (``samples.vertex`` indexes it).
    model_error
        Relative model error of the fit.
    cap_nats
        Largest cost, > 0.
    unnamed
        ``(M,)`` flags: the materials whose regions' fits could not name them (None: none).
    level_cap
        Most chi-square an observation's level adds, > 0 (``numpy.inf``: the whole residual, as the fit).

    Returns
    -------
    ndarray
        ``(V, M)``.

    Raises
    ------
    FitError
        ``cap_nats`` or ``level_cap`` not positive, ``n_vertices`` too small for the samples, no material,
        or ``unnamed`` not one flag per material.
    """
    from processing.materials.region_consistency import pieces_chi2

    if not (np.isfinite(cap_nats) and cap_nats > 0):
        raise FitError(f"cap_nats must be > 0, got {cap_nats!r}")
    if not level_cap > 0:
        raise FitError(f"level_cap must be > 0, got {level_cap!r}")
    if not materials:
        raise FitError("materials: none given; give each region's fitted material (None where it has none)")
    if len(samples) and int(np.max(samples.vertex)) >= n_vertices:
        raise FitError(f"n_vertices {n_vertices} but the samples observe vertex {int(np.max(samples.vertex))}")
    weak = np.zeros(len(materials), dtype=bool) if unnamed is None else np.asarray(unnamed, dtype=bool)
    if weak.shape != (len(materials),):
        raise FitError(f"unnamed: {weak.shape[0] if weak.ndim else 'a scalar'} flags for {len(materials)} materials; "
                       "give one per material")
    absent = np.array([m is None for m in materials])
    cost = np.where(absent, np.inf, 0.0)[None, :].repeat(n_vertices, axis=0)
    if len(samples) and not absent.all():
        ids, chi2, _, _ = pieces_chi2(samples, samples.vertex, model, materials, model_error=model_error,
                                      level_cap=level_cap)
        if ids.size:
            best = np.nanmin(np.where(absent, np.nan, chi2), axis=1, keepdims=True)
            cost[ids] = np.where(absent, np.inf, np.minimum(0.5 * (chi2 - best), cap_nats))
    return cost + np.where(weak & ~absent, cap_nats, 0.0)[None, :]


def relabel_vertices(cost: ArrayLike, labels: ArrayLike, triangles: ArrayLike, *,
                     smoothness: float = SMOOTHNESS_NATS, sweeps: int = 30, seed: int = 0) -> NDArray[np.int32]:
    """Potts labels from ``labels`` by iterated conditional modes with data cost ``cost``.

    Each sweep, every vertex computes ``cost - smoothness * (neighbours of each label)`` and half of
    the vertices that would lower it (chosen at random, so neighbours do not swap in lockstep) take
    the better label, until none would (or ``sweeps`` sweeps).  Vertices labelled -1 (not measured)
    keep -1 and do not vote; a vertex whose current label costs infinity (a region without a
    material) keeps it.

    Parameters
    ----------
    cost
        ``(V, M)`` data cost in nats (:func:`vertex_material_costs`).
    labels
        ``(V,)`` starting label 0..M-1, or -1.
    triangles
        ``(T, 3)`` the mesh's triangles (its edges are the neighbourhood).
    smoothness
        Nats per neighbour of another label, >= 0.
    sweeps
        Most sweeps, >= 1.
    seed
        Seed of the random half of each sweep.

    Returns
    -------
    ndarray
        ``(V,)`` int32.

    Raises
    ------
    FitError
        Shapes that do not agree, a label out of range, or a negative smoothness.

    Examples
    --------
    One vertex of a strip of three that its own observations put in the other region stays, as its
    two neighbours outvote a capped cost of 1 nat; with 3 nats it moves:

    >>> tri = [[0, 1, 2]]
    >>> relabel_vertices([[0, 0], [1, 0], [0, 0]], [0, 0, 0], tri).tolist()
    [0, 0, 0]
    >>> relabel_vertices([[0, 0], [3, 0], [0, 0]], [0, 0, 0], tri).tolist()
    [0, 1, 0]
    """
    from scipy import sparse

    from processing.appearance._surface_features import adjacency

    c = np.asarray(cost, dtype=np.float64)
    lab = np.asarray(labels, dtype=np.int64).copy()
    t = np.asarray(triangles, dtype=np.int64)
    if c.ndim != 2 or lab.shape != (c.shape[0],) or t.ndim != 2 or t.shape[1] != 3 or (t.size and t.max() >= len(lab)):
        raise FitError(f"cost {c.shape}, labels {lab.shape} and triangles {t.shape} do not agree; give (V, M), (V,) "
                       "and (T, 3) indices below V")
    if lab.size and (lab.min() < -1 or lab.max() >= c.shape[1]):
        raise FitError(f"labels must be -1 or 0..{c.shape[1] - 1}")
    if not (np.isfinite(smoothness) and smoothness >= 0) or int(sweeps) < 1:
        raise FitError(f"smoothness {smoothness!r} / sweeps {sweeps!r}: give smoothness >= 0 and sweeps >= 1")
    v, k = c.shape
    adj = adjacency(t, v)
    adj.data[:] = 1.0
    movable = (lab >= 0) & np.isfinite(c[np.arange(v), np.maximum(lab, 0)])
    rng = np.random.default_rng(seed)
    for _ in range(int(sweeps)):
        has = lab >= 0
        onehot = sparse.csr_matrix((np.ones(int(has.sum())), (np.flatnonzero(has), lab[has])), shape=(v, k))
        total = c - smoothness * np.asarray((adj @ onehot).todense())
        new = np.argmin(total, axis=1)
        now = np.take_along_axis(total, np.maximum(lab, 0)[:, None], 1)[:, 0]
        better = movable & (np.take_along_axis(total, new[:, None], 1)[:, 0] < now)
        if not better.any():
            break
        change = better & (rng.random(v) < 0.5)
        lab[change] = new[change]
    return lab.astype(np.int32)


def unexplained_pieces(cost_own: ArrayLike, labels: ArrayLike, triangles: ArrayLike, vertex_area: ArrayLike, *,
                       min_area: float, cap_nats: float = UNARY_CAP_NATS) -> list[NDArray[np.int64]]:
    """Connected pieces of one region whose vertices another material explains better, by the cap, than the region's.

    A region's fitted material can be the best of the regions' and still not explain some of its
    vertices: a material the segmentation never gave a region of its own (a gold beak split between
    the head's region and the lacquer's) has no region to move to in :func:`relabel_vertices`.  Scored
    against rival materials as well (:func:`vertex_material_costs` with the region's material first),
    such vertices cost the region's material the full cap.  A connected piece of them within one
    region, of at least ``min_area``, is a candidate region of its own.

    Parameters
    ----------
    cost_own
        ``(V,)`` each vertex's cost (nats) of its own region's material against the rivals.
    labels
        ``(V,)`` region of each vertex, -1 not measured.
    triangles
        ``(T, 3)`` the mesh's triangles (their edges join a piece).
    vertex_area
        ``(V,)`` area of each vertex (mm2; a third of its faces').
    min_area
        Smallest piece (mm2).
    cap_nats
        The cost at which a vertex counts as unexplained (the cap of :func:`vertex_material_costs`).

    Returns
    -------
    list of ndarray
        The pieces' vertex indices, largest first.

    Examples
    --------
    Two triangles of one region; three vertices at the cap form one piece of 3 mm2:

    >>> p = unexplained_pieces([4, 4, 4, 0], [0, 0, 0, 0], [[0, 1, 2], [1, 2, 3]], [1, 1, 1, 1], min_area=2)
    >>> [x.tolist() for x in p]
    [[0, 1, 2]]
    """
    from scipy import sparse
    from scipy.sparse.csgraph import connected_components

    c = np.asarray(cost_own, dtype=np.float64)
    lab = np.asarray(labels, dtype=np.int64)
    t = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    area = np.asarray(vertex_area, dtype=np.float64)
    if c.shape != lab.shape or area.shape != lab.shape or (t.size and t.max() >= len(lab)):
        raise FitError(f"cost {c.shape}, labels {lab.shape}, areas {area.shape} and triangles {t.shape} do not "
                       "agree; give (V,), (V,), (V,) and (T, 3) indices below V")
    bad = (lab >= 0) & (c >= cap_nats * (1.0 - 1e-9))
    e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    e = e[bad[e[:, 0]] & bad[e[:, 1]] & (lab[e[:, 0]] == lab[e[:, 1]])]
    graph = sparse.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(len(lab), len(lab)))
    _, piece = connected_components(graph, directed=False)
    piece = np.where(bad, piece, -1)
    sizes = np.bincount(piece[bad], weights=area[bad], minlength=int(piece.max()) + 1 if bad.any() else 0)
    keep = [int(k) for k in np.argsort(-sizes) if sizes[k] >= min_area]
    return [np.flatnonzero(piece == k) for k in keep]
