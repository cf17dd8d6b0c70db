"""Simulated chart shots shared by the RAW-decoding, chart-detection and chart-sampling tests.

A chart frame of :class:`mocks.world.World` goes through the camera simulation
into a real DNG file, so every test reads it through LibRaw; the frame keeps
the ground truth (labels, outer corners, mean electrons).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocks.camera_sim import RawFrame, SensorModel, simulate_raw, write_raw
from mocks.world import Frame, World

#: A small grey plate: the object is never rendered by these tests, a world only needs some mesh.
_PLATE = (np.array([[0, 0, 0], [1, 0, 0], [0, 0, 1.0]]), np.array([[0, 1, 2]]))


@dataclass
class Shot:
    path: Path
    frame: Frame
    raw: RawFrame
    world: World

    def label_centres(self) -> np.ndarray:
        """Centroid (x, y) of each patch's labelled pixels: the ground truth of patch positions."""
        lab = self.frame.labels
        ys, xs = np.mgrid[0:lab.shape[0], 0:lab.shape[1]]
        n = int(lab.max()) + 1
        return np.array([[xs[lab == k].mean(), ys[lab == k].mean()] for k in range(n)])


#: The simulated sensor of a chart shot unless one is given (frozen, so one instance serves every call).
_DEFAULT_SENSOR = SensorModel()


def chart_world(layout: str = "classic24", width: int = 600, height: int = 400, **kwargs) -> World:
    v, t = _PLATE
    return World(v, t, np.zeros(1, np.int64), ("plate",), {"plate": "urushi-black"}, chart_layout=layout,
                 width=width, height=height, spectral_step=kwargs.pop("spectral_step", 20.0), **kwargs)


def chart_shot(tmp_path: Path, layout: str = "classic24", *, name: str = "chart.dng", seed: int = 1,
               exposure_boost: float = 1.0, sensor: SensorModel = _DEFAULT_SENSOR, radiance_fn=None,
               **world_kwargs) -> Shot:
    world = chart_world(layout, **world_kwargs)
    frame = world.frame("chart")
    radiance = frame.radiance if radiance_fn is None else radiance_fn(frame)
    raw = simulate_raw(radiance, frame.grid, frame.light, sensor=sensor, seed=seed, exposure_boost=exposure_boost)
    return Shot(write_raw(tmp_path / name, raw), frame, raw, world)
