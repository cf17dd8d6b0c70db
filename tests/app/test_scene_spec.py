"""Parsing of command-line scene values and TOML scene files."""

from __future__ import annotations

import pytest

from app.errors import UsageError
from app.workflows.scene_spec import load_scene_file, parse_light, parse_size, parse_vector


def test_parse_light_variants():
    l = parse_light("point:1,2,3@3200K*4")
    assert (l.kind, l.vector, l.spectrum, l.intensity) == ("point", (1.0, 2.0, 3.0), "3200K", 4.0)
    d = parse_light("directional:0,0,1")
    assert d.spectrum is None and d.intensity == 1.0


@pytest.mark.parametrize("text", ["directional:0,0,0", "directional:", "area:1,2,3", "point:1,2",
                                  "point:1,2,3*-1", "point:a,b,c"])
def test_parse_light_rejects(text):
    with pytest.raises(UsageError, match="--light"):
        parse_light(text)


@pytest.mark.parametrize("text", ["1,2", "1,2,nan", "x,y,z", "1,2,3,4"])
def test_parse_vector_rejects(text):
    with pytest.raises(UsageError, match="--eye"):
        parse_vector(text, "--eye")


def test_parse_size():
    assert parse_size("1024X768") == (1024, 768)
    for bad in ("0x5", "-3x4", "12", "100000x100000"):
        with pytest.raises(UsageError):
            parse_size(bad)


def test_scene_file_errors_name_the_file_and_key(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text("[render]\nsize='10x10'\nbogus=1\n[[object]]\nprocedural='sphere'\n")
    with pytest.raises(UsageError, match=r"s\.toml \[render\].*bogus"):
        load_scene_file(p)
    p.write_text("[render\n")
    with pytest.raises(UsageError, match="not valid TOML"):
        load_scene_file(p)
    p.write_text("[render]\nsize='10x10'\n")
    with pytest.raises(UsageError, match="no \\[\\[object\\]\\]"):
        load_scene_file(p)
    p.write_text("[[object]]\nmesh='a.ply'\nprocedural='sphere'\n")
    with pytest.raises(UsageError, match="exactly one"):
        load_scene_file(p)
    p.write_text("[[light]]\nkind='point'\n[[object]]\nprocedural='sphere'\n")
    with pytest.raises(UsageError, match="needs 'position'"):
        load_scene_file(p)


def test_scene_file_relative_mesh_path(tmp_path):
    p = tmp_path / "sub" / "s.toml"
    p.parent.mkdir()
    p.write_text("[[object]]\nmesh='m.ply'\nmaterial='copper'\nrotate=[0,0,90]\n"
                 "[[light]]\nkind='directional'\ndirection=[0,0,1]\nspectrum='A'\n")
    spec = load_scene_file(p)
    assert spec.objects[0].mesh == p.parent / "m.ply"
    assert spec.objects[0].rotate_deg == (0.0, 0.0, 90.0)
    assert spec.lights[0].spectrum == "A"
