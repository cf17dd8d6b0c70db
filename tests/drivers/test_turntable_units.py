"""Turntable driver: deadline arithmetic and line parsing (no device)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.errors import DeviceError
from drivers.turntable import (
    Reply,
    Status,
    format_number,
    move_deadline_s,
    move_time_s,
    parse_line,
    parse_status,
)


def _distance_covered(T, v, a, n=100001):
    t = np.linspace(0.0, T, n)
    vel = np.minimum(np.minimum(a * t, v), a * (T - t))
    return float(np.sum((vel[1:] + vel[:-1]) * 0.5 * np.diff(t)))


@settings(max_examples=40, deadline=None)
@given(d=st.floats(1e-3, 720.0), v=st.floats(1.0, 500.0), a=st.floats(1.0, 2000.0))
def test_move_time_integrates_to_the_distance(d, v, a):
    T = move_time_s(d, v, a)
    assert _distance_covered(T, v, a) == pytest.approx(d, rel=1e-4)
    assert move_time_s(-d, v, a) == T


def test_move_time_closed_forms():
    assert move_time_s(360.0, 90.0, 90.0) == pytest.approx(360 / 90 + 1.0)   # cruise reached
    assert move_time_s(1.0, 90.0, 1.0) == pytest.approx(2.0)                 # triangular
    d = 90.0 ** 2 / 90.0                                                     # exactly at the boundary
    assert move_time_s(d, 90.0, 90.0) == pytest.approx(2.0 * np.sqrt(d / 90.0))
    assert move_time_s(0.0, 1.0, 1.0) == 0.0


def test_move_time_rejects_bad_input():
    with pytest.raises(ValueError, match="speed_deg_s"):
        move_time_s(1.0, 0.0, 1.0)
    with pytest.raises(ValueError, match="distance_deg"):
        move_time_s(float("inf"), 1.0, 1.0)


def test_deadline_formula():
    t = 360 / 90 + 1.0
    assert move_deadline_s(360.0, 90.0, 90.0, latency_s=0.1, margin_s=0.5, margin_frac=0.2) == pytest.approx(
        0.1 + t + 0.5 + 0.2 * t)
    assert move_deadline_s(0.0, 90.0, 90.0, latency_s=0.1, margin_s=0.5) == pytest.approx(0.6)


@pytest.mark.parametrize("raw,expected", [
    (b"ok", Reply("ok", "ok")),
    (b"ok\r", Reply("ok", "ok")),
    (b"error: Unsupported command", Reply("error", "Unsupported command")),
    (b"error:Alarm lock", Reply("error", "Alarm lock")),
    (b"ALARM:Hard limit", Reply("alarm", "Hard limit")),
    (b"[MSG:Laser 1 off: watchdog]", Reply("feedback", "[MSG:Laser 1 off: watchdog]")),
    (b"<Idle|MPos:1.000>", Reply("status", "<Idle|MPos:1.000>")),
    (b"Horus 0.2 ['$' for help]", Reply("banner", "Horus 0.2 ['$' for help]")),
    (b"Grbl 0.9j ['$' for help]", Reply("banner", "Grbl 0.9j ['$' for help]")),
    (b"\xf0\x00\x93ok", Reply("ok", "ok")),
    (b"", Reply("empty", "")),
    (b"\xff\xfe", Reply("noise", "")),
    (b"okay", Reply("noise", "okay")),
    (b"zzok", Reply("noise", "zzok")),
])
def test_parse_line(raw, expected):
    assert parse_line(raw) == expected


@pytest.mark.parametrize("text,expected", [
    ("<Idle|MPos:90.000|FS:100,0>", Status("Idle", 90.0)),
    ("<Run|MPos:-12.5>", Status("Run", -12.5)),
    ("<Alarm|MPos:0.000>", Status("Alarm", 0.0)),
    ("<Idle,MPos:5.000,0.000,0.000,WPos:5.000,0.000,0.000>", Status("Idle", 5.0)),
    ("<Hold>", Status("Hold", None)),
])
def test_parse_status(text, expected):
    assert parse_status(text) == expected


def test_parse_status_rejects_non_status():
    with pytest.raises(ValueError, match="not a status line"):
        parse_status("ok")


def test_format_number_round_trips_steps():
    spu = 3200 / 360
    for steps in (0, 1, 7, 3199, -3200, 100000):
        assert round(float(format_number(steps / spu)) * spu) == steps
    assert format_number(-0.0000001) == "0"


def test_device_error_names_command_and_text():
    e = DeviceError("M71 T3", "Invalid laser index")
    assert e.command == "M71 T3" and "M71 T3" in str(e) and "Invalid laser index" in str(e)
