"""Horus firmware emulator spoken to over a real pty with plain pyserial (no driver)."""

from __future__ import annotations

import math
import os
import time

import numpy as np
import pytest
import serial

from mocks.faults import Faults
from mocks.horus_firmware import BANNER, HorusFirmware, trapezoid_distance, trapezoid_time
from mocks.waiting import wait_until


class Port:
    def __init__(self, path):
        self.s = serial.serial_for_url(path, baudrate=115200, timeout=5.0)

    def cmd(self, line: str) -> list[str]:
        """Send a line, return every line up to and including the ok/error."""
        self.s.write(line.encode() + b"\r\n")
        out = []
        while True:
            ln = self.s.readline()
            assert ln.endswith(b"\n"), f"no reply to {line!r}: {out}"
            out.append(ln.decode("ascii", "replace").strip())
            if out[-1] == "ok" or out[-1].startswith("error:"):
                return out

    def status(self) -> str:
        self.s.write(b"?")
        return self.s.readline().decode().strip()

    def reset(self) -> str:
        self.s.reset_input_buffer()
        self.s.write(b"\x18")
        while True:
            ln = self.s.readline().decode().strip()
            if ln:
                return ln


@pytest.fixture
def fw(tmp_path):
    with HorusFirmware(tmp_path / "turntable", faults=Faults()) as f:
        yield f


@pytest.fixture
def port(fw):
    p = Port(fw.path)
    assert p.reset() == BANNER
    yield p
    p.s.close()


def _integrated_distance(T, v, a, n=200001):
    # independent reference: integrate the velocity profile min(a t, v, a (T - t))
    t = np.linspace(0.0, T, n)
    vel = np.minimum(np.minimum(a * t, v), a * (T - t))
    return float(np.sum((vel[1:] + vel[:-1]) * 0.5 * np.diff(t)))


@pytest.mark.parametrize("d,v,a", [(90.0, 30.0, 60.0), (1.0, 30.0, 4.0), (15.0, 30.0, 60.0), (360.0, 200.0, 50.0)])
def test_trapezoid_time_covers_the_distance(d, v, a):
    T = trapezoid_time(d, v, a)
    assert _integrated_distance(T, v, a) == pytest.approx(d, rel=1e-6)
    # distance(t) is the integral of the same profile at intermediate times
    for frac in (0.1, 0.5, 0.9):
        t = frac * T
        tt = np.linspace(0, t, 20001)
        vel = np.minimum(np.minimum(a * tt, v), a * (T - tt))
        ref = float(np.sum((vel[1:] + vel[:-1]) * 0.5 * np.diff(tt)))
        assert trapezoid_distance(t, d, v, a) == pytest.approx(ref, rel=1e-6, abs=1e-9)


def test_every_command_answered_once(port, fw):
    assert port.cmd("M17") == ["ok"] and fw.motor_enabled
    assert port.cmd("M71 T1") == ["ok"] and fw.lasers == (True, False)
    assert port.cmd("M71T2") == ["ok"] and fw.lasers == (True, True)
    assert port.cmd("M70 T1") == ["ok"] and fw.lasers == (False, True)
    assert port.cmd("G1 F50") == ["ok"] and fw.feed_units_s == 50
    assert port.cmd("G1 X90") == ["ok"]
    assert fw.angle_deg == pytest.approx(90.0) and port.status().startswith("<Idle|MPos:90.000")
    assert port.cmd("G50") == ["ok"] and fw.position_units == 0 and fw.angle_deg == pytest.approx(90.0)
    assert port.cmd("G1X-45") == ["ok"] and fw.angle_deg == pytest.approx(45.0)
    assert port.cmd("M18") == ["ok"] and not fw.motor_enabled
    assert port.cmd("M71 T3") == ["error: Invalid laser index (T1..T2)"]
    assert port.cmd("G28") == ["error: Unsupported command"]
    assert port.cmd("hello") == ["error: Invalid statement"]
    assert port.cmd("G1 Y3") == ["error: Unsupported axis (the turntable has only X)"]
    assert port.cmd("$$")[-1] == "ok"


def test_released_motor_counts_steps_but_table_stays(port, fw):
    assert port.cmd("M18") == ["ok"]
    assert port.cmd("G1 X30") == ["ok"]
    assert fw.position_units == pytest.approx(30.0, abs=0.2) and fw.angle_deg == 0.0


def test_moves_are_quantised_to_whole_steps(port, fw):
    port.cmd("M17")
    port.cmd("G1 X0.05")  # 0.444 steps -> 0 steps
    assert fw.angle_deg == 0.0
    port.cmd("G1 X0.1")   # 0.889 steps -> 1 step
    assert fw.angle_deg == pytest.approx(360.0 / 3200.0)


def test_scaled_motion_reports_run_then_idle(tmp_path):
    with HorusFirmware(tmp_path / "tt", time_scale=0.2, feed_units_s=100, accel_units_s2=200) as fw:
        p = Port(fw.path)
        p.reset()
        p.cmd("M17")
        t0 = time.monotonic()
        p.s.write(b"G1 X90\r\n")
        assert wait_until(lambda: fw.state == "Run")
        st = p.status()
        assert st.startswith("<Run|MPos:")
        assert p.s.readline().strip() == b"ok"
        elapsed = time.monotonic() - t0
        expected = 0.2 * trapezoid_time(90, 100, 200)  # 0.2 * 1.4 s
        assert elapsed >= expected - 0.01
        assert p.status().startswith("<Idle|MPos:90.000")
        p.s.close()


def test_laser_watchdog_scaled_and_rearmed_by_m71(tmp_path):
    with HorusFirmware(tmp_path / "tt", time_scale=0.01, laser_watchdog_s=40.0) as fw:  # 0.4 s real
        p = Port(fw.path)
        p.reset()
        p.cmd("M71 T1")
        time.sleep(0.25)
        p.cmd("M71 T1")  # re-arms
        t_rearm = time.monotonic()
        time.sleep(0.25)
        if time.monotonic() - t_rearm < 0.38:  # 0.5 s since first on, < 0.4 s since re-arm
            assert fw.lasers[0]
        assert wait_until(lambda: not fw.lasers[0], 3.0)
        assert p.s.readline().strip() == b"[MSG:Laser 1 off: watchdog]"
        p.s.close()


def test_fault_drop_garbage_and_delay(port, fw):
    fw.faults.drop_replies = 1
    port.s.write(b"M17\r\n")
    port.s.timeout = 0.3
    assert port.s.readline() == b""
    port.s.timeout = 5.0
    assert fw.motor_enabled  # executed, reply lost
    fw.faults.garbage_replies = 1
    port.s.write(b"M18\r\n")
    assert port.s.readline() == fw.faults.garbage + b"ok\r\n"
    assert not fw.motor_enabled
    fw.faults.reply_delay_s = 0.3
    t0 = time.monotonic()
    port.s.write(b"M17\r\n")
    assert wait_until(lambda: fw.state == "Run", 1.0)  # busy until the reply is out
    assert port.s.readline().strip() == b"ok"
    assert time.monotonic() - t0 >= 0.29


def test_fault_reset_on_command_sends_banner_and_forgets_state(port, fw):
    port.cmd("M17")
    port.cmd("M71 T1")
    port.cmd("G1 X10")
    fw.faults.reset_on_command = 1
    port.s.write(b"G1 X20\r\n")
    lines = [port.s.readline().strip() for _ in range(2)]
    assert lines == [b"", BANNER.encode()]
    assert fw.resets == 2 and fw.lasers == (False, False) and not fw.motor_enabled
    assert fw.position_units == 0 and fw.angle_deg == pytest.approx(10.0, abs=0.2)


def test_fault_alarm_locks_motion_until_unlock(port, fw):
    fw.faults.alarm_on_move = "Hard limit"
    assert port.cmd("G1 X5") == ["ALARM:Hard limit", "error: Alarm lock"]
    assert port.status().startswith("<Alarm|")
    assert port.cmd("G1 X5") == ["error: Alarm lock"]
    assert port.cmd("M70 T1") == ["ok"]  # non-motion commands still work
    assert port.cmd("$X")[-1] == "ok"
    assert port.cmd("G1 X5") == ["ok"]


def test_fault_unplug_and_replug_moves_symlink(tmp_path):
    faults = Faults(unplug_on_command=1, replug_after_s=0.1)
    with HorusFirmware(tmp_path / "tt", faults=faults) as fw:
        p = Port(fw.path)
        p.reset()
        old = os.path.realpath(fw.path)
        p.s.write(b"M17\r\n")
        with pytest.raises(serial.SerialException):
            p.s.readline()
            p.s.readline()
        p.s.close()
        assert wait_until(lambda: fw.state != "Unplugged", 5.0)
        new = os.path.realpath(fw.path)
        assert new.startswith("/dev/pts/")
        assert os.path.exists(fw.path) and (new == fw.link.device_path) and old.startswith("/dev/pts/")
        p2 = Port(fw.path)
        assert p2.reset() == BANNER
        p2.s.close()


def test_mute_device_answers_nothing(port, fw):
    fw.faults.mute = True
    port.s.timeout = 0.2
    port.s.write(b"?M17\r\n\x18")
    assert port.s.read(1) == b""
    fw.faults.mute = False


def test_silent_after_move_turns_the_table_but_says_nothing_until_reset(port, fw):
    assert port.cmd("M17") == ["ok"]
    fw.faults.silent_after_move = 1
    assert port.cmd("G1 X0") == ["ok"] and fw.faults.silent_after_move == 1     # no turn: not yet
    port.s.timeout = 0.3
    port.s.write(b"G1 X30\r\n")
    assert port.s.read(1) == b""                               # no ok
    assert wait_until(lambda: fw.angle_deg == pytest.approx(30.0, abs=0.1), timeout=5.0)
    port.s.write(b"?")
    assert port.s.read(1) == b""                               # no status either
    port.s.timeout = 5.0
    assert port.reset() == BANNER                              # a reset brings it back ...
    assert fw.position_units == 0 and fw.angle_deg == pytest.approx(30.0, abs=0.1)   # ... counting from 0 again
    assert port.cmd("M17") == ["ok"] and fw.faults.silent_after_move == 0


def test_bad_configuration_is_rejected(tmp_path):
    with pytest.raises(ValueError, match="time_scale"):
        HorusFirmware(tmp_path / "a", time_scale=-1)
    with pytest.raises(ValueError, match="steps_per_unit"):
        HorusFirmware(tmp_path / "b", steps_per_unit=math.nan)
