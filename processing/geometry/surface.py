"""The surface stage: a merged, oriented, confidence-weighted cloud -> one watertight mesh, holes filled.

Matsuda et al. (section 2) merge laser scans taken from several directions
into one shape and complete the parts no scan saw by fitting smooth
surfaces.  :func:`reconstruct_surface` does the same automatically and
measurably: it checks the cloud, fuses overlapping samples
(:mod:`processing.geometry.fusion`), finds the holes of a coarse screened
Poisson surface (:mod:`processing.geometry.mesh_support`), fits each with a
smooth surface (:mod:`processing.geometry.holes`), reconstructs the final
screened Poisson surface on data and guide points, removes unsupported
pieces, optionally decimates, and reports the topology
(:mod:`processing.geometry.mesh_topology`) and the filled holes.  The steps
and the measured accuracy of the presets are in docs/processing.md, section
"Surface reconstruction".

References
----------
.. [1] Kazhdan, M., Hoppe, H. (2013). Screened Poisson surface
   reconstruction. ACM TOG 32(3), 29. doi:10.1145/2487228.2487237
.. [2] Curless, B., Levoy, M. (1996). A volumetric method for building
   complex models from range images. SIGGRAPH 1996.
.. [3] Garland, M., Heckbert, P. S. (1997). Surface simplification using
   quadric error metrics. SIGGRAPH 1997.
.. [4] Matsuda, Tanaka, Ichikawa, Mochizuki, Muroya, Kitamura. CG
   reproduction of a craft object based on a light reflection model. IPSJ
   technical report.

Examples
--------
>>> k = np.arange(6000) + 0.5                      # a Fibonacci sphere of radius 10 mm
>>> z, phi = 1 - 2 * k / 6000, np.pi * (1 + 5 ** 0.5) * k
>>> d = np.stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z], axis=1)
>>> res = reconstruct_surface(10 * d, d, preset="draft", target_triangles=2000)
>>> res.watertight, res.n_triangles <= 2000
(True, True)
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from processing.errors import InputError
from processing.geometry.fusion import (
    dominated_samples,
    fuse_points,
    noise_level,
    point_spacing,
    validate_oriented_cloud,
)
from processing.geometry.holes import HoleFit, hole_guide_points
from processing.geometry.mesh_support import SupportReport, mesh_support
from processing.geometry.mesh_topology import MeshTopology, mesh_topology, triangle_components
from processing.geometry.surface_types import (
    SURFACE_PRESETS,
    FilledHole,
    SurfacePreset,
    SurfaceResult,
    SurfaceTimings,
)

__all__ = [
    "SurfaceError",
    "SurfacePreset",
    "SURFACE_PRESETS",
    "SurfaceTimings",
    "FilledHole",
    "SurfaceResult",
    "reconstruct_surface",
    "poisson_mesh",
    "decimate_mesh",
    "vertex_normals",
]

#: Fewest points accepted (after dropping low-confidence points).
MIN_POINTS = 100
#: A cloud is flat when its spread across the best plane is below this
#: fraction of its spread along it (numerically coplanar).
_FLAT_RATIO = 1e-4
#: Neighbourhood (in spacings or fusion voxels) in which a better sample outclasses a poor one.
_DOMINANCE_RADIUS = 2.0
#: Holes are grown over vertices farther than this many spacings from the data.
_LOW_SUPPORT_FACTOR = 1.5


class SurfaceError(InputError):
    """The cloud cannot be turned into a surface (bad input or a failed step)."""


def vertex_normals(vertices: ArrayLike, triangles: ArrayLike) -> NDArray[np.float64]:
    """Area-weighted unit vertex normals (a vertex of no triangle gets +z).

    Parameters
    ----------
    vertices
        ``(V, 3)`` positions (mm).
    triangles
        ``(T, 3)`` vertex indices, counter-clockwise seen from outside.

    Returns
    -------
    ndarray
        float64 ``(V, 3)`` unit normals.

    Examples
    --------
    >>> vertex_normals([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])[0].tolist()
    [0.0, 0.0, 1.0]
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    fn = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    acc = np.zeros_like(v)
    flat = t.reshape(-1)
    for k in range(3):
        acc[:, k] = np.bincount(flat, weights=np.repeat(fn[:, k], 3), minlength=v.shape[0])
    length = np.linalg.norm(acc, axis=1)
    out = np.zeros_like(v)
    out[:, 2] = 1.0
    ok = length > 0
    out[ok] = acc[ok] / length[ok, None]
    return out


def _o3d_cloud(points: NDArray, normals: NDArray) -> Any:
    """An Open3D point cloud with normals."""
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    pcd.normals = o3d.utility.Vector3dVector(normals)
    return pcd


def poisson_mesh(
    points: ArrayLike,
    normals: ArrayLike,
    *,
    depth: int,
    scale: float = 1.1,
    samples_per_node: float = 1.5,
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Screened Poisson surface of an oriented cloud (Open3D, linear fit).

    The marching-cubes mesh is returned as extracted, less triangles with a
    repeated vertex index and two-sided fins (the same triangle emitted with
    both orientations on an ambiguous cell; both copies are removed).  It
    can hold slivers whose vertices lie
    within 1e-4 cell of each other; merging such vertices by distance breaks
    the two-manifold at places, so they are left to the decimation, which
    collapses them.

    Parameters
    ----------
    points, normals
        ``(N, 3)`` positions (mm) and outward unit normals.
    depth
        Octree depth.
    scale
        Bounding-cube scale.
    samples_per_node
        Minimum samples per octree node.

    Returns
    -------
    vertices, triangles
        float64 ``(V, 3)``, int64 ``(T, 3)``.

    Raises
    ------
    SurfaceError
        Poisson returned no triangles.

    References
    ----------
    .. [1] Kazhdan, M., Hoppe, H. (2013). Screened Poisson surface
       reconstruction. ACM TOG 32(3), 29. doi:10.1145/2487228.2487237
    """
    import open3d as o3d

    p = np.asarray(points, dtype=np.float64)
    pcd = _o3d_cloud(p, np.asarray(normals, dtype=np.float64))
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        # one thread: Open3D's multi-threaded PoissonRecon crashes at random with a segmentation fault (a
        # known upstream bug, seen once in this project's test suite), and a crash takes the process with it
        mesh, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
            pcd, depth=int(depth), scale=float(scale), linear_fit=True, samples_per_node=float(samples_per_node),
            n_threads=1,
        )
    if len(mesh.triangles) == 0:
        raise SurfaceError(
            f"screened Poisson (depth {depth}) produced no surface from {p.shape[0]} points; "
            "check that the normals point outward and the cloud covers an object"
        )
    mesh.remove_degenerate_triangles()
    mesh.remove_unreferenced_vertices()
    v = np.asarray(mesh.vertices, dtype=np.float64)
    t = np.asarray(mesh.triangles, dtype=np.int64)
    return _drop_fins(v, t)


def _compact(v: NDArray[np.float64], t: NDArray[np.int64]) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Drop vertices no triangle uses and renumber."""
    used = np.zeros(v.shape[0], bool)
    used[t.reshape(-1)] = True
    if used.all():
        return v, t
    remap = np.cumsum(used) - 1
    return v[used], remap[t]


def _drop_fins(v: NDArray[np.float64], t: NDArray[np.int64]) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Remove triangles that occur twice (a flat two-sided fin of zero volume).

    Marching cubes on an ambiguous cell can emit the same triangle with both
    orientations; the pair encloses nothing and makes its edges
    non-manifold, so both copies go.
    """
    key = np.sort(t, axis=1)
    n = v.shape[0]
    if n < 2_000_000:
        flat = (key[:, 0] * n + key[:, 1]) * n + key[:, 2]
        _, inv, cnt = np.unique(flat, return_inverse=True, return_counts=True)
    else:
        _, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    single = cnt[inv.reshape(-1)] == 1
    if single.all():
        return v, t
    return _compact(v, t[single])


def decimate_mesh(
    vertices: ArrayLike, triangles: ArrayLike, target_triangles: int
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Quadric-error decimation (Garland & Heckbert 1997; Open3D) to a target count.

    Parameters
    ----------
    vertices, triangles
        The mesh.
    target_triangles
        Triangle count to reach (>= 4); a mesh already at or below it is
        returned unchanged.

    Returns
    -------
    vertices, triangles
        float64 ``(V', 3)`` (mm) and int64 ``(T', 3)``.

    Raises
    ------
    ValueError
        ``target_triangles`` is not an integer >= 4.

    References
    ----------
    .. [1] Garland, M., Heckbert, P. S. (1997). Surface simplification using
       quadric error metrics. SIGGRAPH 1997.

    Examples
    --------
    >>> import open3d as o3d
    >>> from processing.geometry.mesh_topology import mesh_topology
    >>> s = o3d.geometry.TriangleMesh.create_sphere(1.0, resolution=30)
    >>> v, t = decimate_mesh(np.asarray(s.vertices), np.asarray(s.triangles), 400)
    >>> t.shape[0], mesh_topology(t).watertight
    (400, True)
    """
    import open3d as o3d

    if not (isinstance(target_triangles, (int, np.integer)) and target_triangles >= 4):
        raise InputError(f"target_triangles must be an integer >= 4, got {target_triangles!r}")
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    if t.shape[0] <= target_triangles:
        return v, t
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(t.astype(np.int32)))
    out = mesh.simplify_quadric_decimation(int(target_triangles))
    out.remove_degenerate_triangles()
    out.remove_unreferenced_vertices()
    return np.asarray(out.vertices, dtype=np.float64), np.asarray(out.triangles, dtype=np.int64)


def _check_shape(p: NDArray[np.float64]) -> None:
    """Reject collinear and coplanar clouds."""
    centred = p - p.mean(axis=0)
    s = np.linalg.svd(centred[:: max(1, p.shape[0] // 200_000)], compute_uv=False)
    if s[0] <= 0.0:
        raise SurfaceError(
            f"points: all {p.shape[0]} points coincide at {p[0].tolist()}; a surface needs a 3-D cloud"
        )
    if s[1] <= _FLAT_RATIO * s[0]:
        raise SurfaceError(
            f"points: all {p.shape[0]} points lie on a line; a surface needs points spread in three dimensions"
        )
    if s[2] <= _FLAT_RATIO * s[0]:
        raise SurfaceError(
            f"points: all {p.shape[0]} points lie in one plane (spread across it "
            f"{s[2] / np.sqrt(p.shape[0]):.3g} mm); a closed surface needs points spread in three dimensions"
        )


def _resolve_preset(preset: str | SurfacePreset) -> SurfacePreset:
    """The preset named ``preset`` (or ``preset`` itself)."""
    if isinstance(preset, SurfacePreset):
        return preset
    if isinstance(preset, str) and preset in SURFACE_PRESETS:
        return SURFACE_PRESETS[preset]
    raise InputError(f"preset must be one of {sorted(SURFACE_PRESETS)} or a SurfacePreset, got {preset!r}")


_KEEP = object()


def reconstruct_surface(
    points: ArrayLike,
    normals: ArrayLike | None,
    confidence: ArrayLike | None = None,
    *,
    preset: str | SurfacePreset = "standard",
    target_triangles: int | None | object = _KEEP,
    table_z_mm: float | None = None,
    seed: int = 0,
) -> SurfaceResult:
    """Merged oriented cloud -> watertight mesh with filled, reported holes.

    Parameters
    ----------
    points
        ``(N, 3)`` registered, merged points (mm), N >= 100.
    normals
        ``(N, 3)`` outward normals (oriented toward the sensor), non-zero.
    confidence
        Optional ``(N,)`` per-point confidence in [0, 1] (None: all 1).
    preset
        ``"draft"``, ``"standard"``, ``"reference"`` or a :class:`SurfacePreset`.
    target_triangles
        Overrides the preset's decimation target (None: no decimation).
    table_z_mm
        Optional height (mm) of the table top in the cloud's frame (0 when
        the cloud is in the first pass's table frame): no hole is filled
        below it, and the underside of an object standing on it, which no
        pass saw, is closed flat on it (the data stop at the table crop
        height, so a plane through them would sit that much too high).
    seed
        Seed of the random subsets (spacing estimate, ring samples).

    Returns
    -------
    SurfaceResult
        The mesh (mm), its topology, the filled holes, the settings, counts,
        timings and warnings.

    Raises
    ------
    SurfaceError
        Empty cloud, fewer than 100 points, NaN points, missing or NaN
        normals, confidence outside [0, 1], all points collinear or
        coplanar, or a failed reconstruction; the message names the
        parameter.
    ValueError
        An unknown preset name.

    References
    ----------
    .. [1] Kazhdan, M., Hoppe, H. (2013). Screened Poisson surface
       reconstruction. ACM TOG 32(3), 29. doi:10.1145/2487228.2487237
    .. [2] Curless, B., Levoy, M. (1996). A volumetric method for building
       complex models from range images. SIGGRAPH 1996.
    """
    t_all = time.perf_counter()
    pre = _settings(preset, target_triangles, table_z_mm)
    notes: list[str] = []

    t0 = time.perf_counter()
    p, n, c = _checked_cloud(points, normals, confidence)
    t_check = time.perf_counter() - t0

    t0 = time.perf_counter()
    fused = _fused_cloud(p, n, c, pre, seed, notes)
    t_fuse = time.perf_counter() - t0

    t0 = time.perf_counter()
    fits, guide_p, guide_n = _hole_guides(fused, pre, table_z_mm, seed, notes)
    t_holes = time.perf_counter() - t0

    t0 = time.perf_counter()
    all_p = np.concatenate([fused.points, guide_p])
    all_n = np.concatenate([fused.normals, guide_n])
    v, t = poisson_mesh(all_p, all_n, depth=pre.depth, scale=pre.scale, samples_per_node=pre.samples_per_node)
    t_poisson = time.perf_counter() - t0
    cell = pre.scale * float((all_p.max(axis=0) - all_p.min(axis=0)).max()) / 2.0**pre.depth

    t0 = time.perf_counter()
    v, t = _drop_unsupported_components(v, t, all_p, fused.threshold)
    t_cleanup = time.perf_counter() - t0
    n_poisson = int(t.shape[0])

    t0 = time.perf_counter()
    decimated = _decimated(v, t, pre, notes)
    t_decimate = time.perf_counter() - t0

    t0 = time.perf_counter()
    v, t, topo = _final_topology(v, t, decimated, pre, notes)
    normals_out = vertex_normals(v, t)
    support = mesh_support(v, t, None, fused.threshold, tree=fused.tree, min_hole_area_mm2=fused.min_hole_area,
                           low_threshold_mm=fused.low_threshold)
    holes = _describe_holes(v, t, support, guide_p, fused.threshold, topo.watertight)
    t_report = time.perf_counter() - t0

    timings = SurfaceTimings(
        check_s=t_check, fuse_s=t_fuse, holes_s=t_holes, poisson_s=t_poisson, cleanup_s=t_cleanup,
        decimate_s=t_decimate, report_s=t_report, total_s=time.perf_counter() - t_all,
    )
    return SurfaceResult(
        vertices=v, triangles=t, vertex_normals=normals_out, watertight=topo.watertight, topology=topo,
        support=support, holes=holes, hole_fits=fits, n_guide_points=int(guide_p.shape[0]), preset=pre,
        spacing_mm=fused.spacing, support_threshold_mm=fused.threshold, cell_mm=cell,
        n_input_points=int(p.shape[0]), n_fused_points=int(fused.n_fused), n_low_confidence=int(fused.n_low),
        n_dominated=fused.n_dominated, n_triangles_poisson=n_poisson, timings=timings, warnings=tuple(notes),
    )


@dataclass(frozen=True, eq=False)
class _Fused:
    """The fused samples with their k-d tree, spacing, noise, support thresholds (mm) and counts."""

    points: NDArray[np.float64]
    normals: NDArray[np.float64]
    tree: cKDTree
    spacing: float
    noise: float
    threshold: float
    low_threshold: float
    min_hole_area: float
    extent: float
    n_fused: int
    n_low: int
    n_dominated: int


def _settings(preset: str | SurfacePreset, target_triangles: int | None | object,
              table_z_mm: float | None) -> SurfacePreset:
    """The preset with the decimation target overridden, after checking ``target_triangles`` and ``table_z_mm``."""
    pre = _resolve_preset(preset)
    if target_triangles is not _KEEP:
        if target_triangles is not None and not (
            isinstance(target_triangles, (int, np.integer)) and not isinstance(target_triangles, bool)
            and target_triangles >= 100
        ):
            raise SurfaceError(f"target_triangles must be None or an integer >= 100, got {target_triangles!r}")
        pre = replace(pre, target_triangles=None if target_triangles is None else int(target_triangles))
    if table_z_mm is not None and not (
        isinstance(table_z_mm, (int, float, np.floating, np.integer)) and math.isfinite(table_z_mm)
    ):
        raise SurfaceError(f"table_z_mm must be a finite height (mm) or None, got {table_z_mm!r}")
    return pre


def _checked_cloud(points: ArrayLike, normals: ArrayLike | None, confidence: ArrayLike | None
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Points, unit normals and confidences of a valid cloud spread in three dimensions (step 1)."""
    try:
        p, n, c = validate_oriented_cloud(points, normals, confidence, min_points=MIN_POINTS)
    except ValueError as exc:
        raise SurfaceError(str(exc)) from exc
    _check_shape(p)
    return p, n, c


def _fused_cloud(p: NDArray[np.float64], n: NDArray[np.float64], c: NDArray[np.float64], pre: SurfacePreset,
                 seed: int, notes: list[str]) -> _Fused:
    """Fuse the samples per voxel, drop dominated ones, and measure spacing, noise and thresholds (step 2)."""
    keep = (c >= pre.min_confidence) & (c > 0.0)
    n_kept = int(np.count_nonzero(keep))
    if n_kept < MIN_POINTS:
        raise SurfaceError(
            f"confidence: only {n_kept} of {p.shape[0]} points have confidence >= {pre.min_confidence} "
            f"(at least {MIN_POINTS} are needed); rescan or use a preset with a lower min_confidence"
        )
    spacing0 = _input_spacing(p[keep], n_kept, seed)
    if pre.fuse_voxel_factor > 0:
        fused = fuse_points(p, n, c, voxel_mm=pre.fuse_voxel_factor * spacing0, min_confidence=pre.min_confidence)
        fp, fn, fc = fused.points, fused.normals, fused.confidence
        n_low = fused.n_low_confidence
    else:
        fp, fn, fc, n_low = p[keep], n[keep], c[keep], p.shape[0] - n_kept
    n_fused = int(fp.shape[0])
    n_dominated = 0
    if pre.confidence_ratio > 0 and np.ptp(fc) > 0:
        radius = _DOMINANCE_RADIUS * max(spacing0, pre.fuse_voxel_factor * spacing0)
        dominated = dominated_samples(fp, fn, fc, radius_mm=radius, ratio=pre.confidence_ratio)
        n_dominated = int(np.count_nonzero(dominated))
        fp, fn = fp[~dominated], fn[~dominated]
    if fp.shape[0] < MIN_POINTS:
        raise SurfaceError(
            f"points: fusion left {fp.shape[0]} samples (at least {MIN_POINTS} are needed); "
            "the cloud is too small for its spacing"
        )
    return _measured(fp, fn, pre, seed, notes, n_fused, n_low, n_dominated)


def _input_spacing(kept: NDArray[np.float64], n_kept: int, seed: int) -> float:
    """Point spacing (mm) of the kept input points, over distinct positions if repeated points make it 0."""
    spacing0 = point_spacing(kept, seed=seed)
    if not spacing0 > 0:
        uniq = np.unique(kept, axis=0)
        if uniq.shape[0] < MIN_POINTS:
            raise SurfaceError(
                f"points: only {uniq.shape[0]} distinct positions among {n_kept} points "
                f"(at least {MIN_POINTS} are needed)"
            )
        spacing0 = point_spacing(uniq, seed=seed)
    return spacing0


def _measured(fp: NDArray[np.float64], fn: NDArray[np.float64], pre: SurfacePreset, seed: int, notes: list[str],
              n_fused: int, n_low: int, n_dominated: int) -> _Fused:
    """Spacing, noise, support thresholds and extent of the fused samples; a note if the normals look inward."""
    tree = cKDTree(fp)
    spacing = point_spacing(fp, tree=tree, seed=seed)
    noise = noise_level(fp, tree=tree, seed=seed)
    threshold = pre.support_factor * spacing
    low_threshold = min(threshold, _LOW_SUPPORT_FACTOR * spacing)
    min_hole_area = math.pi * threshold**2
    extent = float((fp.max(axis=0) - fp.min(axis=0)).max())
    centred = fp - fp.mean(axis=0)
    if float(np.einsum("ij,ij->", centred, fn)) < 0.0:
        notes.append(
            "normals: most normals point toward the centre of the cloud (inward); "
            "the surface may be inside out"
        )
    return _Fused(points=fp, normals=fn, tree=tree, spacing=spacing, noise=noise, threshold=threshold,
                  low_threshold=low_threshold, min_hole_area=min_hole_area, extent=extent, n_fused=n_fused,
                  n_low=n_low, n_dominated=n_dominated)


def _hole_guides(fused: _Fused, pre: SurfacePreset, table_z_mm: float | None, seed: int, notes: list[str]
                 ) -> tuple[tuple[HoleFit, ...], NDArray[np.float64], NDArray[np.float64]]:
    """Holes of a coarse Poisson surface fitted with smooth surfaces, as guide points and normals (steps 3-4)."""
    fits: tuple[HoleFit, ...] = ()
    guide_p = np.zeros((0, 3))
    guide_n = np.zeros((0, 3))
    if pre.fill_holes:
        fp, fn, threshold = fused.points, fused.normals, fused.threshold
        depth1 = int(np.clip(round(math.log2(pre.scale * fused.extent / threshold)), 5, max(5, pre.depth - 1)))
        cell1 = pre.scale * fused.extent / 2.0**depth1
        coarse = _o3d_cloud(fp, fn).voxel_down_sample(0.5 * cell1)
        cp, cn = np.asarray(coarse.points), np.asarray(coarse.normals)
        cn = cn / np.maximum(np.linalg.norm(cn, axis=1, keepdims=True), 1e-12)
        v1, t1 = poisson_mesh(cp, cn, depth=depth1, scale=pre.scale, samples_per_node=pre.samples_per_node)
        rep1 = mesh_support(v1, t1, None, threshold, tree=fused.tree, min_hole_area_mm2=fused.min_hole_area)
        guides = hole_guide_points(v1, t1, rep1, fp, fn, spacing_mm=fused.spacing, noise_mm=fused.noise,
                                   tree=fused.tree, floor_z_mm=table_z_mm, seed=seed)
        fits = guides.fits
        guide_p, guide_n = guides.points, guides.normals
        for f in fits:
            if not f.fitted:
                notes.append(f"hole {f.hole} of the coarse surface was not fitted: {f.reason}")
    return fits, guide_p, guide_n


def _decimated(v: NDArray[np.float64], t: NDArray[np.int64], pre: SurfacePreset, notes: list[str]
               ) -> tuple[NDArray[np.float64], NDArray[np.int64]] | None:
    """The mesh decimated to the preset's target, or None when it has no target or is already below it."""
    if pre.target_triangles is not None and t.shape[0] > pre.target_triangles:
        dv, dt = decimate_mesh(v, t, pre.target_triangles)
        if dt.shape[0] > pre.target_triangles:
            notes.append(f"decimation stopped at {dt.shape[0]} triangles (target {pre.target_triangles})")
        return dv, dt
    return None


def _final_topology(v: NDArray[np.float64], t: NDArray[np.int64],
                    decimated: tuple[NDArray[np.float64], NDArray[np.int64]] | None, pre: SurfacePreset,
                    notes: list[str]) -> tuple[NDArray[np.float64], NDArray[np.int64], MeshTopology]:
    """The final mesh (the decimated one unless decimation broke a watertight mesh) and its topology (step 6)."""
    if decimated is not None:
        dv, dt = decimated
        topo = mesh_topology(dt)
        if not topo.watertight:
            full = mesh_topology(t)
            if full.watertight:
                notes.append(
                    f"decimation to {pre.target_triangles} triangles broke the two-manifold; "
                    f"the undecimated mesh ({t.shape[0]} triangles) is returned"
                )
                topo = full
            else:
                v, t = dv, dt
        else:
            v, t = dv, dt
    else:
        topo = mesh_topology(t)
    if not topo.watertight:
        notes.append(
            f"the mesh is not watertight ({topo.n_boundary_edges} boundary edges, {topo.n_nonmanifold_edges} "
            f"non-manifold edges, {topo.n_nonmanifold_vertices} non-manifold vertices, "
            f"{topo.n_misoriented_edges} misoriented edges)"
        )
    return v, t, topo


def _drop_unsupported_components(
    v: NDArray[np.float64], t: NDArray[np.int64], samples: NDArray[np.float64], threshold: float
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Remove components with no vertex near a sample, and tiny components."""
    n_comp, labels = triangle_components(t)
    if n_comp <= 1:
        return v, t
    dist, _ = cKDTree(samples).query(v, distance_upper_bound=threshold, workers=-1)
    near = np.isfinite(dist)
    tri_near = near[t].any(axis=1)
    supported = np.bincount(labels, weights=tri_near.astype(np.float64), minlength=n_comp) > 0
    size = np.bincount(labels, minlength=n_comp)
    keep_comp = supported & (size >= max(20, int(1e-3 * t.shape[0])))
    if not keep_comp.any():
        keep_comp = size == size.max()
    return _compact(v, t[keep_comp[labels]])


def _describe_holes(
    v: NDArray[np.float64],
    t: NDArray[np.int64],
    support: SupportReport,
    guide_points: NDArray[np.float64],
    threshold: float,
    closed: bool,
) -> tuple[FilledHole, ...]:
    """One :class:`FilledHole` per unsupported region, filled by a spline fit where guide points lie in it."""
    if not support.n_holes:
        return ()
    spline = np.zeros(support.n_holes, bool)
    if guide_points.shape[0]:
        centres = (v[t[:, 0]] + v[t[:, 1]] + v[t[:, 2]]) / 3.0
        lab = support.hole_label
        idx = np.flatnonzero(lab >= 0)
        d, _ = cKDTree(guide_points).query(centres[idx], distance_upper_bound=threshold, workers=-1)
        hit = np.isfinite(d)
        spline[np.unique(lab[idx[hit]])] = True
    return tuple(
        FilledHole(
            area_mm2=h.area_mm2,
            max_distance_mm=h.max_distance_mm,
            centroid=tuple(float(x) for x in h.centroid),
            filled_by="spline" if spline[i] else "poisson",
            closed=closed,
        )
        for i, h in enumerate(support.holes)
    )
