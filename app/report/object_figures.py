"""Figures of the digitised object in the session report: the material map on the mesh, and the
confidence calibration the session's answers rest on.

:func:`material_views_figure` ray casts the mesh (Open3D) from several directions and colours every
face by its region's material (its sRGB under D65, shaded by the angle to the view so the shape
reads); :func:`reliability_figure` draws the reliability diagram measured by the bench (stated
confidence against observed accuracy) with the session's regions marked on the diagonal.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["material_views_figure", "mesh_views", "reliability_figure", "NOT_MEASURED_RGB"]

#: Colour of faces without a measured material.
NOT_MEASURED_RGB = (150, 150, 150)
_BACKGROUND = (255, 255, 255)


def mesh_views(vertices: np.ndarray, triangles: np.ndarray, face_rgb: np.ndarray, *, views: int = 4,
               size: tuple[int, int] = (260, 260), elevation_deg: float = 20.0) -> list[np.ndarray]:
    """Images ``(H, W, 3) uint8`` of the mesh seen from ``views`` azimuths around its centre.

    Parameters
    ----------
    vertices, triangles
        The mesh.
    face_rgb
        ``(T, 3)`` uint8 colour of every face.
    views
        Number of views, evenly spaced in azimuth.
    size
        ``(width, height)`` of each view in pixels.
    elevation_deg
        Elevation of the viewpoints above the mesh's horizontal plane (z up).

    Returns
    -------
    list of ndarray
        One image per view; faces shaded by ``0.35 + 0.65 |cos|`` of the angle to the view.
    """
    import open3d as o3d

    v = np.asarray(vertices, dtype=np.float32)
    t = np.asarray(triangles, dtype=np.uint32)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(v), o3d.core.Tensor(t))
    lo, hi = v.min(axis=0), v.max(axis=0)
    centre, radius = (lo + hi) / 2, float(np.linalg.norm(hi - lo)) / 2
    w, h = size
    out = []
    for k in range(views):
        az, el = 2 * np.pi * k / views, np.radians(elevation_deg)
        eye = centre + 3.2 * radius * np.array([np.cos(az) * np.cos(el), np.sin(az) * np.cos(el), np.sin(el)])
        rays = o3d.t.geometry.RaycastingScene.create_rays_pinhole(
            fov_deg=40.0, center=o3d.core.Tensor(centre.astype(np.float32)),
            eye=o3d.core.Tensor(eye.astype(np.float32)), up=o3d.core.Tensor(np.float32([0, 0, 1])),
            width_px=w, height_px=h)
        ans = scene.cast_rays(rays)
        hit = np.isfinite(ans["t_hit"].numpy())
        prim = np.where(hit, ans["primitive_ids"].numpy(), 0).astype(np.int64)
        normal = ans["primitive_normals"].numpy()
        d = rays.numpy()[..., 3:]
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        shade = 0.35 + 0.65 * np.abs(np.einsum("hwk,hwk->hw", normal, d))
        img = np.asarray(face_rgb, dtype=np.float64)[prim] * shade[..., None]
        img[~hit] = _BACKGROUND
        out.append(np.ascontiguousarray(np.clip(img, 0, 255).astype(np.uint8)[::-1, ::-1]))   # Open3D: rotated by 180 deg
    return out


def material_views_figure(vertices: np.ndarray, triangles: np.ndarray, face_region: np.ndarray,
                          regions: Sequence[dict[str, Any]], colours: Sequence[tuple[int, int, int]],
                          labels: Sequence[str] | None = None) -> bytes:
    """The material map on the mesh from four sides, with a legend (PNG bytes).

    Parameters
    ----------
    vertices, triangles
        The mesh.
    face_region
        ``(T,)`` region index per face (-1: not measured).
    regions
        The regions (``index``, ``material``, ``confidence``, ``area_mm2``), in index order.
    colours
        sRGB of each region on the map.
    labels
        Legend text of each region (default: index, material, confidence and area).

    Returns
    -------
    bytes
        The PNG.
    """
    from app.report.figures import _plt, png_of

    fr = np.asarray(face_region, dtype=np.int64)
    table = np.array(list(colours) + [NOT_MEASURED_RGB], dtype=np.uint8)
    face_rgb = table[np.where(fr >= 0, fr, len(colours))]
    images = mesh_views(vertices, triangles, face_rgb)
    plt = _plt()
    if labels is None:
        labels = [f"{r['index']}: {r['material']} ({r['confidence']:.2f}), {r['area_mm2']:.0f} mm²" for r in regions]
    rows = [(np.array(c) / 255.0, text) for text, c in zip(labels, colours)]
    if np.any(fr < 0):
        rows.append((np.array(NOT_MEASURED_RGB) / 255.0, "not measured"))
    ncol = 1 if len(rows) <= 4 else 2
    legend_in = 0.3 * math.ceil(len(rows) / ncol) + 0.2
    fig = plt.figure(figsize=(2.4 * len(images), 2.5 + legend_in), constrained_layout=True)
    grid = fig.add_gridspec(2, len(images), height_ratios=[2.5, legend_in])
    for i, img in enumerate(images):
        ax = fig.add_subplot(grid[0, i])
        ax.imshow(img)
        ax.set_title(f"view {i + 1}", fontsize=10)
        ax.axis("off")
    legend = fig.add_subplot(grid[1, :])
    legend.axis("off")
    handles = [plt.Rectangle((0, 0), 1, 1, facecolor=c, edgecolor="#666666") for c, _ in rows]
    legend.legend(handles, [t for _, t in rows], loc="upper left", ncol=ncol, fontsize=10, frameon=False,
                  handlelength=1.6, borderaxespad=0.0)
    return png_of(fig)


def reliability_figure(table: dict[str, Any], session: Sequence[tuple[str, float]] = ()) -> bytes:
    """The reliability diagram measured by the bench, with the session's answers marked (PNG bytes).

    Parameters
    ----------
    table
        ``stated``, ``observed``, ``count`` per bin (lists), ``ece`` and ``source`` (what was simulated).
    session
        ``(label, confidence)`` of the session's answers, drawn as ticks on the stated-confidence axis.

    Returns
    -------
    bytes
        The PNG.
    """
    from app.report.figures import _plt, png_of

    plt = _plt()
    fig, ax = plt.subplots(figsize=(4.6, 3.6), constrained_layout=True)
    stated = np.array(table["stated"], dtype=np.float64)
    observed = np.array(table["observed"], dtype=np.float64)
    count = np.array(table["count"], dtype=np.float64)
    ok = np.isfinite(stated) & np.isfinite(observed) & (count > 0)
    ax.plot([0, 1], [0, 1], color="#888888", lw=1, ls="--", label="perfect calibration")
    ax.plot(stated[ok], observed[ok], "o-", color="#2c6fbb", label=f"measured (ECE {table['ece']:.3f})")
    for s, o, n in zip(stated[ok], observed[ok], count[ok]):
        ax.annotate(f"{int(n)}", (s, o), textcoords="offset points", xytext=(4, -10), fontsize=7, color="#2c6fbb")
    for label, c in session:
        ax.axvline(c, color="#c0392b", lw=0.8, alpha=0.7)
        ax.text(c, 0.02, label, rotation=90, fontsize=7, color="#c0392b", ha="right", va="bottom")
    ax.set_xlim(0, 1.02)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("stated confidence")
    ax.set_ylabel("observed share right")
    ax.set_title("confidence calibration (bench)", fontsize=10)
    ax.legend(fontsize=7, loc="upper left")
    return png_of(fig)
