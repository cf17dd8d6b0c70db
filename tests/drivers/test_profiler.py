"""Laser profiler driver against the profiler emulator over real ptys, with every fault.

Expected profiles come from the closed-form flat-plus-sphere source
(``z = standoff - sqrt(R^2 - x^2)``), computed here independently.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from drivers.errors import DeviceError, DeviceTimeout, HandshakeError, TransportClosed
from drivers.profiler import LaserProfiler
from drivers.transport import SerialTransport
from mocks.faults import Faults
from mocks.profiler_firmware import MODEL, SERIAL, VERSION, ProfilerFirmware, synthetic_source
from mocks.pty_link import PtyLink

N, WIDTH, STANDOFF, RADIUS = 64, 80.0, 150.0, 20.0


def expected_profile():
    x = np.linspace(-WIDTH / 2, WIDTH / 2, N)
    z = STANDOFF - np.sqrt(np.clip(RADIUS**2 - x**2, 0, None))
    return x, z


@pytest.fixture
def faults():
    return Faults()


@pytest.fixture
def fw(tmp_path, faults):
    src = synthetic_source(n_points=N, width_mm=WIDTH, standoff_mm=STANDOFF, sphere_radius_mm=RADIUS)
    with ProfilerFirmware(tmp_path / "profiler", faults=faults, source=src) as f:
        yield f


def make(fw, tmp_path=None, **kw) -> LaserProfiler:
    kw.setdefault("max_points", 256)
    kw.setdefault("margin_s", 0.5)
    log = None if tmp_path is None else tmp_path / "wire.log"
    return LaserProfiler(SerialTransport(fw.path, wire_log=log, label="profiler"), **kw)


@pytest.fixture
def lp(fw, tmp_path):
    p = make(fw, tmp_path)
    p.connect()
    p.laser(True)
    yield p
    p.close()


def assert_sphere(p):
    x, z = expected_profile()
    assert p.valid.all()
    np.testing.assert_allclose(p.x_mm, x, atol=0.0005 + 1e-9)  # integer micrometres
    np.testing.assert_allclose(p.z_mm, z, atol=0.0005 + 1e-9)


def test_connect_identifies_and_configures(fw, tmp_path):
    p = make(fw, tmp_path, exposure_us=1200, rate_hz=50)
    assert p.connect() == VERSION
    assert (p.model, p.serial_number) == (MODEL, SERIAL)
    assert fw.settings == {"EXP": 1200, "RATE": 50}
    assert p.get("EXP") == "1200"
    p.set_exposure(800)
    p.set_rate(200)
    assert fw.settings == {"EXP": 800, "RATE": 200}
    p.close()
    log = (tmp_path / "wire.log").read_text()
    assert "profiler > ID\\r\\n" in log and "profiler < OK,ID,KP-200" in log


def test_profile_matches_closed_form_and_counts_up(lp, fw):
    a = lp.profile(2.0)
    b = lp.profile(2.0)
    assert_sphere(a)
    assert_sphere(b)
    assert b.seq == a.seq + 1
    assert b.timestamp_us > a.timestamp_us
    assert fw.laser_on


def test_invalid_points_become_nan(tmp_path):
    x = np.array([-1.0, 0.0, 1.0, 2.0]) * 1000
    z = np.array([100.0, 101.0, 102.0, 103.0]) * 1000
    ok = np.array([True, False, True, False])
    with ProfilerFirmware(tmp_path / "p", source=lambda: (x, z, ok)) as fw:
        p = make(fw)
        p.connect()
        p.laser(True)
        prof = p.profile(2.0)
        p.close()
    assert prof.valid.tolist() == [True, False, True, False]
    assert np.isnan(prof.x_mm[[1, 3]]).all() and np.isnan(prof.z_mm[[1, 3]]).all()
    assert prof.z_mm[[0, 2]].tolist() == [100.0, 102.0]


def test_error_reply_names_code_meaning_and_port(lp, fw):
    with pytest.raises(DeviceError, match=r"ER,SET,03 \(parameter out of range\)") as ei:
        lp.set_exposure(5)
    assert fw.path in str(ei.value) and ei.value.text == "03"
    lp.laser(False)
    with pytest.raises(DeviceError, match=r"ER,TRG,04 \(not allowed in the current state\)"):
        lp.profile(1.0)
    lp.laser(True)
    assert_sphere(lp.profile(2.0))  # the link stays usable


def test_sequence_wraps_at_2_32(lp, fw):
    fw.set_seq(2**32 - 1)
    assert lp.profile(2.0).seq == 2**32 - 1
    assert lp.profile(2.0).seq == 0


def test_fault_garbage_before_replies(lp, faults):
    faults.garbage_replies = 3
    assert_sphere(lp.profile(2.0))
    assert lp.get("RATE") == "100"


def test_fault_garbage_with_false_magic_before_frames(lp, faults, tmp_path):
    faults.garbage = b"\x00KPRF\x01\x00\x07\x00\x00\x00\xffKPR\x93"  # a false match, then a split magic
    faults.garbage_frames = 2
    assert_sphere(lp.profile(2.0))
    assert_sphere(lp.profile(2.0))
    log = (tmp_path / "wire.log").read_text()
    assert log.count("resynchronised: skipped") == 2


def test_fault_corrupted_frame_is_rerequested(lp, fw, faults):
    faults.corrupt_frames = 2
    p = lp.profile(3.0)
    assert_sphere(p)
    assert [r for r in fw.received if r.startswith("RSND")] == [f"RSND,{p.seq}"] * 2
    assert fw.frames_sent == 1  # the same frame, re-sent


def test_fault_persistent_corruption_is_reported(lp, faults, fw):
    faults.corrupt_frames = 100
    with pytest.raises(DeviceError, match="CRC mismatch") as ei:
        lp.profile(5.0)
    assert fw.path in str(ei.value) and "3 re-requests" in str(ei.value)
    faults.corrupt_frames = 0
    assert_sphere(lp.profile(2.0))


def test_fault_dropped_frame_is_rerequested(lp, fw, faults):
    lp.profile(2.0)
    faults.drop_frames = 1
    p = lp.profile(3.0)
    assert_sphere(p)
    assert fw.received[-1] == f"RSND,{p.seq}"


def test_rsnd_of_a_frame_no_longer_buffered_triggers_again(tmp_path):
    src = synthetic_source(n_points=N, width_mm=WIDTH, standoff_mm=STANDOFF, sphere_radius_mm=RADIUS)
    with ProfilerFirmware(tmp_path / "p", source=src, buffer_frames=1) as fw:
        p = make(fw)
        p.connect()
        p.laser(True)
        seq0 = p.profile(2.0).seq
        seq1 = p.profile(2.0).seq  # evicts seq0 from the one-frame buffer
        assert p._rerequest(seq0) == seq1 + 1
        assert fw.received[-2:] == [f"RSND,{seq0}", "TRG"]
        p.close()


def test_fault_lost_reply_times_out_then_recovers(lp, faults, fw):
    faults.drop_replies = 1
    t0 = time.monotonic()
    with pytest.raises(DeviceTimeout, match="no reply") as ei:
        lp.profile(2.0)
    assert time.monotonic() - t0 < 2.0
    assert fw.path in str(ei.value)
    p = lp.profile(2.0)
    assert_sphere(p)


def test_fault_slow_reply_within_margin(lp, faults):
    faults.reply_delay_s = 0.15
    assert_sphere(lp.profile(2.0))


def test_fault_too_slow_reply_is_reported_then_stale_frame_ignored(lp, faults, fw):
    faults.reply_delay_s = 1.0
    with pytest.raises(DeviceTimeout, match="no reply"):
        lp.profile(2.0)
    stale = fw.seq - 1
    faults.reply_delay_s = 0.0
    time.sleep(1.0)  # the late reply and its frame arrive now
    p = lp.profile(2.0)
    assert p.seq == stale + 1
    assert_sphere(p)


def test_fault_device_reset_on_command_restores_settings(fw, faults, tmp_path):
    p = make(fw, tmp_path, exposure_us=2000)
    p.connect()
    p.laser(True)
    faults.reset_on_command = 1
    prof = p.profile(3.0)
    assert_sphere(prof)
    assert fw.resets == 1 and fw.laser_on and fw.settings["EXP"] == 2000
    assert any("device reset" in r for r in p.recoveries)
    p.close()


def test_spontaneous_reset_between_profiles(lp, fw):
    lp.profile(2.0)
    fw.reset()
    time.sleep(0.05)
    prof = lp.profile(3.0)
    assert_sphere(prof)
    assert prof.seq == 0 and fw.laser_on


def test_explicit_reset_command(lp, fw):
    assert lp.reset() == VERSION
    assert fw.resets == 1 and fw.laser_on
    assert lp.profile(2.0).seq == 0


def test_fault_unplug_then_reconnect(lp, fw, faults):
    lp.profile(2.0)
    faults.unplug_on_command = 1
    faults.replug_after_s = 0.3
    with pytest.raises(TransportClosed) as ei:
        lp.profile(2.0)
    assert fw.path in str(ei.value)
    assert lp.reconnect(timeout_s=5.0) == VERSION
    assert fw.laser_on  # re-asserted after power-up
    assert_sphere(lp.profile(2.0))


def test_unplugged_port_is_reported_with_its_path(fw, tmp_path):
    p = make(fw)
    p.connect()
    fw.unplug()
    with pytest.raises(TransportClosed) as ei:
        p.profile(1.0)
    assert fw.path in str(ei.value)
    p.close()  # best effort, must not raise
    assert not p.transport.is_open


def test_streaming_reports_gaps_and_drops_duplicates(lp, fw, faults):
    lp.set_rate(200)
    lp.start_stream()
    seqs = [lp.profile(2.0).seq for _ in range(3)]
    faults.drop_frames = 2
    seqs += [lp.profile(2.0).seq for _ in range(3)]
    lp.stop_stream()
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    assert len(lp.lost_seqs) == 2
    assert sorted(set(seqs) | set(lp.lost_seqs)) == list(range(seqs[0], seqs[-1] + 1))
    with pytest.raises(DeviceError, match="ER,SET,04"):
        lp.start_stream()
        lp.set_exposure(100)
    lp.stop_stream()
    assert_sphere(lp.profile(2.0))  # back to triggered mode


def test_handshake_with_silent_port_names_it(tmp_path):
    with PtyLink(tmp_path / "silent") as link:
        p = LaserProfiler(SerialTransport(link.path), margin_s=0.2)
        with pytest.raises(HandshakeError, match="no answer to 'ID'") as ei:
            p.connect()
        assert link.path in str(ei.value)
        p.transport.close()


def test_fault_hung_sensor_times_out_and_close_does_not_hang(lp, faults):
    faults.mute = True
    with pytest.raises(DeviceTimeout, match="no reply"):
        lp.profile(2.0)
    t0 = time.monotonic()
    lp.close()
    assert time.monotonic() - t0 < 2.0 and not lp.transport.is_open


def test_close_turns_laser_off(fw):
    with make(fw) as p:
        p.laser(True)
        assert fw.laser_on
    assert not fw.laser_on and not p.transport.is_open


@pytest.mark.parametrize("kw,msg", [({"exposure_us": 0}, "exposure_us"), ({"rate_hz": 5000}, "rate_hz"),
                                    ({"max_retries": -1}, "max_retries"), ({"margin_s": float("nan")}, "margin_s")])
def test_bad_parameters(kw, msg):
    with pytest.raises(ValueError, match=msg):
        LaserProfiler(SerialTransport("loop://"), **kw)


def test_bad_deadline(lp):
    with pytest.raises(ValueError, match="deadline_s"):
        lp.profile(0)
