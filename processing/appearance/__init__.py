"""Appearance: every photo posed on the mesh, which vertices each frame sees, and what it saw there.

Conventions (room, camera, mesh frame M, lamps) are those of
docs/appearance.md; the chain is written once in
:mod:`~processing.appearance.frame_poses`.

Modules
-------
:mod:`~processing.appearance.frame_poses`
    ``mesh_to_camera = room_to_camera @ Rz(theta) @ inv(T_p)``, lamps in M, :class:`FramePose`.
:mod:`~processing.appearance.projection`
    OpenCV projection of mesh points, pixel rays through the distortion model, depth maps by ray casting.
:mod:`~processing.appearance.visibility`
    Which vertices a frame sees: in view, facing, unoccluded, away from silhouettes and depth edges.
:mod:`~processing.appearance.observations`
    Per (vertex, frame) signal, noise, clipping and geometry; the checked ``.npz`` file.
:mod:`~processing.appearance.silhouette`
    Mesh and object masks of a frame, their IoU and boundary offset, outlines for overlays.
:mod:`~processing.appearance.surface_segmentation`
    Regions of one material on the surface from every view of every vertex (mixture + Potts smoothing).

This front door imports nothing heavy (Open3D, OpenCV): import the modules
themselves, e.g. ``from processing.appearance.visibility import visible_vertices``.

References
----------
Callieri, M., Cignoni, P., Corsini, M., Scopigno, R. (2008). Masked photo
blending: mapping dense photographic data set on high-resolution sampled 3D
models. Computers & Graphics 32(4), 464-473. doi:10.1016/j.cag.2008.05.004
"""

from __future__ import annotations

import importlib
from typing import Any

from processing.appearance.frame_poses import (
    AppearanceError,
    FramePose,
    MeshLamp,
    camera_centre_mesh,
    lamp_in_mesh,
    mesh_to_camera,
)

#: name -> module, imported on first use (they import Open3D and OpenCV).
_LAZY = {
    "project_points": "projection", "pixel_rays": "projection", "depth_map": "projection",
    "raycasting_scene": "projection", "mesh_arrays": "projection",
    "visible_vertices": "visibility", "edge_mask": "visibility",
    "Observations": "observations", "observe": "observations", "per_vertex_counts": "observations",
    "write_observations": "observations", "read_observations": "observations",
    "mesh_mask": "silhouette", "object_mask": "silhouette", "silhouette_check": "silhouette",
    "outline_px": "silhouette",
    "SurfaceSegmentation": "surface_segmentation", "segment_surface": "surface_segmentation",
    "vertex_features": "surface_segmentation",
}

__all__ = ["AppearanceError", "FramePose", "MeshLamp", "camera_centre_mesh", "lamp_in_mesh", "mesh_to_camera",
           *_LAZY]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(f"processing.appearance.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'processing.appearance' has no attribute {name!r}")
