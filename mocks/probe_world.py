"""A chrome sphere in a lit room, for light-probe capture: the room's light is a known environment map.

:class:`ProbeWorld` is the mirror-sphere world (:class:`mocks.mirror_world.MirrorWorld`) placed in a
room whose light is a truth :class:`~processing.lighting.environment_map.EnvironmentMap` in the room
frame (:func:`room_environment`: coloured walls, a grey floor, a white ceiling, a window and three
ceiling lamps).  Behind the ball stands the booth's grey card (reflectance
:data:`mocks.world.BACKDROP_REFLECTANCE`, lit by the room), which fills the camera's view, so the
ball is found against a uniform backdrop as in the lamp calibration.  A pixel on the ball shows the
chrome's grey reflectance (:data:`mocks.mirror_world.CHROME_REFLECTANCE`) times what its mirrored ray
meets: the card where the ray heads into it, else the room (the environment along the ray; the room
is far away compared with the ball).  The colour chart lies on the table, facing up, lit by the room:
the world's light (:meth:`ProbeWorld.light_spectrum`) is the room's irradiance on an up-facing
surface, so a chart frame is the same light the probe sees.

Frames are rendered analytically (ray-sphere intersection, mirror reflection, ray-card test,
bilinear look-up of the environment) at ``supersample x supersample`` rays per pixel, in the
environment's coefficients, then turned into spectra once per pixel.  :func:`write_probe_shots`
writes a chart frame and exposure brackets of the ball as DNG files with the simulated camera
(:mod:`mocks.camera_sim`), as a tethered bracketed capture would.  A colour filter over the lens
(:data:`FILTERS`, idealised smooth curves; ``lens_filter`` of the world, or ``transmission`` of
:func:`write_probe_shots`) gives the second bracket set of a probe from two sets;
:func:`write_filter_csv` writes its transmission as a data sheet would.

Truth for tests: :attr:`ProbeWorld.environment` (the room's radiance in the units of the world's
light), :meth:`ProbeWorld.chart_white_luminance` (the luminance of a white diffuser where the chart
lies, the unit a chart-calibrated probe measures in), :meth:`MirrorWorld.sphere_centre_mm`,
:meth:`World.camera_intrinsics`, :meth:`World.room_to_camera`.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mocks.mirror_world import CHROME_REFLECTANCE, MirrorWorld
from mocks.world import BACKDROP_REFLECTANCE, Frame, WorldError, chart_reflectances
from processing.lighting.environment_map import EnvironmentMap, pixel_directions
from processing.spectral.display import spectra_to_xyz
from processing.spectral.spectra import SpectralGrid, light_spectrum

__all__ = ["ProbeWorld", "room_environment", "region_labels", "write_probe_shots", "BRACKET_TIMES_S",
           "CHART_TIME_S", "PROBE_F_NUMBER", "ROOM_REGIONS", "WALL_PATCHES", "FILTERS", "filter_transmission",
           "write_filter_csv", "PROBE_FILTER", "write_filtered_shots", "write_light_csv"]

#: Exposure times (s) of the probe's brackets: 2 EV apart, as gphoto2 shutter settings 1/4000 ... 1.
BRACKET_TIMES_S = (1 / 4000, 1 / 1000, 1 / 250, 1 / 60, 1 / 15, 1 / 4, 1.0)
#: Exposure time (s) of the chart frame shot in the room's light.
CHART_TIME_S = 1 / 500
#: The aperture the simulated lens records.
PROBE_F_NUMBER = 8.0
#: Names of the room's regions (:func:`region_labels`), in label order.
ROOM_REGIONS = ("floor", "ceiling", "red wall", "green wall", "blue wall", "yellow wall", "window",
                "lamp 1", "lamp 2", "lamp 3")

#: Colour filters in front of the lens for a second bracket set (idealised smooth curves, not a product's
#: measured transmission): name -> (kind, centre or edge nm, width nm).  A long-pass rises at its edge, a
#: short-pass falls, a band passes a Gaussian band, a notch removes one.
FILTERS = {"yellow long-pass 500 nm": ("long", 500.0, 12.0), "orange long-pass 550 nm": ("long", 550.0, 12.0),
           "red long-pass 600 nm": ("long", 600.0, 12.0), "cyan short-pass 560 nm": ("short", 560.0, 12.0),
           "green band 530 nm": ("band", 530.0, 40.0), "magenta notch 540 nm": ("notch", 540.0, 30.0)}
#: The filter the probe's second bracket set is shot through by default (:data:`FILTERS`).
PROBE_FILTER = "magenta notch 540 nm"

#: ColorChecker patches (0-based, reading order) of the walls: red, green, blue, yellow (white: the ceiling)
WALL_PATCHES = (14, 13, 12, 15)
_CEILING_PATCH = 18
_FLOOR_REFLECTANCE = 0.3
_WALL_LEVEL = 1.0           # wall radiance = reflectance x D65 of luminance _WALL_LEVEL
_WINDOW_LEVEL = 8.0         # luminance of the window (D65)
_LAMP_LEVEL = 40.0          # luminance of a ceiling lamp
_LAMP_RADIUS_DEG = 10.0
_LAMPS = ((30.0, 60.0), (150.0, 55.0), (270.0, 65.0))        # (azimuth, elevation) degrees
_WINDOW = (200.0, 240.0, 10.0, 40.0)                          # azimuth from-to, elevation from-to, degrees


def region_labels(height: int) -> NDArray[np.int16]:
    """Which room region (:data:`ROOM_REGIONS`) each pixel centre of an ``height x 2 height`` map sees.

    The horizon splits floor and walls, 70 degrees of elevation walls and ceiling; the four walls are
    the quadrants of azimuth centred on +x, +y, -x, -y; the window and lamps lie on top.

    Examples
    --------
    >>> lab = region_labels(16)
    >>> ROOM_REGIONS[int(lab[15, 0])], ROOM_REGIONS[int(lab[0, 0])]
    ('floor', 'ceiling')
    """
    d = pixel_directions(height, 2 * height)
    elev = np.degrees(np.arcsin(np.clip(d[..., 2], -1.0, 1.0)))
    az = np.mod(np.degrees(np.arctan2(d[..., 1], d[..., 0])), 360.0)
    lab = np.full((height, 2 * height), 0, np.int16)
    wall = np.mod(np.floor((az + 45.0) / 90.0), 4).astype(np.int16)
    lab[elev >= 0] = 2 + wall[elev >= 0]
    lab[elev >= 70.0] = 1
    w = _WINDOW
    lab[(az >= w[0]) & (az < w[1]) & (elev >= w[2]) & (elev < w[3])] = 6
    for k, (a, e) in enumerate(_LAMPS):
        c = np.array([math.cos(math.radians(e)) * math.cos(math.radians(a)),
                      math.cos(math.radians(e)) * math.sin(math.radians(a)), math.sin(math.radians(e))])
        lab[d @ c >= math.cos(math.radians(_LAMP_RADIUS_DEG))] = 7 + k
    return lab


_GRID = SpectralGrid(400.0, 700.0, 10.0)


def room_environment(height: int = 128, grid: SpectralGrid = _GRID,
                     lamp_light: str = "D65") -> EnvironmentMap:
    """The simulated room's light as an environment map in the room frame (the truth of a probe).

    Parameters
    ----------
    height
        Rows of the map.
    grid
        Wavelength grid.
    lamp_light
        The ceiling lamps' spectrum (walls, ceiling, floor and window are lit by / are D65).

    Returns
    -------
    EnvironmentMap
        One basis spectrum per region (:data:`ROOM_REGIONS`), coefficient 1 inside the region:
        ``basis[k]`` is the region's spectral radiance; a D65 radiance of luminance 1 is as bright as
        a white diffuser under the station's light (:mod:`mocks.world`).

    Examples
    --------
    >>> env = room_environment(16)
    >>> env.coefficients.shape, round(float(env.luminance([[0.0, 0.0, -1.0]])[0]), 3)
    ((16, 32, 10), 0.3)
    """
    d65 = light_spectrum("D65", grid)
    d65 = d65 / float(spectra_to_xyz(d65, grid)[1])
    lamp = light_spectrum(lamp_light, grid)
    lamp = lamp / float(spectra_to_xyz(lamp, grid)[1])
    patches = chart_reflectances(grid)
    rows = [_FLOOR_REFLECTANCE * d65, _WALL_LEVEL * patches[_CEILING_PATCH] * d65]
    rows += [_WALL_LEVEL * patches[p] * d65 for p in WALL_PATCHES]
    rows += [_WINDOW_LEVEL * d65] + [_LAMP_LEVEL * lamp] * len(_LAMPS)
    lab = region_labels(height)
    coeff = np.zeros((height, 2 * height, len(rows)), np.float32)
    np.put_along_axis(coeff, lab[..., None].astype(np.intp), 1.0, axis=2)
    return EnvironmentMap(coeff, np.stack(rows), grid, source="simulated room")


@dataclass
class ProbeWorld(MirrorWorld):
    """The mirror-sphere world in a room lit by :attr:`environment` (see the module's description).

    Attributes (besides :class:`mocks.mirror_world.MirrorWorld`'s)
    ---------------------------------------------------------------
    environment
        The room's radiance (room frame), on the world's grid; None: :func:`room_environment`.
    card_distance_mm
        Distance of the grey card behind the ball's centre along the camera's axis.
    room_height, lamp_light
        The rows and the lamps' spectrum of :func:`room_environment` when ``environment`` is None.
    lens_filter
        A filter of :data:`FILTERS` in front of the lens for every frame (the chart's too): the second
        bracket set of a probe from two sets.  None: no filter.
    """

    environment: EnvironmentMap | None = None
    card_distance_mm: float = 150.0
    room_height: int = 128
    lamp_light: str = "D65"
    lens_filter: str | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        # a copy of a world (dataclasses.replace) hands its room over: still the room of its settings
        self._own_room = self.environment is None or (
            self.environment.source == "simulated room" and self.environment.height == int(self.room_height))
        if self.environment is None:
            self.environment = room_environment(int(self.room_height), self.grid, self.lamp_light)
        if self.environment.grid != self.grid:
            raise WorldError(f"environment: its grid {self.environment.grid} differs from the world's {self.grid}")
        if not (math.isfinite(self.card_distance_mm) and self.card_distance_mm > self.sphere_radius_mm):
            raise WorldError(f"card_distance_mm must exceed the ball's radius, got {self.card_distance_mm!r}")
        if self.lens_filter is not None and self.lens_filter not in FILTERS:
            raise WorldError(f"lens_filter {self.lens_filter!r} is not one of the simulated filters: "
                             f"{', '.join(FILTERS)}")

    def lens_transmission(self) -> NDArray[np.float64] | float:
        """The lens filter's transmission on the world's grid (1.0 without a filter)."""
        if self.lens_filter is None:
            return 1.0
        return filter_transmission(*FILTERS[self.lens_filter], self.grid.wavelengths)

    def frame(self, kind: str = "object", table_angle_deg: float | None = None) -> Frame:
        """The frame as :meth:`World.frame`, through the lens filter if there is one."""
        f = super().frame(kind, table_angle_deg)
        if self.lens_filter is None:
            return f
        return replace(f, radiance=f.radiance * self.lens_transmission())

    @classmethod
    def probe(cls, radius_mm: float = 20.0, environment: EnvironmentMap | None = None, **kwargs: Any) -> ProbeWorld:
        """A chrome ball of ``radius_mm`` on the table's axis in the room ``environment`` (default :func:`room_environment`).

        Examples
        --------
        >>> w = ProbeWorld.probe(20.0, width=96, height=64)
        >>> w.frame("object").radiance.shape[:2], w.shows_chart
        ((64, 96), True)
        """
        kwargs.setdefault("chart_layout", "classic24")
        own = {k: kwargs.pop(k) for k in ("card_distance_mm", "room_height", "lamp_light", "supersample", "lens_filter")
               if k in kwargs}
        base = MirrorWorld.mirror_sphere(radius_mm, 0.0, **kwargs)
        fields = {f: getattr(base, f) for f in base.__dataclass_fields__}
        fields.update(environment=environment, **own)
        if environment is not None:
            fields["spectral_step"] = environment.grid.step
        return cls(**fields)

    @property
    def shows_chart(self) -> bool:
        """The chart lies on the table in the room's light: the station shoots it first."""
        return bool(self.chart_first)

    def light_spectrum(self) -> NDArray[np.float64]:
        """The room's spectral irradiance on an up-facing surface (the chart's light), world units."""
        env = self.environment
        d = env.directions()
        w = np.clip(d[..., 2], 0.0, None) * env.solid_angles()
        return np.einsum("hw,hwk->k", w, env.coefficients.astype(np.float64)) @ env.basis

    def chart_white_luminance(self) -> float:
        """Luminance of a white diffuser on the table in the room's light (``Y(E / pi)``)."""
        return float(spectra_to_xyz(self.light_spectrum() / math.pi, self.grid)[1])

    @property
    def f_number(self) -> float:
        """The aperture the simulated lens records in the probe's frames."""
        return PROBE_F_NUMBER

    def to_dict(self) -> dict[str, Any]:
        """The mirror world's mapping plus ``"probe"`` (the simulated room; the fake gphoto2's configuration).

        Examples
        --------
        >>> w = ProbeWorld.probe(20.0, width=96, height=64, room_height=16)
        >>> v = ProbeWorld.from_dict(w.to_dict())
        >>> bool(np.array_equal(v.environment.coefficients, w.environment.coefficients))
        True
        """
        if not self._own_room:
            raise WorldError("a probe world with a given environment map cannot be serialised; write its frames "
                             "with write_probe_shots")
        out = super().to_dict()
        out["probe"] = {"card_distance_mm": float(self.card_distance_mm), "room_height": int(self.room_height),
                        "lamp_light": str(self.lamp_light), "lens_filter": self.lens_filter}
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ProbeWorld:
        """Rebuild from :meth:`to_dict`."""
        from mocks.world import world_settings

        data = dict(data)
        spec = data.pop("probe")
        mirror = data.pop("mirror")
        data.pop("mesh", None)
        data.pop("materials", None)
        if not isinstance(spec, dict) or not isinstance(mirror, dict):
            raise WorldError(f"world 'probe' entry must map card_distance_mm, room_height and lamp_light, got {spec!r}")
        return cls.probe(float(mirror["sphere_radius_mm"]), supersample=int(mirror.get("supersample", 3)),
                         card_distance_mm=float(spec["card_distance_mm"]), room_height=int(spec["room_height"]),
                         lamp_light=str(spec["lamp_light"]), lens_filter=spec.get("lens_filter"),
                         **world_settings(data))

    def _card(self) -> tuple[NDArray[np.float64], NDArray[np.float64], float, float]:
        """The card's centre (room, mm), its normal toward the camera, its half width and height (mm)."""
        eye, axes = self._camera_axes()
        centre = self.sphere_centre_mm(0.0) + axes[2] * self.card_distance_mm
        dist = float(np.linalg.norm(centre - eye))
        half_w = 1.2 * dist * math.tan(math.radians(self.fov_deg) / 2)
        return centre, -axes[2], half_w, half_w * self.height / self.width * 1.2

    def _card_hits(self, points: NDArray[np.float64], rays: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Whether rays from ``points`` meet the card."""
        centre, normal, hw, hh = self._card()
        _, axes = self._camera_axes()
        denom = rays @ normal
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((centre - points) @ normal) / denom
        t = np.where(np.isfinite(t), t, -1.0)
        rel = points + rays * t[:, None] - centre
        return (denom < 0) & (t > 0) & (np.abs(rel @ axes[0]) <= hw) & (np.abs(rel @ axes[1]) <= hh)

    def _ball_pixels(self, angle: float) -> NDArray[np.intp]:
        """Flat indices of the pixels whose centre ray passes within the ball's radius + 2 pixel footprints."""
        centre, r = self.sphere_centre_mm(angle), float(self.sphere_radius_mm)
        eye, _ = self._camera_axes()
        k = self.camera_intrinsics()
        oc = eye - centre
        _, dirs = self._rays(1)
        along = dirs.reshape(-1, 3) @ oc
        footprint = 2.0 * float(np.linalg.norm(oc)) / k[0, 0]
        return np.flatnonzero((along < 0) & ((oc @ oc) - along * along < (r + footprint) ** 2))

    def _ball_samples(self, angle: float, pixels: NDArray[np.intp]
                      ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """For flat pixel indices: mean environment coefficients ``(N, K)`` of their rays (chrome applied),
        the weight of the card's radiance ``(N,)`` (rays missing the ball: 1, mirrored into the card: the
        chrome's reflectance) and the share of rays on the ball ``(N,)``."""
        env = self.environment
        w, s = self.width, int(self.supersample)
        centre, r = self.sphere_centre_mm(angle), float(self.sphere_radius_mm)
        eye, axes = self._camera_axes()
        k = self.camera_intrinsics()
        oc = eye - centre
        sub = (np.arange(s) + 0.5) / s - 0.5
        du, dv = (g.ravel() for g in np.meshgrid(sub, sub))
        x = ((pixels % w)[:, None] + du[None, :] - k[0, 2]) / k[0, 0]
        y = ((pixels // w)[:, None] + dv[None, :] - k[1, 2]) / k[1, 1]
        d = axes[2] + x.reshape(-1, 1) * axes[0] + y.reshape(-1, 1) * axes[1]
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        b = d @ oc
        disc = b * b - (oc @ oc - r * r)
        hit = (disc > 0) & (b < 0)
        t = -b[hit] - np.sqrt(disc[hit])
        p = eye + d[hit] * t[:, None]
        n = (p - centre) / r
        refl = d[hit] - 2.0 * np.einsum("ij,ij->i", d[hit], n)[:, None] * n
        on_card = self._card_hits(p, refl)
        kk = env.coefficients.shape[2]
        c = np.zeros((len(d), kk))
        hit_idx = np.flatnonzero(hit)
        c[hit_idx[~on_card]] = CHROME_REFLECTANCE * env.lookup(refl[~on_card])
        card = (~hit).astype(np.float64)
        card[hit_idx[on_card]] = CHROME_REFLECTANCE
        return (c.reshape(-1, s * s, kk).mean(axis=1), card.reshape(-1, s * s).mean(axis=1),
                hit.reshape(-1, s * s).mean(axis=1))

    def _object_frame(self, angle: float) -> Frame:
        """The ball in the room: mirrored room and card, supersampled; the card elsewhere."""
        env, grid = self.environment, self.grid
        h, w = self.height, self.width
        card = BACKDROP_REFLECTANCE * self.light_spectrum() / math.pi
        near = self._ball_pixels(angle)
        radiance = np.broadcast_to(card, (h * w, grid.size)).copy()
        cover = np.zeros(h * w)
        if near.size:
            coeff, card_share, cover[near] = self._ball_samples(angle, near)
            radiance[near] = coeff @ env.basis + card_share[:, None] * card[None, :]
        labels = np.where(cover > 0.5, 0, -1).astype(np.int16).reshape(h, w)
        return Frame(radiance.reshape(h, w, grid.size), grid, self.light_spectrum(), labels, "object", angle)

    def camera_signal(self, sensitivities: NDArray[np.float64], angle: float = 0.0,
                      chunk: int = 1 << 17) -> NDArray[np.float32]:
        """``(H, W, 3)`` camera channel signal of the object frame (radiance x sensitivity x nm, see
        :func:`mocks.camera_sim.channel_signal`) without the spectral image: for large frames.

        Parameters
        ----------
        sensitivities
            ``(L, 3)`` the camera's sensitivities on the world's grid.
        angle
            Table angle.
        chunk
            Pixels per block.

        Returns
        -------
        ndarray
            float32 signal, equal to ``channel_signal(frame("object").radiance)`` to rounding.
        """
        env, grid = self.environment, self.grid
        h, w = self.height, self.width
        s_step = np.asarray(sensitivities, dtype=np.float64) * grid.step * np.reshape(self.lens_transmission(), (-1, 1))
        card = (BACKDROP_REFLECTANCE * self.light_spectrum() / math.pi) @ s_step
        basis_sig = env.basis @ s_step                                      # (K, 3)
        out = np.empty((h * w, 3), np.float32)
        out[:] = card
        near = self._ball_pixels(angle)
        for i in range(0, near.size, chunk):
            idx = near[i:i + chunk]
            coeff, card_share, _ = self._ball_samples(angle, idx)
            out[idx] = coeff @ basis_sig + card_share[:, None] * card[None, :]
        return out.reshape(h, w, 3)


def filter_transmission(kind: str, centre_nm: float, width_nm: float, wavelengths_nm: ArrayLike) -> NDArray[np.float64]:
    """An idealised filter's transmission (0.05-0.95) on ``wavelengths_nm`` (see :data:`FILTERS`).

    Examples
    --------
    >>> t = filter_transmission("long", 550.0, 12.0, np.array([450.0, 550.0, 650.0]))
    >>> [round(float(x), 3) for x in t]
    [0.05, 0.5, 0.95]
    >>> [round(float(x), 2) for x in filter_transmission(*FILTERS[PROBE_FILTER], np.array([440.0, 540.0, 650.0]))]
    [1.0, 0.2, 1.0]
    """
    x = np.asarray(wavelengths_nm, dtype=np.float64)
    if kind in ("long", "short"):
        rise = 1.0 / (1.0 + np.exp(-(x - centre_nm) / width_nm))
        return 0.05 + 0.9 * (rise if kind == "long" else 1.0 - rise)
    bump = np.exp(-0.5 * ((x - centre_nm) / width_nm) ** 2)
    return 0.05 + 0.9 * bump if kind == "band" else 1.0 - 0.8 * bump


def write_filter_csv(path: str | os.PathLike[str], name: str = PROBE_FILTER, step_nm: float = 5.0) -> Path:
    """Write a filter of :data:`FILTERS` as the CSV a filter's data sheet gives: ``wavelength_nm,transmission``.

    380-780 nm every ``step_nm``.
    """
    wl = np.arange(380.0, 780.0 + step_nm / 2, step_nm)
    t = filter_transmission(*FILTERS[name], wl)
    out = Path(path)
    out.write_text("wavelength_nm,transmission\n" + "".join(f"{a:g},{b:.6f}\n" for a, b in zip(wl, t)),
                   encoding="utf-8")
    return out


def write_light_csv(world: ProbeWorld, path: str | os.PathLike[str]) -> Path:
    """The chart's light (:meth:`ProbeWorld.light_spectrum`) as ``wavelength_nm,value`` rows: what a
    spectroradiometer on the table would give (``kogei probe --light CSV``)."""
    out = Path(path)
    out.write_text("wavelength_nm,value\n" + "".join(f"{a:g},{b:.9g}\n" for a, b in
                                                     zip(world.grid.wavelengths, world.light_spectrum())),
                   encoding="utf-8")
    return out


def write_filtered_shots(world: ProbeWorld, folder: str | os.PathLike[str], *, name: str = PROBE_FILTER,
                         seed: int = 1, **kwargs: Any) -> tuple[Path | None, list[Path], Path]:
    """The chart and the brackets through the filter ``name`` of :data:`FILTERS` (:func:`write_probe_shots`
    with its transmission; ``kwargs`` as there), and the filter's data sheet ``filter.csv`` in ``folder``.

    Returns the chart frame's path, the bracket paths and the data sheet's path.
    """
    t = filter_transmission(*FILTERS[name], world.grid.wavelengths)
    chart, frames = write_probe_shots(world, folder, transmission=t, seed=seed, **kwargs)
    return chart, frames, write_filter_csv(Path(folder) / "filter.csv", name)


def write_probe_shots(world: ProbeWorld, folder: str | os.PathLike[str], *,
                      times_s: tuple[float, ...] = BRACKET_TIMES_S, chart_time_s: float | None = CHART_TIME_S,
                      seed: int = 0, f_number: float | None = PROBE_F_NUMBER,
                      transmission: ArrayLike | None = None) -> tuple[Path | None, list[Path]]:
    """Photograph the chart (on the table) and the ball at each exposure time, as DNG files.

    Parameters
    ----------
    world
        The probe world.
    folder
        Where ``chart.dng`` and ``probe-<k>.dng`` are written (created if missing).
    times_s
        The brackets' exposure times (s).
    chart_time_s
        The chart frame's exposure time; None: no chart frame.
    seed
        Seed of the sensor noise (each frame has its own stream).
    f_number
        The aperture the files record (None: none recorded).
    transmission
        ``(L,)`` on the world's grid: a filter in front of the lens for every frame (the second bracket
        set of a two-channel-set probe); None: no filter.

    Returns
    -------
    tuple
        The chart frame's path (or None) and the bracket paths, in the order of ``times_s``.
    """
    from mocks.camera_sim import simulate_raw, write_raw

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    t_filter = 1.0 if transmission is None else np.asarray(transmission, dtype=np.float64)
    chart_path = None
    if chart_time_s is not None:
        f = world.frame("chart")
        raw = simulate_raw(f.radiance * t_filter, f.grid, f.light, exposure_s=chart_time_s, seed=seed * 1000 + 999)
        raw.f_number = f_number
        chart_path = write_raw(out / "chart.dng", raw)
    frame = world.frame("object")
    paths = []
    for i, t in enumerate(times_s):
        raw = simulate_raw(frame.radiance * t_filter, frame.grid, frame.light, exposure_s=float(t),
                           seed=seed * 1000 + i)
        raw.f_number = f_number
        paths.append(write_raw(out / f"probe-{i + 1}.dng", raw))
    return chart_path, paths
