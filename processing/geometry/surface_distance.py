"""Distance between a reconstructed surface and a ground-truth surface.

The accuracy of a reconstruction is measured as in the surface-reconstruction
benchmarks (Berger et al. 2013, "A benchmark for surface reconstruction",
section 5; Aspert et al. 2002, "MESH: measuring errors between surfaces using
the Hausdorff distance"): points are sampled uniformly by area on one
surface and their exact distance to the other surface (the nearest point on
any triangle, Open3D ``RaycastingScene.compute_distance``) is recorded, in
both directions:

* reconstruction -> truth: is every reconstructed point on the object?
  (catches bulges, spurious sheets, wrong fills);
* truth -> reconstruction: is every part of the object reconstructed?
  (catches missing parts, smoothed-away detail).

Mean, median, 95th percentile and maximum of each are reported, and the
same statistics over a chosen set of triangles of the reconstruction (the
filled holes) toward the truth.

References
----------
.. [1] Berger, M., Levine, J. A., Nonato, L. G., Taubin, G., Silva, C. T.
   (2013). A benchmark for surface reconstruction. ACM TOG 32(2).
.. [2] Aspert, N., Santa-Cruz, D., Ebrahimi, T. (2002). MESH: measuring
   errors between surfaces using the Hausdorff distance. ICME 2002.

Examples
--------
>>> import open3d as o3d
>>> a = o3d.geometry.TriangleMesh.create_sphere(10.0, resolution=40)
>>> va, ta = np.asarray(a.vertices), np.asarray(a.triangles)
>>> d = surface_distance(va * 1.01, ta, va, ta, n_samples=2000)
>>> bool(0.09 < d.to_truth.mean < 0.11)
True
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.errors import InputError
from processing.geometry.mesh_support import triangle_areas

__all__ = ["DistanceStats", "SurfaceDistance", "surface_distance", "sample_surface", "distance_to_mesh"]


@dataclass(frozen=True)
class DistanceStats:
    """Statistics of point-to-surface distances (mm).

    Attributes
    ----------
    mean, median, p95, max
        Mean, median, 95th percentile and largest distance (mm); NaN when
        there are none.
    n
        Number of distances.
    """

    mean: float
    median: float
    p95: float
    max: float
    n: int

    @classmethod
    def of(cls, d: NDArray[np.float64]) -> DistanceStats:
        """Statistics of an array of distances.

        Parameters
        ----------
        d
            Distances (mm).

        Returns
        -------
        DistanceStats
            Their statistics.
        """
        if d.size == 0:
            return cls(float("nan"), float("nan"), float("nan"), float("nan"), 0)
        return cls(float(d.mean()), float(np.median(d)), float(np.percentile(d, 95)), float(d.max()), int(d.size))


@dataclass(frozen=True)
class SurfaceDistance:
    """Result of :func:`surface_distance`.

    Attributes
    ----------
    to_truth
        Reconstruction -> truth.
    from_truth
        Truth -> reconstruction.
    region
        Chosen triangles of the reconstruction -> truth (None when no
        region was given).
    """

    to_truth: DistanceStats
    from_truth: DistanceStats
    region: DistanceStats | None

    @property
    def mean(self) -> float:
        """Symmetric mean distance: the mean of the two directions (mm)."""
        return 0.5 * (self.to_truth.mean + self.from_truth.mean)


def _check_mesh(vertices: ArrayLike, triangles: ArrayLike, name: str) -> tuple[NDArray, NDArray]:
    """A checked mesh: non-empty, finite vertices, triangles indexing them."""
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles)
    if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] == 0:
        raise InputError(f"{name} vertices must be a non-empty (V, 3) array, got {v.shape}")
    if t.ndim != 2 or t.shape[1] != 3 or t.shape[0] == 0:
        raise InputError(f"{name} triangles must be a non-empty (T, 3) array, got {t.shape}")
    if not np.all(np.isfinite(v)):
        raise InputError(f"{name} vertices hold NaN or infinite coordinates")
    t = t.astype(np.int64)
    if t.min() < 0 or t.max() >= v.shape[0]:
        raise InputError(f"{name} triangles index vertices outside 0..{v.shape[0] - 1}")
    return v, t


def sample_surface(
    vertices: ArrayLike,
    triangles: ArrayLike,
    n: int,
    *,
    seed: int = 0,
    subset: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """``n`` points uniformly distributed by area on a triangle mesh.

    Parameters
    ----------
    vertices, triangles
        The mesh.
    n
        Number of points.
    seed
        Random seed.
    subset
        Optional indices of the triangles to sample (default: all).

    Returns
    -------
    ndarray
        ``(n, 3)`` points (mm).

    Raises
    ------
    ValueError
        The mesh (or the chosen triangles) has zero area.

    Examples
    --------
    >>> p = sample_surface([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], 1000)
    >>> bool(np.all(p[:, 0] + p[:, 1] <= 1.0 + 1e-12)), p.shape
    (True, (1000, 3))
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    if subset is not None:
        t = t[np.asarray(subset, dtype=np.int64)]
    area = triangle_areas(v, t)
    total = area.sum()
    if not total > 0:
        raise InputError("the mesh (or the chosen triangles) has zero area; nothing to sample")
    rng = np.random.default_rng(seed)
    idx = rng.choice(t.shape[0], size=int(n), p=area / total)
    r1 = np.sqrt(rng.random(int(n)))
    r2 = rng.random(int(n))
    a, b, c = v[t[idx, 0]], v[t[idx, 1]], v[t[idx, 2]]
    return (1.0 - r1)[:, None] * a + (r1 * (1.0 - r2))[:, None] * b + (r1 * r2)[:, None] * c


def distance_to_mesh(points: ArrayLike, vertices: ArrayLike, triangles: ArrayLike) -> NDArray[np.float64]:
    """Unsigned distance (mm) from points to the nearest point of a mesh.

    Coordinates are shifted to the mesh's centre before the float32 ray
    tracer sees them, so large offsets do not cost precision.

    Parameters
    ----------
    points
        Points (mm), reshaped to ``(N, 3)``.
    vertices, triangles
        The mesh (mm).

    Returns
    -------
    ndarray
        float64 ``(N,)`` distances (mm).

    Examples
    --------
    >>> distance_to_mesh([[0.2, 0.2, 3.0]], [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]]).round(6).tolist()
    [3.0]
    """
    import open3d as o3d

    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.ascontiguousarray(v - centre, np.float32)),
        o3d.core.Tensor(np.ascontiguousarray(t, np.uint32)),
    )
    d = scene.compute_distance(o3d.core.Tensor(np.ascontiguousarray(p - centre, np.float32)))
    return d.numpy().astype(np.float64)


def surface_distance(
    vertices: ArrayLike,
    triangles: ArrayLike,
    truth_vertices: ArrayLike,
    truth_triangles: ArrayLike,
    *,
    n_samples: int = 200_000,
    region_triangles: ArrayLike | None = None,
    seed: int = 0,
) -> SurfaceDistance:
    """Two-sided sampled distance between a reconstruction and the truth.

    Parameters
    ----------
    vertices, triangles
        The reconstruction (mm).
    truth_vertices, truth_triangles
        The ground truth in the same frame (mm).
    n_samples
        Points sampled on each surface (and on the region).
    region_triangles
        Optional indices of triangles of the reconstruction (for instance
        the filled holes) whose distance to the truth is also reported.
    seed
        Random seed of the sampling.

    Returns
    -------
    SurfaceDistance
        The statistics in both directions, and of the region.

    Raises
    ------
    ValueError
        ``n_samples`` below 1, a malformed mesh, region indices outside the
        reconstruction's triangles.
    """
    if int(n_samples) < 1:
        raise InputError(f"n_samples must be >= 1, got {n_samples}")
    v, t = _check_mesh(vertices, triangles, "reconstruction")
    tv, tt = _check_mesh(truth_vertices, truth_triangles, "truth")
    a = sample_surface(v, t, n_samples, seed=seed)
    b = sample_surface(tv, tt, n_samples, seed=seed + 1)
    to_truth = distance_to_mesh(a, tv, tt)
    from_truth = distance_to_mesh(b, v, t)
    region = None
    if region_triangles is not None:
        sel = np.asarray(region_triangles, dtype=np.int64).reshape(-1)
        if sel.size:
            if sel.min() < 0 or sel.max() >= t.shape[0]:
                raise InputError(f"region_triangles must index triangles 0..{t.shape[0] - 1}")
            r = sample_surface(v, t, n_samples, seed=seed + 2, subset=sel)
            region = DistanceStats.of(distance_to_mesh(r, tv, tt))
        else:
            region = DistanceStats.of(np.zeros(0))
    return SurfaceDistance(DistanceStats.of(to_truth), DistanceStats.of(from_truth), region)
