"""``kogei materials [NAME]``: list the presets with their colour, or one preset's parameters."""

from __future__ import annotations

import argparse

import numpy as np

from app.errors import UsageError

__all__ = ["add_parser", "run", "preset_srgb"]

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


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add ``kogei materials`` to the subcommands."""
    p = sub.add_parser("materials", help="list material presets, or the parameters of one")
    p.add_argument("name", nargs="?", help="a preset name (optionally with overrides)")


def run(args: argparse.Namespace) -> int:
    from processing.materials.presets import MaterialError, get_material, list_materials, material_parameters

    try:
        if not args.name:
            print(f"{'preset':<28} {'family':<11} {'sRGB (D65)':<14} description")
            for name in list_materials():
                mat = get_material(name)
                r, g, b = preset_srgb(name)
                print(f"{name:<28} {mat.family:<11} #{r:02x}{g:02x}{b:02x} {'':6} {mat.description}")
            return 0
        name = args.name.split(":", 1)[0]
        material = get_material(args.name)
        params = material_parameters(name)
        print(f"{material.name} ({material.family}): {material.description}")
        print(f"{'parameter':<18} {'value':>10}  {'default':>10}  {'unit':<10} description")
        for key, info in params.items():
            value = material.parameters.get(key, info.value)
            print(f"{key:<18} {value!s:>10}  {info.value!s:>10}  {info.unit:<10} {info.description}")
        r, g, b = preset_srgb(args.name)
        print(f"sRGB under D65: #{r:02x}{g:02x}{b:02x}")
        return 0
    except MaterialError as exc:
        raise UsageError(str(exc)) from None
