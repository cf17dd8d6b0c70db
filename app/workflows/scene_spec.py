"""What to render, as plain data: parsed from command-line flags or a TOML scene file.

A :class:`SceneSpec` is independent of the renderer's classes so that the
command line, the scene file, the demo and the GUI describe scenes the same
way; :func:`app.workflows.scene_build.build_scene` turns it into renderer objects.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from app.errors import UsageError

__all__ = [
    "ObjectSpec",
    "LightSpec",
    "SkySpec",
    "CameraSpec",
    "SceneSpec",
    "parse_vector",
    "parse_size",
    "parse_light",
    "load_scene_file",
]


@dataclass
class ObjectSpec:
    """One object: a mesh file or a procedural shape, its material(s) and placement.

    ``material`` is a material spec string (``"gold:roughness=0.2"``);
    ``region_materials`` maps region names of a procedural object (the hawk)
    to material spec strings and overrides ``material`` region by region.
    """

    mesh: Path | None = None
    procedural: str | None = None          # "hawk", "sphere", "plane"
    procedural_args: dict = field(default_factory=dict)
    material: str = "gold"
    region_materials: dict[str, str] = field(default_factory=dict)
    translate: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotate_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)   # about x, y, z, applied in that order
    scale: float = 1.0
    weave_angle_deg: float | None = None


@dataclass
class LightSpec:
    """A light: ``directional`` (``vector`` points from the surface toward the light) or ``point``."""

    kind: str
    vector: tuple[float, float, float]
    spectrum: str | None = None            # None: the scene illuminant
    intensity: float = 1.0


@dataclass
class SkySpec:
    kind: str = "gradient"                 # "uniform", "gradient" or "none"
    zenith: float = 0.25                   # radiance scales relative to the key light's white
    horizon: float = 0.6
    spectrum: str | None = None


@dataclass
class CameraSpec:
    eye: tuple[float, float, float] | None = None
    target: tuple[float, float, float] | None = None
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    fov_deg: float = 35.0


@dataclass
class SceneSpec:
    objects: list[ObjectSpec] = field(default_factory=list)
    lights: list[LightSpec] = field(default_factory=list)
    sky: SkySpec = field(default_factory=SkySpec)
    camera: CameraSpec = field(default_factory=CameraSpec)
    illuminant: str = "D65"
    size: tuple[int, int] = (800, 600)
    preset: str = "standard"


def parse_vector(text: str | list | tuple, name: str) -> tuple[float, float, float]:
    """Parse ``"X,Y,Z"`` (or a 3-list from TOML) into three finite floats.

    Examples
    --------
    >>> parse_vector("1, 2,3", "--eye")
    (1.0, 2.0, 3.0)
    """
    parts = text.split(",") if isinstance(text, str) else list(text)
    try:
        values = tuple(float(p) for p in parts)
    except (TypeError, ValueError):
        raise UsageError(f"{name}: expected three numbers X,Y,Z, got {text!r}") from None
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise UsageError(f"{name}: expected three finite numbers X,Y,Z, got {text!r}")
    return values  # type: ignore[return-value]


def parse_size(text: str) -> tuple[int, int]:
    """Parse ``"WxH"``.

    Examples
    --------
    >>> parse_size("640x480")
    (640, 480)
    """
    try:
        w, h = (int(v) for v in str(text).lower().split("x"))
    except ValueError:
        raise UsageError(f"--size: expected WIDTHxHEIGHT such as 800x600, got {text!r}") from None
    if w <= 0 or h <= 0 or w * h > 64_000_000:
        raise UsageError(f"--size: width and height must be positive (at most 64 megapixels), got {text!r}")
    return w, h


def parse_light(text: str) -> LightSpec:
    """Parse ``directional:DX,DY,DZ`` or ``point:X,Y,Z`` (optionally ``@SPECTRUM`` and ``*INTENSITY``).

    Examples
    --------
    >>> parse_light("directional:1,1,2").kind
    'directional'
    >>> parse_light("point:0,0,100@A*2").spectrum
    'A'
    """
    kind, _, rest = text.partition(":")
    kind = kind.strip().lower()
    if kind not in ("directional", "point") or not rest:
        raise UsageError(
            f"--light: expected 'directional:DX,DY,DZ' or 'point:X,Y,Z', got {text!r}"
        )
    intensity = 1.0
    if "*" in rest:
        rest, _, inten = rest.partition("*")
        try:
            intensity = float(inten)
        except ValueError:
            raise UsageError(f"--light: intensity after '*' must be a number, got {inten!r}") from None
        if not (math.isfinite(intensity) and intensity > 0):
            raise UsageError(f"--light: intensity must be positive, got {inten!r}")
    spectrum = None
    if "@" in rest:
        rest, _, spectrum = rest.partition("@")
    vec = parse_vector(rest, "--light")
    if kind == "directional" and not any(vec):
        raise UsageError("--light: a directional light needs a non-zero direction")
    return LightSpec(kind=kind, vector=vec, spectrum=spectrum or None, intensity=intensity)


def _table(data: dict, key: str, path: Path) -> dict:
    value = data.get(key, {})
    if not isinstance(value, dict):
        raise UsageError(f"{path}: [{key}] must be a table")
    return value


def _check_keys(table: dict, allowed: set[str], where: str) -> None:
    unknown = set(table) - allowed
    if unknown:
        raise UsageError(
            f"{where}: unknown key(s) {', '.join(sorted(unknown))}; allowed: {', '.join(sorted(allowed))}"
        )


def load_scene_file(path: str | Path) -> SceneSpec:
    """Read a TOML scene file (format in ``docs/scene-file.md``).

    Mesh paths are relative to the scene file's folder.
    """
    path = Path(path)
    data = _read_toml(path)
    _check_keys(data, {"render", "camera", "sky", "light", "object"}, str(path))
    spec = SceneSpec()
    _read_render(spec, _table(data, "render", path), path)
    spec.camera = _read_camera(_table(data, "camera", path), path)
    spec.sky = _read_sky(_table(data, "sky", path), path)
    spec.lights.extend(_read_lights(data.get("light", []), path))
    spec.objects.extend(_read_objects(data.get("object", []), path))
    return spec


def _read_toml(path: Path) -> dict[str, Any]:
    """The scene file's TOML document."""
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise UsageError(f"{path}: scene file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise UsageError(f"{path}: cannot read scene file ({exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise UsageError(f"{path}: not valid TOML ({exc})") from None


def _read_render(spec: SceneSpec, render: dict[str, Any], path: Path) -> None:
    """The ``[render]`` table into ``spec``: size, preset, illuminant."""
    _check_keys(render, {"size", "preset", "illuminant"}, f"{path} [render]")
    if "size" in render:
        spec.size = parse_size(render["size"])
    spec.preset = str(render.get("preset", spec.preset))
    spec.illuminant = str(render.get("illuminant", spec.illuminant))


def _read_camera(cam: dict[str, Any], path: Path) -> CameraSpec:
    """The ``[camera]`` table."""
    _check_keys(cam, {"eye", "target", "up", "fov"}, f"{path} [camera]")
    return CameraSpec(
        eye=parse_vector(cam["eye"], f"{path} [camera] eye") if "eye" in cam else None,
        target=parse_vector(cam["target"], f"{path} [camera] target") if "target" in cam else None,
        up=parse_vector(cam.get("up", (0, 0, 1)), f"{path} [camera] up"),
        fov_deg=float(cam.get("fov", 35.0)),
    )


def _read_sky(sky: dict[str, Any], path: Path) -> SkySpec:
    """The ``[sky]`` table."""
    _check_keys(sky, {"kind", "zenith", "horizon", "spectrum"}, f"{path} [sky]")
    return SkySpec(
        kind=str(sky.get("kind", "gradient")),
        zenith=float(sky.get("zenith", 0.25)),
        horizon=float(sky.get("horizon", 0.6)),
        spectrum=sky.get("spectrum"),
    )


def _read_lights(lights: list[dict[str, Any]], path: Path) -> list[LightSpec]:
    """The ``[[light]]`` tables."""
    out = []
    for i, light in enumerate(lights):
        where = f"{path} [[light]] #{i + 1}"
        _check_keys(light, {"kind", "direction", "position", "spectrum", "intensity"}, where)
        kind = str(light.get("kind", "directional"))
        key = "direction" if kind == "directional" else "position"
        if key not in light:
            raise UsageError(f"{where}: a {kind} light needs '{key}'")
        out.append(
            LightSpec(
                kind=kind,
                vector=parse_vector(light[key], f"{where} {key}"),
                spectrum=light.get("spectrum"),
                intensity=float(light.get("intensity", 1.0)),
            )
        )
    return out


def _read_objects(objects: list[dict[str, Any]], path: Path) -> list[ObjectSpec]:
    """The ``[[object]]`` tables (at least one); mesh paths relative to the scene file's folder."""
    if not objects:
        raise UsageError(f"{path}: no [[object]] in the scene; add at least one mesh or procedural object")
    allowed = {"mesh", "procedural", "material", "materials", "translate", "rotate", "scale",
               "weave_angle", "radius", "size", "triangles"}
    out = []
    for i, obj in enumerate(objects):
        where = f"{path} [[object]] #{i + 1}"
        _check_keys(obj, allowed, where)
        if ("mesh" in obj) == ("procedural" in obj):
            raise UsageError(f"{where}: give exactly one of 'mesh' (a file) or 'procedural' (hawk, sphere, plane, cloth)")
        mesh = (path.parent / obj["mesh"]) if "mesh" in obj else None
        proc_args = {k: obj[k] for k in ("radius", "size", "triangles") if k in obj}
        regions = obj.get("materials", {})
        if not isinstance(regions, dict):
            raise UsageError(f"{where}: 'materials' must be a table of region = material")
        out.append(
            ObjectSpec(
                mesh=mesh,
                procedural=obj.get("procedural"),
                procedural_args=proc_args,
                material=str(obj.get("material", "gold")),
                region_materials={str(k): str(v) for k, v in regions.items()},
                translate=parse_vector(obj.get("translate", (0, 0, 0)), f"{where} translate"),
                rotate_deg=parse_vector(obj.get("rotate", (0, 0, 0)), f"{where} rotate"),
                scale=float(obj.get("scale", 1.0)),
                weave_angle_deg=(float(obj["weave_angle"]) if "weave_angle" in obj else None),
            )
        )
    return out
