"""The simulated scan station: one world, a turntable, a laser profiler, a camera and a hot folder.

:class:`SimulatedStation` owns one :class:`mocks.world.World` and serves, on
pseudo-terminal pairs, the Horus turntable (:class:`mocks.horus_firmware.HorusFirmware`)
and the line-profile sensor (:class:`mocks.profiler_firmware.ProfilerFirmware`),
plus a fake ``gphoto2`` (:mod:`mocks.fake_gphoto2`) and a hot folder
(:class:`mocks.hotfolder_writer.HotFolderWriter`), all looking at that world.
docs/simulator.md describes it; in short:

* **Geometry** (:mod:`mocks.station_geometry`): the table axis is the room's
  ``+Z``; the object is at ``Rz(angle) @ pose`` and the profiler at
  :attr:`SimulatedStation.sensor_to_room`.
* **Wiring.**  The profiler's laser line is powered through the Horus
  board's laser output ``T1``: while ``T1`` is off (never switched on,
  switched off by ``M70 T1``, a reset, an unplugged board, or the firmware's
  watchdog) every point of a profile is invalid.
* **Determinism.**  Range noise is seeded per (station seed, placement,
  table angle) and camera noise per (station seed, placement, frame kind,
  table angle) (:mod:`mocks.noise_seed`): a profile or frame re-taken after a
  fault is identical to the one a fault-free run gets.
* **Placements.**  :meth:`SimulatedStation.place` ``(n)``: placement 1 is the
  world's base pose resting on the table; placement ``n >= 2`` a
  pseudo-random rest pose (:func:`mocks.station_geometry.placement_pose`);
  a calibration world's own placement instead where it has one
  (:meth:`mocks.world.World.fixed_placement_pose`: the ChArUco board's tilts,
  the mirror sphere's offsets).  A
  new placement puts the colour chart in view for the next camera frame
  (gphoto2 or hot folder); later frames show the object at the current table
  angle.
* **Cameras in step.**  The turntable calls back when a move has finished,
  before its ``ok``; the station then writes the angle into the fake
  gphoto2's configuration, so a capture after the ``ok`` sees the new angle.
* **Control folder** (:mod:`mocks.station_requests`).  Another process (the
  capture command's hooks) asks for ``place`` and ``shoot`` through request
  files in :attr:`SimulatedStation.control_dir`; :func:`request_place` and
  :func:`request_shoot` are the client side.
* **Faults** (:mod:`mocks.faults`): :meth:`SimulatedStation.apply_faults`
  takes what :func:`parse_faults` reads from ``kogei mock --faults``.

The names of those modules that callers import from here
(:data:`FAULT_NAMES`, :func:`parse_faults`, :func:`placement_pose`,
:func:`request_place`, :class:`StationError` ...) are re-exported.

Examples
--------
>>> from mocks.world import World
>>> with SimulatedStation(World.hawk(2_000), seed=1) as st:
...     os.path.realpath(st.turntable_path).startswith("/dev/pts/"), st.placement
(True, 1)
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
import shutil
import tempfile
import threading
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mocks.faults import FAULT_NAMES, Faults, FaultSpecError, HotFolderFaults, format_faults, parse_faults
from mocks.noise_seed import frame_seed, profile_seed
from mocks.station_geometry import placement_pose, rest_on_table, station_sensor_to_room, table_disc
from mocks.station_requests import StationError, StationTimeout, request_place, request_shoot, serve_requests

__all__ = [
    "SimulatedStation",
    "StationError",
    "StationTimeout",
    "FaultSpecError",
    "HotFolderFaults",
    "FAULT_NAMES",
    "station_sensor_to_room",
    "table_disc",
    "rest_on_table",
    "placement_pose",
    "parse_faults",
    "format_faults",
    "request_place",
    "request_shoot",
]


# ------------------------------------------------------------------ the station
def _check_settings(seed: Any, time_scale: Any, exposure_s: Any, poll_s: Any, laser_watchdog_s: Any,
                    hotfolder_chunks: Any, hotfolder_interval_s: Any) -> None:
    """Refuse station settings out of range (``ValueError`` naming the parameter)."""
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    if not (isinstance(time_scale, (int, float)) and math.isfinite(time_scale) and time_scale >= 0):
        raise ValueError(f"time_scale must be >= 0 real seconds per simulated second (0 = instant motion), "
                         f"got {time_scale!r}")
    for name, v in (("exposure_s", exposure_s), ("poll_s", poll_s), ("laser_watchdog_s", laser_watchdog_s)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be a positive number of seconds, got {v!r}")
    if not isinstance(hotfolder_chunks, int) or hotfolder_chunks < 1:
        raise ValueError(f"hotfolder_chunks must be an integer >= 1, got {hotfolder_chunks!r}")
    if not (math.isfinite(hotfolder_interval_s) and hotfolder_interval_s >= 0):
        raise ValueError(f"hotfolder_interval_s must be >= 0 seconds, got {hotfolder_interval_s!r}")


class SimulatedStation:
    """A turntable, a profiler, a gphoto2 camera and a hot folder, all looking at one world.

    Parameters
    ----------
    world
        The :class:`mocks.world.World` (default: the procedural hawk with
        :func:`mocks.world.station_world_settings`: 240 x 160 frames, a
        ColorChecker Classic laid out on the backdrop).  The
        station owns it: :meth:`place` sets its ``pose``.  Its ``pose`` at
        construction is the base pose of placement 1.
    root
        Folder for the pty symlinks ``turntable`` and ``profiler``, the shim
        ``bin/gphoto2`` and its configuration ``camera.json``, the hot folder
        ``hotfolder/`` and the control folder ``control/`` (created if
        missing, kept on :meth:`stop`); default a temporary folder removed on
        :meth:`stop`.
    seed
        Station seed (integer >= 0): placements and all noise derive from it.
    time_scale
        Real seconds per simulated second of turntable motion (0: instant).
    sensor_to_room
        The profiler's pose (4 x 4, mm); default :func:`station_sensor_to_room`.
    n_points, fov_deg, range_mm, baseline_mm, max_incidence_deg, noise_um
        The profiler's sensor model (:class:`mocks.profiler_firmware.RaycastSource`).
    table_radius_mm
        Radius of the table top disc at ``z = 0`` (mm).
    exposure_s
        Exposure of both cameras (s).
    laser_watchdog_s
        The turntable firmware's laser watchdog (simulated seconds).
    hotfolder_chunks, hotfolder_interval_s
        How a shot is written into the hot folder (pieces, pause between them).
    poll_s
        Polling period of the control folder (s).

    Attributes
    ----------
    seed, time_scale, n_points, exposure_s
        As given.
    turntable_faults, profiler_faults
        The :class:`mocks.faults.Faults` shared with each firmware.
    hotfolder_faults
        :class:`HotFolderFaults` of :meth:`shoot`.
    """

    def __init__(
        self,
        world: Any = None,
        *,
        root: str | os.PathLike[str] | None = None,
        seed: int = 0,
        time_scale: float = 0.0,
        sensor_to_room: ArrayLike | None = None,
        n_points: int = 640,
        fov_deg: float = 40.0,
        range_mm: tuple[float, float] = (150.0, 360.0),
        baseline_mm: float = 60.0,
        max_incidence_deg: float = 70.0,
        noise_um: float = 50.0,
        table_radius_mm: float = 100.0,
        exposure_s: float = 0.01,
        laser_watchdog_s: float = 255.0,
        hotfolder_chunks: int = 4,
        hotfolder_interval_s: float = 0.05,
        poll_s: float = 0.02,
    ) -> None:
        from mocks.profiler_firmware import check_sensor_pose
        from mocks.world import World, station_world_settings

        _check_settings(seed, time_scale, exposure_s, poll_s, laser_watchdog_s, hotfolder_chunks, hotfolder_interval_s)
        self.world = World.hawk(**station_world_settings()) if world is None else world
        if not isinstance(self.world, World):
            raise ValueError(f"world must be a mocks.world.World, got {type(self.world).__name__}")
        self.seed = int(seed)
        self.time_scale = float(time_scale)
        self.n_points = n_points
        self.exposure_s = float(exposure_s)
        self.laser_watchdog_s = float(laser_watchdog_s)
        self.hotfolder_chunks = hotfolder_chunks
        self.hotfolder_interval_s = float(hotfolder_interval_s)
        self.poll_s = float(poll_s)
        self.table_radius_mm = float(table_radius_mm)
        self._table = table_disc(self.table_radius_mm)
        self._sensor_to_room = (station_sensor_to_room() if sensor_to_room is None
                                else check_sensor_pose(sensor_to_room))
        self._source_kw = {"n_points": n_points, "fov_deg": fov_deg, "range_mm": range_mm,
                           "baseline_mm": baseline_mm, "max_incidence_deg": max_incidence_deg,
                           "noise_um": noise_um}
        self.turntable_faults = Faults()
        self.profiler_faults = Faults()
        self.hotfolder_faults = HotFolderFaults()
        self._camera_faults: dict[str, Any] = {}
        self._temporary = root is None
        # absolute: the fake gphoto2 runs in the capture's folder, and finds the station's control folder
        # (which renders its frames) only by an absolute path
        self._root = Path(tempfile.mkdtemp(prefix="kogei-station-")) if root is None else Path(root).absolute()
        self._lock = threading.RLock()
        self._base_pose = np.array(self.world.pose, dtype=np.float64)
        self._turntable: Any = None
        self._profiler: Any = None
        self._control: threading.Thread | None = None
        self._stop_event = threading.Event()
        self._started = self._stopped = False
        self._shots = 0
        self._placement = 0
        self._pose = np.eye(4)
        self._source: Any = None
        try:
            self._set_placement(1)  # validates the sensor model too
        except BaseException:
            if self._temporary:
                shutil.rmtree(self._root, ignore_errors=True)
            raise

    # ----------------------------------------------------------- paths
    @property
    def root(self) -> Path:
        """The station's folder."""
        return self._root

    @property
    def turntable_path(self) -> Path:
        """Stable symlink to the turntable's pty (open it with the Turntable driver)."""
        return self._root / "turntable"

    @property
    def profiler_path(self) -> Path:
        """Stable symlink to the profiler's pty."""
        return self._root / "profiler"

    @property
    def gphoto2_path(self) -> Path:
        """The fake gphoto2 executable bound to this station."""
        return self._root / "bin" / "gphoto2"

    @property
    def config_path(self) -> Path:
        """The fake gphoto2's configuration (world, angle, placement, chart flag, faults)."""
        return self._root / "camera.json"

    @property
    def hotfolder(self) -> Path:
        """The hot folder :meth:`shoot` writes into."""
        return self._root / "hotfolder"

    @property
    def control_dir(self) -> Path:
        """The folder watched for ``request-<id>.json`` files."""
        return self._root / "control"

    # ----------------------------------------------------------- devices and truth
    @property
    def turntable(self) -> Any:
        """The :class:`mocks.horus_firmware.HorusFirmware` (after :meth:`start`)."""
        if self._turntable is None:
            raise StationError("the station is not running: call start() (or use it as a context manager)")
        return self._turntable

    @property
    def profiler(self) -> Any:
        """The :class:`mocks.profiler_firmware.ProfilerFirmware` (after :meth:`start`)."""
        if self._profiler is None:
            raise StationError("the station is not running: call start() (or use it as a context manager)")
        return self._profiler

    @property
    def faults(self) -> dict[str, Any]:
        """The shared fault objects: ``turntable``, ``profiler`` (:class:`Faults`), ``hotfolder``."""
        return {"turntable": self.turntable_faults, "profiler": self.profiler_faults,
                "hotfolder": self.hotfolder_faults}

    @property
    def sensor_to_room(self) -> NDArray[np.float64]:
        """Ground truth: the profiler's pose, sensor -> room (4 x 4, mm)."""
        return self._sensor_to_room.copy()

    @property
    def placement(self) -> int:
        """The current placement number (1 after construction)."""
        with self._lock:
            return self._placement

    @property
    def pose(self) -> NDArray[np.float64]:
        """Ground truth: the current object -> table pose at table angle 0 (4 x 4, mm)."""
        with self._lock:
            return self._pose.copy()

    @property
    def table_angle_deg(self) -> float:
        """The turntable's physical angle (degrees; 0 before :meth:`start`)."""
        return 0.0 if self._turntable is None else float(self._turntable.angle_deg)

    @property
    def laser_powered(self) -> bool:
        """True while the board's laser output T1 (the profiler's laser power) is on."""
        tt = self._turntable
        if tt is None or tt.state == "Unplugged":
            return False
        return bool(tt.lasers[0])

    # ----------------------------------------------------------- life cycle
    def start(self) -> SimulatedStation:
        """Create the folders, the camera configuration and shim, and start the devices (idempotent)."""
        from mocks.fake_gphoto2 import install
        from mocks.horus_firmware import HorusFirmware
        from mocks.profiler_firmware import ProfilerFirmware

        if self._started:
            return self
        if self._stopped:
            raise StationError("a stopped station cannot be started again; create a new SimulatedStation")
        for folder in (self._root, self.hotfolder, self.control_dir, self.gphoto2_path.parent):
            folder.mkdir(parents=True, exist_ok=True)
        self._shots = max([int(m.group(1)) for p in self.hotfolder.iterdir()
                           if (m := re.fullmatch(r"IMG_(\d+)\.DNG", p.name))], default=0)
        self._write_camera_config(table_angle_deg=0.0)
        install(self.gphoto2_path.parent, self.config_path)
        self._started = True
        try:
            self._turntable = HorusFirmware(self.turntable_path, time_scale=self.time_scale,
                                            laser_watchdog_s=self.laser_watchdog_s, faults=self.turntable_faults,
                                            on_move_done=self._on_move_done)
            self._profiler = ProfilerFirmware(self.profiler_path, source=self._profile, faults=self.profiler_faults)
            self._turntable.start()
            self._profiler.start()
            self._stop_event.clear()
            self._control = threading.Thread(target=self._serve_control, name="station-control", daemon=True)
            self._control.start()
            from mocks.fake_gphoto2 import set_renderer

            set_renderer(self.config_path, self.control_dir)    # its frames rendered here, modules loaded
        except BaseException:
            self.stop()
            raise
        return self

    def stop(self) -> None:
        """Stop the devices (their ptys and symlinks disappear); remove the folder if it is temporary."""
        self._stop_event.set()
        if self._control is not None:
            self._control.join(10.0)
            self._control = None
            if self.config_path.is_file():
                from mocks.fake_gphoto2 import set_renderer

                set_renderer(self.config_path, None)           # a later gphoto2 renders its frames itself
        for dev in (self._profiler, self._turntable):
            if dev is not None:
                dev.stop()
        self._stopped = self._stopped or self._started
        if self._temporary and self._root.exists():
            shutil.rmtree(self._root, ignore_errors=True)

    def __enter__(self) -> SimulatedStation:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def info(self) -> dict[str, Any]:
        """Paths and settings as plain JSON-able values (``kogei mock`` writes them as ``station.json``)."""
        return {
            "root": str(self._root),
            "turntable": str(self.turntable_path),
            "profiler": str(self.profiler_path),
            "gphoto2": str(self.gphoto2_path),
            "camera_config": str(self.config_path),
            "hotfolder": str(self.hotfolder),
            "control": str(self.control_dir),
            "world": self.world.mesh_source or "(inline mesh)",
            "materials": dict(self.world.materials),
            "seed": self.seed,
            "time_scale": self.time_scale,
            "sensor_to_room": self._sensor_to_room.tolist(),
            "table_radius_mm": self.table_radius_mm,
        }

    # ----------------------------------------------------------- faults
    def apply_faults(self, spec: Mapping[str, Mapping[str, Any]]) -> None:
        """Switch faults given as :func:`parse_faults` returns them (at any time).

        ``turntable`` and ``profiler`` faults set the shared :class:`Faults`;
        ``camera`` faults go into the fake gphoto2's configuration;
        ``hotfolder`` faults into :attr:`hotfolder_faults`; ``world.chart_present``
        hides or shows the colour chart in chart frames; ``world.chart_outside``
        moves a laid-out chart (``World.chart_layout`` other than ``"grid"``)
        a third out of the frame, or back.
        """
        from mocks.fake_gphoto2 import update_config

        for device, names in spec.items():
            if device not in FAULT_NAMES:
                raise FaultSpecError(f"unknown device {device!r}; known: {', '.join(FAULT_NAMES)}")
            unknown = set(names) - set(FAULT_NAMES[device])
            if unknown:
                raise FaultSpecError(f"unknown {device} fault(s) {', '.join(sorted(unknown))}; "
                                     f"known: {', '.join(FAULT_NAMES[device])}")
        for device, names in spec.items():
            if device in ("turntable", "profiler", "hotfolder"):
                target = self.faults[device]
                for name, value in names.items():
                    setattr(target, name, value)
            elif device == "camera":
                self._camera_faults.update(names)
                if self._started:
                    update_config(self.config_path, faults=dict(names))
            elif device == "world" and "chart_present" in names:
                self.world.chart_present = bool(names["chart_present"])
                if self._started:
                    update_config(self.config_path, chart_present=self.world.chart_present)
            if device == "world" and "chart_outside" in names:
                self._switch_chart_outside(bool(names["chart_outside"]))

    def _switch_chart_outside(self, on: bool) -> None:
        """Move a laid-out chart partly out of the frame (on) or back to where it was (off)."""
        import dataclasses

        from mocks.chart_scene import outside_placement
        from mocks.fake_gphoto2 import update_config

        home = self.__dict__.setdefault("_chart_home", self.world.chart_placement)
        self.world.chart_placement = outside_placement(home) if on else home
        if self._started:
            update_config(self.config_path, chart_placement=dataclasses.asdict(self.world.chart_placement))

    # ----------------------------------------------------------- placements
    def _set_placement(self, n: int) -> NDArray[np.float64]:
        from mocks.profiler_firmware import RaycastSource

        fixed = self.world.fixed_placement_pose(n)     # a calibration world's own placements
        pose = placement_pose(self.world.vertices, self._base_pose, self.seed, n) if fixed is None else fixed
        obj = self.world.vertices @ pose[:3, :3].T + pose[:3, 3]
        tv, tt = self._table
        verts = np.vstack([obj, tv])
        tris = np.vstack([self.world.triangles, tt + len(obj)])
        source = RaycastSource(verts, tris, self._angle, sensor_to_room=self._sensor_to_room,
                               seed=lambda a, p=int(n): profile_seed(self.seed, p, a), **self._source_kw)
        with self._lock:
            self._placement = int(n)
            self._pose = pose
            self._source = source
            self.world.pose = pose
        return pose

    def put_object(self, world: Any) -> NDArray[np.float64]:
        """Take the object off the table and put ``world``'s on it, in placement 1 (the instruments keep running).

        What a technician does between sessions -- the reference sphere for
        the calibration scan, then the piece -- without restarting the
        station, so connected instruments stay connected.  The camera sees
        the new object (and its chart) from the next frame.

        Returns
        -------
        NDArray
            The new object -> table pose (4 x 4, mm), also :attr:`pose`.
        """
        from mocks.world import World

        if not isinstance(world, World):
            raise ValueError(f"world must be a mocks.world.World, got {type(world).__name__}")
        with self._lock:
            self.world = world
            self._base_pose = np.array(world.pose, dtype=np.float64)
            self.__dict__.pop("_chart_home", None)
            pose = self._set_placement(1)
            if self._started:
                self._write_camera_config(table_angle_deg=self.table_angle_deg)
        return pose.copy()

    def place(self, placement: int) -> NDArray[np.float64]:
        """Put the object in the rest pose of ``placement`` (>= 1); the next camera frame shows the chart.

        Calibration targets (the reference sphere, the ChArUco board, the mirror
        sphere: :attr:`mocks.world.World.shows_chart` false) are shot without a
        chart, as their capture plans take none.

        Returns
        -------
        NDArray
            The new object -> table pose (4 x 4, mm), also :attr:`pose`.
        """
        from mocks.fake_gphoto2 import update_config

        if not isinstance(placement, (int, np.integer)) or isinstance(placement, bool) or placement < 1:
            raise ValueError(f"placement must be an integer >= 1, got {placement!r}")
        with self._lock:
            pose = self._set_placement(int(placement))
            if self._started:
                update_config(self.config_path, placement=int(placement), chart_next=self._shows_chart(),
                              pose=pose.tolist())
        return pose.copy()

    # ----------------------------------------------------------- cameras
    def _shows_chart(self) -> bool:
        """Whether the first frame after a placement shows the colour chart (not for calibration targets)."""
        return bool(getattr(self.world, "shows_chart", True))

    def _write_camera_config(self, table_angle_deg: float) -> None:
        """The fake gphoto2's configuration for the current world and placement (the next frame: the chart)."""
        from mocks.fake_gphoto2 import cache_mesh, write_config

        label, world = self._camera_world()
        with self._lock:
            world["pose"] = self._pose.tolist()
            placement = self._placement
        world["table_angle_deg"] = float(table_angle_deg)
        write_config(self.config_path, world, faults=self._camera_faults, chart_first=self._shows_chart(),
                     exposure_s=self.exposure_s, seed=self.seed, placement=placement,
                     renderer=self.control_dir if self._started and not self._stopped else None)
        cache_mesh(self.config_path, self.world, label)

    def _camera_world(self) -> tuple[str, dict[str, Any]]:
        label = self.world.mesh_source or "station:inline-mesh"
        return label, dataclasses.replace(self.world, mesh_source=label).to_dict()

    def _on_move_done(self, angle_deg: float) -> None:
        from mocks.fake_gphoto2 import update_config

        update_config(self.config_path, table_angle_deg=float(angle_deg))

    def shoot(self) -> Path:
        """Render the current frame and write it into the hot folder as a tethering program would.

        The frame is the colour chart if the object was (re-)placed since the
        last complete frame, else the object at the current table angle.

        Returns
        -------
        Path
            The new file ``hotfolder/IMG_<n>.DNG`` (complete unless the
            ``partial`` fault was switched on).
        """
        return Path(self._shoot()["file"])

    def before_frame(self, pass_no: int, index: int, shot: int) -> None:
        """The capture's ``before_frame`` hook: the next object frame is shot ``shot`` of its burst.

        Each shot of a burst at one view is then a new exposure with its own sensor noise
        (:func:`mocks.noise_seed.frame_seed`); shot 0 renders as a frame always did.
        """
        from mocks.fake_gphoto2 import update_config

        update_config(self.config_path, shot_index=int(shot))

    def _shoot(self) -> dict[str, Any]:
        """:meth:`shoot`, returning what was shot (file, kind, angle, placement, partial)."""
        from mocks.fake_gphoto2 import chart_seed_kind, chart_taken, frame_shot, read_config
        from mocks.hotfolder_writer import HotFolderWriter

        if not self._started or self._stopped:
            raise StationError("the station is not running: call start() before shoot()")
        angle = self.table_angle_deg
        with self._lock:
            placement, pose = self._placement, self._pose.copy()
            config = read_config(self.config_path)
            chart = bool(config.get("chart_next"))
            shot = self._shots
            self._shots += 1
        kind = "chart" if chart else "object"
        partial = self.hotfolder_faults.take("partial")
        saturate = self.hotfolder_faults.take("saturate")
        world = dataclasses.replace(self.world, pose=pose)
        writer = HotFolderWriter(self.hotfolder, world, exposure_s=self.exposure_s, count=shot)
        path = writer.capture(kind, angle, chunks=self.hotfolder_chunks, interval_s=self.hotfolder_interval_s,
                              partial=partial, saturate=saturate,
                              seed=frame_seed(self.seed, placement, chart_seed_kind(config, kind), angle,
                                             shot=frame_shot(config, kind)))
        if chart and not partial:
            chart_taken(self.config_path, placement)
        return {"file": str(path), "kind": kind, "table_angle_deg": angle, "placement": placement,
                "partial": partial}

    # ----------------------------------------------------------- profiler
    def _angle(self) -> float:
        return self.table_angle_deg

    def profile_at(self, angle_deg: float) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
        """Ground truth: the profile of the current placement with the table at physical ``angle_deg``.

        ``(x_um, z_um, valid)`` as the profiler measures it, noise included (seeded by the
        angle, so the profile a capture took at that angle exactly); the laser is taken as on.
        """
        with self._lock:
            source = self._source
        if source is None:
            raise RuntimeError("no object placed yet: call place() first")
        return source.profile_at(float(angle_deg))

    def _profile(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
        """The profiler's source: the current placement at the current angle, dark while T1 is off."""
        with self._lock:
            source = self._source
        if not self.laser_powered:
            nan = np.full(self.n_points, np.nan)
            return nan, nan.copy(), np.zeros(self.n_points, dtype=bool)
        return source()

    # ----------------------------------------------------------- control folder
    def _serve_control(self) -> None:
        """The control thread: answer the request files of :attr:`control_dir` until :meth:`stop`."""
        serve_requests(self.control_dir, self._stop_event, self.poll_s, self._perform)

    def _perform(self, payload: dict[str, Any]) -> dict[str, Any]:
        """Carry out one control request (``place`` or ``shoot``) and return the answer."""
        action = payload.get("action")
        if action == "place":
            n = payload.get("placement")
            if not isinstance(n, int) or isinstance(n, bool) or n < 1:
                raise StationError(f"'placement' must be an integer >= 1, got {n!r}")
            pose = self.place(n)
            return {"ok": True, "action": "place", "placement": n, "pose": pose.tolist()}
        if action == "shoot":
            return {"ok": True, "action": "shoot", **self._shoot()}
        if action == "render":
            from mocks.fake_gphoto2 import render_frame

            render_frame(payload["config_path"], payload["config"], payload["path"], payload["kind"])
            return {"ok": True, "action": "render", "file": payload["path"]}
        raise StationError(f"unknown action {action!r}; known: place, shoot, render")
