"""A session folder is untrusted input: the session store's own files, its path helpers, the manifest
and journal schema, full and read-only disks, the lock message and the mode of atomically written files.

Every hostile session is built in ``tmp_path``; a sentinel file outside the session proves nothing
outside it is read, written or truncated."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from app.cli import main
from app.session import (
    JOURNAL,
    LOCK,
    MANIFEST,
    Session,
    SessionError,
    check_regular_file,
    read_session_file,
    session_path,
)

SECRET = b"outside the session: must stay as it is\n"


def _new(tmp_path: Path, name: str = "s") -> Path:
    s = Session.create(tmp_path / name, plan={"kind": "scan", "steps": 4, "passes": 1},
                       object_info={"name": "tsuba"})
    info = s.write_file("passes/p01/a.bin", b"abc")
    s.add_capture("p01/a", kind="note", file=info.path, sha256=info.sha256, bytes=info.bytes)
    s.close()
    return tmp_path / name


def _sentinel(tmp_path: Path) -> tuple[Path, os.stat_result]:
    target = tmp_path / "outside.txt"
    target.write_bytes(SECRET)
    return target, target.stat()


def _untouched(target: Path, before: os.stat_result) -> None:
    assert target.read_bytes() == SECRET
    after = target.stat()
    assert (after.st_mtime_ns, after.st_size) == (before.st_mtime_ns, before.st_size)


def _one_line(exc: BaseException) -> str:
    text = str(exc)
    assert "\n" not in text and "Traceback" not in text
    return text


# ---------------------------------------------------------------------------- 1. the session's own files
@pytest.mark.parametrize("name", [JOURNAL, LOCK, MANIFEST])
@pytest.mark.parametrize("how", ["open", "read"])
def test_symlinked_own_file_is_refused_and_its_target_untouched(tmp_path, name, how):
    root = _new(tmp_path)
    target, before = _sentinel(tmp_path)
    (root / name).unlink()
    (root / name).symlink_to(target)
    if how == "read" and name == LOCK:
        Session.read(root)                      # a reader does not touch the lock file
    else:
        with pytest.raises(SessionError) as err:
            Session.open(root) if how == "open" else Session.read(root)
        msg = _one_line(err.value)
        assert f"{name} is a symbolic link" in msg and "plain files" in msg
    _untouched(target, before)


def test_kogei_report_refuses_a_symlinked_journal(tmp_path, capsys):
    root = _new(tmp_path)
    target, before = _sentinel(tmp_path)
    (root / JOURNAL).unlink()
    (root / JOURNAL).symlink_to(target)
    assert main(["report", str(root)]) == 2
    err = capsys.readouterr().err.strip()
    assert "session.journal is a symbolic link" in err and len(err.splitlines()) == 1
    _untouched(target, before)


@pytest.mark.parametrize("name", [JOURNAL, MANIFEST])
def test_own_file_that_is_a_fifo_or_folder_is_refused_without_blocking(tmp_path, name):
    root = _new(tmp_path)
    (root / name).unlink()
    os.mkfifo(root / name)
    with pytest.raises(SessionError, match="named pipe"):
        Session.read(root)
    (root / name).unlink()
    (root / name).mkdir()
    with pytest.raises(SessionError, match="a folder"):
        Session.open(root)


def test_session_root_itself_may_be_a_symlink(tmp_path):
    root = _new(tmp_path)
    link = tmp_path / "link"
    link.symlink_to(root)
    with Session.open(link) as s:
        assert s.is_done("p01/a")
    assert Session.read(link)["object"]["name"] == "tsuba"


def test_writing_through_a_symlinked_folder_is_refused(tmp_path):
    root = _new(tmp_path)
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    (root / "products").symlink_to(outside)
    with Session.open(root) as s, pytest.raises(SessionError, match="products is a symbolic link"):
        s.write_file("products/report.html", b"x")
    assert list(outside.iterdir()) == []


def test_a_capture_record_pointing_outside_is_not_held(tmp_path):
    root = _new(tmp_path)
    target, before = _sentinel(tmp_path)
    with Session.open(root) as s:
        for i, bad in enumerate((str(target), "../outside.txt")):
            s.add_capture(f"x{i}", file=bad, bytes=len(SECRET))
            assert not s.is_done(f"x{i}")
            assert "relative path inside the session" in s.verify_file(s.capture(f"x{i}"))
        (root / "link.bin").symlink_to(target)
        s.add_capture("x9", file="link.bin", bytes=len(SECRET))
        assert "symbolic link" in s.verify_file(s.capture("x9"))
    _untouched(target, before)


# ---------------------------------------------------------------------------- 1. the public helpers
@pytest.mark.parametrize("rel,match", [
    ("/etc/passwd", "relative path inside"),
    ("../x", "relative path inside"),
    ("a/../../x", "relative path inside"),
    ("a\0b", "NUL byte"),
    ("", "non-empty text"),
    (42, "non-empty text"),
    (None, "non-empty text"),
])
def test_session_path_refuses_escapes(tmp_path, rel, match):
    with pytest.raises(SessionError, match=match) as err:
        session_path(tmp_path, rel, "products.mesh.file")
    assert _one_line(err.value).startswith("products.mesh.file:")


def test_session_path_refuses_a_link_at_any_depth_but_accepts_missing_parts(tmp_path):
    (tmp_path / "a" / "b").mkdir(parents=True)
    assert session_path(tmp_path, "a/b/c/d.bin", "x") == tmp_path / "a/b/c/d.bin"
    (tmp_path / "a" / "b" / "c").symlink_to(tmp_path)
    with pytest.raises(SessionError, match="a/b/c is a symbolic link"):
        session_path(tmp_path, "a/b/c/d.bin", "x")
    (tmp_path / "f").symlink_to(tmp_path / "a")
    with pytest.raises(SessionError, match="f is a symbolic link"):
        session_path(tmp_path, "f", "x")


def test_check_regular_file_refuses_non_files_and_big_files(tmp_path):
    ok = tmp_path / "ok.bin"
    ok.write_bytes(b"12345")
    assert check_regular_file(ok, "x", 5) == ok
    with pytest.raises(SessionError, match="more than the 4"):
        check_regular_file(ok, "x", 4)
    with pytest.raises(SessionError, match="missing"):
        check_regular_file(tmp_path / "nope", "x")
    with pytest.raises(SessionError, match="a folder"):
        check_regular_file(tmp_path, "x")
    os.mkfifo(tmp_path / "fifo")
    with pytest.raises(SessionError, match="named pipe"):
        check_regular_file(tmp_path / "fifo", "x")
    with pytest.raises(SessionError, match="device file"):
        check_regular_file("/dev/null", "x")
    (tmp_path / "link").symlink_to(ok)
    with pytest.raises(SessionError, match="symbolic link"):
        check_regular_file(tmp_path / "link", "x")


def test_read_session_file_reads_plain_files_only(tmp_path):
    (tmp_path / "a.txt").write_bytes(b"hello")
    assert read_session_file(tmp_path, "a.txt", "x", 5) == b"hello"
    with pytest.raises(SessionError, match="more than"):
        read_session_file(tmp_path, "a.txt", "x", 4)
    os.mkfifo(tmp_path / "fifo")                            # opened without blocking, then refused
    with pytest.raises(SessionError, match="named pipe"):
        read_session_file(tmp_path, "fifo", "x", 100)
    (tmp_path / "l").symlink_to(tmp_path / "a.txt")
    with pytest.raises(SessionError, match="symbolic link"):
        read_session_file(tmp_path, "l", "x", 100)
    with pytest.raises(SessionError, match="relative path"):
        read_session_file(tmp_path, "/dev/zero", "x", 100)
