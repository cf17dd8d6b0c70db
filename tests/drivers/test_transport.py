"""Serial transport: deadlines, framing, wire log, unplug/reopen over real ptys."""

from __future__ import annotations

import os
import re
import struct
import threading
import time
from types import SimpleNamespace

import pytest

from drivers import discovery
from drivers.errors import TransportClosed, TransportTimeout
from drivers.transport import SerialTransport, WireLog, escape_bytes
from mocks.pty_link import PtyLink


@pytest.fixture
def link(tmp_path):
    with PtyLink(tmp_path / "dev") as lk:
        yield lk


def _feed(link: PtyLink, data: bytes) -> None:
    os.write(link.master_fd, data)


def _read_master(link: PtyLink, n: int, timeout: float = 5.0) -> bytes:
    os.set_blocking(link.master_fd, True)
    end = time.monotonic() + timeout
    out = b""
    import select
    while len(out) < n and time.monotonic() < end:
        r, _, _ = select.select([link.master_fd], [], [], 0.1)
        if r:
            out += os.read(link.master_fd, n - len(out))
    os.set_blocking(link.master_fd, False)
    return out


def test_escape_bytes_hand_written():
    assert escape_bytes(b"G1 X9\r\n") == "G1 X9\\r\\n"
    assert escape_bytes(b"\x18\x00\xff\\\t") == "\\x18\\x00\\xff\\\\\\t"
    assert escape_bytes(b"") == ""


def test_loop_read_line_strips_crlf_and_keeps_rest():
    with SerialTransport("loop://") as t:
        t.write(b"ok\r\nerror: x\nrest")
        assert t.read_line(1.0) == b"ok"
        assert t.read_line(1.0) == b"error: x"
        with pytest.raises(TransportTimeout) as ei:
            t.read_line(0.1)
        assert ei.value.partial == b"rest"
        t.write(b"!\n")
        assert t.read_line(1.0) == b"rest!"


def test_read_line_deadline_is_respected():
    with SerialTransport("loop://", poll_s=0.02) as t:
        t0 = time.monotonic()
        with pytest.raises(TransportTimeout, match="loop://"):
            t.read_line(0.2)
        elapsed = time.monotonic() - t0
        assert 0.2 <= elapsed < 1.0


def test_garbage_without_newline_is_returned_at_max_len():
    with SerialTransport("loop://") as t:
        t.write(b"\xff" * 10)
        assert t.read_line(1.0, max_len=8) == b"\xff" * 8


def test_read_exact_and_timeout():
    with SerialTransport("loop://") as t:
        t.write(b"abcdef")
        assert t.read_exact(4, 1.0) == b"abcd"
        with pytest.raises(TransportTimeout, match="2 of 3"):
            t.read_exact(3, 0.1)
        with pytest.raises(ValueError):
            t.read_exact(-1, 0.1)


MAGIC = b"\xaa\x55"


def _frame(payload: bytes) -> bytes:
    return MAGIC + struct.pack("<H", len(payload)) + payload


def _size(header: bytes) -> int:
    (n,) = struct.unpack("<H", header[2:4])
    if n > 64:
        raise ValueError("implausible length")
    return 4 + n


def test_read_frame_resynchronises_on_garbage_and_false_magic():
    with SerialTransport("loop://") as t:
        garbage = b"\x01\x02" + MAGIC + b"\xff\xff"  # false magic with an impossible length
        t.write(garbage + _frame(b"hello") + _frame(b""))
        f = t.read_frame(MAGIC, 4, _size, 1.0)
        assert f.data == _frame(b"hello")
        assert f.skipped == garbage
        f2 = t.read_frame(MAGIC, 4, _size, 1.0)
        assert f2.data == _frame(b"") and f2.skipped == b""
        t.write(MAGIC + b"\x05")  # incomplete header
        with pytest.raises(TransportTimeout, match="no complete frame"):
            t.read_frame(MAGIC, 4, _size, 0.1)


def test_wire_log_records_both_directions_flushed(tmp_path):
    path = tmp_path / "session" / "wire.log"
    t = SerialTransport("loop://", wire_log=path, label="tt")
    t.write(b"G50\n")
    assert t.read_line(1.0) == b"G50"
    t.write(b"\x18")
    # read while the transport is still open: lines are flushed per record
    lines = path.read_text().splitlines()
    stamp = r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{6}Z"
    data = [ln for ln in lines if " # " not in ln]
    assert re.fullmatch(stamp + r" tt > G50\\n", data[0])
    assert re.fullmatch(stamp + r" tt < G50\\n", data[1])
    assert re.fullmatch(stamp + r" tt > \\x18", data[2])
    t.close()
    t.close_log()
    assert "closed" in path.read_text().splitlines()[-1]


def test_wire_log_unwritable_path_is_a_clear_error(tmp_path):
    (tmp_path / "f").write_text("")
    with pytest.raises(ValueError, match="wire_log"):
        WireLog(tmp_path / "f" / "wire.log")


def test_bad_arguments():
    with pytest.raises(ValueError, match="baudrate"):
        SerialTransport("loop://", baudrate=0)
    with pytest.raises(ValueError, match="url_or_path"):
        SerialTransport("")


def test_missing_port_names_the_path(tmp_path):
    missing = str(tmp_path / "nope")
    with pytest.raises(TransportClosed, match=re.escape(missing)):
        SerialTransport(missing)


def test_pty_round_trip_through_symlink(link):
    with SerialTransport(link.path) as t:
        t.write(b"?")
        assert _read_master(link, 1) == b"?"
        _feed(link, b"<Idle|MPos:0.000>\r\n")
        assert t.read_line(2.0) == b"<Idle|MPos:0.000>"


def test_unplug_raises_transport_closed_then_reopen_finds_new_pty(link):
    t = SerialTransport(link.path)
    old = link.device_path
    link.unplug()
    with pytest.raises(TransportClosed, match=re.escape(link.path)):
        t.read_line(2.0)
    assert not t.is_open
    with pytest.raises(TransportClosed):
        t.write(b"x")
    with pytest.raises(TransportClosed):
        t.reopen(timeout_s=0.0)
    threading.Timer(0.2, link.plug).start()
    t.reopen(timeout_s=5.0)
    assert link.device_path is not None and os.path.realpath(link.path) == link.device_path
    assert old is not None
    _feed(link, b"ok\r\n")
    assert t.read_line(2.0) == b"ok"
    t.close()


def test_format_ports_and_list_ports_conversion(monkeypatch):
    fake = [
        SimpleNamespace(device="/dev/ttyUSB1", vid=0x2341, pid=0x0043, serial_number="A1B2",
                        description="Arduino Uno"),
        SimpleNamespace(device="/dev/ttyS0", vid=None, pid=None, serial_number=None, description="n/a"),
        SimpleNamespace(device="/dev/ttyUSB0", vid=0x1A86, pid=0x7523, serial_number=None, description=""),
    ]
    monkeypatch.setattr(discovery._list_ports, "comports", lambda: fake)
    rows = discovery.list_ports()
    assert [r.device for r in rows] == ["/dev/ttyUSB0", "/dev/ttyUSB1"]
    assert rows[1].vid_pid == "2341:0043" and rows[1].serial_number == "A1B2"
    assert len(discovery.list_ports(include_non_usb=True)) == 3
    text = discovery.format_ports(rows).splitlines()
    assert text[0].split() == ["DEVICE", "VID:PID", "SERIAL", "DESCRIPTION"]
    assert text[2].split() == ["/dev/ttyUSB1", "2341:0043", "A1B2", "Arduino", "Uno"]
    assert text[1].split() == ["/dev/ttyUSB0", "1a86:7523", "-", "-"]
