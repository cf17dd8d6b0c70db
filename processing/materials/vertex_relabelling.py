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
           "LEVEL_CAP_CHI2", "DECIDED_NATS", "SPLIT_MARGINS_NATS"]

#: Most data cost (nats) one vertex's observations put on a label: a single vertex's few views
#: (a demosaicing error, a view that mixes a neighbour through the lens) cannot outweigh all its
#: neighbours, several vertices that agree can.  The surface segmentation uses the same cap.
UNARY_CAP_NATS = 4.0
#: Potts weight (nats per neighbour of another label), as in the surface segmentation.
SMOOTHNESS_NATS = 1.0
#: A vertex's own observations decide its material when they favour it by this much (nats) over every other:
#: the surface segmentation's confidence margin.  Elsewhere its label is its neighbours'.
DECIDED_NATS = 2.0
#: Prior margins (nats) against "a rival material" in :func:`unexplained_pieces`, strictest first: at 1 nat the
#: noise of the least cost over many rivals stays apart; at 0 a piece whose every vertex leans only a little is
#: found too (on the demo's capture, copper eye rings inside the gold beak's region that no margin of 0.5 or
#: more finds).
SPLIT_MARGINS_NATS = (1.0, 0.0)
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


def unexplained_pieces(cost_own: ArrayLike, cost_rival: ArrayLike, labels: ArrayLike, triangles: ArrayLike,
                       vertex_area: ArrayLike, *, min_area: float, margins: Sequence[float] = SPLIT_MARGINS_NATS,
                       max_share: float = 0.5, smoothness: float = SMOOTHNESS_NATS) -> list[NDArray[np.int64]]:
    """Connected pieces of one region that a rival material explains better than the region's, neighbours agreeing.

    A region's fitted material can be the best of the regions' and still not explain some of its
    vertices: a material the segmentation never gave a region of its own (a gold beak split between
    the head's region and the lacquer's, copper eye rings inside the beak's region) has no region to
    move to in :func:`relabel_vertices`.  Each vertex's cost of its own region's material and of the
    best rival (:func:`vertex_material_costs` with the region's material first) are the data terms of a
    two-label Potts model within each region ("own" or "a rival", the rival's cost raised by a margin:
    the prior that a vertex is not its region's material), relaxed by :func:`relabel_vertices` from the
    vertices' own preference.  One vertex's few views rarely decide (a dark underside, an eye in the
    shadow of a brow), but a piece of vertices that all lean the same way does, and a vertex that leans
    alone returns to its neighbours.  The best rival is the least cost over many materials, so a
    material the region's explains as well is favoured somewhere by chance; the margin keeps such
    noise from joining up, and with a margin of 0 the pieces whose every vertex leans only a little are
    found too.  Connected pieces of "a rival" of at least ``min_area`` and at most ``max_share`` of their
    region (a larger one is the region's own material as its fit sees it) are candidates, for each
    margin in turn.

    Parameters
    ----------
    cost_own, cost_rival
        ``(V,)`` each vertex's cost (nats) of its own region's material and of the best rival.
    labels
        ``(V,)`` region of each vertex, -1 not measured.
    triangles
        ``(T, 3)`` the mesh's triangles (their edges are the neighbourhood and join a piece).
    vertex_area
        ``(V,)`` area of each vertex (mm2; a third of its faces').
    min_area
        Smallest piece (mm2).
    margins
        Nats added to the rival's cost, >= 0, one relaxation each (strictest first).
    max_share
        Largest piece as a share of its region's area, in (0, 1].
    smoothness
        Potts weight (nats per neighbour of the other label).

    Returns
    -------
    list of ndarray
        The pieces' vertex indices: the first margin's, largest first, then the next margin's.  A piece
        found at several margins is listed once; pieces of different margins may overlap.

    Raises
    ------
    FitError
        Shapes that do not agree, a negative margin or a share outside (0, 1].

    Examples
    --------
    A strip of eight triangles, one region: three vertices lean to a rival by 1.5 nats each, the
    others to their own material by 1.  Together the three outweigh their neighbours:

    >>> tri = [[i, i + 1, i + 2] for i in range(8)]
    >>> own = [0, 0, 0, 0, 1.5, 1.5, 1.5, 0, 0, 0]
    >>> rival = [1, 1, 1, 1, 0, 0, 0, 1, 1, 1]
    >>> [p.tolist() for p in unexplained_pieces(own, rival, [0] * 10, tri, [1] * 10, min_area=2)]
    [[4, 5, 6]]

    One vertex leaning alone returns to its neighbours:

    >>> unexplained_pieces([0, 0, 0, 0, 0, 1.5, 0, 0, 0, 0], rival, [0] * 10, tri, [1] * 10, min_area=1)
    []
    """
    from processing.materials.region_consistency import mesh_components

    own = np.asarray(cost_own, dtype=np.float64)
    rival = np.asarray(cost_rival, dtype=np.float64)
    lab = np.asarray(labels, dtype=np.int64)
    t = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    area = np.asarray(vertex_area, dtype=np.float64)
    if not (own.shape == rival.shape == lab.shape == area.shape) or lab.ndim != 1 or (t.size and t.max() >= len(lab)):
        raise FitError(f"costs {own.shape} and {rival.shape}, labels {lab.shape}, areas {area.shape} and triangles "
                       f"{t.shape} do not agree; give (V,), (V,), (V,), (V,) and (T, 3) indices below V")
    margins = [float(m) for m in margins]
    if any(not (np.isfinite(m) and m >= 0) for m in margins):
        raise FitError(f"margins {margins!r}: give nats >= 0")
    if not 0 < max_share <= 1:
        raise FitError(f"max_share {max_share!r}: give a share in (0, 1]")
    measured = lab >= 0
    if not measured.any():
        return []
    n_regions = int(lab.max()) + 1
    region_area = np.bincount(lab[measured], weights=area[measured], minlength=n_regions)
    # label 2r: region r's own material, 2r + 1: a rival within region r -- two regions never agree
    cols = np.full((len(lab), 2 * n_regions), np.inf)
    rows = np.flatnonzero(measured)
    pieces, seen = [], set()
    for margin in margins:
        cols[rows, 2 * lab[rows]] = own[rows]
        cols[rows, 2 * lab[rows] + 1] = rival[rows] + margin
        start = np.where(measured, 2 * lab + (rival + margin < own), -1)
        relaxed = relabel_vertices(cols, start, t, smoothness=smoothness)
        other = measured & (relaxed % 2 == 1)
        piece = mesh_components(np.where(other, lab, -1), t)             # within one region
        sizes = np.bincount(piece[other], weights=area[other], minlength=int(piece.max()) + 1 if other.any() else 0)
        piece_region = np.zeros(len(sizes), dtype=np.int64)
        piece_region[piece[other]] = lab[other]                            # a piece lies within one region
        kept = (sizes >= min_area) & (sizes <= max_share * region_area[piece_region])
        for k in np.flatnonzero(kept)[np.argsort(-sizes[kept], kind="stable")]:
            ids = np.flatnonzero(piece == k)
            if (key := ids.tobytes()) not in seen:
                seen.add(key)
                pieces.append(ids)
    return pieces
