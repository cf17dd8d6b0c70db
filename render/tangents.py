"""Tangent frames for anisotropic materials: the yarn direction on a surface.

An anisotropic lobe (the yarn ellipsoid of Yasuda et al., eq. (1)) needs a
unit tangent t at every shading point, the direction the warp runs; the
weft runs along b = n x t.  Three sources, all per vertex (the renderer
interpolates them like the normals and makes them orthogonal to the shading
normal):

* :func:`tangents_from_uvs`: the direction of increasing u of a texture
  parameterisation, per triangle from the edge vectors and their UV
  differences (Lengyel, "Mathematics for 3D Game Programming and Computer
  Graphics", 3rd ed., section 7.8.3), summed over the triangles of a vertex;
* :func:`tangents_from_field`: a given per-vertex direction field projected
  onto each tangent plane;
* :func:`tangents_from_direction`: one global direction projected onto each
  tangent plane (a cloth draped along x keeps its warp along x), falling
  back to a second direction where the first is nearly normal to the
  surface.

:func:`rotate_tangents` turns the frames about the normals by the weave
angle (0 vs 45 degrees in Yasuda et al., Fig. 16).

References
----------
Yasuda, T., Yokoi, S., Toriwaki, J., Inagaki, K. (1992), "A shading model
for cloth objects", IEEE CG&A 12(6), 15-24, doi:10.1109/38.163621.
Lengyel, E. (2012), "Mathematics for 3D Game Programming and Computer
Graphics", 3rd ed., Course Technology (a book, no DOI).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from render.errors import RenderInputError

__all__ = [
    "DEFAULT_WARP_DIRECTION",
    "tangents_from_direction",
    "tangents_from_field",
    "tangents_from_uvs",
    "rotate_tangents",
]

#: Warp direction used when an object with an anisotropic material gives none.
DEFAULT_WARP_DIRECTION = (1.0, 0.0, 0.0)

_PARALLEL = 1e-3      # |t projected| below this: the direction is (nearly) normal to the surface


def _unit_rows(v: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    norm = np.linalg.norm(v, axis=1)
    return v / np.where(norm > 0, norm, 1.0)[:, None], norm


def _project(normals: NDArray[np.float64], d: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``d - (d.n) n`` normalised, and the length before normalising."""
    p = d - np.sum(d * normals, axis=1, keepdims=True) * normals
    return _unit_rows(p)


def _checked_normals(normals: ArrayLike) -> NDArray[np.float64]:
    n = np.asarray(normals, dtype=np.float64)
    if n.ndim != 2 or n.shape[1] != 3 or not np.all(np.isfinite(n)):
        raise RenderInputError(f"normals must be a finite (V, 3) array, got shape {n.shape}")
    return _unit_rows(n)[0]


def tangents_from_direction(normals: ArrayLike, direction: ArrayLike = DEFAULT_WARP_DIRECTION,
                            fallback: ArrayLike | None = None) -> NDArray[np.float64]:
    """Unit tangents ``(V, 3)``: ``direction`` projected onto each vertex's tangent plane.

    Where ``direction`` is within about 0.06 degrees of the normal the
    ``fallback`` (default: the coordinate axis least aligned with
    ``direction``) is projected instead.

    Parameters
    ----------
    normals
        ``(V, 3)`` vertex normals (normalised here).
    direction
        The warp direction, a non-zero 3-vector.
    fallback
        The direction used where ``direction`` is along the normal.

    Returns
    -------
    ndarray
        float64 ``(V, 3)`` unit tangents.

    Raises
    ------
    RenderInputError
        Bad normals or a zero or non-finite direction.

    Examples
    --------
    >>> tangents_from_direction([[0, 0, 1], [0, -1, 1]], (1, 0, 0)).round(6).tolist()
    [[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]
    >>> tangents_from_direction([[1, 0, 0]], (1, 0, 0)).round(6).tolist()
    [[0.0, 1.0, 0.0]]
    """
    n = _checked_normals(normals)
    d = np.asarray(direction, dtype=np.float64).reshape(-1)
    if d.shape != (3,) or not np.all(np.isfinite(d)) or not np.any(d):
        raise RenderInputError(f"the warp direction must be a non-zero finite 3-vector, got {direction!r}")
    d = d / np.linalg.norm(d)
    if fallback is None:
        fb = np.zeros(3)
        fb[int(np.argmin(np.abs(d)))] = 1.0
    else:
        fb = np.asarray(fallback, dtype=np.float64).reshape(3)
    t, length = _project(n, np.broadcast_to(d, n.shape))
    bad = length < _PARALLEL
    if np.any(bad):
        t[bad] = _project(n[bad], np.broadcast_to(fb, (int(bad.sum()), 3)))[0]
    return t


def tangents_from_field(normals: ArrayLike, field: ArrayLike) -> NDArray[np.float64]:
    """Unit tangents ``(V, 3)`` from a per-vertex direction field projected onto the tangent planes.

    Vertices whose field vector is zero or normal to the surface get the
    projected global :data:`DEFAULT_WARP_DIRECTION`.

    Parameters
    ----------
    normals
        ``(V, 3)`` vertex normals (normalised here).
    field
        ``(V, 3)`` directions, any length.

    Returns
    -------
    ndarray
        float64 ``(V, 3)`` unit tangents.

    Raises
    ------
    RenderInputError
        Bad normals, or a field of another shape or with non-finite values.

    Examples
    --------
    >>> tangents_from_field([[0, 0, 1], [0, 0, 1]], [[0, 2, 1], [0, 0, 3]]).round(6).tolist()
    [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]
    """
    n = _checked_normals(normals)
    f = np.asarray(field, dtype=np.float64)
    if f.shape != n.shape or not np.all(np.isfinite(f)):
        raise RenderInputError(
            f"the tangent field must be a finite (V, 3) array like the normals {n.shape}, got shape {f.shape}"
        )
    t, length = _project(n, f)
    bad = length < _PARALLEL * np.maximum(np.linalg.norm(f, axis=1), 1e-300)
    bad |= length == 0
    if np.any(bad):
        t[bad] = tangents_from_direction(n[bad])
    return t


def tangents_from_uvs(vertices: ArrayLike, triangles: ArrayLike, uvs: ArrayLike,
                      normals: ArrayLike) -> NDArray[np.float64]:
    """Unit tangents ``(V, 3)`` along increasing u of per-vertex texture coordinates.

    Per triangle, ``dP/du`` from the edges e1, e2 and their UV differences
    (Lengyel 2012, eq. 7.35), weighted by the triangle's area in UV space
    (through the unnormalised solution), summed per vertex and projected
    onto the vertex's tangent plane.  Vertices without a usable UV gradient
    get the projected global :data:`DEFAULT_WARP_DIRECTION`.

    Parameters
    ----------
    vertices
        ``(V, 3)`` positions.
    triangles
        ``(T, 3)`` vertex indices.
    uvs
        ``(V, 2)`` texture coordinates.
    normals
        ``(V, 3)`` vertex normals.

    Returns
    -------
    ndarray
        float64 ``(V, 3)`` unit tangents.

    Raises
    ------
    RenderInputError
        Arrays of mismatched shapes or with non-finite values.

    Examples
    --------
    A square in the x-y plane whose u runs along y:

    >>> v = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]
    >>> uv = [[0, 0], [0, 1], [1, 1], [1, 0]]
    >>> tangents_from_uvs(v, [[0, 1, 2], [0, 2, 3]], uv, [[0, 0, 1]] * 4).round(6).tolist()[0]
    [0.0, 1.0, 0.0]
    """
    v = np.asarray(vertices, dtype=np.float64)
    tri = np.asarray(triangles, dtype=np.int64)
    uv = np.asarray(uvs, dtype=np.float64)
    n = _checked_normals(normals)
    if uv.shape != (v.shape[0], 2) or not np.all(np.isfinite(uv)):
        raise RenderInputError(f"uvs must be a finite (V, 2) array for {v.shape[0]} vertices, got shape {uv.shape}")
    if n.shape != v.shape:
        raise RenderInputError(f"normals {n.shape} and vertices {v.shape} must have the same shape")
    e1 = v[tri[:, 1]] - v[tri[:, 0]]
    e2 = v[tri[:, 2]] - v[tri[:, 0]]
    d1 = uv[tri[:, 1]] - uv[tri[:, 0]]
    d2 = uv[tri[:, 2]] - uv[tri[:, 0]]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    # dP/du * det = e1 dv2 - e2 dv1; the sign of det keeps mirrored UV islands pointing along +u
    tu = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) * np.sign(det)[:, None]
    acc = np.zeros_like(v)
    for c in range(3):
        np.add.at(acc, tri[:, c], tu)
    return tangents_from_field(n, acc)


def rotate_tangents(tangents: ArrayLike, normals: ArrayLike, angle_deg: float) -> NDArray[np.float64]:
    """Tangents turned about the normals by ``angle_deg`` (toward b = n x t).

    Parameters
    ----------
    tangents
        ``(V, 3)`` unit tangents orthogonal to the normals.
    normals
        ``(V, 3)`` vertex normals (normalised here).
    angle_deg
        The weave angle in degrees.

    Returns
    -------
    ndarray
        float64 ``(V, 3)``.

    Raises
    ------
    RenderInputError
        A non-finite angle or bad normals.

    Examples
    --------
    >>> rotate_tangents([[1, 0, 0]], [[0, 0, 1]], 90).round(6).tolist()
    [[0.0, 1.0, 0.0]]
    """
    a = float(angle_deg)
    if not math.isfinite(a):
        raise RenderInputError(f"the weave angle must be a finite number of degrees, got {angle_deg!r}")
    t = np.asarray(tangents, dtype=np.float64)
    n = _checked_normals(normals)
    b = np.cross(n, t)
    r = math.radians(a)
    return math.cos(r) * t + math.sin(r) * b
