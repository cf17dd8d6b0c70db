"""The interior of a region of one material: the vertices whose photos see that material alone.

Near the border between two materials a pixel mixes both (the lens blur and the demosaicing spread
a pixel over two or three), and the segmentation places the border itself to within a few vertices.
A fit by least squares over a region is pulled by those mixed observations out of proportion to
their number: half a percent of a gold beak's observations in a shibuichi head moves its Ag share by
more than a point.  :func:`interior_vertices` keeps the vertices farther than a margin from the
region's border (geodesic distance along the mesh's edges, :func:`border_distance_mm`); a region too
small to have such an interior keeps its innermost share instead, so it is still fitted.

References
----------
Dijkstra, E. W. (1959). A note on two problems in connexion with graphs. Numerische Mathematik
1, 269-271. doi:10.1007/BF01386390
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.appearance._surface_features import adjacency
from processing.appearance.frame_poses import AppearanceError

__all__ = ["border_distance_mm", "interior_vertices", "MARGIN_PIXELS", "MIN_INTERIOR_SHARE"]

#: Margin of a region's interior in pixels of the photos (blur and demosaicing mix about 2-3).
MARGIN_PIXELS = 3.0
#: A region whose interior is smaller than this share of it keeps its innermost share instead.
MIN_INTERIOR_SHARE = 0.25


def border_distance_mm(vertex_region: ArrayLike, vertices: ArrayLike, triangles: ArrayLike) -> NDArray[np.float64]:
    """Geodesic distance (mm, along the mesh's edges) of every vertex to the border of its region.

    A vertex with a neighbour of another label (``-1``, not measured, included) is on the border
    (distance 0).

    Parameters
    ----------
    vertex_region
        ``(V,)`` region label of each vertex.
    vertices, triangles
        The mesh (mm).

    Returns
    -------
    ndarray
        ``(V,)``; ``inf`` for a vertex of a component with no border (one label everywhere).

    Examples
    --------
    A strip of 6 vertices 1 mm apart, labels 0 0 0 0 1 1:

    >>> v = np.c_[np.arange(6.0), np.zeros(6), np.zeros(6)]
    >>> t = np.array([[0, 1, 1], [1, 2, 2], [2, 3, 3], [3, 4, 4], [4, 5, 5]])
    >>> border_distance_mm([0, 0, 0, 0, 1, 1], v, t).tolist()
    [3.0, 2.0, 1.0, 0.0, 0.0, 1.0]
    """
    from scipy.sparse.csgraph import dijkstra

    lab = np.asarray(vertex_region, dtype=np.int64).reshape(-1)
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    if lab.shape != (len(v),):
        raise AppearanceError(f"region labels: need one per vertex ({len(v)}), got {lab.shape}")
    a = adjacency(t, len(v), v).tocoo()
    differs = lab[a.row] != lab[a.col]
    border = np.zeros(len(v), dtype=bool)
    border[a.row[differs]] = True
    if not border.any():
        return np.full(len(v), np.inf)
    same = ~differs
    from scipy import sparse

    graph = sparse.csr_matrix((a.data[same], (a.row[same], a.col[same])), shape=(len(v), len(v)))
    return np.asarray(dijkstra(graph, directed=False, indices=np.flatnonzero(border), min_only=True))


def interior_vertices(ids: ArrayLike, distance_mm: ArrayLike, margin_mm: float,
                      min_share: float = MIN_INTERIOR_SHARE) -> NDArray[np.intp]:
    """The vertices of a region (``ids``) at least ``margin_mm`` from its border.

    Parameters
    ----------
    ids
        The region's vertex indices.
    distance_mm
        ``(V,)`` :func:`border_distance_mm`.
    margin_mm
        The margin (>= 0).
    min_share
        When fewer than this share of ``ids`` lie beyond the margin, the innermost ``min_share`` of
        them (at least one vertex) are returned instead.

    Returns
    -------
    ndarray
        Sorted vertex indices, a subset of ``ids``.

    Examples
    --------
    >>> d = np.array([3.0, 2.0, 1.0, 0.0, 0.0, 1.0])
    >>> interior_vertices([0, 1, 2, 3], d, 1.5).tolist()
    [0, 1]
    >>> interior_vertices([4, 5], d, 1.5).tolist()          # no interior: the innermost quarter
    [5]
    """
    idx = np.asarray(ids, dtype=np.intp).reshape(-1)
    if not (math.isfinite(margin_mm) and margin_mm >= 0):
        raise AppearanceError(f"region interior: the margin must be >= 0 mm, got {margin_mm!r}")
    if idx.size == 0:
        return idx
    d = np.asarray(distance_mm, dtype=np.float64)[idx]
    inside = idx[d >= margin_mm]
    if inside.size >= min_share * idx.size:
        return np.sort(inside)
    keep = max(1, int(math.ceil(min_share * idx.size)))
    return np.sort(idx[np.argsort(-d, kind="stable")[:keep]])
