"""HotFolderCamera: slow and partial writes, ordering, and moves that never lose a file."""

from __future__ import annotations

import errno
import os
import threading

import numpy as np
import pytest

import drivers.camera_hotfolder as hf
from drivers.camera_errors import CameraConfigError, CameraFileExistsError, CameraTimeoutError, CameraTransferError
from drivers.camera_hotfolder import HotFolderCamera, move_file_atomic, tiff_complete
from mocks.dng_writer import dng_bytes
from mocks.hotfolder_writer import write_in_chunks

DNG = dng_bytes(np.random.default_rng(0).integers(600, 16383, (64, 96)).astype(np.uint16), black_level=600,
                white_level=16383)


@pytest.fixture
def folders(tmp_path):
    hot, dest = tmp_path / "hot", tmp_path / "session"
    hot.mkdir()
    return hot, dest


def _writer(path, **kwargs):
    t = threading.Thread(target=write_in_chunks, args=(path, DNG), kwargs=kwargs, daemon=True)
    t.start()
    return t


def test_slow_write_is_taken_only_when_complete(folders):
    hot, dest = folders
    cam = HotFolderCamera(hot, dest, stable_s=0.3, timeout_s=10, poll_s=0.02)
    t = _writer(hot / "IMG_0001.DNG", chunks=6, interval_s=0.1)
    path = cam.wait_for_new("f000")
    t.join()
    assert path == dest / "f000.dng"
    assert path.read_bytes() == DNG                    # the whole file, never a prefix
    assert not list(hot.iterdir())


def test_partial_file_is_never_taken_nor_lost(folders):
    hot, dest = folders
    cam = HotFolderCamera(hot, dest, stable_s=0.2, timeout_s=1.0, poll_s=0.02)
    write_in_chunks(hot / "IMG_0001.DNG", DNG, chunks=4, interval_s=0, partial=True)
    size = (hot / "IMG_0001.DNG").stat().st_size
    assert 0 < size < len(DNG)
    with pytest.raises(CameraTimeoutError, match="IMG_0001.DNG.*incomplete RAW file"):
        cam.wait_for_new("f000")
    assert (hot / "IMG_0001.DNG").stat().st_size == size      # left in place
    assert not dest.exists() or not list(dest.iterdir())


def test_growing_file_times_out_with_a_clear_message(folders):
    hot, dest = folders
    cam = HotFolderCamera(hot, dest, stable_s=5.0, timeout_s=0.5, poll_s=0.02)
    (hot / "IMG_0001.NEF").write_bytes(b"abc")
    with pytest.raises(CameraTimeoutError, match="did not reach a stable size"):
        cam.wait_for_new("f000")
    assert (hot / "IMG_0001.NEF").exists()


def test_nothing_arrives(folders):
    hot, dest = folders
    cam = HotFolderCamera(hot, dest, stable_s=0.05, timeout_s=0.3, poll_s=0.02)
    (hot / "notes.txt").write_text("not a raw")
    with pytest.raises(CameraTimeoutError, match="no new RAW file"):
        cam.wait_for_new("f000")


def test_existing_files_are_ignored_and_order_is_kept(folders):
    hot, dest = folders
    (hot / "OLD.DNG").write_bytes(DNG)
    cam = HotFolderCamera(hot, dest, stable_s=0.05, timeout_s=5, poll_s=0.01)
    a, b = hot / "IMG_0001.DNG", hot / "IMG_0002.DNG"
    a.write_bytes(DNG[:-1] + b"A")
    os.utime(a, ns=(10**18, 10**18))
    b.write_bytes(DNG[:-1] + b"B")
    os.utime(b, ns=(2 * 10**18, 2 * 10**18))
    first = cam.wait_for_new("f000")
    second = cam.wait_for_new("f001")
    assert first.read_bytes()[-1:] == b"A" and second.read_bytes()[-1:] == b"B"
    assert sorted(p.name for p in hot.iterdir()) == ["OLD.DNG"]
    assert cam.pending() == []


def test_cross_filesystem_move_copies_then_removes(folders, monkeypatch):
    hot, dest = folders
    dest.mkdir()
    src = hot / "IMG_0001.DNG"
    src.write_bytes(DNG)
    real = os.replace
    calls = []

    def replace(a, b):
        calls.append((a, b))
        if len(calls) == 1:
            raise OSError(errno.EXDEV, "Invalid cross-device link")
        return real(a, b)

    monkeypatch.setattr(hf.os, "replace", replace)
    out = move_file_atomic(src, dest / "f.dng")
    assert out.read_bytes() == DNG and not src.exists()
    assert len(calls) == 2 and os.path.basename(calls[1][0]).startswith(".f.dng.")   # temp file renamed
    assert sorted(p.name for p in dest.iterdir()) == ["f.dng"]


def test_failed_copy_keeps_the_source(folders, monkeypatch):
    hot, dest = folders
    dest.mkdir()
    src = hot / "IMG_0001.DNG"
    src.write_bytes(DNG)

    def replace(a, b):
        raise OSError(errno.EXDEV, "Invalid cross-device link")

    def copy(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(hf.os, "replace", replace)
    monkeypatch.setattr(hf.shutil, "copyfileobj", copy)
    with pytest.raises(CameraTransferError, match="No space left.*stays in"):
        move_file_atomic(src, dest / "f.dng")
    assert src.read_bytes() == DNG
    assert not list(dest.iterdir())                     # no partial copy left


def test_real_other_filesystem_if_available(folders):
    """/dev/shm is a tmpfs on Linux: a real EXDEV move when it is writable."""
    import tempfile

    hot, dest = folders
    dest.mkdir()
    shm = tempfile.mkdtemp(dir="/dev/shm") if os.access("/dev/shm", os.W_OK) else tempfile.mkdtemp()
    try:
        src = os.path.join(shm, "IMG.DNG")
        with open(src, "wb") as fh:
            fh.write(DNG)
        out = move_file_atomic(src, dest / "f.dng")
        assert out.read_bytes() == DNG and not os.path.exists(src)
    finally:
        os.rmdir(shm)


def test_destination_exists(folders):
    hot, dest = folders
    dest.mkdir()
    (dest / "f000.dng").write_bytes(b"earlier")
    cam = HotFolderCamera(hot, dest, stable_s=0.05, timeout_s=5, poll_s=0.01)
    (hot / "IMG_0001.DNG").write_bytes(DNG)
    with pytest.raises(CameraFileExistsError, match="never overwritten"):
        cam.wait_for_new("f000")
    assert (dest / "f000.dng").read_bytes() == b"earlier"
    assert (hot / "IMG_0001.DNG").read_bytes() == DNG
    assert cam.wait_for_new("f001").read_bytes() == DNG       # taken under another name


def test_tiff_complete(tmp_path):
    full, cut, other = tmp_path / "a.dng", tmp_path / "b.dng", tmp_path / "c.cr3"
    full.write_bytes(DNG)
    cut.write_bytes(DNG[: len(DNG) - 100])
    other.write_bytes(b"\x00\x00\x00\x18ftypcrx ")
    assert tiff_complete(full) is True
    assert tiff_complete(cut) is False
    assert tiff_complete(other) is None
    (tmp_path / "d.dng").write_bytes(DNG[:6])
    assert tiff_complete(tmp_path / "d.dng") is None     # too short to be a TIFF header


@pytest.mark.parametrize("kwargs, words", [({"stable_s": 0}, "stable_s"), ({"timeout_s": -1}, "timeout_s"),
                                           ({"poll_s": float("inf")}, "poll_s"), ({"extensions": ()}, "extensions")])
def test_bad_configuration(folders, kwargs, words):
    hot, dest = folders
    with pytest.raises(CameraConfigError, match=words):
        HotFolderCamera(hot, dest, **kwargs)


def test_missing_folder(tmp_path):
    with pytest.raises(CameraConfigError, match="does not exist"):
        HotFolderCamera(tmp_path / "nope", tmp_path / "s")


def test_simulated_writer_end_to_end(folders):
    import rawpy

    from mocks.hotfolder_writer import HotFolderWriter
    from mocks.world import World

    hot, dest = folders
    cam = HotFolderCamera(hot, dest, stable_s=0.2, timeout_s=20, poll_s=0.02)
    writer = HotFolderWriter(hot, World.hawk(2_000, width=48, height=32, spectral_step=20.0))
    thread = writer.capture("chart", chunks=5, interval_s=0.05, background=True)
    path = cam.wait_for_new("chart_000")
    thread.join()
    with rawpy.imread(str(path)) as raw:
        assert raw.raw_image_visible.shape == (32, 48)
        assert raw.raw_pattern.tolist() == [[0, 1], [3, 2]]
    writer.capture("object", 30.0, chunks=3, interval_s=0.0, partial=True)
    with pytest.raises(CameraTimeoutError, match="IMG_0002.DNG.*incomplete"):
        _fresh_wait(hot, dest)
    assert (hot / "IMG_0002.DNG").exists()


def _fresh_wait(hot, dest):
    cam = HotFolderCamera(hot, dest, stable_s=0.1, timeout_s=0.6, poll_s=0.02, include_existing=True)
    return cam.wait_for_new("obj_000")
