"""Turn a :class:`app.workflows.scene_spec.SceneSpec` into renderer objects.

Procedural shapes (the hawk's head, spheres, planes) are built here from
library calls, so the command line, the scene file and the demo share them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from app.errors import UsageError
from app.workflows.scene_spec import EnvironmentSpec, ObjectSpec, SceneSpec, check_procedural_args
from processing.common.rotation import rotation_xyz_deg as rotation_matrix  # about x, then y, then z (degrees)

__all__ = ["RenderJob", "build_job", "build_environment", "object_mesh", "rotation_matrix", "DEFAULT_LIGHT", "neutral_grey",
           "NEUTRAL_GREY_REFLECTANCE", "face_material_object"]

#: Reflectance of the neutral grey given to faces without a measured material (no region, or a region
#: whose spec is unknown): a Lambertian surface of flat spectral reflectance.
NEUTRAL_GREY_REFLECTANCE = 0.5

#: Key light used when none is given: above, to the left of and in front of a
#: camera that looks along the default view direction.
DEFAULT_LIGHT = (-0.4, -1.0, 1.2)


@dataclass
class RenderJob:
    scene: object          # render.scene.Scene
    camera: object         # render.camera.Camera
    settings: object       # render.presets.RenderSettings


def _sphere_arrays(radius: float, triangles: int) -> tuple[NDArray, NDArray, NDArray]:
    import open3d as o3d

    # create_sphere(resolution r) has about 4 r^2 triangles.
    resolution = max(8, int(round(math.sqrt(max(triangles, 200) / 4.0))))
    mesh = o3d.geometry.TriangleMesh.create_sphere(radius=radius, resolution=resolution)
    v = np.asarray(mesh.vertices, dtype=np.float64)
    t = np.asarray(mesh.triangles, dtype=np.int64)
    return v, t, v / radius


def _plane_arrays(size: float, divisions: int = 8) -> tuple[NDArray, NDArray, NDArray]:
    n = divisions + 1
    xs = np.linspace(-size / 2, size / 2, n)
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    v = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    t = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    normals = np.tile([0.0, 0.0, 1.0], (len(v), 1))
    return v, t, normals


def neutral_grey():
    """The Lambertian grey (:data:`NEUTRAL_GREY_REFLECTANCE`, flat spectrum) of faces without a measured material."""
    from processing.materials.dielectric_model import PigmentReflectance
    from processing.materials.lobes import Lobe, Material

    flat = PigmentReflectance([300.0, 1000.0], [NEUTRAL_GREY_REFLECTANCE] * 2)
    return Material("not measured (neutral grey)", (Lobe("lambert", 1.0, flat),), family="dielectric",
                    description="faces without a measured material")


def face_material_object(mesh, overrides: dict[str, str], where: str) -> tuple[list, NDArray[np.int64]]:
    """Materials and per-triangle index of a :class:`render.material_mesh.MaterialMesh`.

    ``overrides`` maps a region's name or index (``"0"``; ``"-1"`` for the faces of
    no region) to a material spec.  Regions without a spec and faces of no region
    get :func:`neutral_grey` (the last material) unless overridden.
    """
    n = mesh.n_regions
    keys = {str(i): [i] for i in range(-1, n)}
    for i, name in enumerate(mesh.names):
        keys.setdefault(name, []).append(i)
    unknown = sorted(set(overrides) - set(keys))
    if unknown:
        raise UsageError(f"{where}: the mesh has no region(s) {', '.join(unknown)}; regions: "
                         + ", ".join(f"{i} ({name})" for i, name in enumerate(mesh.names)) + ", -1 (no region)")
    materials: list = list(mesh.specs) + [None]
    for key, spec in overrides.items():
        for i in keys[key]:
            materials[i] = spec
    grey = neutral_grey()
    materials = [grey if m is None else m for m in materials]
    index = np.where(mesh.face_material < 0, n, mesh.face_material).astype(np.int64)
    return materials, index


def object_mesh(obj: ObjectSpec, default_hawk_triangles: int = 250_000):
    """Build the :class:`render.scene.SceneObject` of one object spec."""
    from processing.materials.presets import get_material
    from render.meshio import load_mesh, make_mesh
    from render.scene import SceneObject

    region_index = None
    tangents = None
    if obj.mesh is not None:
        from render.material_mesh import material_mesh_or_none

        name = str(obj.mesh)
        per_face = material_mesh_or_none(obj.mesh) if Path(obj.mesh).is_file() else None
        if per_face is not None:
            v, t, n = per_face.vertices, per_face.triangles, per_face.normals
            materials, region_index = face_material_object(per_face, obj.region_materials, f"object {name}")
        else:
            base = load_mesh(obj.mesh)
            v, t, n = base.vertices, base.triangles, base.vertex_normals
            materials = [obj.material]
    else:
        kind = (obj.procedural or "").lower()
        # specs built by the GUI or the demo pass the same checks as a scene file's
        args = check_procedural_args(kind, obj.procedural_args, f"procedural object {kind}")
        if kind == "hawk":
            from mocks.procedural_hawk import DEFAULT_MATERIALS, hawk_head

            hawk = hawk_head(int(args.get("triangles", default_hawk_triangles)))
            v, t, n = hawk.vertices, hawk.triangles, hawk.vertex_normals
            unknown = set(obj.region_materials) - set(hawk.region_names)
            if unknown:
                raise UsageError(
                    f"hawk has no region(s) {', '.join(sorted(unknown))}; regions: {', '.join(hawk.region_names)}"
                )
            materials = [obj.region_materials.get(r, DEFAULT_MATERIALS.get(r, obj.material))
                         for r in hawk.region_names]
            region_index = hawk.region
        elif kind == "sphere":
            v, t, n = _sphere_arrays(float(args.get("radius", 1.0)), int(args.get("triangles", 20_000)))
            materials = [obj.material]
        elif kind == "plane":
            v, t, n = _plane_arrays(float(args.get("size", 10.0)))
            materials = [obj.material]
        elif kind == "cloth":
            from processing.cloth.draped import draped_cloth
            from render.tangents import tangents_from_uvs

            # the sheet has about 1.5 d^2 triangles for d divisions along x
            sheet = draped_cloth(divisions=max(2, int(math.sqrt(float(args.get("triangles", 20_000)) / 1.5))))
            v, t, n = sheet.vertices, sheet.triangles, sheet.normals
            tangents = tangents_from_uvs(v, t, sheet.uvs, n)
            materials = [obj.material]
        else:
            raise UsageError(f"unknown procedural object {obj.procedural!r}; use hawk, sphere, plane or cloth")
        name = kind

    rot = rotation_matrix(obj.rotate_deg)
    if not (math.isfinite(obj.scale) and obj.scale > 0):
        raise UsageError(f"object {name}: scale must be positive, got {obj.scale}")
    v = (np.asarray(v) * obj.scale) @ rot.T + np.asarray(obj.translate)
    n = np.asarray(n) @ rot.T
    if tangents is not None:
        tangents = tangents @ rot.T
    resolved = [get_material(m) if isinstance(m, str) else m for m in materials]
    # the index goes through make_mesh so that dropped zero-area triangles take their entries with them
    mesh = make_mesh(v, t, n, region_index, "triangle" if region_index is not None else None, source=name)
    return SceneObject(mesh, resolved, name=name,
                       tangents=tangents, weave_angle_deg=float(obj.weave_angle_deg or 0.0))


def build_environment(env: EnvironmentSpec):
    """The :class:`processing.lighting.environment_map.EnvironmentMap` of an environment spec (file or sky).

    Bad files and settings raise :class:`processing.lighting.environment_map.EnvironmentMapError`
    (an input error: one line naming the file or setting).
    """
    from processing.lighting.daylight_sky import daylight_sky
    from processing.lighting.environment_map import read_environment

    if env.file is not None:
        base = read_environment(env.file)
    else:
        base = daylight_sky(**env.sky)
    return base.with_(rotation_deg=env.rotate_deg, intensity=env.intensity * base.intensity)


def build_job(spec: SceneSpec, *, default_hawk_triangles: int = 250_000) -> RenderJob:
    """Build scene, camera and settings; every bad value becomes a :class:`UsageError`."""
    from processing.spectral.spectra import REFERENCE_GRID, light_spectrum
    from render.camera import Camera
    from render.presets import get_preset
    from render.scene import Light, Scene, Sky

    try:
        light_spectrum(spec.illuminant, REFERENCE_GRID)
    except (ValueError, OSError) as exc:
        raise UsageError(f"--illuminant: {exc}") from None
    for light in spec.lights:
        if light.spectrum:
            try:
                light_spectrum(light.spectrum, REFERENCE_GRID)
            except (ValueError, OSError) as exc:
                raise UsageError(f"light spectrum: {exc}") from None

    environment = build_environment(spec.environment) if spec.environment is not None else None
    objects = [object_mesh(o, default_hawk_triangles) for o in spec.objects]
    lights_spec = spec.lights or []
    lights = [Light(ls.kind, ls.vector, ls.spectrum or spec.illuminant, ls.intensity) for ls in lights_spec]
    if not lights and environment is None:
        lights = [Light("directional", DEFAULT_LIGHT, spec.illuminant, 1.0)]
    # an environment replaces the default key light and sky; asked-for ones light the scene with it
    sky_kind = "none" if environment is not None and not spec.sky_given else spec.sky.kind
    sky = Sky(kind=sky_kind, zenith=spec.sky.zenith, horizon=spec.sky.horizon,
              spectrum=spec.sky.spectrum or spec.illuminant)
    scene = Scene(objects, lights, sky, environment=environment)

    width, height = spec.size
    cam = spec.camera
    if cam.eye is None:
        lo, hi = scene.bounds()
        camera = Camera.framing(lo, hi, width, height, fov_deg=cam.fov_deg, up=cam.up)
        if cam.target is not None:
            camera = Camera(camera.eye, cam.target, cam.up, cam.fov_deg, width, height)
    else:
        if cam.target is None:
            lo, hi = scene.bounds()
            target = tuple(((np.asarray(lo) + np.asarray(hi)) / 2).tolist())
        else:
            target = cam.target
        camera = Camera(cam.eye, target, cam.up, cam.fov_deg, width, height)
    try:
        settings = get_preset(spec.preset)
    except (KeyError, ValueError) as exc:
        raise UsageError(f"--preset: {exc}") from None
    if spec.environment_samples is not None:
        settings = settings.replace(environment_samples=spec.environment_samples)
    return RenderJob(scene, camera, settings)
