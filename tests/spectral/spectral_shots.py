"""Simulated object and chart DNGs for the colour pipeline's command-line tests.

The chart frame is :class:`mocks.world.World`'s laid-out ColorChecker Classic
(``chart_layout="classic24"``, Ohta's spectra) through the simulated Nikon
D5100 into a DNG.  The object frame is a board of flat tiles, each a known
material seen at the geometry identification models (view along the normal,
light 30 deg from it): the 24 ColorChecker reflectances as matte tiles
(``L = R E / pi``) and metal / lacquer tiles with the project's BRDF
(``L = f_r E cos_i``), each scaled to a peak of half a white diffuser's
radiance so nothing clips (a metal's brightness is free in identification).
Tiles are aligned to 2 x 2 CFA cells, so the binned image's labels are exact.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocks.camera_sim import simulate_raw, write_raw
from mocks.world import World, chart_reflectances
from processing.materials.lobes import material_brdf
from processing.materials.presets import get_material

#: A small grey plate: only the chart frame of the world is rendered here.
_PLATE = (np.array([[0, 0, 0], [1, 0, 0], [0, 0, 1.0]]), np.array([[0, 1, 2]]))
#: Materials of the object tiles after the 24 chart patches.
MATERIALS = ("gold", "copper", "nami-shibuichi", "shakudo", "urushi-black", "urushi-red")
TILE, GAP, COLS = 12, 2, 6        # binned pixels


def world(light: str = "D65", width: int = 600, height: int = 400, **kwargs) -> World:
    v, t = _PLATE
    return World(v, t, np.zeros(1, np.int64), ("plate",), {"plate": "urushi-black"}, chart_layout="classic24",
                 width=width, height=height, light=light, spectral_step=10.0, **kwargs)


def chart_dng(path: Path, light: str = "D65", *, seed: int = 1, exposure_boost: float = 1.0, **kwargs) -> Path:
    """Write the chart frame of :func:`world` as a DNG."""
    w = world(light, **kwargs)
    f = w.frame("chart")
    return write_raw(path, simulate_raw(f.radiance, f.grid, f.light, seed=seed, exposure_boost=exposure_boost))


@dataclass
class Board:
    """The object frame's ground truth at the binned resolution."""

    labels: np.ndarray            # (h, w) int: tile index + 1, 0 in the gaps
    names: tuple[str, ...]        # per tile: chart patch name or material
    reflectance: np.ndarray       # (24, L) true reflectance of the chart tiles
    grid: object


def board_dng(path: Path, light: str = "D65", *, seed: int = 2) -> tuple[Path, Board]:
    """Write the tile board under ``light`` as a DNG; return it with the truth."""
    w = world(light)
    grid, e = w.grid, w.light_spectrum()
    chart = chart_reflectances(grid)
    cos_i = math.cos(math.radians(30.0))
    cos_h = math.cos(math.radians(15.0))
    signals = [r * e / math.pi for r in chart]
    for name in MATERIALS:
        s = material_brdf(get_material(name), cos_i, 1.0, cos_h, cos_h, grid.wavelengths) * e * cos_i
        signals.append(s * (0.5 / float(np.max(s / (e / math.pi)))))
    n = len(signals)
    rows = -(-n // COLS)
    hb, wb = rows * (TILE + GAP) + GAP, COLS * (TILE + GAP) + GAP
    hb += hb % 2
    wb += wb % 2
    labels = np.zeros((hb, wb), np.int64)
    back = 0.05 * e / math.pi
    rad = np.broadcast_to(back, (hb, wb, grid.size)).copy()
    for k, s in enumerate(signals):
        r, c = divmod(k, COLS)
        y0, x0 = GAP + r * (TILE + GAP), GAP + c * (TILE + GAP)
        labels[y0:y0 + TILE, x0:x0 + TILE] = k + 1
        rad[y0:y0 + TILE, x0:x0 + TILE] = s
    sensor = np.repeat(np.repeat(rad, 2, axis=0), 2, axis=1)
    raw = simulate_raw(sensor, grid, e, seed=seed)
    names = tuple(get_names()) + MATERIALS
    return write_raw(path, raw), Board(labels, names, chart, grid)


def get_names() -> list[str]:
    from processing.camera.chart_layout import chart_layout

    return list(chart_layout("classic24").names)


def write_labels(path: Path, labels: np.ndarray) -> Path:
    import cv2

    cv2.imwrite(str(path), labels.astype(np.uint16))
    return path
