"""The yarn ellipsoid of Yasuda et al. as a normalised anisotropic microfacet lobe.

Yasuda et al., section 3.1, eq. (1): the fraction of fibre-surface facets
facing the half vector h is the distance ``A(h)`` from the centre of an
ellipsoid (semi-axes a_t along the yarn t, a_b across it, 1 along the
normal) to its surface along h.  ``A`` is not a distribution of normals;
its fourth power, normalised, ``D(h) = A(h)^4 / (pi a_t a_b)``, is (the
anisotropic Trowbridge-Reitz distribution), and with its closed-form Smith
masking the lobe ``D G2 / (4 cos_i cos_o)`` reflects at most what arrives.
docs/cloth.md, section "The ellipsoid as a microfacet lobe", gives the
derivation.  Vectors are given by their components in the local frame
(t, b, n); the functions work in the dtype of their inputs (float32 in the
renderer's table path, float64 elsewhere).

References
----------
.. [1] Yasuda, Yokoi, Toriwaki, Inagaki, "A shading model for cloth
   objects", IEEE Computer Graphics and Applications 12(6), 15-24 (1992),
   doi:10.1109/38.163621.
.. [2] Trowbridge & Reitz, "Average irregularity representation of a
   rough surface for ray reflection", JOSA 65(5), 531-536 (1975).
.. [3] Heitz, "Understanding the masking-shadowing function in
   microfacet-based BRDFs", Journal of Computer Graphics Techniques 3(2),
   48-107 (2014).
.. [4] Smith, "Geometrical shadowing of a random rough surface", IEEE
   Transactions on Antennas and Propagation 15(5), 668-671 (1967),
   doi:10.1109/TAP.1967.1138991.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.errors import InputError

__all__ = [
    "ellipsoid_distance",
    "ellipsoid_ndf",
    "smith_lambda",
    "anisotropic_lobe",
    "check_axes",
    "AXIS_RANGE",
]

#: Accepted range of the ellipsoid semi-axes a_t, a_b (the normal axis is 1):
#: aspect ratios a_b / a_t from 1e-3 to 1e3 and beyond stay finite.
AXIS_RANGE = (1e-4, 1e2)


def check_axes(a_t: float, a_b: float, what: str = "ellipsoid") -> tuple[float, float]:
    """Both semi-axes as floats in ``AXIS_RANGE``.

    Parameters
    ----------
    a_t, a_b
        Semi-axes along and across the yarn (numbers or numeric strings).
    what
        What the axes belong to, for the message.

    Returns
    -------
    tuple of float
        ``(a_t, a_b)``.

    Raises
    ------
    ValueError
        An axis that is not a number in ``AXIS_RANGE`` (the message names it).

    Examples
    --------
    >>> check_axes(0.05, "0.5")
    (0.05, 0.5)
    >>> check_axes(0.0, 0.5)
    Traceback (most recent call last):
    ...
    processing.errors.InputError: ellipsoid axis a_t must be a number in [0.0001, 100], got 0.0
    """
    out = []
    for name, value in (("a_t", a_t), ("a_b", a_b)):
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise InputError(f"{what} axis {name} must be a number, got {value!r}") from None
        if not (math.isfinite(v) and AXIS_RANGE[0] <= v <= AXIS_RANGE[1]):
            raise InputError(f"{what} axis {name} must be a number in [{AXIS_RANGE[0]:g}, {AXIS_RANGE[1]:g}], got {value!r}")
        out.append(v)
    return out[0], out[1]


def ellipsoid_distance(h_t: ArrayLike, h_b: ArrayLike, h_n: ArrayLike, a_t: float, a_b: float) -> NDArray:
    """Distance A(h) from the centre to the ellipsoid along unit h (Yasuda et al., eq. (1)).

    ``A(h) = 1 / sqrt((h.t / a_t)^2 + (h.b / a_b)^2 + (h.n)^2)``.

    Parameters
    ----------
    h_t, h_b, h_n
        Components of the unit vector h along t, b and n.
    a_t, a_b
        Semi-axes along t and b (the normal axis is 1).

    Returns
    -------
    ndarray
        A(h), in units of the normal semi-axis.

    References
    ----------
    .. [1] Yasuda et al. (1992), eq. (1), doi:10.1109/38.163621.

    Examples
    --------
    >>> float(ellipsoid_distance(0.0, 0.0, 1.0, 0.1, 0.5))   # along n: the unit axis
    1.0
    >>> round(float(ellipsoid_distance(1.0, 0.0, 0.0, 0.1, 0.5)), 6)   # along the yarn: a_t
    0.1
    """
    ht, hb, hn = (np.asarray(x) for x in (h_t, h_b, h_n))
    s = (ht / a_t) ** 2 + (hb / a_b) ** 2 + hn * hn
    return 1.0 / np.sqrt(s)


def ellipsoid_ndf(h_t: ArrayLike, h_b: ArrayLike, h_n: ArrayLike, a_t: float, a_b: float) -> NDArray:
    """Normalised facet distribution ``D(h) = A(h)^4 / (pi a_t a_b)``.

    The anisotropic Trowbridge-Reitz (GGX) distribution, with
    ``integral D(h) (h.n) d omega_h = 1``.

    Parameters
    ----------
    h_t, h_b, h_n
        Components of the unit half vector along t, b and n.
    a_t, a_b
        Semi-axes along t and b (the normal axis is 1).

    Returns
    -------
    ndarray
        D in 1/sr; 0 where h.n <= 0.  At least float32.

    References
    ----------
    .. [1] Yasuda et al. (1992), eq. (1), doi:10.1109/38.163621.
    .. [2] Heitz (2014), eq. (85) (no DOI).

    Examples
    --------
    Isotropic axes give the GGX peak ``1 / (pi a^2)``:

    >>> round(float(ellipsoid_ndf(0.0, 0.0, 1.0, 0.5, 0.5)) * math.pi, 6)
    4.0
    """
    ht, hb, hn = (np.asarray(x) for x in (h_t, h_b, h_n))
    # the terms are scaled before squaring: with a = 1e-4 and |h.t| = 1 the
    # square of the sum is 1e16, far inside float32's range
    s = (ht / a_t) ** 2 + (hb / a_b) ** 2 + hn * hn
    dtype = np.result_type(s, np.float32)
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        d = 1.0 / (math.pi * a_t * a_b * s * s)
    return np.where((hn > 0) & np.isfinite(d), d, 0.0).astype(dtype, copy=False)


def smith_lambda(w_t: ArrayLike, w_b: ArrayLike, w_n: ArrayLike, a_t: float, a_b: float) -> NDArray:
    """Smith Lambda of the ellipsoid distribution for direction w.

    ``Lambda = (sqrt(1 + x) - 1) / 2`` with ``x = (a_t^2 w_t^2 + a_b^2 w_b^2) / w_n^2``,
    written as ``x / (2 (1 + sqrt(1 + x)))`` (no cancellation for small x).

    Parameters
    ----------
    w_t, w_b, w_n
        Components of the unit direction along t, b and n.
    a_t, a_b
        Semi-axes along t and b.

    Returns
    -------
    ndarray
        Lambda >= 0; infinite at and below the horizon.

    References
    ----------
    .. [1] Heitz (2014), eq. (86) (no DOI).
    .. [2] Smith (1967), doi:10.1109/TAP.1967.1138991.

    Examples
    --------
    >>> float(smith_lambda(0.0, 0.0, 1.0, 0.3, 0.3))
    0.0
    >>> round(float(smith_lambda(0.6, 0.0, 0.8, 1.0, 1.0)), 6)   # x = tan^2 = 0.5625
    0.125
    """
    wt, wb, wn = (np.asarray(x) for x in (w_t, w_b, w_n))
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        x = ((a_t * wt) ** 2 + (a_b * wb) ** 2) / (wn * wn)
        lam = x / (2.0 * (1.0 + np.sqrt(1.0 + x)))
    return np.where(wn > 0, np.nan_to_num(lam, nan=np.inf), np.inf)


def anisotropic_lobe(
    cos_i: ArrayLike,
    cos_o: ArrayLike,
    cos_h: ArrayLike,
    cos_d: ArrayLike,
    i_t: ArrayLike,
    i_b: ArrayLike,
    o_t: ArrayLike,
    o_b: ArrayLike,
    a_t: float,
    a_b: float,
) -> NDArray:
    """``D(h) G2(i, o) / (4 cos_i cos_o)`` of the yarn ellipsoid, in 1/sr.

    Parameters
    ----------
    cos_i, cos_o, cos_h, cos_d
        n.i, n.o, n.h and i.h.
    i_t, i_b, o_t, o_b
        Components of the unit light and view directions along the yarn t
        and across it (b = n x t).
    a_t, a_b
        Semi-axes of the ellipsoid along t and b (the normal axis is 1).

    Returns
    -------
    ndarray
        The factor in 1/sr (height-correlated G2 = 1 / (1 + Lambda(i) +
        Lambda(o))); zero where either cosine is <= 0; finite everywhere.

    References
    ----------
    .. [1] Yasuda et al. (1992), eq. (1), doi:10.1109/38.163621.
    .. [2] Heitz (2014), eq. (85)-(86) (no DOI).

    Examples
    --------
    Light and view along the normal: ``D(n) / 4 = 1 / (4 pi a_t a_b)``.

    >>> round(float(anisotropic_lobe(1, 1, 1, 1, 0, 0, 0, 0, 0.1, 0.5)) * 4 * math.pi * 0.05, 6)
    1.0
    """
    ci, co, ch, cd = (np.asarray(x) for x in (cos_i, cos_o, cos_h, cos_d))
    it, ib, ot, ob = (np.asarray(x) for x in (i_t, i_b, o_t, o_b))
    dtype = np.result_type(ci, co, ch, cd, it, np.float32)
    valid = (ci > 0) & (co > 0) & (cd > 0)
    with np.errstate(divide="ignore", over="ignore", invalid="ignore", under="ignore"):
        inv = 0.5 / np.where(valid, cd, 1.0)
        d = ellipsoid_ndf((it + ot) * inv, (ib + ob) * inv, ch, a_t, a_b)
        g = 1.0 / (1.0 + smith_lambda(it, ib, ci, a_t, a_b) + smith_lambda(ot, ob, co, a_t, a_b))
        f = d * g / (4.0 * np.where(valid, ci * co, 1.0))
    return np.where(valid, np.nan_to_num(f, nan=0.0, posinf=0.0), 0.0).astype(dtype, copy=False)
