"""Render a scene: Open3D ray casting plus NumPy spectral shading, tile by tile.

Pipeline per tile of pixels (DESIGN.md sections 4-5):

1. primary rays through one sample per stratum of each pixel (ordered grid
   or stratified jitter, :mod:`render.camera`), cast with ``open3d.t.geometry.RaycastingScene.cast_rays`` (one geometry
   per object; geometry ids map hits back to objects);
2. per hit: position, the smooth shading normal interpolated from the vertex
   normals with the barycentric ``primitive_uvs`` (u, v weight vertices 1
   and 2, vertex 0 gets 1 - u - v), the face normal, both turned toward the
   viewer, and the material (per triangle, or per vertex: the vertex with the
   largest barycentric weight);
3. shading (:mod:`render.shading`): shadow rays toward each light, sky light,
   mirrored rays with one bounce, evaluated per wavelength (reference) or
   through angular XYZ tables (standard, draft);
4. the samples of each pixel are averaged; XYZ are normalised so that a white
   Lambertian surface facing the first light has Y = 1 (for a point light,
   at the distance from the light to the centre of the scene's bounds), and
   converted to 8-bit sRGB with chromatic adaptation from the first light's
   white (:func:`processing.display.xyz_to_srgb8`).

Pixels no object covers show the sky along the camera ray (black when the
sky is ``"none"``); ``RenderResult.mask`` holds the fraction of each pixel's
samples that hit an object, the alpha of :meth:`RenderResult.rgba8`.

Memory is bounded by the tile size: only one tile's rays and shading arrays
exist at a time (at most ``MAX_TILE_SAMPLES`` samples, float32 in the table
path), besides the image buffers, the per-triangle vertex normals (36 bytes
per triangle) and the ray tracer's acceleration structure.  Measured peak
resident memory for 1024 x 1024 pixels of a 1M-triangle mesh at the
``standard`` preset: about 0.55 GB.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from numpy.typing import NDArray

from processing.spectra import SpectralGrid
from render.camera import Camera
from render.errors import RenderCancelled, RenderInputError
from render.presets import PRESETS, RenderSettings
from render.scene import Scene, check_point_lights, resolve_spectrum
from render.shading import (
    Hits,
    LightPlan,
    ShadingContext,
    SpectralBackend,
    TableBackend,
    dot3,
    light_samples,
    plan_material,
    shade,
)

__all__ = ["RenderResult", "render", "cast_rays_baseline", "RenderCancelled", "MAX_TILE_SAMPLES"]

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
        Seconds per stage: ``setup``, ``primary_rays``, ``shadow_rays``,
        ``mirror_rays``, ``shading``, ``display``, ``total``.
    stats
        Counts: rays of each kind, hits, triangles, tiles.
    settings
        The settings used.
    sky_visible
        False when the sky is ``"none"`` (background transparent).
    """

    xyz: NDArray[np.float32]
    srgb8: NDArray[np.uint8]
    mask: NDArray[np.float32]
    white: NDArray[np.float64]
    timings: dict[str, float] = field(default_factory=dict)
    stats: dict[str, float] = field(default_factory=dict)
    settings: RenderSettings | None = None
    sky_visible: bool = False

    def rgba8(self) -> NDArray[np.uint8]:
        """``(H, W, 4)`` sRGB with alpha: coverage when the sky is off, opaque otherwise."""
        alpha = np.round(self.mask * 255.0).astype(np.uint8) if not self.sky_visible else np.full(
            self.mask.shape, 255, np.uint8
        )
        return np.concatenate([self.srgb8, alpha[..., None]], axis=-1)


# --------------------------------------------------------------------------- preparation
@dataclass(eq=False)
class _Prepared:
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


def _check_args(scene: Scene, camera: Camera, settings: RenderSettings | None) -> RenderSettings:
    if not isinstance(scene, Scene):
        raise RenderInputError(f"scene must be a render.scene.Scene, got {type(scene).__name__}")
    if not isinstance(camera, Camera):
        raise RenderInputError(f"camera must be a render.camera.Camera, got {type(camera).__name__}")
    if settings is None:
        return PRESETS["standard"]
    if not isinstance(settings, RenderSettings):
        raise RenderInputError(
            f"settings must be a RenderSettings (e.g. render.presets.PRESETS['standard']), got {type(settings).__name__}"
        )
    return settings


def _prepare(scene: Scene, camera: Camera, settings: RenderSettings, *, backends: bool = True) -> _Prepared:
    import open3d as o3d
    from processing.display import white_xyz, xyz_scale

    timings: dict[str, float] = {"primary_rays": 0.0, "shadow_rays": 0.0, "mirror_rays": 0.0}
    t0 = time.perf_counter()
    raycaster = o3d.t.geometry.RaycastingScene()
    # global material numbering (the same Material object shared by objects gets one number)
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
    several = len(materials) > 1
    offsets = [0]
    normals = []
    corners = []
    for i, obj in enumerate(scene.objects):
        mesh = obj.mesh
        gid = raycaster.add_triangles(
            o3d.core.Tensor(np.ascontiguousarray(mesh.vertices, dtype=np.float32)),
            o3d.core.Tensor(np.ascontiguousarray(mesh.triangles, dtype=np.uint32)),
        )
        if gid != i:
            raise RuntimeError(f"Open3D returned geometry id {gid} for object {i}")
        offsets.append(offsets[-1] + mesh.n_triangles)
        normals.append(mesh.vertex_normals.astype(np.float32)[mesh.triangles].reshape(-1, 9).T)
        if several:
            table = per_object_map[i]
            if obj.material_index is None:
                corners.append(np.full((mesh.n_triangles, 3), table[0], dtype=np.int32))
            elif obj.material_index_on == "triangle":
                corners.append(np.repeat(table[obj.material_index][:, None], 3, axis=1))
            else:
                corners.append(table[obj.material_index][mesh.triangles])
    tri_normals = np.ascontiguousarray(normals[0] if len(normals) == 1 else np.concatenate(normals, axis=1))
    corner_material = np.concatenate(corners).astype(np.int32) if several else None
    per_vertex = any(obj.material_index_on == "vertex" for obj in scene.objects)
    triangle_material = None
    if corner_material is not None and not per_vertex:
        triangle_material = np.ascontiguousarray(corner_material[:, 0])   # the three corners agree

    lo, hi = scene.bounds()
    diag = float(np.linalg.norm(hi - lo))
    # Secondary rays start this far off the surface: 1e-4 of the scene's size, plus ~16 float32
    # ulps of the largest coordinate or camera distance involved in computing hit points.
    magnitude = max(float(np.max(np.abs(np.concatenate([lo, hi])))),
                    float(np.linalg.norm(np.asarray(camera.eye) - 0.5 * (lo + hi))))
    offset = 1e-4 * diag + 2e-6 * magnitude

    # spectra and the normalisation
    grid = SpectralGrid(400.0, 700.0, settings.spectral_step)
    spectra = [resolve_spectrum(light.spectrum, grid, f"light {i} spectrum") for i, light in enumerate(scene.lights)]
    key = scene.lights[0]
    if key.kind == "directional":
        key_irradiance = key.intensity
    else:
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
    k = xyz_scale(spectra[0], grid)
    white = white_xyz(spectra[0], grid)
    lights = tuple(
        LightPlan(light.kind, np.asarray(light.vector, dtype=np.float64), e * (light.intensity / key_irradiance))
        for light, e in zip(scene.lights, spectra)
    )
    sky = scene.sky
    sky_spec = resolve_spectrum(sky.spectrum, grid, "sky spectrum") if sky.spectrum is not None else spectra[0]
    sky_radiance = sky_spec / math.pi
    plans = tuple(plan_material(m) for m in materials)
    backend: SpectralBackend | TableBackend | None = None
    if backends:
        spectral = SpectralBackend(grid, k, lights, sky, sky_radiance, plans)
        backend = spectral
        if settings.use_tables:
            backend = TableBackend(grid, k, lights, sky, sky_radiance, plans, settings.table_size, spectral)

    tri_offset = np.asarray(offsets[:-1], dtype=np.int64)
    single_object = len(scene.objects) == 1

    def cast(rays: NDArray[np.float32]) -> dict[str, NDArray]:
        t = time.perf_counter()
        ans = raycaster.cast_rays(o3d.core.Tensor.from_numpy(rays))
        out = {name: value.numpy() for name, value in ans.items()}
        timings["mirror_rays"] += time.perf_counter() - t
        return out

    def occluded(rays: NDArray[np.float32], tfar: float) -> NDArray[np.bool_]:
        t = time.perf_counter()
        ans = raycaster.test_occlusions(o3d.core.Tensor.from_numpy(rays), tnear=0.0, tfar=tfar).numpy()
        timings["shadow_rays"] += time.perf_counter() - t
        return ans

    def make_hits(rays: NDArray[np.float32], answer: dict[str, NDArray], rows: NDArray[np.intp]) -> Hits:
        ray = np.ascontiguousarray(np.take(rays, rows, axis=0).T)          # (6, m)
        d = ray[3:]
        position = ray[:3]
        position += d * np.take(answer["t_hit"], rows)
        prim = np.take(answer["primitive_ids"], rows).astype(np.int64)
        if not single_object:
            prim += tri_offset[np.take(answer["geometry_ids"], rows).astype(np.int64)]
        uv = np.ascontiguousarray(np.take(answer["primitive_uvs"], rows, axis=0).T)
        u, v = uv[0], uv[1]
        w0 = _F32(1.0) - u - v
        corner = np.take(tri_normals, prim, axis=1)                           # (9, m)
        ns = corner[0:3] * w0
        ns += corner[3:6] * u
        ns += corner[6:9] * v
        ng = np.ascontiguousarray(np.take(answer["primitive_normals"], rows, axis=0).T)
        # turn the face normal toward the viewer, then the shading normal to the face normal's side
        ng *= np.where(dot3(ng, d) > 0, _F32(-1.0), _F32(1.0))
        sign = np.where(dot3(ns, ng) < 0, _F32(-1.0), _F32(1.0))
        ns *= sign / np.sqrt(np.maximum(dot3(ns, ns), _F32(1e-30)))
        view = np.negative(d)
        cos_o = dot3(ns, view)
        low = np.flatnonzero(cos_o < _F32(1e-3))
        if low.size:
            # silhouettes of coarse meshes: bend the shading normal until it faces the viewer
            vl = view[:, low]
            bent = ns[:, low] + (_F32(1e-3) - cos_o[low]) * vl
            bent *= _F32(1.0) / np.sqrt(dot3(bent, bent))
            ns[:, low] = bent
            cos_o[low] = np.maximum(dot3(bent, vl), _F32(1e-4))
        if corner_material is None:
            material = np.zeros(rows.size, dtype=np.int32)
        elif triangle_material is not None:
            material = np.take(triangle_material, prim)
        else:
            nearest = np.argmax(np.stack([w0, u, v]), axis=0)
            material = corner_material[prim, nearest]
        return Hits(position, ns, ng, view, cos_o, material)

    ctx = ShadingContext(
        lights=lights,
        sky=sky,
        plans=plans,
        offset=offset,
        shadows=settings.shadows,
        mirror_bounces=settings.mirror_bounces,
        mirror_rays=settings.mirror_rays,
        cast=cast,
        occluded=occluded,
        make_hits=make_hits,
    )
    timings["setup"] = time.perf_counter() - t0
    check_point_lights(scene, raycaster)
    return _Prepared(
        raycaster, grid, k, white, tri_offset, tri_normals, corner_material, ctx, backend, timings,
        int(offsets[-1]),
    )


#: Most samples in one tile: 65536 with tables (float32 XYZ), 16384 with
#: per-sample spectra (float64, L bands each), which bounds the working memory.
MAX_TILE_SAMPLES = {True: 1 << 16, False: 1 << 14}


def _tiles(camera: Camera, settings: RenderSettings) -> list[tuple[int, int, int, int]]:
    """Pixel blocks ``(x0, x1, y0, y1)``, row by row; the side is ``settings.tile_size``, reduced
    so a tile holds at most ``MAX_TILE_SAMPLES`` samples."""
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


# --------------------------------------------------------------------------- render
def render(
    scene: Scene,
    camera: Camera,
    settings: RenderSettings | None = None,
    *,
    progress: Callable[[float], None] | None = None,
    cancel: Callable[[], bool] | None = None,
) -> RenderResult:
    """Render ``scene`` seen by ``camera``.

    Parameters
    ----------
    scene
        Objects, lights (the first sets the exposure) and sky.
    camera
        Pinhole camera; its width and height are the image size.
    settings
        A :class:`~render.presets.RenderSettings`; None means the
        ``standard`` preset.
    progress
        Called with the finished fraction (0..1] after each tile.
    cancel
        Polled between tiles; when it returns True the render stops with
        :class:`~render.errors.RenderCancelled`.

    Returns
    -------
    RenderResult

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

    >>> from processing.material import Lobe, Material
    >>> from processing.dielectric_model import PigmentReflectance
    >>> from render.meshio import make_mesh
    >>> from render.scene import Light, SceneObject, Sky
    >>> white = Material("white", (Lobe("lambert", 1.0, PigmentReflectance([400, 700], [1.0, 1.0])),))
    >>> square = make_mesh([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], [[0, 1, 2], [0, 2, 3]])
    >>> scene = Scene([SceneObject(square, [white])], [Light("directional", (0, 0, 1))], Sky("none"))
    >>> result = render(scene, Camera((0, 0, 4), (0, 0, 0), (0, 1, 0), 20, 4, 4), PRESETS["draft"])
    >>> round(float(result.xyz[..., 1].mean()), 4), int(result.srgb8.min())
    (1.0, 255)
    """
    from processing.display import xyz_to_srgb8

    settings = _check_args(scene, camera, settings)
    t_start = time.perf_counter()
    prep = _prepare(scene, camera, settings)
    ctx, backend = prep.ctx, prep.backend
    width, height, spp = camera.width, camera.height, settings.samples_per_pixel
    xyz = np.zeros((height, width, 3), dtype=_F32)
    mask = np.zeros((height, width), dtype=_F32)
    tiles = _tiles(camera, settings)
    hits_total = 0
    t_loop = time.perf_counter()
    for number, (x0, x1, y0, y1) in enumerate(tiles):
        if cancel is not None and cancel():
            raise RenderCancelled(f"render cancelled after {number} of {len(tiles)} tiles")
        rng = np.random.default_rng([settings.seed, number])
        rays = camera.rays(x0, x1, y0, y1, spp, rng, settings.jitter)
        answer = _cast_primary(prep, rays)
        hit = np.isfinite(answer["t_hit"])
        rows = np.flatnonzero(hit)
        colour = backend.zeros(rays.shape[0])
        if not ctx.sky.is_black:
            miss = np.flatnonzero(~hit)
            if miss.size:
                scale = ctx.sky.radiance_scale(np.take(rays, miss, axis=0)[:, 3:])
                backend.add(colour, miss, backend.background(scale))
        if rows.size:
            hits = ctx.make_hits(rays, answer, rows)
            backend.add(colour, rows, shade(ctx, hits, backend, settings.mirror_bounces, rng))
        hits_total += rows.size
        sample_xyz = backend.to_xyz(colour)
        ny, nx = y1 - y0, x1 - x0
        xyz[y0:y1, x0:x1] = _pixel_mean(sample_xyz, spp).reshape(ny, nx, 3)
        mask[y0:y1, x0:x1] = (np.count_nonzero(hit.reshape(ny, nx, spp), axis=2) / spp).astype(_F32)
        if progress is not None:
            progress((number + 1) / len(tiles))
    t_display = time.perf_counter()
    timings = prep.timings
    timings["shading"] = (t_display - t_loop) - timings["primary_rays"] - timings["shadow_rays"] - timings["mirror_rays"]
    if ctx.sky.is_black:
        # uncovered pixels are exactly black: convert only the covered ones
        covered = mask > 0
        srgb8 = np.zeros((height, width, 3), dtype=np.uint8)
        if np.any(covered):
            srgb8[covered] = xyz_to_srgb8(xyz[covered], prep.white)
    else:
        srgb8 = xyz_to_srgb8(xyz, prep.white)
    t_end = time.perf_counter()
    timings["display"] = t_end - t_display
    timings["total"] = t_end - t_start
    stats = {
        "primary_rays": width * height * spp,
        "hits": hits_total,
        "shadow_rays": ctx.stats.get("shadow_rays", 0),
        "mirror_rays": ctx.stats.get("mirror_rays", 0),
        "secondary_hits": ctx.stats.get("secondary_hits", 0),
        "triangles": prep.n_triangles,
        "objects": len(scene.objects),
        "tiles": len(tiles),
        "wavelengths": prep.grid.size,
    }
    return RenderResult(xyz, srgb8, mask, prep.white, timings, stats, settings, not ctx.sky.is_black)


def cast_rays_baseline(scene: Scene, camera: Camera, settings: RenderSettings | None = None) -> float:
    """Seconds Open3D spends on the bare ray casts of a render, without shading.

    The same tiles and primary rays as :func:`render` (same seed), cast with
    ``cast_rays``, plus the shadow rays of those hits toward every light
    (``test_occlusions``, built exactly as the renderer builds them; only for
    samples facing the light, and only when ``settings.shadows``).  Only the
    Open3D calls are timed; building the ray arrays is not.  Like the
    renderer, it casts into a freshly built ``RaycastingScene``, so the time
    includes Open3D's acceleration-structure build, done lazily by the first
    cast (about 0.5 s for a million triangles on two cores).  ``render time /
    baseline`` is the overhead of shading, mirror rays and bookkeeping.

    Returns
    -------
    float
        Seconds.

    Examples
    --------
    >>> from render.meshio import make_mesh
    >>> from render.scene import Light, SceneObject, Sky
    >>> square = make_mesh([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], [[0, 1, 2], [0, 2, 3]])
    >>> scene = Scene([SceneObject(square, ["gold"])], [Light("directional", (0, 0, 1))], Sky("none"))
    >>> cast_rays_baseline(scene, Camera((0, 0, 4), (0, 0, 0), (0, 1, 0), 20, 8, 8)) > 0
    True
    """
    settings = _check_args(scene, camera, settings)
    prep = _prepare(scene, camera, settings, backends=False)
    ctx = prep.ctx
    spp = settings.samples_per_pixel
    for number, (x0, x1, y0, y1) in enumerate(_tiles(camera, settings)):
        rng = np.random.default_rng([settings.seed, number])
        rays = camera.rays(x0, x1, y0, y1, spp, rng, settings.jitter)
        answer = _cast_primary(prep, rays)
        rows = np.flatnonzero(np.isfinite(answer["t_hit"]))
        if rows.size and settings.shadows:
            hits = ctx.make_hits(rays, answer, rows)
            for i in range(len(ctx.lights)):
                light_samples(ctx, hits, i)
    return prep.timings["primary_rays"] + prep.timings["shadow_rays"]
