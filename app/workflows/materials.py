"""The display colour of a material preset (``kogei materials``, the batch's material maps, the colour demo)."""

from __future__ import annotations

import numpy as np

__all__ = ["preset_srgb"]

# The preset colour is that of the material lit by a uniform D65 sky and seen
# 30 deg off the normal: its directional albedo, so metals show their Fresnel
# colour and lacquers their pigment (plus the small gloss).
_VIEW_DEG = 30.0


def preset_srgb(spec: str, illuminant: str = "D65") -> tuple[int, int, int]:
    """sRGB (8-bit) of a material under a uniform sky of ``illuminant``.

    Examples
    --------
    >>> r, g, b = preset_srgb("gold")
    >>> r > g > b          # gold is yellow: red and green high, blue low
    True
    """
    from processing.materials.albedo import directional_albedo
    from processing.materials.presets import get_material
    from processing.spectral.display import spectra_to_xyz, white_xyz, xyz_scale, xyz_to_srgb8
    from processing.spectral.spectra import REFERENCE_GRID, light_spectrum

    grid = REFERENCE_GRID
    material = get_material(spec)
    light = light_spectrum(illuminant, grid)
    albedo = directional_albedo(material, np.cos(np.radians(_VIEW_DEG)), grid.wavelengths)
    # A uniform sky of radiance light/pi reflects albedo * light/pi.
    xyz = xyz_scale(light, grid) * spectra_to_xyz(albedo * light / np.pi, grid)
    rgb = xyz_to_srgb8(np.asarray(xyz, dtype=np.float64).reshape(1, 3), white_xyz(light, grid))
    return tuple(int(v) for v in np.asarray(rgb).reshape(3))
