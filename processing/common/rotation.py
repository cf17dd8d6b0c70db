"""Rotation matrices, one place for every layer.

Angles are counter-clockwise seen from the tip of the axis looking back
(right-handed).  Functions ending in ``_deg`` take degrees, the others radians.

Examples
--------
>>> import numpy as np
>>> np.round(rotation_z_deg(90) @ [1, 0, 0], 12).tolist()
[0.0, 1.0, 0.0]
>>> np.allclose(rotation_about([0, 0, 1], np.pi / 2), rotation_z_deg(90))
True
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["rotation_z", "rotation_z_deg", "rotation_about", "rotation_xyz_deg"]


def rotation_z(angle_rad: ArrayLike) -> NDArray[np.float64]:
    """Rotations about +z, vectorised.

    Parameters
    ----------
    angle_rad
        Angle(s) in radians, any shape.

    Returns
    -------
    ndarray
        ``angle_rad.shape + (3, 3)``.
    """
    a = np.asarray(angle_rad, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def rotation_z_deg(angle_deg: float) -> NDArray[np.float64]:
    """3 x 3 rotation about +z by ``angle_deg`` degrees.

    Parameters
    ----------
    angle_deg
        Angle in degrees.

    Returns
    -------
    ndarray
        ``(3, 3)``.
    """
    return rotation_z(math.radians(float(angle_deg)))


def rotation_about(axis: ArrayLike, angle_rad: float) -> NDArray[np.float64]:
    """3 x 3 rotation by ``angle_rad`` about ``axis`` (Rodrigues' formula).

    Parameters
    ----------
    axis
        Direction of the axis, ``(3,)``; normalised here.
    angle_rad
        Angle in radians.

    Returns
    -------
    ndarray
        ``(3, 3)``.
    """
    k = np.asarray(axis, dtype=np.float64)
    k = k / np.linalg.norm(k)
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle_rad) * kx + (1.0 - math.cos(angle_rad)) * (kx @ kx)


def rotation_xyz_deg(angles_deg: tuple[float, float, float]) -> NDArray[np.float64]:
    """Rotation about x, then y, then z (fixed axes), angles in degrees: ``Rz @ Ry @ Rx``.

    Parameters
    ----------
    angles_deg
        ``(x, y, z)`` angles in degrees.

    Returns
    -------
    ndarray
        ``(3, 3)``.

    Examples
    --------
    >>> np.round(rotation_xyz_deg((0, 0, 90)) @ [1, 0, 0], 6).tolist()
    [0.0, 1.0, 0.0]
    """
    ax, ay, az = (math.radians(float(a)) for a in angles_deg)
    return rotation_about([0, 0, 1], az) @ rotation_about([0, 1, 0], ay) @ rotation_about([1, 0, 0], ax)
