"""A draped cloth surface: a sheet with sinusoidal folds, with UVs along warp and weft.

Yasuda et al., section 5: "the shape of the cloth is a simple wrinkle
expressed with trigonometric functions".  The sheet lies in the x-y plane
with folds across the warp (x) fading toward the side edges and a finer
secondary wrinkle; docs/cloth.md, section "Rendering", gives the height
field.  u follows x and v follows y, so :func:`render.tangents.tangents_from_uvs`
gives the warp direction along the surface.

References
----------
.. [1] Yasuda, Yokoi, Toriwaki, Inagaki, "A shading model for cloth
   objects", IEEE Computer Graphics and Applications 12(6), 15-24 (1992),
   doi:10.1109/38.163621.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from processing.errors import InputError

__all__ = ["DrapedCloth", "draped_cloth"]


@dataclass(frozen=True)
class DrapedCloth:
    """Arrays of a draped sheet.

    Attributes
    ----------
    vertices
        ``(V, 3)`` positions.
    triangles
        ``(T, 3)`` vertex indices, counter-clockwise seen from +z.
    normals
        ``(V, 3)`` unit normals (the +z side).
    uvs
        ``(V, 2)``: u along the warp (x), v along the weft (y), in [0, 1].
    """

    vertices: NDArray[np.float64]
    triangles: NDArray[np.int64]
    normals: NDArray[np.float64]
    uvs: NDArray[np.float64]


def draped_cloth(width: float = 4.0, depth: float = 3.0, divisions: int = 96, fold_amplitude: float = 0.25,
                 fold_period: float = 1.3, wrinkle_amplitude: float = 0.012, wrinkle_period: float = 0.45) -> DrapedCloth:
    """A ``width`` x ``depth`` sheet centred at the origin with folds across x.

    Parameters
    ----------
    width, depth
        Extent along x (warp) and y (weft), > 0.
    divisions
        Quads along x (>= 2); along y in proportion.
    fold_amplitude, fold_period, wrinkle_amplitude, wrinkle_period
        A, P, a, p of the height field
        ``z = A sin(2 pi x / P) (0.6 + 0.4 cos(pi y / W)) + a sin(2 pi (x + 0.5 y) / p)``
        with W = ``depth`` (amplitudes >= 0, periods > 0; same length unit as
        width and depth).

    Returns
    -------
    DrapedCloth
        Vertices, counter-clockwise triangles, analytic unit normals and UVs.

    Raises
    ------
    ValueError
        A non-positive size or period, a negative amplitude, or fewer than 2
        divisions.

    Examples
    --------
    >>> c = draped_cloth(divisions=8)
    >>> c.vertices.shape[1], bool(np.allclose(np.linalg.norm(c.normals, axis=1), 1.0)), c.uvs.max()
    (3, True, 1.0)
    """
    for name, value in (("width", width), ("depth", depth), ("fold_period", fold_period),
                        ("wrinkle_period", wrinkle_period)):
        if not (math.isfinite(value) and value > 0):
            raise InputError(f"{name} must be a positive number, got {value!r}")
    for name, value in (("fold_amplitude", fold_amplitude), ("wrinkle_amplitude", wrinkle_amplitude)):
        if not (math.isfinite(value) and value >= 0):
            raise InputError(f"{name} must be a number >= 0, got {value!r}")
    if isinstance(divisions, bool) or not isinstance(divisions, (int, np.integer)) or divisions < 2:
        raise InputError(f"divisions must be an integer >= 2, got {divisions!r}")
    nx = int(divisions) + 1
    ny = max(2, int(round(divisions * depth / width))) + 1
    u = np.linspace(0.0, 1.0, nx)
    v = np.linspace(0.0, 1.0, ny)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    x = (uu - 0.5) * width
    y = (vv - 0.5) * depth
    k, kw = 2 * math.pi / fold_period, 2 * math.pi / wrinkle_period
    fade = 0.6 + 0.4 * np.cos(math.pi * y / depth)
    z = fold_amplitude * np.sin(k * x) * fade + wrinkle_amplitude * np.sin(kw * (x + 0.5 * y))
    dzdx = fold_amplitude * k * np.cos(k * x) * fade + wrinkle_amplitude * kw * np.cos(kw * (x + 0.5 * y))
    dzdy = (fold_amplitude * np.sin(k * x) * (-0.4 * math.pi / depth) * np.sin(math.pi * y / depth)
            + wrinkle_amplitude * kw * 0.5 * np.cos(kw * (x + 0.5 * y)))
    normals = np.stack([-dzdx, -dzdy, np.ones_like(z)], axis=-1).reshape(-1, 3)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    idx = np.arange(nx * ny).reshape(nx, ny)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    tris = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int64)
    verts = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    uvs = np.stack([uu, vv], axis=-1).reshape(-1, 2)
    return DrapedCloth(verts, tris, normals, uvs)
