"""``kogei materials [NAME]``: list the presets with their colour, or one preset's parameters."""

from __future__ import annotations

import argparse

from app.workflows.materials import preset_srgb

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add ``kogei materials`` to the subcommands."""
    p = sub.add_parser("materials", help="list material presets, or the parameters of one")
    p.add_argument("name", nargs="?", metavar="NAME[:KEY=VALUE,...]",
                   help="a preset name, optionally with overrides, e.g. gold:roughness=0.2 (default: list every "
                        "preset)")


def run(args: argparse.Namespace) -> int:
    from processing.materials.presets import get_material, list_materials, material_parameters

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
