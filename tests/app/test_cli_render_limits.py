"""`kogei render` refuses, in one line, parameters and inputs float32 rendering cannot resolve (render/limits.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.cli import main
from processing.lighting.environment_map import HEADER_KEY, EnvironmentMap, srgb_basis, write_environment
from processing.spectral.spectra import REFERENCE_GRID


def _write_ply(path, vertices, triangles):
    lines = ["ply", "format ascii 1.0", f"element vertex {len(vertices)}",
             "property double x", "property double y", "property double z",
             f"element face {len(triangles)}", "property list uchar int vertex_indices", "end_header"]
    lines += [" ".join(repr(float(c)) for c in v) for v in vertices]
    lines += ["3 " + " ".join(str(int(i)) for i in t) for t in triangles]
    path.write_text("\n".join(lines) + "\n")
    return path


_TETRA_V = np.array([[10.0, 0, 0], [-10, 10, 0], [-10, -10, 0], [0, 0, 10]])
_TETRA_T = np.array([[0, 1, 2], [0, 3, 1], [1, 3, 2], [2, 3, 0]])


@pytest.fixture(scope="module")
def mesh(tmp_path_factory):
    return _write_ply(tmp_path_factory.mktemp("mesh") / "tetra.ply", _TETRA_V, _TETRA_T)


def _one_line_error(capsys, *argv) -> str:
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 2, err
    lines = [line for line in err.strip().splitlines() if line]
    assert len(lines) == 1 and "Traceback" not in err and "Warning" not in err, err
    return lines[0]


def _render_error(capsys, tmp_path, source, *flags) -> str:
    return _one_line_error(capsys, "render", source, *flags, "--size", "16x12", "--preset", "draft",
                           "--out", tmp_path / "x.png")


def test_deeply_nested_scene_file_is_one_line(tmp_path, capsys):
    scene = tmp_path / "deep.toml"
    scene.write_text('[[object]]\nmesh = "m.ply"\nx = ' + "[" * 5000 + "]" * 5000 + "\n")
    line = _render_error(capsys, tmp_path, scene)
    assert "deep.toml" in line and "nested too deeply" in line


@pytest.mark.parametrize("fov", ["1e-6", "1e-9", "0.05"])
def test_fov_below_the_resolvable_minimum(tmp_path, mesh, capsys, fov):
    line = _render_error(capsys, tmp_path, mesh, "--fov", fov)
    assert line.startswith("kogei render: error: --fov:") and "from 0.1 to 180 degrees" in line


def test_scene_fov_below_the_resolvable_minimum(tmp_path, mesh, capsys):
    scene = tmp_path / "s.toml"
    scene.write_text(f'[camera]\nfov = 1e-9\n[[object]]\nmesh = "{mesh}"\n')
    line = _render_error(capsys, tmp_path, scene)
    assert "[camera] fov" in line and "from 0.1 to 180 degrees" in line


def test_narrowest_fov_renders(tmp_path, mesh, capsys):
    assert main(["render", str(mesh), "--fov", "0.1", "--size", "16x12", "--preset", "draft", "--quiet",
                 "--out", str(tmp_path / "ok.png")]) == 0


@pytest.mark.parametrize("flag,value,fragment", [
    ("--eye", "0,0,1e300", "--eye: expected three numbers X,Y,Z of magnitude at most 1e+07 mm"),
    ("--target", "1e308,1e308,1e308", "--target: expected three numbers X,Y,Z of magnitude at most 1e+07 mm"),
    ("--light", "point:0,0,1e300", "--light: expected three numbers X,Y,Z of magnitude at most 1e+07 mm"),
    ("--light", "directional:0,0,1*1e300", "--light: expected an intensity after '*' from 1e-09 to 1e+12"),
    ("--weave-angle", "1e300", "--weave-angle: expected an angle in degrees from -360 to 360"),
])
def test_huge_command_line_parameters(tmp_path, mesh, capsys, flag, value, fragment):
    assert fragment in _render_error(capsys, tmp_path, mesh, flag, value)


@pytest.mark.parametrize("table,fragment", [
    ("[[object]]\nmesh = '{mesh}'\nscale = 1e300\n", "[[object]] #1 scale: expected a finite number between 1e-06 and 1e+06"),
    ("[[object]]\nmesh = '{mesh}'\nrotate = [1e300, 0, 0]\n", "[[object]] #1 rotate: expected three numbers X,Y,Z of "
                                                              "magnitude at most 360 degrees"),
    ("[[object]]\nmesh = '{mesh}'\ntranslate = [1e300, 0, 0]\n", "[[object]] #1 translate: expected three numbers"),
    ("[camera]\neye = [0, 0, 1e300]\n[[object]]\nmesh = '{mesh}'\n", "[camera] eye: expected three numbers"),
    ("[[light]]\nkind = 'point'\nposition = [0, 0, 1e300]\n[[object]]\nmesh = '{mesh}'\n",
     "[[light]] #1 position: expected three numbers X,Y,Z of magnitude at most 1e+07 mm"),
    ("[[light]]\ndirection = [0, 0, 1]\n[[light]]\ndirection = [1, 0, 1]\nintensity = 1e300\n"
     "[[object]]\nmesh = '{mesh}'\n", "[[light]] #2 intensity: expected a finite number between 1e-09 and 1e+12"),
    ("[sky]\nzenith = 1e300\n[[object]]\nmesh = '{mesh}'\n", "[sky] zenith: expected a finite number between 0 and 1e+06"),
    ("[environment]\n[environment.sky]\ncct = 6500\nluminance = 1e-300\n[[object]]\nmesh = '{mesh}'\n",
     "[environment] luminance: expected a number from 1e-06 to 1e+06"),
    ("[environment]\nrotate = 1e300\n[environment.sky]\ncct = 6500\n[[object]]\nmesh = '{mesh}'\n",
     "[environment] rotate: expected an angle in degrees from -360 to 360"),
])
def test_huge_scene_file_parameters(tmp_path, mesh, capsys, table, fragment):
    scene = tmp_path / "s.toml"
    scene.write_text(table.format(mesh=mesh))
    line = _render_error(capsys, tmp_path, scene)
    assert "s.toml" in line and fragment in line


@pytest.mark.parametrize("factor,offset,fragment", [
    (1e15, 0.0, "coordinates reach 1e+16 mm; the renderer takes coordinates within +-1e+07 mm"),
    (1e200, 0.0, "coordinates reach 1e+201 mm"),
    (1.0, 1e10, "coordinates reach 1e+10 mm"),
    (1.0, 1e6, "lies 1e+06 mm from the origin; float32 ray casting resolves a mesh at most 10000 times its extent"),
    (1e-12, 0.0, "the mesh spans only 2e-11 mm; the renderer takes meshes of at least 0.001 mm"),
])
def test_meshes_float32_cannot_resolve(tmp_path, capsys, factor, offset, fragment):
    ply = _write_ply(tmp_path / "far.ply", _TETRA_V * factor + offset, _TETRA_T)
    line = _render_error(capsys, tmp_path, ply)
    assert "far.ply" in line and fragment in line


def _exr(path, rgb, basis=None):
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    if basis is not None:
        header[HEADER_KEY] = json.dumps({"wavelengths_nm": REFERENCE_GRID.wavelengths.tolist(),
                                         "basis": basis.tolist()})
    with OpenEXR.File(header, {"RGB": np.ascontiguousarray(rgb, dtype=np.float32)}) as f:
        f.write(str(path))
    return path


@pytest.mark.parametrize("make,fragment", [
    (lambda d: _exr(d / "zero.exr", np.zeros((8, 16, 3))), "gives no light (brightest pixel luminance 0"),
    (lambda d: _exr(d / "tiny.exr", np.full((8, 16, 3), 1e-44)), "gives no light"),
    (lambda d: _exr(d / "bzero.exr", np.ones((8, 16, 3)), 0.0 * srgb_basis()), "gives no light"),
    (lambda d: _exr(d / "bneg.exr", np.ones((8, 16, 3)), -srgb_basis()), "radiance is negative"),
    (lambda d: _exr(d / "huge.exr", np.full((8, 16, 3), 3e38)), "above 1e+15"),
])
def test_maps_without_usable_light(tmp_path, mesh, capsys, make, fragment):
    path = make(tmp_path)
    line = _render_error(capsys, tmp_path, mesh, "--environment", path)
    assert path.name in line and fragment in line


@pytest.mark.parametrize("option", ["intensity=1e-8", "intensity=1e-300", "intensity=1e300"])
def test_environment_intensity_range(tmp_path, mesh, capsys, option):
    grey = EnvironmentMap(np.full((8, 16, 3), 0.6, np.float32), srgb_basis(), source="grey")
    probe = write_environment(tmp_path / "probe.exr", grey)
    line = _render_error(capsys, tmp_path, mesh, "--environment", f"{probe}:{option}")
    assert "--environment intensity: expected a number from 1e-06 to 1e+06" in line


def test_sky_luminance_range(tmp_path, mesh, capsys):
    line = _render_error(capsys, tmp_path, mesh, "--environment", "sky:cct=6500,luminance=1e-300")
    assert "--environment luminance: expected a number from 1e-06 to 1e+06" in line
