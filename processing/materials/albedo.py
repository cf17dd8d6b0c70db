"""Directional albedo of a material: the hemispherical integral of BRDF * cos_i.

    a(omega_o, lambda) = integral f(omega_i, omega_o, lambda) cos(theta_i) d omega_i

Energy conservation requires a <= 1 at every viewing direction; the
renderer also uses a(cos_o) for sky lighting tables.  Lambert lobes are
integrated over the incident hemisphere, microfacet lobes over the half
vector (so the narrow peak of D is resolved at any roughness);
docs/materials.md, section "Directional albedo", gives the quadrature.

References
----------
.. [1] Pharr, Jakob, Humphreys, "Physically Based Rendering", 3rd ed.,
   section 14.1 (book, no DOI).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.errors import InputError
from processing.materials.lobes import Lobe, Material, lobe_geometry

__all__ = ["directional_albedo", "lobe_albedo"]

_S_MAX = 6.5
_CHUNK_ELEMENTS = 1_500_000
# Angle-dependent spectral factors (Fresnel terms) are evaluated once on this
# many nodes in cos_d and linearly interpolated: each quadrature node's weight
# is split between its two table neighbours, so the cost no longer scales with
# (quadrature nodes x wavelengths) complex Fresnel evaluations.  With 4097
# nodes the interpolation error of a Fresnel curve is below 1e-6.
_SPECTRAL_TABLE_NODES = 4097


def _check_counts(n_theta: int, n_phi: int) -> None:
    for name, value in (("n_theta", n_theta), ("n_phi", n_phi)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 4:
            raise InputError(f"{name} must be an integer >= 4, got {value!r}")


def _geometry_nodes(
    lobe: Lobe, cos_o: NDArray[np.float64], n_theta: int, n_phi: int
) -> tuple[NDArray[np.float64], ...]:
    """cos_i, cos_h, cos_d and quadrature weights for a batch of cos_o.

    Shapes ``(N, T, P)``; the weights include the Jacobian so that the
    albedo is ``sum(weights * f)`` with f the BRDF (without cos_i).
    """
    x, wx = np.polynomial.legendre.leggauss(n_theta)
    phi = (np.arange(n_phi) + 0.5) * (np.pi / n_phi)
    w_phi = 2.0 * np.pi / n_phi  # [0, pi] doubled by symmetry
    sin_o = np.sqrt(np.clip(1.0 - cos_o * cos_o, 0.0, 1.0))[:, None, None]
    co = cos_o[:, None, None]
    cphi, sphi = np.cos(phi)[None, None, :], np.sin(phi)[None, None, :]
    if lobe.kind == "lambert":
        return _incident_nodes(x, wx, w_phi, sin_o, co, cphi, sphi)
    return _half_vector_nodes(lobe.roughness, x, wx, w_phi, sin_o, co, cphi)


def _incident_nodes(
    x: NDArray[np.float64], wx: NDArray[np.float64], w_phi: float, sin_o: NDArray[np.float64],
    co: NDArray[np.float64], cphi: NDArray[np.float64], sphi: NDArray[np.float64],
) -> tuple[NDArray[np.float64], ...]:
    """Nodes of a Lambert lobe: Gauss-Legendre in u = cos^2(theta_i), midpoint rule in phi."""
    u = 0.5 * (x + 1.0)  # u = cos^2(theta_i) in [0, 1]
    wu = 0.5 * wx
    ci = np.sqrt(u)[None, :, None]
    si = np.sqrt(1.0 - u)[None, :, None]
    hx, hy, hz = si * cphi + sin_o, si * sphi, ci + co
    norm = np.sqrt(hx * hx + hy * hy + hz * hz)
    safe = np.where(norm > 0, norm, 1.0)
    cos_h = np.where(norm > 0, hz / safe, 1.0)
    cos_d = np.where(norm > 0, (si * cphi * hx + si * sphi * hy + ci * hz) / safe, 0.0)
    weights = (0.5 * wu)[None, :, None] * w_phi * np.ones_like(cphi)
    # f cos_i d omega = f (du dphi / 2); f is the BRDF, so weights carry no cos_i.
    cos_i = np.broadcast_to(ci, np.broadcast_shapes(ci.shape, co.shape, cphi.shape))
    return cos_i, np.broadcast_to(cos_h, cos_i.shape), np.broadcast_to(cos_d, cos_i.shape), (
        np.broadcast_to(weights, cos_i.shape) * 1.0
    )


def _half_vector_nodes(
    sigma: float, x: NDArray[np.float64], wx: NDArray[np.float64], w_phi: float, sin_o: NDArray[np.float64],
    co: NDArray[np.float64], cphi: NDArray[np.float64],
) -> tuple[NDArray[np.float64], ...]:
    """Nodes of a microfacet lobe of RMS slope ``sigma``: over the half vector, up to the horizon cut."""
    # omega_i = 2 (o.h) h - o is above the horizon exactly for theta_h below
    # theta_cut(phi_h), where cos(2 theta) cos_o + sin(2 theta) cos(phi) sin_o = 0;
    # integrating up to it keeps the integrand smooth on the whole domain.
    theta_cut = 0.5 * (np.arctan2(cphi * sin_o, co) + 0.5 * np.pi)  # (N, 1, P)
    theta_max = np.minimum(theta_cut, np.arctan(sigma * _S_MAX))
    s_max = np.tan(theta_max) / sigma
    s = 0.5 * s_max * (x[None, :, None] + 1.0)  # (N, T, P)
    ws = 0.5 * s_max * wx[None, :, None]
    theta_h = np.arctan(sigma * s)
    dtheta = sigma / (1.0 + (sigma * s) ** 2) * ws
    ch = np.cos(theta_h)
    sh = np.sin(theta_h)
    # h = (sh cphi, sh sphi, ch); o = (sin_o, 0, cos_o)
    cos_d = sh * cphi * sin_o + ch * co
    cos_i = 2.0 * cos_d * ch - co
    valid = (cos_d > 0) & (cos_i > 0)
    # f cos_i d omega_i = f cos_i 4 cos_d sin(theta_h) dtheta_h dphi_h
    weights = np.where(valid, cos_i * 4.0 * cos_d * sh * dtheta * w_phi, 0.0)
    return (
        np.where(valid, cos_i, 0.0),
        ch,
        np.clip(cos_d, 0.0, 1.0),
        weights,
    )


def lobe_albedo(
    lobe: Lobe,
    cos_o: ArrayLike,
    wavelengths: ArrayLike,
    *,
    n_theta: int = 48,
    n_phi: int = 48,
) -> NDArray[np.float64]:
    """Directional albedo of one isotropic lobe, including its weight.

    Parameters
    ----------
    lobe
        A Lambert or microfacet lobe.
    cos_o
        Cosines of the viewing angle in [0, 1], any shape.
    wavelengths
        1-D wavelengths in nm, L of them.
    n_theta, n_phi
        Quadrature nodes in the polar and azimuthal directions (>= 4).

    Returns
    -------
    ndarray
        Shape ``shape(cos_o) + (L,)``: the fraction of incident energy the
        lobe reflects.

    Raises
    ------
    ValueError
        Node counts below 4, ``cos_o`` outside [0, 1] or non-finite, or
        wavelengths that are not a non-empty 1-D array.

    Examples
    --------
    >>> class White:
    ...     angle_dependent = False
    ...     def reflectance(self, cos_d, wl):
    ...         return np.ones(np.shape(cos_d) + (len(wl),))
    >>> a = lobe_albedo(Lobe("lambert", 1.0, White()), 0.5, [550.0])
    >>> round(float(a[0]), 9)
    1.0
    """
    _check_counts(n_theta, n_phi)
    co = np.asarray(cos_o, dtype=np.float64)
    if not np.all(np.isfinite(co)) or np.any(co < 0) or np.any(co > 1):
        raise InputError("cos_o must be finite and in [0, 1] (cosine of the viewing angle)")
    wl = np.asarray(wavelengths, dtype=np.float64)
    if wl.ndim != 1 or wl.size == 0:
        raise InputError(f"wavelengths must be a non-empty 1-D array (nm), got shape {wl.shape}")
    flat = co.reshape(-1)
    out = np.zeros((flat.size, wl.size))
    if lobe.weight == 0.0 or flat.size == 0:
        return out.reshape(co.shape + (wl.size,))
    m = _SPECTRAL_TABLE_NODES
    if lobe.spectral.angle_dependent:
        table = lobe.spectral.reflectance(np.linspace(0.0, 1.0, m), wl)      # (M, L)
    else:
        table = lobe.spectral.reflectance(np.ones(1), wl)                   # (1, L)
    chunk = max(1, _CHUNK_ELEMENTS // (n_theta * n_phi))
    for start in range(0, flat.size, chunk):
        c = flat[start : start + chunk]
        cos_i, cos_h, cos_d, weights = _geometry_nodes(lobe, c, n_theta, n_phi)
        geo = lobe_geometry(lobe, cos_i, c[:, None, None], cos_h, cos_d) * weights
        n_views = c.size
        if not lobe.spectral.angle_dependent:
            out[start : start + chunk] = lobe.weight * geo.reshape(n_views, -1).sum(axis=1)[:, None] * table[0]
            continue
        pos = np.clip(cos_d, 0.0, 1.0).reshape(n_views, -1) * (m - 1)
        lo = np.minimum(pos.astype(np.int64), m - 2)
        frac = pos - lo
        g = geo.reshape(n_views, -1)
        base = (np.arange(n_views) * m)[:, None]
        w = np.bincount((base + lo).ravel(), (g * (1.0 - frac)).ravel(), minlength=n_views * m)
        w += np.bincount((base + lo + 1).ravel(), (g * frac).ravel(), minlength=n_views * m)
        out[start : start + chunk] = lobe.weight * (w.reshape(n_views, m) @ table)
    return out.reshape(co.shape + (wl.size,))


def directional_albedo(
    material_or_lobe: Material | Lobe,
    cos_o: ArrayLike,
    wavelengths: ArrayLike,
    *,
    n_theta: int = 48,
    n_phi: int = 48,
) -> NDArray[np.float64]:
    """Hemispherical integral of BRDF * cos_i for viewing directions ``cos_o``.

    Parameters
    ----------
    material_or_lobe
        A :class:`~processing.materials.lobes.Material` (sum over all its lobes,
        mirror lobes included) or a single :class:`~processing.materials.lobes.Lobe`
        (with its weight).  Anisotropic lobes give their albedo averaged
        over the view azimuth (:func:`processing.cloth.anisotropic_albedo.azimuth_mean_albedo`).
    cos_o
        Cosines of the viewing angle in [0, 1], any shape.  At exactly 0
        (grazing) the BRDF is 0 and so is the albedo.
    wavelengths
        1-D wavelengths in nm.
    n_theta, n_phi
        Quadrature nodes in the polar and azimuthal directions (>= 4).  With
        the defaults (48 x 48) the presets agree with 160 x 160 nodes to
        1e-5 and a rough lobe with an independent fine quadrature to 1e-5.

    Returns
    -------
    ndarray
        Shape ``shape(cos_o) + (L,)``: the fraction of incident energy
        reflected (<= 1 for an energy-conserving material).

    Raises
    ------
    ValueError
        Not a Material or Lobe, or bad arguments as for :func:`lobe_albedo`.

    Examples
    --------
    >>> from processing.materials.presets import get_material
    >>> a = directional_albedo(get_material("silver"), [1.0, 0.5], [450.0, 650.0])
    >>> bool(((a > 0.8) & (a <= 1.0)).all())
    True
    """
    if isinstance(material_or_lobe, Lobe):
        lobes: tuple[Lobe, ...] = (material_or_lobe,)
    elif isinstance(material_or_lobe, Material):
        lobes = material_or_lobe.lobes
    else:
        raise InputError(
            f"material_or_lobe must be a Material or a Lobe, got {type(material_or_lobe).__name__}"
        )
    total = None
    for lobe in lobes:
        if lobe.kind == "anisotropic":
            # depends on the view azimuth too: the mean over azimuth (processing.cloth.anisotropic_albedo)
            from processing.cloth.anisotropic_albedo import azimuth_mean_albedo

            co = np.asarray(cos_o, dtype=np.float64)
            wl = np.asarray(wavelengths, dtype=np.float64).reshape(-1)
            a = lobe.weight * azimuth_mean_albedo(lobe, co.reshape(-1), wl).reshape(co.shape + (wl.size,))
            total = a if total is None else total + a
            continue
        a = lobe_albedo(lobe, cos_o, wavelengths, n_theta=n_theta, n_phi=n_phi)
        total = a if total is None else total + a
    if total is None:
        co = np.asarray(cos_o, dtype=np.float64)
        total = np.zeros(co.shape + (np.asarray(wavelengths).size,))
    return total
