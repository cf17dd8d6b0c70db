"""Render a posed photo in the observations' units: chart-normalised camera RGB.

:func:`render_signal` draws the object's mesh, with one material per face
region, as the calibrated camera of a posed frame
(:class:`render.calibrated_camera.CalibratedCamera`) saw it under the frame's
lamps, per pixel the quantity the observations hold
(:mod:`processing.appearance.observations`): camera RGB relative to a white
Lambertian diffuser facing the lamp at the reference irradiance,

    m_c = k * sum_lamps irr * cos_i * pi * sum_l f_r(l) E(l) s_c(l) / sum_l E(l) s_c(l)

with ``f_r`` the spectral BRDF of the face's material
(:func:`processing.materials.lobes.material_brdf`, 1/sr), ``E`` the lamp
spectrum, ``s_c`` the camera's sensitivities, ``irr = (d_ref / d)^2`` for a
point lamp at distance ``d`` (1 for a distant lamp) and ``k`` the lamp's
intensity scale.  Direct light only, with shadow rays (the booth is dark: no
environment, no inter-reflections).  One ray per pixel centre (the photo's
pixels are point samples of the same model); hits are found with Open3D's
``RaycastingScene``.  A camera's lens and optical low-pass filter spread each
point over about a photosite before the colour filter array: with
``spread_px`` the rendered signal is blurred by that Gaussian point spread
within the object (a normalised convolution over the measured pixels,
:func:`processing.camera.point_spread.spread_within`: the
backdrop a photo mixes into its outline's outer pixels is not rendered, so
compare those eroded by ``4 * spread_px + 1`` pixels, the kernel's reach).

References
----------
Wald, I., Woop, S., Benthin, C., Johnson, G. S., Ernst, M. (2014). Embree: a
kernel framework for efficient CPU ray tracing. ACM TOG 33(4), 143.
doi:10.1145/2601097.2601199
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import open3d as o3d
from numpy.typing import ArrayLike, NDArray

from processing.camera.point_spread import spread_within
from processing.camera.response import camera_sensitivities
from processing.materials.lobes import material_brdf
from processing.materials.presets import get_material
from processing.spectral.spectra import SpectralGrid, light_spectrum
from render.calibrated_camera import CalibratedCamera
from render.errors import RenderInputError

__all__ = ["render_signal", "pixel_faces", "SIGNAL_GRID"]

#: Wavelength grid of :func:`render_signal` unless one is given: 400-700 nm every 10 nm.
SIGNAL_GRID = SpectralGrid(400.0, 700.0, 10.0)


def _spectra(light: Any, sensitivities: Any, grid: SpectralGrid) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The lamp spectrum ``(L,)`` and the sensitivities ``(L, 3)`` on ``grid``, checked."""
    e = light_spectrum(light, grid) if isinstance(light, (str, int, float)) else np.asarray(light, dtype=np.float64)
    if e.shape != (grid.size,) or not np.all(np.isfinite(e)) or np.any(e < 0):
        raise RenderInputError(f"render_signal light_spectrum: give a name, a CCT or {grid.size} finite values >= 0 "
                               f"on the grid, got shape {e.shape}")
    if sensitivities is None or isinstance(sensitivities, str):
        s = camera_sensitivities(grid, *(() if sensitivities is None else (sensitivities,)))
    else:
        s = np.asarray(sensitivities, dtype=np.float64)
    if s.shape != (grid.size, 3) or not np.all(np.isfinite(s)) or not np.all(e @ s > 0):
        raise RenderInputError(f"render_signal sensitivities: give a camera name or ({grid.size}, 3) finite values "
                               "with a signal in every channel under the lamp")
    return e, s


def _mesh(vertices: ArrayLike, triangles: ArrayLike, normals: ArrayLike | None, face_material: ArrayLike,
          n_specs: int) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64] | None, NDArray[np.int64]]:
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles)
    fm = np.asarray(face_material)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0 or not np.all(np.isfinite(v)):
        raise RenderInputError("render_signal vertices: give a non-empty finite (V, 3) array (mm)")
    if t.ndim != 2 or t.shape[1] != 3 or len(t) == 0 or t.min() < 0 or t.max() >= len(v):
        raise RenderInputError("render_signal triangles: give a non-empty (T, 3) array of vertex indices")
    if fm.shape != (len(t),) or (fm.size and (fm.min() < -1 or fm.max() >= n_specs)):
        raise RenderInputError(f"render_signal face_material: give one region index per triangle in -1..{n_specs - 1}")
    n = None
    if normals is not None:
        n = np.asarray(normals, dtype=np.float64)
        if n.shape != v.shape or not np.all(np.isfinite(n)):
            raise RenderInputError("render_signal normals: give finite (V, 3) vertex normals or None (flat shading)")
        n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return v, t.astype(np.int64), n, fm.astype(np.int64)


def _hits(scene: Any, camera: CalibratedCamera) -> dict[str, NDArray[Any]]:
    """Primary hits through the pixel centres: index, position, geometric normal, primitive and barycentrics."""
    rays = camera.rays(0, camera.width, 0, camera.height, 1)
    ans = scene.cast_rays(o3d.core.Tensor(rays))
    t = ans["t_hit"].numpy().astype(np.float64)
    idx = np.flatnonzero(np.isfinite(t))
    d = rays[idx, 3:].astype(np.float64)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pos = np.asarray(camera.eye)[None, :] + d * t[idx, None]
    return {"idx": idx, "pos": pos, "view": -d, "geo": ans["primitive_normals"].numpy()[idx].astype(np.float64),
            "prim": ans["primitive_ids"].numpy()[idx].astype(np.int64), "uv": ans["primitive_uvs"].numpy()[idx]}


def _shading_normal(hits: dict[str, NDArray[Any]], triangles: NDArray[np.int64],
                    normals: NDArray[np.float64] | None) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Geometric and shading normals at the hits, both turned toward the viewer."""
    view = hits["view"]
    geo = hits["geo"] * np.where(np.einsum("ij,ij->i", hits["geo"], view) < 0, -1.0, 1.0)[:, None]
    if normals is None:
        return geo, geo
    tri = triangles[hits["prim"]]
    u, w = hits["uv"][:, 0:1].astype(np.float64), hits["uv"][:, 1:2].astype(np.float64)
    n = (1.0 - u - w) * normals[tri[:, 0]] + u * normals[tri[:, 1]] + w * normals[tri[:, 2]]
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    n *= np.where(np.einsum("ij,ij->i", n, geo) < 0, -1.0, 1.0)[:, None]
    return geo, n


def _lamp_terms(lamp: Any, pos: NDArray[np.float64], geo: NDArray[np.float64], scene: Any, size_mm: float,
                d_ref_mm: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Unit directions toward one lamp and its relative irradiance times visibility at the hits."""
    vec = np.asarray(lamp.vector, dtype=np.float64)
    if lamp.kind == "point":
        to = vec[None, :] - pos
        dist = np.maximum(np.linalg.norm(to, axis=1), 1e-9)
        light, irr, tfar = to / dist[:, None], (d_ref_mm / dist) ** 2, 1.0
        toward = to
    else:
        light = np.broadcast_to(vec / np.linalg.norm(vec), pos.shape)
        irr, tfar, toward = np.ones(len(pos)), math.inf, light
    origin = pos + geo * (1e-4 * size_mm)
    shadow = np.concatenate([origin, toward], axis=1).astype(np.float32)
    lit = ~scene.test_occlusions(o3d.core.Tensor(shadow), tfar=tfar).numpy() if len(pos) else np.ones(0, bool)
    return np.ascontiguousarray(light), irr * lit


def _reference_distance(frame_pose: Any, vertices: NDArray[np.float64], irradiance_ref_mm: float | None) -> float:
    if irradiance_ref_mm is not None:
        d = float(irradiance_ref_mm)
        if not (math.isfinite(d) and d > 0):
            raise RenderInputError(f"render_signal irradiance_ref_mm: give a distance > 0 mm, got {irradiance_ref_mm!r}")
        return d
    centre = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    points = [lamp.vector for lamp in frame_pose.lamps if lamp.kind == "point"]
    return float(np.linalg.norm(np.asarray(points[0]) - centre)) if points else 1.0


def render_signal(vertices: ArrayLike, triangles: ArrayLike, normals: ArrayLike | None, face_material: ArrayLike,
                  specs: Sequence[str | None], frame_pose: Any, light_spectrum: Any, *, sensitivities: Any = None,
                  scale: float = 1.0, irradiance_ref_mm: float | None = None,
                  grid: SpectralGrid = SIGNAL_GRID, spread_px: float = 0.0
                  ) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """Render a posed frame as chart-normalised camera RGB (the observations' signal).

    Parameters
    ----------
    vertices, triangles
        The mesh in M, ``(V, 3)`` mm and ``(T, 3)``.
    normals
        ``(V, 3)`` vertex normals, interpolated across faces (smooth
        shading); None shades each face with its own normal (flat).
    face_material
        ``(T,)`` region index per face into ``specs``; -1: not measured.
    specs
        Material spec per region (:func:`processing.materials.presets.get_material`);
        None: not measured.  Pixels of unmeasured faces are NaN and not in the mask.
    frame_pose
        The :class:`processing.appearance.frame_poses.FramePose` (camera, pose, lamps in M).
    light_spectrum
        The lamp spectrum: a name or CCT (``processing.spectral.spectra.light_spectrum``) or ``(L,)`` on ``grid``.
    sensitivities
        Camera sensitivities: None (the default camera), a camera name or ``(L, 3)`` on ``grid``.
    scale
        The lamp intensity scale ``k`` of the chart calibration.
    irradiance_ref_mm
        ``d_ref`` of a point lamp's relative irradiance ``(d_ref / d)^2``;
        None: the first point lamp's distance to the mesh's bounding-box centre.
    grid
        Wavelength grid of the spectral sums.
    spread_px
        The camera's point spread (Gaussian standard deviation, pixels) to
        blur the rendering with, within the measured pixels; 0: a pinhole.

    Returns
    -------
    signal, mask
        ``(H, W, 3)`` float32 (0 on the backdrop, NaN on unmeasured faces)
        and ``(H, W)`` bool: pixels of faces with a material.

    Examples
    --------
    >>> import numpy as np
    >>> from processing.appearance.frame_poses import FramePose, MeshLamp
    >>> m2c = np.eye(4); m2c[2, 3] = 100.0
    >>> f = FramePose("f", 1, 0.0, (8, 8), [[40, 0, 3.5], [0, 40, 3.5], [0, 0, 1]], np.zeros(5), m2c,
    ...               (MeshLamp("lamp", "distant", [0.0, 0.0, -1.0]),))
    >>> v = np.array([[-50, -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0.0]])
    >>> sig, mask = render_signal(v, [[0, 1, 2], [0, 2, 3]], None, [0, 0], ["urushi-black"], f, "D65")
    >>> bool(mask.all()), sig.shape
    (True, (8, 8, 3))
    """
    v, t, n, fm = _mesh(vertices, triangles, normals, face_material, len(specs))
    e, s = _spectra(light_spectrum, sensitivities, grid)
    if not (math.isfinite(float(scale)) and float(scale) > 0):
        raise RenderInputError(f"render_signal scale: give a lamp scale > 0, got {scale!r}")
    if not frame_pose.lamps:
        raise RenderInputError(f"render_signal: frame {frame_pose.name!r} has no lamp; pose it with its lamps")
    if not (math.isfinite(float(spread_px)) and 0 <= float(spread_px) <= 10):
        raise RenderInputError(f"render_signal spread_px: give the camera's point spread in [0, 10] px, "
                               f"got {spread_px!r}")
    camera = CalibratedCamera.from_frame(frame_pose)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(t.astype(np.uint32)))
    hits = _hits(scene, camera)
    geo, normal = _shading_normal(hits, t, n)
    size_mm = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    d_ref = _reference_distance(frame_pose, v, irradiance_ref_mm)
    region = fm[hits["prim"]]
    rgb = np.full((len(region), 3), np.nan)
    measured = np.array([spec is not None for spec in specs] + [False])[region]
    rgb[measured] = 0.0
    weight = math.pi * float(scale) * (e[:, None] * s) / (e @ s)[None, :]           # (L, 3)
    for lamp in frame_pose.lamps:
        light, irr = _lamp_terms(lamp, hits["pos"], geo, scene, size_mm, d_ref)
        _add_lamp(rgb, region, specs, normal, hits["view"], light, irr, weight, grid)
    h, w = camera.height, camera.width
    signal = np.zeros((h * w, 3), dtype=np.float32)
    signal[hits["idx"]] = rgb
    mask = np.zeros(h * w, dtype=bool)
    mask[hits["idx"]] = measured
    signal, mask = signal.reshape(h, w, 3), mask.reshape(h, w)
    if spread_px > 0:
        signal[mask] = spread_within(signal, mask, float(spread_px))[mask]
    return signal, mask


def _add_lamp(rgb: NDArray[np.float64], region: NDArray[np.int64], specs: Sequence[str | None],
              normal: NDArray[np.float64], view: NDArray[np.float64], light: NDArray[np.float64],
              irr: NDArray[np.float64], weight: NDArray[np.float64], grid: SpectralGrid) -> None:
    """Add one lamp's direct light to ``rgb`` in place, region by region."""
    ci = np.clip(np.einsum("ij,ij->i", normal, light), 0.0, 1.0)
    co = np.clip(np.einsum("ij,ij->i", normal, view), 1e-6, 1.0)
    half = light + view
    half /= np.maximum(np.linalg.norm(half, axis=1, keepdims=True), 1e-12)
    ch = np.clip(np.einsum("ij,ij->i", normal, half), 0.0, 1.0)
    cd = np.clip(np.einsum("ij,ij->i", half, light), 0.0, 1.0)
    for r, spec in enumerate(specs):
        sel = np.flatnonzero((region == r) & (ci * irr > 0))
        if spec is None or sel.size == 0:
            continue
        try:
            material = get_material(spec)
        except ValueError as exc:
            raise RenderInputError(f"render_signal region {r} spec {spec!r}: {exc}") from None
        f = material_brdf(material, ci[sel], co[sel], ch[sel], cd[sel], grid.wavelengths)
        rgb[sel] += (f @ weight) * (ci[sel] * irr[sel])[:, None]


def pixel_faces(vertices: ArrayLike, triangles: ArrayLike, frame_pose: Any) -> NDArray[np.int64]:
    """The triangle seen through each pixel centre of a posed frame (the rays of :func:`render_signal`).

    Parameters
    ----------
    vertices, triangles
        The mesh in M.
    frame_pose
        The :class:`processing.appearance.frame_poses.FramePose`.

    Returns
    -------
    ndarray
        ``(H, W)`` int64 triangle index, -1 on the backdrop.
    """
    v, t, _, _ = _mesh(vertices, triangles, None, np.zeros(len(np.asarray(triangles)), np.int64), 1)
    camera = CalibratedCamera.from_frame(frame_pose)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(t.astype(np.uint32)))
    hits = _hits(scene, camera)
    out = np.full(camera.height * camera.width, -1, dtype=np.int64)
    out[hits["idx"]] = hits["prim"]
    return out.reshape(camera.height, camera.width)
