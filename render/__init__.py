"""Re-rendering a digitised object under any light: Open3D ray casting, NumPy spectral shading.

docs/rendering.md describes the pipeline, the presets and their measured
accuracy and speed.

Modules
-------
:mod:`render.backends`
    The colour backends of the shading: full spectra, or XYZ angle tables.
:mod:`render.camera`
    Pinhole camera and primary rays (stratified or rotated-grid samples).
:mod:`render.errors`
    The renderer's exceptions.
:mod:`render.integrator`
    Shading of ray hits: direct light with shadow rays, sky light, one mirror bounce.
:mod:`render.image_io`
    Atomic writing of 8-bit sRGB PNG and float32 XYZ TIFF.
:mod:`render.meshio`
    Loading and validating triangle meshes; smooth vertex normals.
:mod:`render.presets`
    Render settings and the ``draft`` / ``standard`` / ``reference`` presets.
:mod:`render.renderer`
    The tile loop: ray casting, shading, adaptive anti-aliasing, display.
:mod:`render.scene`
    Objects with materials, lights and the sky.
:mod:`render.shading`
    The shading's geometry: hits, microfacet terms, material and light plans.
:mod:`render.tables`
    Angular XYZ tables of a lobe's spectral integral.
:mod:`render.tangents`
    Yarn directions (tangent frames) for anisotropic cloth materials.

References
----------
Matsuda, Tanaka, Ichikawa, Mochizuki, Muroya, Kitamura, "CG reproduction of
a craft object based on a light reflection model", IPSJ technical report
(no DOI).
Yasuda, T., Yokoi, S., Toriwaki, J., Inagaki, K. (1992), "A shading model
for cloth objects", IEEE CG&A 12(6), 15-24, doi:10.1109/38.163621.
Walter, B., Marschner, S. R., Li, H., Torrance, K. E. (2007), "Microfacet
models for refraction through rough surfaces", EGSR 2007, 195-206,
doi:10.2312/EGWR/EGSR07/195-206.
Mitchell, D. P. (1987), "Generating antialiased images at low sampling
densities", SIGGRAPH '87, 65-72, doi:10.1145/37402.37410.

Examples
--------
>>> from render import PRESETS, Camera, Light, Scene, SceneObject, make_mesh, render
>>> square = make_mesh([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], [[0, 1, 2], [0, 2, 3]])
>>> scene = Scene([SceneObject(square, ["gold"])], [Light("directional", (0, 0, 1))])
>>> render(scene, Camera((0, 0, 4), (0, 0, 0), (0, 1, 0), 20, 4, 4), PRESETS["draft"]).srgb8.shape
(4, 4, 3)
"""

from render.camera import DEFAULT_VIEW_DIRECTION, Camera
from render.errors import MeshError, MeshWarning, RenderCancelled, RenderInputError
from render.image_io import read_xyz_tiff, write_png, write_xyz_tiff
from render.meshio import MESH_SUFFIXES, Mesh, face_normals, load_mesh, make_mesh, smooth_vertex_normals
from render.presets import PRESETS, RenderSettings, get_preset
from render.renderer import (
    MAX_TILE_SAMPLES,
    BaselineTiming,
    RenderResult,
    cast_rays_baseline,
    pixels_to_refine,
    render,
)
from render.scene import (
    Light,
    Scene,
    SceneObject,
    Sky,
    check_point_lights,
    hemisphere_mean_clamped_cosine,
    resolve_spectrum,
)
from render.tangents import (
    DEFAULT_WARP_DIRECTION,
    rotate_tangents,
    tangents_from_direction,
    tangents_from_field,
    tangents_from_uvs,
)

__all__ = [
    "Camera",
    "DEFAULT_VIEW_DIRECTION",
    "RenderInputError",
    "MeshError",
    "MeshWarning",
    "RenderCancelled",
    "write_png",
    "write_xyz_tiff",
    "read_xyz_tiff",
    "Mesh",
    "MESH_SUFFIXES",
    "load_mesh",
    "make_mesh",
    "smooth_vertex_normals",
    "face_normals",
    "RenderSettings",
    "PRESETS",
    "get_preset",
    "RenderResult",
    "render",
    "pixels_to_refine",
    "BaselineTiming",
    "cast_rays_baseline",
    "MAX_TILE_SAMPLES",
    "SceneObject",
    "Light",
    "Sky",
    "Scene",
    "resolve_spectrum",
    "hemisphere_mean_clamped_cosine",
    "check_point_lights",
    "DEFAULT_WARP_DIRECTION",
    "tangents_from_direction",
    "tangents_from_field",
    "tangents_from_uvs",
    "rotate_tangents",
]
