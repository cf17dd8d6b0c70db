"""A chrome sphere on the turntable, for calibrating the station's lamps from their highlights.

:class:`MirrorWorld` is the station world (:class:`mocks.world.World`) with a
mirror ball of ``sphere_radius_mm`` resting on the table ``offset_mm`` from the
axis (along the table's +x at angle 0), turned with the table.  A pixel on the
ball shows the environment reflected there, times the chrome's grey
reflectance (0.6): a lamp's emitting disc where the reflected ray meets it,
else the uniform backdrop radiance (:data:`mocks.world.BACKDROP_REFLECTANCE`
times the light over pi, as on the backdrop itself).

Lamps (:attr:`MirrorWorld.lamps`, fixed in the room) are point lamps
``{"position_mm": [x, y, z], "radius_mm": r}`` -- a disc of radius ``r``
(default :attr:`World.lamp_radius_mm`) facing ``camera_target_mm`` -- or
distant lamps ``{"direction": [x, y, z], "angular_radius_deg": a}`` (default
1 degree).  Without a list the world's own lamp is used
(``light_position_mm`` or ``light_direction``).  A lamp's radiance is chosen
so that its highlight reaches about half the sensor's well
(:class:`mocks.camera_sim.SensorModel`) at the station's default exposure
(0.01 s).

Frames are rendered analytically (ray-sphere intersection, mirror reflection,
ray-disc or cone test) at ``supersample x supersample`` rays per pixel.
Station placement n puts the ball at ``offsets_mm[n - 1]`` (cyclic).

Truth for tests: :meth:`MirrorWorld.lamp_truths`,
:meth:`MirrorWorld.sphere_centre_mm`, :meth:`World.camera_intrinsics`,
:meth:`World.room_to_camera`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocks.world import BACKDROP_REFLECTANCE, Frame, World, WorldError, rotation_z

__all__ = ["MirrorWorld", "CHROME_REFLECTANCE", "DISTANT_LAMP_RADIUS_DEG", "HIGHLIGHT_WELL_FRACTION"]

#: Grey reflectance of the chrome ball.
CHROME_REFLECTANCE = 0.6
#: Angular radius of a distant lamp.
DISTANT_LAMP_RADIUS_DEG = 1.0
#: Fraction of the sensor's well a highlight reaches at the default exposure.
HIGHLIGHT_WELL_FRACTION = 0.5
#: The station's default exposure (s), see :class:`mocks.station.SimulatedStation`.
_DEFAULT_EXPOSURE_S = 0.01


def _check_lamp(lamp: Any, index: int) -> dict[str, Any]:
    """One lamp entry, normalised: a point lamp (position, radius) or a distant one (unit direction, radius)."""
    if not isinstance(lamp, dict) or ("position_mm" in lamp) == ("direction" in lamp):
        raise WorldError(f"lamps[{index}] must map either position_mm (a point lamp) or direction (a distant "
                         f"lamp), got {lamp!r}")
    key = "position_mm" if "position_mm" in lamp else "direction"
    unknown = set(lamp) - {key, "radius_mm" if key == "position_mm" else "angular_radius_deg"}
    if unknown:
        raise WorldError(f"lamps[{index}]: unknown key(s) {', '.join(sorted(unknown))}")
    v = np.asarray(lamp[key], dtype=np.float64)
    if v.shape != (3,) or not np.all(np.isfinite(v)) or (key == "direction" and np.linalg.norm(v) == 0):
        raise WorldError(f"lamps[{index}].{key} must be a finite (non-zero) 3-vector, got {lamp[key]!r}")
    if key == "position_mm":
        r = float(lamp.get("radius_mm", 15.0))
        if not (math.isfinite(r) and r > 0):
            raise WorldError(f"lamps[{index}].radius_mm must be > 0 mm, got {r!r}")
        return {"position_mm": v.tolist(), "radius_mm": r}
    a = float(lamp.get("angular_radius_deg", DISTANT_LAMP_RADIUS_DEG))
    if not (math.isfinite(a) and 0 < a < 45):
        raise WorldError(f"lamps[{index}].angular_radius_deg must be in (0, 45) degrees, got {a!r}")
    norm = float(np.linalg.norm(v))
    return {"direction": (v if abs(norm - 1.0) < 1e-12 else v / norm).tolist(), "angular_radius_deg": a}


@dataclass
class MirrorWorld(World):
    """The station world with a chrome sphere on the table (see the module's description).

    Attributes (besides :class:`mocks.world.World`'s)
    -------------------------------------------------
    sphere_radius_mm
        The ball's radius.
    offsets_mm
        Distance of the ball's centre from the axis in placement n = 1, 2, ... (cyclic).
    lamps
        Point or distant lamps (room frame); None: the world's own lamp.
    supersample
        Rays per pixel along each axis (>= 3).
    """

    sphere_radius_mm: float = 20.0
    offsets_mm: tuple[float, ...] = (35.0,)
    lamps: list[dict[str, Any]] | None = None
    supersample: int = 3

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (math.isfinite(self.sphere_radius_mm) and self.sphere_radius_mm > 0):
            raise WorldError(f"sphere_radius_mm must be > 0, got {self.sphere_radius_mm!r}")
        self.offsets_mm = tuple(float(v) for v in self.offsets_mm)
        if not self.offsets_mm or not all(math.isfinite(v) and v >= 0 for v in self.offsets_mm):
            raise WorldError(f"offsets_mm must hold distances >= 0 mm from the axis, got {self.offsets_mm!r}")
        if self.lamps is not None:
            if not isinstance(self.lamps, (list, tuple)) or not self.lamps:
                raise WorldError("lamps must be a non-empty list of point or distant lamps, or None")
            self.lamps = [_check_lamp(lamp, i) for i, lamp in enumerate(self.lamps)]
        if not isinstance(self.supersample, (int, np.integer)) or self.supersample < 3:
            raise WorldError(f"supersample must be an integer >= 3, got {self.supersample!r}")

    @classmethod
    def mirror_sphere(cls, radius_mm: float = 20.0, offset_mm: float | tuple[float, ...] = 35.0,
                      lamps: list[dict[str, Any]] | None = None, **kwargs: Any) -> MirrorWorld:
        """A chrome ball of ``radius_mm`` resting on the table ``offset_mm`` from the axis (a tuple: per placement).

        Defaults: 960 x 640 pixels, 25 degrees field of view.

        Examples
        --------
        >>> w = MirrorWorld.mirror_sphere(20.0, 35.0, width=96, height=64)
        >>> w.sphere_centre_mm(90.0).round(9).tolist(), w.frame("object", 0.0).radiance.shape[:2]
        ([0.0, 35.0, 20.0], (64, 96))
        """
        import open3d as o3d

        offsets = tuple(float(v) for v in np.atleast_1d(offset_mm))
        if not (math.isfinite(radius_mm) and radius_mm > 0) or not offsets:
            raise WorldError(f"mirror sphere: radius_mm must be > 0 and offset_mm given, got {radius_mm!r}, "
                             f"{offset_mm!r}")
        mesh = o3d.geometry.TriangleMesh.create_sphere(float(radius_mm), resolution=60)
        kwargs.setdefault("width", 960)
        kwargs.setdefault("height", 640)
        kwargs.setdefault("fov_deg", 25.0)
        pose = np.eye(4)
        pose[0, 3], pose[2, 3] = offsets[0], float(radius_mm)
        kwargs.setdefault("pose", pose)
        return cls(np.asarray(mesh.vertices), np.asarray(mesh.triangles), np.zeros(len(mesh.triangles), np.int64),
                   ("sphere",), {"sphere": "chrome"}, mesh_source=f"mirror:{radius_mm:g}:{offsets[0]:g}",
                   sphere_radius_mm=float(radius_mm), offsets_mm=offsets, lamps=lamps, **kwargs)

    @property
    def shows_chart(self) -> bool:
        """A calibration target: the station shoots no chart frame."""
        return False

    def fixed_placement_pose(self, placement: int) -> NDArray[np.float64]:
        """Ball -> table pose of station placement ``placement`` (>= 1): centre at the n-th offset on +x."""
        pose = np.eye(4)
        pose[0, 3] = self.offsets_mm[(int(placement) - 1) % len(self.offsets_mm)]
        pose[2, 3] = self.sphere_radius_mm
        return pose

    def sphere_centre_mm(self, table_angle_deg: float | None = None) -> NDArray[np.float64]:
        """True centre of the ball (room frame, mm) at a table angle (None: :attr:`table_angle_deg`)."""
        angle = self.table_angle_deg if table_angle_deg is None else float(table_angle_deg)
        return (rotation_z(angle) @ self.pose @ [0.0, 0.0, 0.0, 1.0])[:3]

    def lamp_truths(self) -> list[dict[str, Any]]:
        """The lamps as the calibration should find them: ``{"kind": "point", "position_mm", "radius_mm"}``
        or ``{"kind": "distant", "direction", "angular_radius_deg"}`` (room frame)."""
        if self.lamps is None:
            own = self.lamp_truth()
            if own["kind"] == "point":
                return [{"kind": "point", "position_mm": own["position_mm"], "radius_mm": own["radius_mm"]}]
            return [{"kind": "distant", "direction": own["direction"],
                     "angular_radius_deg": DISTANT_LAMP_RADIUS_DEG}]
        return [{"kind": "point" if "position_mm" in lamp else "distant", **lamp} for lamp in self.lamps]

    def lamp_radiance_scale(self) -> float:
        """Lamp radiance over that of a white diffuser lit by the world's light (``E / pi``).

        Chosen so the brightest camera channel of a highlight (chrome 0.6 times
        the lamp) reaches :data:`HIGHLIGHT_WELL_FRACTION` of the well at 0.01 s.
        """
        from mocks.camera_sim import SensorModel, channel_signal

        sensor = SensorModel()
        white = float(np.max(channel_signal(self.light_spectrum() / math.pi, self.grid)))
        return HIGHLIGHT_WELL_FRACTION * sensor.well_e / (CHROME_REFLECTANCE * white * sensor.quantum_scale
                                                          * _DEFAULT_EXPOSURE_S)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> MirrorWorld:
        """Rebuild from :meth:`to_dict` (the fake gphoto2's configuration).

        Examples
        --------
        >>> w = MirrorWorld.mirror_sphere(15.0, (30.0, 40.0), lamps=[{"direction": [0, -1, 1]}], width=96, height=64)
        >>> v = MirrorWorld.from_dict(w.to_dict())
        >>> v.sphere_radius_mm, v.offsets_mm, v.lamps[0]["angular_radius_deg"]
        (15.0, (30.0, 40.0), 1.0)
        """
        from mocks.world import world_settings

        data = dict(data)
        spec = data.pop("mirror")
        if not isinstance(spec, dict) or not {"sphere_radius_mm", "offsets_mm", "lamps"} <= set(spec):
            raise WorldError(f"world 'mirror' entry must map sphere_radius_mm, offsets_mm and lamps, got {spec!r}")
        data.pop("mesh", None)
        data.pop("materials", None)
        extra = {"supersample": int(spec["supersample"])} if "supersample" in spec else {}
        return cls.mirror_sphere(float(spec["sphere_radius_mm"]), tuple(spec["offsets_mm"]), spec["lamps"],
                                 **extra, **world_settings(data))

    def to_dict(self) -> dict[str, Any]:
        """The station world's mapping plus ``"mirror"``: radius, offsets, lamps, supersampling."""
        out = super().to_dict()
        out["mirror"] = {"sphere_radius_mm": float(self.sphere_radius_mm), "offsets_mm": list(self.offsets_mm),
                         "lamps": None if self.lamps is None else [dict(lamp) for lamp in self.lamps],
                         "supersample": int(self.supersample)}
        return out

    def _sees_lamp(self, points: NDArray[np.float64], rays: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Whether reflected rays (unit, ``(N, 3)``) from ``points`` meet any lamp."""
        target = np.asarray(self.camera_target_mm, dtype=np.float64)
        seen = np.zeros(len(rays), dtype=bool)
        for lamp in self.lamp_truths():
            if lamp["kind"] == "distant":
                seen |= rays @ np.asarray(lamp["direction"]) >= math.cos(math.radians(lamp["angular_radius_deg"]))
                continue
            centre = np.asarray(lamp["position_mm"], dtype=np.float64)
            normal = (target - centre) / np.linalg.norm(target - centre)     # the disc faces the target
            denom = rays @ normal
            with np.errstate(divide="ignore", invalid="ignore"):
                t = ((centre - points) @ normal) / denom
            hit = points + rays * np.where(np.isfinite(t), t, 0.0)[:, None]
            seen |= (denom < 0) & (t > 0) & (np.linalg.norm(hit - centre, axis=1) <= lamp["radius_mm"])
        return seen

    def _object_frame(self, angle: float) -> Frame:
        """The ball at table angle ``angle``: reflected lamps and backdrop, supersampled."""
        grid, e = self.grid, self.light_spectrum()
        h, w, s = self.height, self.width, int(self.supersample)
        centre, r = self.sphere_centre_mm(angle), float(self.sphere_radius_mm)
        eye, axes = self._camera_axes()
        k = self.camera_intrinsics()
        # pixels whose centre ray passes within r + 2 pixel footprints of the centre: only those are supersampled
        eye_c, centre_dirs = self._rays(1)
        d1 = centre_dirs.reshape(-1, 3)
        oc = eye_c - centre
        along = d1 @ oc
        miss2 = (oc @ oc) - along * along
        footprint = 2.0 * float(np.linalg.norm(oc)) / k[0, 0]
        near = np.flatnonzero((along < 0) & (miss2 < (r + footprint) ** 2))
        value = np.full(h * w, BACKDROP_REFLECTANCE)
        cover = np.zeros(h * w)
        if near.size:
            sub = (np.arange(s) + 0.5) / s - 0.5
            du, dv = (g.ravel() for g in np.meshgrid(sub, sub))
            x = ((near % w)[:, None] + du[None, :] - k[0, 2]) / k[0, 0]
            y = ((near // w)[:, None] + dv[None, :] - k[1, 2]) / k[1, 1]
            d = axes[2] + x.reshape(-1, 1) * axes[0] + y.reshape(-1, 1) * axes[1]
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            b = d @ oc
            disc = b * b - (oc @ oc - r * r)
            hit = (disc > 0) & (b < 0)
            sample = np.full(len(d), BACKDROP_REFLECTANCE)
            t = -b[hit] - np.sqrt(disc[hit])
            p = eye + d[hit] * t[:, None]
            n = (p - centre) / r
            refl = d[hit] - 2.0 * np.einsum("ij,ij->i", d[hit], n)[:, None] * n
            lamp = self._sees_lamp(p, refl)
            sample[hit] = CHROME_REFLECTANCE * np.where(lamp, self.lamp_radiance_scale(), BACKDROP_REFLECTANCE)
            value[near] = sample.reshape(-1, s * s).mean(axis=1)
            cover[near] = hit.reshape(-1, s * s).mean(axis=1)
        labels = np.where(cover > 0.5, 0, -1).astype(np.int16).reshape(h, w)
        return Frame(value.reshape(h, w)[..., None] * (e / math.pi), grid, e, labels, "object", angle)
