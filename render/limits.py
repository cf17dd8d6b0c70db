"""The ranges of scene parameters the renderer resolves.

Open3D casts rays in float32 (24-bit mantissa: a position is known to about
6e-8 of its distance from the origin) and the shading tables are float32 too,
so a parameter is accepted only within a range where the image it gives is
still right.  The scene-file reader, the command line and the renderer's own
classes check against these same constants, and their messages state them.

Examples
--------
>>> MIN_FOV_DEG, MAX_COORDINATE_MM
(0.1, 10000000.0)
"""

from __future__ import annotations

__all__ = [
    "MAX_COORDINATE_MM",
    "MIN_MESH_EXTENT_MM",
    "MAX_MESH_OFFSET_EXTENTS",
    "MIN_FOV_DEG",
    "MAX_ANGLE_DEG",
    "SCALE_RANGE",
    "LIGHT_INTENSITY_RANGE",
    "MAX_SKY_RADIANCE",
    "ENVIRONMENT_INTENSITY_RANGE",
    "ENVIRONMENT_LUMINANCE_RANGE",
]

#: Largest coordinate of a vertex, the camera's eye and target, a point light or a translation, mm
#: (10 km): squared distances stay far inside float32.
MAX_COORDINATE_MM = 1e7

#: Smallest extent (largest side of the bounding box) of a mesh, mm (1 micrometre): below it float32
#: normals of its triangles underflow.
MIN_MESH_EXTENT_MM = 1e-3

#: Farthest a mesh may lie from the origin, in multiples of its extent: at 1e4 extents float32 resolves
#: its vertices to 6e-4 of its size (a sub-pixel error); farther, the ray caster sees blobs or nothing.
MAX_MESH_OFFSET_EXTENTS = 1e4

#: Smallest vertical field of view, degrees: float32 ray directions resolve about 6e-8 rad, so 0.1
#: degree keeps several thousand rays per pixel row distinct at any image height up to 8000 pixels.
MIN_FOV_DEG = 0.1

#: Largest magnitude of a rotation angle, degrees (one full turn either way).
MAX_ANGLE_DEG = 360.0

#: Object scale factors accepted (inclusive).
SCALE_RANGE = (1e-6, 1e6)

#: Light intensities accepted (inclusive): relative to the default key light's 1; a point light's is a
#: radiant intensity in mm^2 units (8000 at 200 mm matches a directional light of 0.2).
LIGHT_INTENSITY_RANGE = (1e-9, 1e12)

#: Largest sky radiance scale (``zenith``, ``horizon``), relative to the key light's white.
MAX_SKY_RADIANCE = 1e6

#: Environment intensity factors accepted (inclusive).
ENVIRONMENT_INTENSITY_RANGE = (1e-6, 1e6)

#: Luminance of an environment map's brightest pixel, intensity applied, in render units (1: display
#: white), accepted (inclusive): below, the map gives no visible light; above, float32 shading overflows.
ENVIRONMENT_LUMINANCE_RANGE = (1e-6, 1e15)
