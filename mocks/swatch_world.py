"""A simulated fabric swatch on the turntable, with known cloth parameters.

The station's world (:class:`mocks.world.World`) with a flat square swatch of
a cloth material (Yasuda et al.'s model, :mod:`processing.cloth.model`)
instead of a scanned object: its object frames are rendered with the
anisotropic model, the warp turning with the table, so a ``swatch`` capture
plan records how the cloth's reflection changes with the yarn direction.
The camera and the light are fixed in the room and set near the mirror
configuration (the half vector about 10 degrees off the normal), where the
anisotropic lobes change most with the table angle.  Chart frames are those
of the station world.

The world renders in-process for the simulated hot-folder camera; its
serialised form (:meth:`SwatchWorld.to_dict`, the station world's mapping with
a ``"swatch"`` entry: cloth spec, size, weave angle) lets the fake ``gphoto2``
rebuild it (:meth:`mocks.world.World.from_dict` dispatches on that entry).

:meth:`SwatchWorld.geometry` is the set-up a lab would measure and give to
``kogei cloth fit`` (camera pose, light direction, swatch size).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from mocks.world import BACKDROP_REFLECTANCE, Frame, World, WorldError

__all__ = ["SwatchWorld"]


@dataclass
class SwatchWorld(World):
    """The station world with a flat cloth swatch (centred on the table axis, warp along x at angle 0).

    Attributes (besides :class:`mocks.world.World`'s)
    -------------------------------------------------
    cloth
        The swatch's material spec (a cloth preset with overrides, e.g.
        ``"silk:a_t=0.08"``): the ground truth of a fit.
    swatch_mm
        Side of the square swatch.
    weave_angle_deg
        Warp direction from the table's x axis.
    """

    cloth: str = "silk"
    swatch_mm: float = 80.0
    weave_angle_deg: float = 0.0

    @classmethod
    def swatch(cls, cloth: str = "silk", swatch_mm: float = 80.0, **kwargs: Any) -> SwatchWorld:
        """A swatch world; keyword arguments set :class:`World` fields (image size, light, camera...).

        Examples
        --------
        >>> w = SwatchWorld.swatch("cotton", width=32, height=24)
        >>> f = w.frame("object", 30.0)
        >>> f.radiance.shape[:2], int(f.labels.max()), w.geometry()["swatch_mm"]
        ((24, 32), 0, 80.0)
        """
        from processing.materials.presets import get_material

        get_material(cloth)                                  # refuse a bad spec early, by name
        if not (math.isfinite(swatch_mm) and swatch_mm > 0):
            raise WorldError(f"swatch_mm must be > 0, got {swatch_mm!r}")
        half = swatch_mm / 2
        vertices = np.array([[-half, -half, 0.0], [half, -half, 0.0], [half, half, 0.0], [-half, half, 0.0]])
        triangles = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
        kwargs.setdefault("camera_elevation_deg", 45.0)
        kwargs.setdefault("camera_target_mm", (0.0, 0.0, 0.0))   # the swatch's centre on the table
        kwargs.setdefault("light_direction", (0.22, 0.6, 0.77))
        kwargs.setdefault("width", 160)
        kwargs.setdefault("height", 120)
        return cls(vertices, triangles, np.zeros(2, np.int64), ("swatch",), {"swatch": cloth},
                   mesh_source=f"swatch:{swatch_mm:g}", cloth=cloth, swatch_mm=float(swatch_mm), **kwargs)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SwatchWorld:
        """Rebuild a swatch world from :meth:`to_dict` (the fake gphoto2's configuration).

        Examples
        --------
        >>> w = SwatchWorld.swatch("satin", swatch_mm=50.0, width=32, height=24, weave_angle_deg=20.0)
        >>> v = SwatchWorld.from_dict(w.to_dict())
        >>> v.cloth, v.swatch_mm, v.weave_angle_deg, v.width
        ('satin', 50.0, 20.0, 32)
        """
        from mocks.world import world_settings

        data = dict(data)
        swatch = data.pop("swatch")
        if not isinstance(swatch, dict) or set(swatch) != {"cloth", "swatch_mm", "weave_angle_deg"}:
            raise WorldError(f"world 'swatch' entry must map cloth, swatch_mm and weave_angle_deg, got {swatch!r}")
        data.pop("mesh", None)
        data.pop("materials", None)
        return cls.swatch(str(swatch["cloth"]), float(swatch["swatch_mm"]),
                          weave_angle_deg=float(swatch["weave_angle_deg"]), **world_settings(data))

    def to_dict(self) -> dict[str, Any]:
        """The station world's mapping plus ``"swatch"``: cloth spec, side (mm) and weave angle (degrees)."""
        out = super().to_dict()
        out["swatch"] = {"cloth": self.cloth, "swatch_mm": float(self.swatch_mm),
                         "weave_angle_deg": float(self.weave_angle_deg)}
        return out

    def geometry(self) -> dict[str, Any]:
        """The set-up as ``kogei cloth fit`` reads it (:class:`processing.cloth.swatch_geometry.SwatchGeometry`)."""
        from mocks.camera_sim import SENSITIVITIES

        d = np.asarray(self.light_direction, dtype=np.float64)
        return {"width": int(self.width), "height": int(self.height),
                "camera_distance_mm": float(self.camera_distance_mm),
                "camera_elevation_deg": float(self.camera_elevation_deg), "fov_deg": float(self.fov_deg),
                "light_direction": (d / np.linalg.norm(d)).tolist(), "light": str(self.light),
                "swatch_mm": float(self.swatch_mm), "warp_angle_deg": float(self.weave_angle_deg),
                "camera": SENSITIVITIES, "chart": self.chart}

    def _view(self) -> tuple[np.ndarray, np.ndarray]:
        """The station's camera, aimed at the table centre whatever the placement's pose.

        The swatch lies flat where it was put: a new pass of a swatch capture
        moves the lamp, not the swatch, so the station's placement poses
        (meant for re-placing a scanned object) must not turn the camera.
        """
        return World._view(dataclasses.replace(self, pose=np.eye(4)))

    def _object_frame(self, angle: float) -> Frame:
        """The swatch at table angle ``angle``: the plane z = 0 hit by the camera rays, shaded by the cloth model."""
        from processing.materials.lobes import material_brdf
        from processing.materials.presets import get_material

        grid, e = self.grid, self.light_spectrum()
        eye, dirs = self._view()
        h, w = self.height, self.width
        d = dirs.reshape(-1, 3)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(d[:, 2] < 0, -eye[2] / d[:, 2], np.inf)
        p = eye + d * np.where(np.isfinite(t), t, 0.0)[:, None]
        a = math.radians(angle)
        # into the swatch's frame: undo the table's turn
        qx = math.cos(a) * p[:, 0] + math.sin(a) * p[:, 1]
        qy = -math.sin(a) * p[:, 0] + math.cos(a) * p[:, 1]
        half = self.swatch_mm / 2
        hit = np.isfinite(t) & (np.abs(qx) <= half) & (np.abs(qy) <= half)
        radiance = np.empty((h * w, grid.size))
        radiance[:] = BACKDROP_REFLECTANCE * e / math.pi
        labels = np.full(h * w, -1, dtype=np.int16)
        idx = np.flatnonzero(hit)
        if idx.size:
            light = np.asarray(self.light_direction, dtype=np.float64)
            light = light / np.linalg.norm(light)
            view = -d[idx]
            half_v = light + view
            half_v /= np.linalg.norm(half_v, axis=1, keepdims=True)
            warp = a + math.radians(self.weave_angle_deg)
            tan = np.array([math.cos(warp), math.sin(warp), 0.0])
            bit = np.cross([0.0, 0.0, 1.0], tan)
            ci = np.full(idx.size, light[2])
            tangential = (np.full(idx.size, light @ tan), np.full(idx.size, light @ bit), view @ tan, view @ bit)
            f = material_brdf(get_material(self.cloth), ci, view[:, 2], half_v[:, 2], half_v @ light,
                              grid.wavelengths, tangential)
            radiance[idx] = f * ci[:, None] * e
            labels[idx] = 0
        return Frame(radiance.reshape(h, w, grid.size), grid, e, labels.reshape(h, w), "object", angle)
