"""A session folder is untrusted input: ``kogei report`` and ``kogei batch`` against hostile sessions.

Each session is written by hand (``session.json`` is enough for what these
commands read) and made hostile: product, capture and calibration paths that
are absolute, contain ``..`` or cross a symlink to a sentinel file outside the
session; a FIFO and an oversized (sparse) file as products; a symlinked
``products/`` and ``batch.log``; a ``plan.passes`` of 1e9; wrong-typed
manifest fields; corrupt journal lines; a non-UTF-8 session path.  Every
command ends within a time limit, with exit 2 and one stderr line or with the
fault listed under "Problems found" (report) or as the session's failure
reason (batch); the sentinel's bytes and mtime never change and its bytes
(base64) never appear in the report.
"""

from __future__ import annotations

import base64
import contextlib
import hashlib
import json
import os
import signal
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from app.batch.runner import process_one
from app.batch.steps import BatchOptions
from app.cli import main
from app.session_paths import (
    UnsafeSessionPath,
    confined,
    confined_file,
    open_log_append,
    read_confined_bytes,
)
from processing.common.png import png_bytes
from tests.app.cli_checks import png_header

LIMIT_S = 20


@contextlib.contextmanager
def time_limit(seconds: float = LIMIT_S) -> Iterator[None]:
    """Fail (instead of hanging the test run) if the body takes longer than ``seconds``."""
    def expired(signum: int, frame: Any) -> None:
        raise TimeoutError(f"took more than {seconds} s (a FIFO read or an endless loop?)")

    old = signal.signal(signal.SIGALRM, expired)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def _png() -> bytes:
    import numpy as np

    img = np.zeros((4, 4, 3), np.uint8)
    img[1, 2] = (200, 17, 99)       # a recognisable secret
    return png_bytes(img)


class Sentinel:
    """A file outside the session whose bytes and mtime must never change nor leak."""

    def __init__(self, path: Path, data: bytes) -> None:
        self.path = path
        path.write_bytes(data)
        os.utime(path, ns=(1_000_000_000, 1_000_000_000))
        self.data = data
        self.stat = path.stat()

    def unchanged(self) -> bool:
        st = self.path.stat()
        return self.path.read_bytes() == self.data and st.st_mtime_ns == self.stat.st_mtime_ns

    def leaked_into(self, text: str) -> bool:
        return base64.b64encode(self.data).decode() in text


def _manifest(**fields: Any) -> dict[str, Any]:
    m = {"schema": "kogei.session", "version": 1, "created_utc": "2026-01-01T00:00:00.000000Z",
         "updated_utc": "2026-01-01T00:00:00.000000Z", "status": "complete", "object": {"name": "hostile"},
         "devices": {}, "settings": {}, "calibration": None, "plan": {"kind": "scan", "steps": 4, "passes": 1},
         "passes": {}, "state": {}, "captures": {}, "history": []}
    m.update(fields)
    return m


def _session(root: Path, **fields: Any) -> Path:
    root.mkdir(parents=True)
    (root / "session.json").write_text(json.dumps(_manifest(**fields)))
    return root


def _renders(file: str, sha: str | None = None) -> dict[str, Any]:
    rec = {"file": file} if sha is None else {"file": file, "sha256": sha}
    return {"renders": {"material": "gold", "size": [4, 4], "preset": "draft", "images": {"D65": rec}}}


@pytest.fixture
def sentinel(tmp_path: Path) -> Sentinel:
    (tmp_path / "outside").mkdir()
    return Sentinel(tmp_path / "outside" / "secret.png", _png())


def _report(root: Path, out: Path, capsys) -> tuple[int, str, str]:
    with time_limit():
        code = main(["report", str(root), "--out", str(out)])
    err = capsys.readouterr().err
    return code, out.read_text(encoding="utf-8") if out.exists() else "", err


def _problems(html: str) -> str:
    start = html.find("<section id='problems'>")
    assert start >= 0, "no 'Problems found' section"
    return html[start:html.index("</section>", start)]


# ---------------------------------------------------------------------------- the confinement module
def test_confined_refuses_escapes_and_symlinks(tmp_path):
    root = tmp_path / "s"
    (root / "products").mkdir(parents=True)
    (root / "products" / "ok.txt").write_bytes(b"ok")
    (root / "link").symlink_to(tmp_path)
    assert confined(root, "products/ok.txt", "f") == root / "products" / "ok.txt"
    assert confined(root, "products/new.txt", "f") == root / "products" / "new.txt"     # may not exist yet
    for bad in ("/etc/passwd", "../x", "products/../../x", "a\0b", "", None, 3, ["x"], "link/s/products/ok.txt"):
        with pytest.raises(UnsafeSessionPath, match="^products.mesh.file: "):
            confined(root, bad, "products.mesh.file")


def test_read_confined_bytes_refuses_fifo_dir_symlink_and_oversized(tmp_path):
    root = tmp_path / "s"
    root.mkdir()
    os.mkfifo(root / "fifo")
    (root / "dir").mkdir()
    (root / "big").write_bytes(b"x" * 11)
    (root / "ln").symlink_to(root / "big")
    with time_limit(5):
        for name, why in (("fifo", "is a FIFO"), ("dir", "is a folder"), ("big", "more than the 10"),
                          ("ln", "is a symlink")):
            with pytest.raises(UnsafeSessionPath, match=why):
                read_confined_bytes(root, name, "what", 10)
    with pytest.raises(FileNotFoundError):
        read_confined_bytes(root, "missing", "what", 10)
    with pytest.raises(UnsafeSessionPath, match="is a FIFO"):
        confined_file(root, "fifo", "what")
    assert read_confined_bytes(root, "big", "what", 11) == b"x" * 11


def test_open_log_append_refuses_a_symlinked_log(tmp_path, sentinel):
    root = tmp_path / "s"
    root.mkdir()
    (root / "batch.log").symlink_to(sentinel.path)
    with pytest.raises(UnsafeSessionPath, match="batch.log.*symlink"):
        open_log_append(root, "batch.log", "batch.log")
    assert sentinel.unchanged()
    (root / "batch.log").unlink()
    with open_log_append(root, "batch.log", "batch.log") as fh:
        fh.write("line\n")
    assert (root / "batch.log").read_text() == "line\n"


# ---------------------------------------------------------------------------- kogei report
@pytest.mark.parametrize("kind", ["absolute", "dotdot", "symlinked file", "symlinked folder"])
def test_report_never_embeds_a_product_outside_the_session(tmp_path, sentinel, capsys, kind):
    root = tmp_path / "s"
    if kind == "absolute":
        name = str(sentinel.path)
    elif kind == "dotdot":
        name = "products/../../outside/secret.png"
    elif kind == "symlinked file":
        name = "products/renders/D65.png"
    else:
        name = "products/renders/secret.png"
    _session(root, products=_renders(name))
    if kind == "symlinked file":
        (root / "products" / "renders").mkdir(parents=True)
        (root / name).symlink_to(sentinel.path)
    elif kind == "symlinked folder":
        (root / "products").mkdir()
        (root / "products" / "renders").symlink_to(sentinel.path.parent)
    code, html, err = _report(root, tmp_path / "r.html", capsys)
    assert code == 0, err
    assert not sentinel.leaked_into(html)
    assert "products.renders.images.D65.file" in _problems(html)
    assert sentinel.unchanged()


def test_report_of_a_fifo_or_an_oversized_product_ends_and_lists_it(tmp_path, capsys):
    root = _session(tmp_path / "s", products={**_renders("products/fifo.png"),
                                              "mesh": {"file": "products/huge.ply"},
                                              "process_report": {"file": "products/huge.json"}})
    (root / "products").mkdir()
    os.mkfifo(root / "products" / "fifo.png")
    with open(root / "products" / "huge.ply", "wb") as fh:      # sparse: no disk space used
        fh.truncate(600 * 1024 * 1024)
    with open(root / "products" / "huge.json", "wb") as fh:
        fh.truncate(100 * 1024 * 1024)
    code, html, err = _report(root, tmp_path / "r.html", capsys)
    assert code == 0, err
    problems = _problems(html)
    assert "fifo.png" in problems and "is a FIFO" in problems
    assert "huge.ply" in problems and "huge.json" in problems and "bytes, more than" in problems


@pytest.mark.parametrize("fields, text", [
    ({"captures": "x"}, "captures must be an object"),
    ({"object": ["a", "b"]}, "object must be an object"),
    ({"plan": {"kind": "scan", "passes": 1_000_000_000}}, "plan.passes must be an integer in 1..1000"),
    ({"history": {"not": "a list"}}, "history must be a list"),
    ({"products": [1, 2]}, "products must be an object"),
    ({"calibration": "cal.json"}, "calibration must be an object or null"),
    ({"captures": {"p01/profiles": "x"}}, "captures.p01/profiles must be an object"),
])
def test_report_refuses_wrong_types_and_huge_plan_passes(tmp_path, capsys, fields, text):
    # the manifest is checked against its schema on load: one line naming the field, exit 2, no endless loop
    root = _session(tmp_path / "s", **fields)
    code, html, err = _report(root, tmp_path / "r.html", capsys)
    assert code == 2 and err.count("\n") == 1 and text in err and "Traceback" not in err, err
    assert html == ""


def test_report_lists_a_calibration_outside_the_session(tmp_path, sentinel, capsys):
    root = _session(tmp_path / "s",
                    calibration={"path": str(sentinel.path), "sha256": hashlib.sha256(sentinel.data).hexdigest()})
    code, html, err = _report(root, tmp_path / "r.html", capsys)
    assert code == 0, err
    problems = _problems(html)
    assert "calibration.file" in problems and "must be a relative path" in problems
    assert sentinel.unchanged() and base64.b64encode(sentinel.data).decode() not in html


def test_report_lists_corrupt_journal_lines(tmp_path, capsys):
    root = _session(tmp_path / "s")
    good = json.dumps({"op": "event", "entry": {"utc": "2026-01-01T00:00:01.000000Z", "event": "note", "detail": "d"}})
    (root / "session.journal").write_text(f"{good}\nnot json at all\n[1, 2]\n{good}\n")
    code, html, err = _report(root, tmp_path / "r.html", capsys)
    assert code == 0, err
    problems = _problems(html)
    assert "session.journal line 2 is corrupt" in problems and "session.journal line 3 is corrupt" in problems


def test_report_of_a_damaged_journal_op_is_one_line(tmp_path, capsys):
    root = _session(tmp_path / "s")
    (root / "session.journal").write_text(json.dumps({"op": "pass", "pass": 1, "fields": "x"}) + "\n"
                                          + json.dumps({"op": "status", "status": "complete"}) + "\n")
    code, html, err = _report(root, tmp_path / "r.html", capsys)
    assert code == 0 and "Traceback" not in err, err
    assert "session.journal" in _problems(html)


def test_report_of_a_non_utf8_session_path(tmp_path, capsys):
    root = _session(tmp_path / os.fsdecode(b"s\xff\xfe"))
    code, html, err = _report(root, tmp_path / "r.html", capsys)
    assert code == 0, err
    assert "\\udcff" in html or "\\xff" in html


def test_report_refuses_a_symlinked_products_folder(tmp_path, sentinel, capsys):
    root = _session(tmp_path / "s")
    (root / "products").symlink_to(sentinel.path.parent)
    with time_limit():
        code = main(["report", str(root)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert "products" in err and "symlink" in err and "--out" in err
    assert sorted(p.name for p in sentinel.path.parent.iterdir()) == ["secret.png"]
    assert sentinel.unchanged()


# ---------------------------------------------------------------------------- kogei batch
def test_batch_refuses_one_session_given_twice(tmp_path, capsys):
    root = _session(tmp_path / "s")
    (tmp_path / "alias").symlink_to(root)
    for args in ([str(root), str(root) + "/"], [str(root), str(tmp_path / "alias")],
                 [str(root), str(tmp_path / "s" / ".." / "s")]):
        assert main(["batch", *args, "--quiet"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "same folder" in err
        assert repr(args[0]) in err and repr(args[1]) in err
    assert not (root / "batch.log").exists()


def test_batch_refuses_a_symlinked_batch_log(tmp_path, sentinel, capsys):
    root = _session(tmp_path / "s")
    (root / "batch.log").symlink_to(sentinel.path)
    with time_limit(60):
        code = main(["batch", str(root), "--steps", "report", "--quiet"])
    out, err = capsys.readouterr()
    assert code == 1 and err.count("\n") == 1
    assert "batch.log" in out and "symlink" in out
    assert sentinel.unchanged()
    assert not (root / "products").exists()


def _one(root: Path, steps: tuple[str, ...], **options: Any) -> Any:
    with time_limit():
        return process_one(str(root), steps, BatchOptions(preset="draft", render_size=(32, 24), **options))


def test_batch_report_step_refuses_a_symlinked_products_folder(tmp_path, sentinel):
    root = _session(tmp_path / "s")
    (root / "products").symlink_to(sentinel.path.parent)
    r = _one(root, ("report",))
    assert r.status == "failed" and "symlink" in r.reason, r
    assert sorted(p.name for p in sentinel.path.parent.iterdir()) == ["secret.png"]
    assert sentinel.unchanged()


def test_batch_report_step_never_embeds_a_product_outside(tmp_path, sentinel):
    root = _session(tmp_path / "s", products=_renders(str(sentinel.path)))
    r = _one(root, ("report",))
    assert r.status == "ok", r
    html = (root / "products" / "report.html").read_text()
    assert not sentinel.leaked_into(html) and "must be a relative path" in html
    assert sentinel.unchanged()


@pytest.mark.parametrize("name", ["ABS", "../outside/secret.png", "products/link.ply"])
def test_batch_render_step_refuses_a_mesh_outside(tmp_path, sentinel, name):
    name = str(sentinel.path) if name == "ABS" else name
    root = _session(tmp_path / "s", products={"mesh": {"file": name, "sha256": "0" * 64}})
    if name == "products/link.ply":
        (root / "products").mkdir()
        (root / name).symlink_to(sentinel.path)
    r = _one(root, ("render",))
    assert r.status == "failed" and "products.mesh.file" in r.reason, r
    assert sentinel.unchanged()


def test_batch_colour_step_refuses_a_chart_frame_outside_or_a_fifo(tmp_path, sentinel):
    root = _session(tmp_path / "s", captures={"p01/chart": {"kind": "chart", "status": "done",
                                                            "file": "../outside/secret.png", "sha256": "0"}})
    r = _one(root, ("colour",))
    assert r.status == "failed" and "captures.p01/chart.file" in r.reason, r
    root2 = _session(tmp_path / "s2", captures={"p01/chart": {"kind": "chart", "status": "done",
                                                              "file": "passes/p01/chart.dng", "sha256": "0"}})
    (root2 / "passes" / "p01").mkdir(parents=True)
    os.mkfifo(root2 / "passes" / "p01" / "chart.dng")
    r = _one(root2, ("colour",))
    assert r.status == "failed" and "is a FIFO" in r.reason, r
    assert sentinel.unchanged()


def test_batch_geometry_step_refuses_a_calibration_outside(tmp_path, sentinel):
    cal = {"path": str(sentinel.path), "sha256": hashlib.sha256(sentinel.data).hexdigest()}
    root = _session(tmp_path / "s", calibration=cal)
    r = _one(root, ("geometry",))
    assert r.status == "failed" and "calibration.path" in r.reason, r
    assert sentinel.unchanged()


def _calibrated(root: Path, **fields: Any) -> Path:
    """A hand-written session holding a valid (ideal) scanner calibration."""
    import numpy as np

    from processing.geometry.calibration import ScannerCalibration, ideal_sensor_to_room

    cal = ScannerCalibration(ideal_sensor_to_room(), 10.0, np.array([50.0, 0, 10]), 0.05, 0.2, 40, 4000, 9000,
                             0.04, 10.001, np.arange(2), np.array([0.05, 0.06]))
    blob = json.dumps(cal.to_dict()).encode()
    _session(root, calibration={"path": "calibration.json", "sha256": hashlib.sha256(blob).hexdigest()}, **fields)
    (root / "calibration.json").write_bytes(blob)
    return root


@pytest.mark.parametrize("passes", [1_000_000_000, "x", True, -3])
def test_batch_geometry_step_refuses_a_bad_plan_passes(tmp_path, passes):
    root = _calibrated(tmp_path / "s", plan={"kind": "scan", "steps": 4, "passes": passes})
    r = _one(root, ("geometry",))
    assert r.status == "failed" and "plan.passes" in r.reason, r


@pytest.mark.parametrize("kind", ["absolute", "fifo"])
def test_batch_geometry_step_refuses_profiles_outside_or_a_fifo(tmp_path, sentinel, kind):
    name = str(sentinel.path) if kind == "absolute" else "passes/p01/profiles.npz"
    root = _calibrated(tmp_path / "s", captures={"p01/profiles": {"kind": "profiles", "status": "done", "pass": 1,
                                                                  "file": name, "sha256": "0" * 64}})
    if kind == "fifo":
        (root / "passes" / "p01").mkdir(parents=True)
        os.mkfifo(root / name)
    r = _one(root, ("geometry",))
    assert r.status == "failed" and "captures.p01/profiles.file" in r.reason, r
    assert sentinel.unchanged()


def test_batch_geometry_step_refuses_a_symlinked_calibration(tmp_path, sentinel):
    cal = {"path": "calibration.json", "sha256": hashlib.sha256(sentinel.data).hexdigest()}
    root = _session(tmp_path / "s", calibration=cal)
    (root / "calibration.json").symlink_to(sentinel.path)
    r = _one(root, ("geometry",))
    assert r.status == "failed" and "symlink" in r.reason, r
    assert sentinel.unchanged()


@pytest.mark.parametrize("fields, field", [({"captures": "x"}, "captures must be an object"),
                                           ({"plan": [1]}, "plan must be an object"),
                                           ({"products": 3}, "products must be an object"),
                                           ({"captures": {"p01/chart": "x"}}, "captures.p01/chart must be an object")])
def test_batch_names_a_wrong_typed_manifest_field(tmp_path, fields, field):
    root = _session(tmp_path / "s", **fields)
    r = _one(root, ("geometry", "colour", "report"))
    assert r.status == "failed" and field in r.reason, r
    assert "Traceback" not in r.reason and not (root / "batch.log").exists()


def test_report_refuses_a_symlinked_report_file(tmp_path, sentinel, capsys):
    root = _session(tmp_path / "s")
    (root / "products").mkdir()
    (root / "products" / "report.html").symlink_to(sentinel.path)
    with time_limit():
        code = main(["report", str(root)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "symlink" in err
    assert (root / "products" / "report.html").is_symlink() and sentinel.unchanged()


def test_batch_refuses_a_calibration_source_with_a_symlinked_file(tmp_path, sentinel):
    cal = tmp_path / "cal"
    cal.mkdir()
    (cal / "calibration.json").symlink_to(sentinel.path)
    root = _session(tmp_path / "s")
    r = _one(root, ("geometry",), calibration=str(cal))
    assert r.status == "failed" and "--calibration" in r.reason and "symlink" in r.reason, r
    assert sentinel.unchanged()


def test_batch_of_a_non_utf8_session_path(tmp_path, capsys):
    root = _session(tmp_path / os.fsdecode(b"s\xff"))
    r = _one(root, ("report",))
    assert r.status == "ok", r
    assert (root / "products" / "report.html").is_file()


# ---------------------------------------------------------------------------- kogei process / calibrate
def _cli(args: list[str], capsys) -> tuple[int, str]:
    with time_limit():
        code = main(args)
    return code, capsys.readouterr().err


@pytest.mark.parametrize("fields, text", [
    ({"plan": {"kind": "scan", "steps": 4, "passes": 10 ** 9}}, "plan.passes"),
    ({"passes": {"1": "x"}}, "passes.1 must be an object"),
    ({"captures": {"p01/profile/000": 7}}, "captures.p01/profile/000 must be an object"),
    ({"captures": {"p01/profiles": {"kind": "profiles", "pass": 1, "file": "../outside/secret.png", "sha256": "0"}}},
     "captures.p01/profiles.file"),
    ({"passes": {"1": {"angle_uncertain_deg": "a lot"}}},
     "session.json: passes.1.angle_uncertain_deg must be an angle in degrees between 0 and 360, or null"),
])
def test_process_of_a_hostile_session_is_one_line(tmp_path, sentinel, capsys, fields, text):
    root = _calibrated(tmp_path / "s", **fields)
    code, err = _cli(["process", str(root), "--preset", "draft", "--quiet"], capsys)
    assert code == 2 and err.count("\n") == 1 and text in err, err
    assert sentinel.unchanged()


def test_calibrate_refuses_profiles_outside_the_session(tmp_path, sentinel, capsys):
    root = _session(tmp_path / "s", captures={"p01/profiles": {"kind": "profiles", "pass": 1, "status": "done",
                                                               "file": str(sentinel.path), "sha256": "0"}})
    code, err = _cli(["calibrate", str(root), "--sphere-radius", "25"], capsys)
    assert code == 2 and err.count("\n") == 1 and "captures.p01/profiles.file" in err, err
    assert sentinel.unchanged()


def test_report_of_a_decompression_bomb_costs_only_its_section(tmp_path, capsys):
    root = _session(tmp_path / "s", products={"materials": {
        "report": {"file": "products/materials.json"},
        "maps": {"p01/frame/00": {"file": "products/materials/map.png"}}}})
    (root / "products" / "materials").mkdir(parents=True)
    (root / "products" / "materials.json").write_text(json.dumps({"regions": [], "largest": None}))
    (root / "products" / "materials" / "map.png").write_bytes(png_header(40_000, 40_000))
    code, html, err = _report(root, tmp_path / "r.html", capsys)
    assert code == 0, err
    assert "Material map and confidences: the session" in _problems(html)
    assert "DecompressionBombError" in _problems(html)


def test_batch_refuses_a_symlinked_batch_lock(tmp_path, sentinel):
    root = _session(tmp_path / "s")
    (root / "batch.lock").symlink_to(sentinel.path)
    r = _one(root, ("report",))
    assert r.status == "failed" and "batch.lock is a symlink" in r.reason, r
    assert sentinel.unchanged() and not (root / "batch.log").exists()


# ---------------------------------------------------------------------------- JSON nested too deeply
#: A JSON document whose arrays nest 100 000 deep: it exhausts the parser's stack (``RecursionError``).
DEEP = b'{"zzz": ' + b"[" * 100_000 + b"]" * 100_000 + b', "schema": "kogei.object_materials", "version": 1}'


def _deep_json_session(root: Path, key: str, rel: str) -> Path:
    """A session whose ``key`` (a product, or the calibration) is :data:`DEEP`, its checksum made to match."""
    sha = hashlib.sha256(DEEP).hexdigest()
    fields = {"calibration": {"path": rel, "sha256": sha}} if key == "calibration" else \
        {"products": {key: {"file": rel, "sha256": sha, "bytes": len(DEEP)}}}
    _session(root, **fields)
    (root / rel).parent.mkdir(parents=True, exist_ok=True)
    (root / rel).write_bytes(DEEP)
    return root


def test_export_of_object_materials_nested_100000_deep_is_one_line(tmp_path, capsys):
    root = _deep_json_session(tmp_path / "s", "object_materials", "products/object-materials.json")
    code, err = _cli(["export", str(root), "--gltf", str(tmp_path / "o.glb")], capsys)
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err, err
    assert (f"{root / 'products' / 'object-materials.json'} is not JSON kogei can read (arrays or objects nested too "
            f"deeply to read); run kogei fit-materials {root} again") in err
    assert not (tmp_path / "o.glb").exists()


@pytest.mark.parametrize("key, rel", [("object_materials", "products/object-materials.json"),
                                      ("process_report", "products/process-report.json"),
                                      ("calibration", "calibration.json")])
def test_report_lists_a_json_file_nested_100000_deep(tmp_path, capsys, key, rel):
    root = _deep_json_session(tmp_path / "s", key, rel)
    code, html, err = _report(root, tmp_path / "r.html", capsys)
    assert code == 0 and "Traceback" not in err, err
    assert (f"{rel} is not JSON kogei can read (arrays or objects nested too deeply to read); it is not shown; "
            "write it again with the step that made it") in _problems(html)
