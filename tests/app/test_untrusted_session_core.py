"""A session folder is untrusted input: the session store's own files, its path helpers, the manifest
and journal schema, full and read-only disks, the lock message and the mode of atomically written files.

Every hostile session is built in ``tmp_path``; a sentinel file outside the session proves nothing
outside it is read, written or truncated."""

from __future__ import annotations

import errno
import json
import os
import stat
from pathlib import Path

import pytest

from app.cli import main
from app.session import (
    JOURNAL,
    LOCK,
    MANIFEST,
    SCHEMA_VERSION,
    Session,
    SessionError,
    SessionLockedError,
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


# ---------------------------------------------------------------------------- 2. manifest and journal schema
def _with_manifest(tmp_path: Path, **fields) -> Path:
    root = _new(tmp_path)
    m = json.loads((root / MANIFEST).read_text())
    m.update(fields)
    (root / MANIFEST).write_text(json.dumps(m))
    return root


@pytest.mark.parametrize("field,value,match", [
    ("version", 0, "version must be an integer"),
    ("version", -5, "version must be an integer"),
    ("version", True, "version must be an integer"),
    ("version", "1", "version must be an integer"),
    ("version", SCHEMA_VERSION + 1, "update kogei"),
    ("captures", "x", "captures must be an object"),
    ("captures", {"a": "x"}, "captures.a must be an object"),
    ("captures", {"a": {"file": 3}}, "captures.a.file must be a file name"),
    ("captures", {"a": {"file": "a", "bytes": -1}}, "captures.a.bytes must be"),
    ("object", [1, 2], "object must be an object"),
    ("devices", "x", "devices must be an object"),
    ("settings", None, "settings must be an object"),
    ("calibration", "cal.json", "calibration must be an object or null"),
    ("plan", [], "plan must be an object"),
    ("plan", {"passes": 1_000_000_000}, r"plan.passes must be an integer in 1..1000"),
    ("plan", {"passes": True}, r"plan.passes must be an integer"),
    ("plan", {"steps": 0}, r"plan.steps must be an integer in 1..100000"),
    ("plan", {"camera_angles_deg": list(range(5000))}, "plan.camera_angles_deg"),
    ("passes", {"1": 5}, "passes.1 must be an object"),
    ("passes", {"1": {"table_frame": "x"}}, "passes.1.table_frame must be a table frame number"),
    ("captures", {"a": {"file": "a", "table_frame": -1}}, "captures.a.table_frame must be"),
    ("history", {}, "history must be a list"),
    ("history", ["x"], r"history\[0\] must be an object"),
    ("status", "bogus", "status must be one of"),
    ("products", "x", "products must be an object"),
    # fields the window shows when the session is opened (each made the window fail before it was checked)
    ("object", {"name": 7}, "object.name must be a text"),
    ("plan", {"kind": "scan", "steps": None, "passes": 1}, "plan.steps must be an integer"),
    ("captures", {"a": {"file": "a", "pass": "x"}}, "captures.a.pass must be a pass number"),
    ("captures", {"a": {"file": "a", "angle_deg": [1]}}, "captures.a.angle_deg must be an angle"),
    ("captures", {"a": {"file": "a", "angle_deg": float("nan")}}, "captures.a.angle_deg must be an angle"),
    ("captures", {"a": {"file": "a", "kind": 3}}, "captures.a.kind must be a text"),
    ("camera_calibration", {"source": "x"}, "camera_calibration.source must be an object"),
    ("camera_calibration", {"source": {"frames_rejected": 3}}, "camera_calibration.source.frames_rejected"),
    ("camera_calibration", {"image_size": "x"}, r"camera_calibration.image_size must be \[width, height\]"),
    ("lamp_calibration", {"rms_mm": "x"}, "lamp_calibration.rms_mm must be a finite number"),
    # per-pass numbers that processing formats or compares (an older session's angle uncertainty, the share of
    # profiles that saw the object)
    ("passes", {"1": {"angle_uncertain_deg": "a lot"}},
     r"passes.1.angle_uncertain_deg must be an angle in degrees between 0 and 360, or null, got 'a lot'"),
    ("passes", {"1": {"angle_uncertain_deg": -3}}, "passes.1.angle_uncertain_deg must be an angle in degrees"),
    ("passes", {"1": {"angle_uncertain_deg": True}}, "passes.1.angle_uncertain_deg must be an angle in degrees"),
    ("passes", {"1": {"valid_share": "most"}}, "passes.1.valid_share must be a share between 0 and 1"),
    ("passes", {"1": {"valid_share": 1.5}}, "passes.1.valid_share must be a share between 0 and 1"),
])
@pytest.mark.parametrize("how", ["read", "open"])
def test_wrong_types_and_bounds_in_the_manifest_are_named(tmp_path, field, value, match, how):
    root = _with_manifest(tmp_path, **{field: value})
    with pytest.raises(SessionError, match=match) as err:
        Session.read(root) if how == "read" else Session.open(root)
    assert MANIFEST in _one_line(err.value)


def test_pass_numbers_are_checked_and_an_older_session_still_loads(tmp_path):
    (tmp_path / "old").mkdir()
    (tmp_path / "bad").mkdir()
    old = _with_manifest(tmp_path / "old", passes={"1": {"angle_uncertain_deg": 2.5, "valid_share": 0.0},
                                                   "2": {"angle_uncertain_deg": None, "valid_share": 1}})
    assert Session.read(old)["passes"]["1"]["angle_uncertain_deg"] == 2.5
    bad = _with_manifest(tmp_path / "bad", passes={"1": {"angle_uncertain_deg": 2.5},
                                                   "2": {"angle_uncertain_deg": "2"}})
    with pytest.raises(SessionError) as err:
        Session.read(bad)
    assert f"{MANIFEST}: passes.2.angle_uncertain_deg must be an angle in degrees" in _one_line(err.value)
    assert f"fix that field or restore {MANIFEST} from a backup" in str(err.value)


def test_kogei_report_on_a_wrong_typed_manifest_exits_2_with_one_line(tmp_path, capsys):
    root = _with_manifest(tmp_path, plan={"kind": "scan", "steps": 4, "passes": 1_000_000_000})
    assert main(["report", str(root)]) == 2
    err = capsys.readouterr().err.strip()
    assert "plan.passes" in err and len(err.splitlines()) == 1


def _append_journal(root: Path, *lines: bytes) -> None:
    with open(root / JOURNAL, "ab") as fh:
        fh.write(b"".join(line + b"\n" for line in lines))


GOOD_OP = json.dumps({"op": "state", "fields": {"x": 1}}).encode()


@pytest.mark.parametrize("line,match", [
    (b"[1, 2]", "the operation must be an object"),
    (b'{"op": "capture", "id": "b", "record": "x"}', "record of capture b must be an object"),
    (b'{"op": "capture", "id": 7, "record": {}}', "capture id must be a text"),
    (b'{"op": "nuke"}', "op must be one of"),
    (b'{"op": "pass", "pass": true, "fields": {}}', "pass must be an integer"),
    (b'{"op": "state", "fields": []}', "state fields must be an object"),
    (b'{"op": "set", "key": "captures", "value": {}}', "set key must be"),
    (b'{"op": "set", "key": "plan", "value": {"passes": 1000000000}}', "plan.passes"),
    (b'{"op": "status", "status": 3}', "status must be one of"),
    (b'{"op": "pass", "pass": 1, "fields": {"angle_uncertain_deg": "a lot"}}',
     "passes.1.angle_uncertain_deg must be an angle in degrees"),
])
def test_a_bad_journal_op_is_a_named_error_on_open_and_a_problem_on_read(tmp_path, line, match):
    root = _new(tmp_path)
    _append_journal(root, GOOD_OP, line, GOOD_OP)
    with pytest.raises(SessionError, match=match) as err:
        Session.open(root)
    assert "line 2 is corrupt" in _one_line(err.value)
    manifest, problems = Session.read_checked(root)
    assert manifest["state"]["x"] == 1 and len(problems) == 1
    assert "line 2 is corrupt" in problems[0] and "\n" not in problems[0]
    assert Session.problems(root) == problems


def test_a_bad_last_op_that_is_json_is_not_mistaken_for_a_torn_line(tmp_path):
    root = _new(tmp_path)
    _append_journal(root, GOOD_OP, b'{"op": "capture", "id": "b", "record": []}')
    assert len(Session.problems(root)) == 1
    with pytest.raises(SessionError, match="line 2 is corrupt"):
        Session.open(root)


def test_corrupt_middle_lines_are_listed_torn_last_line_is_not(tmp_path):
    root = _new(tmp_path)
    _append_journal(root, b"garbage", GOOD_OP, b"more garbage", GOOD_OP)
    with open(root / JOURNAL, "ab") as fh:
        fh.write(b'{"op":"capture","id":"b","rec')              # torn: the process died mid-append
    problems = Session.problems(root)
    assert [p.split(" is corrupt")[0] for p in problems] == ["session.journal line 1", "session.journal line 3"]
    assert Session.problems(_new(tmp_path, "clean")) == []


#: An array nested 100 000 deep: valid JSON that exhausts the parser's stack (``RecursionError``).
DEEP = b"[" * 100_000 + b"]" * 100_000


def test_a_manifest_nested_100000_deep_is_one_line_naming_it(tmp_path, capsys):
    root = _new(tmp_path)
    text = (root / MANIFEST).read_bytes()
    (root / MANIFEST).write_bytes(text.replace(b"{", b'{"zzz": ' + DEEP + b", ", 1))
    for load in (Session.read, Session.open):
        with pytest.raises(SessionError) as err:
            load(root)
        assert (f"{MANIFEST} is unreadable (arrays or objects nested too deeply to read); restore it from a backup"
                in _one_line(err.value))
    assert main(["report", str(root)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert f"{root / MANIFEST} is unreadable (arrays or objects nested too deeply" in err
    assert "restore it from a backup" in err


def test_a_journal_line_nested_100000_deep_is_one_line_naming_it(tmp_path, capsys):
    root = _new(tmp_path)
    _append_journal(root, GOOD_OP, b'{"zzz": ' + DEEP + b', "op": "state", "fields": {}}', GOOD_OP)
    with pytest.raises(SessionError) as err:
        Session.open(root)
    msg = _one_line(err.value)
    assert f"{JOURNAL}: line 2 is corrupt (not JSON (arrays or objects nested too deeply to read)" in msg
    assert "move the journal aside and resume" in msg
    manifest, problems = Session.read_checked(root)             # a viewer skips the line and says so
    assert manifest["state"]["x"] == 1 and len(problems) == 1
    assert problems[0].startswith(f"{JOURNAL} line 2 is corrupt (not JSON (arrays or objects nested too deeply")
    assert main(["process", str(root), "--no-project", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert f"{root / JOURNAL}: line 2 is corrupt" in err and "move the journal aside and resume" in err


def test_update_refuses_a_wrong_typed_value_before_journaling_it(tmp_path):
    root = _new(tmp_path)
    with Session.open(root) as s:
        with pytest.raises(SessionError, match="products must be an object"):
            s.update("products", "x")
    assert Session.problems(root) == [] and "products" not in Session.read(root)


# ---------------------------------------------------------------------------- 3. full disk, read-only filesystem
def _raising(code: int):
    def fail(*args, **kwargs):
        raise OSError(code, os.strerror(code))
    return fail


def _with_journaled_capture(tmp_path: Path) -> Path:
    """A session whose last capture is only in the journal (a capture killed before its checkpoint)."""
    root = _new(tmp_path)
    s = Session.open(root)
    info = s.write_file("passes/p01/b.bin", b"bbb")
    s.add_capture("p01/b", kind="note", file=info.path, sha256=info.sha256, bytes=info.bytes)
    s._journal.flush()
    s._release()
    return root


@pytest.mark.parametrize("code,todo", [(errno.ENOSPC, "disk is full: free space"),
                                       (errno.EDQUOT, "disk is full: free space"),
                                       (errno.EROFS, "read-only"), (errno.EACCES, "read-only")])
def test_open_on_a_full_or_read_only_disk_is_one_line_and_loses_nothing(tmp_path, monkeypatch, code, todo):
    root = _with_journaled_capture(tmp_path)
    manifest, journal = (root / MANIFEST).read_bytes(), (root / JOURNAL).read_bytes()
    monkeypatch.setattr("app.session.atomic_write_bytes", _raising(code))
    with pytest.raises(SessionError) as err:
        Session.open(root)
    msg = _one_line(err.value)
    assert f"cannot save {MANIFEST}" in msg and todo in msg and f"kogei capture --resume {root}" in msg
    assert (root / MANIFEST).read_bytes() == manifest and (root / JOURNAL).read_bytes() == journal
    monkeypatch.undo()
    with Session.open(root) as s:                   # the lock was released; nothing was lost
        assert s.is_done("p01/a") and s.is_done("p01/b")


@pytest.mark.parametrize("code", [errno.EROFS, errno.EACCES, errno.ENOSPC])
def test_lock_and_journal_open_failures_are_one_line(tmp_path, monkeypatch, code):
    root = _new(tmp_path)
    real_open = os.open

    def open_(path, flags, *args, **kwargs):
        if Path(path).name in (LOCK, JOURNAL) and flags & os.O_CREAT:
            raise OSError(code, os.strerror(code), str(path))
        return real_open(path, flags, *args, **kwargs)

    monkeypatch.setattr(os, "open", open_)
    with pytest.raises(SessionError, match=f"cannot open {LOCK} for writing") as err:
        Session.open(root)
    _one_line(err.value)
    monkeypatch.setattr("app.session._open_journal", _raising(code))
    monkeypatch.setattr(os, "open", real_open)
    with pytest.raises(SessionError, match=f"cannot open {JOURNAL} for writing"):
        Session.open(root)
    monkeypatch.undo()
    Session.open(root).close()                      # the lock was released


def test_close_on_the_error_path_keeps_the_first_message(tmp_path, monkeypatch):
    root = _new(tmp_path)
    with pytest.raises(SessionError, match="the first error"):
        with Session.open(root) as s:
            s.set_state(x=1)
            monkeypatch.setattr("app.session.atomic_write_bytes", _raising(errno.ENOSPC))
            raise SessionError("the first error")
    monkeypatch.undo()
    assert Session.read(root)["state"]["x"] == 1    # still in the journal
    s = Session.open(root)
    monkeypatch.setattr("app.session.atomic_write_bytes", _raising(errno.ENOSPC))
    with pytest.raises(SessionError, match="disk is full"):
        s.close()                                   # a plain close reports it in one line ...
    monkeypatch.undo()
    Session.open(root).close()                      # ... and released the lock all the same


def test_kogei_report_on_a_full_disk_exits_2_with_one_line(tmp_path, monkeypatch, capsys):
    root = _with_journaled_capture(tmp_path)
    manifest = (root / MANIFEST).read_bytes()
    monkeypatch.setattr("app.session.atomic_write_bytes", _raising(errno.ENOSPC))
    assert main(["report", str(root)]) == 2
    err = capsys.readouterr().err.strip()
    assert "free space" in err and len(err.splitlines()) == 1 and "Traceback" not in err
    assert (root / MANIFEST).read_bytes() == manifest
    monkeypatch.undo()
    assert Session.read(root)["captures"]["p01/b"]["bytes"] == 3


def test_read_only_copy_can_be_read_but_not_opened(tmp_path, capsys):
    root = _with_journaled_capture(tmp_path)
    files = [root, *root.rglob("*")]
    for p in files:
        p.chmod(p.stat().st_mode & ~0o222)
    try:
        if os.access(root / MANIFEST, os.W_OK) or os.access(root, os.W_OK):
            pytest.skip("running as root: chmod does not make the session read-only")
        assert Session.read(root)["captures"]["p01/b"]["bytes"] == 3
        with pytest.raises(SessionError, match="read-only") as err:
            Session.open(root)
        _one_line(err.value)
        assert main(["report", str(root)]) == 2
        assert len(capsys.readouterr().err.strip().splitlines()) == 1
    finally:
        for p in files:
            p.chmod(p.stat().st_mode | 0o200)


# ---------------------------------------------------------------------------- 4. the lock message
def test_lock_message_tells_a_cli_user_what_to_do(tmp_path, capsys):
    root = _new(tmp_path)
    with Session.open(root):
        with pytest.raises(SessionLockedError) as err:
            Session.open(root)
        msg = _one_line(err.value)
        assert "another process" in msg and "wait for it to finish or close it" in msg
        assert "--out FILE.html" in msg and "Session.read" not in msg
        assert main(["report", str(root)]) == 2
        cli = capsys.readouterr().err.strip()
        assert "wait for it" in cli and len(cli.splitlines()) == 1
        out = tmp_path / "r.html"
        assert main(["report", str(root), "--out", str(out)]) == 0 and out.is_file()


# ---------------------------------------------------------------------------- 5. atomically written files respect the umask
@pytest.fixture
def umask():
    old = os.umask(0o022)
    yield os.umask
    os.umask(old)


@pytest.mark.parametrize("mask,mode", [(0o022, 0o644), (0o027, 0o640), (0o002, 0o664)])
def test_atomic_writes_respect_the_umask(tmp_path, umask, mask, mode):
    from processing.common.files import atomic_path, atomic_write_json

    umask(mask)
    root = _new(tmp_path)
    with Session.open(root) as s:
        info = s.write_file("products/report.html", b"<html>")
        s.adopt_file(_plain(tmp_path / "frame.dng"), "passes/p01/raw/frame_00.dng")
    written = [root / MANIFEST, root / info.path, root / "passes/p01/raw/frame_00.dng",
               atomic_write_json(tmp_path / "cal" / "calibration.json", {"a": 1})]
    with atomic_path(tmp_path / "mesh.ply") as tmp:
        tmp.write_bytes(b"ply\n")
    written.append(tmp_path / "mesh.ply")
    for p in written:
        assert stat.S_IMODE(p.stat().st_mode) == mode, p


def _plain(path: Path) -> Path:
    path.write_bytes(b"II*\0raw")
    return path
