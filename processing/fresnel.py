"""Unpolarised Fresnel reflectance for conductors (complex index) and dielectrics.

Matsuda et al., eq. (1)-(2): the specular colour of a metal is the Fresnel
reflectance of its complex refractive index eta = n + i k, averaged over the
s and p polarisations, F = (|r_s|^2 + |r_p|^2) / 2.

The complex form is evaluated directly in complex arithmetic (no real-valued
rearrangement with square roots of differences), which stays finite at
grazing incidence: at cos(theta) = 0 both amplitude ratios have modulus 1 and
F = 1 exactly.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["fresnel_conductor", "fresnel_dielectric"]


def fresnel_conductor(cos_theta: ArrayLike, eta: ArrayLike) -> NDArray[np.float64]:
    """Unpolarised reflectance of a surface of complex relative index ``eta``.

    Parameters
    ----------
    cos_theta
        Cosine of the incidence angle, in [0, 1] (values outside are clipped).
    eta
        Complex relative refractive index n + i k (k >= 0), broadcast against
        ``cos_theta``; a real value gives the dielectric result.

    Returns
    -------
    ndarray
        Reflectance in [0, 1], shape ``broadcast(cos_theta, eta)``.

    Examples
    --------
    >>> round(float(fresnel_conductor(1.0, 1.5)), 4)   # glass at normal incidence
    0.04
    >>> float(fresnel_conductor(0.0, 0.27 + 2.78j))     # grazing: a perfect mirror
    1.0
    """
    cos_i = np.clip(np.asarray(cos_theta, dtype=np.float64), 0.0, 1.0)
    eta = np.asarray(eta, dtype=np.complex128)
    sin2 = 1.0 - cos_i * cos_i
    # cos of the (complex) refraction angle; principal root has Re >= 0 for k >= 0.
    cos_t = np.sqrt(eta * eta - sin2 + 0j) / eta
    r_s = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    r_p = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    f = 0.5 * (np.abs(r_s) ** 2 + np.abs(r_p) ** 2)
    return np.clip(f, 0.0, 1.0)


def fresnel_dielectric(cos_theta: ArrayLike, n: ArrayLike) -> NDArray[np.float64]:
    """Unpolarised reflectance of a dielectric of real relative index ``n``.

    Uses the textbook real formula; for ``n < 1`` total internal reflection
    gives 1.  It equals :func:`fresnel_conductor` with ``k = 0``.

    Examples
    --------
    >>> round(float(fresnel_dielectric(1.0, 1.5)), 4)
    0.04
    >>> float(fresnel_dielectric(0.0, 1.5))
    1.0
    """
    cos_i = np.clip(np.asarray(cos_theta, dtype=np.float64), 0.0, 1.0)
    n = np.asarray(n, dtype=np.float64)
    sin2_t = (1.0 - cos_i * cos_i) / (n * n)
    tir = sin2_t >= 1.0
    cos_t = np.sqrt(np.clip(1.0 - sin2_t, 0.0, 1.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        r_s = (cos_i - n * cos_t) / (cos_i + n * cos_t)
        r_p = (n * cos_i - cos_t) / (n * cos_i + cos_t)
        f = 0.5 * (r_s * r_s + r_p * r_p)
    # cos_i = 0 and n*cos_t = 0 together only at tir; both limits are 1.
    f = np.where(tir | ~np.isfinite(f), 1.0, f)
    return np.clip(f, 0.0, 1.0)
