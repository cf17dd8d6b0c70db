"""Emulator of the laser line-profile sensor on a pseudo-terminal pair.

``docs/protocols.md`` ("Laser profiler"): ASCII command lines answered by ``OK,<cmd>[,...]`` or
``ER,<cmd>,<code>``, profiles as binary ``KPRF`` frames (little-endian
header with length, sequence counter and timestamp, int32 micrometre points,
``INT32_MIN`` for invalid points, CRC-32 of everything before it), a ring
buffer of recent frames for ``RSND,<seq>``, and ``STRT``/``STOP``
streaming at the configured rate.

Profiles come from a pluggable *source*, a callable returning
``(x_um, z_um, valid)`` arrays: :func:`synthetic_source` (a flat plane with a
spherical cap, closed form) or :class:`RaycastSource` (an Open3D ray cast of
a mesh on the turntable at the table's current angle, with range noise, a
field-of-view and range limit, camera occlusion, and dropouts where the
surface turns away from the sensor, a stand-in for a metal's specular lobe
sending the laser light elsewhere).  The sensor's pose in the room is a 4 x 4
``sensor_to_room`` transform (:func:`default_sensor_to_room` by default; the
convention is in :class:`RaycastSource` and ``docs/protocols.md``).

Faults come from a shared :class:`mocks.faults.Faults` (garbage before
replies or frames, corrupted or dropped frames, slow replies, unplug on a
command, reset on a command).

Examples
--------
>>> import os, time
>>> with ProfilerFirmware() as fw:
...     fd = os.open(fw.path, os.O_RDWR | os.O_NOCTTY)
...     _ = os.write(fd, b"ID\\r\\n")
...     time.sleep(0.2)
...     print(os.read(fd, 100).decode().strip())
...     os.close(fd)
OK,ID,KP-200,SN000001,1.3.0
"""

from __future__ import annotations

import math
import os
import struct
import threading
import time
import zlib
from collections import OrderedDict
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mocks.faults import Faults
from mocks.pty_link import PtyDevice

__all__ = [
    "MODEL",
    "VERSION",
    "SERIAL",
    "INVALID",
    "MAX_POINTS",
    "Source",
    "pack_frame",
    "synthetic_source",
    "RaycastSource",
    "default_sensor_to_room",
    "check_sensor_pose",
    "ProfilerFirmware",
]

MODEL = "KP-200"
VERSION = "1.3.0"
SERIAL = "SN000001"
#: Invalid-point sentinel (``INT32_MIN``) for both coordinates.
INVALID = -(2**31)
#: Most points a frame may carry.
MAX_POINTS = 4096
_HEADER = struct.Struct("<4sHIIQI")  # magic, version, length, seq, timestamp_us, n

Source = Callable[[], tuple[ArrayLike, ArrayLike, ArrayLike]]


def pack_frame(seq: int, timestamp_us: int, x_um: ArrayLike, z_um: ArrayLike, valid: ArrayLike) -> bytes:
    """Encode one profile as a ``KPRF`` frame (see ``docs/protocols.md``).

    Parameters
    ----------
    seq
        Sequence counter (taken modulo 2^32).
    timestamp_us
        Sensor timestamp in microseconds.
    x_um, z_um
        Coordinates in micrometres (rounded to integers).
    valid
        Points without a return are written as :data:`INVALID`.

    Examples
    --------
    >>> f = pack_frame(7, 0, [1.0], [2.0], [True])
    >>> len(f), f[:4], zlib.crc32(f[:-4]) == int.from_bytes(f[-4:], "little")
    (38, b'KPRF', True)
    """
    x = np.asarray(x_um, dtype=np.float64)
    z = np.asarray(z_um, dtype=np.float64)
    ok = np.asarray(valid, dtype=bool) & np.isfinite(x) & np.isfinite(z)
    pts = np.full((x.size, 2), INVALID, dtype="<i4")
    pts[ok, 0] = np.clip(np.rint(x[ok]), INVALID + 1, 2**31 - 1)
    pts[ok, 1] = np.clip(np.rint(z[ok]), INVALID + 1, 2**31 - 1)
    payload = pts.tobytes()
    head = _HEADER.pack(b"KPRF", 1, len(payload), seq % 2**32, timestamp_us % 2**64, x.size)
    body = head + payload
    return body + struct.pack("<I", zlib.crc32(body))


def synthetic_source(
    n_points: int = 640,
    width_mm: float = 80.0,
    standoff_mm: float = 150.0,
    sphere_radius_mm: float = 20.0,
    noise_um: float = 0.0,
    seed: int = 0,
) -> Source:
    """A flat plane at ``standoff_mm`` with a spherical cap bulging toward the sensor.

    Closed form: ``z = standoff - sqrt(R^2 - x^2)`` for ``|x| < R``, else
    ``standoff``; ``x`` evenly spaced over ``width_mm``.

    Parameters
    ----------
    n_points
        Points per profile.
    width_mm
        Extent of ``x`` (mm), centred on 0.
    standoff_mm
        Range of the plane (mm).
    sphere_radius_mm
        Radius of the sphere centred on the plane (0 for a flat profile).
    noise_um
        Standard deviation of Gaussian range noise (micrometres).
    seed
        Seed of the noise generator (owned by the returned source).

    Examples
    --------
    >>> x, z, v = synthetic_source(n_points=3, width_mm=20.0, sphere_radius_mm=20.0)()
    >>> x.tolist(), np.round(z, 3).tolist(), v.tolist()
    ([-10000.0, 0.0, 10000.0], [132679.492, 130000.0, 132679.492], [True, True, True])
    """
    if not isinstance(n_points, int) or not 1 <= n_points <= MAX_POINTS:
        raise ValueError(f"n_points must be an integer in 1..{MAX_POINTS}, got {n_points!r}")
    for name, v in (("width_mm", width_mm), ("standoff_mm", standoff_mm)):
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be positive (mm), got {v!r}")
    if not (math.isfinite(sphere_radius_mm) and 0 <= sphere_radius_mm < standoff_mm):
        raise ValueError(f"sphere_radius_mm must be in [0, standoff_mm), got {sphere_radius_mm!r}")
    rng = np.random.default_rng(seed)
    x = np.linspace(-width_mm / 2, width_mm / 2, n_points)
    cap = np.sqrt(np.clip(sphere_radius_mm**2 - x * x, 0.0, None))
    z = standoff_mm - cap

    def source() -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
        zz = z * 1000.0
        if noise_um > 0:
            zz = zz + rng.normal(0.0, noise_um, zz.shape)
        return x * 1000.0, zz, np.ones(n_points, dtype=bool)

    return source


def default_sensor_to_room(standoff_mm: float = 200.0, height_mm: float = 0.0) -> NDArray[np.float64]:
    """The sensor pose of :class:`RaycastSource`'s default geometry (sensor -> room, 4 x 4, mm).

    Columns of the rotation: ``X_s = (0, 0, 1)`` (along the laser line, up),
    ``Y_s = (0, 1, 0)`` (toward the triangulation camera), ``Z_s = (-1, 0, 0)``
    (the range direction, toward the table axis); translation: the emitter
    at ``(standoff_mm, 0, height_mm)``.

    Examples
    --------
    >>> default_sensor_to_room(250.0, 40.0)[:3].tolist()
    [[0.0, 0.0, -1.0, 250.0], [0.0, 1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 40.0]]
    """
    m = np.eye(4)
    m[:3, 0] = (0.0, 0.0, 1.0)
    m[:3, 1] = (0.0, 1.0, 0.0)
    m[:3, 2] = (-1.0, 0.0, 0.0)
    m[:3, 3] = (float(standoff_mm), 0.0, float(height_mm))
    return m


def check_sensor_pose(sensor_to_room: ArrayLike, name: str = "sensor_to_room") -> NDArray[np.float64]:
    """``sensor_to_room`` as a float 4 x 4 rigid transform; a ``ValueError`` naming ``name`` otherwise.

    Examples
    --------
    >>> check_sensor_pose(np.eye(4)).shape
    (4, 4)
    >>> check_sensor_pose(np.diag([1.0, 1.0, -1.0, 1.0]))
    Traceback (most recent call last):
    ...
    ValueError: sensor_to_room must be a rigid transform: its 3 x 3 part must be a rotation (orthonormal, determinant +1)
    """
    m = np.asarray(sensor_to_room, dtype=np.float64)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise ValueError(f"{name} must be a finite 4 x 4 matrix (mm), got shape {m.shape}")
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0]):
        raise ValueError(f"{name} must have the last row (0, 0, 0, 1), got {m[3].tolist()}")
    r = m[:3, :3]
    if not np.allclose(r.T @ r, np.eye(3), atol=1e-6) or np.linalg.det(r) <= 0:
        raise ValueError(f"{name} must be a rigid transform: its 3 x 3 part must be a rotation "
                         "(orthonormal, determinant +1)")
    return m


class RaycastSource:
    """Line profiles of a triangle mesh on the turntable, by Open3D ray casting.

    Room frame: the table axis is ``+Z`` through the origin (table top at
    ``z = 0`` when the scene has one); the mesh turns with the table
    (``angle_deg()``, counter-clockwise seen from above), so a point
    ``p`` of the mesh is at ``Rz(angle) p`` in the room.  Sensor frame:
    ``sensor_to_room`` (4 x 4) has columns ``X_s`` (along the laser line),
    ``Y_s`` (toward the triangulation camera) and ``Z_s`` (the range
    direction, away from the sensor) and translation ``origin_s`` (the
    emitter); a profile point ``(x_mm, z_mm)`` is at
    ``origin_s + x_mm X_s + z_mm Z_s`` in the room.  The laser fans
    ``n_points`` rays over ``fov_deg`` in the ``X_s``-``Z_s`` plane, ray
    ``theta`` along ``sin(theta) X_s + cos(theta) Z_s``, so a hit at
    distance ``t`` has ``x = t sin(theta)``, ``z = t cos(theta)``; the camera
    sits ``baseline_mm`` from the emitter along ``Y_s``.  The default pose
    (:func:`default_sensor_to_room`) is ``X_s = (0, 0, 1)``,
    ``Y_s = (0, 1, 0)``, ``Z_s = (-1, 0, 0)``, emitter
    ``(standoff_mm, 0, height_mm)``: a vertical laser plane through the table
    axis, aimed at ``-X``.

    A point is invalid when the ray misses, its range is outside
    ``range_mm``, the camera's view of it is blocked (occlusion), or the
    angle between the surface normal and the direction back to the emitter
    exceeds ``max_incidence_deg`` (the specular-metal stand-in); valid points
    get Gaussian range noise ``noise_um``.

    Parameters
    ----------
    vertices
        (V, 3) mesh vertices in mm, table frame at angle 0.
    triangles
        (T, 3) vertex indices.
    angle_deg
        Callable returning the current table angle (e.g.
        ``HorusFirmware.angle_deg`` via ``lambda: fw.angle_deg``).
    n_points, fov_deg, baseline_mm, range_mm, max_incidence_deg, noise_um
        Sensor model, see above.
    standoff_mm, height_mm
        Emitter position of the default pose (default 200 mm and 0 mm); not
        allowed together with ``sensor_to_room``.
    seed
        Noise seed: an integer (one generator, advancing with every profile)
        or a callable ``seed(angle_deg) -> int`` giving each profile its own
        generator (the same angle, the same noise).
    sensor_to_room
        4 x 4 rigid sensor pose in the room (mm); default
        :func:`default_sensor_to_room`.

    Examples
    --------
    >>> v = np.array([[0, -50, -50], [0, 50, -50], [0, 0, 80]], float)
    >>> src = RaycastSource(v, np.array([[0, 1, 2]]), lambda: 0.0, n_points=3, fov_deg=10.0)
    >>> x, z, ok = src()
    >>> ok.tolist(), float(z[1])
    ([True, True, True], 200000.0)
    """

    def __init__(
        self,
        vertices: ArrayLike,
        triangles: ArrayLike,
        angle_deg: Callable[[], float],
        *,
        n_points: int = 640,
        fov_deg: float = 30.0,
        standoff_mm: float | None = None,
        height_mm: float | None = None,
        baseline_mm: float = 60.0,
        range_mm: tuple[float, float] = (100.0, 300.0),
        max_incidence_deg: float = 70.0,
        noise_um: float = 0.0,
        seed: int | Callable[[float], int] = 0,
        sensor_to_room: ArrayLike | None = None,
    ) -> None:
        import open3d as o3d

        v = np.asarray(vertices, dtype=np.float64)
        t = np.asarray(triangles)
        if v.ndim != 2 or v.shape[1] != 3 or not np.all(np.isfinite(v)):
            raise ValueError(f"vertices must be a finite (V, 3) array in mm, got shape {v.shape}")
        if t.ndim != 2 or t.shape[1] != 3 or t.size == 0 or t.min() < 0 or t.max() >= len(v):
            raise ValueError(f"triangles must be a non-empty (T, 3) array of indices < {len(v)}")
        if not callable(angle_deg):
            raise ValueError("angle_deg must be a callable returning the table angle in degrees")
        if not isinstance(n_points, int) or not 1 <= n_points <= MAX_POINTS:
            raise ValueError(f"n_points must be an integer in 1..{MAX_POINTS}, got {n_points!r}")
        if not 0 < fov_deg < 170:
            raise ValueError(f"fov_deg must be in (0, 170) degrees, got {fov_deg!r}")
        if not 0 < range_mm[0] < range_mm[1]:
            raise ValueError(f"range_mm must be (near, far) with 0 < near < far, got {range_mm!r}")
        if not 0 < max_incidence_deg <= 90:
            raise ValueError(f"max_incidence_deg must be in (0, 90], got {max_incidence_deg!r}")
        if not (math.isfinite(noise_um) and noise_um >= 0):
            raise ValueError(f"noise_um must be a finite standard deviation >= 0 (micrometres), got {noise_um!r}")
        if not (math.isfinite(baseline_mm) and baseline_mm >= 0):
            raise ValueError(f"baseline_mm must be a finite distance >= 0 (mm), got {baseline_mm!r}")
        if not (callable(seed) or isinstance(seed, (int, np.integer))):
            raise ValueError(f"seed must be an integer or a callable seed(angle_deg) -> int, got {seed!r}")
        if sensor_to_room is None:
            pose = default_sensor_to_room(200.0 if standoff_mm is None else standoff_mm,
                                          0.0 if height_mm is None else height_mm)
            check_sensor_pose(pose, "standoff_mm/height_mm")
        else:
            if standoff_mm is not None or height_mm is not None:
                raise ValueError("give either sensor_to_room or standoff_mm/height_mm, not both "
                                 "(the pose's translation is the emitter)")
            pose = check_sensor_pose(sensor_to_room)
        self._o3d = o3d
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(t.astype(np.uint32)))
        self.angle_deg = angle_deg
        self.n_points = n_points
        self.sensor_to_room = pose
        self.emitter = pose[:3, 3].copy()
        self.camera = self.emitter + baseline_mm * pose[:3, 1]
        self.range_mm = (float(range_mm[0]), float(range_mm[1]))
        self.cos_max = math.cos(math.radians(max_incidence_deg))
        self.noise_um = float(noise_um)
        self._seed = seed
        self._rng = None if callable(seed) else np.random.default_rng(int(seed))
        theta = np.radians(np.linspace(-fov_deg / 2, fov_deg / 2, n_points))
        self._sin, self._cos = np.sin(theta), np.cos(theta)
        self._dirs = self._sin[:, None] * pose[:3, 0] + self._cos[:, None] * pose[:3, 2]

    def __call__(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
        return self.profile_at(float(self.angle_deg()))

    def profile_at(self, angle_deg: float) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
        """The profile with the table at ``angle_deg``: ``(x_um, z_um, valid)``, NaN where invalid.

        Examples
        --------
        >>> v = np.array([[0, -50, -50], [0, 50, -50], [0, 0, 80]], float)
        >>> src = RaycastSource(v, np.array([[0, 1, 2]]), lambda: 0.0, n_points=3, fov_deg=10.0,
        ...                     noise_um=50.0, seed=lambda a: 7)
        >>> bool(np.array_equal(src.profile_at(0.0)[1], src.profile_at(0.0)[1]))
        True
        """
        a = math.radians(angle_deg)
        c, s = math.cos(a), math.sin(a)
        to_obj = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # rotation by -angle
        o = to_obj @ self.emitter
        d = self._dirs @ to_obj.T
        rays = np.concatenate([np.broadcast_to(o, d.shape), d], axis=1).astype(np.float32)
        ans = self._scene.cast_rays(self._o3d.core.Tensor(rays))
        t_hit = ans["t_hit"].numpy().astype(np.float64)
        normal = ans["primitive_normals"].numpy().astype(np.float64)
        hit = np.isfinite(t_hit)
        t_safe = np.where(hit, t_hit, 0.0)
        p = o + d * t_safe[:, None]
        # incidence: the normal must face the emitter within the allowed cone
        cos_i = np.abs(np.sum(normal * -d, axis=1))
        ok = hit & (cos_i >= self.cos_max)
        # occlusion: the camera must see the lit point
        cam = to_obj @ self.camera
        to_cam = cam - p
        dist = np.linalg.norm(to_cam, axis=1)
        dirc = to_cam / np.maximum(dist, 1e-12)[:, None]
        start = p + dirc * 1e-3
        shadow = np.concatenate([start, dirc], axis=1).astype(np.float32)
        t_occ = self._scene.cast_rays(self._o3d.core.Tensor(shadow))["t_hit"].numpy()
        ok &= ~(t_occ < dist - 2e-3)
        # sensor frame: z the range along Z_s, x along the laser line X_s
        rng_mm = t_safe * self._cos
        x_mm = t_safe * self._sin
        ok &= (rng_mm >= self.range_mm[0]) & (rng_mm <= self.range_mm[1])
        z_um = rng_mm * 1000.0
        if self.noise_um > 0:
            if self._rng is None:
                gen = np.random.default_rng(int(self._seed(angle_deg)))  # type: ignore[operator]
            else:
                gen = self._rng
            z_um = z_um + gen.normal(0.0, self.noise_um, z_um.shape)
        x_um = x_mm * 1000.0
        return np.where(ok, x_um, np.nan), np.where(ok, z_um, np.nan), ok


class _Reset(Exception):
    pass


class ProfilerFirmware(PtyDevice):
    """The profile sensor's firmware, served from a thread on a pty pair.

    Parameters
    ----------
    link_path
        Stable symlink to the current ``/dev/pts/N``; ``None`` for a private
        temporary path.
    source
        Profile source, ``source() -> (x_um, z_um, valid)`` (default
        :func:`synthetic_source`).
    faults
        Shared fault switches (a fresh all-off :class:`Faults` if omitted).
    buffer_frames
        Frames kept for ``RSND``.
    model, version, serial
        Identity reported by ``ID`` and the banner.

    Attributes
    ----------
    received
        Every command line, for tests.
    frames_sent
        Number of frames generated (excluding re-sends).
    """

    _thread_name = "profiler-firmware"

    def __init__(
        self,
        link_path: str | os.PathLike[str] | None = None,
        *,
        source: Source | None = None,
        faults: Faults | None = None,
        buffer_frames: int = 16,
        model: str = MODEL,
        version: str = VERSION,
        serial: str = SERIAL,
    ) -> None:
        if source is not None and not callable(source):
            raise ValueError("source must be a callable returning (x_um, z_um, valid)")
        if not isinstance(buffer_frames, int) or buffer_frames < 1:
            raise ValueError(f"buffer_frames must be a positive integer, got {buffer_frames!r}")
        self._open_link(link_path, "profiler-", "profiler")
        self.source: Source = source if source is not None else synthetic_source()
        self.faults = faults if faults is not None else Faults()
        self.buffer_frames = buffer_frames
        self.model, self.version, self.serial = model, version, serial
        self.received: list[str] = []
        self.resets = 0
        self.frames_sent = 0
        self._lock = threading.RLock()
        self._replug_at: float | None = None
        self._t0 = time.monotonic()
        self._power_on()

    # ----------------------------------------------------------- public state
    @property
    def laser_on(self) -> bool:
        """True after ``LAS,1``."""
        with self._lock:
            return self._laser

    @property
    def settings(self) -> dict[str, int]:
        """Current ``EXP`` (us) and ``RATE`` (Hz)."""
        with self._lock:
            return dict(self._settings)

    @property
    def seq(self) -> int:
        """Sequence number the next frame will carry."""
        with self._lock:
            return self._seq

    def set_seq(self, seq: int) -> None:
        """Set the next sequence number (to test the 2^32 wrap)."""
        with self._lock:
            self._seq = seq % 2**32

    # ---------------------------------------------------------------- control
    def reset(self) -> None:
        """Spontaneous reset: state lost, banner sent."""
        with self._lock:
            self._reset()

    # ------------------------------------------------------------- internals
    def _power_on(self) -> None:
        self._settings = {"EXP": 500, "RATE": 100}
        self._laser = False
        self._streaming = False
        self._next_stream = 0.0
        self._seq = 0
        self._ring: OrderedDict[int, bytes] = OrderedDict()
        self._inbuf = bytearray()
        self._out = bytearray()
        self._pending: list[tuple[float, bytes]] = []

    def _reset(self) -> None:
        sent = self._out  # bytes already on the wire survive the reset
        self._power_on()
        self._out = sent
        self.resets += 1
        self._out += f"PROFILER {self.model} {self.version}\r\n".encode()

    def _queue(self, data: bytes, delay: float = 0.0) -> None:
        due = time.monotonic() + max(0.0, delay)
        if self._pending and self._pending[-1][0] > due:
            due = self._pending[-1][0]  # keep order
        self._pending.append((due, data))

    def _reply(self, text: str, frame: bytes = b"") -> None:
        if self.faults.take("drop_replies"):
            return
        data = text.encode() + b"\r\n"
        if self.faults.take("garbage_replies"):
            data = bytes(self.faults.garbage) + data
        self._queue(data + frame, self.faults.reply_delay_s)

    def _new_frame(self) -> tuple[int, bytes]:
        x, z, v = self.source()
        x = np.asarray(x, dtype=np.float64).ravel()
        z = np.asarray(z, dtype=np.float64).ravel()
        v = np.asarray(v, dtype=bool).ravel()
        if not (x.shape == z.shape == v.shape) or x.size > MAX_POINTS:
            raise _Error("99")
        seq = self._seq
        self._seq = (self._seq + 1) % 2**32
        t_us = int((time.monotonic() - self._t0) * 1e6)
        frame = pack_frame(seq, t_us, x, z, v)
        self._ring[seq] = frame
        while len(self._ring) > self.buffer_frames:
            self._ring.popitem(last=False)
        self.frames_sent += 1
        return seq, frame

    def _transmit(self, frame: bytes) -> bytes:
        """The frame as it goes over the wire (faults applied)."""
        if self.faults.take("drop_frames"):
            return b""
        if self.faults.take("corrupt_frames"):
            b = bytearray(frame)
            b[_HEADER.size + (len(b) - _HEADER.size - 4) // 2] ^= 0x5A  # a payload byte (CRC too if empty)
            frame = bytes(b)
        if self.faults.take("garbage_frames"):
            frame = bytes(self.faults.garbage) + frame
        return frame

    def _next_wait(self, now: float) -> float:
        wait = 0.02
        if self._pending:
            wait = min(wait, self._pending[0][0] - now)
        return wait

    def _tick(self, now: float) -> None:
        while self._pending and self._pending[0][0] <= now:
            self._out += self._pending.pop(0)[1]
        if self._streaming and now >= self._next_stream:
            self._next_stream = now + 1.0 / self._settings["RATE"]
            if self._laser:
                _, frame = self._new_frame()
                self._out += self._transmit(frame)
        self._flush()

    def _flush(self) -> None:
        if self._out and self.link.plugged:
            try:
                n = os.write(self.link.master_fd, bytes(self._out))
                del self._out[:n]
            except (BlockingIOError, InterruptedError):
                pass
            except OSError:
                self._out.clear()

    def _receive(self, data: bytes, now: float) -> None:
        if self.faults.mute:
            return
        for b in data:
            if b in (0x0A, 0x0D):
                line = self._inbuf.decode("ascii", "replace").strip()
                self._inbuf.clear()
                if line:
                    self._execute(line)
                    if not self.link.plugged:
                        return
            elif len(self._inbuf) < 64:
                self._inbuf.append(b)
            else:  # over-long line: answered as unknown when it ends
                self._inbuf = bytearray(b"?")

    def _execute(self, line: str) -> None:
        self.received.append(line)
        if self.faults.take("unplug_on_command"):
            self.link.unplug()
            after = self.faults.replug_after_s
            self._replug_at = None if after is None else time.monotonic() + after
            return
        if self.faults.take("reset_on_command"):
            self._reset()
            return
        fields = line.split(",")
        cmd = fields[0]
        try:
            self._dispatch(cmd, fields[1:])
        except _Error as exc:
            self._reply(f"ER,{cmd},{exc}")

    def _dispatch(self, cmd: str, args: list[str]) -> None:
        def nargs(n: int) -> None:
            if len(args) != n:
                raise _Error("02")

        def integer(s: str, lo: int, hi: int) -> int:
            try:
                v = int(s)
            except ValueError:
                raise _Error("03") from None
            if not lo <= v <= hi:
                raise _Error("03")
            return v

        if cmd == "ID":
            nargs(0)
            return self._reply(f"OK,ID,{self.model},{self.serial},{self.version}")
        if cmd == "RST":
            nargs(0)
            self._reply("OK,RST")
            self._pending_to_out()
            return self._reset()
        if cmd == "STOP":
            nargs(0)
            self._streaming = False
            return self._reply("OK,STOP")
        if cmd == "SET":
            if self._streaming:
                raise _Error("04")
            nargs(2)
            limits = {"EXP": (10, 100_000), "RATE": (1, 2000)}
            if args[0] not in limits:
                raise _Error("03")
            self._settings[args[0]] = integer(args[1], *limits[args[0]])
            return self._reply(f"OK,SET,{args[0]},{self._settings[args[0]]}")
        if cmd == "GET":
            nargs(1)
            if args[0] in self._settings:
                return self._reply(f"OK,GET,{args[0]},{self._settings[args[0]]}")
            if args[0] == "LAS":
                return self._reply(f"OK,GET,LAS,{int(self._laser)}")
            raise _Error("03")
        if cmd == "LAS":
            nargs(1)
            self._laser = integer(args[0], 0, 1) == 1
            return self._reply(f"OK,LAS,{int(self._laser)}")
        if cmd == "TRG":
            nargs(0)
            if self._streaming or not self._laser:
                raise _Error("04")
            seq, frame = self._new_frame()
            return self._reply(f"OK,TRG,{seq}", self._transmit(frame))
        if cmd == "RSND":
            nargs(1)
            seq = integer(args[0], 0, 2**32 - 1)
            if seq not in self._ring:
                raise _Error("03")
            return self._reply(f"OK,RSND,{seq}", self._transmit(self._ring[seq]))
        if cmd == "STRT":
            nargs(0)
            if not self._laser:
                raise _Error("04")
            self._streaming = True
            self._next_stream = time.monotonic()
            return self._reply("OK,STRT")
        raise _Error("01")

    def _pending_to_out(self) -> None:
        for _, data in self._pending:
            self._out += data
        self._pending.clear()


class _Error(Exception):
    pass
