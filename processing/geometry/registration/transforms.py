"""Rigid transforms: rotations spread over SO(3), applying and comparing transforms, Kabsch fit of picks.

Units are millimetres and degrees.  A transform ``T`` (4 x 4) maps points
``x`` to ``T @ x``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.geometry.registration.presets import RegistrationError

__all__ = ["pose_difference", "rigid_from_picks", "rotation_samples", "transform_points"]


def rotation_samples(n: int) -> NDArray[np.float64]:
    """``n`` rotation matrices spread evenly over SO(3) (super-Fibonacci spiral).

    Alexa (CVPR 2022), algorithm 1: sample ``i`` is the unit quaternion
    ``(r sin a, r cos a, R sin b, R cos b)`` with ``s = i + 1/2``,
    ``r = sqrt(s / n)``, ``R = sqrt(1 - s / n)``, ``a = 2 pi s / sqrt(2)``,
    ``b = 2 pi s / psi`` and ``psi^4 = psi + 4``.

    Parameters
    ----------
    n
        Number of rotations (>= 1).

    Returns
    -------
    ndarray
        ``(n, 3, 3)`` proper rotation matrices.

    Raises
    ------
    RegistrationError
        ``n`` is not a positive integer.

    References
    ----------
    .. [1] Alexa, M. (2022). Super-Fibonacci spirals: fast, low-discrepancy
       sampling of SO(3). CVPR 2022.

    Examples
    --------
    >>> r = rotation_samples(100)
    >>> r.shape, bool(np.allclose(r @ r.transpose(0, 2, 1), np.eye(3)))
    ((100, 3, 3), True)
    >>> bool(np.allclose(np.linalg.det(r), 1.0))
    True
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise RegistrationError(f"rotation_samples: n must be a positive integer, got {n!r}")
    psi = 1.533751168755204288118041
    s = np.arange(n) + 0.5
    r = np.sqrt(s / n)
    big = np.sqrt(1.0 - s / n)
    a = 2.0 * np.pi * s / np.sqrt(2.0)
    b = 2.0 * np.pi * s / psi
    q = np.stack([r * np.sin(a), r * np.cos(a), big * np.sin(b), big * np.cos(b)], axis=1)
    return _quat_to_matrix(q)


def _quat_to_matrix(q: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation matrices ``(K, 3, 3)`` of quaternions ``(K, 4)`` stored ``(x, y, z, w)`` (normalised here)."""
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    x, y, z, w = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], axis=1)


def _rodrigues(w: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation matrices ``(K, 3, 3)`` of rotation vectors ``(K, 3)``."""
    theta = np.linalg.norm(w, axis=1)
    small = theta < 1e-12
    k = w / np.where(small, 1.0, theta)[:, None]
    kx = np.zeros((len(w), 3, 3))
    kx[:, 0, 1], kx[:, 0, 2], kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    kx = kx - kx.transpose(0, 2, 1)
    s = np.sin(theta)[:, None, None]
    c = (1.0 - np.cos(theta))[:, None, None]
    return np.eye(3) + s * kx + c * (kx @ kx)


def _rotation_angle_deg(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Angle (deg) of ``a^T b`` for stacks of rotations (broadcasting).

    ``atan2(sin, cos)`` from its skew part and trace, accurate near 0 and 180 degrees.
    """
    m = np.einsum("...ji,...jk->...ik", a, b)
    cos = (np.trace(m, axis1=-2, axis2=-1) - 1.0) / 2.0
    skew = np.stack([m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1)
    return np.degrees(np.arctan2(np.linalg.norm(skew, axis=-1) / 2.0, cos))


def transform_points(transform: ArrayLike, points: ArrayLike) -> NDArray[np.float64]:
    """Apply a 4 x 4 rigid transform to ``(N, 3)`` points.

    Parameters
    ----------
    transform
        4 x 4 rigid transform.
    points
        Points (mm), reshaped to ``(N, 3)``.

    Returns
    -------
    ndarray
        ``(N, 3)`` transformed points (mm).

    Examples
    --------
    >>> t = np.eye(4); t[:3, 3] = [1, 2, 3]
    >>> transform_points(t, [[0, 0, 0]]).tolist()
    [[1.0, 2.0, 3.0]]
    """
    t = np.asarray(transform, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return p @ t[:3, :3].T + t[:3, 3]


def pose_difference(
    a: ArrayLike, b: ArrayLike, points: ArrayLike | None = None
) -> tuple[float, float]:
    """Rotation (degrees) and displacement (mm) between two rigid transforms.

    Parameters
    ----------
    a, b
        4 x 4 rigid transforms.
    points
        Optional ``(N, 3)`` points (mm): the displacement is then the largest
        ``|a x - b x|`` over them, which does not depend on where the origin
        is; without points it is the difference of the translations.

    Returns
    -------
    tuple of float
        ``(rotation_deg, displacement_mm)``.

    Examples
    --------
    >>> a = np.eye(4); b = np.eye(4); b[:3, 3] = [0, 0.1, 0]
    >>> [round(v, 6) for v in pose_difference(a, b)]
    [0.0, 0.1]
    """
    ta = np.asarray(a, dtype=np.float64)
    tb = np.asarray(b, dtype=np.float64)
    rot = float(_rotation_angle_deg(ta[:3, :3], tb[:3, :3]))
    if points is None:
        return rot, float(np.linalg.norm(ta[:3, 3] - tb[:3, 3]))
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    disp = np.linalg.norm(transform_points(ta, p) - transform_points(tb, p), axis=1)
    return rot, float(disp.max()) if len(disp) else 0.0


def rigid_from_picks(
    source_points: ArrayLike, target_points: ArrayLike
) -> tuple[NDArray[np.float64], float]:
    """Rigid transform (no scale) that best maps picked source points onto target points.

    Kabsch (1976) / Umeyama (1991) without scale: the rotation from the SVD of
    the cross-covariance of the centred pairs, with the reflection removed.

    Parameters
    ----------
    source_points, target_points
        ``(M, 3)`` corresponding points (mm), ``M >= 3``, not collinear.

    Returns
    -------
    tuple
        ``(transform, rms_mm)``: the 4 x 4 transform source -> target and the
        RMS distance of the mapped picks to their partners.

    Raises
    ------
    RegistrationError
        Not ``(M, 3)`` arrays, fewer than 3 pairs, NaN or infinite
        coordinates, unequal numbers of points, collinear or coincident picks.

    References
    ----------
    .. [1] Kabsch, W. (1976). A solution for the best rotation to relate two
       sets of vectors. Acta Cryst. A32, 922-923. doi:10.1107/S0567739476001873
    .. [2] Umeyama, S. (1991). Least-squares estimation of transformation
       parameters between two point patterns. IEEE TPAMI 13(4), 376-380.
       doi:10.1109/34.88573

    Examples
    --------
    >>> src = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10]], float)
    >>> t, rms = rigid_from_picks(src, src + [1, 2, 3])
    >>> np.round(t[:3, 3], 9).tolist(), rms < 1e-9
    ([1.0, 2.0, 3.0], True)
    """
    src = _picks_array(source_points, "source_points")
    tgt = _picks_array(target_points, "target_points")
    if src.shape != tgt.shape:
        raise RegistrationError(
            f"source_points and target_points must pair up one to one, got {len(src)} and "
            f"{len(tgt)} points"
        )
    for name, p in (("source_points", src), ("target_points", tgt)):
        centred = p - p.mean(axis=0)
        sv = np.linalg.svd(centred, compute_uv=False)
        if sv[0] == 0.0 or sv[1] <= 1e-6 * sv[0]:
            raise RegistrationError(
                f"{name} are collinear (or coincide): pick at least 3 points that span a "
                "triangle, well apart from each other"
            )
    cs, ct = src.mean(axis=0), tgt.mean(axis=0)
    h = (src - cs).T @ (tgt - ct)
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    t = np.eye(4)
    t[:3, :3] = r
    t[:3, 3] = ct - r @ cs
    rms = float(np.sqrt(np.mean(np.sum((transform_points(t, src) - tgt) ** 2, axis=1))))
    return t, rms


def _picks_array(points: ArrayLike, name: str) -> NDArray[np.float64]:
    """Picked points as a checked ``(M, 3)`` float array (at least 3, finite)."""
    try:
        p = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise RegistrationError(f"{name} must be an (M, 3) array of points in mm: {exc}") from None
    if p.ndim != 2 or p.shape[1] != 3:
        raise RegistrationError(f"{name} must be an (M, 3) array of points in mm, got shape {p.shape}")
    if len(p) < 3:
        raise RegistrationError(f"{name}: at least 3 picked point pairs are needed, got {len(p)}")
    if not np.all(np.isfinite(p)):
        raise RegistrationError(f"{name} contains NaN or infinite coordinates; pick the points again")
    return p
