"""Observations of a simulated object with their truth: the posed-photo chain without files.

:func:`simulated_observations` renders the object of a :class:`mocks.world.World`
(its mesh, per-region materials, camera and lamp) at a list of table angles
with the simulated camera's spectral chain (:func:`mocks.world.World.frame`,
then the camera's sensitivities, optional shot and read noise, and the
division by a white diffuser's signal that the chart calibration performs),
poses every frame with the world's *true* camera and lamp, and samples the
images at the vertices with :func:`processing.appearance.observations.observe`.
The mesh frame M is the table frame (one pass, identity pose), so the truth
per vertex and per triangle (region index, material spec) comes with it.

Tests of the segmentation, the material fit and the validation use it: what
they measure is the method, not the calibration or the registration.

Examples
--------
>>> sim = simulated_observations(World.hawk(2_000, width=96, height=64, light_position_mm=(-150, -250, 300)),
...                              [0, 120, 240])
>>> len(sim.frames), sim.observations.n_vertices == len(sim.vertices)
(3, True)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mocks.camera_sim import SENSITIVITIES, SensorModel, channel_signal
from mocks.world import World

__all__ = ["SimulatedObservations", "simulated_observations", "world_lamps", "CLIP_FRACTION"]

#: Share of the well at which an observation counts as clipped (as the session's frames: 0.98 of the white level).
CLIP_FRACTION = 0.98
_SENSOR = SensorModel()


@dataclass(frozen=True)
class SimulatedObservations:
    """Observations of a simulated object and the truth behind them.

    Attributes
    ----------
    observations
        :class:`processing.appearance.observations.Observations` of the mesh.
    vertices, triangles, normals
        The mesh in M (the table frame), ``(V, 3)``, ``(T, 3)``, ``(V, 3)`` (unit, outward).
    frames
        The :class:`processing.appearance.frame_poses.FramePose` of every frame.
    images
        ``(K, H, W, 3)`` float32 chart-normalised images (signal 1 = a white diffuser lit like the chart).
    labels
        ``(K, H, W)`` int16 region index per pixel (-1: backdrop).
    face_region
        ``(T,)`` true region index per triangle.
    vertex_region
        ``(V,)`` true region index per vertex (the region of most of its triangles).
    region_names
        Names of the regions.
    materials
        Region name -> true material spec.
    light
        The lamp's spectrum name (``World.light``).
    sensitivities
        The simulated camera's sensitivities (a colour-science camera name).
    """

    observations: object
    vertices: NDArray[np.float64]
    triangles: NDArray[np.int64]
    normals: NDArray[np.float64]
    frames: tuple
    images: NDArray[np.float32]
    labels: NDArray[np.int16]
    face_region: NDArray[np.int64]
    vertex_region: NDArray[np.int64]
    region_names: tuple[str, ...]
    materials: dict[str, str]
    light: str
    sensitivities: str


def world_lamps(world: World) -> list[dict]:
    """The world's lamp in the room frame, as the lamp calibration reports it (one entry)."""
    truth = world.lamp_truth()
    if truth["kind"] == "point":
        return [{"name": "lamp1", "position_mm": truth["position_mm"]}]
    return [{"name": "lamp1", "direction": truth["direction"]}]


def _vertex_region(triangles: NDArray[np.int64], face_region: NDArray[np.int64], n_vertices: int,
                   n_regions: int) -> NDArray[np.int64]:
    votes = np.zeros((n_vertices, n_regions))
    np.add.at(votes, (triangles.ravel(), np.repeat(face_region, 3)), 1.0)
    return np.argmax(votes, axis=1).astype(np.int64)


def simulated_observations(world: World, angles_deg: Sequence[float], *, noise: bool = True, seed: int = 0,
                           sensor: SensorModel = _SENSOR, exposure_s: float = 0.01,
                           sensitivities: str = SENSITIVITIES, max_view_deg: float = 75.0,
                           edge_margin_px: float = 1.0) -> SimulatedObservations:
    """Render, pose and observe the world's object at ``angles_deg`` (one pass, M = table frame).

    Parameters
    ----------
    world
        The simulated world (its size, camera, lamp and object).
    angles_deg
        Table angles of the frames (degrees).
    noise
        Add the sensor's shot and read noise (Poisson and Gaussian electrons).
    seed
        Seed of the noise.
    sensor, exposure_s
        The sensor model and exposure that set the noise level (a white
        diffuser facing the lamp gives ``quantum_scale * exposure_s`` electrons per unit signal).
    sensitivities
        The camera (a colour-science camera name) whose RGB the observations hold.
    max_view_deg, edge_margin_px
        As :func:`processing.appearance.observations.observe`.

    Returns
    -------
    SimulatedObservations
    """
    from processing.appearance.frame_poses import FramePose
    from processing.appearance.observations import observe

    m = world.pose
    verts = world.vertices @ m[:3, :3].T + m[:3, 3]
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(verts),
                                     o3d.utility.Vector3iVector(world.triangles.astype(np.int32)))
    mesh.compute_vertex_normals()
    normals = np.asarray(mesh.vertex_normals, dtype=np.float64)
    grid, e = world.grid, world.light_spectrum()
    white = channel_signal(e, grid, sensitivities) / np.pi     # a white diffuser facing the lamp: radiance E / pi
    rng = np.random.default_rng(seed)
    k, r2c, lamps = world.camera_intrinsics(), world.room_to_camera(), world_lamps(world)
    frames, images, labels = [], [], []
    electrons = sensor.quantum_scale * exposure_s
    for i, angle in enumerate(angles_deg):
        f = world.frame("object", float(angle))
        rgb = channel_signal(f.radiance, grid, sensitivities)
        mu = np.clip(rgb * electrons, 0.0, None)
        if noise:
            mu = rng.poisson(mu) + rng.normal(0.0, sensor.read_noise_e, mu.shape)
        images.append((np.clip(mu, None, sensor.well_e) / electrons / white).astype(np.float32))
        labels.append(f.labels)
        frames.append(FramePose.from_chain(f"p01/frame/{i:02d}", 1, r2c, float(angle), np.eye(4), k, np.zeros(5),
                                           (world.width, world.height), lamps))
    w = float(np.mean(white))
    a, b = (sensor.read_noise_e / (electrons * w)) ** 2, 1.0 / (electrons * w)
    clip = CLIP_FRACTION * sensor.well_e / electrons / float(np.max(white))
    obs = observe(frames, mesh, images, noise=np.array([a, b]), clip_level=clip, max_view_deg=max_view_deg,
                  edge_margin_px=edge_margin_px)
    face_region = world.region.astype(np.int64)
    return SimulatedObservations(obs, verts, world.triangles.astype(np.int64), normals, tuple(frames),
                                 np.stack(images), np.stack(labels), face_region,
                                 _vertex_region(world.triangles, face_region, len(verts), len(world.region_names)),
                                 tuple(world.region_names), dict(world.materials), world.light, sensitivities)
