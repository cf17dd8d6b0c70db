"""Vertex normals for shading a scanned mesh: smoothed at the scale the reconstruction resolves.

A mesh extracted from an implicit surface (screened Poisson on an octree, then an iso-surface)
carries no detail finer than about two octree cells, yet the facets of the extraction tilt its
vertex normals at the cell scale.  A highlight moves by twice a normal's error, so those tilts,
a few degrees, move a metal's highlights by more than their width and spoil a material fit at
the observations' angles.  :func:`smoothed_normals` diffuses the normals over the mesh's edges
(each step averages a vertex with its neighbours, then renormalises) until the spread equals a
Gaussian of standard deviation ``sigma_mm``; with ``sigma_mm`` two cells, detail the scan resolved
stays and the extraction's facets go.  docs/materials.md ("Normals for shading") gives the
measured effect on the demo hawk (median error against the simulated object 2.6 -> 0.8 deg).

References
----------
Taubin, G. (1995). A signal processing approach to fair surface design. Proceedings of SIGGRAPH
95, 351-358. doi:10.1145/218380.218473

Kazhdan, M., Hoppe, H. (2013). Screened Poisson surface reconstruction. ACM Transactions on
Graphics 32(3), 29. doi:10.1145/2487228.2487237
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.appearance._surface_features import adjacency
from processing.appearance.frame_poses import AppearanceError

__all__ = ["smoothed_normals", "diffusion_steps", "SMOOTHING_CELLS", "MAX_STEPS"]

#: Standard deviation of the smoothing, in octree cells of the reconstruction.
SMOOTHING_CELLS = 2.0
#: Most diffusion steps (a sigma far above the edge length is refused rather than run for minutes).
MAX_STEPS = 400


def _checked(vertices: ArrayLike, triangles: ArrayLike, normals: ArrayLike
             ) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]]:
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    n = np.asarray(normals, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or n.shape != v.shape:
        raise AppearanceError(f"normals: vertices and normals must both be (V, 3), got {v.shape} and {n.shape}")
    if t.ndim != 2 or t.shape[1] != 3 or (t.size and (t.min() < 0 or t.max() >= len(v))):
        raise AppearanceError(f"normals: triangles must be (T, 3) indices into {len(v)} vertices")
    if not (np.isfinite(v).all() and np.isfinite(n).all()):
        raise AppearanceError("normals: the mesh holds NaN or infinite vertices or normals; rebuild it")
    return v, t, n


def diffusion_steps(vertices: ArrayLike, triangles: ArrayLike, sigma_mm: float) -> int:
    """Steps of one-ring averaging whose spread is a Gaussian of ``sigma_mm`` on this mesh.

    One step (a vertex and its ``d`` neighbours, equal weights) adds a variance of
    ``d / (d + 1) * mean(e^2) / 2`` along each surface direction (``e`` the edge lengths); the
    steps add up.

    Parameters
    ----------
    vertices, triangles
        The mesh (mm).
    sigma_mm
        Target standard deviation (mm), >= 0.

    Returns
    -------
    int
        Steps (0 for ``sigma_mm = 0``).

    Examples
    --------
    >>> import numpy as np
    >>> x, y = np.meshgrid(np.arange(21.0), np.arange(21.0))
    >>> v = np.stack([x.ravel(), y.ravel(), 0 * x.ravel()], axis=1)
    >>> q = (np.arange(20)[:, None] * 21 + np.arange(20)[None, :]).ravel()
    >>> t = np.concatenate([np.stack([q, q + 1, q + 22], 1), np.stack([q, q + 22, q + 21], 1)])
    >>> diffusion_steps(v, t, 3.0)      # 6 neighbours, mean e^2 = 4/3: 9 / (6/7 * 2/3) = 15.75
    16
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    if not (math.isfinite(sigma_mm) and sigma_mm >= 0):
        raise AppearanceError(f"normals: the smoothing scale must be >= 0 mm, got {sigma_mm!r}")
    if sigma_mm == 0 or len(t) == 0:
        return 0
    a = adjacency(t, len(v), v)
    deg = np.diff(a.indptr)
    mean_e2 = np.asarray(a.multiply(a).sum(axis=1)).ravel() / np.maximum(deg, 1)
    used = deg > 0
    per_step = float(np.mean(deg[used] / (deg[used] + 1.0) * mean_e2[used] / 2.0))
    steps = int(round(sigma_mm ** 2 / per_step))
    if steps > MAX_STEPS:
        raise AppearanceError(f"normals: smoothing by {sigma_mm:g} mm takes {steps} steps on edges of "
                              f"{math.sqrt(2 * per_step):.3g} mm; give a scale below {math.sqrt(MAX_STEPS * per_step):.3g} mm")
    return steps


def smoothed_normals(vertices: ArrayLike, triangles: ArrayLike, normals: ArrayLike,
                     sigma_mm: float) -> NDArray[np.float64]:
    """Unit vertex normals diffused over the mesh to a Gaussian spread of ``sigma_mm``.

    Parameters
    ----------
    vertices, triangles
        The mesh (mm).
    normals
        ``(V, 3)`` its vertex normals.
    sigma_mm
        Standard deviation of the smoothing (mm); 0 returns the normals (unit length).

    Returns
    -------
    ndarray
        ``(V, 3)`` unit normals (a vertex whose neighbourhood cancels keeps its own normal).

    Raises
    ------
    AppearanceError
        Shapes that do not match, NaN / infinite values, a negative or excessive scale.

    Examples
    --------
    A plane whose normals were tilted at random by about 5 deg comes back within a degree of +z:

    >>> import numpy as np
    >>> x, y = np.meshgrid(np.arange(21.0), np.arange(21.0))
    >>> v = np.stack([x.ravel(), y.ravel(), 0 * x.ravel()], axis=1)
    >>> q = (np.arange(20)[:, None] * 21 + np.arange(20)[None, :]).ravel()
    >>> t = np.concatenate([np.stack([q, q + 1, q + 22], 1), np.stack([q, q + 22, q + 21], 1)])
    >>> rng = np.random.default_rng(0)
    >>> n = np.array([0.0, 0.0, 1.0]) + np.c_[rng.normal(0, 0.06, (len(v), 2)), np.zeros(len(v))]
    >>> tilt = lambda m: np.degrees(np.arccos(np.clip(m[:, 2] / np.linalg.norm(m, axis=1), -1, 1)))
    >>> bool(np.median(tilt(n)) > 3.0), bool(np.median(tilt(smoothed_normals(v, t, n, 3.0))) < 1.0)
    (True, True)
    """
    v, t, n = _checked(vertices, triangles, normals)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    if (length == 0).any():
        raise AppearanceError(f"normals: {int((length == 0).sum())} vertex normals are zero; rebuild the mesh")
    n = n / length
    steps = diffusion_steps(v, t, sigma_mm)
    if steps == 0:
        return n
    a = adjacency(t, len(v))
    m = n
    for _ in range(steps):
        s = m + a @ m
        norm = np.linalg.norm(s, axis=1, keepdims=True)
        m = np.where(norm > 1e-12, s / np.maximum(norm, 1e-300), m)
    return m
