"""Render a scene: Open3D ray casting plus NumPy spectral shading, tile by tile.

Per tile of pixels: primary rays through one sample per stratum of each
pixel (:mod:`render.camera`), cast with Open3D's ``RaycastingScene`` (one
geometry per object); per hit the position, the smooth shading normal
interpolated from the vertex normals with the barycentric ``primitive_uvs``
(u, v weight vertices 1 and 2, vertex 0 gets 1 - u - v), the face normal,
both turned toward the viewer, and the material (per triangle, or per vertex:
the vertex with the largest barycentric weight); shading
(:mod:`render.shading`); adaptive anti-aliasing of the pixels whose samples
disagree (:func:`pixels_to_refine`); the mean of each pixel's samples,
normalised so that a white Lambertian surface facing the first light has
Y = 1 and converted to 8-bit sRGB.  docs/rendering.md describes the
pipeline, the exposure and the anti-aliasing ("Pipeline", "Exposure and
normalisation", "Adaptive anti-aliasing").

Pixels no object covers show the sky along the camera ray (black when the
sky is ``"none"``); ``RenderResult.mask`` holds the fraction of each pixel's
samples that hit an object, the alpha of :meth:`RenderResult.rgba8`.

Memory is bounded by the tile size: only one tile's rays and shading arrays
exist at a time (at most ``MAX_TILE_SAMPLES`` samples, float32 in the table
path), besides the image buffers, the per-triangle vertex normals (36 bytes
per triangle) and the ray tracer's acceleration structure.  Measured peak
resident memory for 1024 x 1024 pixels of a 1M-triangle mesh at the
``standard`` preset: about 0.6 GB.

Open3D builds its acceleration structure (BVH) on the first query; the
renderer triggers it with a one-ray cast and reports it as
``timings["bvh_build"]``, apart from the per-ray casting.

References
----------
Mitchell, D. P. (1987), "Generating antialiased images at low sampling
densities", SIGGRAPH '87, Computer Graphics 21(4), 65-72,
doi:10.1145/37402.37410.
"""

from __future__ import annotations

import functools
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from processing.spectral.spectra import SpectralGrid
from render.backends import SpectralBackend, TableBackend
from render.calibrated_camera import CalibratedCamera
from render.camera import Camera
from render.environment import EnvironmentPlan
from render.errors import RenderCancelled, RenderInputError
from render.integrator import ShadingContext, light_samples, shade
from render.presets import PRESETS, RenderSettings
from render.scene import Scene, Sky, check_point_lights, resolve_spectrum
from render.shading import Hits, LightPlan, MaterialPlan, dot3, orthonormal_basis, plan_material

__all__ = [
    "RenderResult",
    "render",
    "pixels_to_refine",
    "BaselineTiming",
    "cast_rays_baseline",
    "GeometryCache",
    "RenderCancelled",
    "MAX_TILE_SAMPLES",
    "BYTES_PER_PIXEL",
    "BYTES_PER_TRIANGLE",
    "estimate_peak_bytes",
    "available_memory_bytes",
    "check_memory",
]

_F32 = np.float32


@dataclass(eq=False)
class RenderResult:
    """The rendered image and how it was made.

    Attributes
    ----------
    xyz
        float32 ``(H, W, 3)`` CIE XYZ, a white Lambertian facing the first
        light has Y = 1.
    srgb8
        uint8 ``(H, W, 3)`` sRGB (adapted from ``white`` to D65).
    mask
        float32 ``(H, W)`` fraction of each pixel covered by objects.
    white
        XYZ of the scene white (the first light), for colour differences.
    timings
        Seconds per stage: ``setup``, ``bvh_build`` (Open3D's acceleration
        structure, built by a one-ray cast before the first tile),
        ``primary_rays``, ``shadow_rays``, ``mirror_rays`` (casting only),
        ``shading`` (everything else in the tile loop: ray generation,
        shading, anti-aliasing decisions), ``display``, ``total``.
    stats
        Counts: rays of each kind, hits, triangles, tiles, refined pixels
        (``refined_pixels``, ``refined_fraction``); ``geometry_reused``
        True when a :class:`GeometryCache` supplied the ray tracer.
    settings
        The settings used.
    sky_visible
        False when the sky is ``"none"`` (background transparent).
    refined
        bool ``(H, W)``: the pixels adaptive anti-aliasing rendered again
        with ``settings.adaptive_samples`` samples (all False when it is
        off); :func:`cast_rays_baseline` takes it to cast the same rays.
    """

    xyz: NDArray[np.float32]
    srgb8: NDArray[np.uint8]
    mask: NDArray[np.float32]
    white: NDArray[np.float64]
    timings: dict[str, float] = field(default_factory=dict)
    stats: dict[str, float] = field(default_factory=dict)
    settings: RenderSettings | None = None
    sky_visible: bool = False
    refined: NDArray[np.bool_] | None = None

    def rgba8(self) -> NDArray[np.uint8]:
        """``(H, W, 4)`` sRGB with alpha: coverage when the sky is off, opaque otherwise.

        Returns
        -------
        ndarray
            uint8 ``(H, W, 4)``.
        """
        alpha = np.round(self.mask * 255.0).astype(np.uint8) if not self.sky_visible else np.full(
            self.mask.shape, 255, np.uint8
        )
        return np.concatenate([self.srgb8, alpha[..., None]], axis=-1)


# --------------------------------------------------------------------------- preparation
def _vertex_tangents(obj) -> NDArray[np.float64]:
    """Per-vertex yarn directions of an object: its own, else the global default, turned by its weave angle."""
    from render.tangents import rotate_tangents, tangents_from_direction, tangents_from_field

    normals = obj.mesh.vertex_normals
    if obj.tangents is not None:
        t = tangents_from_field(normals, obj.tangents)
    else:
        t = tangents_from_direction(normals)
    if obj.weave_angle_deg:
        t = rotate_tangents(t, normals, obj.weave_angle_deg)
    return t


@dataclass(eq=False)
class _Prepared:
    """What every tile of a render shares: ray tracer, colour normalisation, triangle arrays, shading context."""

    raycaster: object
    grid: SpectralGrid
    k: float
    white: NDArray[np.float64]
    tri_offset: NDArray[np.int64]
    tri_normals: NDArray[np.float32]            # (9, T): vertex normals of each triangle's corners
    corner_material: NDArray[np.int32] | None   # (T, 3) global material per corner, None: all 0
    ctx: ShadingContext
    backend: SpectralBackend | TableBackend | None
    timings: dict[str, float]
    n_triangles: int
    n_materials: int
    geometry_reused: bool = False


@dataclass(eq=False)
class _Triangles:
    """Per-triangle arrays of all objects, concatenated in object order (global triangle numbers)."""

    tri_offset: NDArray[np.int64]                   # first global triangle of each object
    n_triangles: int
    normals: NDArray[np.float32]                    # (9, T): vertex normals of each triangle's corners
    tangents: NDArray[np.float32] | None            # (9, T) corner yarn directions, None: all isotropic
    corner_material: NDArray[np.int32] | None       # (T, 3) global material per corner, None: all 0
    triangle_material: NDArray[np.int32] | None     # (T,) when no object is indexed per vertex
    single_object: bool
    corner_normals: list[NDArray[np.float32]]       # per object (9, T_i), what a GeometryCache keeps


@dataclass(eq=False)
class _Lighting:
    """The lights scaled to the key light's exposure, the XYZ normalisation, the sky radiance and the environment."""

    lights: tuple[LightPlan, ...]
    k: float
    white: NDArray[np.float64]
    sky_radiance: NDArray[np.float64]
    environment: EnvironmentPlan | None = None


def _check_args(scene: Scene, camera: Camera, settings: RenderSettings | None) -> RenderSettings:
    """The settings to use (None: the ``standard`` preset), after checking the argument types."""
    if not isinstance(scene, Scene):
        raise RenderInputError(f"scene must be a render.scene.Scene, got {type(scene).__name__}")
    if not isinstance(camera, (Camera, CalibratedCamera)):
        raise RenderInputError(f"camera must be a render.camera.Camera or a render.calibrated_camera.CalibratedCamera, "
                               f"got {type(camera).__name__}")
    if settings is None:
        return PRESETS["standard"]
    if not isinstance(settings, RenderSettings):
        raise RenderInputError(
            f"settings must be a RenderSettings (e.g. render.presets.PRESETS['standard']), got {type(settings).__name__}"
        )
    return settings


class GeometryCache:
    """The ray tracer of the last geometry rendered, kept for the next render of the same meshes.

    Building Open3D's acceleration structure is most of an interactive
    render's time (about 0.8 s of a 1M-triangle draft at 640 x 480): a
    window that re-renders one object under another light, material or view
    passes the same cache to every :func:`render` and pays it once.  The key
    is the identity of the scene's :class:`render.meshio.Mesh` objects in
    order -- a ``Mesh`` is immutable (frozen; it caches its bounds the same
    way), and the cache holds the meshes so their identities cannot be
    reused -- so a new or reloaded mesh always gets a new tracer; materials,
    lights and the camera may change freely.  Besides the tracer it keeps the
    triangles' corner normals (36 bytes per triangle).  One geometry is held
    at a time (a 1M-triangle tracer takes a few hundred MB); :meth:`clear`
    frees it.  Safe to share between threads.

    Examples
    --------
    >>> from render.meshio import make_mesh
    >>> from render.scene import Light, SceneObject, Sky
    >>> square = make_mesh([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], [[0, 1, 2], [0, 2, 3]])
    >>> scene = Scene([SceneObject(square, ["gold"])], [Light("directional", (0, 0, 1))], Sky("none"))
    >>> camera, cache = Camera((0, 0, 4), (0, 0, 0), (0, 1, 0), 20, 4, 4), GeometryCache()
    >>> [render(scene, camera, PRESETS["draft"], geometry_cache=cache).stats["geometry_reused"] for _ in range(2)]
    [False, True]
    """

    def __init__(self) -> None:
        import threading

        self._lock = threading.Lock()
        self._meshes: tuple = ()
        self._entry: tuple[object, list[NDArray[np.float32]]] | None = None

    def lookup(self, scene: Scene) -> tuple[object, list[NDArray[np.float32]]] | None:
        """The tracer and corner normals kept for ``scene``'s meshes, or None.

        Parameters
        ----------
        scene
            The scene about to be rendered.

        Returns
        -------
        tuple or None
            ``(raycaster, normals)`` (normals: one ``(9, T)`` float32 array per object).
        """
        meshes = tuple(obj.mesh for obj in scene.objects)
        with self._lock:
            same = len(meshes) == len(self._meshes) and all(a is b for a, b in zip(meshes, self._meshes))
            return self._entry if same else None

    def store(self, scene: Scene, raycaster: object, normals: list[NDArray[np.float32]]) -> None:
        """Keep ``raycaster`` (acceleration structure built) and ``normals`` for ``scene``'s meshes.

        Parameters
        ----------
        scene
            The scene rendered.
        raycaster
            Its ``open3d.t.geometry.RaycastingScene``.
        normals
            Its objects' corner normals.
        """
        with self._lock:
            self._meshes = tuple(obj.mesh for obj in scene.objects)
            self._entry = (raycaster, normals)

    def clear(self) -> None:
        """Free the kept tracer, normals and meshes."""
        with self._lock:
            self._meshes, self._entry = (), None


def _prepare(scene: Scene, camera: Camera, settings: RenderSettings, *, backends: bool = True,
             cache: GeometryCache | None = None) -> _Prepared:
    """Build (or take from ``cache``) the ray tracer; the triangle arrays, the lights and the shading context."""
    import open3d as o3d

    timings: dict[str, float] = {"primary_rays": 0.0, "shadow_rays": 0.0, "mirror_rays": 0.0}
    t0 = time.perf_counter()
    cached = cache.lookup(scene) if cache is not None else None
    raycaster = cached[0] if cached is not None else o3d.t.geometry.RaycastingScene()
    materials, per_object_map = _number_materials(scene)
    triangles = _add_objects(raycaster, scene, materials, per_object_map, None if cached is None else cached[1])
    lo, hi = scene.bounds()
    offset = _ray_offset(lo, hi, camera)
    grid = SpectralGrid(400.0, 700.0, settings.spectral_step)
    lighting = _lighting(scene, grid, lo, hi)
    plans = tuple(plan_material(m) for m in materials)
    backend = _backend(settings, grid, lighting, scene.sky, plans) if backends else None
    environment = lighting.environment
    tracer = _Tracer(raycaster, timings)
    ctx = ShadingContext(
        lights=lighting.lights,
        sky=scene.sky,
        plans=plans,
        offset=offset,
        shadows=settings.shadows,
        mirror_bounces=settings.mirror_bounces,
        mirror_rays=settings.mirror_rays,
        cast=tracer.cast,
        occluded=tracer.occluded,
        make_hits=functools.partial(_make_hits, triangles),
        environment=environment,
        environment_samples=settings.environment_samples,
    )
    timings["setup"] = time.perf_counter() - t0
    timings["bvh_build"] = 0.0 if cached is not None else _build_acceleration(raycaster, camera)
    if cache is not None and cached is None:
        cache.store(scene, raycaster, triangles.corner_normals)
    check_point_lights(scene, raycaster)
    return _Prepared(
        raycaster, grid, lighting.k, lighting.white, triangles.tri_offset, triangles.normals,
        triangles.corner_material, ctx, backend, timings, triangles.n_triangles, len(materials),
        cached is not None,
    )


def _number_materials(scene: Scene) -> tuple[list, list[NDArray[np.int32]]]:
    """Global material numbers (a Material shared by objects gets one) and each object's local -> global map."""
    materials: list = []
    number: dict[int, int] = {}
    per_object_map: list[NDArray[np.int32]] = []
    for obj in scene.objects:
        ids = []
        for m in obj.materials:
            if id(m) not in number:
                number[id(m)] = len(materials)
                materials.append(m)
            ids.append(number[id(m)])
        per_object_map.append(np.asarray(ids, dtype=np.int32))
    return materials, per_object_map


def _add_objects(raycaster, scene: Scene, materials: list, per_object_map: list[NDArray[np.int32]],
                 normals: list[NDArray[np.float32]] | None = None) -> _Triangles:
    """Add every object's triangles to the ray tracer (geometry id = object index) and gather their arrays.

    With ``normals`` (the corner normals of a :class:`GeometryCache`) the tracer already holds the objects.
    """
    import open3d as o3d

    several = len(materials) > 1
    anisotropic = any(m.anisotropic for m in materials)
    offsets = [0]
    reuse = normals is not None
    normals = list(normals) if reuse else []
    tangents = []
    corners = []
    for i, obj in enumerate(scene.objects):
        mesh = obj.mesh
        if not reuse:
            gid = raycaster.add_triangles(
                o3d.core.Tensor(np.ascontiguousarray(mesh.vertices, dtype=np.float32)),
                o3d.core.Tensor(np.ascontiguousarray(mesh.triangles, dtype=np.uint32)),
            )
            if gid != i:
                raise RuntimeError(f"Open3D returned geometry id {gid} for object {i}")
            normals.append(np.ascontiguousarray(mesh.vertex_normals.astype(np.float32)[mesh.triangles].reshape(-1, 9).T))
        offsets.append(offsets[-1] + mesh.n_triangles)
        if anisotropic:
            tangents.append(_vertex_tangents(obj).astype(np.float32)[mesh.triangles].reshape(-1, 9).T)
        if several:
            corners.append(_corner_materials(obj, per_object_map[i]))
    tri_normals = normals[0] if len(normals) == 1 else np.concatenate(normals, axis=1)
    tri_tangents = None
    if anisotropic:
        tri_tangents = np.ascontiguousarray(tangents[0] if len(tangents) == 1 else np.concatenate(tangents, axis=1))
    corner_material = np.concatenate(corners).astype(np.int32) if several else None
    per_vertex = any(obj.material_index_on == "vertex" for obj in scene.objects)
    triangle_material = None
    if corner_material is not None and not per_vertex:
        triangle_material = np.ascontiguousarray(corner_material[:, 0])   # the three corners agree
    return _Triangles(np.asarray(offsets[:-1], dtype=np.int64), int(offsets[-1]), tri_normals, tri_tangents,
                      corner_material, triangle_material, len(scene.objects) == 1, normals)


def _corner_materials(obj, table: NDArray[np.int32]) -> NDArray[np.int32]:
    """Global material number of each corner of an object's triangles ``(T, 3)``."""
    mesh = obj.mesh
    if obj.material_index is None:
        return np.full((mesh.n_triangles, 3), table[0], dtype=np.int32)
    if obj.material_index_on == "triangle":
        return np.repeat(table[obj.material_index][:, None], 3, axis=1)
    return table[obj.material_index][mesh.triangles]


def _ray_offset(lo: NDArray[np.float64], hi: NDArray[np.float64], camera: Camera) -> float:
    """How far secondary rays start off the surface (scene units)."""
    diag = float(np.linalg.norm(hi - lo))
    # Secondary rays start this far off the surface: 1e-4 of the scene's size, plus ~16 float32
    # ulps of the largest coordinate or camera distance involved in computing hit points.
    magnitude = max(float(np.max(np.abs(np.concatenate([lo, hi])))),
                    float(np.linalg.norm(np.asarray(camera.eye) - 0.5 * (lo + hi))))
    return 1e-4 * diag + 2e-6 * magnitude


def _key_irradiance(scene: Scene, lo: NDArray[np.float64], hi: NDArray[np.float64]) -> float:
    """Irradiance scale of the first light at the centre of the scene's bounds (it sets the exposure)."""
    key = scene.lights[0]
    if key.kind == "directional":
        key_irradiance = key.intensity
    else:
        diag = float(np.linalg.norm(hi - lo))
        centre = 0.5 * (lo + hi)
        d2 = float(np.sum((np.asarray(key.vector) - centre) ** 2))
        if d2 <= (1e-9 * max(diag, 1e-300)) ** 2:
            raise RenderInputError(
                "light 0 (a point light) sits at the centre of the scene; the exposure is set at the distance "
                "from the first light to the scene centre, so move it away"
            )
        key_irradiance = key.intensity / d2
    if not key_irradiance > 0:
        raise RenderInputError(
            "light 0 has intensity 0; the first light sets the exposure and must have intensity > 0"
        )
    return key_irradiance


def _lighting(scene: Scene, grid: SpectralGrid, lo: NDArray[np.float64], hi: NDArray[np.float64]) -> _Lighting:
    """Light spectra relative to the key light's irradiance, the XYZ normalisation k, the white and the sky."""
    from processing.spectral.display import white_xyz, xyz_scale

    spectra = [resolve_spectrum(light.spectrum, grid, f"light {i} spectrum") for i, light in enumerate(scene.lights)]
    env = scene.environment
    if spectra:
        key_irradiance = _key_irradiance(scene, lo, hi)
        k = xyz_scale(spectra[0], grid)
        white = white_xyz(spectra[0], grid)
        key_spectrum = spectra[0]
    else:
        # no lights: the environment alone; the white (and the unit of a synthetic sky) is the map's white: the
        # spectrum it names (a probe's chart white), else its basis rows together (D65 for an sRGB map)
        key_irradiance = 1.0
        key_spectrum = (EnvironmentPlan.basis_on_grid(env, grid).sum(axis=0) if env.white is None
                        else EnvironmentPlan.spectrum_on_grid(env.white, env.grid, grid))
        k = xyz_scale(key_spectrum, grid)
        white = white_xyz(key_spectrum, grid)
    lights = tuple(
        LightPlan(light.kind, np.asarray(light.vector, dtype=np.float64), e * (light.intensity / key_irradiance))
        for light, e in zip(scene.lights, spectra)
    )
    sky = scene.sky
    sky_spec = resolve_spectrum(sky.spectrum, grid, "sky spectrum") if sky.spectrum is not None else key_spectrum
    plan = None if env is None else EnvironmentPlan.cached(env, grid, k)
    return _Lighting(lights, k, white, sky_spec / math.pi, plan)


def _backend(settings: RenderSettings, grid: SpectralGrid, lighting: _Lighting, sky: Sky,
             plans: tuple[MaterialPlan, ...]) -> SpectralBackend | TableBackend:
    """The colour backend of the settings: angular tables, or per-sample spectra."""
    spectral = SpectralBackend(grid, lighting.k, lighting.lights, sky, lighting.sky_radiance, plans,
                               environment=lighting.environment)
    if settings.use_tables:
        return TableBackend(grid, lighting.k, lighting.lights, sky, lighting.sky_radiance, plans,
                            settings.table_size, spectral)
    return spectral


class _Tracer:
    """Open3D casts for shading, timed into ``timings`` (mirror rays and shadow rays)."""

    def __init__(self, raycaster, timings: dict[str, float]) -> None:
        self.raycaster = raycaster
        self.timings = timings

    def cast(self, rays: NDArray[np.float32]) -> dict[str, NDArray]:
        """``cast_rays`` of mirrored rays, as NumPy arrays."""
        import open3d as o3d

        t = time.perf_counter()
        ans = self.raycaster.cast_rays(o3d.core.Tensor.from_numpy(rays))
        out = {name: value.numpy() for name, value in ans.items()}
        self.timings["mirror_rays"] += time.perf_counter() - t
        return out

    def occluded(self, rays: NDArray[np.float32], tfar: float) -> NDArray[np.bool_]:
        """``test_occlusions`` of shadow rays up to ``tfar``."""
        import open3d as o3d

        t = time.perf_counter()
        ans = self.raycaster.test_occlusions(o3d.core.Tensor.from_numpy(rays), tnear=0.0, tfar=tfar).numpy()
        self.timings["shadow_rays"] += time.perf_counter() - t
        return ans


def _make_hits(tri: _Triangles, rays: NDArray[np.float32], answer: dict[str, NDArray],
               rows: NDArray[np.intp]) -> Hits:
    """The :class:`Hits` of the rows ``rows`` of a cast answer: position, normals toward the viewer, material."""
    ray = np.ascontiguousarray(np.take(rays, rows, axis=0).T)          # (6, m)
    d = ray[3:]
    position = ray[:3]
    position += d * np.take(answer["t_hit"], rows)
    prim = np.take(answer["primitive_ids"], rows).astype(np.int64)
    if not tri.single_object:
        prim += tri.tri_offset[np.take(answer["geometry_ids"], rows).astype(np.int64)]
    uv = np.ascontiguousarray(np.take(answer["primitive_uvs"], rows, axis=0).T)
    u, v = uv[0], uv[1]
    w0 = _F32(1.0) - u - v
    corner = np.take(tri.normals, prim, axis=1)                           # (9, m)
    ns = corner[0:3] * w0
    ns += corner[3:6] * u
    ns += corner[6:9] * v
    ng = np.ascontiguousarray(np.take(answer["primitive_normals"], rows, axis=0).T)
    # turn the face normal toward the viewer, then the shading normal to the face normal's side
    ng *= np.where(dot3(ng, d) > 0, _F32(-1.0), _F32(1.0))
    sign = np.where(dot3(ns, ng) < 0, _F32(-1.0), _F32(1.0))
    ns *= sign / np.sqrt(np.maximum(dot3(ns, ns), _F32(1e-30)))
    view = np.negative(d)
    cos_o = _bend_silhouettes(ns, view)
    tangent = None if tri.tangents is None else _hit_tangents(tri.tangents, prim, w0, u, v, ns)
    return Hits(position, ns, ng, view, cos_o, _hit_materials(tri, prim, w0, u, v), tangent)


def _bend_silhouettes(ns: NDArray[np.float32], view: NDArray[np.float32]) -> NDArray[np.float32]:
    """``cos_o`` of the shading normals ``ns`` (bent in place to face the viewer at silhouettes of coarse meshes)."""
    cos_o = dot3(ns, view)
    low = np.flatnonzero(cos_o < _F32(1e-3))
    if low.size:
        # silhouettes of coarse meshes: bend the shading normal until it faces the viewer
        vl = view[:, low]
        bent = ns[:, low] + (_F32(1e-3) - cos_o[low]) * vl
        bent *= _F32(1.0) / np.sqrt(dot3(bent, bent))
        ns[:, low] = bent
        cos_o[low] = np.maximum(dot3(bent, vl), _F32(1e-4))
    return cos_o


def _hit_tangents(tri_tangents: NDArray[np.float32], prim: NDArray[np.int64], w0: NDArray[np.float32],
                  u: NDArray[np.float32], v: NDArray[np.float32], ns: NDArray[np.float32]) -> NDArray[np.float32]:
    """Unit yarn directions ``(3, m)`` of the hits, orthogonal to the (final) shading normals ``ns``."""
    # interpolated like the normals, then made orthogonal to the (final) shading normal
    tc = np.take(tri_tangents, prim, axis=1)
    tangent = tc[0:3] * w0
    tangent += tc[3:6] * u
    tangent += tc[6:9] * v
    tangent -= ns * dot3(ns, tangent)
    length = np.sqrt(dot3(tangent, tangent))
    tangent *= _F32(1.0) / np.maximum(length, _F32(1e-30))
    weak = np.flatnonzero(length < _F32(1e-4))
    if weak.size:
        tangent[:, weak] = orthonormal_basis(np.ascontiguousarray(ns[:, weak]))[0]
    return tangent


def _hit_materials(tri: _Triangles, prim: NDArray[np.int64], w0: NDArray[np.float32], u: NDArray[np.float32],
                   v: NDArray[np.float32]) -> NDArray[np.int32]:
    """Global material number of each hit: its triangle's, or that of the corner with the largest weight."""
    if tri.corner_material is None:
        return np.zeros(prim.size, dtype=np.int32)
    if tri.triangle_material is not None:
        return np.take(tri.triangle_material, prim)
    nearest = np.argmax(np.stack([w0, u, v]), axis=0)
    return tri.corner_material[prim, nearest]


def _build_acceleration(raycaster, camera: Camera) -> float:
    """Seconds Open3D takes to build its acceleration structure, triggered by a one-ray cast."""
    import open3d as o3d

    # Open3D builds its acceleration structure lazily on the first query: trigger it with one ray
    # so that its cost is reported apart from the per-ray casting.
    t = time.perf_counter()
    probe = np.zeros((1, 6), dtype=np.float32)
    probe[0, :3] = np.asarray(camera.eye, dtype=np.float32)
    probe[0, 3:] = camera.basis()[2].astype(np.float32)
    raycaster.cast_rays(o3d.core.Tensor.from_numpy(probe))
    return time.perf_counter() - t


#: Most samples in one tile: 65536 with tables (float32 XYZ), 16384 with
#: per-sample spectra (float64, L bands each), which bounds the working memory.
MAX_TILE_SAMPLES = {True: 1 << 16, False: 1 << 14}


def _tiles(camera: Camera, settings: RenderSettings) -> list[tuple[int, int, int, int]]:
    """Pixel blocks ``(x0, x1, y0, y1)``, row by row; side ``tile_size``, less if it exceeds ``MAX_TILE_SAMPLES``."""
    budget = MAX_TILE_SAMPLES[settings.use_tables] // settings.samples_per_pixel
    size = max(1, min(settings.tile_size, math.isqrt(max(budget, 1))))
    return [
        (x0, min(x0 + size, camera.width), y0, min(y0 + size, camera.height))
        for y0 in range(0, camera.height, size)
        for x0 in range(0, camera.width, size)
    ]


def _cast_primary(prep: _Prepared, rays: NDArray[np.float32]) -> dict[str, NDArray]:
    import open3d as o3d

    t = time.perf_counter()
    ans = prep.raycaster.cast_rays(o3d.core.Tensor.from_numpy(rays))
    out = {name: value.numpy() for name, value in ans.items()}
    prep.timings["primary_rays"] += time.perf_counter() - t
    return out


def _pixel_mean(samples: NDArray[np.float32], spp: int) -> NDArray[np.float32]:
    """Mean ``(n / spp, 3)`` of consecutive groups of ``spp`` rows of ``(n, 3)`` samples (one pixel each)."""
    grouped = samples.T.reshape(3, -1, spp)
    total = grouped[:, :, 0].astype(_F32, copy=True)
    for s in range(1, spp):
        total += grouped[:, :, s]
    total *= _F32(1.0 / spp)
    return total.T


def _pixel_fraction(flags: NDArray[np.bool_], spp: int) -> NDArray[np.float32]:
    """Fraction of True among consecutive groups of ``spp`` flags (one pixel each)."""
    grouped = flags.reshape(-1, spp).view(np.uint8)
    total = grouped[:, 0].astype(_F32)
    for s in range(1, spp):
        total += grouped[:, s]
    total *= _F32(1.0 / spp)
    return total


_LAB_EPSILON = (6.0 / 29.0) ** 3


def _lab_f(t: NDArray[np.float32]) -> NDArray[np.float32]:
    """The CIELAB function ``f(t)``: ``t^(1/3)`` above ``(6/29)^3``, linear below (CIE 015:2018, eq. 8.7)."""
    return np.where(t > _F32(_LAB_EPSILON), np.cbrt(t),
                    t * _F32(1.0 / (3.0 * (6.0 / 29.0) ** 2)) + _F32(4.0 / 29.0))


def pixels_to_refine(
    sample_xyz: NDArray[np.float32],
    key: NDArray[np.integer],
    samples: int,
    white: NDArray[np.floating],
    threshold: float,
) -> NDArray[np.bool_]:
    """Which pixels' base samples disagree (adaptive anti-aliasing, Mitchell 1987).

    Sample sparsely, then sample more where the samples of a pixel differ
    (Mitchell 1987).  A pixel is refined when its samples see different
    surfaces (``key``: object and material number, -1 for a miss, so hit vs
    miss counts) or their colours spread by more than ``threshold`` CIELAB
    lightness units: ``116 (max - min)`` of ``f(X/Xw)``, ``f(Y/Yw)`` or
    ``f(Z/Zw)`` over the pixel's samples.  Pixels whose samples all miss
    (sky only, smooth) are never refined.

    Parameters
    ----------
    sample_xyz
        float32 ``(n, 3)`` XYZ of the samples, ``samples`` consecutive rows
        per pixel.
    key
        ``(n,)`` surface number of each sample, -1 for a miss.
    samples
        Samples per pixel (>= 2).
    white
        XYZ of the scene white (Y = 1).
    threshold
        Lightness units; ``inf`` refines on surface changes only.

    Returns
    -------
    ndarray
        bool ``(n / samples,)``.

    References
    ----------
    Mitchell, D. P. (1987), "Generating antialiased images at low sampling
    densities", SIGGRAPH '87, 65-72, doi:10.1145/37402.37410.
    CIE 015:2018 Colorimetry, eq. 8.7 (the CIELAB function f),
    doi:10.25039/TR.015.2018.

    Examples
    --------
    Two pixels of two samples: a uniform one and one with a step of
    about 4 L* units (Y 0.50 vs 0.45):

    >>> xyz = np.array([[.5, .5, .5], [.5, .5, .5], [.5, .5, .5], [.45, .45, .45]], np.float32)
    >>> pixels_to_refine(xyz, np.zeros(4, int), 2, np.ones(3), 2.0).tolist()
    [False, True]
    >>> pixels_to_refine(xyz, np.array([0, 0, 0, 0]), 2, np.ones(3), 5.0).tolist()
    [False, False]
    >>> pixels_to_refine(xyz, np.array([0, 1, -1, -1]), 2, np.ones(3), 5.0).tolist()
    [True, False]
    """
    keys = np.asarray(key).reshape(-1, samples)
    first = keys[:, 0]
    refine = keys[:, 1] != first
    for s in range(2, samples):                 # column by column: cheaper than a reduction over 2-16 samples
        refine |= keys[:, s] != first
    candidates = np.flatnonzero(~refine & (first >= 0))
    if candidates.size and math.isfinite(threshold):
        grouped = np.asarray(sample_xyz, dtype=_F32).T.reshape(3, -1, samples)
        sub = np.take(grouped, candidates, axis=1)                         # (3, c, samples)
        sub *= (1.0 / np.asarray(white, dtype=np.float64)).astype(_F32)[:, None, None]
        f = _lab_f(sub)
        high = f[:, :, 0].copy()
        low = f[:, :, 0].copy()
        for s in range(1, samples):
            np.maximum(high, f[:, :, s], out=high)
            np.minimum(low, f[:, :, s], out=low)
        high -= low
        spread = np.maximum(np.maximum(high[0], high[1]), high[2])
        refine[candidates[spread > _F32(threshold / 116.0)]] = True
    return refine


def _refine_chunks(count: int, samples: int, use_tables: bool) -> list[slice]:
    """Slices of the refined pixels of a tile processed at once (at most ``MAX_TILE_SAMPLES`` samples)."""
    step = max(1, MAX_TILE_SAMPLES[use_tables] // samples)
    return [slice(i, min(i + step, count)) for i in range(0, count, step)]


def _shade_samples(
    prep: _Prepared, rays: NDArray[np.float32], rng: np.random.Generator, settings: RenderSettings
) -> tuple[NDArray[np.float32], NDArray[np.bool_], NDArray[np.int64], NDArray[np.float32]]:
    """Cast and shade primary ``rays``: sample XYZ, hit flags, surface keys, XYZ without sampled environment light.

    The XYZ are ``(n, 3)``, keys -1 for a miss; the last is what adaptive anti-aliasing compares.
    """
    ctx, backend = prep.ctx, prep.backend
    answer = _cast_primary(prep, rays)
    hit = np.isfinite(answer["t_hit"])
    rows = np.flatnonzero(hit)
    colour = backend.zeros(rays.shape[0])
    key = np.full(rays.shape[0], -1, dtype=np.int32) if settings.adaptive_samples else np.empty(0, np.int32)
    if not ctx.sky.is_black:
        miss = np.flatnonzero(~hit)
        if miss.size:
            scale = ctx.sky.radiance_scale(np.take(rays, miss, axis=0)[:, 3:])
            backend.add(colour, miss, backend.background(scale))
    if ctx.environment is not None:
        miss = np.flatnonzero(~hit)
        if miss.size:
            dirs = np.ascontiguousarray(np.take(rays, miss, axis=0)[:, 3:].T)
            dirs *= _F32(1.0) / np.sqrt(dot3(dirs, dirs))
            backend.add(colour, miss, backend.env_background(ctx.environment.lookup(dirs)))
    if rows.size:
        hits = ctx.make_hits(rays, answer, rows)
        if settings.adaptive_samples:
            surface = hits.material.astype(np.int32)
            if len(prep.tri_offset) > 1:
                surface += prep.n_materials * np.take(answer["geometry_ids"], rows).astype(np.int32)
            key[rows] = surface
        ctx.environment_term = None
        backend.add(colour, rows, shade(ctx, hits, backend, settings.mirror_bounces, rng))
        if settings.adaptive_samples and ctx.environment_term is not None:
            # the sampled environment light's noise would refine nearly every pixel: decide without it
            steady = colour.copy()
            backend.add(steady, rows, -ctx.environment_term)
            ctx.environment_term = None
            return backend.to_xyz(colour), hit, key, backend.to_xyz(steady)
    xyz = backend.to_xyz(colour)
    return xyz, hit, key, xyz


def _tile_rngs(settings: RenderSettings, number: int) -> tuple[np.random.Generator, ...]:
    """Independent generators of tile ``number``: base sample jitter, refinement jitter, shading."""
    return tuple(np.random.default_rng([settings.seed, number, stream]) for stream in range(3))


# --------------------------------------------------------------------------- memory bound
#: Peak memory per image pixel of a render and its PNG, above the process's resident size.  Measured
#: with ``ru_maxrss`` of ``kogei render`` (a 20k-triangle sphere, gradient sky): draft 1000 x 1000 ->
#: 2000 x 2000 grew 369 -> 748 MiB (132 B/pixel), standard 1000 x 1000 -> 2000 x 1000 grew
#: 363 -> 495 MiB (138 B/pixel); with ``--xyz`` the same.  The full-size buffers (XYZ, coverage,
#: refined flags: 17 B) are small beside the float64 intermediates of the colour conversion of the
#: whole image in ``_display``; the tiles themselves are bounded by ``MAX_TILE_SAMPLES``.
BYTES_PER_PIXEL = 140

#: Peak memory per scene triangle (ray tracer's BVH, per-triangle normals, tangents and materials):
#: a 2M-triangle sphere at 64 x 64 pixels peaked 416 MiB above the 20k-triangle one (about 218 B,
#: some of it the mesh arrays built before rendering).
BYTES_PER_TRIANGLE = 200

#: Working memory of one tile and the shading tables, whatever the image size (MiB-scale, rounded up).
_TILE_BYTES = 64 << 20


#: Share of the free memory a suggested smaller size may use.
_SUGGEST_SHARE = 0.8


def estimate_peak_bytes(width: int, height: int, n_triangles: int = 0) -> int:
    """Estimated peak memory of :func:`render` (and writing its PNG) above what the process already holds.

    Parameters
    ----------
    width, height
        Image size in pixels.
    n_triangles
        Triangles of all the scene's objects.

    Returns
    -------
    int
        Bytes: ``BYTES_PER_PIXEL`` per pixel, ``BYTES_PER_TRIANGLE`` per
        triangle and one tile's working memory.

    Examples
    --------
    >>> estimate_peak_bytes(8000, 8000) / 1e9 > 8.9
    True
    """
    return int(width) * int(height) * BYTES_PER_PIXEL + int(n_triangles) * BYTES_PER_TRIANGLE + _TILE_BYTES


def available_memory_bytes() -> int | None:
    """Memory available to new allocations of this process.

    The least of the system's available memory, the room left under a
    cgroup memory limit (containers, batch schedulers) and the room left
    under the address-space limit (``ulimit -v``).

    Returns
    -------
    int or None
        Bytes; None when none of them can be read.
    """
    found = [x for x in (_system_available(), _cgroup_room(), _address_space_room()) if x is not None]
    return max(0, min(found)) if found else None


def _system_available() -> int | None:
    """``MemAvailable`` of /proc/meminfo, else the free pages (``SC_AVPHYS_PAGES``)."""
    value = _proc_field("/proc/meminfo", "MemAvailable:")
    if value is not None:
        return value
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):
        return None


def _proc_field(path: str, key: str) -> int | None:
    """A ``key: N kB`` field of a /proc file in bytes (None: absent or unreadable)."""
    try:
        with open(path, encoding="ascii", errors="replace") as fh:
            for line in fh:
                if line.startswith(key):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _read_int(path: str) -> int | None:
    """The integer a cgroup file holds (None: absent, ``max`` or unreadable)."""
    try:
        with open(path, encoding="ascii") as fh:
            return int(fh.read().strip())
    except (OSError, ValueError):
        return None


def _cgroup_room() -> int | None:
    """Limit minus usage of this process's cgroup (v2, else v1); None without a limit."""
    for limit_file, usage_file in (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
                                   ("/sys/fs/cgroup/memory/memory.limit_in_bytes",
                                    "/sys/fs/cgroup/memory/memory.usage_in_bytes")):
        limit = _read_int(limit_file)
        if limit is not None and limit < 1 << 60:        # v1 writes a huge number for "no limit"
            return limit - (_read_int(usage_file) or 0)
    return None


def _address_space_room() -> int | None:
    """``RLIMIT_AS`` minus the process's virtual size (None: unlimited)."""
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    except (ImportError, OSError, ValueError):
        return None
    if soft == resource.RLIM_INFINITY:
        return None
    return soft - (_proc_field("/proc/self/status", "VmSize:") or 0)


def check_memory(width: int, height: int, n_triangles: int = 0, available: int | None = None) -> None:
    """Refuse a render whose estimated peak memory exceeds the available memory.

    Parameters
    ----------
    width, height
        Image size in pixels.
    n_triangles
        Triangles of all the scene's objects.
    available
        Bytes available; None: :func:`available_memory_bytes` (when that
        cannot be known the render is allowed).

    Raises
    ------
    RenderInputError
        One line with the estimate, the memory available and the largest
        size of the same aspect ratio that fits.
    """
    if available is None:
        available = available_memory_bytes()
    need = estimate_peak_bytes(width, height, n_triangles)
    if available is None or need <= available:
        return
    room = available - estimate_peak_bytes(0, 0, n_triangles)
    if room <= 0:
        raise RenderInputError(
            f"rendering {n_triangles} triangles needs about {need / 1e9:.1f} GB but only "
            f"{available / 1e9:.1f} GB of memory is available; simplify the mesh or free memory"
        )
    # the suggested size leaves a fifth of the room free: the estimate is a measured mean, and a render that
    # fills the memory to the last byte would still fail (or swap)
    f = math.sqrt(_SUGGEST_SHARE * room / BYTES_PER_PIXEL / (width * height))
    fit_w, fit_h = max(1, int(width * f)), max(1, int(height * f))
    raise RenderInputError(
        f"a {width}x{height} render needs about {need / 1e9:.1f} GB of memory but {available / 1e9:.1f} GB "
        f"is available; render at most {fit_w}x{fit_h} (--size) or free memory"
    )


# --------------------------------------------------------------------------- render
def render(
    scene: Scene,
    camera: Camera,
    settings: RenderSettings | None = None,
    *,
    progress: Callable[[float], None] | None = None,
    cancel: Callable[[], bool] | None = None,
    geometry_cache: GeometryCache | None = None,
) -> RenderResult:
    """Render ``scene`` seen by ``camera``.

    Each tile is rendered with ``settings.samples_per_pixel`` samples per
    pixel; with adaptive anti-aliasing (``settings.adaptive_samples > 0``)
    the pixels whose samples disagree (:func:`pixels_to_refine`) are then
    rendered again with ``adaptive_samples`` samples, which give their
    value.

    Parameters
    ----------
    scene
        Objects, lights (the first sets the exposure) and sky.
    camera
        Pinhole camera, or the calibrated camera of a posed photo
        (:class:`render.calibrated_camera.CalibratedCamera`); its width and
        height are the image size.
    settings
        A :class:`~render.presets.RenderSettings`; None means the
        ``standard`` preset.
    progress
        Called with the finished fraction (0..1] after each tile.
    cancel
        Polled between tiles; when it returns True the render stops with
        :class:`~render.errors.RenderCancelled`.
    geometry_cache
        A :class:`GeometryCache` kept between renders: the ray tracer of the
        same geometry is reused (``timings["bvh_build"]`` 0,
        ``stats["geometry_reused"]`` True).  None builds it afresh.

    Returns
    -------
    RenderResult
        The image (XYZ, sRGB, coverage), timings and counts.

    Raises
    ------
    RenderInputError
        Bad scene, camera or settings (e.g. a point light inside a closed
        mesh, a first light of intensity 0).
    RenderCancelled
        When ``cancel()`` returned True.

    Examples
    --------
    A white Lambertian square facing a directional light renders at Y = 1:

    >>> from processing.materials.lobes import Lobe, Material
    >>> from processing.materials.dielectric_model import PigmentReflectance
    >>> from render.meshio import make_mesh
    >>> from render.scene import Light, SceneObject, Sky
    >>> white = Material("white", (Lobe("lambert", 1.0, PigmentReflectance([400, 700], [1.0, 1.0])),))
    >>> square = make_mesh([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], [[0, 1, 2], [0, 2, 3]])
    >>> scene = Scene([SceneObject(square, [white])], [Light("directional", (0, 0, 1))], Sky("none"))
    >>> result = render(scene, Camera((0, 0, 4), (0, 0, 0), (0, 1, 0), 20, 4, 4), PRESETS["draft"])
    >>> round(float(result.xyz[..., 1].mean()), 4), int(result.srgb8.min())
    (1.0, 255)
    """
    settings = _check_args(scene, camera, settings)
    check_memory(camera.width, camera.height, sum(o.mesh.n_triangles for o in scene.objects))
    t_start = time.perf_counter()
    if geometry_cache is not None and not isinstance(geometry_cache, GeometryCache):
        raise RenderInputError(f"geometry_cache must be a render.renderer.GeometryCache, got "
                               f"{type(geometry_cache).__name__}")
    prep = _prepare(scene, camera, settings, cache=geometry_cache)
    ctx = prep.ctx
    width, height = camera.width, camera.height
    xyz = np.zeros((height, width, 3), dtype=_F32)
    mask = np.zeros((height, width), dtype=_F32)
    refined = np.zeros((height, width), dtype=bool)
    tiles = _tiles(camera, settings)
    hits_total = 0
    primary_total = 0
    t_loop = time.perf_counter()
    for number, (x0, x1, y0, y1) in enumerate(tiles):
        if cancel is not None and cancel():
            raise RenderCancelled(f"render cancelled after {number} of {len(tiles)} tiles")
        pixel, cover, todo, n_primary, n_hits = _render_tile(prep, camera, settings, number, (x0, x1, y0, y1))
        primary_total += n_primary
        hits_total += n_hits
        ny, nx = y1 - y0, x1 - x0
        if todo is not None:
            refined[y0 + todo // nx, x0 + todo % nx] = True
        xyz[y0:y1, x0:x1] = pixel.reshape(ny, nx, 3)
        mask[y0:y1, x0:x1] = cover.reshape(ny, nx)
        if progress is not None:
            progress((number + 1) / len(tiles))
    t_display = time.perf_counter()
    timings = prep.timings
    timings["shading"] = (t_display - t_loop) - timings["primary_rays"] - timings["shadow_rays"] - timings["mirror_rays"]
    background_black = ctx.sky.is_black and ctx.environment is None
    srgb8 = _display(xyz, mask, prep.white, background_black)
    t_end = time.perf_counter()
    timings["display"] = t_end - t_display
    timings["total"] = t_end - t_start
    stats = _render_stats(prep, scene, refined, primary_total, hits_total, len(tiles))
    return RenderResult(xyz, srgb8, mask, prep.white, timings, stats, settings, not background_black, refined)


def _render_tile(
    prep: _Prepared, camera: Camera, settings: RenderSettings, number: int, tile: tuple[int, int, int, int]
) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.intp] | None, int, int]:
    """Pixel XYZ and coverage of tile ``number``, the refined pixels (None: no refinement), rays and hits cast."""
    x0, x1, y0, y1 = tile
    spp, extra = settings.samples_per_pixel, settings.adaptive_samples
    rng_base, rng_refine, rng_shade = _tile_rngs(settings, number)
    rays = camera.rays(x0, x1, y0, y1, spp, rng_base, settings.jitter)
    sample_xyz, hit, key, steady_xyz = _shade_samples(prep, rays, rng_shade, settings)
    primary_total = rays.shape[0]
    hits_total = int(np.count_nonzero(hit))
    nx = x1 - x0
    pixel = _pixel_mean(sample_xyz, spp)
    cover = _pixel_fraction(hit, spp)
    if not extra:
        return pixel, cover, None, primary_total, hits_total
    todo = np.flatnonzero(pixels_to_refine(steady_xyz, key, spp, prep.white, settings.adaptive_threshold))
    for part in _refine_chunks(todo.size, extra, settings.use_tables):
        idx = todo[part]
        more = camera.pixel_rays(x0 + idx % nx, y0 + idx // nx, extra, rng_refine, settings.jitter)
        more_xyz, more_hit, _, _ = _shade_samples(prep, more, rng_shade, settings)
        primary_total += more.shape[0]
        hits_total += int(np.count_nonzero(more_hit))
        pixel[idx] = _pixel_mean(more_xyz, extra)
        cover[idx] = _pixel_fraction(more_hit, extra)
    return pixel, cover, todo, primary_total, hits_total


def _display(xyz: NDArray[np.float32], mask: NDArray[np.float32], white: NDArray[np.float64],
             sky_is_black: bool) -> NDArray[np.uint8]:
    """8-bit sRGB of the image (uncovered pixels exactly black under a black sky)."""
    from processing.spectral.display import xyz_to_srgb8

    if sky_is_black:
        # uncovered pixels are exactly black: convert only the covered ones
        covered = mask > 0
        srgb8 = np.zeros(mask.shape + (3,), dtype=np.uint8)
        if np.any(covered):
            srgb8[covered] = xyz_to_srgb8(xyz[covered], white)
        return srgb8
    return xyz_to_srgb8(xyz, white)


def _render_stats(prep: _Prepared, scene: Scene, refined: NDArray[np.bool_], primary_total: int, hits_total: int,
                  n_tiles: int) -> dict[str, float]:
    """The counts of :attr:`RenderResult.stats`."""
    ctx = prep.ctx
    n_refined = int(np.count_nonzero(refined))
    return {
        "primary_rays": primary_total,
        "hits": hits_total,
        "shadow_rays": ctx.stats.get("shadow_rays", 0),
        "mirror_rays": ctx.stats.get("mirror_rays", 0),
        "secondary_hits": ctx.stats.get("secondary_hits", 0),
        "environment_rays": ctx.stats.get("environment_rays", 0),
        "refined_pixels": n_refined,
        "refined_fraction": n_refined / refined.size,
        "triangles": prep.n_triangles,
        "objects": len(scene.objects),
        "tiles": n_tiles,
        "geometry_reused": prep.geometry_reused,
        "wavelengths": prep.grid.size,
    }


@dataclass(frozen=True)
class BaselineTiming:
    """Seconds Open3D spends on the bare ray casts of a render (see :func:`cast_rays_baseline`).

    Attributes
    ----------
    build
        The acceleration-structure build (the first, one-ray cast).
    primary, shadow
        ``cast_rays`` of the primary rays, ``test_occlusions`` of the shadow
        rays, with the structure built.
    primary_rays, shadow_rays
        How many rays of each kind were cast.
    """

    build: float
    primary: float
    shadow: float
    primary_rays: int
    shadow_rays: int

    @property
    def cast(self) -> float:
        """Casting time without the build: ``primary + shadow``."""
        return self.primary + self.shadow

    @property
    def with_build(self) -> float:
        """Casting time including the build, as a render from scratch pays it."""
        return self.build + self.cast


def cast_rays_baseline(
    scene: Scene,
    camera: Camera,
    settings: RenderSettings | None = None,
    *,
    refined: NDArray[np.bool_] | None = None,
) -> BaselineTiming:
    """Time the bare Open3D ray casts of a render, without shading.

    The same tiles and primary rays as :func:`render` (same seed and sample
    streams), cast with ``cast_rays``, plus the shadow rays of those hits
    toward every light (``test_occlusions``, built exactly as the renderer
    builds them; only for samples facing the light, and only when
    ``settings.shadows``).  With adaptive anti-aliasing the decisions need
    the shading, so they are taken from the render being compared:
    ``refined`` (its :attr:`RenderResult.refined`) names the pixels whose
    refinement rays are cast too.  Mirror rays are not cast.  Only the
    Open3D calls are timed; building the ray arrays is not.  Like the
    renderer, it casts into a freshly built ``RaycastingScene`` and times the
    acceleration-structure build (the first, one-ray cast) separately.

    Parameters
    ----------
    scene, camera, settings
        As for :func:`render` (None: the ``standard`` preset).
    refined
        bool ``(H, W)`` pixels refined by the render (required when
        ``settings.adaptive_samples > 0``).

    Returns
    -------
    BaselineTiming
        Seconds of the build and of each kind of cast, and the ray counts.

    Raises
    ------
    RenderInputError
        Bad arguments, or ``refined`` missing or of the wrong shape with
        adaptive anti-aliasing.

    Examples
    --------
    >>> from render.meshio import make_mesh
    >>> from render.scene import Light, SceneObject, Sky
    >>> square = make_mesh([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], [[0, 1, 2], [0, 2, 3]])
    >>> scene = Scene([SceneObject(square, ["gold"])], [Light("directional", (0, 0, 1))], Sky("none"))
    >>> camera = Camera((0, 0, 4), (0, 0, 0), (0, 1, 0), 20, 8, 8)
    >>> result = render(scene, camera)
    >>> base = cast_rays_baseline(scene, camera, refined=result.refined)
    >>> base.cast > 0, base.primary_rays == result.stats["primary_rays"]
    (True, True)
    """
    settings = _check_args(scene, camera, settings)
    extra = settings.adaptive_samples
    if extra:
        refined = _checked_refined(refined, camera)
    prep = _prepare(scene, camera, settings, backends=False)
    ctx = prep.ctx
    spp = settings.samples_per_pixel
    count = 0

    def cast(rays: NDArray[np.float32]) -> None:
        answer = _cast_primary(prep, rays)
        rows = np.flatnonzero(np.isfinite(answer["t_hit"]))
        if rows.size and settings.shadows:
            hits = ctx.make_hits(rays, answer, rows)
            for i in range(len(ctx.lights)):
                light_samples(ctx, hits, i)

    for number, (x0, x1, y0, y1) in enumerate(_tiles(camera, settings)):
        rng_base, rng_refine, _ = _tile_rngs(settings, number)
        rays = camera.rays(x0, x1, y0, y1, spp, rng_base, settings.jitter)
        cast(rays)
        count += rays.shape[0]
        if extra:
            todo = np.flatnonzero(refined[y0:y1, x0:x1].reshape(-1))
            nx = x1 - x0
            for part in _refine_chunks(todo.size, extra, settings.use_tables):
                idx = todo[part]
                more = camera.pixel_rays(x0 + idx % nx, y0 + idx // nx, extra, rng_refine, settings.jitter)
                cast(more)
                count += more.shape[0]
    t = prep.timings
    return BaselineTiming(t["bvh_build"], t["primary_rays"], t["shadow_rays"], count,
                          int(ctx.stats.get("shadow_rays", 0)))


def _checked_refined(refined: NDArray[np.bool_] | None, camera: Camera) -> NDArray[np.bool_]:
    """``refined`` as a bool ``(H, W)`` array; refused when missing or of another shape or type."""
    if refined is None:
        raise RenderInputError(
            "cast_rays_baseline: with adaptive anti-aliasing (adaptive_samples > 0) pass refined=, the "
            "RenderResult.refined of the render to compare with, so the same rays are cast"
        )
    refined = np.asarray(refined)
    if refined.shape != (camera.height, camera.width) or refined.dtype != np.bool_:
        raise RenderInputError(
            f"cast_rays_baseline: refined must be a bool array of shape ({camera.height}, {camera.width}) "
            f"(RenderResult.refined), got {refined.dtype} {refined.shape}"
        )
    return refined
