"""`kogei render` / `kogei materials` end to end, including every bad-input path (docs/scene-file.md)."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from app.cli import main


def _write_ply(path, vertices, triangles):
    lines = ["ply", "format ascii 1.0", f"element vertex {len(vertices)}",
             "property float x", "property float y", "property float z",
             f"element face {len(triangles)}", "property list uchar int vertex_indices", "end_header"]
    lines += [" ".join(str(float(c)) for c in v) for v in vertices]
    lines += ["3 " + " ".join(str(int(i)) for i in t) for t in triangles]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def sphere_ply(tmp_path_factory):
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh.create_sphere(radius=10.0, resolution=24)
    path = tmp_path_factory.mktemp("mesh") / "sphere.ply"
    return _write_ply(path, np.asarray(mesh.vertices), np.asarray(mesh.triangles))


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_render_gold_sphere_is_yellow_and_background_dark(tmp_path, sphere_ply, capsys):
    out = tmp_path / "gold.png"
    xyz = tmp_path / "gold.tiff"
    code, _, err = _run(capsys, "render", sphere_ply, "--material", "gold", "--size", "96x64",
                        "--preset", "draft", "--sky", "uniform", "--out", out, "--xyz", xyz, "--quiet")
    assert code == 0, err
    img = np.asarray(Image.open(out))
    assert img.shape == (64, 96, 3) and img.dtype == np.uint8
    # The sphere fills the middle; gold's Fresnel reflectance is highest in the red, lowest in the blue.
    centre = img[24:40, 40:56].reshape(-1, 3).astype(float).mean(axis=0)
    assert centre[0] > centre[2] + 10
    import tifffile

    data = tifffile.imread(xyz)
    assert data.shape == (64, 96, 3) and data.dtype == np.float32
    assert np.isfinite(data).all()


def test_red_lacquer_stays_red_under_d65_and_a_after_adaptation(tmp_path, capsys):
    # A flat square facing the camera and the light, filling the middle of the image.
    verts = np.array([[-5, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0]], float)
    tris = np.array([[0, 1, 2], [0, 2, 3]])
    ply = _write_ply(tmp_path / "square.ply", verts, tris)
    outs = {}
    for ill in ("D65", "A"):
        out = tmp_path / f"sq-{ill}.png"
        code, _, err = _run(capsys, "render", ply, "--material", "urushi-red", "--illuminant", ill,
                            "--light", "directional:0,0,1", "--eye", "0,-0.01,30", "--target", "0,0,0",
                            "--size", "32x32", "--preset", "draft", "--sky", "none", "--out", out, "--quiet")
        assert code == 0, err
        outs[ill] = np.asarray(Image.open(out)).astype(float)[12:20, 12:20].reshape(-1, 3).mean(0)
    # Adapted to each light's white, red lacquer stays clearly red under both.
    for rgb in outs.values():
        assert rgb[0] > rgb[1] + 20 and rgb[0] > rgb[2] + 20


def test_scene_file_with_two_objects(tmp_path, sphere_ply, capsys):
    scene = tmp_path / "scene.toml"
    scene.write_text(f"""
[render]
size = "80x60"
preset = "draft"
illuminant = "D50"

[camera]
eye = [0, -100, 0]
target = [0, 0, 0]
fov = 30

[[light]]
kind = "directional"
direction = [0.3, -1, 1]

[[object]]
mesh = "{sphere_ply}"
material = "copper"
translate = [-12, 0, 0]

[[object]]
procedural = "sphere"
radius = 10
material = "silver"
translate = [12, 0, 0]
""")
    out = tmp_path / "scene.png"
    code, _, err = _run(capsys, "render", scene, "--out", out, "--quiet")
    assert code == 0, err
    img = np.asarray(Image.open(out)).astype(float)
    # Half the image height spans 100 tan(15 deg) = 26.8 units over 30 px: the sphere centres at
    # x = -12 and +12 project to columns 40 -+ 13.4, each sphere about 11 px in radius.
    left, right = img[26:34, 23:31].reshape(-1, 3).mean(0), img[26:34, 50:58].reshape(-1, 3).mean(0)
    # Copper is redder than silver (r/b ratio): both spheres are there with their own materials.
    assert left[0] / max(left[2], 1) > right[0] / max(right[2], 1) + 0.2


def test_materials_lists_every_preset_with_a_colour(capsys):
    from processing.materials.presets import list_materials

    code, out, err = _run(capsys, "materials")
    assert code == 0, err
    for name in list_materials():
        assert name in out
    assert out.count("#") >= len(list_materials())


def test_materials_shows_parameters_of_one_preset(capsys):
    from processing.materials.presets import material_parameters

    code, out, err = _run(capsys, "materials", "gold")
    assert code == 0, err
    for key in material_parameters("gold"):
        assert key in out


@pytest.mark.parametrize(
    "argv_tail, fragment",
    [
        (["--material", "unobtainium"], "gold"),                  # lists the valid names
        (["--material", "gold:shininess=3"], "roughness"),          # lists the valid parameters
        (["--size", "0x10"], "--size"),
        (["--size", "banana"], "--size"),
        (["--light", "spot:1,2,3"], "--light"),
        (["--illuminant", "nosuchlight"], "illuminant"),
        (["--fov", "0"], "--fov"),
    ],
)
def test_bad_arguments_give_one_line_errors(tmp_path, sphere_ply, capsys, argv_tail, fragment):
    code, _, err = _run(capsys, "render", sphere_ply, *argv_tail, "--out", tmp_path / "x.png")
    assert code == 2
    lines = [l for l in err.strip().splitlines() if l]
    assert len(lines) == 1, err
    assert fragment in lines[0]
    assert "Traceback" not in err


def _error_for_mesh(tmp_path, capsys, path, *extra):
    code, _, err = _run(capsys, "render", path, "--out", tmp_path / "x.png", "--size", "16x16", *extra)
    assert code == 2, err
    lines = [l for l in err.strip().splitlines() if l]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def test_missing_mesh(tmp_path, capsys):
    assert "not found" in _error_for_mesh(tmp_path, capsys, tmp_path / "nope.ply")


def test_unreadable_mesh(tmp_path, capsys):
    bad = tmp_path / "garbage.ply"
    bad.write_bytes(b"\x00\x01not a ply at all\xff" * 10)
    line = _error_for_mesh(tmp_path, capsys, bad)
    assert "garbage.ply" in line


def test_empty_mesh(tmp_path, capsys):
    empty = _write_ply(tmp_path / "empty.ply", np.zeros((0, 3)), np.zeros((0, 3), int))
    line = _error_for_mesh(tmp_path, capsys, empty)
    assert "empty.ply" in line


def test_nan_vertices(tmp_path, capsys):
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, np.nan, 0], [0, 0, 1]], float)
    ply = _write_ply(tmp_path / "nan.ply", verts, np.array([[0, 1, 2], [0, 1, 3]]))
    line = _error_for_mesh(tmp_path, capsys, ply)
    assert "nan" in line.lower()


def test_only_degenerate_triangles(tmp_path, capsys):
    verts = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], float)      # collinear: zero area
    ply = _write_ply(tmp_path / "flat.ply", verts, np.array([[0, 1, 2]]))
    line = _error_for_mesh(tmp_path, capsys, ply)
    assert "degenerate" in line.lower()


def test_light_inside_the_object(tmp_path, sphere_ply, capsys):
    line = _error_for_mesh(tmp_path, capsys, sphere_ply, "--light", "point:2,-3,4")   # inside the r = 10 sphere
    assert "inside" in line.lower()
