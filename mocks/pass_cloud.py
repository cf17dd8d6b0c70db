"""One pass of the simulated station as a point cloud, without the serial devices.

:func:`simulated_pass` measures a world's object in placement ``n`` exactly as
:class:`mocks.station.SimulatedStation` does (the station's sensor pose, fan,
range window, incidence limit, occlusion and 0.05 mm Gaussian range noise,
seeded per profile by :func:`mocks.noise_seed.profile_seed`, and the same
placements :func:`mocks.station_geometry.placement_pose`), over one revolution
of ``steps`` profiles, and returns the valid points in the pass's frame (the
table frame at angle 0), with normals fitted to the points and turned toward
the sensor by :func:`processing.geometry.scan_points.profiles_to_points`
with the true sensor pose.  The table itself is left out (processing crops it
from a session).  Registration tests and benchmarks use it to get many passes of a
known placement quickly; the truth is :attr:`SimulatedPass.pose`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocks.noise_seed import profile_seed
from mocks.station_geometry import placement_pose, rest_on_table, station_sensor_to_room

__all__ = ["SimulatedPass", "pass_colour_views", "pass_colours", "pass_posed_frames", "simulated_pass"]


@dataclass(frozen=True)
class SimulatedPass:
    """A pass: points and normals (mm, the pass's frame) and the truth.

    Attributes
    ----------
    points, normals
        ``(N, 3)`` valid points and unit normals toward the sensor.
    pose
        4 x 4 object -> pass frame (the placement's pose on the table at angle 0).
    placement
        The placement number.
    """

    points: NDArray[np.float64]
    normals: NDArray[np.float64]
    pose: NDArray[np.float64]
    placement: int


def simulated_pass(world: Any, seed: int, placement: int, *, steps: int = 72, n_points: int = 640,
                   noise_um: float = 50.0) -> SimulatedPass:
    """The station's scan of ``world``'s object in placement ``placement`` over one revolution.

    Parameters
    ----------
    world
        A :class:`mocks.world.World` (its vertices, triangles and base pose).
    seed
        Station seed (placements and noise derive from it, as the station's).
    placement
        Placement number (>= 1).
    steps
        Profiles per revolution (the printed scan takes 72).
    n_points
        Points per profile (the station's 640).
    noise_um
        Range noise (micrometres, the station's 50).

    Returns
    -------
    SimulatedPass
        The points, normals and the true pose.

    Examples
    --------
    >>> from mocks.world import World
    >>> p = simulated_pass(World.calibration_sphere(20.0, 0.0), 0, 1, steps=36, n_points=160)
    >>> centre = p.pose[:3, 3]
    >>> d = np.linalg.norm(p.points - centre, axis=1)
    >>> cos = np.sum(p.normals * (p.points - centre), 1) / d
    >>> bool(abs(np.median(d) - 20.0) < 0.1), bool(np.median(cos) > 0.99)   # points on the sphere, normals outward
    (True, True)
    """
    from mocks.profiler_firmware import RaycastSource
    from processing.geometry.scan_points import profiles_to_points

    pose = placement_pose(world.vertices, rest_on_table(world.vertices, world.pose), seed, placement)
    obj = world.vertices @ pose[:3, :3].T + pose[:3, 3]
    sensor = station_sensor_to_room()
    src = RaycastSource(obj, world.triangles, lambda: 0.0, sensor_to_room=sensor, n_points=n_points, fov_deg=40.0,
                        range_mm=(150.0, 360.0), max_incidence_deg=70.0, noise_um=noise_um,
                        seed=lambda a: profile_seed(seed, placement, a))
    angles = 360.0 * np.arange(steps) / steps
    prof = [src.profile_at(float(a)) for a in angles]
    x_mm = 1e-3 * np.stack([pr[0] for pr in prof])
    z_mm = 1e-3 * np.stack([pr[1] for pr in prof])
    cloud = profiles_to_points(x_mm, z_mm, angles, sensor, range_mm=(150.0, 360.0))
    p, n = cloud.points, cloud.normals
    return SimulatedPass(p, n, pose, int(placement))


def pass_colours(world: Any, sim: SimulatedPass, table_angles_deg: Any = tuple(range(0, 360, 30))) -> NDArray[np.float64]:
    """Colours ``(N, 3)`` of a pass's points from the station camera's frames: :func:`pass_colour_views`'s first part.

    Examples
    --------
    >>> from mocks.world import World
    >>> w = World.calibration_sphere(20.0, 0.0)
    >>> p = simulated_pass(w, 0, 1, steps=36, n_points=160)
    >>> pass_colours(w, p, (0,)).shape == p.points.shape
    True
    """
    return pass_colour_views(world, sim, table_angles_deg)[0]


def pass_colour_views(world: Any, sim: SimulatedPass, table_angles_deg: Any = tuple(range(0, 360, 30)),
                      frame_size: tuple[int, int] | None = None
                      ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Colours ``(N, 3)`` of a pass's points from the station camera's frames of that placement.

    The frames are the simulated camera's (``world.frame("object", angle)``, at the station's
    240 x 160 pixels, or ``frame_size`` (width, height): the same camera sampled finer) at each table angle, with the object in the pass's placement; the camera's
    true intrinsics and pose stand in for a camera calibration (posed photos).  A point takes the
    colour of the pixel it projects to in the frame that sees it most frontally, where the camera's
    ray reaches it unoccluded (the simulation's depth), the point is lit and the camera is more than
    30 deg from the lamp's mirror direction (a highlight shows the lamp's colour, not the surface's); three band sums of the spectral radiance
    (600-700, 500-590, 400-490 nm: red, green, blue) are its linear colour.  NaN where no frame sees a point.

    Returns
    -------
    colours, lamp_dirs, camera_mm
        ``(N, 3)`` each: the linear colour, the unit direction toward the (distant) lamp and the
        camera's centre (mm), both in the pass's frame at the table angle of the frame that gave the
        colour (the lamp and camera are fixed in the room; the table turns under them).  NaN where no
        frame sees a point.

    Examples
    --------
    >>> from mocks.world import World
    >>> w = World.calibration_sphere(20.0, 0.0)
    >>> p = simulated_pass(w, 0, 1, steps=36, n_points=160)
    >>> c, lamp, cam = pass_colour_views(w, p, (0, 180))
    >>> bool(np.isfinite(c).all(axis=1).mean() > 0.5), bool(np.nanmean(c[:, 0]) > np.nanmean(c[:, 2]))  # red lacquer
    (True, True)
    """
    import dataclasses

    import open3d as o3d

    from mocks.world import rotation_z, station_world_settings

    size = {} if frame_size is None else {"width": int(frame_size[0]), "height": int(frame_size[1])}
    w = dataclasses.replace(world, pose=sim.pose, **{**station_world_settings(), **size})
    k_mat, to_cam = w.camera_intrinsics(), w.room_to_camera()
    cam_room = -to_cam[:3, :3].T @ to_cam[:3, 3]
    wl = w.grid.wavelengths
    bands = [(wl >= lo) & (wl <= hi) for lo, hi in ((600, 700), (500, 590), (400, 490))]
    best_cos = np.full(len(sim.points), 0.2)
    light = np.asarray(w.light_direction, dtype=np.float64)
    light = light / np.linalg.norm(light)
    glint_cos = math.cos(math.radians(30.0))
    colours = np.full((len(sim.points), 3), np.nan)
    lamp = np.full((len(sim.points), 3), np.nan)
    camera = np.full((len(sim.points), 3), np.nan)
    obj = w.vertices @ sim.pose[:3, :3].T + sim.pose[:3, 3]
    for angle in table_angles_deg:
        rz = rotation_z(float(angle))[:3, :3]
        p = sim.points @ rz.T
        n = sim.normals @ rz.T
        ray = cam_room - p
        dist = np.linalg.norm(ray, axis=1)
        cos = np.sum(n * ray, axis=1) / dist
        # away from the lamp's mirror direction (a highlight shows the lamp's colour) and lit
        mirror = 2.0 * cos[:, None] * n - ray / dist[:, None]
        cos = np.where((mirror @ light < glint_cos) & (n @ light > 0.1), cos, -1.0)
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor((obj @ rz.T).astype(np.float32)),
                            o3d.core.Tensor(w.triangles.astype(np.uint32)))
        d = -ray / dist[:, None]
        hit = scene.cast_rays(o3d.core.Tensor(np.hstack([np.broadcast_to(cam_room, p.shape), d]).astype(np.float32)))
        seen = hit["t_hit"].numpy() >= dist - 0.3
        x = p @ to_cam[:3, :3].T + to_cam[:3, 3]
        uv = x @ k_mat.T
        u = np.rint(uv[:, 0] / uv[:, 2]).astype(np.int64)
        v = np.rint(uv[:, 1] / uv[:, 2]).astype(np.int64)
        inside = (x[:, 2] > 0) & (u >= 0) & (u < w.width) & (v >= 0) & (v < w.height)
        better = seen & inside & (cos > best_cos)
        if not better.any():
            continue
        radiance = w.frame("object", float(angle)).radiance
        rgb = np.stack([radiance[..., b].sum(axis=-1) for b in bands], axis=-1)
        colours[better] = rgb[v[better], u[better]]
        lamp[better] = rz.T @ light            # the room's lamp and camera in the pass's frame
        camera[better] = rz.T @ cam_room
        best_cos[better] = cos[better]
    return colours, lamp, camera


def pass_posed_frames(world: Any, sim: SimulatedPass, table_angles_deg: Any = tuple(range(0, 360, 30)),
                      frame_size: tuple[int, int] | None = None) -> tuple[list[Any], list[NDArray[np.float32]]]:
    """The station camera's frames of a pass, posed in the pass's frame, and their linear images.

    What a session with a camera and lamp calibration gives the registration
    before any pass is registered: per table angle a
    :class:`processing.appearance.frame_poses.FramePose` (the camera's true
    intrinsics and pose, the lamp, the pass pose the identity) and the frame
    as ``(H, W, 3)`` band sums of its spectral radiance (600-700, 500-590,
    400-490 nm), as :func:`pass_colour_views` reads them (at the station's
    240 x 160 pixels, or ``frame_size`` (width, height): the same camera
    sampled finer).  For
    :func:`processing.geometry.registration.photo_consistency.colour_points`.

    Examples
    --------
    >>> from mocks.world import World
    >>> w = World.calibration_sphere(20.0, 0.0)
    >>> p = simulated_pass(w, 0, 1, steps=36, n_points=160)
    >>> frames, images = pass_posed_frames(w, p, (0, 90))
    >>> [f.table_angle_deg for f in frames], images[0].shape
    ([0.0, 90.0], (160, 240, 3))
    """
    import dataclasses

    from mocks.world import station_world_settings
    from processing.appearance.frame_poses import FramePose

    size = {} if frame_size is None else {"width": int(frame_size[0]), "height": int(frame_size[1])}
    w = dataclasses.replace(world, pose=sim.pose, **{**station_world_settings(), **size})
    wl = w.grid.wavelengths
    bands = [(wl >= lo) & (wl <= hi) for lo, hi in ((600, 700), (500, 590), (400, 490))]
    lamp = {"name": "lamp", **{k: v for k, v in w.lamp_truth().items() if k in ("position_mm", "direction")}}
    frames, images = [], []
    for angle in table_angles_deg:
        frames.append(FramePose.from_chain(f"angle-{float(angle):g}", sim.placement, w.room_to_camera(), float(angle),
                                           np.eye(4), w.camera_intrinsics(), np.zeros(5), (w.width, w.height), [lamp]))
        radiance = w.frame("object", float(angle)).radiance
        images.append(np.stack([radiance[..., b].sum(axis=-1) for b in bands], axis=-1).astype(np.float32))
    return frames, images
