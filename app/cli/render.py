"""``kogei render``: one mesh with one material, or a TOML scene."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from app.cli.outputs import check_output_file, writing
from app.errors import UsageError
from app.workflows.scene_spec import (
    CameraSpec,
    ObjectSpec,
    SceneSpec,
    check_path_text,
    check_range,
    load_scene_file,
    parse_environment,
    parse_fov,
    parse_light,
    parse_position,
    parse_size,
)

__all__ = ["add_parser", "run", "spec_from_args"]


def spec_from_args(args: argparse.Namespace) -> SceneSpec:
    """Scene description from ``kogei render`` flags; flags override a scene file's values."""
    check_path_text(args.scene, "MESH|SCENE.toml")
    src = Path(args.scene)
    if src.suffix.lower() == ".toml":
        spec = load_scene_file(src)
        if args.material is not None:
            for obj in spec.objects:
                obj.material = args.material
    else:
        if not src.exists():
            raise UsageError(f"{src}: mesh file not found")
        spec = SceneSpec(objects=[ObjectSpec(mesh=src, material=args.material or "gold")])
    if args.weave_angle is not None:
        from render.limits import MAX_ANGLE_DEG

        check_range(args.weave_angle, "--weave-angle", -MAX_ANGLE_DEG, MAX_ANGLE_DEG, "an angle in degrees")
        for obj in spec.objects:
            obj.weave_angle_deg = args.weave_angle
    if args.light:
        spec.lights = [parse_light(text) for text in args.light]
    if args.illuminant:
        spec.illuminant = args.illuminant
    if args.sky:
        spec.sky.kind = args.sky
        spec.sky_given = True
    if args.environment is not None:
        spec.environment = parse_environment(args.environment)
    if args.environment_samples is not None:
        if not (args.environment_samples == 0 or 2 <= args.environment_samples <= 4096):
            raise UsageError(f"--environment-samples: expected 0 (prefiltered map) or 2 to 4096, "
                             f"got {args.environment_samples}")
        spec.environment_samples = args.environment_samples
    if args.size:
        spec.size = parse_size(args.size)
    if args.preset:
        spec.preset = args.preset
    cam = spec.camera
    spec.camera = CameraSpec(
        eye=parse_position(args.eye, "--eye") if args.eye else cam.eye,
        target=parse_position(args.target, "--target") if args.target else cam.target,
        up=parse_position(args.up, "--up") if args.up else cam.up,
        fov_deg=parse_fov(args.fov, "--fov") if args.fov is not None else cam.fov_deg,
    )
    return spec


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add ``kogei render`` to the subcommands."""
    p = sub.add_parser(
        "render",
        help="render a mesh or a TOML scene spectrally to an sRGB PNG (and float XYZ TIFF)",
        description="Render MESH (PLY/OBJ/STL/glTF) or a TOML scene file.",
    )
    p.add_argument("scene", metavar="MESH|SCENE.toml",
                   help="a mesh (PLY, OBJ, STL, glTF; coordinates in mm) or a TOML scene file (docs/scene-file.md)")
    p.add_argument("--material", default=None,
                   help="preset name with optional overrides, e.g. gold:roughness=0.2,mirror=0 "
                        "(see 'kogei materials'); default gold")
    p.add_argument("--light", action="append", default=[], metavar="SPEC",
                   help="directional:DX,DY,DZ (a direction toward the light, any length) or point:X,Y,Z (a "
                        "position in mm, each within +-1e7); optional @SPECTRUM (as --illuminant) and *INTENSITY "
                        "(relative, 1e-9 to 1e12; 1 = the default key light); repeatable (default: one directional light from above left front)")
    p.add_argument("--illuminant", default=None, metavar="NAME|CCT|CSV",
                   help="spectrum of the lights and the sky: a CIE name (D65, A, D50, F2, ...), a correlated colour "
                        "temperature in kelvin such as 3200K, or a CSV of (wavelength nm, relative power) "
                        "(default D65, or the scene file's)")
    p.add_argument("--sky", default=None, choices=["uniform", "gradient", "none"],
                   help="environment seen in mirror reflections (default gradient)")
    p.add_argument("--environment", default=None, metavar="MAP",
                   help="light the scene with an environment map: FILE.exr or FILE.hdr (equirectangular, 2:1, z up) "
                        "with optional :rotate=DEG (within +-360),intensity=X (1e-6 to 1e6), or the analytic daylight sky "
                        "sky:cct=K,sun_elevation=DEG,sun_azimuth=DEG,type=clear|intermediate|overcast|1-15,sun=X,"
                        "sun_cct=K,luminance=Y (1e-6 to 1e6),ground=R,height=ROWS (and rotate, intensity); it replaces the default "
                        "light and sky unless --light or --sky are given (docs/lighting.md)")
    p.add_argument("--environment-samples", type=int, default=None, metavar="N",
                   help="directions per surface sample with which the environment lights non-mirror lobes (half "
                        "from the map, half from the material; 0: the prefiltered map, no occlusion); more is less "
                        "noise and more time (default: the preset's, draft 0, standard 8, reference 16)")
    p.add_argument("--eye", default=None, metavar="X,Y,Z",
                   help="camera position in the mesh's coordinates, mm, each within +-1e7 (default: framed to show "
                        "the whole scene)")
    p.add_argument("--target", default=None, metavar="X,Y,Z",
                   help="point the camera looks at, mm, each within +-1e7 (default: the centre of the scene's "
                        "bounding box)")
    p.add_argument("--up", default=None, metavar="X,Y,Z",
                   help="direction that is up in the image, unitless (default 0,0,1: +z)")
    p.add_argument("--fov", type=float, default=None, metavar="DEG",
                   help="vertical field of view in degrees, from 0.1 (the narrowest float32 ray casting resolves) "
                        "to 180, 180 excluded (default 35)")
    p.add_argument("--size", default=None, metavar="WxH", help="image size in pixels (default 800x600)")
    p.add_argument("--preset", default=None, choices=["draft", "standard", "reference"],
                   help="speed against accuracy: draft (a quick look), standard, reference (slowest, the noise "
                        "floor); docs/rendering.md measures each (default standard, or the scene file's)")
    p.add_argument("--weave-angle", type=float, default=None, metavar="DEG",
                   help="turn the yarn directions of cloth materials about the normal, degrees, within +-360 (default 0, or the scene file's)")
    p.add_argument("--out", required=True, metavar="IMG.png", help="the sRGB PNG to write (required)")
    p.add_argument("--xyz", default=None, metavar="IMG.tiff", help="also write float32 CIE XYZ")
    p.add_argument("--quiet", action="store_true", help="do not print the size and time of the render")


def run(args: argparse.Namespace) -> int:
    """Run ``kogei render``; running out of memory is a one-line :class:`UsageError`, not a traceback."""
    try:
        return _render(args)
    except MemoryError:
        raise UsageError(f"{args.scene}: not enough memory for this render; use a smaller --size "
                         "or a simpler mesh, or free memory") from None


def _render(args: argparse.Namespace) -> int:
    """Build the scene, render it and write the PNG (and XYZ TIFF)."""
    from app.workflows.scene_build import build_job
    from render.image_io import write_png, write_xyz_tiff
    from render.renderer import render

    if Path(args.out).suffix.lower() != ".png":
        raise UsageError(f"--out: {args.out} must end in .png (the sRGB image); use --xyz for float XYZ")
    out = check_output_file(args.out, "--out", make_parents=True)     # both outputs before the work
    xyz = check_output_file(args.xyz, "--xyz") if args.xyz else None
    spec = spec_from_args(args)
    job = build_job(spec)
    t0 = time.perf_counter()
    result = render(job.scene, job.camera, job.settings)
    elapsed = time.perf_counter() - t0
    with writing(out, "--out"):
        out.parent.mkdir(parents=True, exist_ok=True)
        write_png(out, result.srgb8)
    if xyz is not None:
        with writing(xyz, "--xyz"):
            write_xyz_tiff(xyz, result.xyz)
    if not args.quiet:
        w, h = spec.size
        print(f"wrote {out} ({w}x{h}, preset {job.settings.name}, {elapsed:.2f} s)", file=sys.stderr)
    return 0
