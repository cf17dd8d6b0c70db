"""Render settings and the named speed / accuracy presets.

DESIGN.md section 5: every expensive knob has a named preset whose cost and
error are measured.  The knobs of the renderer are the spectral sampling,
the anti-aliasing samples per pixel, the mirror bounce and its rays, the
angular tables and the shadow rays:

``reference``
    5 nm (61 bands) spectral evaluation of every lobe at every sample (no
    tables), 16 samples per pixel on a rotated ordered 4 x 4 grid, one mirror
    bounce with rough mirrors jittered by their roughness (2 rays per
    sample).
``standard``
    the same 5 nm spectral integral, but through per-(material, light)
    angular tables (exact spectral result at RGB cost, table error measured
    in ``tests/test_render_tables.py``), 4 samples per pixel on the rotated
    grid, one bounce, one jittered mirror ray per sample.

    Measured mean CIEDE2000 from ``reference`` (64 x 48 images, gradient
    sky, one light; ``tests/test_render_renderer.py``): 0.03 for a metal
    surface filling the frame, 0.06 for a gold sphere against the sky (within
    the 0.1 target).  On scenes with several objects reflecting each other,
    or with sub-pixel relief (the feathers of the procedural hawk at
    320 x 240: 0.22), the anti-aliasing of sharp reflected edges and
    sub-pixel highlights dominates, the same order as the difference between
    the reference and a jittered 16-sample reference (0.14-0.19); 9 samples
    give 0.13 on the hawk, 16 give 0.03.  The tables themselves add less than
    0.001.  The ordered grid averages linearly varying shading exactly,
    where jittered samples add noise (0.12 instead of 0.06 for the sphere).
``draft``
    20 nm tables, one sample per pixel (pixel centres), no mirror bounce
    (mirror lobes see the sky without occlusion), shadows kept.

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
        for flag in ("use_tables", "shadows", "jitter"):
            if not isinstance(getattr(self, flag), bool):
                raise RenderInputError(f"render setting {flag} must be True or False, got {getattr(self, flag)!r}")

    def replace(self, **changes: object) -> "RenderSettings":
        """A copy with some fields changed (validated again).

        Examples
        --------
        >>> PRESETS["standard"].replace(samples_per_pixel=1).samples_per_pixel
        1
        """
        try:
            return dataclasses.replace(self, **changes)
        except TypeError as exc:
            fields = ", ".join(f.name for f in dataclasses.fields(self))
            raise RenderInputError(f"unknown render setting in {sorted(changes)}; known: {fields}") from exc


PRESETS: dict[str, RenderSettings] = {
    "draft": RenderSettings(
        name="draft", spectral_step=20.0, samples_per_pixel=1, jitter=False, mirror_bounces=0, mirror_rays=0,
        use_tables=True, table_size=128, shadows=True, tile_size=256,
    ),
    "standard": RenderSettings(
        name="standard", spectral_step=5.0, samples_per_pixel=4, jitter=False, mirror_bounces=1, mirror_rays=1,
        use_tables=True, table_size=256, shadows=True, tile_size=128,
    ),
    "reference": RenderSettings(
        name="reference", spectral_step=5.0, samples_per_pixel=16, jitter=False, mirror_bounces=1, mirror_rays=2,
        use_tables=False, table_size=256, shadows=True, tile_size=32,
    ),
}


def get_preset(name: str) -> RenderSettings:
    """The preset called ``name`` (``draft``, ``standard`` or ``reference``)."""
    try:
        return PRESETS[name]
    except (KeyError, TypeError):
        raise RenderInputError(f"unknown render preset {name!r}; choose one of {', '.join(PRESETS)}") from None
