"""Geometry of a flat swatch on the turntable seen by a fixed camera under a fixed light.

The set-up of ``kogei cloth fit``: a flat square swatch on the table, the
camera looking at the table centre from the room's -y side (a pinhole, the
one of the simulated station), a distant light fixed in the room (one per
pass).  Turning the table by theta turns the warp by theta about the
normal; the light, view and half vectors stay where they are.  Per
photosite this module gives the four cosines and the tangent-frame
components the anisotropic lobes need
(:func:`processing.materials.lobes.material_brdf`).  docs/cloth.md, section
"The swatch set-up", defines the frame and the pinhole.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.errors import InputError

__all__ = ["SwatchGeometry", "SwatchSamples", "swatch_samples", "SwatchGeometryError"]


class SwatchGeometryError(InputError):
    """A value of the swatch set-up is missing or not valid; the message names it."""


#: Field -> (lowest, highest, lowest excluded, what the range means): the physically sensible set-ups of a
#: swatch on a turntable (a camera 1 cm to 10 m away, a lens of 0.5 deg to 170 deg, a swatch of 1 mm to 1 m).
_RANGES: dict[str, tuple[float, float, bool, str]] = {
    "camera_distance_mm": (10.0, 10_000.0, False, "mm, 1 cm to 10 m from the table centre"),
    "camera_elevation_deg": (0.0, 89.0, True, "degrees above the table plane"),
    "fov_deg": (0.5, 170.0, False, "degrees, the lens's horizontal field of view"),
    "swatch_mm": (1.0, 1000.0, False, "mm, the side of the swatch, up to a metre"),
}

#: Fields that are names (strings).
_NAMES = ("light", "camera", "chart")


def _number_problem(name: str, v: Any) -> str | None:
    """Why ``v`` is not a valid value of the numeric field ``name`` (:data:`_RANGES`), or None."""
    lo, hi, open_low, what = _RANGES[name]
    number = isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
    if number and math.isfinite(v) and (lo < v if open_low else lo <= v) and v <= hi:
        return None
    return f"{name} must be a number in {'(' if open_low else '['}{lo:g}, {hi:g}] ({what}), got {v!r}"


def _direction(v: Any) -> NDArray[np.float64] | None:
    """``v`` as three finite numbers with z > 0, or None."""
    if isinstance(v, (str, bytes)):
        return None
    try:
        d = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        return None
    if d.shape != (3,) or not np.all(np.isfinite(d)) or d[2] <= 0:
        return None
    return d


@dataclass(frozen=True)
class SwatchGeometry:
    """The fixed set-up of a swatch measurement (lengths in mm, angles in degrees).

    Attributes
    ----------
    width, height
        Photosites of the camera (even numbers).
    camera_distance_mm
        Distance of the camera from the table centre, in [10, 10000] (1 cm to 10 m).
    camera_elevation_deg
        Elevation of the camera above the table plane, in (0, 89].
    fov_deg
        Horizontal field of view, in [0.5, 170].
    light_direction
        Unit vector toward the distant light of pass 1, in the room (z up).
    light
        Illuminant of the light (a spec of :func:`processing.spectral.spectra.light_spectrum`).
    swatch_mm
        Side of the square swatch, in [1, 1000] (up to a metre).
    warp_angle_deg
        Angle of the warp from the table's x axis at table angle 0.
    camera
        Camera sensitivities (a name of :func:`processing.camera.response.camera_sensitivities`).
    chart
        Colour chart of colour-science's ``SDS_COLOURCHECKERS``.
    pass_light_directions
        Light directions of passes 2, 3, ...

    Raises
    ------
    SwatchGeometryError
        A value missing or out of range (the message names it).

    Examples
    --------
    >>> g = SwatchGeometry.from_dict({"width": 64, "height": 48, "swatch_mm": 60})
    >>> g.width, g.camera_elevation_deg, SwatchGeometry.from_dict(g.to_dict()) == g
    (64, 45.0, True)
    """

    width: int = 160
    height: int = 120
    camera_distance_mm: float = 260.0
    camera_elevation_deg: float = 45.0
    fov_deg: float = 25.0
    light_direction: tuple[float, float, float] = (0.22, 0.6, 0.77)
    light: str = "D65"
    swatch_mm: float = 80.0
    warp_angle_deg: float = 0.0
    camera: str = "Nikon 5100 (NPL)"
    chart: str = "ColorChecker N Ohta"
    pass_light_directions: tuple[tuple[float, float, float], ...] = ()

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 2 or v % 2:
                raise SwatchGeometryError(f"{name} must be an even number of photosites >= 2, got {v!r}")
        for name in _RANGES:
            problem = _number_problem(name, getattr(self, name))
            if problem:
                raise SwatchGeometryError(problem)
        w = self.warp_angle_deg
        if isinstance(w, bool) or not isinstance(w, (int, float, np.integer, np.floating)) or not math.isfinite(w):
            raise SwatchGeometryError(f"warp_angle_deg must be a finite number of degrees, got {w!r}")
        for name in _NAMES:
            if not isinstance(getattr(self, name), str):
                raise SwatchGeometryError(f"{name} must be a name (a string), got {getattr(self, name)!r}")
        d = _direction(self.light_direction)
        if d is None:
            raise SwatchGeometryError(
                f"light_direction must be three numbers toward the light with z > 0 (above the table), "
                f"got {self.light_direction!r}"
            )
        object.__setattr__(self, "light_direction", tuple(float(v) for v in d / np.linalg.norm(d)))
        lights = []
        for k, item in enumerate(self.pass_light_directions, start=2):
            d = _direction(item)
            if d is None:
                raise SwatchGeometryError(
                    f"pass_light_directions: the light of pass {k} must be three numbers toward the light with "
                    f"z > 0 (above the table), got {item!r}"
                )
            lights.append(tuple(float(v) for v in d / np.linalg.norm(d)))
        object.__setattr__(self, "pass_light_directions", tuple(lights))

    @property
    def passes(self) -> int:
        """Number of light positions (passes) the set-up describes.

        Returns
        -------
        int
            1 + the number of ``pass_light_directions``.
        """
        return 1 + len(self.pass_light_directions)

    def for_pass(self, pass_no: int) -> SwatchGeometry:
        """The one-light set-up of pass ``pass_no``.

        Parameters
        ----------
        pass_no
            Pass number, 1-based.

        Returns
        -------
        SwatchGeometry
            The same set-up with that pass's light as ``light_direction`` and
            no further passes.

        Raises
        ------
        SwatchGeometryError
            A pass the set-up has no light for.

        Examples
        --------
        >>> g = SwatchGeometry(pass_light_directions=((0.0, -0.6, 0.8),))
        >>> g.passes, g.for_pass(2).light_direction, g.for_pass(1) == SwatchGeometry()
        (2, (0.0, -0.6, 0.8), True)
        """
        if isinstance(pass_no, bool) or not isinstance(pass_no, (int, np.integer)) or not 1 <= pass_no <= self.passes:
            raise SwatchGeometryError(
                f"pass {pass_no!r} has no light direction: the set-up gives {self.passes} "
                "(light_direction for pass 1, pass_light_directions for passes 2, 3, ...)"
            )
        light = self.light_direction if pass_no == 1 else self.pass_light_directions[pass_no - 2]
        return replace(self, light_direction=light, pass_light_directions=())

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SwatchGeometry:
        """The set-up of a JSON mapping.

        Parameters
        ----------
        data
            Field name -> value; missing fields take their defaults.

        Returns
        -------
        SwatchGeometry
            The set-up.

        Raises
        ------
        SwatchGeometryError
            Not a table, unknown keys (named), or a value of the wrong type or outside its
            range (the message names the field and the range).
        """
        if not isinstance(data, dict):
            raise SwatchGeometryError(
                f"swatch geometry must be a JSON table of field: value (camera_distance_mm, fov_deg, "
                f"light_direction, swatch_mm, ...), got a {type(data).__name__}"
            )
        known = {f.name for f in fields(cls)}
        unknown = {str(k) for k in data} - known
        if unknown:
            raise SwatchGeometryError(
                f"unknown swatch geometry key(s) {', '.join(sorted(unknown))}; valid keys: {', '.join(sorted(known))}"
            )
        kw = dict(data)
        if isinstance(kw.get("light_direction"), list):
            kw["light_direction"] = tuple(kw["light_direction"])
        if "pass_light_directions" in kw:
            lights = kw["pass_light_directions"]
            if not isinstance(lights, (list, tuple)):
                raise SwatchGeometryError(f"pass_light_directions must be a list of directions, got {lights!r}")
            kw["pass_light_directions"] = tuple(tuple(d) if isinstance(d, (list, tuple)) else d for d in lights)
        try:
            return cls(**kw)
        except TypeError as exc:
            raise SwatchGeometryError(f"swatch geometry: {exc}") from None

    def to_dict(self) -> dict[str, Any]:
        """JSON form, the inverse of :meth:`from_dict`.

        Returns
        -------
        dict
            Field name -> value, directions as lists.
        """
        out = asdict(self)
        out["light_direction"] = list(self.light_direction)
        out["pass_light_directions"] = [list(d) for d in self.pass_light_directions]
        return out

    def camera_frame(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Eye position and the camera's unit axes.

        Returns
        -------
        eye : ndarray
            ``(3,)`` position of the pinhole in mm, table centre at the origin.
        forward, right, up : ndarray
            ``(3,)`` unit vectors.
        """
        el = math.radians(self.camera_elevation_deg)
        eye = self.camera_distance_mm * np.array([0.0, -math.cos(el), math.sin(el)])
        fwd = -eye / np.linalg.norm(eye)
        right = np.cross(fwd, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        up = np.cross(right, fwd)
        return eye, fwd, right, up

    def rays(self, i: ArrayLike, j: ArrayLike) -> NDArray[np.float64]:
        """Unit ray directions through photosites.

        Parameters
        ----------
        i, j
            Column and row of each photosite, broadcast together.

        Returns
        -------
        ndarray
            ``(..., 3)`` unit directions in the room frame.

        Examples
        --------
        >>> g = SwatchGeometry(width=2, height=2, camera_elevation_deg=60.0)
        >>> r = g.rays([0, 1], [0, 0])
        >>> bool(np.allclose(np.linalg.norm(r, axis=1), 1.0)), bool(r[0, 0] < 0 < r[1, 0])   # left, right
        (True, True)
        """
        _, fwd, right, up = self.camera_frame()
        half = math.tan(math.radians(self.fov_deg) / 2)
        x = ((np.asarray(i, dtype=np.float64) + 0.5) / self.width * 2 - 1) * half
        y = (1 - (np.asarray(j, dtype=np.float64) + 0.5) / self.height * 2) * half * self.height / self.width
        d = fwd + x[..., None] * right + y[..., None] * up
        return d / np.linalg.norm(d, axis=-1, keepdims=True)


@dataclass(frozen=True)
class SwatchSamples:
    """Geometry of photosites on the swatch at table angles; arrays of shape ``(A, P)``.

    Attributes
    ----------
    cos_i, cos_o, cos_h, cos_d
        n.l, n.v, n.h, l.h.
    tangential
        ``(i_t, i_b, o_t, o_b)``: light and view along the warp t and across it.
    inside
        bool: the photosite sees the swatch (at least ``margin`` mm inside its edge).
    """

    cos_i: NDArray[np.float64]
    cos_o: NDArray[np.float64]
    cos_h: NDArray[np.float64]
    cos_d: NDArray[np.float64]
    tangential: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]
    inside: NDArray[np.bool_]


def swatch_samples(geometry: SwatchGeometry, angles_deg: ArrayLike, i: ArrayLike, j: ArrayLike,
                   margin_mm: float = 0.0) -> SwatchSamples:
    """Geometry of photosites on the swatch at table angles.

    Parameters
    ----------
    geometry
        The set-up.
    angles_deg
        ``(A,)`` table angles in degrees.
    i, j
        ``(P,)`` column and row of each photosite.
    margin_mm
        Photosites within this distance of the swatch's edge count as outside.

    Returns
    -------
    SwatchSamples
        Cosines, tangent-frame components and the inside mask, shape ``(A, P)``.

    Examples
    --------
    >>> g = SwatchGeometry(width=4, height=4)
    >>> s = swatch_samples(g, [0.0, 90.0], [2], [2])
    >>> bool(s.inside.all()), bool(np.allclose(s.cos_i, g.light_direction[2]))
    (True, True)
    """
    a = np.radians(np.asarray(angles_deg, dtype=np.float64).reshape(-1, 1))
    eye = geometry.camera_frame()[0]
    d = geometry.rays(np.asarray(i).reshape(-1), np.asarray(j).reshape(-1))          # (P, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d[:, 2] < 0, -eye[2] / d[:, 2], np.inf)
    p = eye + d * np.where(np.isfinite(t), t, 0.0)[:, None]
    # the point in the swatch's own frame: the table turned by -angle
    c, s = np.cos(a), np.sin(a)
    qx = c * p[:, 0] + s * p[:, 1]
    qy = -s * p[:, 0] + c * p[:, 1]
    half = geometry.swatch_mm / 2 - margin_mm
    inside = (np.abs(qx) <= half) & (np.abs(qy) <= half) & np.isfinite(t)[None, :]
    w = a + math.radians(geometry.warp_angle_deg)
    tx, ty = np.cos(w), np.sin(w)                       # warp direction in the room, (A, 1)
    bx, by = -ty, tx                                    # b = n x t with n = +z
    lx, ly, lz = geometry.light_direction
    ox, oy, oz = (-d[:, 0])[None, :], (-d[:, 1])[None, :], (-d[:, 2])[None, :]
    hx, hy, hz = lx + ox, ly + oy, lz + oz
    hn = np.sqrt(hx * hx + hy * hy + hz * hz)
    cos_h = hz / hn
    cos_d = (lx * hx + ly * hy + lz * hz) / hn
    shape = inside.shape
    full = np.ones(shape)
    return SwatchSamples(
        cos_i=lz * full, cos_o=oz * full, cos_h=cos_h * full, cos_d=cos_d * full,
        tangential=(lx * tx + ly * ty + 0 * full, lx * bx + ly * by + 0 * full, ox * tx + oy * ty, ox * bx + oy * by),
        inside=inside,
    )
