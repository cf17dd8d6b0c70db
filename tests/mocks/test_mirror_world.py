"""The mirror-sphere world: highlights where the mirror law puts them, as bright as promised."""

from __future__ import annotations

import numpy as np
import pytest

from mocks.camera_sim import SensorModel, simulate_raw
from mocks.mirror_world import MirrorWorld
from mocks.world import World, WorldError

LAMPS = [{"position_mm": [-120.0, -200.0, 250.0], "radius_mm": 15.0}, {"direction": [0.5, -0.6, 0.6]}]


@pytest.fixture(scope="module")
def world():
    return MirrorWorld.mirror_sphere(20.0, (35.0, 25.0), lamps=LAMPS, spectral_step=50.0)


def _mirror_point(world, centre, lamp):
    """Where the sphere's normal bisects the reversed view ray and the direction to the lamp (fixed point)."""
    eye = np.linalg.inv(world.room_to_camera())[:3, 3]
    r = world.sphere_radius_mm
    n = (eye - centre) / np.linalg.norm(eye - centre)
    for _ in range(200):
        x = centre + r * n
        to_lamp = (np.asarray(lamp["position_mm"]) - x) if "position_mm" in lamp else np.asarray(lamp["direction"])
        bis = (eye - x) / np.linalg.norm(eye - x) + to_lamp / np.linalg.norm(to_lamp)
        n = bis / np.linalg.norm(bis)
    cam = world.room_to_camera() @ np.append(centre + r * n, 1.0)
    uv = world.camera_intrinsics() @ cam[:3]
    return uv[:2] / uv[2]


def _centroid(frame, uv, half=14):
    v = frame.radiance[..., 2]
    u0, v0 = np.round(uv).astype(int)
    win = v[v0 - half:v0 + half + 1, u0 - half:u0 + half + 1]
    w = np.clip(win - np.median(win), 0.0, None)
    rows, cols = np.mgrid[v0 - half:v0 + half + 1, u0 - half:u0 + half + 1]
    assert w.sum() > 0
    return np.array([(w * cols).sum() / w.sum(), (w * rows).sum() / w.sum()])


@pytest.mark.parametrize("angle", [0.0, 35.0, -40.0])
def test_highlight_centroids_are_the_mirror_points(world, angle):
    """Each lamp's highlight centroid within 0.5 px of the analytic mirror point at 960 x 640."""
    frame = world.frame("object", angle)
    centre = world.sphere_centre_mm(angle)
    assert np.allclose(centre, [35.0 * np.cos(np.radians(angle)), 35.0 * np.sin(np.radians(angle)), 20.0])
    for lamp in LAMPS:
        uv = _mirror_point(world, centre, lamp)
        assert frame.labels[int(round(uv[1])), int(round(uv[0]))] == 0
        err = np.linalg.norm(_centroid(frame, uv) - uv)
        assert err < 0.5, (angle, lamp, err)


def test_highlight_reaches_half_the_well(world):
    frame = world.frame("object", 20.0)
    raw = simulate_raw(frame.radiance, frame.grid, frame.light, exposure_s=0.01, seed=3)
    peak = raw.mean_electrons.max() / SensorModel().well_e
    assert 0.4 < peak < 0.6


def test_placements_move_the_ball_and_round_trip(world):
    assert world.fixed_placement_pose(2)[0, 3] == 25.0 and world.fixed_placement_pose(3)[0, 3] == 35.0
    again = World.from_dict(world.to_dict())
    assert isinstance(again, MirrorWorld) and again.lamps == world.lamps and again.offsets_mm == (35.0, 25.0)
    truths = again.lamp_truths()
    assert [t["kind"] for t in truths] == ["point", "distant"]
    assert np.allclose(truths[1]["direction"], np.array(LAMPS[1]["direction"]) / np.linalg.norm(LAMPS[1]["direction"]))


def test_default_lamp_is_the_worlds_own():
    w = MirrorWorld.mirror_sphere(width=96, height=64, light_position_mm=(0.0, -150.0, 200.0))
    assert w.lamp_truths() == [{"kind": "point", "position_mm": [0.0, -150.0, 200.0], "radius_mm": 15.0}]
    assert MirrorWorld.mirror_sphere(width=96, height=64).lamp_truths()[0]["kind"] == "distant"


def test_bad_lamps():
    with pytest.raises(WorldError, match=r"lamps\[0\]"):
        MirrorWorld.mirror_sphere(lamps=[{"position_mm": [0, 0, 1], "direction": [0, 0, 1]}])
    with pytest.raises(WorldError, match=r"lamps\[1\].radius_mm"):
        MirrorWorld.mirror_sphere(lamps=[{"direction": [0, 0, 1]}, {"position_mm": [0, 0, 300], "radius_mm": -1}])
