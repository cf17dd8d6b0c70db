"""What the renderer draws: objects with materials, lights and a sky.

The terms of the colour signal of Matsuda et al., eq. (2) and (5): the
light's spectral power E(lambda) and its incidence (directional and point
lights), the environment reflected by the mirror term (the sky), and the
objects' reflection models (materials of :mod:`processing.materials.presets`).

* :class:`SceneObject`: a :class:`~render.meshio.Mesh` with a list of
  :class:`~processing.materials.lobes.Material` and an optional material index per
  triangle or per vertex (a vertex-indexed material covers the part of each
  triangle nearest to that vertex: the largest barycentric weight wins).
* :class:`Light`: ``"directional"`` (``vector`` is the direction from the
  surface toward the light; irradiance ``intensity * E(lambda)`` on a
  surface facing it) or ``"point"`` (``vector`` is its position; irradiance
  ``intensity * E(lambda) / r^2`` at distance r, the inverse-square law).
  ``E`` is the relative spectrum, 1 at 560 nm.
* :class:`Sky`: the environment seen by mirror lobes and lighting the other
  lobes.  Radiance along a direction d is ``s(d) * S(lambda) / pi`` in units
  of the key (first) light's irradiance, where ``S`` is the sky's relative
  spectrum and the scale ``s`` is ``zenith`` everywhere (``"uniform"``) or
  ``horizon + (zenith - horizon) * max(0, d . up)`` (``"gradient"``; below
  the horizon it stays at ``horizon``).  The unit is chosen so that a white
  Lambertian surface under a uniform sky of scale s with the key light's
  spectrum has the luminance s of the renderer's normalisation (a white
  Lambertian facing the key light has luminance 1).

:func:`check_point_lights` finds point lights enclosed by a closed mesh
(every ray from the light hits the back of a surface) and reports them.

References
----------
Matsuda, Tanaka, Ichikawa, Mochizuki, Muroya, Kitamura, "CG reproduction of
a craft object based on a light reflection model", IPSJ technical report
(no DOI).

Examples
--------
>>> Sky("gradient", zenith=0.2, horizon=0.6).radiance_scale([[0, 0, 1], [1, 0, 0]]).tolist()
[0.2, 0.6]
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.lighting.environment_map import EnvironmentMap
from processing.materials.lobes import Material
from processing.spectral.spectra import REFERENCE_GRID, SpectralGrid, light_spectrum, resample
from render.errors import RenderInputError
from render.limits import LIGHT_INTENSITY_RANGE, MAX_COORDINATE_MM, MAX_SKY_RADIANCE
from render.meshio import Mesh, check_mesh_extent

__all__ = [
    "SceneObject",
    "Light",
    "Sky",
    "Scene",
    "resolve_spectrum",
    "hemisphere_mean_clamped_cosine",
    "check_point_lights",
]

SpectrumLike = Any  # str | float | os.PathLike | ndarray | None


def resolve_spectrum(spec: SpectrumLike, grid: SpectralGrid, what: str = "spectrum") -> NDArray[np.float64]:
    """Relative spectral power of a light or sky on ``grid``, 1 at 560 nm.

    Parameters
    ----------
    spec
        A CIE illuminant name, a colour temperature (``"3200K"`` or a number
        in K) or a CSV path (see :func:`processing.spectral.spectra.light_spectrum`);
        or an array: ``(K, 2)`` rows of (nm, value), or ``(61,)`` values on
        the 400-700 nm / 5 nm reference grid.
    grid
        Target grid.
    what
        Name of the parameter for error messages.

    Returns
    -------
    ndarray
        float64 ``(L,)`` relative power on ``grid`` (1 at the grid's
        wavelength nearest 560 nm, or at its peak when that is 0).

    Raises
    ------
    RenderInputError
        Unknown name, unreadable file, wrong array shape, negative or
        non-finite values, no power at all.

    Examples
    --------
    >>> e = resolve_spectrum([[400, 1.0], [700, 2.0]], SpectralGrid(400, 700, 100))   # 1 at 600 nm, nearest 560
    >>> [round(float(x), 4) for x in e]
    [0.6, 0.8, 1.0, 1.2]
    """
    if isinstance(spec, (str, os.PathLike, int, float, np.integer, np.floating)) and not isinstance(spec, bool):
        try:
            return light_spectrum(spec, grid)
        except ValueError as exc:
            raise RenderInputError(f"{what}: {exc}") from None
    try:
        arr = np.asarray(spec, dtype=np.float64)
    except (TypeError, ValueError):
        raise RenderInputError(
            f"{what} must be an illuminant name, a colour temperature, a CSV path or an array, got {spec!r}"
        ) from None
    if not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise RenderInputError(f"{what}: spectral values must be finite and >= 0")
    try:
        if arr.ndim == 2 and arr.shape[1] == 2:
            values = resample(arr[:, 0], arr[:, 1], grid, method="average")
        elif arr.ndim == 1 and arr.size == REFERENCE_GRID.size:
            values = resample(REFERENCE_GRID.wavelengths, arr, grid, method="average")
        else:
            raise RenderInputError(
                f"{what}: an array spectrum must be (K, 2) rows of (nm, value) or {REFERENCE_GRID.size} "
                f"values on 400-700 nm at 5 nm, got shape {arr.shape}"
            )
    except RenderInputError:
        raise
    except ValueError as exc:
        raise RenderInputError(f"{what}: {exc}") from None
    ref = values[int(np.argmin(np.abs(grid.wavelengths - 560.0)))]
    if not ref > 0:
        ref = float(values.max())
    if not ref > 0:
        raise RenderInputError(f"{what}: the spectrum has no power on {grid.start:g}-{grid.stop:g} nm")
    return values / ref


def _vector(value: ArrayLike, what: str) -> NDArray[np.float64]:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise RenderInputError(f"{what} must be three numbers (x, y, z), got {value!r}") from None
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise RenderInputError(f"{what} must be three finite numbers (x, y, z), got {value!r}")
    return arr


def _resolve_materials(materials: Sequence[Material | str], name: str) -> tuple[Material, ...]:
    if isinstance(materials, (Material, str)):
        materials = [materials]
    out: list[Material] = []
    for i, m in enumerate(materials):
        if isinstance(m, str):
            from processing.materials.presets import get_material

            try:
                m = get_material(m)
            except ValueError as exc:
                raise RenderInputError(f"object {name!r} material {i}: {exc}") from None
        if not isinstance(m, Material):
            raise RenderInputError(
                f"object {name!r} material {i} must be a processing.materials.lobes.Material or a material "
                f"spec string, got {type(m).__name__}"
            )
        if not m.lobes:
            raise RenderInputError(f"object {name!r} material {m.name!r} has no lobes")
        out.append(m)
    if not out:
        raise RenderInputError(f"object {name!r} has no materials; give at least one")
    return tuple(out)


@dataclass(frozen=True, eq=False)
class SceneObject:
    """A mesh with its materials.

    Parameters
    ----------
    mesh
        The geometry.
    materials
        One or more materials (or material spec strings for
        :func:`processing.materials.presets.get_material`).
    material_index
        Material number per triangle ``(T,)`` or per vertex ``(V,)``; None
        uses the mesh's own index if it has one, else material 0 everywhere.
    material_index_on
        ``"triangle"`` or ``"vertex"``; inferred from the length when None.
    name
        Used in messages.
    tangents
        Optional ``(V, 3)`` per-vertex yarn (warp) directions for
        anisotropic materials (:mod:`render.tangents` builds them from UVs,
        a direction field or a global direction); None projects
        :data:`render.tangents.DEFAULT_WARP_DIRECTION`.
    weave_angle_deg
        The weave turned about the normals by this angle (Yasuda et al.,
        Fig. 16: 0 vs 45 degrees); only anisotropic materials see it.

    Raises
    ------
    RenderInputError
        No materials, an index of the wrong length or out of range, several
        materials without an index, tangents of the wrong shape.
    MeshError
        A mesh float32 ray casting cannot resolve (:func:`render.meshio.check_mesh_extent`).
    """

    mesh: Mesh
    materials: Sequence[Material | str]
    material_index: ArrayLike | None = None
    material_index_on: str | None = None
    name: str = ""
    tangents: ArrayLike | None = None
    weave_angle_deg: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.mesh, Mesh):
            raise RenderInputError(
                f"object {self.name!r}: mesh must be a render.meshio.Mesh (use load_mesh or make_mesh), "
                f"got {type(self.mesh).__name__}"
            )
        name = self.name or os.path.basename(self.mesh.source)
        object.__setattr__(self, "name", name)
        check_mesh_extent(*self.mesh.bounds(), name)
        mats = _resolve_materials(self.materials, name)
        object.__setattr__(self, "materials", mats)
        if self.tangents is not None:
            object.__setattr__(self, "tangents", _checked_tangents(self.tangents, self.mesh, name))
        if not math.isfinite(float(self.weave_angle_deg)):
            raise RenderInputError(f"object {name!r}: weave_angle_deg must be finite, got {self.weave_angle_deg!r}")
        idx, on = self.material_index, self.material_index_on
        if idx is None and self.mesh.material_index is not None:
            idx, on = self.mesh.material_index, self.mesh.material_index_on
        if idx is None:
            if len(mats) > 1:
                raise RenderInputError(
                    f"object {name!r} has {len(mats)} materials but no material_index saying which "
                    "triangles or vertices use which"
                )
            object.__setattr__(self, "material_index", None)
            object.__setattr__(self, "material_index_on", None)
            return
        arr, on = _checked_material_index(idx, on, self.mesh, len(mats), name)
        object.__setattr__(self, "material_index", arr)
        object.__setattr__(self, "material_index_on", on)


def _checked_tangents(tangents: ArrayLike, mesh: Mesh, name: str) -> NDArray[np.float64]:
    """Per-vertex yarn directions as a finite float64 ``(V, 3)`` array."""
    tan = np.asarray(tangents, dtype=np.float64)
    if tan.shape != (mesh.n_vertices, 3) or not np.all(np.isfinite(tan)):
        raise RenderInputError(
            f"object {name!r}: tangents must be a finite ({mesh.n_vertices}, 3) array, one direction "
            f"per vertex, got shape {tan.shape}"
        )
    return tan


def _checked_material_index(idx: ArrayLike, on: str | None, mesh: Mesh, n_materials: int,
                            name: str) -> tuple[NDArray[np.int64], str]:
    """An object's material numbers per triangle or per vertex, and which of the two (inferred from the length)."""
    arr = np.asarray(idx)
    if arr.dtype.kind not in "iu" or arr.ndim != 1:
        raise RenderInputError(
            f"object {name!r}: material_index must be a 1-D integer array, got dtype {arr.dtype} "
            f"shape {arr.shape}"
        )
    arr = arr.astype(np.int64)
    nv, nt = mesh.n_vertices, mesh.n_triangles
    if on is None:
        if arr.size == nt and arr.size != nv:
            on = "triangle"
        elif arr.size == nv and arr.size != nt:
            on = "vertex"
        elif arr.size == nt:
            raise RenderInputError(
                f"object {name!r}: the mesh has as many vertices as triangles; say "
                "material_index_on='triangle' or 'vertex'"
            )
    expected = {"triangle": nt, "vertex": nv}.get(on)
    if expected is None or arr.size != expected:
        raise RenderInputError(
            f"object {name!r}: material_index has {arr.size} entries; expected one per triangle ({nt}) "
            f"or one per vertex ({nv})"
            + (f" (material_index_on={on!r})" if on else "")
        )
    if arr.size and (arr.min() < 0 or arr.max() >= n_materials):
        raise RenderInputError(
            f"object {name!r}: material_index values must be in 0..{n_materials - 1} "
            f"(it has {n_materials} materials), found {int(arr.min())}..{int(arr.max())}"
        )
    return arr, on


@dataclass(frozen=True)
class Light:
    """A directional or point light.

    Parameters
    ----------
    kind
        ``"directional"`` or ``"point"``.
    vector
        Directional: direction from the surface toward the light (any
        length, normalised here).  Point: position in scene units.
    spectrum
        Relative spectral power (see :func:`resolve_spectrum`).
    intensity
        Directional: irradiance scale on a surface facing the light.  Point:
        radiant intensity scale; irradiance ``intensity / r^2``.

    Raises
    ------
    RenderInputError
        An unknown kind, a vector that is not three finite numbers (or
        zero for a directional light, or a point light beyond
        ``render.limits.MAX_COORDINATE_MM``), a negative or non-finite
        intensity or one above ``render.limits.LIGHT_INTENSITY_RANGE``.

    Examples
    --------
    >>> Light("directional", (0, 0, 2)).vector
    (0.0, 0.0, 1.0)
    """

    kind: str
    vector: tuple[float, float, float]
    spectrum: SpectrumLike = "D65"
    intensity: float = 1.0

    def __post_init__(self) -> None:
        if self.kind not in ("directional", "point"):
            raise RenderInputError(f"light kind must be 'directional' or 'point', got {self.kind!r}")
        vec = _vector(self.vector, f"{self.kind} light vector")
        if self.kind == "directional":
            norm = float(np.linalg.norm(vec))
            if norm == 0.0:
                raise RenderInputError(
                    "directional light vector is zero; give the direction from the surface toward the light"
                )
            vec = vec / norm
        elif float(np.abs(vec).max()) > MAX_COORDINATE_MM:
            raise RenderInputError(f"point light position {vec.tolist()} lies beyond +-{MAX_COORDINATE_MM:g} mm, "
                                   "the range float32 ray casting resolves: bring it nearer the scene")
        object.__setattr__(self, "vector", tuple(vec.tolist()))
        try:
            intensity = float(self.intensity)
        except (TypeError, ValueError):
            raise RenderInputError(f"light intensity must be a number, got {self.intensity!r}") from None
        if not (math.isfinite(intensity) and 0.0 <= intensity <= LIGHT_INTENSITY_RANGE[1]):
            raise RenderInputError(f"light intensity must be finite and >= 0 (at most {LIGHT_INTENSITY_RANGE[1]:g}), "
                                   f"got {self.intensity!r}")
        object.__setattr__(self, "intensity", intensity)


def hemisphere_mean_clamped_cosine(cos_normal_up: ArrayLike) -> NDArray[np.float64]:
    """Cosine-weighted mean of ``max(0, d . up)`` over the hemisphere around a normal n.

    ``(1/pi) * integral over {d . n > 0} of max(0, d . up) (d . n) dd``
    ``= 2 / (3 pi) * ((pi - g) cos g + sin g)`` with ``g`` the angle between n
    and up (the overlap integral of two clamped cosines).

    Parameters
    ----------
    cos_normal_up
        ``cos g``, the cosine of the angle between the normal and up (any
        shape; clipped to [-1, 1]).

    Returns
    -------
    ndarray
        float64, the shape of ``cos_normal_up``: 2/3 facing up, 0 facing
        down.

    Examples
    --------
    >>> [round(float(x), 4) for x in hemisphere_mean_clamped_cosine([1.0, 0.0, -1.0])]
    [0.6667, 0.2122, 0.0]
    """
    c = np.clip(np.asarray(cos_normal_up, dtype=np.float64), -1.0, 1.0)
    g = np.arccos(c)
    return (2.0 / (3.0 * np.pi)) * ((np.pi - g) * c + np.sin(g))


@dataclass(frozen=True)
class Sky:
    """Environment radiance (see the module notes for units).

    Parameters
    ----------
    kind
        ``"uniform"`` (scale ``zenith`` in every direction), ``"gradient"``
        (``horizon`` at and below the horizon, rising linearly in
        ``d . up`` to ``zenith`` overhead) or ``"none"`` (black).
    zenith, horizon
        Radiance scales, >= 0.
    spectrum
        Relative spectrum; None takes the key (first) light's spectrum.
    up
        The zenith direction.

    Raises
    ------
    RenderInputError
        An unknown kind, a negative or non-finite scale, a zero or
        non-finite up vector.
    """

    kind: str = "none"
    zenith: float = 0.25
    horizon: float = 0.6
    spectrum: SpectrumLike = None
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)

    def __post_init__(self) -> None:
        if self.kind not in ("uniform", "gradient", "none"):
            raise RenderInputError(f"sky kind must be 'uniform', 'gradient' or 'none', got {self.kind!r}")
        for name in ("zenith", "horizon"):
            value = getattr(self, name)
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise RenderInputError(f"sky {name} must be a number, got {value!r}") from None
            if not (math.isfinite(value) and 0.0 <= value <= MAX_SKY_RADIANCE):
                raise RenderInputError(f"sky {name} radiance scale must be finite, >= 0 and at most "
                                       f"{MAX_SKY_RADIANCE:g}, got {value!r}")
            object.__setattr__(self, name, value)
        up = _vector(self.up, "sky up")
        norm = float(np.linalg.norm(up))
        if norm == 0.0:
            raise RenderInputError("sky up vector is zero; give the zenith direction such as (0, 0, 1)")
        object.__setattr__(self, "up", tuple((up / norm).tolist()))

    @property
    def is_black(self) -> bool:
        """True when the sky adds no light."""
        return self.kind == "none" or (self.zenith == 0.0 and (self.kind == "uniform" or self.horizon == 0.0))

    def radiance_scale(self, directions: ArrayLike) -> NDArray[np.float64]:
        """Scale ``s(d)`` of the sky radiance along unit directions.

        Parameters
        ----------
        directions
            ``(..., 3)`` unit directions.

        Returns
        -------
        ndarray
            ``(...)`` scales (relative to the key light's irradiance / pi).
        """
        d = np.asarray(directions)
        shape = d.shape[:-1]
        if self.kind == "none":
            return np.zeros(shape)
        if self.kind == "uniform":
            return np.full(shape, self.zenith)
        t = np.clip(d @ np.asarray(self.up, dtype=d.dtype if d.dtype.kind == "f" else np.float64), 0.0, 1.0)
        return self.horizon + (self.zenith - self.horizon) * t

    def hemisphere_mean(self, normals: ArrayLike) -> NDArray[np.float64]:
        """Cosine-weighted mean of ``s(d)`` over the hemisphere around unit ``normals`` (..., 3).

        Equal to the radiance a white Lambertian surface reflects (divided by
        the spectral part), ignoring occlusion by the scene.

        Parameters
        ----------
        normals
            ``(..., 3)`` unit normals.

        Returns
        -------
        ndarray
            ``(...)`` mean scales.
        """
        n = np.asarray(normals)
        shape = n.shape[:-1]
        if self.kind == "none":
            return np.zeros(shape)
        if self.kind == "uniform":
            return np.full(shape, self.zenith)
        c = n @ np.asarray(self.up, dtype=n.dtype if n.dtype.kind == "f" else np.float64)
        return self.horizon + (self.zenith - self.horizon) * hemisphere_mean_clamped_cosine(c)


@dataclass(frozen=True, eq=False)
class Scene:
    """Objects, lights (the first is the key light of the normalisation) and a sky.

    Parameters
    ----------
    objects
        One :class:`SceneObject` or a sequence of them (stored as a tuple).
    lights
        One :class:`Light` or a sequence of them (stored as a tuple); the
        first sets the exposure.
    sky
        The synthetic sky (default: none, black).
    environment
        An environment map (:class:`processing.lighting.environment_map.EnvironmentMap`,
        its rotation and intensity included) lighting the scene besides the
        lights and the sky, or None.  Its luminance is the render's: a white
        Lambertian surface under a uniform map of luminance Y renders with Y.
        With an environment the scene may have no lights (the white is then
        the map's basis white).

    Raises
    ------
    RenderInputError
        No objects, no lights (and no environment), or wrong types.

    Examples
    --------
    >>> from render.meshio import make_mesh
    >>> tri = make_mesh([[0, 0, 0], [2, 0, 0], [0, 1, 3]], [[0, 1, 2]])
    >>> scene = Scene([SceneObject(tri, ["silver"])], [Light("directional", (0, 0, 1))])
    >>> [b.tolist() for b in scene.bounds()], scene.sky.kind
    ([[0.0, 0.0, 0.0], [2.0, 1.0, 3.0]], 'none')
    """

    objects: Sequence[SceneObject]
    lights: Sequence[Light]
    sky: Sky = field(default_factory=Sky)
    environment: EnvironmentMap | None = None

    def __post_init__(self) -> None:
        objects = (self.objects,) if isinstance(self.objects, SceneObject) else tuple(self.objects)
        lights = (self.lights,) if isinstance(self.lights, Light) else tuple(self.lights)
        if not objects:
            raise RenderInputError("the scene has no objects to render")
        for i, o in enumerate(objects):
            if not isinstance(o, SceneObject):
                raise RenderInputError(f"scene object {i} must be a SceneObject, got {type(o).__name__}")
        if self.environment is not None and not isinstance(self.environment, EnvironmentMap):
            raise RenderInputError(f"scene environment must be a processing.lighting.environment_map.EnvironmentMap "
                                   f"(read_environment, daylight_sky), got {type(self.environment).__name__}")
        if self.environment is not None:
            from render.environment import check_environment_light

            check_environment_light(self.environment)
        if not lights and self.environment is None:
            raise RenderInputError(
                "the scene has no lights; add at least one (the first light sets the exposure: a white "
                "Lambertian surface facing it renders with luminance Y = 1)"
            )
        for i, light in enumerate(lights):
            if not isinstance(light, Light):
                raise RenderInputError(f"scene light {i} must be a Light, got {type(light).__name__}")
        if not isinstance(self.sky, Sky):
            raise RenderInputError(f"scene sky must be a Sky, got {type(self.sky).__name__}")
        object.__setattr__(self, "objects", objects)
        object.__setattr__(self, "lights", lights)

    def bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Axis-aligned bounds ``(min, max)`` of all objects.

        Returns
        -------
        tuple of ndarray
            The lowest and highest ``(3,)`` coordinates (scene units).
        """
        lows, highs = zip(*(o.mesh.bounds() for o in self.objects))
        return np.min(lows, axis=0), np.max(highs, axis=0)


def _fibonacci_directions(n: int) -> NDArray[np.float64]:
    """``n`` unit directions spread evenly over the sphere (Fibonacci lattice)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z * z)
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def check_point_lights(scene: Scene, raycaster: Any = None, n_rays: int = 64) -> None:
    """Raise if a point light is enclosed by a closed mesh.

    From each point light ``n_rays`` rays go out in directions spread over
    the sphere; when every one of them hits a surface from behind (the ray
    runs along the triangle's outward normal, ``d . n > 0``), the light is
    inside a closed object and would light only its inside.

    Parameters
    ----------
    scene
        The scene.
    raycaster
        An ``open3d.t.geometry.RaycastingScene`` holding the objects in
        order (geometry id = object index); built here when None.
    n_rays
        Number of probe rays per light.

    Raises
    ------
    RenderInputError
        Naming the light, its position and the enclosing object.

    Examples
    --------
    >>> from render.meshio import make_mesh
    >>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    >>> tetra = make_mesh(v, [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    >>> obj = SceneObject(tetra, ["gold"], name="tetra")
    >>> check_point_lights(Scene([obj], [Light("point", (2, 2, 2))]))          # outside: no error
    >>> check_point_lights(Scene([obj], [Light("point", (0.1, 0.1, 0.1))]))  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    render.errors.RenderInputError: point light 0 at [0.1, 0.1, 0.1] is inside object 'tetra' ...
    """
    points = [(i, light) for i, light in enumerate(scene.lights) if light.kind == "point"]
    if not points:
        return
    import open3d as o3d

    if raycaster is None:
        raycaster = o3d.t.geometry.RaycastingScene()
        for obj in scene.objects:
            raycaster.add_triangles(
                o3d.core.Tensor(obj.mesh.vertices.astype(np.float32)),
                o3d.core.Tensor(obj.mesh.triangles.astype(np.uint32)),
            )
    dirs = _fibonacci_directions(n_rays)
    for i, light in points:
        rays = np.empty((n_rays, 6), dtype=np.float32)
        rays[:, :3] = light.vector
        rays[:, 3:] = dirs
        ans = raycaster.cast_rays(o3d.core.Tensor(rays))
        t_hit = ans["t_hit"].numpy()
        if not np.all(np.isfinite(t_hit)):
            continue
        normals = ans["primitive_normals"].numpy()
        if np.all(np.einsum("ij,ij->i", normals, dirs) > 0.0):
            ids = ans["geometry_ids"].numpy().astype(np.int64)
            obj = scene.objects[int(np.bincount(ids).argmax())]
            raise RenderInputError(
                f"point light {i} at {list(light.vector)} is inside object {obj.name!r} (a closed mesh): "
                f"all {n_rays} rays from it hit the inside of the surface, so it would light nothing "
                "visible; move the light outside the object"
            )
