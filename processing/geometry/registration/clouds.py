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

__all__ = ["MIN_POINTS"]


#: Fewest points a cloud must have to be registered.
MIN_POINTS = 10


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
        _, idx = cKDTree(points).query(centres, distance_upper_bound=reach + cell, workers=-1)
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

    def source_pcd(self, max_points: int) -> Any:
        """The level as an ICP source: at most ``max_points`` points (an even stride)."""
        if len(self.points) <= max_points:
            return self.pcd
        every = math.ceil(len(self.points) / max_points)
        return self.pcd.uniform_down_sample(every)

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
        scan data) from making the estimate too small.
        """
        key = round(float(spacing), 9)
        if key not in self._roughness:
            k = min(9, len(self.points))
            dist, idx = self.tree.query(self.points, k=k, workers=-1)
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
            d, _ = cKDTree(self.points).query(self.points[::every], k=k, workers=-1)
            self._spacing = float(np.median(d[:, -1]) * math.sqrt(math.pi / max(k - 1, 1)))
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


def _downsample(
    points: NDArray[np.float64],
    normals: NDArray[np.float64] | None,
    voxel: float,
    coarser: Any = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Voxel-grid average of the points, with normals fitted to the neighbourhood (PCA).

    Fitted normals describe the sampled surface at this scale better than
    averaged input normals; the input normals, when given, only orient them
    (otherwise they point away from the centroid).  Scan data is sampled
    unevenly (dense along a profile, sparser across profiles): where the
    neighbours within ``3 voxel`` are nearly collinear (the middle eigenvalue
    of their covariance below 5 % of the largest), the normal of the nearest
    point of the ``coarser`` level (a callable returning it) is used instead.
    """
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    if normals is not None:
        pcd.normals = o3d.utility.Vector3dVector(normals)
    down = pcd.voxel_down_sample(voxel)
    p = np.asarray(down.points).copy()
    guide = np.asarray(down.normals).copy() if normals is not None else p - p.mean(axis=0)
    down.estimate_covariances(o3d.geometry.KDTreeSearchParamHybrid(radius=3.0 * voxel, max_nn=20))
    evals, evecs = np.linalg.eigh(np.asarray(down.covariances))
    n = evecs[:, :, 0].copy()
    bad = evals[:, 1] < 0.05 * np.maximum(evals[:, 2], 1e-300)
    if bad.any() and coarser is not None:
        lvl = coarser()
        _, idx = lvl.tree.query(p[bad], workers=-1)
        n[bad] = lvl.normals[idx]
    flip = np.sum(n * guide, axis=1) < 0
    n[flip] *= -1.0
    return p, n


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
