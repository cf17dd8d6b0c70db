"""Render settings and the named speed / accuracy presets.

Every expensive knob has a named preset whose cost and error are measured
(docs/rendering.md, "Presets and what each knob costs").  The knobs of the renderer are the spectral sampling,
the anti-aliasing samples per pixel, the mirror bounce and its rays, the
angular tables and the shadow rays:

``reference``
    5 nm (61 bands) spectral evaluation of every lobe at every sample (no
    tables), 16 samples per pixel on a rotated ordered 4 x 4 grid, and
    adaptive anti-aliasing: pixels whose samples disagree by more than
    0.25 L* (or see different surfaces) are rendered again with 256 samples
    (16 x 16); one mirror bounce with rough mirrors jittered by their
    roughness (2 rays per sample).  Its noise floor on the procedural hawk
    (320 x 240, against the same preset with jittered samples and another
    seed) is about 0.02 mean CIEDE2000.
``standard``
    the same 5 nm spectral integral, but through per-(material, light)
    angular tables (exact spectral result at RGB cost, table error measured
    in ``tests/render/test_render_tables.py``: below 0.001 delta E00), 4 samples
    per pixel on the rotated grid, refined to 64 samples (8 x 8) where they
    disagree by more than 0.5 L* or see different surfaces; one bounce, one
    jittered mirror ray per sample.

    Measured on the procedural hawk (320 x 240, sun and gradient sky,
    ``bench/render_bench.py``; docs/rendering.md): about 0.07 mean
    CIEDE2000 from ``reference`` (0.22 without the refinement), with about
    5 % of the pixels refined.  The error left is anti-aliasing of sub-pixel
    highlights that none of the four base samples sees.
``draft``
    20 nm tables, one sample per pixel (pixel centres), no refinement, no
    mirror bounce (mirror lobes see the sky without occlusion), shadows
    kept.

Examples
--------
>>> PRESETS["standard"].samples_per_pixel, PRESETS["reference"].use_tables
(4, False)
>>> get_preset("draft").spectral_step
20.0
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from render.errors import RenderInputError

__all__ = ["RenderSettings", "PRESETS", "get_preset"]


def _whole(value: object, name: str, low: int, high: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, int) and not (
        isinstance(value, float) and value.is_integer()
    ):
        raise RenderInputError(f"render setting {name} must be a whole number, got {value!r}")
    value = int(value)
    if value < low or (high is not None and value > high):
        span = f">= {low}" if high is None else f"in {low}..{high}"
        raise RenderInputError(f"render setting {name} must be {span}, got {value}")
    return value


@dataclass(frozen=True)
class RenderSettings:
    """Knobs of one render.

    Attributes
    ----------
    name
        Preset name (``"custom"`` when built by hand).
    spectral_step
        Wavelength step in nm of the 400-700 nm grid (must divide 300).
    samples_per_pixel
        Anti-aliasing samples per pixel (1 = pixel centre; more: one per
        stratum of a square grid over the pixel).
    jitter
        True: each sample at a random position in its stratum (stratified
        jitter: noise instead of aliasing); False: at the stratum centre (an
        ordered grid: exact pixel averages of linear shading, deterministic).
    mirror_bounces
        0: mirror lobes reflect the sky without occlusion; 1: a mirrored ray
        is traced and sees the other objects (lit directly) or the sky.
    mirror_rays
        Mirrored rays per sample for rough mirror lobes, directions jittered
        by sampling their Beckmann distribution; 0 traces the ideal mirror
        direction only.
    use_tables
        True: angular XYZ tables per (lobe, light); False: per-sample
        spectral evaluation.
    table_size
        Number of table rows over cos(theta) in [0, 1] (linear interpolation).
    shadows
        Cast shadow rays toward the lights.
    tile_size
        Side of the square pixel tiles processed at once (memory / progress
        granularity); reduced by the renderer so that a tile holds at most
        65536 samples (16384 with per-sample spectra).
    seed
        Seed of the sample jitter (renders are reproducible).
    adaptive_samples
        Adaptive anti-aliasing: pixels whose ``samples_per_pixel`` base
        samples disagree are rendered again with this many samples (which
        replace the base samples in the pixel's value); 0 turns it off.
        Must exceed ``samples_per_pixel``, which must be at least 2.
    environment_samples
        Directions per primary hit with which an environment map lights the
        non-mirror lobes (half from the map's luminance, half from the
        BRDF, multiple importance sampling, a shadow ray each when
        ``shadows``); 0: each lobe group's albedo times the map
        prefiltered by it, without occlusion by the scene.
    adaptive_threshold
        When the base samples of a pixel disagree: they hit different
        objects or materials, some hit and some miss, or their colours
        spread by more than this many CIELAB lightness units (the largest
        range over the samples of ``116 f(X/Xw)``, ``116 f(Y/Yw)``,
        ``116 f(Z/Zw)``, with ``f`` the CIELAB cube-root function).
    """

    name: str = "custom"
    spectral_step: float = 5.0
    samples_per_pixel: int = 4
    jitter: bool = False
    mirror_bounces: int = 1
    mirror_rays: int = 1
    use_tables: bool = True
    table_size: int = 256
    shadows: bool = True
    tile_size: int = 64
    seed: int = 0
    adaptive_samples: int = 0
    adaptive_threshold: float = 2.0
    environment_samples: int = 8

    def __post_init__(self) -> None:
        try:
            step = float(self.spectral_step)
        except (TypeError, ValueError):
            raise RenderInputError(f"render setting spectral_step must be a number of nm, got {self.spectral_step!r}") from None
        count = 300.0 / step if step > 0 else math.nan
        if not (math.isfinite(step) and step > 0 and abs(count - round(count)) < 1e-9):
            raise RenderInputError(
                f"render setting spectral_step must divide 400-700 nm evenly (e.g. 5, 10, 20 nm), got {self.spectral_step!r}"
            )
        object.__setattr__(self, "spectral_step", step)
        object.__setattr__(self, "samples_per_pixel", _whole(self.samples_per_pixel, "samples_per_pixel", 1, 4096))
        object.__setattr__(self, "mirror_bounces", _whole(self.mirror_bounces, "mirror_bounces", 0, 1))
        object.__setattr__(self, "mirror_rays", _whole(self.mirror_rays, "mirror_rays", 0, 256))
        object.__setattr__(self, "table_size", _whole(self.table_size, "table_size", 2, 1 << 20))
        object.__setattr__(self, "tile_size", _whole(self.tile_size, "tile_size", 1, 1 << 14))
        object.__setattr__(self, "seed", _whole(self.seed, "seed", 0))
        object.__setattr__(self, "adaptive_samples", _whole(self.adaptive_samples, "adaptive_samples", 0, 4096))
        object.__setattr__(self, "environment_samples",
                           _whole(self.environment_samples, "environment_samples", 0, 4096))
        if self.environment_samples == 1:
            raise RenderInputError("render setting environment_samples must be 0 (prefiltered map) or at least 2 "
                                   "(half from the map, half from the BRDF), got 1")
        if self.adaptive_samples:
            if self.samples_per_pixel < 2:
                raise RenderInputError(
                    "render setting adaptive_samples needs samples_per_pixel >= 2 (base samples to compare), "
                    f"got samples_per_pixel={self.samples_per_pixel}; raise it or set adaptive_samples=0"
                )
            if self.adaptive_samples <= self.samples_per_pixel:
                raise RenderInputError(
                    f"render setting adaptive_samples ({self.adaptive_samples}) must exceed samples_per_pixel "
                    f"({self.samples_per_pixel}), or be 0 to turn adaptive anti-aliasing off"
                )
        try:
            threshold = float(self.adaptive_threshold)
        except (TypeError, ValueError):
            threshold = math.nan
        if isinstance(self.adaptive_threshold, bool) or not (threshold >= 0.0):
            raise RenderInputError(
                f"render setting adaptive_threshold must be a number >= 0 (CIELAB lightness units), "
                f"got {self.adaptive_threshold!r}"
            )
        object.__setattr__(self, "adaptive_threshold", threshold)
        for flag in ("use_tables", "shadows", "jitter"):
            if not isinstance(getattr(self, flag), bool):
                raise RenderInputError(f"render setting {flag} must be True or False, got {getattr(self, flag)!r}")

    def replace(self, **changes: object) -> RenderSettings:
        """A copy with some fields changed (validated again).

        Parameters
        ----------
        **changes
            Field names and their new values.

        Returns
        -------
        RenderSettings
            The new settings.

        Raises
        ------
        RenderInputError
            An unknown field or a bad value.

        Examples
        --------
        >>> PRESETS["standard"].replace(samples_per_pixel=9).samples_per_pixel
        9
        """
        try:
            return dataclasses.replace(self, **changes)
        except TypeError as exc:
            fields = ", ".join(f.name for f in dataclasses.fields(self))
            raise RenderInputError(f"unknown render setting in {sorted(changes)}; known: {fields}") from exc


PRESETS: dict[str, RenderSettings] = {
    "draft": RenderSettings(
        name="draft", spectral_step=20.0, samples_per_pixel=1, jitter=False, mirror_bounces=0, mirror_rays=0,
        use_tables=True, table_size=128, shadows=True, tile_size=256, environment_samples=0,
    ),
    "standard": RenderSettings(
        name="standard", spectral_step=5.0, samples_per_pixel=4, jitter=False, mirror_bounces=1, mirror_rays=1,
        use_tables=True, table_size=256, shadows=True, tile_size=128, adaptive_samples=64, adaptive_threshold=0.5,
        environment_samples=8,
    ),
    "reference": RenderSettings(
        name="reference", spectral_step=5.0, samples_per_pixel=16, jitter=False, mirror_bounces=1, mirror_rays=2,
        use_tables=False, table_size=256, shadows=True, tile_size=32, adaptive_samples=256, adaptive_threshold=0.25,
        environment_samples=16,
    ),
}


def get_preset(name: str) -> RenderSettings:
    """The preset called ``name`` (``draft``, ``standard`` or ``reference``).

    Parameters
    ----------
    name
        The preset's name.

    Returns
    -------
    RenderSettings
        The preset (shared; use :meth:`RenderSettings.replace` to change it).

    Raises
    ------
    RenderInputError
        Naming the presets when ``name`` is none of them.
    """
    try:
        return PRESETS[name]
    except (KeyError, TypeError):
        raise RenderInputError(f"unknown render preset {name!r}; choose one of {', '.join(PRESETS)}") from None
