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
    "EnvironmentSpec",
    "CameraSpec",
    "SceneSpec",
    "parse_vector",
    "parse_fov",
    "parse_position",
    "parse_angles",
    "check_range",
    "parse_size",
    "parse_light",
    "parse_environment",
    "ENVIRONMENT_SKY_KEYS",
    "load_scene_file",
    "MAX_SCENE_BYTES",
    "check_path_text",
    "check_procedural_args",
    "MAX_TRIANGLES",
    "PROCEDURAL_KEYS",
    "PRESET_NAMES",
    "SKY_KINDS",
]

#: Render presets a scene file may name (render/presets.py).
PRESET_NAMES = ("draft", "standard", "reference")

#: Sky kinds (render/scene.py).
SKY_KINDS = ("uniform", "gradient", "none")


@dataclass
class ObjectSpec:
    """One object: a mesh file or a procedural shape, its material(s) and placement.

    ``material`` is a material spec string (``"gold:roughness=0.2"``);
    ``region_materials`` maps region names of a procedural object (the hawk)
    to material spec strings and overrides ``material`` region by region.  For
    a mesh file with per-face materials (a PLY with a face ``material``
    property, a glTF with a primitive per material,
    :mod:`render.material_mesh`) the file's own specs are used and
    ``region_materials`` keys are region names or indices (``"0"``; ``"-1"``
    for the faces of no region); faces without a material render in a neutral
    grey and ``material`` is not used.
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
class EnvironmentSpec:
    """An environment map lighting the scene: a file (``.exr`` / ``.hdr``) or the analytic sky.

    ``file`` is None for the analytic sky, whose settings (the keyword arguments
    of :func:`processing.lighting.daylight_sky.daylight_sky`) are in ``sky``.
    """

    file: Path | None = None
    sky: dict[str, Any] = field(default_factory=dict)
    rotate_deg: float = 0.0
    intensity: float = 1.0


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
    environment: EnvironmentSpec | None = None
    environment_samples: int | None = None  # None: the preset's
    sky_given: bool = False                # a sky was asked for (else an environment replaces the default one)


def parse_vector(text: str | list | tuple, name: str, limit: float | None = None,
                 unit: str = "") -> tuple[float, float, float]:
    """Parse ``"X,Y,Z"`` (or a 3-list from TOML) into three finite floats.

    Parameters
    ----------
    text
        ``"X,Y,Z"`` or a sequence of three numbers.
    name
        The flag or key, for messages.
    limit
        Largest magnitude of each number (None: no bound but finiteness).
    unit
        Unit of ``limit`` in messages (``" mm"``, ``" degrees"``).

    Returns
    -------
    tuple of float
        The three numbers.

    Examples
    --------
    >>> parse_vector("1, 2,3", "--eye")
    (1.0, 2.0, 3.0)
    >>> parse_vector("0,0,1e9", "--eye", 1e7, " mm")
    Traceback (most recent call last):
    ...
    app.errors.UsageError: --eye: expected three numbers X,Y,Z of magnitude at most 1e+07 mm, got '0,0,1e9'
    """
    try:
        parts = text.split(",") if isinstance(text, str) else list(text)
        values = tuple(float(p) for p in parts)
    except (TypeError, ValueError):
        raise UsageError(f"{name}: expected three numbers X,Y,Z, got {text!r}") from None
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise UsageError(f"{name}: expected three finite numbers X,Y,Z, got {text!r}")
    if limit is not None and max(abs(v) for v in values) > limit:
        raise UsageError(f"{name}: expected three numbers X,Y,Z of magnitude at most {limit:g}{unit}, got {text!r}")
    return values  # type: ignore[return-value]


def parse_position(text: str | list | tuple, name: str) -> tuple[float, float, float]:
    """:func:`parse_vector` of a position or direction, each coordinate within ``render.limits.MAX_COORDINATE_MM``."""
    from render.limits import MAX_COORDINATE_MM

    return parse_vector(text, name, MAX_COORDINATE_MM, " mm")


def parse_angles(text: str | list | tuple, name: str) -> tuple[float, float, float]:
    """:func:`parse_vector` of three rotation angles, each within ``render.limits.MAX_ANGLE_DEG`` degrees."""
    from render.limits import MAX_ANGLE_DEG

    return parse_vector(text, name, MAX_ANGLE_DEG, " degrees")


def parse_fov(value: Any, name: str) -> float:
    """A vertical field of view in degrees, from ``render.limits.MIN_FOV_DEG`` up to (not including) 180.

    Parameters
    ----------
    value
        The number given.
    name
        The flag or key, for messages.

    Returns
    -------
    float
        The field of view, degrees.

    Examples
    --------
    >>> parse_fov(35, "--fov")
    35.0
    >>> parse_fov(1e-6, "--fov")
    Traceback (most recent call last):
    ...
    app.errors.UsageError: --fov: expected a vertical field of view from 0.1 to 180 degrees (180 excluded; \
float32 ray casting resolves no narrower view), got 1e-06
    """
    from render.limits import MIN_FOV_DEG

    fov = float(value)
    if not (math.isfinite(fov) and MIN_FOV_DEG <= fov < 180.0):
        raise UsageError(f"{name}: expected a vertical field of view from {MIN_FOV_DEG:g} to 180 degrees (180 "
                         f"excluded; float32 ray casting resolves no narrower view), got {value!r}")
    return fov


def check_range(value: float, name: str, low: float, high: float, what: str) -> float:
    """``value`` if it is finite and within ``[low, high]``, else a :class:`UsageError` stating the range.

    Examples
    --------
    >>> check_range(2.0, "--light", 1e-9, 1e12, "intensity")
    2.0
    """
    if not (math.isfinite(value) and low <= value <= high):
        raise UsageError(f"{name}: expected {what} from {low:g} to {high:g}, got {value!r}")
    return value


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
        from render.limits import LIGHT_INTENSITY_RANGE

        check_range(intensity, "--light", *LIGHT_INTENSITY_RANGE, "an intensity after '*'")
    spectrum = None
    if "@" in rest:
        rest, _, spectrum = rest.partition("@")
    vec = parse_position(rest, "--light")
    if kind == "directional" and not any(vec):
        raise UsageError("--light: a directional light needs a non-zero direction")
    return LightSpec(kind=kind, vector=vec, spectrum=spectrum or None, intensity=intensity)


#: Settings of the analytic sky (``--environment sky:KEY=VALUE,...``, ``[environment.sky]``): the
#: keyword argument of :func:`processing.lighting.daylight_sky.daylight_sky` each sets.
ENVIRONMENT_SKY_KEYS = {"cct": "cct", "sun_elevation": "sun_elevation_deg", "sun_azimuth": "sun_azimuth_deg",
                        "type": "sky_type", "sun": "sun", "sun_cct": "sun_cct", "luminance": "luminance",
                        "ground": "ground", "height": "height"}

_ENVIRONMENT_FORMS = ("FILE.exr|FILE.hdr[:rotate=DEG,intensity=X] or "
                      "sky[:cct=K,sun_elevation=DEG,sun_azimuth=DEG,type=clear|intermediate|overcast|1-15,...]")


def _environment_value(key: str, value: Any, where: str) -> Any:
    """One environment setting checked: a finite number (the sky type may be a name), ranges for the common keys."""
    if key == "type" and isinstance(value, str) and not value.strip().lstrip("-").isdigit():
        return value.strip().lower()
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            raise UsageError(f"{where} {key}: expected a number, got {value!r}") from None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(float(value)):
        raise UsageError(f"{where} {key}: expected a finite number, got {value!r}")
    value = float(value)
    if key == "intensity" and not value > 0:
        raise UsageError(f"{where} intensity: expected a number > 0, got {value:g}")
    _environment_range(key, value, where)
    if key in ("type", "height"):
        if not value.is_integer():
            raise UsageError(f"{where} {key}: expected a whole number, got {value:g}")
        return int(value)
    return value


def _environment_range(key: str, value: float, where: str) -> None:
    """Refuse an environment ``intensity`` or sky ``luminance`` outside ``render.limits.ENVIRONMENT_INTENSITY_RANGE``
    and a ``rotate`` beyond ``render.limits.MAX_ANGLE_DEG``."""
    from render.limits import ENVIRONMENT_INTENSITY_RANGE, MAX_ANGLE_DEG

    if key in ("intensity", "luminance"):
        low, high = ENVIRONMENT_INTENSITY_RANGE
        check_range(value, f"{where} {key}", low, high, "a number")
    elif key == "rotate":
        check_range(value, f"{where} rotate", -MAX_ANGLE_DEG, MAX_ANGLE_DEG, "an angle in degrees")


def _environment_options(items: dict[str, Any], is_file: bool, where: str) -> tuple[dict[str, Any], float, float]:
    """Checked options: the sky's keyword arguments, the rotation and the intensity."""
    allowed = {"rotate", "intensity"} | (set() if is_file else set(ENVIRONMENT_SKY_KEYS))
    unknown = sorted(set(items) - allowed)
    if unknown:
        raise UsageError(f"{where}: unknown option(s) {', '.join(unknown)}; allowed: {', '.join(sorted(allowed))}")
    values = {k: _environment_value(k, v, where) for k, v in items.items()}
    rotate = values.pop("rotate", 0.0)
    intensity = values.pop("intensity", 1.0)
    return {ENVIRONMENT_SKY_KEYS[k]: v for k, v in values.items()}, rotate, intensity


def parse_environment(text: str, where: str = "--environment") -> EnvironmentSpec:
    """Parse ``FILE.exr[:rotate=DEG,intensity=X]`` or ``sky[:cct=K,sun_elevation=DEG,...]``.

    The file must end in ``.exr`` or ``.hdr``; ``sky`` is the analytic sky
    (:func:`processing.lighting.daylight_sky.daylight_sky`, keys in
    :data:`ENVIRONMENT_SKY_KEYS`), which takes ``rotate`` and ``intensity``
    too.

    Examples
    --------
    >>> parse_environment("probe.exr:rotate=90,intensity=2").rotate_deg
    90.0
    >>> parse_environment("sky:cct=5000,sun_elevation=30,type=overcast").sky
    {'cct': 5000.0, 'sun_elevation_deg': 30.0, 'sky_type': 'overcast'}
    """
    text = text.strip()
    low = text.lower()
    if low == "sky" or low.startswith("sky:"):
        source, options, is_file = None, text[4:], False
    else:
        cut = max(low.rfind(".exr"), low.rfind(".hdr"))
        if cut < 0 or (len(text) > cut + 4 and text[cut + 4] != ":"):
            raise UsageError(f"{where}: expected {_ENVIRONMENT_FORMS}, got {text!r}")
        source, options, is_file = text[:cut + 4], text[cut + 5:], True
        check_path_text(source, where)
    items: dict[str, str] = {}
    for part in filter(None, (p.strip() for p in options.split(","))):
        key, eq, value = part.partition("=")
        if not eq or not key.strip():
            raise UsageError(f"{where}: options are KEY=VALUE separated by commas, got {part!r} in {text!r}")
        items[key.strip().lower()] = value.strip()
    sky, rotate, intensity = _environment_options(items, is_file, where)
    return EnvironmentSpec(Path(source) if source else None, sky, rotate, intensity)


#: Most triangles a procedural object may ask for: the renderer needs about 0.6 GB for a
#: 1M-triangle mesh (render/renderer.py), so 10 million is a generous but finite bound.
MAX_TRIANGLES = 10_000_000

#: Procedural shapes and the keys each takes besides the common ones.
PROCEDURAL_KEYS = {"hawk": ("triangles",), "sphere": ("radius", "triangles"), "plane": ("size",),
                   "cloth": ("triangles",)}


def _kind(value: Any) -> str:
    """The TOML name of ``value``'s type, for messages."""
    if isinstance(value, bool):
        return "boolean"
    if isinstance(value, dict):
        return "table"
    if isinstance(value, list):
        return "array"
    return {int: "integer", float: "float", str: "string"}.get(type(value), type(value).__name__)


def _string(table: dict, key: str, where: str, default: Any = None,
            choices: tuple[str, ...] | None = None) -> Any:
    """``table[key]`` as a string (``default`` when absent), one of ``choices`` if given."""
    if key not in table:
        return default
    value = table[key]
    if not isinstance(value, str):
        expected = f"one of {', '.join(choices)}" if choices else "a string"
        raise UsageError(f"{where} {key}: expected {expected}, got {value!r} ({_kind(value)})")
    if choices is not None and value.lower() not in choices:
        raise UsageError(f"{where} {key}: expected one of {', '.join(choices)}, got {value!r}")
    return value.lower() if choices is not None else value


def _number(table: dict, key: str, where: str, default: float | None, *, low: float | None = None,
            high: float | None = None, strict: bool = False) -> float | None:
    """``table[key]`` as a finite float in ``[low, high]`` (``(low, high)`` when ``strict``); ``default`` when absent."""
    if key not in table:
        return default
    value = table[key]
    rng = _range_text(low, high, strict)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise UsageError(f"{where} {key}: expected a number{rng}, got {value!r} ({_kind(value)})")
    x = float(value)
    ok = math.isfinite(x)
    if ok and low is not None:
        ok = x > low if strict else x >= low
    if ok and high is not None:
        ok = x < high if strict else x <= high
    if not ok:
        raise UsageError(f"{where} {key}: expected a finite number{rng}, got {value!r}")
    return x


def _range_text(low: float | None, high: float | None, strict: bool) -> str:
    """`` > 0``, `` between 0 and 180`` ...: the range part of a message."""
    if low is not None and high is not None:
        return f" between {low:g} and {high:g}" + (" (exclusive)" if strict else "")
    if low is not None:
        return f" {'>' if strict else '>='} {low:g}"
    if high is not None:
        return f" {'<' if strict else '<='} {high:g}"
    return ""


def _whole(table: dict, key: str, where: str, low: int, high: int) -> int | None:
    """``table[key]`` as a whole number in ``[low, high]`` (None when absent)."""
    if key not in table:
        return None
    value = table[key]
    if (isinstance(value, bool) or not isinstance(value, (int, float))
            or (isinstance(value, float) and not (math.isfinite(value) and value.is_integer()))):
        raise UsageError(f"{where} {key}: expected a whole number from {low} to {high}, "
                         f"got {value!r} ({_kind(value)})")
    if not low <= value <= high:
        raise UsageError(f"{where} {key}: expected a whole number from {low} to {high}, got {value!r}")
    return int(value)


def _vector(table: dict, key: str, where: str, default: Any,
            parse: Any = None) -> tuple[float, float, float] | None:
    """``table[key]`` as three finite numbers (an array ``[x, y, z]``); ``default`` when absent.

    ``parse`` checks the numbers' range (default :func:`parse_position`; :func:`parse_angles` for rotations).
    """
    if key not in table:
        return default
    value = table[key]
    if (not isinstance(value, list) or len(value) != 3
            or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in value)):
        raise UsageError(f"{where} {key}: expected an array of three numbers [x, y, z], "
                         f"got {value!r} ({_kind(value)})")
    return (parse or parse_position)(value, f"{where} {key}")


def check_procedural_args(kind: str, args: dict[str, Any], where: str) -> dict[str, Any]:
    """The checked size arguments of a procedural object (``radius``, ``size`` > 0, ``triangles`` bounded).

    Raises :class:`UsageError` naming ``where`` and the key for a wrong type,
    a non-finite or non-positive size, a triangle count outside
    ``1..MAX_TRIANGLES`` or a key the shape does not take.

    Parameters
    ----------
    kind
        The procedural shape: one of :data:`PROCEDURAL_KEYS`.
    args
        Its ``radius``, ``size`` and ``triangles`` values as given.
    where
        Names the object in messages.

    Returns
    -------
    dict
        ``radius`` and ``size`` as floats, ``triangles`` as an int.

    Examples
    --------
    >>> check_procedural_args("sphere", {"radius": 2, "triangles": 500}, "obj")
    {'radius': 2.0, 'triangles': 500}
    """
    allowed = PROCEDURAL_KEYS.get(kind, ())
    extra = sorted(set(args) - set(allowed))
    if extra:
        raise UsageError(f"{where}: a {kind} object takes no {', '.join(extra)} "
                         f"(it takes {', '.join(allowed) or 'no size keys'})")
    out: dict[str, Any] = {}
    for key in ("radius", "size"):
        if key in args:
            out[key] = _number(args, key, where, None, low=0.0, strict=True)
    if "triangles" in args:
        out["triangles"] = _whole(args, "triangles", where, 1, MAX_TRIANGLES)
    return out


def check_path_text(text: str, where: str) -> None:
    r"""Refuse a file name the operating system cannot take: empty, with a NUL byte, or too long.

    Parameters
    ----------
    text
        The file path as given.
    where
        Names the key or flag in messages.

    Examples
    --------
    >>> check_path_text("head.ply", "mesh")
    >>> check_path_text("a\x00b", "mesh")
    Traceback (most recent call last):
    ...
    app.errors.UsageError: mesh: expected a file path, got 'a\x00b' (it cannot contain a NUL byte)
    """
    if not text.strip():
        raise UsageError(f"{where}: expected a file path, got an empty string")
    if "\x00" in text:
        raise UsageError(f"{where}: expected a file path, got {text!r} (it cannot contain a NUL byte)")
    try:
        Path(text).exists()
    except (OSError, ValueError) as exc:
        raise UsageError(f"{where}: {text[:80]!r} cannot be used as a file path ({exc.__class__.__name__}: "
                         f"{getattr(exc, 'strerror', None) or exc})") from None


def _table(data: dict, key: str, path: Path) -> dict:
    value = data.get(key, {})
    if not isinstance(value, dict):
        raise UsageError(f"{path}: [{key}] must be a table, got {value!r} ({_kind(value)})")
    return value


def _tables(data: dict, key: str, path: Path) -> list[dict]:
    """``[[key]]``: an array of tables (empty when absent)."""
    value = data.get(key, [])
    if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
        raise UsageError(f"{path}: [[{key}]] must be an array of tables ([[{key}]] headers), "
                         f"got {value!r} ({_kind(value)})")
    return value


def _check_keys(table: dict, allowed: set[str], where: str) -> None:
    unknown = set(table) - allowed
    if unknown:
        raise UsageError(
            f"{where}: unknown key(s) {', '.join(sorted(unknown))}; allowed: {', '.join(sorted(allowed))}"
        )


def load_scene_file(path: str | Path) -> SceneSpec:
    """Read a TOML scene file (format in ``docs/scene-file.md``).

    Mesh paths are relative to the scene file's folder.  Every value is
    checked for its type and range; a wrong one is a :class:`UsageError`
    naming the file, the table and the key.
    """
    path = Path(path)
    data = _read_toml(path)
    _check_keys(data, {"render", "camera", "sky", "light", "object", "environment"}, str(path))
    spec = SceneSpec()
    _read_render(spec, _table(data, "render", path), path)
    spec.camera = _read_camera(_table(data, "camera", path), path)
    spec.sky = _read_sky(_table(data, "sky", path), path)
    spec.sky_given = "sky" in data
    if "environment" in data:
        spec.environment = _read_environment(_table(data, "environment", path), path)
    spec.lights.extend(_read_lights(_tables(data, "light", path), path))
    spec.objects.extend(_read_objects(_tables(data, "object", path), path))
    return spec


#: Largest scene file read (a scene is a few hundred bytes; this refuses a disk image or a device).
MAX_SCENE_BYTES = 1 << 20


def _read_toml(path: Path) -> dict[str, Any]:
    """The scene file's TOML document (a regular file of at most ``MAX_SCENE_BYTES``)."""
    try:
        if path.exists() and not path.is_file():
            raise UsageError(f"{path}: not a regular file; give a TOML scene file")
        if path.exists() and path.stat().st_size > MAX_SCENE_BYTES:
            raise UsageError(f"{path}: {path.stat().st_size} bytes is too large for a scene file "
                             f"(at most {MAX_SCENE_BYTES} bytes)")
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except RecursionError:
        raise UsageError(f"{path}: arrays or tables nested too deeply to read; a scene file needs at most "
                         "a few levels of nesting (docs/scene-file.md)") from None
    except FileNotFoundError:
        raise UsageError(f"{path}: scene file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise UsageError(f"{path}: cannot read scene file ({exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise UsageError(f"{path}: not valid TOML ({exc})") from None


def _read_render(spec: SceneSpec, render: dict[str, Any], path: Path) -> None:
    """The ``[render]`` table into ``spec``: size, preset, illuminant."""
    where = f"{path} [render]"
    _check_keys(render, {"size", "preset", "illuminant", "environment_samples"}, where)
    size = _string(render, "size", where)
    if size is not None:
        try:
            spec.size = parse_size(size)
        except UsageError as exc:
            raise UsageError(f"{where} size: {str(exc).removeprefix('--size: ')}") from None
    spec.preset = _string(render, "preset", where, spec.preset, PRESET_NAMES)
    spec.illuminant = _string(render, "illuminant", where, spec.illuminant)
    samples = _whole(render, "environment_samples", where, 0, 4096)
    if samples == 1:
        raise UsageError(f"{where} environment_samples: expected 0 (prefiltered map) or 2 to 4096, got 1")
    spec.environment_samples = samples


def _read_camera(cam: dict[str, Any], path: Path) -> CameraSpec:
    """The ``[camera]`` table."""
    where = f"{path} [camera]"
    _check_keys(cam, {"eye", "target", "up", "fov"}, where)
    return CameraSpec(
        eye=_vector(cam, "eye", where, None),
        target=_vector(cam, "target", where, None),
        up=_vector(cam, "up", where, (0.0, 0.0, 1.0)),
        fov_deg=parse_fov(_number(cam, "fov", where, 35.0), f"{where} fov"),
    )


def _read_sky(sky: dict[str, Any], path: Path) -> SkySpec:
    """The ``[sky]`` table."""
    where = f"{path} [sky]"
    _check_keys(sky, {"kind", "zenith", "horizon", "spectrum"}, where)
    return SkySpec(
        kind=_string(sky, "kind", where, "gradient", SKY_KINDS),
        zenith=_number(sky, "zenith", where, 0.25, low=0.0, high=_max_sky_radiance()),
        horizon=_number(sky, "horizon", where, 0.6, low=0.0, high=_max_sky_radiance()),
        spectrum=_string(sky, "spectrum", where),
    )


def _max_sky_radiance() -> float:
    from render.limits import MAX_SKY_RADIANCE

    return MAX_SKY_RADIANCE


def _read_environment(env: dict[str, Any], path: Path) -> EnvironmentSpec:
    """The ``[environment]`` table: ``file`` (relative to the scene file) or an ``[environment.sky]`` table."""
    where = f"{path} [environment]"
    _check_keys(env, {"file", "sky", "rotate", "intensity"}, where)
    if ("file" in env) == ("sky" in env):
        raise UsageError(f"{where}: give exactly one of 'file' (an .exr or .hdr map) or a [environment.sky] table")
    common = {k: env[k] for k in ("rotate", "intensity") if k in env}
    if "file" in env:
        name = _string(env, "file", where)
        check_path_text(name, f"{where} file")
        if Path(name).suffix.lower() not in (".exr", ".hdr"):
            raise UsageError(f"{where} file: expected an .exr or .hdr environment map, got {name!r}")
        _, rotate, intensity = _environment_options(common, True, where)
        return EnvironmentSpec(path.parent / name, {}, rotate, intensity)
    sky = env["sky"]
    if not isinstance(sky, dict):
        raise UsageError(f"{where} sky: expected a table of sky settings ([environment.sky]), got {sky!r} ({_kind(sky)})")
    options, rotate, intensity = _environment_options({**sky, **common}, False, f"{where}")
    return EnvironmentSpec(None, options, rotate, intensity)


def _read_lights(lights: list[dict[str, Any]], path: Path) -> list[LightSpec]:
    """The ``[[light]]`` tables."""
    out = []
    for i, light in enumerate(lights):
        where = f"{path} [[light]] #{i + 1}"
        _check_keys(light, {"kind", "direction", "position", "spectrum", "intensity"}, where)
        kind = _string(light, "kind", where, "directional", ("directional", "point"))
        key = "direction" if kind == "directional" else "position"
        if key not in light:
            raise UsageError(f"{where}: a {kind} light needs '{key}'")
        vector = _vector(light, key, where, None)
        if kind == "directional" and not any(vector):
            raise UsageError(f"{where} direction: expected a non-zero direction, got {light[key]!r}")
        from render.limits import LIGHT_INTENSITY_RANGE

        low, high = LIGHT_INTENSITY_RANGE
        out.append(LightSpec(kind=kind, vector=vector, spectrum=_string(light, "spectrum", where),
                             intensity=_number(light, "intensity", where, 1.0, low=low, high=high)))
    return out


def _read_objects(objects: list[dict[str, Any]], path: Path) -> list[ObjectSpec]:
    """The ``[[object]]`` tables (at least one); mesh paths relative to the scene file's folder."""
    if not objects:
        raise UsageError(f"{path}: no [[object]] in the scene; add at least one mesh or procedural object")
    return [_read_object(obj, f"{path} [[object]] #{i + 1}", path) for i, obj in enumerate(objects)]


def _read_object(obj: dict[str, Any], where: str, path: Path) -> ObjectSpec:
    """One ``[[object]]`` table."""
    allowed = {"mesh", "procedural", "material", "materials", "translate", "rotate", "scale",
               "weave_angle", "radius", "size", "triangles"}
    _check_keys(obj, allowed, where)
    if ("mesh" in obj) == ("procedural" in obj):
        raise UsageError(f"{where}: give exactly one of 'mesh' (a file) or 'procedural' (hawk, sphere, plane, cloth)")
    mesh = _string(obj, "mesh", where)
    if mesh is not None:
        check_path_text(mesh, f"{where} mesh")
    procedural = _string(obj, "procedural", where, None, tuple(PROCEDURAL_KEYS))
    proc_args = {k: obj[k] for k in ("radius", "size", "triangles") if k in obj}
    if procedural is not None:
        proc_args = check_procedural_args(procedural, proc_args, where)
    elif proc_args:
        raise UsageError(f"{where}: {', '.join(proc_args)} belong(s) to procedural objects, not to a mesh file")
    regions = obj.get("materials", {})
    if not isinstance(regions, dict) or not all(isinstance(v, str) for v in regions.values()):
        raise UsageError(f"{where} materials: expected a table of region = \"material\" strings, "
                         f"got {regions!r} ({_kind(regions)})")
    from render.limits import MAX_ANGLE_DEG, SCALE_RANGE

    weave = _number(obj, "weave_angle", where, None, low=-MAX_ANGLE_DEG, high=MAX_ANGLE_DEG)
    return ObjectSpec(
        mesh=(path.parent / mesh) if mesh is not None else None,
        procedural=procedural,
        procedural_args=proc_args,
        material=_string(obj, "material", where, "gold"),
        region_materials={str(k): v for k, v in regions.items()},
        translate=_vector(obj, "translate", where, (0.0, 0.0, 0.0)),
        rotate_deg=_vector(obj, "rotate", where, (0.0, 0.0, 0.0), parse_angles),
        scale=_number(obj, "scale", where, 1.0, low=SCALE_RANGE[0], high=SCALE_RANGE[1]),
        weave_angle_deg=weave,
    )
