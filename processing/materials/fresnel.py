"""Unpolarised Fresnel reflectance of conductors (complex index) and dielectrics.

Matsuda et al., eq. (1)-(2): the specular colour of a metal is the Fresnel
reflectance of its complex refractive index eta = n + i k, averaged over the
s and p polarisations, F = (|r_s|^2 + |r_p|^2) / 2.  The complex form is
evaluated directly in complex arithmetic, which stays finite at grazing
incidence (F = 1 exactly at cos(theta) = 0).

References
----------
.. [1] Matsuda, Tanaka, Ichikawa, Mochizuki, Muroya, Kitamura, "CG
   reproduction of a craft object based on a light reflection model", IPSJ
   technical report (no DOI).
.. [2] Cook & Torrance, "A reflectance model for computer graphics", ACM
   Transactions on Graphics 1(1), 7-24 (1982), doi:10.1145/357290.357293.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.errors import InputError

__all__ = ["fresnel_conductor", "fresnel_dielectric"]


def fresnel_conductor(cos_theta: ArrayLike, eta: ArrayLike) -> NDArray[np.float64]:
    """Unpolarised reflectance of a surface of complex relative index ``eta``.

    Parameters
    ----------
    cos_theta
        Cosine of the incidence angle, in [0, 1] (values outside are clipped).
    eta
        Complex relative refractive index n + i k (n >= 0, k >= 0, eta != 0),
        broadcast against ``cos_theta``; a real value gives the dielectric
        result.

    Returns
    -------
    ndarray
        Reflectance in [0, 1], shape ``broadcast(cos_theta, eta)``.

    Raises
    ------
    ValueError
        Non-finite ``cos_theta`` or ``eta``, a negative n or k, or eta = 0.

    References
    ----------
    .. [1] Matsuda et al., eq. (1) (no DOI).
    .. [2] Cook & Torrance (1982), doi:10.1145/357290.357293.

    Examples
    --------
    >>> round(float(fresnel_conductor(1.0, 1.5)), 4)   # glass at normal incidence
    0.04
    >>> float(fresnel_conductor(0.0, 0.27 + 2.78j))     # grazing: a perfect mirror
    1.0
    """
    cos_i = _checked_cos(cos_theta)
    eta = np.asarray(eta, dtype=np.complex128)
    if not np.all(np.isfinite(eta)):
        raise InputError("eta contains NaN or infinite values")
    if np.any(eta.imag < 0) or np.any(eta.real < 0) or np.any(eta == 0):
        raise InputError(
            "eta must be n + i k with n >= 0, k >= 0 and eta != 0 (the refractiveindex.info "
            "convention for absorbing media); take the complex conjugate of an index given as n - i k"
        )
    eta2 = eta * eta
    # eta * cos(theta_t) = sqrt(eta^2 - sin^2), written as (eta^2 - 1) + cos^2 so
    # that it stays accurate near grazing; the principal root has Re >= 0 and
    # Im >= 0 for k >= 0.
    root = np.sqrt((eta2 - 1.0) + cos_i * cos_i)
    with np.errstate(divide="ignore", invalid="ignore"):
        r_s = _difference_ratio(cos_i, root)
        r_p = _difference_ratio(eta2 * cos_i, root)
        f = 0.5 * (np.abs(r_s) ** 2 + np.abs(r_p) ** 2)
    # At grazing incidence both ratios have modulus 1 (the limit for every
    # eta != 1; eta = 1 is the only 0/0 case).
    f = np.where(cos_i <= 0.0, 1.0, f)
    return np.clip(f, 0.0, 1.0)


def _difference_ratio(a: NDArray, b: NDArray) -> NDArray[np.complex128]:
    """(a - b) / (a + b), with both scaled by max(|a|, |b|) first.

    numpy's complex division overflows when a and b are denormal
    (cos_theta ~ 1e-320 with eta ~ 1).  The ratio is 0/0 (NaN) only where
    a = b = 0.
    """
    scale = np.maximum(np.abs(a), np.abs(b))
    scale = np.where(scale > 0.0, scale, 1.0)
    # part by part: dividing a complex by a (denormal) real goes through its reciprocal
    a = (np.real(a) / scale) + 1j * (np.imag(a) / scale)
    b = (np.real(b) / scale) + 1j * (np.imag(b) / scale)
    return (a - b) / (a + b)


def _checked_cos(cos_theta: ArrayLike) -> NDArray[np.float64]:
    c = np.asarray(cos_theta, dtype=np.float64)
    if not np.all(np.isfinite(c)):
        raise InputError("cos_theta contains NaN or infinite values")
    return np.clip(c, 0.0, 1.0)


def fresnel_dielectric(cos_theta: ArrayLike, n: ArrayLike) -> NDArray[np.float64]:
    """Unpolarised reflectance of a dielectric of real relative index ``n``.

    Uses the textbook real formula; for ``n < 1`` total internal reflection
    gives 1.  It equals :func:`fresnel_conductor` with ``k = 0``.

    Parameters
    ----------
    cos_theta
        Cosine of the incidence angle, in [0, 1] (values outside are clipped).
    n
        Real relative index (> 0), broadcast against ``cos_theta``.

    Returns
    -------
    ndarray
        Reflectance in [0, 1], shape ``broadcast(cos_theta, n)``.

    Raises
    ------
    ValueError
        Non-finite ``cos_theta`` or ``n``, or n <= 0.

    Examples
    --------
    >>> round(float(fresnel_dielectric(1.0, 1.5)), 4)
    0.04
    >>> float(fresnel_dielectric(0.0, 1.5))
    1.0
    """
    cos_i = _checked_cos(cos_theta)
    n = np.asarray(n, dtype=np.float64)
    if not np.all(np.isfinite(n)) or np.any(n <= 0):
        raise InputError("the dielectric index n must be finite and > 0")
    # (n cos(theta_t))^2 = n^2 - sin^2 = (n^2 - 1) + cos^2, accurate near grazing
    # and for n close to 1; it is <= 0 under total internal reflection (n < 1).
    arg = (n * n - 1.0) + cos_i * cos_i
    tir = arg <= 0.0
    n_cos_t = np.sqrt(np.clip(arg, 0.0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        r_s = (cos_i - n_cos_t) / (cos_i + n_cos_t)
        r_p = (n * n * cos_i - n_cos_t) / (n * n * cos_i + n_cos_t)
        f = 0.5 * (r_s * r_s + r_p * r_p)
    # cos_i = 0 and n cos_t = 0 together only at n = 1 (grazing): the limit is 1.
    f = np.where(tir | ~np.isfinite(f), 1.0, f)
    return np.clip(f, 0.0, 1.0)
