"""How much a camera's point spread widens a highlight: the roughness a pinhole fit overstates.

A lens (and its optical low-pass filter, and the demosaic) spreads every point of the image over
``sigma`` photosites.  On a curved surface neighbouring photosites see normals that differ by the
photo pixel's size on the surface (mm) times the surface's curvature (1/mm), so the spread averages
the reflection over normals within about ``s = sigma_px * footprint_mm * curvature_per_mm`` radians
of each other: a Gaussian smear of the normal with that standard deviation along each of the two
axes of the tangent plane.  A Beckmann lobe of RMS slope ``m`` seen through it is close to a
Beckmann lobe with ``m_eff^2 = m^2 + 2 s^2`` (the mean square slopes of independent Gaussian slopes
add, one ``s^2`` per axis), and a fit that models a pinhole recovers ``m_eff``: it overstates the
roughness by ``m_eff - sqrt(m_eff^2 - 2 s^2)``.  On a simulated gold sphere of 8 mm radius photographed
at 0.47 mm per pixel through a spread of one photosite, the fit reads 0.135 against 0.106 through a
pinhole; the formula, from the pinhole's figure, predicts 0.134 (tests/materials/test_lens_smear.py).

:func:`mesh_curvature` estimates the curvature at every vertex of a mesh from its normals;
:func:`roughness_overstatement` gives the overstatement.  The product states it as a systematic part
of a region's roughness uncertainty (docs/materials.md, "The lens's share of the roughness").

References
----------
Beckmann, P., Spizzichino, A. (1963). The scattering of electromagnetic waves from rough surfaces.
Pergamon.

Walter, B., Marschner, S. R., Li, H., Torrance, K. E. (2007). Microfacet models for refraction through
rough surfaces. EGSR 2007. doi:10.2312/EGWR/EGSR07/195-206
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.materials._forward_fit_samples import FitError

__all__ = ["mesh_curvature", "normal_smear_rad", "roughness_overstatement"]


def mesh_curvature(vertices: ArrayLike, triangles: ArrayLike, normals: ArrayLike) -> NDArray[np.float64]:
    """``(V,)`` curvature (1/mm) at every vertex: the mean over its edges of the turn of the normal per mm.

    For a sphere of radius R every edge turns the normal by its length over R, so the figure is 1/R;
    on a cylinder it is the mean over the edges' directions (between 0 and 1/R).

    Parameters
    ----------
    vertices
        ``(V, 3)`` mm.
    triangles
        ``(T, 3)`` indices.
    normals
        ``(V, 3)`` unit vertex normals (smoothed ones for a scanned mesh: a faceted normal field reads
        as curvature).

    Returns
    -------
    ndarray
        ``(V,)``; 0 for a vertex on no edge.

    Raises
    ------
    FitError
        Shapes that do not agree.

    Examples
    --------
    >>> import open3d as o3d
    >>> m = o3d.geometry.TriangleMesh.create_sphere(radius=8.0, resolution=40)
    >>> v = np.asarray(m.vertices)
    >>> k = mesh_curvature(v, np.asarray(m.triangles), v / 8.0)
    >>> bool(abs(np.median(k) - 1 / 8) < 0.002)
    True
    """
    from processing.appearance._surface_features import adjacency

    v = np.asarray(vertices, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or n.shape != v.shape or t.ndim != 2 or t.shape[1] != 3 \
            or (t.size and (t.min() < 0 or t.max() >= len(v))):
        raise FitError(f"vertices {v.shape}, normals {n.shape} and triangles {t.shape} do not agree; give (V, 3), "
                       "(V, 3) and (T, 3) indices below V")
    a = adjacency(t, len(v)).tocoo()
    i, j = a.row, a.col
    turn = np.linalg.norm(n[i] - n[j], axis=1) / np.maximum(np.linalg.norm(v[i] - v[j], axis=1), 1e-12)
    count = np.bincount(i, minlength=len(v))
    return np.bincount(i, weights=turn, minlength=len(v)) / np.maximum(count, 1)


def normal_smear_rad(spread_px: float, footprint_mm: ArrayLike, curvature_per_mm: ArrayLike) -> NDArray[np.float64]:
    """Standard deviation (rad, per axis) of the normals a point spread of ``spread_px`` averages over.

    Parameters
    ----------
    spread_px
        The camera's point spread (Gaussian sigma, photosites), >= 0.
    footprint_mm
        A photo pixel's size on the surface.
    curvature_per_mm
        The surface's curvature there (:func:`mesh_curvature`).

    Returns
    -------
    ndarray
        ``spread_px * footprint_mm * curvature_per_mm``.

    Examples
    --------
    >>> float(normal_smear_rad(1.0, 0.47, 1 / 8))
    0.05875
    """
    if not (np.isfinite(spread_px) and spread_px >= 0):
        raise FitError(f"spread_px must be >= 0 (photosites), got {spread_px!r}")
    return float(spread_px) * np.asarray(footprint_mm, dtype=np.float64) * np.asarray(curvature_per_mm, dtype=np.float64)


def roughness_overstatement(roughness: float, smear_rad: float) -> float:
    """How much a pinhole fit's Beckmann RMS slope ``roughness`` overstates the surface's under a normal smear.

    ``m_eff - sqrt(m_eff^2 - 2 s^2)`` (module docstring); the whole of ``roughness`` when the smear
    alone would explain it.

    Parameters
    ----------
    roughness
        The fitted RMS slope ``m_eff`` (> 0).
    smear_rad
        The normal smear ``s`` (:func:`normal_smear_rad`), >= 0.

    Returns
    -------
    float
        >= 0, at most ``roughness``.

    Examples
    --------
    >>> round(roughness_overstatement(0.135, 0.0586), 4)      # the 8 mm gold sphere of the module docstring
    0.0284
    >>> roughness_overstatement(0.1, 0.0)
    0.0
    """
    m, s = float(roughness), float(smear_rad)
    if not (np.isfinite(m) and m > 0 and np.isfinite(s) and s >= 0):
        raise FitError(f"roughness {roughness!r} / smear {smear_rad!r}: give a roughness > 0 and a smear >= 0")
    return m - float(np.sqrt(max(m * m - 2.0 * s * s, 0.0)))
