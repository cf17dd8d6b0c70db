"""Lighting: measured and analytic light around the table, as spectral environment maps.

Modules
-------
environment_map
    :class:`~processing.lighting.environment_map.EnvironmentMap` (equirectangular
    spectral-basis radiance in the table frame), reading and writing ``.exr`` /
    ``.hdr`` files, sRGB upsampling by Mallett and Yuksel (2019).
daylight_sky
    :func:`~processing.lighting.daylight_sky.daylight_sky`: an outdoor sky
    (CIE general sky luminance, CIE daylight spectra, a sun disc, a ground).

docs/lighting.md describes the frame, the units and the file format.

References
----------
Mallett, I., & Yuksel, C. (2019). Spectral Primary Decomposition for
Rendering with sRGB Reflectance. doi:10.2312/sr.20191216
"""

from processing.lighting.environment_map import (
    HEADER_KEY,
    EnvironmentMap,
    EnvironmentMapError,
    direction_pixels,
    pixel_directions,
    read_environment,
    srgb_basis,
    uniform_environment,
    write_environment,
)

__all__ = [
    "HEADER_KEY",
    "EnvironmentMap",
    "EnvironmentMapError",
    "direction_pixels",
    "pixel_directions",
    "read_environment",
    "srgb_basis",
    "uniform_environment",
    "write_environment",
]
