"""Geometry of the simulated station: the sensor's pose, the table top and the placements of the object.

Room frame: the table axis is ``+Z`` through the origin and the table top (a
disc of ``table_radius_mm``, part of the ray-cast scene, :func:`table_disc`)
is at ``z = 0``.  A point ``p_obj`` of the object is at
``Rz(angle) @ pose @ p_obj`` in the room, ``angle`` the turntable's physical
angle (counter-clockwise seen from above), ``pose`` the placement's object ->
table transform (:func:`placement_pose`).  The sensor pose has columns
``X_s`` (along the laser line), ``Y_s``, ``Z_s`` (the range direction) and the
emitter as translation; a profile point ``(x_mm, z_mm)`` is at
``origin_s + x_mm X_s + z_mm Z_s``.  The default
(:func:`station_sensor_to_room`) looks at the table axis from 260 mm, its
emitter 120 mm above the table, tilted 20 deg down, with a 40 deg fan: the
procedural hawk is seen whole, top to bottom, in any placement, and so is the
table top in front of it.  docs/simulator.md ("Geometry", "Placements") draws
the frames.

Examples
--------
>>> v, t = table_disc(50.0, 16)
>>> float(placement_pose(v, np.eye(4), seed=0, placement=1)[2, 3])
0.0
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mocks.noise_seed import stable_seed

__all__ = ["station_sensor_to_room", "table_disc", "rest_on_table", "placement_pose"]


def station_sensor_to_room(standoff_mm: float = 260.0, height_mm: float = 120.0,
                           tilt_deg: float = 20.0) -> NDArray[np.float64]:
    """The station's sensor pose (sensor -> room, 4 x 4, mm): looking at the table axis, tilted down.

    The laser plane is the vertical plane ``y = 0`` through the table axis.
    Columns: ``X_s = (-sin b, 0, cos b)`` (along the laser line, upward),
    ``Y_s = (0, 1, 0)`` (toward the triangulation camera),
    ``Z_s = (-cos b, 0, -sin b)`` (the range direction: toward the axis,
    ``b = tilt_deg`` below the horizontal); translation: the emitter at
    ``(standoff_mm, 0, height_mm)``.  ``tilt_deg = 0`` is
    :func:`mocks.profiler_firmware.default_sensor_to_room`.

    Parameters
    ----------
    standoff_mm
        Horizontal distance of the emitter from the table axis (mm, > 0).
    height_mm
        Height of the emitter above the table top (mm).
    tilt_deg
        Downward tilt of the range direction (degrees, in (-90, 90)).

    Examples
    --------
    >>> m = station_sensor_to_room(260.0, 120.0, 0.0)
    >>> (m[:3, 2] + 0.0).tolist(), m[:3, 3].tolist()
    ([-1.0, 0.0, 0.0], [260.0, 0.0, 120.0])
    """
    if not (math.isfinite(standoff_mm) and standoff_mm > 0):
        raise ValueError(f"standoff_mm must be a positive distance (mm), got {standoff_mm!r}")
    if not math.isfinite(height_mm):
        raise ValueError(f"height_mm must be finite (mm), got {height_mm!r}")
    if not (math.isfinite(tilt_deg) and -90 < tilt_deg < 90):
        raise ValueError(f"tilt_deg must be in (-90, 90) degrees, got {tilt_deg!r}")
    b = math.radians(tilt_deg)
    m = np.eye(4)
    m[:3, 0] = (-math.sin(b), 0.0, math.cos(b))
    m[:3, 1] = (0.0, 1.0, 0.0)
    m[:3, 2] = (-math.cos(b), 0.0, -math.sin(b))
    m[:3, 3] = (float(standoff_mm), 0.0, float(height_mm))
    return m


def table_disc(radius_mm: float = 100.0, segments: int = 128) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """The table top: a disc of ``radius_mm`` at ``z = 0`` centred on the axis, as a triangle fan.

    Examples
    --------
    >>> v, t = table_disc(100.0, 8)
    >>> v.shape, t.shape, float(abs(v[:, 2]).max()), float(np.hypot(v[1:, 0], v[1:, 1]).min())
    ((9, 3), (8, 3), 0.0, 100.0)
    """
    if not (math.isfinite(radius_mm) and radius_mm > 0):
        raise ValueError(f"table_radius_mm must be a positive radius (mm), got {radius_mm!r}")
    if not isinstance(segments, int) or segments < 3:
        raise ValueError(f"segments must be an integer >= 3, got {segments!r}")
    phi = np.linspace(0.0, 2 * math.pi, segments, endpoint=False)
    ring = np.stack([radius_mm * np.cos(phi), radius_mm * np.sin(phi), np.zeros(segments)], axis=1)
    v = np.vstack([np.zeros((1, 3)), ring])
    i = np.arange(segments)
    t = np.stack([np.zeros(segments, np.int64), 1 + i, 1 + (i + 1) % segments], axis=1)
    return v, t


def _rotation_about(axis: NDArray[np.float64], angle_rad: float) -> NDArray[np.float64]:
    """3 x 3 rotation by ``angle_rad`` about the unit vector ``axis`` (Rodrigues' formula, axis used as given).

    :func:`processing.common.rotation.rotation_about` normalises the axis
    first, which changes the last bit of the poses for about one tilt axis
    ``(cos a, sin a, 0)`` in five; placements stay bit-identical with this one.
    """
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + math.sin(angle_rad) * k + (1.0 - math.cos(angle_rad)) * (k @ k)


def rest_on_table(vertices: ArrayLike, pose: ArrayLike) -> NDArray[np.float64]:
    """``pose`` shifted along z so the transformed mesh's lowest vertex is at ``z = 0``.

    Examples
    --------
    >>> m = np.eye(4); m[2, 3] = 7.0
    >>> float(rest_on_table([[0, 0, -2.0], [1, 1, 3.0]], m)[2, 3])
    2.0
    """
    v = np.asarray(vertices, dtype=np.float64)
    out = np.array(pose, dtype=np.float64)
    z = v @ out[2, :3] + out[2, 3]
    out[2, 3] -= z.min()
    return out


def placement_pose(vertices: ArrayLike, base_pose: ArrayLike, seed: int, placement: int,
                   *, offset_mm: float = 5.0) -> NDArray[np.float64]:
    """The object -> table pose (4 x 4, mm) of placement number ``placement``.

    Placement 1 is ``base_pose`` lowered or raised to rest on the table
    (lowest vertex at ``z = 0``).  Placement ``n >= 2`` draws, from a
    generator seeded by ``(seed, n)``: a tilt of 20-90 deg about a horizontal
    axis of uniform azimuth, then a turn of 0-360 deg about ``z``, applied
    after ``base_pose``; the result is translated so the mesh rests on the
    table (lowest vertex at ``z = 0``) with the centre of its bounding box
    within ``offset_mm`` of the table axis.

    Parameters
    ----------
    vertices
        (V, 3) mesh vertices, object frame (mm).
    base_pose
        The object's base pose on the table (4 x 4).
    seed
        Station seed (integer >= 0).
    placement
        Placement number (>= 1).
    offset_mm
        Largest distance of the bounding-box centre from the axis (mm).

    Examples
    --------
    >>> v = np.array([[-1, -1, 0], [1, 1, 2.0]])
    >>> p = placement_pose(v, np.eye(4), 0, 2)
    >>> bool(np.allclose(p[:3, :3].T @ p[:3, :3], np.eye(3))), float(round((v @ p[:3, :3].T + p[:3, 3])[:, 2].min(), 9))
    (True, 0.0)
    """
    if not isinstance(placement, (int, np.integer)) or isinstance(placement, bool) or placement < 1:
        raise ValueError(f"placement must be an integer >= 1, got {placement!r}")
    v = np.asarray(vertices, dtype=np.float64)
    base = np.asarray(base_pose, dtype=np.float64)
    if placement == 1:
        return rest_on_table(v, base)
    rng = np.random.default_rng(stable_seed("placement", int(seed), int(placement)))
    tilt = math.radians(rng.uniform(20.0, 90.0))
    azimuth = rng.uniform(0.0, 2 * math.pi)
    turn = rng.uniform(0.0, 2 * math.pi)
    offset_r = offset_mm * math.sqrt(rng.uniform())
    offset_a = rng.uniform(0.0, 2 * math.pi)
    axis = np.array([math.cos(azimuth), math.sin(azimuth), 0.0])
    rot = _rotation_about(np.array([0.0, 0.0, 1.0]), turn) @ _rotation_about(axis, tilt)
    pose = np.eye(4)
    pose[:3, :3] = rot @ base[:3, :3]
    pose[:3, 3] = rot @ base[:3, 3]
    p = v @ pose[:3, :3].T + pose[:3, 3]
    centre = 0.5 * (p.min(axis=0) + p.max(axis=0))
    pose[0, 3] += offset_r * math.cos(offset_a) - centre[0]
    pose[1, 3] += offset_r * math.sin(offset_a) - centre[1]
    pose[2, 3] -= p[:, 2].min()
    return pose
