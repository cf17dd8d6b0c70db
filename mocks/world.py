"""The simulated world the mock devices share: an object on a turntable, a colour chart, a light.

:class:`World` holds the object mesh (the procedural hawk head of
:mod:`mocks.procedural_hawk` or a mesh file), its pose on the table
(object -> table, 4 x 4, millimetres), a material per mesh region, the
ColorChecker (colour-science's ``SDS_COLOURCHECKERS``, Ohta's measured
spectra by default), one light with a named spectrum (distant, or a point lamp
at ``light_position_mm``), the camera -- fixed in the room, aimed at
``camera_target_mm`` -- and the table angle.  :meth:`World.camera_intrinsics`,
:meth:`World.room_to_camera` and :meth:`World.lamp_truth` are the truth a
calibration should find.  :meth:`World.frame` returns the spectral radiance
image a camera at the station sees:

* ``kind="chart"``: with ``chart_layout="grid"`` the 24 patches (4 rows x 6
  columns) filling the view, lit at normal incidence: ``L = R(lambda)
  E(lambda) / pi`` (Lambertian); with ``"classic24"``, ``"sg140"`` or
  ``"vinyl18"`` a physically laid-out chart (black frame, square patches with
  gaps) lying on the backdrop at ``chart_placement`` in perspective
  (:mod:`mocks.chart_scene`), which ``cv2.mcc`` can detect.
* ``kind="object"``: the object turned by the table angle about the table's
  z axis, ray cast with Open3D (pinhole camera); per hit pixel
  ``L = f_r(lambda) E(lambda) cos_i`` (normals interpolated from the vertex normals: the
  object is smooth, its mesh only samples it) with ``f_r`` the project's spectral BRDF
  (:func:`processing.materials.lobes.material_brdf`, Matsuda et al. eq. (2) for
  metals and alloys, eq. (5) for lacquer; its spectral factors tabulated over
  ``cos_d``, :func:`tabulated_brdf`), a shadow ray toward the light,
  and a dark grey backdrop.  Direct light only: mirror lobes reflect the
  light but not the surroundings (there is no environment in the booth),
  and there are no inter-reflections.  One ray per pixel, then the lens and
  optical low-pass filter's spread (``lens_sigma_px``,
  :func:`mocks.camera_sim.lens_blur`) over the image, as a camera's optics do
  before the colour filter array.

The light is scaled so that a white diffuser facing it has luminance Y = 1
(:func:`processing.spectral.display.xyz_scale`).
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocks.camera_sim import LENS_SIGMA_PX, lens_blur
from processing.common.rotation import rotation_z_deg
from processing.errors import InputError
from processing.spectral.spectra import SpectralGrid, light_spectrum, resample

__all__ = [
    "Frame",
    "World",
    "WorldError",
    "chart_reflectances",
    "rotation_z",
    "BACKDROP_REFLECTANCE",
    "world_settings",
    "STATION_FRAME_SIZE",
    "STATION_CHART_LAYOUT",
    "station_world_settings",
    "tabulated_brdf",
    "SPECTRAL_NODE_STEP",
]

#: Reflectance of the booth's grey backdrop and of gaps between chart patches.
BACKDROP_REFLECTANCE = 0.05

#: The simulated station's camera frame (width, height in pixels) as ``kogei mock``, ``kogei gui --mock`` and
#: ``SimulatedStation()`` set it up: the standing hawk about 140 x 158 pixels at table angle 0 (85 x 156 at 90),
#: the chart card 168 pixels wide.
STATION_FRAME_SIZE = (240, 160)
#: The station's colour chart: a ColorChecker Classic lying on the backdrop, whole in the frame, which
#: ``cv2.mcc`` finds in every pass's chart frame at :data:`STATION_FRAME_SIZE` (``World``'s own default,
#: ``"grid"``, fills the frame edge to edge and is reported as partly outside it).
STATION_CHART_LAYOUT = "classic24"


def station_world_settings() -> dict[str, Any]:
    """The :class:`World` fields of the simulated station's camera: frame size and chart layout.

    Examples
    --------
    >>> station_world_settings()
    {'width': 240, 'height': 160, 'chart_layout': 'classic24'}
    """
    return {"width": STATION_FRAME_SIZE[0], "height": STATION_FRAME_SIZE[1], "chart_layout": STATION_CHART_LAYOUT}


class WorldError(InputError):
    """A parameter of the simulated world is not valid; the message names it."""


def rotation_z(angle_deg: float) -> NDArray[np.float64]:
    """4 x 4 rotation about +z by ``angle_deg`` (counter-clockwise seen from above).

    Examples
    --------
    >>> np.round(rotation_z(90) @ [1, 0, 0, 1], 12).tolist()
    [0.0, 1.0, 0.0, 1.0]
    """
    m = np.eye(4)
    m[:3, :3] = rotation_z_deg(angle_deg)
    return m


def chart_reflectances(grid: SpectralGrid, chart: str = "ColorChecker N Ohta") -> NDArray[np.float64]:
    """Reflectances ``(24, L)`` of the chart's patches in reading order (dark skin ... black).

    Examples
    --------
    >>> r = chart_reflectances(SpectralGrid(400, 700, 10))
    >>> r.shape, bool(r[18].mean() > r[23].mean())     # white above black
    ((24, 31), True)
    """
    import colour

    try:
        sds = colour.SDS_COLOURCHECKERS[chart]
    except KeyError:
        raise WorldError(
            f"unknown chart {chart!r}; choose one of {', '.join(sorted(colour.SDS_COLOURCHECKERS.keys()))}"
        ) from None
    return np.stack([resample(sd.wavelengths, sd.values, grid) for sd in sds.values()])


@dataclass
class Frame:
    """What the camera sees: spectral radiance plus labels for checks.

    Attributes
    ----------
    radiance
        float64 ``(H, W, L)`` spectral radiance (light units with a white
        diffuser at Y = 1).
    grid
        Wavelength grid of the last axis.
    light
        ``(L,)`` spectral irradiance of the light (the same units).
    labels
        int16 ``(H, W)``: chart patch index 0-23 or object region index;
        -1 backdrop.
    kind
        ``"chart"`` or ``"object"``.
    table_angle_deg
        Table angle of the frame.
    chart_corners
        ``(4, 2)`` image positions of a laid-out chart's outer corners (top-left,
        top-right, bottom-right, bottom-left of the chart), else None.
    """

    radiance: NDArray[np.float64]
    grid: SpectralGrid
    light: NDArray[np.float64]
    labels: NDArray[np.int16]
    kind: str
    table_angle_deg: float
    chart_corners: NDArray[np.float64] | None = None


@dataclass
class World:
    """The simulated scan station.

    Attributes
    ----------
    vertices, triangles
        Object mesh in millimetres (object frame, +z up).
    region
        ``(T,)`` region index per triangle.
    region_names
        Region names.
    materials
        Material spec (``processing.materials.presets.get_material``) per region name.
    pose
        4 x 4 object -> table transform (mm); the table turns about its z axis.
    light
        Light spectrum name or CCT (``processing.spectral.spectra.light_spectrum``).
    light_direction
        Unit vector toward the light in the table's frame at angle 0 (fixed
        in the room; the table turns under it).
    chart
        Name of the ColorChecker in ``colour.SDS_COLOURCHECKERS``.
    chart_present
        False simulates the "missing chart" fault: the chart frame shows
        only the backdrop.
    chart_layout
        ``"grid"`` (patches filling the frame) or a chart laid out on the
        backdrop: ``"classic24"``, ``"sg140"``, ``"vinyl18"``.
    chart_placement
        Where a laid-out chart lies (:class:`mocks.chart_scene.ChartPlacement`
        or its fields as a dict); a placement reaching past the image is the
        "chart partly outside the frame" fault.
    width, height
        Image size in pixels (even).
    camera_distance_mm, camera_elevation_deg, fov_deg
        Camera on the room's -y side at this distance (mm) from
        ``camera_target_mm`` and this elevation (degrees), with this
        horizontal field of view (degrees): an ideal pinhole
        (:meth:`camera_intrinsics`, :meth:`room_to_camera`).
    camera_target_mm
        The room point (mm) the camera looks at; fixed in the room, so
        re-placing the object does not move the camera.  The default is
        about the procedural hawk's centre standing on the table.
    light_position_mm
        A point lamp's position (room frame, mm); None: the distant light of
        ``light_direction``.  A point lamp's irradiance falls off as
        ``(d0 / d)**2`` with ``d0`` its distance to ``camera_target_mm``.
    lamp_radius_mm
        Radius of the lamp's emitting disc (mm), seen only in a mirror
        (:mod:`mocks.mirror_world`).
    spectral_step
        Wavelength step (nm) of the simulation grid over 400-700 nm.
    table_angle_deg
        Current table angle (degrees).
    mesh_source
        Where the mesh came from (``"hawk:<triangles>"`` or a path).
    chart_first
        The station shows the colour chart in the first frame after each
        placement (a technician holding the chart up); False for a scan
        whose plan takes no chart (the reference sphere's).
    lens_sigma_px
        Point spread of the camera's lens and optical low-pass filter on
        the object photos (Gaussian standard deviation, photosites;
        :func:`mocks.camera_sim.lens_blur`); 0: a pinhole.
    """

    vertices: NDArray[np.float64]
    triangles: NDArray[np.int64]
    region: NDArray[np.int64]
    region_names: tuple[str, ...]
    materials: dict[str, str]
    pose: NDArray[np.float64] = field(default_factory=lambda: np.eye(4))
    light: str = "D65"
    light_direction: tuple[float, float, float] = (-0.4, -0.6, 0.7)
    chart: str = "ColorChecker N Ohta"
    chart_present: bool = True
    chart_layout: str = "grid"
    chart_placement: Any = None
    width: int = 96
    height: int = 64
    camera_distance_mm: float = 260.0
    camera_elevation_deg: float = 15.0
    fov_deg: float = 25.0
    spectral_step: float = 10.0
    table_angle_deg: float = 0.0
    mesh_source: str = ""
    camera_target_mm: tuple[float, float, float] = (0.0, 0.0, 37.0)
    light_position_mm: tuple[float, float, float] | None = None
    lamp_radius_mm: float = 15.0
    chart_first: bool = True
    lens_sigma_px: float = LENS_SIGMA_PX

    def __post_init__(self) -> None:
        self.vertices = np.asarray(self.vertices, dtype=np.float64)
        self.triangles = np.asarray(self.triangles, dtype=np.int64)
        self.region = np.asarray(self.region, dtype=np.int64)
        self.pose = np.asarray(self.pose, dtype=np.float64)
        if self.vertices.ndim != 2 or self.vertices.shape[1] != 3 or not np.all(np.isfinite(self.vertices)):
            raise WorldError(f"vertices must be finite (V, 3) millimetres, got shape {self.vertices.shape}")
        if self.triangles.ndim != 2 or self.triangles.shape[1] != 3 or self.triangles.size == 0 \
                or self.triangles.min() < 0 or self.triangles.max() >= len(self.vertices):
            raise WorldError("triangles must be (T, 3) indices into vertices, T >= 1")
        if self.region.shape != (len(self.triangles),) or self.region.min() < 0 \
                or self.region.max() >= len(self.region_names):
            raise WorldError("region must hold one index into region_names per triangle")
        missing = [r for r in self.region_names if r not in self.materials]
        if missing:
            raise WorldError(f"materials has no entry for region(s) {', '.join(missing)}; give a material spec each")
        if self.pose.shape != (4, 4) or not np.all(np.isfinite(self.pose)) \
                or not np.allclose(self.pose[3], [0, 0, 0, 1]):
            raise WorldError("pose must be a finite 4 x 4 rigid transform with last row (0, 0, 0, 1)")
        for name in ("width", "height"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or v < 22 or v % 2:
                raise WorldError(f"{name} must be an even number of pixels >= 22 (a raw decoder's minimum), got {v!r}")
        d = np.asarray(self.light_direction, dtype=np.float64)
        if d.shape != (3,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) == 0:
            raise WorldError(f"light_direction must be a non-zero 3-vector, got {self.light_direction!r}")
        if not 0 < self.fov_deg < 170:
            raise WorldError(f"fov_deg must be in (0, 170) degrees, got {self.fov_deg!r}")
        if not self.camera_distance_mm > 0:
            raise WorldError(f"camera_distance_mm must be > 0, got {self.camera_distance_mm!r}")
        self.camera_target_mm = _point3("camera_target_mm", self.camera_target_mm)
        if self.light_position_mm is not None:
            self.light_position_mm = _point3("light_position_mm", self.light_position_mm)
            if np.linalg.norm(np.subtract(self.light_position_mm, self.camera_target_mm)) == 0:
                raise WorldError("light_position_mm must differ from camera_target_mm")
        if not (isinstance(self.lamp_radius_mm, (int, float)) and math.isfinite(self.lamp_radius_mm)
                and self.lamp_radius_mm > 0):
            raise WorldError(f"lamp_radius_mm must be > 0 mm, got {self.lamp_radius_mm!r}")
        if not (isinstance(self.lens_sigma_px, (int, float)) and math.isfinite(self.lens_sigma_px)
                and 0 <= self.lens_sigma_px <= 10):
            raise WorldError(f"lens_sigma_px must be in [0, 10] photosites, got {self.lens_sigma_px!r}")
        _ = self.grid  # validates spectral_step
        from mocks.chart_scene import ChartPlacement, ChartSceneError

        if self.chart_layout not in ("grid", "classic24", "sg140", "vinyl18"):
            raise WorldError(f"chart_layout must be 'grid', 'classic24', 'sg140' or 'vinyl18', got {self.chart_layout!r}")
        if self.chart_placement is None:
            self.chart_placement = ChartPlacement()
        elif isinstance(self.chart_placement, dict):
            try:
                self.chart_placement = ChartPlacement(**self.chart_placement)
            except (TypeError, ChartSceneError) as exc:
                raise WorldError(f"chart_placement: {exc}") from None
        elif not isinstance(self.chart_placement, ChartPlacement):
            raise WorldError(f"chart_placement must be a ChartPlacement or a dict of its fields, "
                             f"got {type(self.chart_placement).__name__}")

    # ------------------------------------------------------------------ construction
    @classmethod
    def hawk(cls, triangles: int = 4_000, materials: dict[str, str] | None = None, **kwargs: Any) -> World:
        """The procedural hawk head with its default materials (nami-shibuichi, gold, urushi, copper).

        Examples
        --------
        >>> w = World.hawk(2_000)
        >>> w.region_names[:2], w.materials["beak"]
        (('head', 'beak'), 'gold')
        """
        from mocks.procedural_hawk import DEFAULT_MATERIALS, hawk_head

        mesh = hawk_head(triangles)
        mats = dict(DEFAULT_MATERIALS)
        mats.update(materials or {})
        return cls(mesh.vertices, mesh.triangles, mesh.region.astype(np.int64), tuple(mesh.region_names), mats,
                   mesh_source=f"hawk:{triangles}", **kwargs)

    @classmethod
    def turned(cls, name: str, materials: dict[str, str] | None = None, **kwargs: Any) -> World:
        """A turned object of :mod:`mocks.turned_objects` (``vase``, ``inlaid-bowl``, ``plain-bowl``,
        ``plain-bowl:bare``) standing upright on the table's axis.

        Examples
        --------
        >>> w = World.turned("plain-bowl")
        >>> w.mesh_source, w.materials["motif"]
        ('plain-bowl', 'urushi-black')
        """
        from mocks.turned_objects import turned_object

        try:
            mesh = turned_object(name)
        except ValueError as exc:
            raise WorldError(str(exc)) from None
        mats = dict(mesh.materials)
        mats.update(materials or {})
        return cls(mesh.vertices, mesh.triangles, mesh.region, mesh.region_names, mats, mesh_source=name, **kwargs)

    @classmethod
    def calibration_sphere(cls, radius_mm: float = 25.0, offset_mm: float = 60.0, **kwargs: Any) -> World:
        """A reference sphere for scanner calibration, resting on the table ``offset_mm`` from the axis.

        Examples
        --------
        >>> w = World.calibration_sphere(20.0, 50.0)
        >>> w.mesh_source, round(float(w.pose[0, 3]), 1), round(float(w.pose[2, 3]), 1)
        ('sphere:20:50', 50.0, 20.0)
        """
        import open3d as o3d

        if not (math.isfinite(radius_mm) and radius_mm > 0 and math.isfinite(offset_mm) and offset_mm >= 0):
            raise WorldError(f"calibration sphere: radius_mm must be > 0 and offset_mm >= 0, got "
                             f"{radius_mm!r}, {offset_mm!r}")
        mesh = o3d.geometry.TriangleMesh.create_sphere(float(radius_mm), resolution=120)
        pose = np.eye(4)
        pose[0, 3], pose[2, 3] = float(offset_mm), float(radius_mm)
        kwargs.setdefault("pose", pose)
        return cls(np.asarray(mesh.vertices), np.asarray(mesh.triangles), np.zeros(len(mesh.triangles), np.int64),
                   ("sphere",), {"sphere": "urushi-red"}, mesh_source=f"sphere:{radius_mm:g}:{offset_mm:g}", **kwargs)

    @classmethod
    def from_mesh_file(cls, path: str | os.PathLike[str], material: str = "nami-shibuichi", *,
                       region_materials: dict[str, str] | None = None, **kwargs: Any) -> World:
        """Any mesh file :func:`render.meshio.load_mesh` reads; per-face materials when the file has them.

        A file with per-face materials (:func:`render.material_mesh.material_mesh_or_none`: a PLY
        with a face ``material`` property, a glTF with a primitive per material) gives one region per
        region of the file, named by the file's names (``region-<i>`` for a PLY, the material names
        of a glTF, made unique with ``#2``, ...), each of the file's spec; a region without a spec,
        and the faces of no region (``"no region"``), are ``material``.  glTF positions are metres
        and become millimetres.  Any other file is one region ``"object"`` of ``material``.
        ``region_materials`` (region name -> spec) overrides regions by name.

        Examples
        --------
        >>> import tempfile, pathlib
        >>> from render.material_mesh import write_material_ply
        >>> p = pathlib.Path(tempfile.mkdtemp()) / "two.ply"
        >>> write_material_ply(p, [[0, 0, 0], [9, 0, 0], [0, 9, 0], [9, 9, 0]], [[0, 1, 2], [1, 3, 2]],
        ...                    [[0, 0, 1]] * 4, [0, 1], ["gold", None])
        >>> w = World.from_mesh_file(p, "copper")
        >>> w.region.tolist(), w.materials
        ([0, 1], {'region-0': 'gold', 'region-1': 'copper'})
        """
        from render.material_mesh import material_mesh_or_none
        from render.meshio import load_mesh

        overrides = dict(region_materials or {})
        per_face = material_mesh_or_none(path)
        if per_face is None:
            mesh = load_mesh(path)
            return cls(mesh.vertices, mesh.triangles, np.zeros(len(mesh.triangles), np.int64), ("object",),
                       {"object": overrides.get("object", material)}, mesh_source=os.fspath(path), **kwargs)
        names = _unique_names(per_face.names)
        materials = {name: spec or material for name, spec in zip(names, per_face.specs)}
        region = per_face.face_material.copy()
        if np.any(region < 0):
            names.append(_unique_names([*names, "no region"])[-1])
            materials[names[-1]] = material
            region[region < 0] = len(names) - 1
        unknown = sorted(set(overrides) - set(names))
        if unknown:
            raise WorldError(f"{os.fspath(path)}: no region(s) {', '.join(unknown)}; regions: {', '.join(names)}")
        materials.update(overrides)
        return cls(per_face.vertices, per_face.triangles, region, tuple(names), materials,
                   mesh_source=os.fspath(path), **kwargs)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> World:
        """Rebuild a world from :meth:`to_dict` (the fake gphoto2's configuration).

        A mapping with a ``"swatch"`` entry is a :class:`mocks.swatch_world.SwatchWorld`, with
        ``"board"`` a :class:`mocks.board_world.BoardWorld`, with ``"probe"`` a
        :class:`mocks.probe_world.ProbeWorld`, with ``"mirror"`` a :class:`mocks.mirror_world.MirrorWorld`.
        """
        if "swatch" in data:
            from mocks.swatch_world import SwatchWorld  # imported here: it builds on this module

            return SwatchWorld.from_dict(data)
        if "board" in data:
            from mocks.board_world import BoardWorld

            return BoardWorld.from_dict(data)
        if "probe" in data:
            from mocks.probe_world import ProbeWorld

            return ProbeWorld.from_dict(data)
        if "mirror" in data:
            from mocks.mirror_world import MirrorWorld

            return MirrorWorld.from_dict(data)
        data = dict(data)
        source = str(data.pop("mesh", "hawk:4000"))
        if source.startswith("sphere:"):
            try:
                radius, offset = (float(v) for v in source.split(":")[1:3])
            except ValueError:
                raise WorldError(f"mesh {source!r}: use 'sphere:<radius_mm>:<offset_mm>'") from None
            data.pop("materials", None)
            return cls.calibration_sphere(radius, offset, **world_settings(data))
        from mocks.turned_objects import TURNED_OBJECTS

        if source in TURNED_OBJECTS:
            return cls.turned(source, materials=data.pop("materials", None), **world_settings(data))
        if source.startswith("hawk:"):
            try:
                n = int(source.split(":", 1)[1])
            except ValueError:
                raise WorldError(f"mesh {source!r}: use 'hawk:<triangles>' or a mesh file path") from None
            world = cls.hawk(n, materials=data.pop("materials", None), **world_settings(data))
        else:
            materials = data.pop("materials", None) or {}
            world = cls.from_mesh_file(source, materials.get("object", "nami-shibuichi"),
                                       region_materials=materials, **world_settings(data))
        return world

    def to_dict(self) -> dict[str, Any]:
        """A JSON-serialisable description (mesh by source, not by vertices)."""
        if not self.mesh_source:
            raise WorldError("this world's mesh has no source (hawk:<n> or a file); it cannot be serialised")
        return {
            "mesh": self.mesh_source,
            "materials": dict(self.materials),
            "pose": self.pose.tolist(),
            "light": self.light,
            "light_direction": list(self.light_direction),
            "chart": self.chart,
            "chart_present": self.chart_present,
            "chart_layout": self.chart_layout,
            "chart_placement": {k: (list(v) if isinstance(v, tuple) else v)
                                for k, v in dataclasses.asdict(self.chart_placement).items()},
            "width": self.width,
            "height": self.height,
            "camera_distance_mm": self.camera_distance_mm,
            "camera_elevation_deg": self.camera_elevation_deg,
            "fov_deg": self.fov_deg,
            "spectral_step": self.spectral_step,
            "table_angle_deg": self.table_angle_deg,
            "camera_target_mm": list(self.camera_target_mm),
            "light_position_mm": None if self.light_position_mm is None else list(self.light_position_mm),
            "lamp_radius_mm": float(self.lamp_radius_mm),
            "chart_first": bool(self.chart_first),
            "lens_sigma_px": float(self.lens_sigma_px),
        }

    def fixed_placement_pose(self, placement: int) -> NDArray[np.float64] | None:
        """The object -> table pose of station placement ``placement``, or None: the station's
        pseudo-random rest pose (:func:`mocks.station_geometry.placement_pose`).  Calibration
        worlds (board, mirror sphere) return their own."""
        return None

    # ------------------------------------------------------------------ rendering
    @property
    def shows_chart(self) -> bool:
        """Whether the station shows the colour chart in the first frame after a placement (:attr:`chart_first`)."""
        return bool(self.chart_first)

    @property
    def grid(self) -> SpectralGrid:
        """The simulation's wavelength grid, 400-700 nm at ``spectral_step``."""
        try:
            return SpectralGrid(400.0, 700.0, float(self.spectral_step))
        except ValueError as exc:
            raise WorldError(f"spectral_step: {exc}") from None

    def light_spectrum(self) -> NDArray[np.float64]:
        """The light's spectral irradiance, scaled so a white diffuser facing it has Y = 1."""
        from processing.spectral.display import xyz_scale

        e = light_spectrum(self.light, self.grid)
        return e * xyz_scale(e, self.grid)

    def frame(self, kind: str = "object", table_angle_deg: float | None = None) -> Frame:
        """The spectral radiance image of a ``"chart"`` or ``"object"`` frame.

        Parameters
        ----------
        kind
            ``"chart"`` (the colour chart, first frame of a lighting setup)
            or ``"object"``.
        table_angle_deg
            Table angle; None uses :attr:`table_angle_deg`.

        Examples
        --------
        >>> w = World.hawk(2_000)
        >>> f = w.frame("chart")
        >>> f.radiance.shape, int(f.labels.max())
        ((64, 96, 31), 23)
        """
        angle = self.table_angle_deg if table_angle_deg is None else float(table_angle_deg)
        if not math.isfinite(angle):
            raise WorldError(f"table_angle_deg must be finite, got {table_angle_deg!r}")
        if kind == "chart":
            return self._chart_frame(angle)
        if kind == "object":
            return self._object_frame(angle)
        raise WorldError(f"frame kind must be 'chart' or 'object', got {kind!r}")

    def _chart_frame(self, angle: float) -> Frame:
        grid, e = self.grid, self.light_spectrum()
        h, w = self.height, self.width
        if self.chart_present and self.chart_layout != "grid":
            from mocks.chart_scene import render_chart

            refl = chart_reflectances(grid, self.chart) if self.chart_layout == "classic24" else None
            radiance, labels, corners = render_chart(self.chart_layout, w, h, self.chart_placement, grid, e,
                                                     BACKDROP_REFLECTANCE, refl)
            return Frame(radiance, grid, e, labels, "chart", angle, corners)
        labels = np.full((h, w), -1, dtype=np.int16)
        if self.chart_present:
            rows = np.floor(np.arange(h) / h * 4).astype(int)
            cols = np.floor(np.arange(w) / w * 6).astype(int)
            ry = (np.arange(h) / h * 4) % 1.0
            rx = (np.arange(w) / w * 6) % 1.0
            inside = ((ry > 0.12) & (ry < 0.88))[:, None] & ((rx > 0.12) & (rx < 0.88))[None, :]
            patch = rows[:, None] * 6 + cols[None, :]
            labels[inside] = patch[inside]
        table = np.vstack([chart_reflectances(grid, self.chart), np.full((1, grid.size), BACKDROP_REFLECTANCE)])
        radiance = table[labels] * (e / math.pi)          # label -1 picks the backdrop row
        return Frame(radiance, grid, e, labels, "chart", angle)

    def _camera_axes(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The camera's centre (room, mm) and its axes as rows (x right, y down, z forward), room frame."""
        target = np.asarray(self.camera_target_mm, dtype=np.float64)
        el = math.radians(self.camera_elevation_deg)
        eye = target + self.camera_distance_mm * np.array([0.0, -math.cos(el), math.sin(el)])
        fwd = (target - eye) / np.linalg.norm(target - eye)
        right = np.cross(fwd, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        up = np.cross(right, fwd)
        return eye, np.stack([right, -up, fwd])

    def camera_intrinsics(self) -> NDArray[np.float64]:
        """The true camera matrix ``K`` (3 x 3, pixels; OpenCV: the centre of pixel (0, 0) is at (0, 0)).

        ``fx = fy = (width / 2) / tan(fov / 2)``, ``cx = width / 2 - 0.5``,
        ``cy = height / 2 - 0.5``; zero distortion.  For tests (truth).

        Examples
        --------
        >>> k = World.hawk(2_000, width=240, height=160).camera_intrinsics()
        >>> round(float(k[0, 0]), 3), float(k[0, 2]), float(k[1, 2])
        (541.285, 119.5, 79.5)
        """
        f = (self.width / 2) / math.tan(math.radians(self.fov_deg) / 2)
        return np.array([[f, 0.0, self.width / 2 - 0.5], [0.0, f, self.height / 2 - 0.5], [0.0, 0.0, 1.0]])

    def room_to_camera(self) -> NDArray[np.float64]:
        """The true room -> camera transform (4 x 4, mm; camera x right, y down, z forward).  For tests.

        Examples
        --------
        >>> w = World.hawk(2_000)
        >>> (np.round(w.room_to_camera() @ [*w.camera_target_mm, 1.0], 9) + 0.0).tolist()
        [0.0, 0.0, 260.0, 1.0]
        """
        eye, axes = self._camera_axes()
        m = np.eye(4)
        m[:3, :3] = axes
        m[:3, 3] = -axes @ eye
        return m

    def lamp_truth(self) -> dict[str, Any]:
        """The lamp as the lamp calibration should find it: ``{"kind": "point", "position_mm": [...],
        "radius_mm": r}`` or ``{"kind": "distant", "direction": [...]}`` (room frame, unit vector toward it)."""
        if self.light_position_mm is not None:
            return {"kind": "point", "position_mm": [float(v) for v in self.light_position_mm],
                    "radius_mm": float(self.lamp_radius_mm), "spectrum": self.light}
        d = np.asarray(self.light_direction, dtype=np.float64)
        return {"kind": "distant", "direction": (d / np.linalg.norm(d)).tolist(), "spectrum": self.light}

    def _rays(self, supersample: int = 1) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Camera centre and unit ray directions ``(H * s, W * s, 3)`` through ``s x s`` points per pixel."""
        eye, axes = self._camera_axes()
        k = self.camera_intrinsics()
        s = int(supersample)
        sub = (np.arange(s) + 0.5) / s - 0.5
        u = (np.arange(self.width)[:, None] + sub[None, :]).ravel()
        v = (np.arange(self.height)[:, None] + sub[None, :]).ravel()
        x = (u - k[0, 2]) / k[0, 0]
        y = (v - k[1, 2]) / k[1, 1]
        d = axes[2] + x[None, :, None] * axes[0] + y[:, None, None] * axes[1]
        return eye, d / np.linalg.norm(d, axis=-1, keepdims=True)

    def _view(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Camera position and unit ray directions ``(H, W, 3)`` through the pixel centres (pinhole)."""
        return self._rays(1)

    def _lamp_at(self, points: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                                             NDArray[np.float64]]:
        """Unit directions toward the lamp ``(N, 3)``, relative irradiance ``(N,)`` and lamp distance
        ``(N,)`` (inf for a distant lamp) at room points ``(N, 3)``."""
        if self.light_position_mm is None:
            light = np.asarray(self.light_direction, dtype=np.float64)
            light = light / np.linalg.norm(light)
            n = len(points)
            return np.broadcast_to(light, (n, 3)), np.ones(n), np.full(n, np.inf)
        lamp = np.asarray(self.light_position_mm, dtype=np.float64)
        to = lamp - points
        dist = np.linalg.norm(to, axis=1)
        d0 = float(np.linalg.norm(lamp - np.asarray(self.camera_target_mm)))
        return to / dist[:, None], (d0 / dist) ** 2, dist

    def _shading_normals(self, verts: NDArray[np.float64], prim: NDArray[np.uint32], uvs: NDArray[np.float32],
                         flat: NDArray[np.float32]) -> NDArray[np.float64]:
        """Normals at ray hits interpolated from the vertex normals (a smooth surface, as the object is).

        Open3D's barycentric ``(u, v)`` weigh the triangle's second and third vertex.  Misses keep the
        (unused) face normal.
        """
        import open3d as o3d

        mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(verts),
                                         o3d.utility.Vector3iVector(self.triangles.astype(np.int32)))
        vn = np.asarray(mesh.compute_vertex_normals().vertex_normals, dtype=np.float64)
        hit = prim != o3d.t.geometry.RaycastingScene.INVALID_ID
        out = flat.astype(np.float64)
        tri = self.triangles[prim[hit].astype(np.int64)]
        u, v = uvs[hit, 0:1].astype(np.float64), uvs[hit, 1:2].astype(np.float64)
        n = (1.0 - u - v) * vn[tri[:, 0]] + u * vn[tri[:, 1]] + v * vn[tri[:, 2]]
        out[hit] = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        return out

    def _object_frame(self, angle: float) -> Frame:
        import open3d as o3d

        from processing.materials.presets import get_material

        grid, e = self.grid, self.light_spectrum()
        m = rotation_z(angle) @ self.pose
        verts = self.vertices @ m[:3, :3].T + m[:3, 3]
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor(verts.astype(np.float32)),
                            o3d.core.Tensor(self.triangles.astype(np.uint32)))
        eye, dirs = self._view()
        h, w = self.height, self.width
        rays = np.concatenate([np.broadcast_to(eye, dirs.shape), dirs], axis=-1).reshape(-1, 6).astype(np.float32)
        ans = scene.cast_rays(o3d.core.Tensor(rays))
        t = ans["t_hit"].numpy().astype(np.float64)
        hit = np.isfinite(t)
        prim = ans["primitive_ids"].numpy()
        normal = self._shading_normals(verts, prim, ans["primitive_uvs"].numpy(), ans["primitive_normals"].numpy())
        d = dirs.reshape(-1, 3)
        radiance = np.empty((h * w, grid.size))
        radiance[:] = BACKDROP_REFLECTANCE * e / math.pi
        labels = np.full(h * w, -1, dtype=np.int16)
        idx = np.flatnonzero(hit)
        if idx.size:
            n = normal[idx]
            view = -d[idx]
            n *= np.where(np.einsum("ij,ij->i", n, view) < 0, -1.0, 1.0)[:, None]
            pos = eye + d[idx] * t[idx, None]
            light, irradiance, dist = self._lamp_at(pos)
            size = float(np.linalg.norm(verts.max(axis=0) - verts.min(axis=0)))
            origin = pos + n * (1e-4 * size)
            point = bool(np.all(np.isfinite(dist)))      # a point lamp: occluders only up to the lamp (t < 1)
            toward = light * dist[:, None] if point else light
            shadow = np.concatenate([origin, toward], axis=1).astype(np.float32)
            lit = ~scene.test_occlusions(o3d.core.Tensor(shadow), tfar=1.0 if point else math.inf).numpy()
            ci = np.clip(np.einsum("ij,ij->i", n, light), 0.0, 1.0) * lit
            co = np.clip(np.einsum("ij,ij->i", n, view), 1e-6, 1.0)
            half = light + view
            half /= np.linalg.norm(half, axis=1, keepdims=True)
            ch = np.clip(np.einsum("ij,ij->i", n, half), 0.0, 1.0)
            cd = np.clip(np.einsum("ij,ij->i", half, light), 0.0, 1.0)
            reg = self.region[prim[idx]]
            labels[idx] = reg
            for r, name in enumerate(self.region_names):
                sel = np.flatnonzero(reg == r)
                if sel.size == 0:
                    continue
                mat = get_material(self.materials[name])
                f = tabulated_brdf(mat, ci[sel], co[sel], ch[sel], cd[sel], grid.wavelengths)
                radiance[idx[sel]] = f * (ci[sel] * irradiance[sel])[:, None] * e
        image = lens_blur(radiance.reshape(h, w, grid.size), self.lens_sigma_px)
        return Frame(image, grid, e, labels.reshape(h, w), "object", angle)


#: Spacing (in cos_d) of the nodes on which :func:`tabulated_brdf` evaluates a lobe's spectral factor.
SPECTRAL_NODE_STEP = 1e-4


def tabulated_brdf(material: Any, cos_i: NDArray[np.float64], cos_o: NDArray[np.float64],
                   cos_h: NDArray[np.float64], cos_d: NDArray[np.float64],
                   wavelengths: NDArray[np.float64]) -> NDArray[np.float64]:
    """:func:`processing.materials.lobes.material_brdf` of ``material`` at N points, its spectral factors tabulated.

    A lobe is a wavelength-free geometric factor times a spectral factor of ``cos_d`` alone
    (:mod:`processing.materials.lobes`).  The spectral factor -- a metal's complex Fresnel reflectance,
    most of a frame's cost when evaluated at every pixel -- is evaluated on nodes
    :data:`SPECTRAL_NODE_STEP` apart over the points' range of ``cos_d`` and interpolated linearly, an
    error below ``step^2 / 8 max|F''|`` (about 1e-9 of the factor; the simulated sensor's shot noise is
    1e-2 and more).  Isotropic lobes only, as the world's object has no tangent frame.

    Parameters
    ----------
    material
        A :class:`processing.materials.lobes.Material`.
    cos_i, cos_o, cos_h, cos_d
        ``(N,)`` cosines as for :func:`processing.materials.lobes.lobe_geometry`.
    wavelengths
        ``(L,)`` nm.

    Returns
    -------
    ndarray
        ``(N, L)`` BRDF (1/sr).

    Examples
    --------
    >>> from processing.materials.lobes import material_brdf
    >>> from processing.materials.presets import get_material
    >>> c = np.linspace(0.3, 1.0, 50)
    >>> wl = np.arange(400.0, 701.0, 10.0)
    >>> gold = get_material("gold")
    >>> exact = material_brdf(gold, c, c, np.ones(50), c, wl)
    >>> bool(np.allclose(tabulated_brdf(gold, c, c, np.ones(50), c, wl), exact, rtol=1e-8, atol=0))
    True
    """
    from processing.materials.lobes import lobe_geometry

    wl = np.asarray(wavelengths, dtype=np.float64)
    cd = np.asarray(cos_d, dtype=np.float64)
    total = np.zeros((cd.size, wl.size))
    if cd.size == 0:
        return total
    lo, hi = float(cd.min()), float(cd.max())
    n = max(2, int(math.ceil((hi - lo) / SPECTRAL_NODE_STEP)) + 1)
    nodes = np.linspace(lo, hi, n)
    pos = (cd - lo) * ((n - 1) / (hi - lo)) if hi > lo else np.zeros_like(cd)
    k = np.clip(np.floor(pos).astype(np.int64), 0, n - 2)
    frac = (pos - k)[:, None]
    for lobe in material.lobes:
        if lobe.weight == 0.0:
            continue
        g = np.broadcast_to(lobe_geometry(lobe, cos_i, cos_o, cos_h, cd, None), cd.shape)
        if lobe.spectral.angle_dependent:
            table = lobe.spectral.reflectance(nodes, wl)
            spectral = table[k] * (1.0 - frac) + table[k + 1] * frac
        else:
            spectral = lobe.spectral.reflectance(cd[:1], wl)
        total += lobe.weight * g[:, None] * spectral
    return total


def world_settings(data: dict[str, Any]) -> dict[str, Any]:
    """Checked keyword arguments of :class:`World` (besides the mesh) from a :meth:`World.to_dict` mapping.

    Examples
    --------
    >>> world_settings({"light": "A", "light_direction": [0, 0, 1]})["light_direction"]
    (0.0, 0.0, 1.0)
    """
    allowed = {"pose", "light", "light_direction", "chart", "chart_present", "chart_layout", "chart_placement",
               "width", "height",
               "camera_distance_mm", "camera_elevation_deg", "fov_deg", "spectral_step", "table_angle_deg",
               "camera_target_mm", "light_position_mm", "lamp_radius_mm", "chart_first", "lens_sigma_px"}
    unknown = set(data) - allowed
    if unknown:
        raise WorldError(f"unknown world setting(s) {', '.join(sorted(unknown))}; known: {', '.join(sorted(allowed))}")
    out = dict(data)
    if "light_direction" in out:
        out["light_direction"] = tuple(float(v) for v in out["light_direction"])
    for key in ("camera_target_mm", "light_position_mm"):
        if out.get(key) is not None:
            out[key] = tuple(float(v) for v in out[key])
    if "pose" in out:
        out["pose"] = np.asarray(out["pose"], dtype=np.float64)
    return out


def _unique_names(names: Any) -> list[str]:
    """``names`` with repeats made unique: ``gold``, ``gold #2``, ...

    Examples
    --------
    >>> _unique_names(["gold", "gold", "red"])
    ['gold', 'gold #2', 'red']
    """
    out: list[str] = []
    for name in names:
        candidate, k = name, 1
        while candidate in out:
            k += 1
            candidate = f"{name} #{k}"
        out.append(candidate)
    return out


def _point3(name: str, value: Any) -> tuple[float, float, float]:
    """``value`` as a finite 3-tuple of floats, or a :class:`WorldError` naming ``name``."""
    try:
        p = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        p = np.array([np.nan])
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise WorldError(f"{name} must be a finite 3-vector in millimetres (room frame), got {value!r}")
    return (float(p[0]), float(p[1]), float(p[2]))
