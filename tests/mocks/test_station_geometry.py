"""Geometry of the simulated station without devices: the sensor-pose convention of the ray-cast
profile source, the table disc, placement poses, noise seeds and the fault syntax."""

from __future__ import annotations

import math

import numpy as np
import open3d as o3d
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mocks.faults import FAULT_NAMES, FaultSpecError, HotFolderFaults, format_faults, parse_faults
from mocks.noise_seed import angle_key, frame_seed, profile_seed
from mocks.profiler_firmware import (
    RaycastSource,
    check_sensor_pose,
    default_sensor_to_room,
)
from mocks.station import SimulatedStation
from mocks.station_geometry import placement_pose, rest_on_table, station_sensor_to_room, table_disc
from mocks.station_requests import StationError
from mocks.world import World, rotation_z


def box_mesh(lo, hi):
    m = o3d.geometry.TriangleMesh.create_box(*(np.subtract(hi, lo)))
    return np.asarray(m.vertices) + np.asarray(lo, float), np.asarray(m.triangles)


def box_world(lo=(-20.0, -15.0, 0.0), hi=(20.0, 15.0, 50.0), **kw):
    v, t = box_mesh(lo, hi)
    return World(v, t, np.zeros(len(t), np.int64), ("object",), {"object": "gold"}, width=48, height=32,
                 spectral_step=20.0, **kw)


# ------------------------------------------------------------------ sensor pose convention
def test_default_pose_is_the_historical_geometry():
    m = default_sensor_to_room(200.0, 10.0)
    np.testing.assert_array_equal(m[:3, 0], [0, 0, 1])
    np.testing.assert_array_equal(m[:3, 1], [0, 1, 0])
    np.testing.assert_array_equal(m[:3, 2], [-1, 0, 0])
    np.testing.assert_array_equal(m[:3, 3], [200, 0, 10])
    v, t = box_mesh((-60.0, -100.0, -100.0), (-50.0, 100.0, 100.0))
    a = RaycastSource(v, t, lambda: 0.0, n_points=41, standoff_mm=200.0, height_mm=10.0)()
    b = RaycastSource(v, t, lambda: 0.0, n_points=41, sensor_to_room=m)()
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("tilt", [0.0, 20.0, 35.0, 60.0])
def test_profile_points_map_to_the_room_by_the_pose(tilt):
    """A profile of the bare table: every point origin + x X_s + z Z_s lies on z = 0, at the
    closed-form ray-plane intersection."""
    m = station_sensor_to_room(260.0, 300.0, tilt)
    v, t = table_disc(2000.0)
    src = RaycastSource(v, t, lambda: 0.0, sensor_to_room=m, n_points=81, fov_deg=40.0,
                        range_mm=(1.0, 5000.0), max_incidence_deg=89.0)
    x, z, ok = src()
    th = np.radians(np.linspace(-20.0, 20.0, 81))
    d = np.sin(th)[:, None] * m[:3, 0] + np.cos(th)[:, None] * m[:3, 2]
    with np.errstate(divide="ignore"):
        t_ref = np.where(d[:, 2] < 0, -m[2, 3] / d[:, 2], np.inf)
    hit = (d[:, 2] < 0) & (np.abs(m[0, 3] + t_ref * d[:, 0]) < 1990.0)
    assert not ok[d[:, 2] >= 0].any()  # rays going up see nothing
    clear = hit & (-d[:, 2] > math.cos(math.radians(88.0)))
    assert clear.sum() > 20 and ok[clear].all()
    p = m[:3, 3] + (x[:, None] / 1000) * m[:3, 0] + (z[:, None] / 1000) * m[:3, 2]
    np.testing.assert_allclose(p[ok, 2], 0.0, atol=0.01)
    np.testing.assert_allclose(z[clear] / 1000, t_ref[clear] * np.cos(th[clear]), atol=0.01)
    np.testing.assert_allclose(x[clear] / 1000, t_ref[clear] * np.sin(th[clear]), atol=0.01)


def test_pose_rotates_with_the_table():
    """A wall facing +x at x = 30 seen by a sensor on the -y side (pose rotated by 90 deg about z)
    after the table turned the wall by -90 deg: the same ranges as the default pose at angle 0."""
    v, t = box_mesh((20.0, -80.0, -80.0), (30.0, 80.0, 80.0))
    m0 = default_sensor_to_room(200.0, 0.0)
    ref = RaycastSource(v, t, lambda: 0.0, n_points=21, fov_deg=20.0, sensor_to_room=m0)()
    m1 = rotation_z(-90.0) @ m0
    got = RaycastSource(v, t, lambda: -90.0, n_points=21, fov_deg=20.0, sensor_to_room=m1)()
    assert ref[2].all() and got[2].all()
    np.testing.assert_allclose(got[1], ref[1], atol=1.0)  # micrometres (float32 ray casting)
    np.testing.assert_allclose(got[1] / 1000, 200.0 - 30.0, atol=0.01)


@pytest.mark.parametrize("bad,msg", [
    (np.eye(3), "4 x 4"),
    (np.diag([1.0, 1.0, -1.0, 1.0]), "rotation"),
    (np.diag([2.0, 1.0, 1.0, 1.0]), "rotation"),
    (np.full((4, 4), np.nan), "finite"),
    (np.vstack([np.eye(4)[:3], [0, 0, 1, 1]]), "last row"),
])
def test_bad_sensor_pose(bad, msg):
    with pytest.raises(ValueError, match=msg):
        check_sensor_pose(bad)
    v, t = box_mesh((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    with pytest.raises(ValueError, match="sensor_to_room"):
        RaycastSource(v, t, lambda: 0.0, sensor_to_room=bad)


def test_pose_and_standoff_together_is_an_error():
    v, t = box_mesh((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    with pytest.raises(ValueError, match="either sensor_to_room or standoff_mm"):
        RaycastSource(v, t, lambda: 0.0, sensor_to_room=np.eye(4), standoff_mm=100.0)


def test_seed_callable_gives_noise_per_angle():
    v, t = box_mesh((-60.0, -100.0, -100.0), (-50.0, 100.0, 100.0))
    src = RaycastSource(v, t, lambda: 0.0, n_points=500, fov_deg=10.0, noise_um=50.0,
                        seed=lambda a: round(a * 1000))
    a0, a0b, a1 = src.profile_at(0.0)[1], src.profile_at(0.0)[1], src.profile_at(0.001)[1]
    np.testing.assert_array_equal(a0, a0b)
    assert not np.array_equal(a0, a1)
    assert np.std(a0 - 250_000.0) == pytest.approx(50.0, rel=0.15)
    with pytest.raises(ValueError, match="seed"):
        RaycastSource(v, t, lambda: 0.0, seed="x")


def test_station_default_pose_geometry():
    m = station_sensor_to_room()
    np.testing.assert_allclose(m[:3, 3], [260.0, 0.0, 120.0])
    np.testing.assert_allclose(m[:3, 2], [-math.cos(math.radians(20)), 0, -math.sin(math.radians(20))])
    np.testing.assert_allclose(np.cross(m[:3, 0], m[:3, 1]), m[:3, 2], atol=1e-15)
    assert m[1, 0] == m[1, 2] == 0.0  # the laser plane is y = 0, through the table axis
    for kw, msg in (({"standoff_mm": 0.0}, "standoff_mm"), ({"tilt_deg": 90.0}, "tilt_deg"),
                    ({"height_mm": math.inf}, "height_mm")):
        with pytest.raises(ValueError, match=msg):
            station_sensor_to_room(**kw)


def test_table_disc_is_a_flat_disc():
    v, t = table_disc(100.0, 64)
    area = 0.5 * np.linalg.norm(np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]), axis=1).sum()
    assert area == pytest.approx(0.5 * 64 * 100.0**2 * math.sin(2 * math.pi / 64))
    assert np.all(v[:, 2] == 0.0)
    with pytest.raises(ValueError, match="table_radius_mm"):
        table_disc(-1.0)


# ------------------------------------------------------------------ placements
def _is_rigid(m):
    r = m[:3, :3]
    return np.allclose(r.T @ r, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(r), 1.0) \
        and np.allclose(m[3], [0, 0, 0, 1])


def test_placement_one_is_the_base_pose_resting_on_the_table():
    w = box_world()
    base = rotation_z(30.0)
    base[:3, 3] = (4.0, -3.0, 12.0)  # floating 12 mm above the table
    p = placement_pose(w.vertices, base, 0, 1)
    np.testing.assert_array_equal(p[:3, :3], base[:3, :3])
    np.testing.assert_array_equal(p[:2, 3], base[:2, 3])
    assert p[2, 3] == pytest.approx(0.0, abs=1e-12)


@given(seed=st.integers(0, 2**31), n=st.integers(2, 10_000))
@settings(max_examples=40, deadline=None)
def test_placements_are_rigid_resting_tilted_and_near_the_axis(seed, n):
    w = box_world()
    p = placement_pose(w.vertices, np.eye(4), seed, n)
    assert _is_rigid(p)
    q = w.vertices @ p[:3, :3].T + p[:3, 3]
    assert q[:, 2].min() == pytest.approx(0.0, abs=1e-9)
    tilt = math.degrees(math.acos(np.clip(p[2, 2], -1, 1)))  # the object's +z against the table's
    assert 20.0 - 1e-9 <= tilt <= 90.0 + 1e-9
    centre = 0.5 * (q.min(axis=0) + q.max(axis=0))
    assert math.hypot(centre[0], centre[1]) <= 5.0 + 1e-9
    np.testing.assert_array_equal(p, placement_pose(w.vertices, np.eye(4), seed, n))


def test_placements_differ_between_numbers_and_seeds():
    w = box_world()
    a = placement_pose(w.vertices, np.eye(4), 0, 2)
    assert not np.allclose(a, placement_pose(w.vertices, np.eye(4), 0, 3))
    assert not np.allclose(a, placement_pose(w.vertices, np.eye(4), 1, 2))


def test_placement_applies_after_the_base_pose():
    """The tilt is measured from the base pose: the object's base up-vector ends 20-90 deg from +z."""
    w = box_world()
    base = np.eye(4)
    base[:3, :3] = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float)  # lying on its side
    for n in range(2, 12):
        p = placement_pose(w.vertices, base, 5, n)
        up = p[:3, :3] @ np.linalg.inv(base[:3, :3]) @ [0, 0, 1.0]
        assert 20.0 - 1e-9 <= math.degrees(math.acos(np.clip(up[2], -1, 1))) <= 90.0 + 1e-9


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "2"])
def test_bad_placement_number(bad):
    with pytest.raises(ValueError, match="placement"):
        placement_pose(np.zeros((3, 3)), np.eye(4), 0, bad)


def test_rest_on_table_for_any_pose():
    v = np.array([[0, 0, 0], [1, 2, 3], [-4, 5, -6]], float)
    pose = rotation_z(10.0)
    pose[2, 3] = -40.0
    out = rest_on_table(v, pose)
    assert (v @ out[:3, :3].T + out[:3, 3])[:, 2].min() == pytest.approx(0.0, abs=1e-12)


# ------------------------------------------------------------------ noise seeds
@given(micro=st.integers(-10**10, 10**10), k=st.integers(-20, 20), jitter=st.floats(-1e-9, 1e-9))
@settings(max_examples=80, deadline=None)
def test_angle_key_is_periodic_and_ignores_round_off(micro, k, jitter):
    """An angle of whole micro-degrees, turned by k revolutions and disturbed by round-off, has the key
    computed in integer arithmetic."""
    expected = micro % 360_000_000
    key = angle_key(micro / 1e6 + 360.0 * k + jitter)
    assert key == f"{expected // 1_000_000}.{expected % 1_000_000:06d}"


def test_angle_key_edges():
    assert angle_key(0.0) == angle_key(-0.0) == angle_key(360.0) == angle_key(-1e-12) == "0.000000"
    assert angle_key(90.1125 + 1e-11) == angle_key(90.1125) == "90.112500"
    with pytest.raises(ValueError, match="angle_deg"):
        angle_key(math.nan)


def test_seeds_depend_on_what_is_measured():
    assert profile_seed(0, 1, 10.0) == profile_seed(0, 1, 370.0)
    assert len({profile_seed(0, 1, 10.0), profile_seed(0, 2, 10.0), profile_seed(1, 1, 10.0),
                profile_seed(0, 1, 10.1125)}) == 4
    assert frame_seed(0, 1, "chart", 0.0) != frame_seed(0, 1, "object", 0.0)
    assert frame_seed(0, 1, "object", 45.0) == frame_seed(0, 1, "object", 45.0 + 1e-10)


# ------------------------------------------------------------------ fault syntax
def test_fault_spec_parses_every_kind():
    spec = parse_faults(["turntable.garbage_replies=3, profiler.corrupt_frames=2,camera.busy=1",
                         "turntable.unplug_on_command=1,turntable.replug_after_s=1.5,camera.no_camera=off",
                         "turntable.alarm_on_move=Hard limit,hotfolder.partial=1,world.chart_present=no",
                         "camera.exit_code=255"])
    assert spec == {
        "turntable": {"garbage_replies": 3, "unplug_on_command": 1, "replug_after_s": 1.5,
                      "alarm_on_move": "Hard limit"},
        "profiler": {"corrupt_frames": 2},
        "camera": {"busy": 1, "no_camera": False, "exit_code": 255},
        "hotfolder": {"partial": 1},
        "world": {"chart_present": False},
    }
    assert parse_faults("") == {} and parse_faults([]) == {}
    assert parse_faults(format_faults(spec)) == spec


@pytest.mark.parametrize("text,words", [
    ("turntable.garbage=3", ["turntable.garbage=3", "unknown turntable fault 'garbage'", "garbage_replies"]),
    ("lamp.on=1", ["unknown device 'lamp'", "turntable, profiler, camera, hotfolder, world"]),
    ("turntable.garbage_replies", ["DEVICE.NAME=VALUE"]),
    ("garbage_replies=3", ["DEVICE.NAME=VALUE"]),
    ("turntable.garbage_replies=-1", ["turntable.garbage_replies takes a whole number >= 0", "'-1'"]),
    ("turntable.garbage_replies=2.5", ["whole number"]),
    ("turntable.replug_after_s=soon", ["number of seconds"]),
    ("turntable.replug_after_s=nan", ["number of seconds"]),
    ("profiler.mute=maybe", ["1/0, true/false"]),
    ("camera.exit_code=256", ["0..255"]),
    ("turntable.alarm_on_move=", ["some text"]),
    ("profiler.alarm_on_move=x", ["unknown profiler fault 'alarm_on_move'"]),
])
def test_fault_spec_errors_name_the_item(text, words):
    with pytest.raises(FaultSpecError) as info:
        parse_faults(text)
    msg = str(info.value)
    assert "\n" not in msg
    for w in words:
        assert w in msg


def test_every_listed_fault_exists_on_its_device():
    from mocks.fake_gphoto2 import DEFAULT_FAULTS
    from mocks.faults import Faults

    for name in (*FAULT_NAMES["turntable"], *FAULT_NAMES["profiler"]):
        assert hasattr(Faults(), name)
    assert set(FAULT_NAMES["camera"]) == set(DEFAULT_FAULTS)
    for name in FAULT_NAMES["hotfolder"]:
        assert hasattr(HotFolderFaults(), name)


# ------------------------------------------------------------------ station parameters
@pytest.mark.parametrize("kw,msg", [({"seed": -1}, "seed"), ({"time_scale": -1.0}, "time_scale"),
                                    ({"exposure_s": 0.0}, "exposure_s"), ({"fov_deg": 200.0}, "fov_deg"),
                                    ({"table_radius_mm": 0.0}, "table_radius_mm"),
                                    ({"sensor_to_room": np.eye(3)}, "sensor_to_room"),
                                    ({"hotfolder_chunks": 0}, "hotfolder_chunks")])
def test_bad_station_parameters(kw, msg, tmp_path):
    with pytest.raises(ValueError, match=msg):
        SimulatedStation(box_world(), root=tmp_path / "st", **kw)


def test_station_reexports_the_names_of_its_parts():
    import mocks.faults
    import mocks.station
    import mocks.station_geometry
    import mocks.station_requests

    for module in (mocks.faults, mocks.station_geometry, mocks.station_requests):
        for name in set(module.__all__) & set(mocks.station.__all__):
            assert getattr(mocks.station, name) is getattr(module, name)
    assert set(mocks.station.__all__) <= set(dir(mocks.station))


def test_station_before_start_has_ground_truth_but_no_devices(tmp_path):
    st_ = SimulatedStation(box_world(), root=tmp_path / "st", seed=4)
    assert st_.placement == 1 and _is_rigid(st_.pose)
    assert st_.turntable_path == tmp_path / "st" / "turntable"
    with pytest.raises(StationError, match="start"):
        _ = st_.turntable
    pose = st_.place(3)
    np.testing.assert_array_equal(pose, placement_pose(st_.world.vertices, np.eye(4), 4, 3))
    np.testing.assert_array_equal(st_.world.pose, pose)
