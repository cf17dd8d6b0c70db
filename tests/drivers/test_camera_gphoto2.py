"""Gphoto2Camera against the fake gphoto2 executable (real subprocesses) and hand-written stand-ins."""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import rawpy

from drivers.camera_errors import (
    CameraBusyError,
    CameraCommandError,
    CameraConfigError,
    CameraError,
    CameraFileExistsError,
    CameraNotFoundError,
    CameraOutputMissingError,
    CameraTimeoutError,
)
from drivers.camera_gphoto2 import Gphoto2Camera, classify_gphoto2_error, parse_saved_files
from mocks.dng_writer import dng_bytes
from mocks.fake_gphoto2 import install, update_config, write_config

WORLD = {"mesh": "hawk:2000", "width": 48, "height": 32, "spectral_step": 20.0}


@pytest.fixture
def fake(tmp_path):
    config = write_config(tmp_path / "cam.json", WORLD)
    shim = install(tmp_path / "bin", config)
    return shim, config, tmp_path / "session"


def _script(tmp_path: Path, body: str) -> Path:
    """A stand-in gphoto2 written in Python (shebang of this interpreter)."""
    path = tmp_path / "gphoto2-standin"
    path.write_text(f"#!{sys.executable}\nimport sys, os\n{body}\n")
    path.chmod(0o755)
    return path


def test_capture_downloads_and_moves_the_raw(fake):
    shim, config, session = fake
    cam = Gphoto2Camera(session, executable=shim, filename_pattern="shot-%n.%C", timeout_s=60)
    first = cam.capture("chart_000")
    second = cam.capture("pass1_step000")
    assert first == session / "chart_000.dng" and second == session / "pass1_step000.dng"
    assert sorted(p.name for p in session.iterdir()) == ["chart_000.dng", "pass1_step000.dng"]  # no work folders
    with rawpy.imread(str(first)) as raw:
        chart = raw.raw_image_visible.copy()
        assert raw.raw_image_visible.shape == (32, 48)
        assert raw.white_level == 16383
    with rawpy.imread(str(second)) as raw:
        obj = raw.raw_image_visible.copy()
    assert not np.array_equal(chart, obj)          # the chart frame first, then the object


def test_no_camera(fake):
    shim, config, session = fake
    update_config(config, faults={"no_camera": True})
    with pytest.raises(CameraNotFoundError) as info:
        Gphoto2Camera(session, executable=shim, timeout_s=30).capture("x")
    msg = str(info.value)
    assert "no camera found" in msg and str(shim) in msg and "--auto-detect" in msg
    assert info.value.executable == str(shim)
    assert not any(session.iterdir())


def test_busy_then_free(fake):
    shim, config, session = fake
    update_config(config, faults={"busy": 2, "no_output": True})
    cam = Gphoto2Camera(session, executable=shim, timeout_s=60)
    for _ in range(2):
        with pytest.raises(CameraBusyError, match="busy or claimed") as info:
            cam.capture("x")
        assert "Could not claim the USB device" in info.value.stderr
    # the camera is free again: the third attempt gets past the claim (and hits the no-output switch)
    with pytest.raises(CameraOutputMissingError):
        cam.capture("x")


def test_timeout_kills_the_process(fake):
    shim, config, session = fake
    update_config(config, faults={"slow_s": 30})
    cam = Gphoto2Camera(session, executable=shim, timeout_s=1.0)
    t0 = time.monotonic()
    with pytest.raises(CameraTimeoutError, match="did not finish the capture within 1 s"):
        cam.capture("x")
    assert time.monotonic() - t0 < 10
    assert not any(session.iterdir())


def test_nonzero_exit(fake):
    shim, config, session = fake
    update_config(config, faults={"exit_code": 3})
    with pytest.raises(CameraCommandError) as info:
        Gphoto2Camera(session, executable=shim, timeout_s=30).capture("x")
    assert info.value.returncode == 3
    assert "status 3" in str(info.value) and "Unspecified error" in str(info.value)


def test_success_without_file(fake):
    shim, config, session = fake
    update_config(config, faults={"no_output": True})
    with pytest.raises(CameraOutputMissingError, match="no RAW file"):
        Gphoto2Camera(session, executable=shim, timeout_s=30).capture("x")


def test_saturation_fault_clips(fake):
    shim, config, session = fake
    update_config(config, faults={"saturate": True})
    path = Gphoto2Camera(session, executable=shim, timeout_s=60).capture("x")
    with rawpy.imread(str(path)) as raw:
        assert (raw.raw_image_visible == 16383).mean() > 0.2


def test_jpeg_only_download(tmp_path):
    exe = _script(tmp_path, "open('DSC_0001.JPG', 'wb').write(b'jpeg'); print('Saving file as DSC_0001.JPG')")
    with pytest.raises(CameraOutputMissingError, match="DSC_0001.JPG.*image quality to RAW"):
        Gphoto2Camera(tmp_path / "s", executable=exe, timeout_s=30).capture("x")


def test_raw_plus_jpeg_takes_the_raw(tmp_path):
    exe = _script(tmp_path, "open('DSC_0001.NEF', 'wb').write(b'nef'); open('DSC_0001.JPG', 'wb').write(b'j')")
    path = Gphoto2Camera(tmp_path / "s", executable=exe, timeout_s=30).capture("x")
    assert path.name == "x.nef" and path.read_bytes() == b"nef"
    assert sorted(p.name for p in (tmp_path / "s").iterdir()) == ["x.nef"]


def test_two_raws_is_ambiguous(tmp_path):
    exe = _script(tmp_path, "open('a.nef', 'wb').write(b'1'); open('b.nef', 'wb').write(b'2')")
    with pytest.raises(CameraOutputMissingError, match="several RAW files"):
        Gphoto2Camera(tmp_path / "s", executable=exe, timeout_s=30).capture("x")


def test_truncated_raw_is_refused(tmp_path):
    data = dng_bytes(np.full((32, 48), 700, np.uint16), black_level=600, white_level=16383)
    cut = tmp_path / "cut.dng"
    cut.write_bytes(data[: len(data) // 2])
    exe = _script(tmp_path, f"import shutil; shutil.copy({str(cut)!r}, 'DSC_0002.dng')")
    with pytest.raises(CameraOutputMissingError, match="empty or truncated"):
        Gphoto2Camera(tmp_path / "s2", executable=exe, timeout_s=30).capture("x")


def test_destination_is_never_overwritten(tmp_path):
    exe = _script(tmp_path, "open('DSC_0001.NEF', 'wb').write(os.urandom(64))")
    session = tmp_path / "s"
    cam = Gphoto2Camera(session, executable=exe, timeout_s=30)
    first = cam.capture("x")
    before = first.read_bytes()
    with pytest.raises(CameraFileExistsError, match="never overwritten"):
        cam.capture("x")
    assert first.read_bytes() == before
    kept = [p for p in session.iterdir() if p.name.startswith(".gphoto2-")]
    assert len(kept) == 1 and [f.suffix for f in kept[0].iterdir()] == [".NEF"]   # the new frame is kept


def test_missing_executable(tmp_path):
    with pytest.raises(CameraConfigError, match="not found on PATH"):
        Gphoto2Camera(tmp_path, executable="gphoto2-does-not-exist-here").capture("x")
    with pytest.raises(CameraConfigError, match="does not exist"):
        Gphoto2Camera(tmp_path, executable=tmp_path / "nope" / "gphoto2").capture("x")
    plain = tmp_path / "gphoto2"
    plain.write_text("not a program")
    with pytest.raises(CameraConfigError, match="not executable"):
        Gphoto2Camera(tmp_path, executable=plain).capture("x")


@pytest.mark.parametrize("name", ["", "../x", "a/b", ".hidden", ".."])
def test_bad_capture_name(tmp_path, name):
    with pytest.raises(CameraConfigError, match="plain file stem"):
        Gphoto2Camera(tmp_path, executable=sys.executable).capture(name)


@pytest.mark.parametrize("kwargs", [{"timeout_s": 0}, {"timeout_s": -1}, {"filename_pattern": "a/%f.%C"},
                                    {"filename_pattern": ""}, {"extensions": ()}, {"executable": ""}])
def test_bad_configuration(tmp_path, kwargs):
    with pytest.raises(CameraConfigError):
        Gphoto2Camera(tmp_path, **kwargs)


def test_all_errors_are_camera_errors():
    for cls in (CameraBusyError, CameraCommandError, CameraConfigError, CameraNotFoundError,
                CameraOutputMissingError, CameraTimeoutError, CameraFileExistsError):
        assert issubclass(cls, CameraError)


@pytest.mark.parametrize(
    "text, kind",
    [
        ("\n*** Error: No camera found. ***\n", "no_camera"),
        ("*** Error (-53: 'Could not claim the USB device') ***", "busy"),
        ("*** Error (-110: 'I/O in progress') ***", "busy"),
        ("An error occurred in the io-library ('Could not claim the USB device'): Device or resource busy", "busy"),
        ("*** Error (-1: 'Unspecified error') ***", None),
        ("", None),
    ],
)
def test_classify(text, kind):
    assert classify_gphoto2_error(text) == kind


def test_parse_saved_files():
    out = ("New file is in location /capt0000.nef on the camera\nSaving file as DSC_0001.nef\n"
           "Deleting file /capt0000.nef on the camera\n")
    assert parse_saved_files(out) == ["DSC_0001.nef"]


def test_extra_args_precede_the_command(tmp_path):
    cam = Gphoto2Camera(tmp_path, extra_args=["--port", "usb:001,004"])
    assert cam.command()[1:4] == ["--port", "usb:001,004", "--capture-image-and-download"]
    assert os.path.basename(cam.command()[0]) == "gphoto2"


def test_relative_executable_path_works(fake, tmp_path, monkeypatch):
    """A relative program path is taken from the caller's folder, not the capture's working folder."""
    shim, _, session = fake
    monkeypatch.chdir(tmp_path)
    cam = Gphoto2Camera(session, executable="./bin/gphoto2", timeout_s=60)
    assert cam._resolve_executable() == str(shim.resolve())
    frame = cam.capture("f1")
    assert frame.name == "f1.dng" and frame.stat().st_size > 1000
