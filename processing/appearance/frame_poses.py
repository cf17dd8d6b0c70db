"""Where a photo was taken from, in the mesh frame: the chain room -> table -> pass -> mesh.

Sign conventions (docs/appearance.md has the figure in words):

* Room frame R: the scanner calibration's frame, turntable axis +Z through the
  origin, millimetres.  At firmware table angle ``theta`` (degrees,
  counter-clockwise seen from above) a point ``q`` of the table frame is at
  ``Rz(theta) @ q`` in the room.
* Camera (OpenCV): ``X_cam = R @ X_room + t`` is ``room_to_camera``; x right,
  y down, z forward; pixel (u, v) = (column, row), the centre of pixel (0, 0)
  at (0, 0); distortion is OpenCV's (k1, k2, p1, p2, k3).
* Mesh frame M = pass 1's table frame.  ``T_p`` (the registered pose of pass
  p) maps pass p's table frame into M, so a point ``X`` of M is at
  ``inv(T_p) @ X`` in pass p's table frame, at ``Rz(theta) @ inv(T_p) @ X`` in
  the room and at ``room_to_camera @ Rz(theta) @ inv(T_p) @ X`` in the camera:
  ``mesh_to_camera = room_to_camera @ Rz(theta) @ inv(T_p)``.
* Lamps are fixed in the room; for one frame they are fixed relative to the
  object in M at ``T_p @ Rz(-theta) @ x`` (a point lamp's position, w = 1) or
  ``R(T_p) @ Rz(-theta) @ d`` (a distant lamp's unit direction toward the
  lamp, w = 0).

Examples
--------
>>> import numpy as np
>>> m = mesh_to_camera(np.eye(4), 90.0, np.eye(4))
>>> np.round(m[:3, :3] @ [1.0, 0.0, 0.0], 12).tolist()
[0.0, 1.0, 0.0]
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.common.rotation import rotation_z_deg
from processing.errors import InputError

__all__ = [
    "AppearanceError",
    "MeshLamp",
    "FramePose",
    "mesh_to_camera",
    "camera_centre_mesh",
    "lamp_in_mesh",
    "table_rotation",
]

FRAME_POSE_SCHEMA = "kogei.frame_pose"
FRAME_POSE_VERSION = 1


class AppearanceError(InputError):
    """A frame pose, image, mesh or observation file is unusable; the message names it."""


def _finite(value: Any, shape: tuple[int, ...], what: str) -> NDArray[np.float64]:
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise AppearanceError(f"{what}: not numbers; give an array of shape {shape}") from None
    if a.shape != shape:
        raise AppearanceError(f"{what}: shape {a.shape}, expected {shape}")
    if not np.all(np.isfinite(a)):
        raise AppearanceError(f"{what}: contains NaN or infinity; give finite numbers")
    return a


def _rigid(value: Any, what: str) -> NDArray[np.float64]:
    """A validated 4 x 4 rigid transform (orthonormal rotation, last row 0 0 0 1)."""
    t = _finite(value, (4, 4), what)
    if not np.allclose(t[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise AppearanceError(f"{what}: last row is not 0 0 0 1; give a rigid 4x4 transform")
    r = t[:3, :3]
    if not np.allclose(r.T @ r, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
        raise AppearanceError(f"{what}: rotation part is not a proper rotation; give a rigid 4x4 transform")
    return t


def _angle(value: Any, what: str) -> float:
    try:
        a = float(value)
    except (TypeError, ValueError):
        raise AppearanceError(f"{what}: not a number; give the table angle in degrees") from None
    if not math.isfinite(a):
        raise AppearanceError(f"{what}: not finite; give the table angle in degrees")
    return a


def _inverse_rigid(t: NDArray[np.float64]) -> NDArray[np.float64]:
    out = np.eye(4)
    out[:3, :3] = t[:3, :3].T
    out[:3, 3] = -t[:3, :3].T @ t[:3, 3]
    return out


def table_rotation(table_angle_deg: float) -> NDArray[np.float64]:
    """4 x 4 rotation of the table frame into the room at a firmware table angle.

    Parameters
    ----------
    table_angle_deg
        Firmware table angle, degrees counter-clockwise seen from above.

    Returns
    -------
    ndarray
        ``(4, 4)`` homogeneous ``Rz(theta)``.
    """
    out = np.eye(4)
    out[:3, :3] = rotation_z_deg(_angle(table_angle_deg, "table_angle_deg"))
    return out


def mesh_to_camera(room_to_camera: ArrayLike, table_angle_deg: float, pass_pose: ArrayLike) -> NDArray[np.float64]:
    """The transform from the mesh frame M into the camera for one frame.

    Parameters
    ----------
    room_to_camera
        ``(4, 4)`` rigid transform, room -> camera (``X_cam = R X_room + t``).
    table_angle_deg
        Firmware table angle of the frame, degrees.
    pass_pose
        ``(4, 4)`` registered pose ``T_p`` of the frame's pass (pass table frame -> M).

    Returns
    -------
    ndarray
        ``(4, 4)``: ``room_to_camera @ Rz(theta) @ inv(T_p)``.
    """
    rc = _rigid(room_to_camera, "room_to_camera")
    tp = _rigid(pass_pose, "pass_pose")
    return rc @ table_rotation(table_angle_deg) @ _inverse_rigid(tp)


def camera_centre_mesh(room_to_camera: ArrayLike, table_angle_deg: float, pass_pose: ArrayLike) -> NDArray[np.float64]:
    """The camera's optical centre in the mesh frame for one frame, mm.

    Parameters
    ----------
    room_to_camera
        ``(4, 4)`` rigid transform, room -> camera.
    table_angle_deg
        Firmware table angle of the frame, degrees.
    pass_pose
        ``(4, 4)`` registered pose ``T_p`` of the frame's pass.

    Returns
    -------
    ndarray
        ``(3,)``.
    """
    return _inverse_rigid(mesh_to_camera(room_to_camera, table_angle_deg, pass_pose))[:3, 3]


@dataclass(frozen=True)
class MeshLamp:
    """A lamp seen from the mesh frame for one frame.

    Parameters
    ----------
    name
        The lamp's name.
    kind
        ``"point"`` (``vector`` is a position in M, mm) or ``"distant"``
        (``vector`` is the unit direction toward the lamp in M).
    vector
        ``(3,)``.
    """

    name: str
    kind: str
    vector: NDArray[np.float64] = field(repr=False)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise AppearanceError("lamp name: give a non-empty string")
        if self.kind not in ("point", "distant"):
            raise AppearanceError(f"lamp {self.name!r}: kind {self.kind!r}; give 'point' or 'distant'")
        v = _finite(self.vector, (3,), f"lamp {self.name!r} vector")
        if self.kind == "distant":
            n = np.linalg.norm(v)
            if not 0.999 < n < 1.001:
                raise AppearanceError(f"lamp {self.name!r}: direction has length {n:.4g}; give a unit vector")
        object.__setattr__(self, "vector", v)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form.

        Returns
        -------
        dict
            ``{"name", "kind", "vector"}``.
        """
        return {"name": self.name, "kind": self.kind, "vector": self.vector.tolist()}


def _lamp_field(lamp: Any, key: str) -> Any:
    if isinstance(lamp, Mapping):
        return lamp.get(key)
    return getattr(lamp, key, None)


def lamp_in_mesh(lamp_room: Any, table_angle_deg: float, pass_pose: ArrayLike) -> MeshLamp:
    """A room-fixed lamp moved into the mesh frame for one frame: ``T_p @ Rz(-theta) @ x``.

    Parameters
    ----------
    lamp_room
        A mapping or object with ``name`` and either ``position_mm`` (point
        lamp, room frame) or ``direction`` (distant lamp, unit vector toward
        the lamp, room frame).
    table_angle_deg
        Firmware table angle of the frame, degrees.
    pass_pose
        ``(4, 4)`` registered pose ``T_p`` of the frame's pass.

    Returns
    -------
    MeshLamp
        The lamp's position (point) or direction (distant) in M.
    """
    name = str(_lamp_field(lamp_room, "name") or "lamp")
    room_to_mesh = _rigid(pass_pose, "pass_pose") @ _inverse_rigid(table_rotation(table_angle_deg))
    position, direction = _lamp_field(lamp_room, "position_mm"), _lamp_field(lamp_room, "direction")
    if (position is None) == (direction is None):
        raise AppearanceError(f"lamp {name!r}: give exactly one of position_mm (point) or direction (distant)")
    if position is not None:
        p = _finite(position, (3,), f"lamp {name!r} position_mm")
        return MeshLamp(name, "point", room_to_mesh[:3, :3] @ p + room_to_mesh[:3, 3])
    d = _finite(direction, (3,), f"lamp {name!r} direction")
    n = np.linalg.norm(d)
    if not 0.999 < n < 1.001:
        raise AppearanceError(f"lamp {name!r}: direction has length {n:.4g}; give a unit vector")
    return MeshLamp(name, "distant", room_to_mesh[:3, :3] @ (d / n))


def _image_size(value: Any, what: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in value)
        ok = all(float(x) == int(x) for x in value)
    except (TypeError, ValueError):
        raise AppearanceError(f"{what}: give (width, height) in pixels") from None
    if not ok or not (1 <= w <= 100_000 and 1 <= h <= 100_000):
        raise AppearanceError(f"{what}: {tuple(value)!r}; give two whole numbers of pixels in 1..100000")
    return w, h


def _intrinsics(k_value: Any, dist_value: Any, what: str) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    k = _finite(k_value, (3, 3), f"{what} K")
    if k[0, 0] <= 0 or k[1, 1] <= 0 or k[0, 1] != 0 or np.any(k[2] != [0.0, 0.0, 1.0]) or k[1, 0] != 0:
        raise AppearanceError(f"{what} K: give [[fx,0,cx],[0,fy,cy],[0,0,1]] with fx, fy > 0")
    dist = _finite(dist_value, (5,), f"{what} dist")
    return k, dist


@dataclass(frozen=True)
class FramePose:
    """One photo posed on the mesh: its camera, where it looked from and its lamps, all in M.

    Parameters
    ----------
    name
        The frame's name (a file name or id).
    pass_index
        The pass the frame was shot in (1-based, as the registration numbers them).
    table_angle_deg
        Firmware table angle, degrees.
    image_size
        ``(width, height)`` in pixels.
    K
        ``(3, 3)`` intrinsics for that image size.
    dist
        ``(5,)`` OpenCV distortion (k1, k2, p1, p2, k3).
    mesh_to_camera
        ``(4, 4)`` rigid transform M -> camera (:func:`mesh_to_camera`).
    lamps
        The lamps in M for this frame (:func:`lamp_in_mesh`).
    """

    name: str
    pass_index: int
    table_angle_deg: float
    image_size: tuple[int, int]
    K: NDArray[np.float64] = field(repr=False)
    dist: NDArray[np.float64] = field(repr=False)
    mesh_to_camera: NDArray[np.float64] = field(repr=False)
    lamps: tuple[MeshLamp, ...] = ()

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise AppearanceError("frame name: give a non-empty string")
        what = f"frame {self.name!r}"
        if isinstance(self.pass_index, bool) or not isinstance(self.pass_index, (int, np.integer)) \
                or self.pass_index < 0:
            raise AppearanceError(f"{what} pass_index: give a whole number >= 0")
        k, dist = _intrinsics(self.K, self.dist, what)
        lamps = tuple(self.lamps)
        if not all(isinstance(lamp, MeshLamp) for lamp in lamps):
            raise AppearanceError(f"{what} lamps: give MeshLamp objects (lamp_in_mesh)")
        object.__setattr__(self, "pass_index", int(self.pass_index))
        object.__setattr__(self, "table_angle_deg", _angle(self.table_angle_deg, f"{what} table_angle_deg"))
        object.__setattr__(self, "image_size", _image_size(self.image_size, f"{what} image_size"))
        object.__setattr__(self, "K", k)
        object.__setattr__(self, "dist", dist)
        object.__setattr__(self, "mesh_to_camera", _rigid(self.mesh_to_camera, f"{what} mesh_to_camera"))
        object.__setattr__(self, "lamps", lamps)

    @classmethod
    def from_chain(cls, name: str, pass_index: int, room_to_camera: ArrayLike, table_angle_deg: float,
                   pass_pose: ArrayLike, K: ArrayLike, dist: ArrayLike, image_size: Sequence[int],
                   lamps_room: Sequence[Any] = ()) -> FramePose:
        """A frame pose from the room calibration, the table angle and the pass pose.

        Parameters
        ----------
        name, pass_index, table_angle_deg, K, dist, image_size
            As the fields.
        room_to_camera
            ``(4, 4)`` room -> camera.
        pass_pose
            ``(4, 4)`` registered pose ``T_p`` of the pass.
        lamps_room
            Lamps in the room (see :func:`lamp_in_mesh`).

        Returns
        -------
        FramePose
        """
        lamps = tuple(lamp_in_mesh(lamp, table_angle_deg, pass_pose) for lamp in lamps_room)
        return cls(name, pass_index, table_angle_deg, tuple(image_size), K, dist,
                   mesh_to_camera(room_to_camera, table_angle_deg, pass_pose), lamps)

    @property
    def camera_centre_mm(self) -> NDArray[np.float64]:
        """The optical centre in M, ``(3,)`` mm."""
        return _inverse_rigid(self.mesh_to_camera)[:3, 3]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (schema ``kogei.frame_pose``, version 1).

        Returns
        -------
        dict
        """
        return {"schema": FRAME_POSE_SCHEMA, "version": FRAME_POSE_VERSION, "name": self.name,
                "pass_index": self.pass_index, "table_angle_deg": self.table_angle_deg,
                "image_size": list(self.image_size), "K": self.K.tolist(), "dist": self.dist.tolist(),
                "mesh_to_camera": self.mesh_to_camera.tolist(), "lamps": [lp.to_dict() for lp in self.lamps]}

    @classmethod
    def from_dict(cls, data: Any) -> FramePose:
        """A frame pose from untrusted JSON data, validated.

        Parameters
        ----------
        data
            What :meth:`to_dict` wrote.

        Returns
        -------
        FramePose

        Raises
        ------
        AppearanceError
            One line naming the field when the data are malformed.
        """
        if not isinstance(data, Mapping):
            raise AppearanceError("frame pose: not a JSON object; give what FramePose.to_dict wrote")
        if data.get("schema") != FRAME_POSE_SCHEMA or data.get("version") != FRAME_POSE_VERSION:
            raise AppearanceError(f"frame pose: schema/version {data.get('schema')!r}/{data.get('version')!r}; "
                                  f"expected {FRAME_POSE_SCHEMA!r}/{FRAME_POSE_VERSION}")
        missing = {"name", "pass_index", "table_angle_deg", "image_size", "K", "dist", "mesh_to_camera",
                   "lamps"} - set(data)
        if missing:
            raise AppearanceError(f"frame pose: missing field(s) {', '.join(sorted(missing))}")
        lamps = data["lamps"]
        if not isinstance(lamps, list) or not all(isinstance(lp, Mapping) for lp in lamps):
            raise AppearanceError(f"frame pose {data['name']!r} lamps: give a list of objects")
        return cls(data["name"], data["pass_index"], data["table_angle_deg"], data["image_size"], data["K"],
                   data["dist"], data["mesh_to_camera"],
                   tuple(MeshLamp(lp.get("name"), lp.get("kind"), lp.get("vector")) for lp in lamps))
