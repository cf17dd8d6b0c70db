"""Output paths of every command: checked before the work (one line, exit 2, nothing written), and a write that
fails anyway (the folder removed meanwhile) ends as one line naming the option, the file and the reason."""

from __future__ import annotations

import errno

import pytest

from app.cli import main
from app.cli.outputs import OutputPathError, check_output_file, check_output_folder, writing
from tests.app.cli_checks import fails_with_one_line


@pytest.fixture
def place(tmp_path):
    for folder in ("dir.dng", "d.exr", "m.ply"):
        (tmp_path / folder).mkdir()
    (tmp_path / "a.xyz").write_text("0 0 0\n1 0 0\n0 1 0\n")
    return tmp_path


def test_check_output_file(place):
    assert check_output_file(place / "new.json", "--json") == place / "new.json"
    assert check_output_file(place / "n" / "m" / "x.png", "--out", make_parents=True).name == "x.png"
    cases = [
        (place / "dir.dng", {}, "--json {p}: is a folder; give a file name"),
        (place / "a.xyz" / "p.json", {}, "{a} is a file, not a folder; give a path in a folder"),
        (place / "a.xyz" / "deep" / "p.json", {"make_parents": True}, "{a} is a file, not a folder"),
        (place / "nowhere" / "p.json", {}, "the folder {n} does not exist; create it first"),
        ("/proc/self/foo.json", {}, "cannot write in the folder /proc/self ("),
        (place / "p.txt", {"suffixes": (".json",)}, "must end in .json"),
    ]
    for path, kw, needle in cases:
        with pytest.raises(OutputPathError) as info:
            check_output_file(path, "--json", **kw)
        assert needle.format(p=path, a=place / "a.xyz", n=place / "nowhere") in str(info.value), str(info.value)
    assert sorted(p.name for p in place.iterdir()) == ["a.xyz", "d.exr", "dir.dng", "m.ply"]      # the write check leaves nothing


def test_check_output_folder(place):
    assert check_output_folder(place / "new" / "fit", "--out") == place / "new" / "fit"
    with pytest.raises(OutputPathError, match="is a file, not a folder; give a folder"):
        check_output_folder(place / "a.xyz", "--out")
    with pytest.raises(OutputPathError, match="a.xyz is a file, not a folder"):
        check_output_folder(place / "a.xyz" / "fit", "--out")


def test_writing_turns_only_os_errors_into_one_line(place):
    with pytest.raises(OutputPathError, match=r"^--out .*x\.png: cannot be written \(No space left on device\); "
                                              "check the folder exists, is writable and has space$"):
        with writing(place / "x.png", "--out"):
            raise OSError(errno.ENOSPC, "No space left on device")
    with pytest.raises(KeyError):
        with writing(place / "x.png", "--out"):
            raise KeyError("not an OSError: not turned")


@pytest.mark.parametrize(("argv", "needles"), [
    (["chart", "{d}/none.dng", "--json", "{d}/dir.dng"], ["--json", "dir.dng: is a folder"]),
    (["chart", "{d}/none.dng", "--json", "/proc/self/foo.json"], ["--json /proc/self/foo.json", "cannot write"]),
    (["probe", "{d}/none.dng", "--sphere-radius", "20", "--out", "{d}/d.exr"], ["--out", "is a folder"]),
    (["probe", "{d}/none.dng", "--sphere-radius", "20", "--out", "{d}/a.xyz/o.exr"], ["a.xyz is a file, not a folder"]),
    (["render", "{d}/none.ply", "--out", "{d}/a.xyz/x.png"], ["--out", "a.xyz is a file, not a folder"]),
    (["render", "{d}/none.ply", "--out", "{d}/x.png", "--xyz", "/proc/self/x.tiff"], ["--xyz", "cannot write"]),
    (["render", "{d}/none.ply", "--out", "{d}/x.png", "--xyz", "{d}/dir.dng"], ["--xyz", "is a folder"]),
    (["register", "{d}/a.xyz", "{d}/a.xyz", "--poses", "{d}/a.xyz/p.json"], ["--poses", "a.xyz is a file"]),
    (["register", "{d}/a.xyz", "{d}/a.xyz", "--out", "{d}/m.ply"], ["--out", "is a folder"]),
    (["spectral", "estimate", "{d}/a.xyz", "--chart", "{d}/a.xyz", "--out", "{d}/a.xyz/r.npz"], ["--out", "a.xyz is a file"]),
    (["export", "{d}", "--gltf", "/proc/self/o.glb"], ["--gltf", "cannot write"]),
    (["report", "{d}", "--out", "{d}/a.xyz/r.html"], ["--out", "a.xyz is a file"]),
], ids=["chart-dir", "chart-proc", "probe-dir", "probe-file-parent", "render-file-parent", "render-xyz-proc",
        "render-xyz-dir", "register-poses", "register-out-dir", "spectral", "export", "report"])
def test_bad_output_paths_end_before_the_work(place, capsys, argv, needles):
    """Checked first: the inputs (which do not even exist here) are never read, no output is written."""
    fails_with_one_line([a.format(d=place) for a in argv], capsys, place, *needles)


def test_a_write_that_fails_after_the_check_is_one_line(place, capsys, monkeypatch):
    """The folder removed while the chart was measured: the --json write ends as one line, no traceback."""
    import app.cli.chart as chart_cli

    out = place / "gone" / "c.json"
    out.parent.mkdir()

    def report(*args, **kwargs):
        out.parent.rmdir()
        return {"patches": [], "warnings": [], "method": "corners", "chart": "classic24"}

    monkeypatch.setattr(chart_cli, "chart_report", report)
    code = main(["chart", str(place / "none.dng"), "--json", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and len(err.splitlines()) == 1, err
    assert f"--json {out}: cannot be written (No such file or directory)" in err
