"""`kogei render --environment` and the scene file's [environment]: maps, the analytic sky, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from app.cli import main
from app.workflows.scene_spec import parse_environment
from processing.lighting.environment_map import EnvironmentMap, srgb_basis, write_environment


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def _raw_exr(path, rgb):
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {"RGB": np.ascontiguousarray(rgb, dtype=np.float32)}) as f:
        f.write(str(path))
    return path


@pytest.fixture(scope="module")
def probe(tmp_path_factory):
    grey = EnvironmentMap(np.full((16, 32, 3), 0.6, np.float32), srgb_basis(), source="grey")
    return write_environment(tmp_path_factory.mktemp("env") / "probe.exr", grey)


def _one_line_error(capsys, *argv) -> str:
    code, _, err = _run(capsys, *argv)
    assert code == 2, err
    lines = [line for line in err.strip().splitlines() if line]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def test_render_under_a_map_and_under_the_sky(tmp_path, probe, capsys):
    """A white-ish sphere under a uniform grey map is lit evenly; under a low sun from +x its +x side is
    brighter than its -x side (the camera looks along +y)."""
    out = tmp_path / "map.png"
    code, _, err = _run(capsys, "render", _sphere_scene(tmp_path), "--environment",
                        f"{probe}:rotate=30,intensity=1.5", "--preset", "draft", "--size", "48x48", "--out", out,
                        "--quiet")
    assert code == 0, err
    img = np.asarray(Image.open(out), dtype=float)
    centre = img[20:28, 20:28].mean()
    assert centre > 60                                          # lit by the map alone (no default light)
    assert np.ptp(img[18:30, 18:30].mean(axis=2)) < 12           # and evenly: a uniform map
    out2 = tmp_path / "sky.png"
    code, _, err = _run(capsys, "render", _sphere_scene(tmp_path), "--environment",
                        "sky:cct=5000,sun_elevation=10,sun_azimuth=0,type=clear,sun=8", "--preset", "draft",
                        "--size", "48x48", "--out", out2, "--quiet")
    assert code == 0, err
    img = np.asarray(Image.open(out2), dtype=float).mean(axis=2)
    assert img[24, 34] > img[24, 14] + 20                       # +x (image right) faces the sun


def _sphere_scene(tmp_path, extra: str = "") -> str:
    path = tmp_path / "scene.toml"
    path.write_text('[render]\npreset = "draft"\n[camera]\neye = [0, -40, 0]\ntarget = [0, 0, 0]\nfov = 35\n'
                    '[[object]]\nprocedural = "sphere"\nradius = 10\ntriangles = 2000\n'
                    'material = "urushi-red:diffuse=0.9,gloss=0,mirror=0.0"\n' + extra)
    return str(path)


def test_scene_file_environment_tables(tmp_path, probe, capsys):
    scene = _sphere_scene(tmp_path, f'[environment]\nfile = "{probe}"\nrotate = 45\nintensity = 2\n')
    code, _, err = _run(capsys, "render", scene, "--size", "24x24", "--out", tmp_path / "a.png", "--quiet")
    assert code == 0, err
    scene = _sphere_scene(tmp_path, "[environment]\nrotate = 10\n[environment.sky]\ncct = 6500\nsun_elevation = 30\n"
                                    'type = "intermediate"\n')
    code, _, err = _run(capsys, "render", scene, "--size", "24x24", "--out", tmp_path / "b.png", "--quiet")
    assert code == 0, err


def test_parse_environment_forms():
    spec = parse_environment("maps/room.HDR:rotate=-90")
    assert spec.file.name == "room.HDR" and spec.rotate_deg == -90.0 and spec.intensity == 1.0
    assert parse_environment("sky").file is None
    assert parse_environment("sky:type=13,height=64").sky == {"sky_type": 13, "height": 64}


@pytest.mark.parametrize("make,fragment", [
    (lambda d: d / "missing.exr", "no such environment map"),
    (lambda d: _raw_exr(d / "nan.exr", np.where(np.arange(16 * 32 * 3).reshape(16, 32, 3) == 5, np.nan, 1.0)),
     "NaN or infinite"),
    (lambda d: _raw_exr(d / "inf.exr", np.where(np.arange(16 * 32 * 3).reshape(16, 32, 3) == 5, np.inf, 1.0)),
     "NaN or infinite"),
    (lambda d: _raw_exr(d / "neg.exr", np.where(np.arange(16 * 32 * 3).reshape(16, 32, 3) == 5, -1.0, 1.0)),
     "negative"),
    (lambda d: _raw_exr(d / "square.exr", np.ones((16, 16, 3))), "twice as wide as high"),
    (lambda d: (d / "garbage.exr").write_bytes(b"not an exr") and d / "garbage.exr", "not a readable OpenEXR"),
    (lambda d: (d / "garbage.hdr").write_bytes(b"not an hdr") and d / "garbage.hdr", "not a readable Radiance"),
])
def test_bad_map_files(tmp_path, capsys, make, fragment):
    path = make(tmp_path)
    line = _one_line_error(capsys, "render", _sphere_scene(tmp_path), "--environment", str(path), "--size", "16x16",
                           "--out", tmp_path / "x.png")
    assert fragment in line and path.name in line


@pytest.mark.parametrize("value,fragment", [
    ("{probe}:spin=3", "unknown option"),
    ("{probe}:rotate=nan", "rotate"),
    ("{probe}:intensity=-1", "intensity"),
    ("{probe}:intensity=inf", "intensity"),
    ("{probe}:rotate", "KEY=VALUE"),
    ("room.png", "FILE.exr"),
    ("sky:colour=blue", "unknown option"),
    ("sky:cct=3000", "cct"),
    ("sky:type=16", "type"),
    ("sky:type=sunny", "type"),
    ("sky:sun_elevation=100", "sun_elevation"),
    ("sky:height=2.5", "height"),
    ("sky:luminance=0", "luminance"),
])
def test_bad_environment_options(tmp_path, probe, capsys, value, fragment):
    line = _one_line_error(capsys, "render", _sphere_scene(tmp_path), "--environment", value.format(probe=probe),
                           "--size", "16x16", "--out", tmp_path / "x.png")
    assert fragment in line


@pytest.mark.parametrize("table,fragment", [
    ('[environment]\nfile = "{probe}"\n[environment.sky]\ncct = 6500\n', "exactly one"),
    ("[environment]\nrotate = 3\n", "exactly one"),
    ('[environment]\nfile = "{probe}"\nglow = 1\n', "unknown key"),
    ('[environment]\nfile = "room.png"\n', ".exr or .hdr"),
    ('[environment]\nfile = "{probe}"\nintensity = -2\n', "intensity"),
    ("[environment]\n[environment.sky]\ncct = 2000\n", "cct"),
    ("[environment]\n[environment.sky]\nfog = 1\n", "unknown option"),
    ('[environment]\nsky = "clear"\n', "table of sky settings"),
])
def test_bad_scene_file_environment(tmp_path, probe, capsys, table, fragment):
    scene = _sphere_scene(tmp_path, table.format(probe=probe))
    line = _one_line_error(capsys, "render", scene, "--size", "16x16", "--out", tmp_path / "x.png")
    assert fragment in line


def test_environment_samples_option(tmp_path, probe, capsys):
    code, _, err = _run(capsys, "render", _sphere_scene(tmp_path), "--environment", str(probe), "--preset", "standard",
                        "--environment-samples", "2", "--size", "16x16", "--out", tmp_path / "s.png", "--quiet")
    assert code == 0, err
    for bad in ("1", "-3", "5000"):
        line = _one_line_error(capsys, "render", _sphere_scene(tmp_path), "--environment", str(probe),
                               "--environment-samples", bad, "--size", "16x16", "--out", tmp_path / "x.png")
        assert "--environment-samples" in line
    scene = _sphere_scene(tmp_path, f'[environment]\nfile = "{probe}"\n')
    text = open(scene).read().replace('preset = "draft"', 'preset = "draft"\nenvironment_samples = 1')
    open(scene, "w").write(text)
    assert "environment_samples" in _one_line_error(capsys, "render", scene, "--size", "16x16",
                                                     "--out", tmp_path / "x.png")
