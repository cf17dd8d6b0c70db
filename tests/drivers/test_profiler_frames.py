"""KPRF frame layout, CRC and reply parsing of the profiler driver (no device).

Frames are built here with ``struct`` and ``zlib`` directly from the table in
``docs/protocols.md``, independently of both the driver and the emulator.
"""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.profiler import (
    INVALID,
    FrameError,
    decode_frame,
    frame_size,
    parse_reply,
    to_profile,
)
from drivers.transport import SerialTransport
from mocks.profiler_firmware import pack_frame


def build(seq: int, pts: list[tuple[int, int]], t_us: int = 123) -> bytes:
    payload = b"".join(struct.pack("<ii", x, z) for x, z in pts)
    body = b"KPRF" + struct.pack("<H", 1) + struct.pack("<I", len(payload)) + struct.pack("<I", seq) \
        + struct.pack("<Q", t_us) + struct.pack("<I", len(pts)) + payload
    return body + struct.pack("<I", zlib.crc32(body))


def test_crc32_is_ieee_8023():
    # the standard CRC-32 check value of "123456789"
    assert zlib.crc32(b"123456789") == 0xCBF43926


def test_decode_known_frame():
    f = build(42, [(-1500, 120000), (INVALID, INVALID), (2**31 - 1, 0)], t_us=987654321012)
    assert len(f) == 26 + 24 + 4
    raw = decode_frame(f)
    assert raw.seq == 42 and raw.timestamp_us == 987654321012
    p = to_profile(raw)
    assert p.valid.tolist() == [True, False, True]
    assert p.x_mm[0] == -1.5 and p.z_mm[0] == 120.0
    assert np.isnan(p.x_mm[1]) and np.isnan(p.z_mm[1])
    assert p.x_mm[2] == (2**31 - 1) / 1000.0


def test_emulator_packer_matches_the_spec_layout():
    assert pack_frame(7, 5, [1.0, 2.4], [3.0, -4.6], [True, True]) == build(7, [(1, 3), (2, -5)], t_us=5)
    assert pack_frame(8, 0, [1.0], [3.0], [False]) == build(8, [(INVALID, INVALID)], t_us=0)


def test_every_single_bit_flip_is_detected():
    f = build(3, [(10, 20), (30, 40)])
    for i in range(len(f)):
        for bit in range(8):
            bad = bytearray(f)
            bad[i] ^= 1 << bit
            with pytest.raises(FrameError):
                decode_frame(bytes(bad))


@pytest.mark.parametrize("length,n,msg", [(15, 2, "length 15"), (16, 3, "length 16"), (8 * 5000, 5000, "5000 >")])
def test_implausible_headers_are_false_matches(length, n, msg):
    head = struct.pack("<4sHIIQI", b"KPRF", 1, length, 0, 0, n)
    with pytest.raises(ValueError, match=msg):
        frame_size(head)


def test_wrong_version_is_a_false_match():
    with pytest.raises(ValueError, match="version 2"):
        frame_size(struct.pack("<4sHIIQI", b"KPRF", 2, 8, 0, 0, 1))


def test_truncated_frame():
    with pytest.raises(FrameError, match="header says"):
        decode_frame(build(1, [(1, 2)])[:-1] + b"\x00\x00")
    with pytest.raises(FrameError, match="shorter"):
        decode_frame(b"KPRF")


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.integers(INVALID + 1, 2**31 - 1), st.integers(INVALID + 1, 2**31 - 1)),
                max_size=50),
       st.integers(0, 2**32 - 1))
def test_round_trip_extremes(pts, seq):
    raw = decode_frame(build(seq, pts))
    assert raw.seq == seq
    assert raw.x_um.tolist() == [p[0] for p in pts] and raw.z_um.tolist() == [p[1] for p in pts]
    p = to_profile(raw)
    assert p.valid.all()
    np.testing.assert_array_equal(p.z_mm, np.array([q[1] for q in pts], float) / 1000.0)


def test_resync_through_garbage_and_false_magic_on_loopback():
    """read_frame skips noise and a false 'KPRF' whose length is implausible."""
    t = SerialTransport("loop://", wire_log=None)
    good = build(9, [(1000, 2000)])
    false = b"KPRF" + struct.pack("<HIIQI", 1, 13, 0, 0, 1)  # length not 8 * n
    t.write(b"\xf0\x00KP" + false + b"\x93KPR" + good)
    frame = t.read_frame(b"KPRF", 26, frame_size, 1.0)
    t.close()
    assert frame.data == good
    assert decode_frame(frame.data).seq == 9
    assert frame.skipped.endswith(b"\x93KPR") and frame.skipped.startswith(b"\xf0\x00KP")


@pytest.mark.parametrize("raw,expected", [
    (b"OK,ID,KP-200,SN9,1.3.0", ("OK", "ID", ["KP-200", "SN9", "1.3.0"])),
    (b"\xf0\x00\x93OK,TRG,17", ("OK", "TRG", ["17"])),
    (b"ER,RSND,03", ("ER", "RSND", ["03"])),
    (b"OK,STOP", ("OK", "STOP", [])),
    (b"PROFILER KP-200 2.0.1", ("banner", "KP-200", ["2.0.1"])),
])
def test_parse_reply(raw, expected):
    assert parse_reply(raw) == expected


def test_parse_reply_noise():
    assert parse_reply(b"\x01\x02garbage")[0] == "noise"
    assert parse_reply(b"ok")[0] == "noise"


class _ScriptedTransport:
    """A transport whose received lines are a script: the driver needs nothing else to run a command."""

    url = "script://profiler"
    baudrate = 115200
    is_open = True

    def __init__(self, lines):
        self.lines = list(lines)
        self.sent = []

    def write(self, data):
        self.sent.append(data)

    def read_line(self, deadline_s):
        from drivers.errors import TransportTimeout

        if not self.lines:
            raise TransportTimeout("no more scripted lines")
        return self.lines.pop(0)

    def reset_input(self):
        pass


def test_printable_noise_before_a_reply_is_ignored(caplog):
    from drivers.profiler import LaserProfiler

    t = _ScriptedTransport([b"hello from a confused sensor", b"OK,GET,EXP,500"])
    lp = LaserProfiler(t)
    with caplog.at_level("INFO", logger="kogei.drivers.profiler"):
        assert lp.get("EXP") == "500"
    assert t.sent == [b"GET,EXP\r\n"]
    assert any("ignored line" in r.getMessage() for r in caplog.records)
