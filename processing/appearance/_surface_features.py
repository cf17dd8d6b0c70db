"""Private helpers of :mod:`processing.appearance.surface_segmentation`: per-vertex statistics over CSR rows.

Everything is vectorised over the observations (sorted by vertex, CSR
offsets): per-vertex medians by one ``lexsort`` per channel, sums by
``np.bincount``, maxima by ``np.maximum.reduceat``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

__all__ = ["irradiance", "group_median", "group_sum", "group_argmax", "chromaticity", "chromaticity_sd",
           "vertex_areas", "adjacency"]


def irradiance(vertex_pos: NDArray[np.float64], frame: NDArray[np.int32], frames: Sequence | None,
               lamp: int) -> NDArray[np.float64]:
    """Relative irradiance ``(d_ref / d)^2`` of a point lamp per observation (1 for distant lamps or no frames).

    Parameters
    ----------
    vertex_pos
        ``(n, 3)`` position in M of each observation's vertex (mm).
    frame
        ``(n,)`` frame index of each observation.
    frames
        The frames' poses (with ``lamps``), or None.
    lamp
        Lamp index.

    Returns
    -------
    ndarray
        ``(n,)`` float64, median 1 over the observations of point lamps.
    """
    n = len(frame)
    if frames is None:
        return np.ones(n)
    pos = np.full((len(frames), 3), np.nan)
    for k, f in enumerate(frames):
        lp = f.lamps[lamp]
        if lp.kind == "point":
            pos[k] = lp.vector
    lamp_pos = pos[frame]
    point = np.isfinite(lamp_pos[:, 0])
    d2 = np.ones(n)
    d2[point] = np.einsum("ij,ij->i", lamp_pos[point] - vertex_pos[point], lamp_pos[point] - vertex_pos[point])
    if point.any():
        d2[point] = np.maximum(d2[point], 1e-6)
        d2[point] /= float(np.median(d2[point]))
    return 1.0 / d2


def group_median(values: NDArray[np.float64], group: NDArray[np.intp], n_groups: int) -> NDArray[np.float64]:
    """Median of ``values`` per group (NaN for empty groups), by one lexsort.

    Parameters
    ----------
    values
        ``(n,)``.
    group
        ``(n,)`` group index.
    n_groups
        Number of groups.

    Returns
    -------
    ndarray
        ``(n_groups,)``.

    Examples
    --------
    >>> group_median(np.array([3.0, 1.0, 2.0, 5.0]), np.array([0, 0, 0, 2]), 3).tolist()
    [2.0, nan, 5.0]
    """
    out = np.full(n_groups, np.nan)
    if len(values) == 0:
        return out
    order = np.lexsort((values, group))
    v, g = values[order], group[order]
    counts = np.bincount(g, minlength=n_groups)
    start = np.concatenate(([0], np.cumsum(counts)[:-1]))
    has = counts > 0
    lo = start[has] + (counts[has] - 1) // 2
    hi = start[has] + counts[has] // 2
    out[has] = 0.5 * (v[lo] + v[hi])
    return out


def group_sum(values: NDArray[np.float64], group: NDArray[np.intp], n_groups: int) -> NDArray[np.float64]:
    """Sum of ``(n,)`` or ``(n, C)`` values per group.

    Parameters
    ----------
    values
        ``(n,)`` or ``(n, C)``.
    group
        ``(n,)`` group index.
    n_groups
        Number of groups.

    Returns
    -------
    ndarray
        ``(n_groups,)`` or ``(n_groups, C)`` (0 for empty groups).
    """
    if values.ndim == 1:
        return np.bincount(group, weights=values, minlength=n_groups)
    return np.stack([np.bincount(group, weights=values[:, c], minlength=n_groups)
                     for c in range(values.shape[1])], axis=1)


def group_argmax(values: NDArray[np.float64], group: NDArray[np.intp], n_groups: int) -> NDArray[np.intp]:
    """Index (into ``values``) of each group's maximum.

    Parameters
    ----------
    values
        ``(n,)``.
    group
        ``(n,)`` group index.
    n_groups
        Number of groups.

    Returns
    -------
    ndarray
        ``(n_groups,)`` intp; -1 for empty groups.
    """
    out = np.full(n_groups, -1, dtype=np.intp)
    if len(values) == 0:
        return out
    order = np.lexsort((values, group))
    g = group[order]
    last = np.flatnonzero(np.r_[g[1:] != g[:-1], True])
    out[g[last]] = order[last]
    return out


def chromaticity(rgb: NDArray[np.float64], floor: float) -> NDArray[np.float64]:
    """``(r, b) = (R, B) / (R + G + B)`` regularised toward neutral: ``floor`` is added to every channel.

    Parameters
    ----------
    rgb
        ``(n, 3)``; negative values count as 0.
    floor
        Added to every channel: a signal far below it reads neutral (1/3, 1/3).

    Returns
    -------
    ndarray
        ``(n, 2)``.

    Examples
    --------
    >>> chromaticity(np.array([[2.0, 1.0, 1.0]]), 0.0).tolist()
    [[0.5, 0.25]]
    """
    x = np.maximum(rgb, 0.0) + floor
    s = x.sum(axis=1, keepdims=True)
    return (x / s)[:, [0, 2]]


def chromaticity_sd(rgb: NDArray[np.float64], var: NDArray[np.float64]) -> NDArray[np.float64]:
    """Noise standard deviation of :func:`chromaticity` (floor 0) by first-order propagation.

    Parameters
    ----------
    rgb
        ``(n, 3)`` signal; negative values count as 0.
    var
        ``(n, 3)`` noise variance of each channel.

    Returns
    -------
    ndarray
        ``(n, 2)`` standard deviations of ``(r, b)``; inf where the signal sums to 0.

    Examples
    --------
    >>> chromaticity_sd(np.array([[1.0, 1.0, 1.0]]), np.array([[0.09, 0.09, 0.09]])).round(4).tolist()
    [[0.0816, 0.0816]]
    """
    x = np.maximum(rgb, 0.0)
    s = x.sum(axis=1)
    ok = s > 0.0
    out = np.full((len(x), 2), np.inf)
    r, b = x[ok, 0] / s[ok], x[ok, 2] / s[ok]
    v = var[ok]
    out[ok, 0] = np.sqrt((1 - r) ** 2 * v[:, 0] + r ** 2 * (v[:, 1] + v[:, 2])) / s[ok]
    out[ok, 1] = np.sqrt((1 - b) ** 2 * v[:, 2] + b ** 2 * (v[:, 0] + v[:, 1])) / s[ok]
    return out


def vertex_areas(vertices: NDArray[np.float64], triangles: NDArray[np.int64]) -> NDArray[np.float64]:
    """A third of the area of every triangle at each vertex.

    Parameters
    ----------
    vertices, triangles
        ``(V, 3)`` mm and ``(T, 3)`` indices.

    Returns
    -------
    ndarray
        ``(V,)`` mm^2.
    """
    a, b, c = (vertices[triangles[:, i]] for i in range(3))
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    return np.bincount(triangles.ravel(), weights=np.repeat(area / 3.0, 3), minlength=len(vertices))


def adjacency(triangles: NDArray[np.int64], n_vertices: int, vertices: NDArray[np.float64] | None = None):
    """Symmetric vertex adjacency of the mesh's edges.

    Parameters
    ----------
    triangles
        ``(T, 3)`` indices.
    n_vertices
        V.
    vertices
        ``(V, 3)`` mm: weight each edge by its length; None: weight 1.

    Returns
    -------
    scipy.sparse.csr_matrix
        ``(V, V)``, non-zero where two vertices share an edge.
    """
    from scipy import sparse

    e = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    e = np.sort(e, axis=1).astype(np.int64)
    key = np.unique(e[:, 0] * np.int64(max(n_vertices, 1)) + e[:, 1])     # rows in lexicographic order
    e = np.stack([key // max(n_vertices, 1), key % max(n_vertices, 1)], axis=1)
    e = e[e[:, 0] != e[:, 1]]
    w = np.ones(len(e)) if vertices is None else np.maximum(
        np.linalg.norm(vertices[e[:, 0]] - vertices[e[:, 1]], axis=1), 1e-9)
    return sparse.csr_matrix((np.concatenate([w, w]), (np.concatenate([e[:, 0], e[:, 1]]),
                                                       np.concatenate([e[:, 1], e[:, 0]]))),
                             shape=(n_vertices, n_vertices))
