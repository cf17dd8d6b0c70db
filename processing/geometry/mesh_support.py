"""Where a reconstructed mesh is supported by measured data, and its holes.

A reconstruction (Poisson, or any hole filling) also produces surface where
nothing was measured: under the object on the table, in occluded folds, where
a specular surface dropped out.  Following the usual test of the scanning
literature (Curless & Levoy 1996, section 4, "hole filling": surface is
*observed* near samples and *unseen* elsewhere), a mesh vertex is
**supported** when a data point lies within a distance threshold of it, and a
triangle is **unsupported** when any of its vertices is not.  Unsupported
triangles joined through shared edges form one **hole** (a region the
reconstruction filled), reported with

* its area: the sum over its triangles of the triangle area times the
  fraction of the triangle's vertices that are unsupported (so a triangle
  straddling the border counts by the part that lies in the hole);
* the largest and mean distance from its vertices to the data.

The threshold should exceed the point spacing (a vertex between samples is
up to about half a spacing from the nearest one, more where the sampling is
uneven): about four spacings marks real gaps only.  A hole of radius r in
the data would then show as an unsupported region of radius r - threshold
only; so, as in hysteresis thresholding (Canny 1986), a region found with
the threshold is grown over the vertices farther than a lower threshold
(about one spacing) connected to it, and its area is measured there: about
the area of the gap in the data.

References
----------
.. [1] Curless, B., Levoy, M. (1996). A volumetric method for building
   complex models from range images. SIGGRAPH 1996.
.. [2] Canny, J. (1986). A computational approach to edge detection. IEEE
   TPAMI 8(6), 679-698.

Examples
--------
>>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
>>> t = np.array([[0, 1, 2], [1, 3, 2]])
>>> report = mesh_support(v, t, v[:3], threshold_mm=0.5)
>>> report.n_holes, round(report.holes[0].area_mm2, 3), report.holes[0].max_distance_mm
(1, 0.167, 1.0)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from processing.errors import InputError
from processing.geometry.mesh_topology import triangle_components

__all__ = ["Hole", "SupportReport", "mesh_support", "triangle_areas"]


@dataclass(frozen=True)
class Hole:
    """One connected unsupported region of a mesh.

    Attributes
    ----------
    area_mm2
        Area of the region (mm^2), see the module docstring.
    max_distance_mm
        Largest distance (mm) from the region's vertices to the nearest data
        point (exact).
    n_triangles
        Triangles in the region (including those straddling its border).
    centroid
        ``(3,)`` area-weighted centroid of the region (mm).
    triangles
        int64 indices of the region's triangles.
    """

    area_mm2: float
    max_distance_mm: float
    n_triangles: int
    centroid: NDArray[np.float64]
    triangles: NDArray[np.int64]


@dataclass(frozen=True)
class SupportReport:
    """Result of :func:`mesh_support`.

    Attributes
    ----------
    threshold_mm
        Support distance (mm).
    low_threshold_mm
        Distance (mm) over which the regions were grown (= threshold_mm when
        they were not).
    vertex_distance
        ``(V,)`` distance (mm) from every vertex to the nearest data point:
        exact up to twice the threshold, beyond it measured to a voxel grid
        of the data (edge half the threshold) and so within 0.87 threshold
        of the exact value.
    unsupported
        ``(T,)`` bool, True for triangles with a vertex farther than the
        threshold from the data, or in a region grown from one.
    hole_label
        ``(T,)`` index into ``holes`` of each unsupported triangle, -1 for
        supported triangles and for regions smaller than the minimum area.
    holes
        Regions, largest area first.
    mesh_area_mm2
        Total area of the mesh (mm^2).
    """

    threshold_mm: float
    low_threshold_mm: float
    vertex_distance: NDArray[np.float64]
    unsupported: NDArray[np.bool_]
    hole_label: NDArray[np.int64]
    holes: tuple[Hole, ...]
    mesh_area_mm2: float

    @property
    def n_holes(self) -> int:
        """Number of reported holes."""
        return len(self.holes)

    @property
    def hole_area_mm2(self) -> float:
        """Total area of the reported holes (mm^2)."""
        return float(sum(h.area_mm2 for h in self.holes))

    @property
    def max_distance_mm(self) -> float:
        """Largest vertex-to-data distance over the whole mesh (mm)."""
        return float(self.vertex_distance.max()) if self.vertex_distance.size else 0.0


def triangle_areas(vertices: ArrayLike, triangles: ArrayLike) -> NDArray[np.float64]:
    """Areas of the triangles.

    Parameters
    ----------
    vertices
        ``(V, 3)`` positions (mm).
    triangles
        ``(T, 3)`` vertex indices.

    Returns
    -------
    ndarray
        float64 ``(T,)`` areas (mm^2).

    Examples
    --------
    >>> triangle_areas([[0, 0, 0], [2, 0, 0], [0, 3, 0]], [[0, 1, 2]]).tolist()
    [3.0]
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    c = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    return 0.5 * np.sqrt(np.einsum("ij,ij->i", c, c))


def _vertex_distances(tree: cKDTree, v: NDArray[np.float64], threshold: float) -> tuple[NDArray[np.float64], Any]:
    """Nearest-sample distances, exact up to 2 thresholds, voxel-grid estimates beyond.

    An exact nearest-neighbour search from a point far from every sample (in
    a hole, at the centre of a dome) visits a large part of the KD-tree
    (seconds per thousand points on 10^5 samples), so far vertices are
    measured to one representative sample per voxel of edge ``c``
    (the estimate is within ``c sqrt(3)`` of the exact distance); the
    returned function gives the exact largest distance over a set of
    vertices by searching the full tree only from the candidates that can
    hold it.
    """
    bound = 2.0 * threshold
    dist, _ = tree.query(v, distance_upper_bound=bound, workers=-1)
    dist = np.asarray(dist, dtype=np.float64)
    far = ~np.isfinite(dist)
    slack = 0.0
    if far.any():
        data = np.asarray(tree.data)
        edge = 0.5 * threshold
        key = np.floor((data - data.min(axis=0)) / edge).astype(np.int64)
        _, first = np.unique(key, axis=0, return_index=True)
        coarse, _ = cKDTree(data[first]).query(v[far], workers=-1)
        slack = edge * np.sqrt(3.0)
        dist[far] = np.maximum(coarse, bound)

    def exact_max(verts: NDArray[np.int64]) -> float:
        d = dist[verts]
        top = float(d.max())
        if top <= bound or slack == 0.0:
            return top
        cand = verts[d >= top - 2.0 * slack]
        if cand.size > 64:
            cand = cand[np.argsort(-dist[cand])[:64]]
        exact, _ = tree.query(v[cand], workers=-1)
        return float(np.max(exact))

    return dist, exact_max


def mesh_support(
    vertices: ArrayLike,
    triangles: ArrayLike,
    data_points: ArrayLike | None,
    threshold_mm: float,
    *,
    tree: cKDTree | None = None,
    min_hole_area_mm2: float = 0.0,
    low_threshold_mm: float | None = None,
) -> SupportReport:
    """Distances from a mesh to the data and the mesh's unsupported regions.

    Parameters
    ----------
    vertices
        ``(V, 3)`` mesh vertices (mm).
    triangles
        ``(T, 3)`` vertex indices.
    data_points
        ``(N, 3)`` measured points (mm); may be None when ``tree`` is given.
    threshold_mm
        Support distance (mm), > 0.
    tree
        Optional ``scipy.spatial.cKDTree`` of the data points (reused).
    min_hole_area_mm2
        Regions smaller than this are not reported as holes (their triangles
        stay marked unsupported).
    low_threshold_mm
        Optional lower distance (mm, <= ``threshold_mm``) over which regions
        are grown (see the module docstring); None: no growing.

    Returns
    -------
    SupportReport
        Vertex distances, unsupported triangles and the holes.

    Raises
    ------
    ValueError
        Bad shapes, no data, a non-positive threshold.
    """
    v, t, tree, low = _checked_input(vertices, triangles, data_points, threshold_mm, tree, low_threshold_mm)
    dist, exact_far = _vertex_distances(tree, v, float(threshold_mm))
    far_count, unsupported, comp, n_comp = _unsupported_regions(t, dist, low, threshold_mm)
    area = triangle_areas(v, t) if t.size else np.zeros(0)
    labels, holes = _holes(v, t, area, far_count, unsupported, comp, n_comp, exact_far, min_hole_area_mm2)
    return SupportReport(
        threshold_mm=float(threshold_mm),
        low_threshold_mm=low,
        vertex_distance=dist,
        unsupported=unsupported,
        hole_label=labels,
        holes=tuple(holes),
        mesh_area_mm2=float(area.sum()),
    )


def _checked_input(vertices: ArrayLike, triangles: ArrayLike, data_points: ArrayLike | None, threshold_mm: float,
                   tree: cKDTree | None, low_threshold_mm: float | None
                   ) -> tuple[NDArray[np.float64], NDArray[np.int64], cKDTree, float]:
    """The mesh as arrays, a k-d tree of the data and the low threshold (mm), after checking them."""
    if not (np.isfinite(threshold_mm) and threshold_mm > 0):
        raise InputError(f"threshold_mm must be a finite distance > 0 (mm), got {threshold_mm!r}")
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or t.ndim != 2 or t.shape[1] != 3:
        raise InputError(f"vertices must be (V, 3) and triangles (T, 3), got {v.shape} and {t.shape}")
    if tree is None:
        if data_points is None:
            raise InputError("data_points: give the measured points or a KD-tree of them")
        d = np.asarray(data_points, dtype=np.float64)
        if d.ndim != 2 or d.shape[1] != 3 or d.shape[0] == 0:
            raise InputError(f"data_points must be a non-empty (N, 3) array, got {d.shape}")
        tree = cKDTree(d)
    low = float(threshold_mm) if low_threshold_mm is None else float(low_threshold_mm)
    if not (np.isfinite(low) and 0 < low <= threshold_mm):
        raise InputError(f"low_threshold_mm must be in (0, threshold_mm={threshold_mm}], got {low_threshold_mm!r}")
    return v, t, tree, low


def _unsupported_regions(t: NDArray[np.int64], dist: NDArray[np.float64], low: float, threshold_mm: float
                         ) -> tuple[NDArray[np.int64], NDArray[np.bool_], NDArray[np.int64], int]:
    """Vertices beyond ``low`` per triangle, the unsupported triangles, their region labels and count.

    Regions of triangles with a vertex beyond ``low`` are kept when they
    hold a vertex beyond the (high) threshold.
    """
    far_v = dist > low
    far_count = far_v[t].sum(axis=1) if t.size else np.zeros(0, np.int64)
    candidate = far_count > 0
    n_comp, comp = triangle_components(t, candidate) if t.size else (0, np.zeros(0, np.int64))
    if n_comp:
        # keep the grown regions that hold a vertex beyond the (high) threshold
        seed = (dist > threshold_mm)[t].any(axis=1) & candidate
        has_seed = np.bincount(comp[seed], minlength=n_comp) > 0
        unsupported = candidate & has_seed[np.maximum(comp, 0)]
        _, dense = np.unique(comp[unsupported], return_inverse=True)
        comp = np.full(t.shape[0], -1, np.int64)
        comp[unsupported] = dense.reshape(-1)
        n_comp = int(dense.max()) + 1 if dense.size else 0
    else:
        unsupported = candidate
    return far_count, unsupported, comp, n_comp


def _holes(v: NDArray[np.float64], t: NDArray[np.int64], area: NDArray[np.float64], far_count: NDArray[np.int64],
           unsupported: NDArray[np.bool_], comp: NDArray[np.int64], n_comp: int, exact_far: Any,
           min_hole_area_mm2: float) -> tuple[NDArray[np.int64], list[Hole]]:
    """The regions at least ``min_hole_area_mm2`` large as holes, largest first, and each triangle's hole."""
    labels = np.full(t.shape[0], -1, np.int64)
    holes: list[Hole] = []
    if n_comp:
        part = area * far_count / 3.0
        comp_area = np.bincount(comp[unsupported], weights=part[unsupported], minlength=n_comp)
        centre = (v[t[:, 0]] + v[t[:, 1]] + v[t[:, 2]]) / 3.0
        tri_idx = np.flatnonzero(unsupported)
        order = tri_idx[np.argsort(comp[tri_idx], kind="stable")]
        bounds = np.searchsorted(comp[order], np.arange(n_comp + 1))
        ranked = np.argsort(-comp_area, kind="stable")
        for c in ranked:
            if comp_area[c] < min_hole_area_mm2:
                continue
            tris = order[bounds[c]:bounds[c + 1]]
            verts = np.unique(t[tris])
            w = part[tris]
            labels[tris] = len(holes)
            holes.append(
                Hole(
                    area_mm2=float(comp_area[c]),
                    max_distance_mm=exact_far(verts),
                    n_triangles=int(tris.size),
                    centroid=(w[:, None] * centre[tris]).sum(axis=0) / w.sum(),
                    triangles=tris,
                )
            )
    return labels, holes
