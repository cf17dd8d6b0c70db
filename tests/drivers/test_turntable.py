"""Turntable driver against the Horus firmware emulator over real ptys, with every fault."""

from __future__ import annotations

import re
import time

import pytest

from drivers.errors import (
    DeviceAlarm,
    DeviceError,
    DeviceResetError,
    DeviceTimeout,
    HandshakeError,
    TransportClosed,
)
from drivers.transport import SerialTransport
from drivers.turntable import HORUS_BANNER, Turntable, move_time_s
from mocks.faults import Faults
from mocks.horus_firmware import HorusFirmware
from mocks.pty_link import PtyLink
from mocks.waiting import wait_until

STEP = 360.0 / 3200.0  # one motor step in degrees


@pytest.fixture
def faults():
    return Faults()


@pytest.fixture
def fw(tmp_path, faults):
    with HorusFirmware(tmp_path / "turntable", faults=faults) as f:
        yield f


def make_tt(fw, tmp_path=None, **kw) -> Turntable:
    kw.setdefault("margin_s", 0.3)
    kw.setdefault("status_timeout_s", 1.0)
    log = None if tmp_path is None else tmp_path / "wire.log"
    return Turntable(SerialTransport(fw.path, wire_log=log, label="turntable"), **kw)


@pytest.fixture
def tt(fw, tmp_path):
    t = make_tt(fw, tmp_path)
    t.connect()
    yield t
    t.close()


def test_handshake_records_version_and_sets_speed(fw, tt):
    assert tt.firmware_version == "Horus 0.2"
    assert fw.resets == 1
    assert fw.feed_units_s == pytest.approx(100.0)


def test_other_firmware_banner_is_rejected(tmp_path):
    with HorusFirmware(tmp_path / "tt", banner="Grbl 0.9j ['$' for help]") as fw:
        t = make_tt(fw)
        with pytest.raises(HandshakeError, match=re.escape("Grbl 0.9j")) as ei:
            t.connect()
        assert HORUS_BANNER in str(ei.value)
        t.close()


def test_no_banner_is_a_clear_handshake_error(tmp_path):
    with PtyLink(tmp_path / "silent") as link:
        t = Turntable(SerialTransport(link.path), handshake_timeout_s=0.3)
        with pytest.raises(HandshakeError, match="no banner within 0.3 s"):
            t.connect()
        t.close()


def test_every_command(fw, tt):
    tt.motor(True)
    assert fw.motor_enabled
    tt.laser(2, True)
    assert fw.lasers == (False, True)
    tt.laser(2, False)
    assert fw.lasers == (False, False)
    tt.set_speed(45.0)
    assert fw.feed_units_s == pytest.approx(45.0)
    assert tt.move_to(90.0) == pytest.approx(90.0, abs=STEP / 2)
    assert fw.angle_deg == pytest.approx(90.0, abs=STEP / 2)
    tt.zero()
    assert tt.position_deg == 0.0 and fw.position_units == 0.0
    tt.move_to(-30.0)
    assert fw.angle_deg == pytest.approx(60.0, abs=STEP)
    tt.motor(False)
    assert not fw.motor_enabled
    assert tt.status().state == "Idle"
    assert "G50" in fw.received and "M71 T2" in fw.received and "M70 T2" in fw.received


def test_positions_are_whole_steps_in_degrees(fw, tt):
    tt.motor(True)
    got = tt.move_to(10.0)
    assert round(got / STEP) == round(10.0 / STEP)
    assert got == pytest.approx(round(10.0 / STEP) * STEP)
    assert fw.angle_deg == pytest.approx(got)


def test_firmware_units_differ_from_degrees(tmp_path):
    # firmware $100 = 2 x mechanical steps/deg: X counts half-degrees
    spd = 3200 / 360
    with HorusFirmware(tmp_path / "tt", steps_per_unit=2 * spd, steps_per_degree=spd) as fw:
        tt = make_tt(fw, firmware_steps_per_unit=2 * spd, steps_per_degree=spd)
        tt.connect()
        tt.motor(True)
        tt.move_to(90.0)
        assert fw.position_units == pytest.approx(45.0)
        assert fw.angle_deg == pytest.approx(90.0)
        tt.set_speed(60.0)
        assert fw.feed_units_s == pytest.approx(30.0)
        tt.close()


def test_move_waits_for_scaled_motion_with_correct_deadline(tmp_path):
    with HorusFirmware(tmp_path / "tt", time_scale=0.5, accel_units_s2=200.0) as fw:
        tt = make_tt(fw, accel_deg_s2=200.0)
        tt.connect()
        tt.motor(True)
        t0 = time.monotonic()
        tt.move_to(30.0)
        elapsed = time.monotonic() - t0
        assert elapsed >= 0.5 * move_time_s(30.0, 100.0, 200.0) - 0.01  # the ok comes after the move
        assert fw.status_queries == 0  # the deadline was long enough: no status query needed
        assert fw.angle_deg == pytest.approx(30.0, abs=STEP)
        tt.close()


def test_underestimated_move_is_extended_by_status(tmp_path):
    # the driver believes in a much faster table than the firmware's: its deadline passes mid-move
    with HorusFirmware(tmp_path / "tt", time_scale=1.0, accel_units_s2=200.0) as fw:
        tt = make_tt(fw, speed_deg_s=100.0, accel_deg_s2=1e6, latency_s=0.0, margin_s=0.05, margin_frac=0.0)
        tt.connect()
        tt.motor(True)
        tt.move_to(40.0)  # real: 2 sqrt(40/200) = 0.89 s; driver's deadline 0.45 s
        assert fw.status_queries >= 1
        assert fw.angle_deg == pytest.approx(40.0, abs=STEP)
        assert tt.position_deg == pytest.approx(40.0, abs=STEP)
        tt.close()


def test_firmware_error_names_command(fw):
    tt = make_tt(fw, n_lasers=3)  # the board has only two lasers
    tt.connect()
    with pytest.raises(DeviceError, match=re.escape("'M71 T3'")) as ei:
        tt.laser(3, True)
    assert ei.value.text == "Invalid laser index (T1..T2)"
    tt.laser(1, True)  # the link stays usable
    assert fw.lasers == (True, False)
    tt.close()


def test_bad_arguments_are_rejected_before_sending(fw, tt):
    n = len(fw.received)
    with pytest.raises(ValueError, match="laser index"):
        tt.laser(0, True)
    with pytest.raises(ValueError, match="deg"):
        tt.move_to(float("nan"))
    with pytest.raises(ValueError, match="deg_s"):
        tt.set_speed(-1.0)
    assert len(fw.received) == n
    with pytest.raises(ValueError, match="steps_per_degree"):
        Turntable(tt.transport, steps_per_degree=0)


def test_alarm_surfaces_on_pending_move_and_reset_clears_it(fw, faults, tt):
    tt.motor(True)
    faults.alarm_on_move = "Hard limit"
    with pytest.raises(DeviceAlarm, match="ALARM:Hard limit") as ei:
        tt.move_to(20.0)
    assert ei.value.command.startswith("G1 X")
    assert "Hard limit" in tt.unsolicited
    assert fw.angle_deg == 0.0
    tt.connect()
    tt.motor(True)
    tt.move_to(20.0)
    assert fw.angle_deg == pytest.approx(20.0, abs=STEP)


def test_watchdog_message_is_logged_and_step_reasserts_lasers(fw, tt, caplog):
    tt.step(10.0, lasers=[1])
    assert fw.lasers == (True, False) and fw.motor_enabled
    fw.fire_laser_watchdog()
    assert wait_until(lambda: not fw.lasers[0])
    fw.release_motor()
    with caplog.at_level("INFO", logger="kogei.drivers.turntable"):
        tt.step(20.0)
    assert fw.lasers == (True, False) and fw.motor_enabled
    assert fw.angle_deg == pytest.approx(20.0, abs=STEP)
    assert "[MSG:Laser 1 off: watchdog]" in tt.unsolicited
    assert any("watchdog" in r.getMessage() for r in caplog.records)


def test_fault_dropped_ok_is_recovered_via_status(fw, faults, tt):
    tt.motor(True)
    faults.drop_replies = 1
    tt.move_to(15.0)
    assert fw.status_queries == 1
    assert tt.position_deg == pytest.approx(15.0, abs=STEP) and fw.angle_deg == pytest.approx(15.0, abs=STEP)
    assert any("ok lost" in r for r in tt.recoveries)
    faults.drop_replies = 1
    tt.laser(1, True)  # non-move: idle per status, resent (idempotent)
    assert fw.lasers == (True, False)
    assert fw.received.count("M71 T1") == 2


def test_fault_binary_garbage_is_stripped(fw, faults, tt):
    tt.motor(True)
    faults.garbage_replies = 3
    for a in (5.0, 10.0, 15.0):
        tt.move_to(a)
    assert fw.status_queries == 0
    assert fw.angle_deg == pytest.approx(15.0, abs=STEP)


def test_fault_printable_garbage_is_recovered_via_status(fw, faults, tt):
    tt.motor(True)
    faults.garbage = b"#~"
    faults.garbage_replies = 1
    tt.move_to(25.0)
    assert "#~ok" in tt.unsolicited and fw.status_queries == 1
    assert fw.angle_deg == pytest.approx(25.0, abs=STEP)


def test_fault_slow_replies_extend_the_deadline(fw, faults, tt):
    faults.reply_delay_s = 0.5  # longer than the driver's 0.35 s command deadline
    t0 = time.monotonic()
    tt.motor(True)
    assert time.monotonic() - t0 >= 0.5
    assert fw.motor_enabled and fw.received.count("M17") == 1  # extended, not resent
    assert fw.status_queries >= 1
    faults.reply_delay_s = 0.0


def test_fault_hung_device_times_out_clearly(fw, faults, tt):
    faults.mute = True
    t0 = time.monotonic()
    with pytest.raises(DeviceTimeout, match="no answer to the '\\?' status query"):
        tt.motor(True)
    assert time.monotonic() - t0 < 5.0
    faults.mute = False


def test_fault_device_reset_mid_run_is_recovered(fw, faults, tt):
    tt.step(30.0, lasers=[1, 2])
    faults.reset_on_command = 1
    tt.step(60.0)  # the M17 of this step meets the reset
    assert fw.resets == 2
    assert fw.angle_deg == pytest.approx(60.0, abs=STEP) and tt.position_deg == pytest.approx(60.0, abs=STEP)
    assert fw.lasers == (True, True) and fw.motor_enabled
    assert any("device reset" in r for r in tt.recoveries)
    faults.reset_on_command = 1
    tt.move_to(90.0)  # reset meets the move itself: re-expressed in the new firmware zero
    assert fw.angle_deg == pytest.approx(90.0, abs=STEP) and tt.position_deg == pytest.approx(90.0, abs=STEP)
    assert fw.motor_enabled and fw.lasers == (True, True)


def test_device_reset_can_be_reported_instead(fw, faults):
    tt = make_tt(fw, recover_resets=False)
    tt.connect()
    faults.reset_on_command = 1
    with pytest.raises(DeviceResetError, match="device reset"):
        tt.motor(True)
    tt.close()


def test_fault_unplug_mid_pass_then_reconnect(fw, faults, tmp_path):
    tt = make_tt(fw, tmp_path)
    tt.connect()
    old_dev = fw.link.device_path
    done = []
    faults.replug_after_s = 0.3
    for k in range(6):
        target = 15.0 * k
        if k == 3:
            faults.unplug_on_command = 1
        try:
            tt.step(target, lasers=[1])
        except TransportClosed as exc:
            assert fw.path in str(exc)
            tt.reconnect(timeout_s=10.0)
            tt.step(target)  # absolute, so repeating the interrupted step is safe
        done.append(tt.position_deg)
        assert fw.angle_deg == pytest.approx(target, abs=STEP)
    assert done == pytest.approx([15.0 * k for k in range(6)], abs=STEP)
    assert fw.lasers == (True, False) and fw.motor_enabled
    assert fw.link.device_path is not None and old_dev is not None
    log = (tmp_path / "wire.log").read_text()
    assert "port lost" in log and log.count("turntable > \\x18") == 2
    tt.close()


def test_close_on_exception_turns_lasers_off_and_releases_motor(fw):
    with pytest.raises(RuntimeError, match="boom"):
        with make_tt(fw) as tt:
            tt.step(45.0, lasers=[1, 2])
            assert fw.lasers == (True, True) and fw.motor_enabled
            raise RuntimeError("boom")
    assert fw.lasers == (False, False) and not fw.motor_enabled
    assert not tt.transport.is_open


def test_close_is_best_effort_when_the_port_is_gone(fw):
    tt = make_tt(fw)
    tt.connect()
    tt.step(10.0, lasers=[1])
    fw.unplug()
    tt.close()  # must not raise
    assert not tt.transport.is_open
    fw.replug()
    assert fw.lasers == (False, False)  # power was lost with the cable


def test_close_with_hung_device_does_not_raise(fw, faults):
    tt = make_tt(fw, margin_s=0.1, status_timeout_s=0.2)
    tt.connect()
    faults.mute = True
    t0 = time.monotonic()
    tt.close()
    assert time.monotonic() - t0 < 5.0 and not tt.transport.is_open
