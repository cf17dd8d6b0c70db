"""``kogei cloth simulate`` makes the swatch session ``kogei cloth fit`` needs, from the command line alone.

The simulated swatch's parameters are the truth: the fit of the simulated session must recover them
(within 10 %, as tests/cloth/test_cloth_fit.py requires of the library call).
"""

from __future__ import annotations

import json

import pytest

from app.cli import main

TRUTH = {"a_t": 0.08, "a_b": 0.5, "specular": 0.25, "internal": 0.3, "diffuse": 0.4}
SPEC = ("silk:a_t=0.08,a_b=0.5,weft_a_t=0.08,weft_a_b=0.5,specular=0.25,internal=0.3,diffuse=0.4,"
        "warp_colour=#3060a0,weft_colour=#3060a0")


def test_simulate_then_fit_recovers_the_swatch(tmp_path, capsys):
    session = tmp_path / "swatch"
    assert main(["cloth", "simulate", str(session), "--cloth", SPEC, "--steps", "8", "--size", "64x48"]) == 0
    out = capsys.readouterr().out
    assert f"kogei cloth fit {session}" in out
    assert (session / "swatch.json").is_file()
    manifest = json.loads((session / "session.json").read_text())
    assert manifest["plan"]["kind"] == "swatch" and manifest["plan"]["steps"] == 8
    assert main(["cloth", "fit", str(session), "--pixels", "64", "--quiet"]) == 0
    got = json.loads((session / "cloth-fit" / "cloth-fit.json").read_text())["parameters"]
    for name, want in TRUTH.items():
        assert got[name] == pytest.approx(want, rel=0.10), name


@pytest.mark.parametrize("argv,words", [
    (["--size", "64"], ["--size", "WxH"]),
    (["--steps", "1"], ["--steps", "at least 2"]),
    (["--cloth", "unobtainium"], ["unobtainium"]),
])
def test_bad_options_are_one_line_errors(argv, words, tmp_path, capsys):
    code = main(["cloth", "simulate", str(tmp_path / "s"), *argv])
    err = capsys.readouterr().err
    assert code == 2 and all(w in err for w in words) and "Traceback" not in err and len(err.splitlines()) == 1
    assert list(tmp_path.iterdir()) == []            # nothing written


def test_an_existing_folder_is_refused_untouched(tmp_path, capsys):
    keep = tmp_path / "work"
    keep.mkdir()
    (keep / "notes.txt").write_text("mine")
    code = main(["cloth", "simulate", str(keep)])
    err = capsys.readouterr().err
    assert code == 2 and "exists" in err and (keep / "notes.txt").read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["work"]
