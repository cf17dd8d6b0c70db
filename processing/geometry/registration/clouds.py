"""Validated point clouds and their voxel pyramids, with normals, roughness and nearest-neighbour grids.

Every cloud given to the registration is checked once (:func:`_as_cloud`)
and downsampled lazily per voxel size (:class:`_Cloud`, :class:`_Level`);
see docs/processing.md, section "Registration of passes".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from processing.geometry.registration.presets import RegistrationError

__all__ = ["MIN_POINTS", "PARALLEL_QUERY_POINTS", "SAME_FACE_DEG", "query_workers"]


#: Fewest points a cloud must have to be registered.
MIN_POINTS = 10

#: Fewest query points for which a k-d tree query runs on every core (``workers=-1``).  SciPy starts
#: one thread per core for every such query; the registration makes thousands of queries of at most
#: a preset's ``icp_points`` (5000 for draft), where starting the threads costs more than they save:
#: one thread for them took a draft registration of three hawk passes from 37.9 to 26.3 s of CPU (53
#: to 33 s on 2 busy cores), the same poses and mesh bit for bit (a query's answer does not depend on
#: its threads); a 10 000-point query took 8.1 ms in one thread and 9.5 ms in two on an idle machine.
PARALLEL_QUERY_POINTS = 50_000


def query_workers(n_points: int) -> int:
    """The ``workers`` argument of a :meth:`scipy.spatial.cKDTree.query` of ``n_points`` points.

    Parameters
    ----------
    n_points
        Number of query points.

    Returns
    -------
    int
        ``-1`` (every core) from :data:`PARALLEL_QUERY_POINTS` points on, else ``1``.

    Examples
    --------
    >>> query_workers(5_000), query_workers(200_000)
    (1, -1)
    """
    return -1 if n_points >= PARALLEL_QUERY_POINTS else 1


class _NearestGrid:
    """Nearest target point of every cell of a regular grid: O(1) approximate nearest neighbours.

    Cells farther than ``reach`` from every point hold the index ``len(points)``:
    callers append a sentinel point far away (see :attr:`_Level.padded`).
    """

    def __init__(self, points: NDArray[np.float64], cell: float, reach: float, max_cells: int = 300_000):
        lo = points.min(axis=0) - reach
        hi = points.max(axis=0) + reach
        ext = hi - lo
        cell = max(cell, float(np.prod(ext) / max_cells) ** (1.0 / 3.0))
        shape = np.maximum(np.ceil(ext / cell).astype(int), 1)
        axes = [lo[k] + (np.arange(shape[k]) + 0.5) * cell for k in range(3)]
        centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        # cells farther than ``reach`` from the cloud point at a sentinel far away (no match)
        _, idx = cKDTree(points).query(centres, distance_upper_bound=reach + cell, workers=query_workers(len(centres)))
        self.lo, self.cell, self.shape = lo, cell, shape
        self.index = idx.astype(np.int32)  # len(points) where nothing is within reach

    def __call__(self, x: NDArray[np.float64]) -> NDArray[np.int32]:
        ijk = np.floor((x - self.lo) / self.cell).astype(np.int64)
        np.clip(ijk, 0, self.shape - 1, out=ijk)
        flat = (ijk[..., 0] * self.shape[1] + ijk[..., 1]) * self.shape[2] + ijk[..., 2]
        return self.index[flat]


@dataclass
class _Level:
    """A cloud downsampled on one voxel grid, with lazily built search structures."""

    points: NDArray[np.float64]
    normals: NDArray[np.float64]
    _pcd: Any = None
    _tree: cKDTree | None = None
    _roughness: dict[float, float] = field(default_factory=dict)
    _grids: dict[tuple[float, float], Any] = field(default_factory=dict)

    @property
    def pcd(self) -> Any:
        """The level as an Open3D point cloud with normals (built once)."""
        if self._pcd is None:
            import open3d as o3d

            self._pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(self.points))
            self._pcd.normals = o3d.utility.Vector3dVector(self.normals)
        return self._pcd

    def source_sample(self, max_points: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Points and normals of the level as an ICP source: at most ``max_points`` (an even stride)."""
        every = max(1, math.ceil(len(self.points) / max_points))
        return self.points[::every], self.normals[::every]

    def partners(
        self, x: NDArray[np.float64], nx: NDArray[np.float64], reach: float, min_cos: float,
        signed: bool = True, k: int = 8,
    ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """Nearest point of the level within ``reach`` (mm) whose normal agrees with ``nx``, for each of ``x``.

        The normals agree when their cosine is at least ``min_cos`` (its
        absolute value unless ``signed``).  Across a thin wall (a bowl's, a
        cup's) the nearest point is often on the other face, a wall's
        thickness away with its normal reversed; pairing it pulls the pose
        toward the middle of the wall.  Where the nearest point disagrees,
        the ``k`` nearest are searched for one that agrees.

        Returns
        -------
        distance, index
            ``(N,)`` each: the partner's distance (inf where there is none)
            and index (``len(points)`` where there is none), as
            :meth:`scipy.spatial.cKDTree.query` reports a miss.
        """
        n = len(self.points)
        d, idx = self.tree.query(x, distance_upper_bound=reach, workers=query_workers(len(x)))
        hit = np.isfinite(d)
        cos = np.einsum("ij,ij->i", nx[hit], self.normals[idx[hit]])
        bad = np.flatnonzero(hit)[(cos if signed else np.abs(cos)) < min_cos]
        if len(bad):
            d[bad], idx[bad] = np.inf, n
            if k > 1 and n > 1:
                kk = min(k, n)
                d2, i2 = self.tree.query(x[bad], k=kk, distance_upper_bound=reach, workers=query_workers(len(bad)))
                c2 = np.einsum("ikj,ij->ik", self.normals[np.minimum(i2, n - 1)], nx[bad])
                ok = np.isfinite(d2) & ((c2 if signed else np.abs(c2)) >= min_cos)
                has = ok.any(axis=1)
                first = np.argmax(ok, axis=1)[has]
                d[bad[has]] = d2[has, first]
                idx[bad[has]] = i2[has, first]
        return d, idx

    def grid(self, cell: float, reach: float) -> _NearestGrid:
        """Nearest-neighbour lookup grid of the level (cached), see :class:`_NearestGrid`."""
        key = (float(cell), float(reach))
        if key not in self._grids:
            self._grids[key] = _NearestGrid(self.points, cell, reach)
        return self._grids[key]

    @property
    def padded(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Points and normals with a sentinel point far away appended (index ``len(points)``)."""
        far = np.abs(self.points).max() * 1e3 + 1e6
        return (np.concatenate([self.points, [[far, far, far]]]),
                np.concatenate([self.normals, [[0.0, 0.0, 0.0]]]))

    @property
    def tree(self) -> cKDTree:
        """k-d tree of the level's points (built once)."""
        if self._tree is None:
            self._tree = cKDTree(self.points)
        return self._tree

    def roughness(self, spacing: float) -> float:
        """Robust RMS point-to-plane residual of each point against a neighbour at least ``spacing / 2`` away (mm).

        What a perfect registration leaves of two samplings of this surface
        with sample spacing ``spacing`` (noise, relief between samples,
        normals).  The distance floor keeps a
        profile's own next point (much closer than the profiles are apart in
        scan data) from making the estimate too small.  A level of a single
        point has no neighbour to measure against: its roughness is 0.
        """
        key = round(float(spacing), 9)
        if key not in self._roughness:
            n = len(self.points)
            k = min(9, n)
            if k < 2:
                self._roughness[key] = 0.0
                return 0.0
            dist, idx = self.tree.query(self.points, k=k, workers=query_workers(n))
            dist, idx = dist.reshape(n, k), idx.reshape(n, k)   # k = 1 would give 1-D arrays
            far = dist[:, 1:] >= 0.5 * spacing
            first = np.where(far.any(axis=1), np.argmax(far, axis=1), k - 2) + 1
            j = idx[np.arange(len(idx)), first]
            r = np.einsum("ij,ij->i", self.points - self.points[j], self.normals[j])
            self._roughness[key] = float(np.sqrt(np.median(r * r) / 0.4549))  # median of chi2(1)
        return self._roughness[key]


@dataclass
class _Cloud:
    """A validated cloud with its pyramid of downsampled levels (cached per voxel size)."""

    points: NDArray[np.float64]
    normals: NDArray[np.float64] | None
    name: str
    levels: dict[tuple[float, bool], _Level] = field(default_factory=dict)
    _spacing: float | None = None

    @property
    def oriented(self) -> bool:
        """Whether normals were given (hence oriented)."""
        return self.normals is not None

    @property
    def diagonal(self) -> float:
        """Bounding-box diagonal of the points (mm)."""
        return float(np.linalg.norm(self.points.max(axis=0) - self.points.min(axis=0)))

    @property
    def spacing(self) -> float:
        """Mean distance between samples on the surface (mm): ``1 / sqrt(density)``.

        It comes from the distance ``d_8`` to the 8th nearest neighbour (``pi d_8^2`` holds
        8 samples), which spans neighbouring profiles of unevenly sampled scans.
        """
        if self._spacing is None:
            every = max(1, len(self.points) // 2000)
            k = min(9, len(self.points))
            d, _ = cKDTree(self.points).query(self.points[::every], k=k, workers=query_workers(len(self.points) // every))
            self._spacing = float(np.median(d.reshape(len(d), k)[:, -1]) * math.sqrt(math.pi / max(k - 1, 1)))
        return self._spacing

    def level(self, voxel: float, fallback: bool = True) -> _Level:
        """The cloud downsampled on a ``voxel`` grid (mm), with unit normals.

        Where the neighbourhood is too thin for a normal, the normal of a
        level twice as coarse is used (``fallback``).
        """
        key = (float(voxel), fallback)
        if key not in self.levels:
            coarser = None
            if fallback and 2.0 * voxel < 0.25 * self.diagonal:
                coarser = lambda: self.level(2.0 * voxel, fallback=False)
            self.levels[key] = _Level(*_downsample(self.points, self.normals, float(voxel), coarser))
        return self.levels[key]


#: Neighbours whose input normals differ by more than this angle are on another face (deg).
SAME_FACE_DEG = 60.0


def _downsample(
    points: NDArray[np.float64],
    normals: NDArray[np.float64] | None,
    voxel: float,
    coarser: Any = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Voxel-grid average of the points, with normals fitted to the neighbourhood (PCA).

    Fitted normals describe the sampled surface at this scale better than
    averaged input normals; the input normals, when given, only orient them
    (otherwise they point away from the centroid) and keep the other face of
    a thin wall out of the fit: of the 20 nearest neighbours within
    ``3 voxel``, those whose averaged input normal is more than
    :data:`SAME_FACE_DEG` from the point's are left out (a bowl's wall is
    thinner than the gap between a scan's profiles, and its inner face's
    points would tilt the outer face's normals).  Scan data is sampled
    unevenly (dense along a profile, sparser across profiles): where the
    neighbours are nearly collinear (the middle eigenvalue of their
    covariance below 5 % of the largest), fewer than three, or fit a normal
    more than :data:`SAME_FACE_DEG` from the averaged input normal (one
    profile's points across a rounded rim lie in the profile's plane, and
    the fit returns that plane's normal), the normal of
    the nearest point of the ``coarser`` level (a callable returning it) is
    used instead; without a coarser level, the averaged input normal made
    perpendicular to the line the neighbours lie on (along a rounded rim:
    across it, not tilted along it).
    """
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    if normals is not None:
        pcd.normals = o3d.utility.Vector3dVector(normals)
    down = pcd.voxel_down_sample(voxel)
    p = np.asarray(down.points).copy()
    guide = np.asarray(down.normals).copy() if normals is not None else p - p.mean(axis=0)
    k = min(20, len(p))
    dist, idx = cKDTree(p).query(p, k=k, distance_upper_bound=3.0 * voxel, workers=query_workers(len(p)))
    dist, idx = dist.reshape(len(p), k), idx.reshape(len(p), k)
    use = np.isfinite(dist)
    idx = np.minimum(idx, len(p) - 1)
    if normals is not None:
        unit = guide / np.maximum(np.linalg.norm(guide, axis=1, keepdims=True), 1e-300)
        use &= np.einsum("ikj,ij->ik", unit[idx], unit) >= math.cos(math.radians(SAME_FACE_DEG))
    count = use.sum(axis=1)
    w = use / np.maximum(count, 1)[:, None]
    centred = p[idx] - np.einsum("ik,ikj->ij", w, p[idx])[:, None, :]
    cov = np.einsum("ik,ikj,ikl->ijl", w, centred, centred)
    evals, evecs = np.linalg.eigh(cov)
    n = evecs[:, :, 0].copy()
    bad = (evals[:, 1] < 0.05 * np.maximum(evals[:, 2], 1e-300)) | (count < 3)
    if normals is not None:
        # neighbours all from one profile across a curved rim lie in the profile's plane, whose
        # normal the fit returns: a fitted normal far from the input normals is not the surface's
        bad |= np.abs(np.sum(n * unit, axis=1)) < math.cos(math.radians(SAME_FACE_DEG))
    if bad.any() and coarser is not None:
        lvl = coarser()
        _, near = lvl.tree.query(p[bad], workers=query_workers(int(np.count_nonzero(bad))))
        n[bad] = lvl.normals[near]
    elif bad.any() and normals is not None:
        # no coarser level: the input normal made perpendicular to the line the neighbours lie on
        line = np.where((count[bad] >= 2)[:, None], evecs[bad, :, 2], 0.0)
        g = guide[bad] - np.sum(guide[bad] * line, axis=1, keepdims=True) * line
        size = np.linalg.norm(g, axis=1, keepdims=True)
        n[bad] = np.where(size > 1e-9, g / np.maximum(size, 1e-300), n[bad])
    flip = np.sum(n * guide, axis=1) < 0
    n[flip] *= -1.0
    return p, n


def _check_search_level(cloud: _Cloud, voxel: float, scale: float) -> None:
    """Refuse a cloud of which the pair's coarsest (search) level keeps fewer than :data:`MIN_POINTS` points.

    A cloud far smaller than its partner (a few mm against a whole object)
    collapses to a point or two on the ``voxel`` grid (mm) the pair is
    searched on; no pose can be found or checked from so few.
    """
    n = len(cloud.level(voxel).points)
    if n < MIN_POINTS:
        raise RegistrationError(
            f"{cloud.name}: only {n} point(s) remain on the {voxel:.3g} mm grid the pair is searched on "
            f"(registration needs at least {MIN_POINTS}): it spans {cloud.diagonal:.3g} mm of the clouds' "
            f"{scale:.3g} mm; register clouds of similar extent, or crop the larger one to the overlap"
        )


def _as_cloud(points: ArrayLike, normals: ArrayLike | None, name: str) -> _Cloud:
    """A checked cloud: ``(N, 3)`` finite points, at least :data:`MIN_POINTS`, spanning a volume."""
    try:
        p = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise RegistrationError(f"{name}: points must be an (N, 3) array in mm: {exc}") from None
    if p.ndim != 2 or p.shape[1] != 3:
        raise RegistrationError(f"{name}: points must be an (N, 3) array in mm, got shape {p.shape}")
    if len(p) == 0:
        raise RegistrationError(f"{name} is empty: it has no points to register")
    bad = ~np.all(np.isfinite(p), axis=1)
    if bad.any():
        raise RegistrationError(
            f"{name} has {int(bad.sum())} NaN or infinite points of {len(p)}; drop them first "
            "(e.g. points[np.isfinite(points).all(axis=1)])"
        )
    if len(p) < MIN_POINTS:
        raise RegistrationError(
            f"{name} has only {len(p)} point(s); registration needs at least {MIN_POINTS}"
        )
    centred = p - p.mean(axis=0)
    sv = np.linalg.svd(centred[:: max(1, len(p) // 20000)], compute_uv=False)
    if sv[0] == 0.0:
        raise RegistrationError(f"{name}: all {len(p)} points coincide; there is no shape to register")
    if sv[1] <= 1e-6 * sv[0]:
        raise RegistrationError(
            f"{name}: all points lie on a line; a line's rotation about itself cannot be registered"
        )
    if sv[2] <= 1e-6 * sv[0]:
        raise RegistrationError(
            f"{name}: all points lie in one plane; a plane slides and turns within itself, so "
            "it cannot be registered (scan some relief or use picked points)"
        )
    n_arr = None
    if normals is not None:
        n_arr = np.asarray(normals, dtype=np.float64)
        if n_arr.shape != p.shape:
            raise RegistrationError(
                f"{name}: normals must have the shape of the points {p.shape}, got {n_arr.shape}"
            )
        if not np.all(np.isfinite(n_arr)):
            raise RegistrationError(f"{name}: normals contain NaN or infinite values")
    return _Cloud(points=p, normals=n_arr, name=name)
