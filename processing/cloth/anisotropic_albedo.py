"""Directional albedo of anisotropic (yarn-ellipsoid) lobes and of cloth materials.

    a(omega_o, lambda) = integral f(omega_i, omega_o, lambda) cos(theta_i) d omega_i

For an anisotropic lobe it depends on the azimuth of the view relative to
the yarn as well as on its elevation.  The quadrature runs over the half
vector in the scaled slopes of the ellipsoid distribution, where its
measure is uniform, so it resolves the lobe at any axes (1e-4 to 1e2);
docs/cloth.md, section "Albedo of an anisotropic lobe", gives it.

References
----------
.. [1] Heitz, "Understanding the masking-shadowing function in
   microfacet-based BRDFs", Journal of Computer Graphics Techniques 3(2),
   48-107 (2014), section 5.
.. [2] Pharr, Jakob, Humphreys, "Physically Based Rendering", 3rd ed.,
   section 14.1 (book, no DOI).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.cloth.anisotropic_microfacet import ellipsoid_ndf
from processing.errors import InputError
from processing.materials.lobes import Lobe, Material, lobe_geometry

__all__ = ["anisotropic_lobe_albedo", "material_albedo", "azimuth_mean_albedo"]

_TABLE_NODES = 2049


def _nodes(n_q: int, n_phi: int) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Gauss-Legendre nodes and weights in q on [0, 1) and midpoint azimuths on [0, 2 pi)."""
    x, w = np.polynomial.legendre.leggauss(n_q)
    q = 0.5 * (x + 1.0)
    wq = 0.5 * w
    phi = (np.arange(n_phi) + 0.5) * (2.0 * math.pi / n_phi)
    return q, wq, phi


def _lobe_cd_weights(lobe: Lobe, wo: NDArray[np.float64], n_q: int, n_phi: int) -> NDArray[np.float64]:
    """Per view direction, the quadrature weights binned on the cos_d table: ``(N, _TABLE_NODES)``.

    The albedo is ``weights @ S(table nodes, lambda)``.
    """
    q, wq, phi = _nodes(n_q, n_phi)
    r = np.sqrt(q / (1.0 - q))
    u = (r[:, None] * np.cos(phi)[None, :]).ravel()
    v = (r[:, None] * np.sin(phi)[None, :]).ravel()
    wgt = np.repeat(wq, n_phi) / n_phi            # dq dphi / (2 pi) with the 2 pi / n_phi midpoint rule
    h = np.stack([-lobe.roughness * u, -lobe.roughness_b * v, np.ones_like(u)])
    h /= np.linalg.norm(h, axis=0)
    n = wo.shape[0]
    od = wo @ h                                                   # (N, M): o . h
    wi = 2.0 * od[None, :, :] * h[:, None, :] - wo.T[:, :, None]  # (3, N, M)
    ci = wi[2]
    co = np.broadcast_to(wo[:, 2:3], od.shape)
    ch = np.broadcast_to(h[2][None, :], od.shape)
    ok = (od > 0) & (ci > 0) & (co > 0)
    rows, cols = np.nonzero(ok)
    out = np.zeros((n, _TABLE_NODES))
    if rows.size == 0:
        return out
    cd = od[rows, cols]
    cir, chr_ = ci[rows, cols], ch[rows, cols]
    # through lobe_geometry, so the integrand is what the renderers evaluate:
    # f ci d omega_i = f ci 4 (o.h) / (D cos_h) dP, with dP = D cos_h d omega_h the measure of the nodes
    f = lobe_geometry(lobe, cir, wo[rows, 2], chr_, cd,
                      (wi[0][rows, cols], wi[1][rows, cols], wo[rows, 0], wo[rows, 1]))
    d = ellipsoid_ndf(h[0, cols], h[1, cols], chr_, lobe.roughness, lobe.roughness_b)
    with np.errstate(divide="ignore", invalid="ignore"):
        val = f * cir * 4.0 * cd / (d * chr_)
    val = np.where(np.isfinite(val), val, 0.0) * wgt[cols]
    x = np.clip(cd, 0.0, 1.0) * (_TABLE_NODES - 1)
    lo = np.minimum(x.astype(np.intp), _TABLE_NODES - 2)
    frac = x - lo
    base = rows * _TABLE_NODES
    flat = np.bincount(base + lo, val * (1.0 - frac), n * _TABLE_NODES)
    flat += np.bincount(base + lo + 1, val * frac, n * _TABLE_NODES)
    out = flat.reshape(n, _TABLE_NODES)
    return out


def _directions(cos_o: ArrayLike, phi_o: ArrayLike) -> NDArray[np.float64]:
    """``(N, 3)`` unit view directions in the frame (t, b, n) from their elevation cosines and azimuths."""
    c = np.asarray(cos_o, dtype=np.float64).reshape(-1)
    p = np.broadcast_to(np.asarray(phi_o, dtype=np.float64).reshape(-1), c.shape) if np.ndim(phi_o) else np.full(
        c.shape, float(phi_o))
    if np.any(~np.isfinite(c)) or np.any(c < 0) or np.any(c > 1):
        raise InputError("cos_o must be finite and in [0, 1]")
    if np.any(~np.isfinite(p)):
        raise InputError("phi_o must be finite (radians from the tangent t)")
    s = np.sqrt(1.0 - c * c)
    return np.stack([s * np.cos(p), s * np.sin(p), c], axis=1)


def anisotropic_lobe_albedo(
    lobe: Lobe, cos_o: ArrayLike, phi_o: ArrayLike, wavelengths: ArrayLike, *, n_q: int = 64, n_phi: int = 96
) -> NDArray[np.float64]:
    """Directional albedo ``(N, L)`` of one anisotropic lobe, without its weight.

    Parameters
    ----------
    lobe
        A lobe of kind ``"anisotropic"``.
    cos_o
        Cosines of the view elevation, in [0, 1].
    phi_o
        View azimuth from the tangent t (radians), scalar or one per cos_o.
    wavelengths
        Wavelengths in nm, L of them.
    n_q, n_phi
        Quadrature nodes (>= 4).

    Returns
    -------
    ndarray
        ``(N, L)``: the fraction of incident energy the lobe reflects (its
        weight not applied).

    Raises
    ------
    ValueError
        A lobe that is not anisotropic, node counts below 4, ``cos_o``
        outside [0, 1] or a non-finite ``phi_o``.

    Examples
    --------
    >>> from processing.materials.dielectric_model import PigmentReflectance
    >>> white = PigmentReflectance([400, 700], [1.0, 1.0])
    >>> a = anisotropic_lobe_albedo(Lobe("anisotropic", 1.0, white, 0.01, roughness_b=0.01), [1.0], 0.0, [550.0])
    >>> round(float(a[0, 0]), 3)      # a near-mirror reflects everything at normal incidence
    1.0
    """
    if lobe.kind != "anisotropic":
        raise InputError(f"anisotropic_lobe_albedo needs an anisotropic lobe, got kind {lobe.kind!r}")
    for name, value in (("n_q", n_q), ("n_phi", n_phi)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 4:
            raise InputError(f"{name} must be an integer >= 4, got {value!r}")
    wl = np.asarray(wavelengths, dtype=np.float64).reshape(-1)
    weights = _lobe_cd_weights(lobe, _directions(cos_o, phi_o), n_q, n_phi)
    table = np.asarray(lobe.spectral.reflectance(np.linspace(0.0, 1.0, _TABLE_NODES), wl), dtype=np.float64)
    return weights @ table.reshape(_TABLE_NODES, wl.size)


def material_albedo(
    material: Material, cos_o: ArrayLike, phi_o: ArrayLike, wavelengths: ArrayLike, *, n_q: int = 64,
    n_phi: int = 96
) -> NDArray[np.float64]:
    """Directional albedo of a material of Lambert and anisotropic lobes (weights included).

    Isotropic microfacet lobes, if any, go through
    :func:`processing.materials.albedo.directional_albedo`.

    Parameters
    ----------
    material
        The material (a cloth, typically).
    cos_o
        Cosines of the view elevation, in [0, 1], N of them.
    phi_o
        View azimuth from the tangent t (radians), scalar or one per cos_o.
    wavelengths
        Wavelengths in nm, L of them.
    n_q, n_phi
        Quadrature nodes of the anisotropic lobes (>= 4).

    Returns
    -------
    ndarray
        ``(N, L)``: the fraction of incident energy reflected (<= 1 for an
        energy-conserving material).

    Raises
    ------
    ValueError
        Bad directions or node counts, as for :func:`anisotropic_lobe_albedo`.

    Examples
    --------
    >>> from processing.cloth.model import Dye, Yarn, cloth_material
    >>> clear = Dye(np.array([400.0, 700.0]), np.zeros(2))
    >>> m = cloth_material("white", Yarn("spun", 0.3, 0.5, clear), Yarn("spun", 0.3, 0.5, clear),
    ...                    specular=0.0, internal=0.0, diffuse=1.0)
    >>> material_albedo(m, [0.5], 0.0, [500.0]).round(9).tolist()
    [[1.0]]
    """
    wl = np.asarray(wavelengths, dtype=np.float64).reshape(-1)
    dirs = _directions(cos_o, phi_o)
    total = np.zeros((dirs.shape[0], wl.size))
    for lobe in material.lobes:
        if lobe.weight == 0.0:
            continue
        if lobe.kind == "lambert":
            s = np.asarray(lobe.spectral.reflectance(np.array([1.0]), wl), dtype=np.float64).reshape(1, -1)
            total += lobe.weight * np.where(dirs[:, 2:3] > 0, 1.0, 0.0) * s
        elif lobe.kind == "anisotropic":
            total += lobe.weight * anisotropic_lobe_albedo(lobe, dirs[:, 2], np.arctan2(dirs[:, 1], dirs[:, 0]),
                                                           wl, n_q=n_q, n_phi=n_phi)
        else:
            from processing.materials.albedo import directional_albedo

            total += lobe.weight * np.asarray(directional_albedo(lobe, dirs[:, 2], wl)).reshape(-1, wl.size)
    return total


def azimuth_mean_albedo(lobe: Lobe, cos_o: ArrayLike, wavelengths: ArrayLike, *, n_azimuth: int = 4,
                        n_q: int = 16, n_phi: int = 24) -> NDArray[np.float64]:
    """Albedo of an anisotropic lobe averaged over the view azimuth (without its weight).

    Used for sky light, which the renderer tabulates over cos_o only.  The
    azimuths are spread over [0, pi/2) (the lobe is symmetric about t and b).
    The default nodes agree with 16 azimuths and 64 x 96 nodes to 1e-3 of
    the white for the silk preset (most at grazing view).

    Parameters
    ----------
    lobe
        A lobe of kind ``"anisotropic"``.
    cos_o
        Cosines of the view elevation, in [0, 1], N of them.
    wavelengths
        Wavelengths in nm, L of them.
    n_azimuth
        View azimuths averaged.
    n_q, n_phi
        Quadrature nodes (>= 4).

    Returns
    -------
    ndarray
        ``(N, L)``.

    Raises
    ------
    ValueError
        As :func:`anisotropic_lobe_albedo`.

    Examples
    --------
    >>> from processing.materials.dielectric_model import PigmentReflectance
    >>> white = PigmentReflectance([400, 700], [1.0, 1.0])
    >>> a = azimuth_mean_albedo(Lobe("anisotropic", 1.0, white, 0.05, roughness_b=0.5), [0.0, 1.0], [550.0])
    >>> float(a[0, 0]), bool(0.8 < a[1, 0] <= 1.0)
    (0.0, True)
    """
    c = np.asarray(cos_o, dtype=np.float64).reshape(-1)
    phis = (np.arange(n_azimuth) + 0.5) * (0.5 * math.pi / n_azimuth)
    cc = np.repeat(c, n_azimuth)
    pp = np.tile(phis, c.size)
    a = anisotropic_lobe_albedo(lobe, cc, pp, wavelengths, n_q=n_q, n_phi=n_phi)
    return a.reshape(c.size, n_azimuth, -1).mean(axis=1)
