"""The simulated station driven through the project's drivers over real ptys: profiles against
closed-form sections of a box, the table top, the laser power through the board's T1, determinism of
noise, placements, the chart rule and the cameras following the turntable."""

from __future__ import annotations

import math
import os
import time

import numpy as np
import open3d as o3d
import pytest
import rawpy

from drivers.camera_errors import CameraBusyError
from drivers.camera_gphoto2 import Gphoto2Camera
from drivers.errors import TransportClosed
from drivers.profiler import LaserProfiler
from drivers.transport import SerialTransport
from drivers.turntable import Turntable
from mocks.camera_sim import simulate_raw
from mocks.fake_gphoto2 import read_config
from mocks.horus_firmware import HorusFirmware
from mocks.station import SimulatedStation
from mocks.waiting import wait_until
from mocks.world import World, rotation_z

HALF_X, HALF_Y, HEIGHT = 20.0, 15.0, 50.0


def box_world(lo=(-HALF_X, -HALF_Y, 0.0), hi=(HALF_X, HALF_Y, HEIGHT)):
    m = o3d.geometry.TriangleMesh.create_box(*(np.subtract(hi, lo)))
    v = np.asarray(m.vertices) + np.asarray(lo, float)
    t = np.asarray(m.triangles)
    return World(v, t, np.zeros(len(t), np.int64), ("object",), {"object": "gold"}, width=48, height=32,
                 spectral_step=20.0)


class Rig:
    """A station with the Turntable and LaserProfiler drivers connected to it."""

    def __init__(self, station: SimulatedStation):
        self.st = station
        self.tt = Turntable(SerialTransport(str(station.turntable_path)), margin_s=0.5)
        self.lp = LaserProfiler(SerialTransport(str(station.profiler_path)), margin_s=0.5)
        self.tt.connect()
        self.lp.connect()
        self.lp.laser(True)

    def close(self):
        self.lp.close()
        self.tt.close()


@pytest.fixture
def rig(tmp_path, request):
    kw = getattr(request, "param", {})
    kw = {"hotfolder_interval_s": 0.01, **kw}
    with SimulatedStation(box_world(), root=tmp_path / "station", seed=7, **kw) as st:
        r = Rig(st)
        try:
            yield r
        finally:
            r.close()


def fan(st: SimulatedStation):
    th = np.radians(np.linspace(-20.0, 20.0, st.n_points))
    m = st.sensor_to_room
    return th, m, np.sin(th)[:, None] * m[:3, 0] + np.cos(th)[:, None] * m[:3, 2]


def expected_box_profile(st, half_x, margin=0.5):
    """Closed-form profile of the box section [-half_x, half_x] x [0, HEIGHT] in the laser plane y = 0
    plus the table (z = 0, radius 100): the near face x = half_x or the table in front of it.

    Returns the sensor (x, z) of each ray's hit, a mask of rays certainly valid (face or table, away from
    edges, incidence <= 70 deg, range 150..360) and a mask of rays certainly invalid (over the box top,
    where the incidence exceeds the limit, or past the table's edge)."""
    th, m, d = fan(st)
    o = m[:3, 3]
    t_face = (half_x - o[0]) / d[:, 0]
    z_face = o[2] + t_face * d[:, 2]
    with np.errstate(divide="ignore"):
        t_tab = np.where(d[:, 2] < 0, -o[2] / d[:, 2], np.inf)
    x_tab = o[0] + t_tab * d[:, 0]
    face = (z_face > margin) & (z_face < HEIGHT - margin)
    table = (z_face < -margin) & (x_tab > half_x + margin) & (x_tab < 100.0 * math.cos(math.pi / 128) - margin)
    t = np.where(face, t_face, np.where(table, t_tab, np.nan))
    cos_i = np.where(face, -d[:, 0], -d[:, 2])
    rng = t * np.cos(th)
    valid = (face | table) & (cos_i > math.cos(math.radians(69.5))) & (rng > 151) & (rng < 359)
    invalid = (z_face > HEIGHT + margin) | (x_tab > 100.0 + margin)
    return t * np.sin(th), rng, valid, invalid, face, table


def to_room(st, x_mm, z_mm):
    m = st.sensor_to_room
    return m[:3, 3] + x_mm[:, None] * m[:3, 0] + z_mm[:, None] * m[:3, 2]


@pytest.mark.parametrize("rig", [{"noise_um": 0.0}], indirect=True)
def test_box_section_matches_closed_form_at_two_angles(rig):
    st = rig.st
    for angle, half_x in ((0.0, HALF_X), (90.0, HALF_Y), (180.0, HALF_X)):
        assert rig.tt.step(angle, lasers=[1]) == pytest.approx(angle)
        prof = rig.lp.profile(2.0)
        x_ref, z_ref, valid, invalid, face, table = expected_box_profile(st, half_x)
        assert valid.sum() > 100 and (valid & face).sum() > 50 and (valid & table).sum() > 30
        assert prof.valid[valid].all() and not prof.valid[invalid].any()
        # micrometre integers on the wire, float32 ray casting
        np.testing.assert_allclose(prof.x_mm[valid], x_ref[valid], atol=0.005)
        np.testing.assert_allclose(prof.z_mm[valid], z_ref[valid], atol=0.005)
        room = to_room(st, prof.x_mm[valid & face], prof.z_mm[valid & face])
        np.testing.assert_allclose(room[:, 0], half_x, atol=0.005)     # the section's width
        np.testing.assert_allclose(room[:, 1], 0.0, atol=1e-9)        # the laser plane
        on_table = to_room(st, prof.x_mm[valid & table], prof.z_mm[valid & table])
        np.testing.assert_allclose(on_table[:, 2], 0.0, atol=0.005)  # the table top is in the profile


def test_table_beyond_the_far_range_is_cropped(tmp_path):
    """A 2 mm cube on the axis and a short range window: table points farther than the window are
    invalid, nearer ones valid at the closed-form position."""
    world = box_world((-1.0, -1.0, 0.0), (1.0, 1.0, 2.0))
    with SimulatedStation(world, root=tmp_path / "st", noise_um=0.0, range_mm=(150.0, 250.0)) as st:
        rig = Rig(st)
        try:
            rig.tt.step(0.0, lasers=[1])
            prof = rig.lp.profile(2.0)
        finally:
            rig.close()
    th, m, d = fan(st)
    with np.errstate(divide="ignore"):
        t_tab = np.where(d[:, 2] < 0, -m[2, 3] / d[:, 2], np.inf)
    x_tab = m[0, 3] + t_tab * d[:, 0]
    rng = t_tab * np.cos(th)
    on_disc = (x_tab > 2.0) & (x_tab < 99.0) & (-d[:, 2] > math.cos(math.radians(69.5)))
    near, far = on_disc & (rng < 249.0), on_disc & (rng > 251.0)
    assert near.sum() > 20 and far.sum() > 10
    assert prof.valid[near].all() and not prof.valid[far].any()
    np.testing.assert_allclose(prof.z_mm[near], rng[near], atol=0.005)


def test_laser_line_is_powered_by_the_board_output_t1(rig):
    tt, lp, st = rig.tt, rig.lp, rig.st
    tt.motor(True)
    prof = lp.profile(2.0)                     # the profiler's own laser is on, T1 never switched on
    assert prof.valid.size == st.n_points and not prof.valid.any()
    tt.laser(1, True)
    assert lp.profile(2.0).valid.sum() > 100
    tt.laser(2, True)
    tt.laser(1, False)                          # T2 is the board's other laser, not the profiler's
    assert not lp.profile(2.0).valid.any()
    tt.step(10.0, lasers=[1])
    assert lp.profile(2.0).valid.sum() > 100
    st.turntable.fire_laser_watchdog()
    assert wait_until(lambda: not st.turntable.lasers[0], 2.0)
    assert not lp.profile(2.0).valid.any()     # switched off behind the host's back
    tt.step(20.0)                               # step() re-asserts the lasers
    assert lp.profile(2.0).valid.sum() > 100


def test_laser_watchdog_fault_after_moves(rig):
    tt, lp, st = rig.tt, rig.lp, rig.st
    st.apply_faults({"turntable": {"laser_watchdog_after_moves": 2}})
    tt.step(10.0, lasers=[1])
    assert lp.profile(2.0).valid.any()
    tt.move_to(20.0)                            # the second move: the watchdog comes due
    assert lp.profile(2.0).valid.any()          # ... at the next command, not yet
    tt.move_to(30.0)                            # a host that does not re-assert loses the laser
    assert not lp.profile(2.0).valid.any()
    assert any("watchdog" in line for line in tt.unsolicited)
    tt.step(40.0)                               # one that does gets it back at once
    assert lp.profile(2.0).valid.any()


def test_same_angle_same_profile_and_noise_of_the_requested_size(rig):
    tt, lp, st = rig.tt, rig.lp, rig.st
    tt.step(0.0, lasers=[1])
    a = lp.profile(2.0)
    tt.step(90.0)
    b = lp.profile(2.0)
    tt.step(360.0)                              # the same view, a revolution later
    c = lp.profile(2.0)
    tt.step(0.0)
    d = lp.profile(2.0)
    for p in (c, d):
        np.testing.assert_array_equal(p.valid, a.valid)
        np.testing.assert_array_equal(p.z_mm[a.valid], a.z_mm[a.valid])
    assert not np.array_equal(a.valid, b.valid) or not np.array_equal(a.z_mm, b.z_mm)
    _, z_ref, valid, _, _, _ = expected_box_profile(st, HALF_X)
    resid = (a.z_mm - z_ref)[valid] * 1000.0
    assert abs(resid.mean()) < 12.0 and resid.std() == pytest.approx(50.0, rel=0.25)
    st.place(2)
    st.place(1)                                  # the same placement again: the same data
    np.testing.assert_array_equal(lp.profile(2.0).z_mm[a.valid], a.z_mm[a.valid])


def test_two_stations_with_one_seed_agree(tmp_path):
    profiles = []
    for i in range(2):
        with SimulatedStation(box_world(), root=tmp_path / f"st{i}", seed=3) as st:
            rig = Rig(st)
            try:
                rig.tt.step(33.75, lasers=[1])
                profiles.append(rig.lp.profile(2.0))
            finally:
                rig.close()
    np.testing.assert_array_equal(profiles[0].z_mm, profiles[1].z_mm)
    np.testing.assert_array_equal(profiles[0].x_mm, profiles[1].x_mm)


def _box_distance(p, half=(HALF_X, HALF_Y, HEIGHT)):
    """Distance of points (N, 3) from the surface of the box [-hx, hx] x [-hy, hy] x [0, h]."""
    lo = np.array([-half[0], -half[1], 0.0])
    hi = np.array([half[0], half[1], half[2]])
    outside = np.linalg.norm(np.maximum(np.maximum(lo - p, p - hi), 0.0), axis=1)
    inside = np.min(np.minimum(p - lo, hi - p), axis=1)
    return np.where(np.all((p >= lo) & (p <= hi), axis=1), inside, outside)


def test_profiles_follow_the_placement(rig):
    """After place(n) every valid point, taken back through the table angle and the placement pose,
    lies on the box's surface or on the table top."""
    tt, lp, st = rig.tt, rig.lp, rig.st
    tt.step(0.0, lasers=[1])
    for n in (2, 3):
        pose = st.place(n)
        assert st.placement == n
        np.testing.assert_array_equal(st.pose, pose)
        seen_object = 0
        for target in (0.0, 120.0, 240.0):
            angle = tt.step(target)                # whole motor steps: 120 deg is 120.0375 deg
            prof = lp.profile(2.0)
            room = to_room(st, prof.x_mm[prof.valid], prof.z_mm[prof.valid])
            table = np.abs(room[:, 2]) < 0.3
            to_obj = np.linalg.inv(rotation_z(angle) @ pose)
            obj = room[~table] @ to_obj[:3, :3].T + to_obj[:3, 3]
            assert np.all(_box_distance(obj) < 0.3)  # 6 sigma of 50 um noise
            seen_object += len(obj)
        assert seen_object > 100


def dng(path):
    with rawpy.imread(str(path)) as raw:
        return raw.raw_image_visible.astype(np.float64), float(np.mean(raw.black_level_per_channel))


def chart_score(path):
    """Mean signal of the white patch's area (bottom-left of a chart frame) over the black level."""
    img, black = dng(path)
    h, w = img.shape
    return img[int(h * 0.78):int(h * 0.97), int(w * 0.02):int(w * 0.15)].mean() - black


def test_hot_folder_chart_after_each_placement_then_object_frames(rig):
    st = rig.st
    first, second, third = st.shoot(), st.shoot(), st.shoot()
    assert [p.name for p in (first, second, third)] == ["IMG_0001.DNG", "IMG_0002.DNG", "IMG_0003.DNG"]
    assert chart_score(first) > 5 * chart_score(second)
    # object frames at one angle and placement are identical; the chart differs from them
    np.testing.assert_array_equal(dng(second)[0], dng(third)[0])
    st.place(2)
    chart2 = st.shoot()
    assert chart_score(chart2) > 5 * chart_score(st.shoot())
    np.testing.assert_array_equal(dng(chart2)[0].shape, dng(first)[0].shape)


def test_hot_folder_partial_fault_keeps_the_chart_pending(rig):
    st = rig.st
    st.apply_faults({"hotfolder": {"partial": 1}})
    cut = st.shoot()
    full = st.shoot()
    assert 0 < cut.stat().st_size < full.stat().st_size
    assert chart_score(full) > 5 * chart_score(st.shoot())   # the re-shot frame is still the chart


def expected_object_raw(world, angle):
    frame = world.frame("object", angle)
    return simulate_raw(frame.radiance, frame.grid, frame.light, exposure_s=0.01, seed=12345).bayer.astype(float)


@pytest.mark.parametrize("rig", [{"time_scale": 0.05}], indirect=True)
def test_gphoto2_renders_the_angle_the_turntable_just_reached(rig, tmp_path):
    st, tt = rig.st, rig.tt
    tt.step(90.0, lasers=[1])
    # the camera's configuration holds the new angle as soon as the driver has its ok
    assert read_config(st.config_path)["world"]["table_angle_deg"] == pytest.approx(90.0, abs=1e-9)
    assert st.shoot().name == "IMG_0001.DNG"         # the hot folder takes the chart frame
    cam = Gphoto2Camera(tmp_path / "session", executable=st.gphoto2_path, timeout_s=60)
    got, _ = dng(cam.capture("f090"))
    at90, at0 = expected_object_raw(st.world, 90.0), expected_object_raw(st.world, 0.0)
    assert not np.allclose(at90, at0)
    assert np.abs(got - at90).mean() < 0.5 * np.abs(got - at0).mean()
    assert read_config(st.config_path)["chart_next"] is False


def test_camera_faults_and_chart_flag_go_through_the_configuration(rig, tmp_path):
    st = rig.st
    st.apply_faults({"camera": {"busy": 1}, "world": {"chart_present": False}})
    config = read_config(st.config_path)
    assert config["faults"]["busy"] == 1 and config["world"]["chart_present"] is False
    cam = Gphoto2Camera(tmp_path / "session", executable=st.gphoto2_path, timeout_s=60)
    with pytest.raises(CameraBusyError):
        cam.capture("chart_000")
    config = read_config(st.config_path)
    assert config["faults"]["busy"] == 0 and config["chart_next"] is True  # a failed shot keeps the chart
    st.place(4)
    config = read_config(st.config_path)
    assert config["placement"] == 4
    np.testing.assert_allclose(config["world"]["pose"], st.pose)


def test_unplugged_turntable_recovers_with_the_same_profile(rig):
    tt, lp, st = rig.tt, rig.lp, rig.st
    tt.step(45.0, lasers=[1])
    before = lp.profile(2.0)
    tt.step(90.0)
    st.apply_faults({"turntable": {"unplug_on_command": 1, "replug_after_s": 0.2}})
    with pytest.raises(TransportClosed):
        tt.step(45.0)
    assert not os.path.exists(st.turntable_path)
    assert not lp.profile(2.0).valid.any()           # the board lost power: the laser is off
    tt.reconnect(5.0)
    assert tt.step(45.0) == pytest.approx(45.0)
    after = lp.profile(2.0)
    np.testing.assert_array_equal(after.valid, before.valid)
    np.testing.assert_array_equal(after.z_mm[after.valid], before.z_mm[before.valid])


def test_move_done_callback_runs_before_the_ok(tmp_path):
    seen = []

    def done(angle):
        time.sleep(0.2)
        seen.append((angle, time.monotonic()))
        raise RuntimeError("a failing simulator must not stop the firmware")

    with HorusFirmware(tmp_path / "tt", time_scale=0.02, on_move_done=done) as fw:
        tt = Turntable(SerialTransport(fw.path), margin_s=0.5)
        tt.connect()
        tt.motor(True)
        assert tt.move_to(45.0) == pytest.approx(45.0)
        answered = time.monotonic()
        assert len(seen) == 1 and seen[0][0] == pytest.approx(45.0)
        assert seen[0][1] <= answered          # the ok came after the callback had returned
        tt.close()
    with pytest.raises(ValueError, match="on_move_done"):
        HorusFirmware(tmp_path / "tt2", on_move_done=3)


def test_stop_removes_ptys_and_temporary_folder():
    st = SimulatedStation(box_world()).start()
    root, link = st.root, st.turntable_path
    assert os.path.realpath(link).startswith("/dev/pts/")
    fd = os.open(link, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        with pytest.raises(BlockingIOError):
            os.read(fd, 1)                      # alive, nothing to read
        st.stop()
        try:                                    # the emulator's end is closed: end of file or EIO
            hung_up = os.read(fd, 1) == b""
        except BlockingIOError:
            hung_up = False
        except OSError:
            hung_up = True
        assert hung_up
    finally:
        os.close(fd)
    assert not root.exists()
    st.stop()  # idempotent


def test_gphoto2_frames_rendered_by_the_station_equal_those_it_renders_itself(tmp_path):
    # The station renders the fake gphoto2's frames in its own process (modules loaded); the frame must be
    # the one the program renders itself, byte for byte (same world, same seeded noise), and a stopped
    # station hands the rendering back to the program.
    import hashlib
    import subprocess

    from mocks.fake_gphoto2 import set_renderer

    digests = {}
    for mode in ("station", "program"):
        with SimulatedStation(box_world(), root=tmp_path / mode, seed=7) as st:
            assert read_config(st.config_path)["renderer"] == str(st.control_dir)
            if mode == "program":
                set_renderer(st.config_path, None)
            subprocess.run([str(st.gphoto2_path), "--capture-image-and-download", "--filename",
                            str(tmp_path / f"{mode}.%C")], cwd=tmp_path, check=True, capture_output=True)
            digests[mode] = hashlib.sha1((tmp_path / f"{mode}.dng").read_bytes()).hexdigest()
        assert "renderer" not in read_config(st.config_path)
    assert digests["station"] == digests["program"]


def test_a_station_on_a_relative_folder_renders_the_programs_frames(tmp_path, monkeypatch):
    """The demo (``make demo`` writes into ``out/demo``) names its stations' folders relative to where it runs, and
    the camera driver runs gphoto2 in the capture's folder: the program must still find the station (else every
    frame costs a fresh program's imports and world, seconds each)."""
    import subprocess

    import mocks.fake_gphoto2 as fake

    rendered, real = [], fake.render_frame

    def recording(*args, **kwargs):
        rendered.append(args[2])
        return real(*args, **kwargs)

    monkeypatch.setattr(fake, "render_frame", recording)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "capture").mkdir()
    with SimulatedStation(box_world(), root="station", seed=7) as st:
        subprocess.run([str(st.gphoto2_path), "--capture-image-and-download", "--filename", "frame.%C"],
                       cwd=tmp_path / "capture", check=True, capture_output=True)
    assert (tmp_path / "capture" / "frame.dng").stat().st_size > 1000
    assert rendered == [str(tmp_path / "capture" / "frame.dng")]        # by the station, in this process
