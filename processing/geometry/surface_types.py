"""Settings and results of the surface stage (:func:`processing.geometry.surface.reconstruct_surface`).

The presets trade speed for accuracy; their measured time and error are in
docs/processing.md, section "Surface reconstruction".
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from processing.errors import InputError
from processing.geometry.holes import HoleFit
from processing.geometry.mesh_support import SupportReport
from processing.geometry.mesh_topology import MeshTopology

__all__ = ["FilledHole", "SURFACE_PRESETS", "SurfacePreset", "SurfaceResult", "SurfaceTimings"]


@dataclass(frozen=True)
class SurfacePreset:
    """Speed / accuracy settings of :func:`~processing.geometry.surface.reconstruct_surface`.

    Attributes
    ----------
    name
        Preset name.
    depth
        Octree depth of the final screened Poisson solve (cells of
        ``1.1 * extent / 2**depth``; the octree also stops refining where
        fewer than ``samples_per_node`` samples fall in a cell).
    samples_per_node
        Poisson's minimum samples per octree node (more smooths noise more).
    fuse_voxel_factor
        Fusion voxel as a multiple of the point spacing (0: no fusion).
    support_factor
        Support threshold as a multiple of the (fused) point spacing: mesh
        farther than this from every sample is a hole.
    min_confidence
        Samples below this confidence are dropped.
    confidence_ratio
        After fusion, samples whose confidence is below this fraction of the
        best confidence within two spacings (same facing) are dropped: a
        better measurement of the same surface exists (0: keep all).
    fill_holes
        Fit every hole with a smooth surface before the final solve (else
        Poisson alone, which leaves large holes open).
    target_triangles
        Quadric decimation target (None: keep the Poisson mesh).
    scale
        Poisson's bounding-cube scale.

    Raises
    ------
    ValueError
        A setting out of range (depth outside 5..12, fewer than one sample
        per node, a negative fusion factor, a support factor below 1, a
        confidence setting outside [0, 1], a decimation target below 100, a
        scale outside (1, 4]).
    """

    name: str
    depth: int
    samples_per_node: float
    fuse_voxel_factor: float
    support_factor: float
    min_confidence: float
    fill_holes: bool
    target_triangles: int | None
    confidence_ratio: float = 0.5
    scale: float = 1.1

    def __post_init__(self) -> None:
        if not (isinstance(self.depth, int) and 5 <= self.depth <= 12):
            raise InputError(f"SurfacePreset.depth must be an integer in 5..12, got {self.depth!r}")
        if not self.samples_per_node >= 1.0:
            raise InputError(f"SurfacePreset.samples_per_node must be >= 1, got {self.samples_per_node!r}")
        if not self.fuse_voxel_factor >= 0.0:
            raise InputError(f"SurfacePreset.fuse_voxel_factor must be >= 0, got {self.fuse_voxel_factor!r}")
        if not self.support_factor >= 1.0:
            raise InputError(f"SurfacePreset.support_factor must be >= 1, got {self.support_factor!r}")
        if not 0.0 <= self.confidence_ratio <= 1.0:
            raise InputError(f"SurfacePreset.confidence_ratio must be in [0, 1], got {self.confidence_ratio!r}")
        if not 0.0 <= self.min_confidence < 1.0:
            raise InputError(f"SurfacePreset.min_confidence must be in [0, 1), got {self.min_confidence!r}")
        if self.target_triangles is not None and not (
            isinstance(self.target_triangles, int) and self.target_triangles >= 100
        ):
            raise InputError(
                f"SurfacePreset.target_triangles must be None or an integer >= 100, got {self.target_triangles!r}"
            )
        if not 1.0 < self.scale <= 4.0:
            raise InputError(f"SurfacePreset.scale must be in (1, 4], got {self.scale!r}")


#: Named presets.  ``standard`` is meant for 3 passes x 200k points within
#: 60 s together with registration.
SURFACE_PRESETS: dict[str, SurfacePreset] = {
    "draft": SurfacePreset("draft", depth=7, samples_per_node=2.0, fuse_voxel_factor=1.5,
                           support_factor=4.0, min_confidence=0.05, fill_holes=True,
                           target_triangles=50_000),
    "standard": SurfacePreset("standard", depth=8, samples_per_node=1.5, fuse_voxel_factor=1.0,
                              support_factor=4.0, min_confidence=0.05, fill_holes=True,
                              target_triangles=200_000),
    "reference": SurfacePreset("reference", depth=9, samples_per_node=1.5, fuse_voxel_factor=0.0,
                               support_factor=4.0, min_confidence=0.0, fill_holes=True,
                               target_triangles=None),
}


@dataclass(frozen=True)
class SurfaceTimings:
    """Wall-clock seconds of each step.

    Attributes
    ----------
    check_s, fuse_s, holes_s, poisson_s, cleanup_s, decimate_s, report_s
        Checking the cloud, fusion, finding and fitting the holes, the final
        Poisson solve, removing unsupported pieces, decimation, the report (s).
    total_s
        The whole stage (s).
    """

    check_s: float = 0.0
    fuse_s: float = 0.0
    holes_s: float = 0.0
    poisson_s: float = 0.0
    cleanup_s: float = 0.0
    decimate_s: float = 0.0
    report_s: float = 0.0
    total_s: float = 0.0


@dataclass(frozen=True)
class FilledHole:
    """A hole of the final mesh: a region not supported by measured data.

    Attributes
    ----------
    area_mm2
        Area (mm^2) of the region.
    max_distance_mm
        Largest distance (mm) from the region to the nearest sample.
    centroid
        ``(3,)`` area-weighted centre (mm).
    filled_by
        ``"spline"`` when guide points of a fitted surface lie in it,
        ``"poisson"`` when only the Poisson solve spans it.
    closed
        True when the mesh is watertight (every hole is closed).
    """

    area_mm2: float
    max_distance_mm: float
    centroid: tuple[float, float, float]
    filled_by: str
    closed: bool


@dataclass(frozen=True, eq=False)
class SurfaceResult:
    """Result of :func:`reconstruct_surface`.

    Attributes
    ----------
    vertices, triangles, vertex_normals
        The mesh: float64 ``(V, 3)`` mm, int64 ``(T, 3)`` counter-clockwise
        seen from outside, float64 ``(V, 3)`` unit area-weighted normals.
    watertight
        Closed, consistently oriented two-manifold (``topology.watertight``).
    topology
        Edge / vertex / component counts.
    support
        Support of the final mesh by the (fused) samples; its holes are the
        filled regions.
    holes
        One :class:`FilledHole` per region of ``support.holes``.
    hole_fits
        How each hole of the coarse surface was fitted.
    n_guide_points
        Guide points added on fitted surfaces.
    preset
        The settings used.
    spacing_mm, support_threshold_mm, cell_mm
        Point spacing of the fused cloud, support threshold, Poisson cell edge.
    n_input_points, n_fused_points, n_low_confidence, n_dominated
        Points given, samples after fusion, points dropped for low
        confidence, fused samples dropped because a better sample of the
        same surface lies next to them.
    n_triangles_poisson
        Triangles before decimation.
    timings
        Seconds per step.
    warnings
        Anything the caller should report (not watertight, a hole fit
        failed, normals look inward, decimation stopped early).
    """

    vertices: NDArray[np.float64]
    triangles: NDArray[np.int64]
    vertex_normals: NDArray[np.float64]
    watertight: bool
    topology: MeshTopology
    support: SupportReport
    holes: tuple[FilledHole, ...]
    hole_fits: tuple[HoleFit, ...]
    n_guide_points: int
    preset: SurfacePreset
    spacing_mm: float
    support_threshold_mm: float
    cell_mm: float
    n_input_points: int
    n_fused_points: int
    n_low_confidence: int
    n_dominated: int
    n_triangles_poisson: int
    timings: SurfaceTimings
    warnings: tuple[str, ...] = field(default_factory=tuple)

    @property
    def n_triangles(self) -> int:
        """Triangles of the final mesh."""
        return int(self.triangles.shape[0])

    @property
    def n_holes(self) -> int:
        """Holes (unsupported regions) of the final mesh."""
        return len(self.holes)

    @property
    def hole_area_mm2(self) -> float:
        """Total area of the holes (mm^2)."""
        return float(sum(h.area_mm2 for h in self.holes))

    def to_open3d(self) -> Any:
        """The mesh as an ``open3d.geometry.TriangleMesh`` (with vertex normals).

        Returns
        -------
        open3d.geometry.TriangleMesh
            The vertices (mm), triangles and vertex normals.
        """
        import open3d as o3d

        m = o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(self.vertices), o3d.utility.Vector3iVector(self.triangles.astype(np.int32))
        )
        m.vertex_normals = o3d.utility.Vector3dVector(self.vertex_normals)
        return m

    def summary(self) -> dict[str, Any]:
        """A JSON-ready report: counts, holes, topology, settings, timings.

        Returns
        -------
        dict
            ``preset``, ``points``, ``mesh``, ``holes``, ``timings_s`` and
            ``warnings`` (lengths in mm, areas in mm^2, times in s).
        """
        return {
            "preset": asdict(self.preset),
            "points": {
                "input": self.n_input_points,
                "fused": self.n_fused_points,
                "low_confidence_dropped": self.n_low_confidence,
                "dominated_dropped": self.n_dominated,
                "guide": self.n_guide_points,
                "spacing_mm": self.spacing_mm,
            },
            "mesh": {
                "vertices": int(self.vertices.shape[0]),
                "triangles": self.n_triangles,
                "triangles_before_decimation": self.n_triangles_poisson,
                "watertight": self.watertight,
                "components": self.topology.n_components,
                "genus": self.topology.genus,
                "boundary_edges": self.topology.n_boundary_edges,
                "nonmanifold_edges": self.topology.n_nonmanifold_edges,
                "nonmanifold_vertices": self.topology.n_nonmanifold_vertices,
                "cell_mm": self.cell_mm,
                "area_mm2": self.support.mesh_area_mm2,
            },
            "holes": {
                "threshold_mm": self.support_threshold_mm,
                "count": self.n_holes,
                "total_area_mm2": self.hole_area_mm2,
                "filled": sum(h.closed for h in self.holes),
                "items": [asdict(h) for h in self.holes],
                "fits": [
                    {"reason": f.reason, "guide_points": f.n_guide_points, "fit_samples": f.n_fit_samples,
                     "fit_rms_mm": f.fit_rms_mm, "direction": [float(x) for x in f.direction]}
                    for f in self.hole_fits
                ],
            },
            "timings_s": asdict(self.timings),
            "warnings": list(self.warnings),
        }
