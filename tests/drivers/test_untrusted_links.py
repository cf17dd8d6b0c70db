"""Drivers never write through a symbolic link or into a FIFO, nor take a linked frame: nothing outside the session is touched."""

from __future__ import annotations

import os

import pytest

from drivers.transport import WireLog


@pytest.fixture
def outside(tmp_path):
    target = tmp_path / "outside" / "precious.txt"
    target.parent.mkdir()
    target.write_text("precious\n")
    return target, target.stat().st_mtime_ns


def _untouched(outside) -> None:
    target, mtime = outside
    assert target.read_text() == "precious\n" and target.stat().st_mtime_ns == mtime


def test_symlinked_log_is_refused(tmp_path, outside):
    log = tmp_path / "s" / "wire" / "turntable.log"
    log.parent.mkdir(parents=True)
    log.symlink_to(outside[0])
    with pytest.raises(ValueError, match="is a symbolic link"):
        WireLog(log)
    _untouched(outside)


def test_dangling_symlinked_log_creates_nothing(tmp_path):
    log = tmp_path / "s" / "wire" / "turntable.log"
    log.parent.mkdir(parents=True)
    log.symlink_to(tmp_path / "created-outside.log")
    with pytest.raises(ValueError, match="is a symbolic link"):
        WireLog(log)
    assert not (tmp_path / "created-outside.log").exists()


def test_symlinked_wire_folder_is_refused(tmp_path, outside):
    (tmp_path / "s").mkdir()
    (tmp_path / "s" / "wire").symlink_to(outside[0].parent, target_is_directory=True)
    with pytest.raises(ValueError, match="folder .* is a symbolic link"):
        WireLog(tmp_path / "s" / "wire" / "precious.txt")
    _untouched(outside)
    assert sorted(p.name for p in outside[0].parent.iterdir()) == ["precious.txt"]


def test_fifo_log_is_refused_without_blocking(tmp_path):
    log = tmp_path / "wire.log"
    os.mkfifo(log)
    with pytest.raises(ValueError, match="wire_log"):
        WireLog(log)


def test_plain_log_still_appends(tmp_path):
    log = tmp_path / "wire" / "x.log"
    with WireLog(log) as w:
        w.record("tt", ">", b"G0")
    with WireLog(log) as w:
        w.record("tt", "<", b"ok")
    assert len(log.read_text().splitlines()) == 2


def test_hot_folder_never_takes_a_symbolic_link(tmp_path, outside):
    import numpy as np

    from drivers.camera_errors import CameraTimeoutError
    from drivers.camera_hotfolder import HotFolderCamera, raw_format_problem
    from mocks.dng_writer import dng_bytes

    hot, dest = tmp_path / "hot", tmp_path / "dest"
    hot.mkdir()
    real = tmp_path / "outside" / "real.dng"
    real.write_bytes(dng_bytes(np.full((32, 48), 700, np.uint16), black_level=600, white_level=16383))
    cam = HotFolderCamera(hot, dest, stable_s=0.05, timeout_s=0.5, poll_s=0.01)
    (hot / "IMG_0001.DNG").symlink_to(real)
    with pytest.raises(CameraTimeoutError, match="no new RAW file"):
        cam.wait_for_new("f")
    assert real.exists() and (hot / "IMG_0001.DNG").is_symlink()
    assert "not a regular file" in raw_format_problem(hot / "IMG_0001.DNG")
