"""Untrusted inputs of ``kogei render``, ``register``, ``spectral`` and ``identify``: one-line messages, exit 2.

Scene files with wrong types or absurd values, sizes whose image buffers do
not fit in memory, point clouds whose headers claim more data than the file
holds, and files named ``.npz`` that are not kogei results each end as one
line naming the file and the key (or the count) and exit status 2, never a
traceback, a MemoryError or a long allocation.
"""

from __future__ import annotations

import pytest

from app.cli import main


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def _one_line_error(capsys, argv, *needles):
    code, _, err = _run(capsys, *argv)
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


# ----------------------------------------------------------------------------------------- scene files

_SPHERE = "[[object]]\nprocedural = 'sphere'\n"

#: (scene text, words the message must contain): each a wrong type or an out-of-range value.
BAD_SCENES = [
    ("[[object]]\nmesh = 42\n", ("mesh", "string", "42")),
    (_SPHERE + "scale = 'big'\n", ("scale", "number", "'big'")),
    (_SPHERE + "scale = 0\n", ("scale", "between 1e-06 and 1e+06")),
    (_SPHERE + "scale = nan\n", ("scale", "finite")),
    (_SPHERE + "scale = inf\n", ("scale", "finite")),
    (_SPHERE + "radius = -1\n", ("radius", "> 0")),
    (_SPHERE + "radius = 0.0\n", ("radius", "> 0")),
    (_SPHERE + "radius = '2'\n", ("radius", "number")),
    (_SPHERE + "triangles = 1e12\n", ("triangles", "whole number from 1 to")),
    (_SPHERE + "triangles = 1000000000000\n", ("triangles", "whole number from 1 to")),
    (_SPHERE + "triangles = 2.5\n", ("triangles", "whole number")),
    (_SPHERE + "triangles = -5\n", ("triangles", "whole number")),
    (_SPHERE + "triangles = true\n", ("triangles", "boolean")),
    ("[[object]]\nprocedural = 'hawk'\ntriangles = 1e12\n", ("triangles", "whole number")),
    ("[[object]]\nprocedural = 'cloth'\ntriangles = inf\n", ("triangles", "whole number")),
    ("[[object]]\nprocedural = 'plane'\nsize = -3\n", ("size", "> 0")),
    ("[[object]]\nprocedural = 'plane'\nradius = 3\n", ("radius", "plane")),
    ("[[object]]\nprocedural = 42\n", ("procedural", "one of")),
    ("[[object]]\nprocedural = 'cube'\n", ("procedural", "one of")),
    (_SPHERE + "material = 3\n", ("material", "string")),
    (_SPHERE + "materials = 'gold'\n", ("materials", "table")),
    (_SPHERE + "materials = {head = 1}\n", ("materials", "table")),
    (_SPHERE + "translate = 'here'\n", ("translate", "three numbers")),
    (_SPHERE + "rotate = [0, 0]\n", ("rotate", "three numbers")),
    (_SPHERE + "rotate = [0, nan, 0]\n", ("rotate", "finite")),
    (_SPHERE + "translate = [0, true, 0]\n", ("translate", "three numbers")),
    (_SPHERE + "weave_angle = 'x'\n", ("weave_angle", "number")),
    (_SPHERE + "weave_angle = inf\n", ("weave_angle", "finite")),
    ("object = 5\n", ("[[object]]", "array of tables")),
    ("object = [1, 2]\n", ("[[object]]", "array of tables")),
    ("light = 'sun'\n" + _SPHERE, ("[[light]]", "array of tables")),
    ("render = 5\n" + _SPHERE, ("[render]", "table")),
    ("camera = [1]\n" + _SPHERE, ("[camera]", "table")),
    ("[render]\nsize = 1024\n" + _SPHERE, ("size", "string")),
    ("[render]\nsize = '100000x100000'\n" + _SPHERE, ("[render] size", "64 megapixels")),
    ("[render]\npreset = 3\n" + _SPHERE, ("preset", "one of")),
    ("[render]\npreset = 'ultra'\n" + _SPHERE, ("preset", "one of")),
    ("[render]\nilluminant = 6500\n" + _SPHERE, ("illuminant", "string")),
    ("[camera]\nfov = 'wide'\n" + _SPHERE, ("fov", "number")),
    ("[camera]\nfov = 0\n" + _SPHERE, ("fov", "from 0.1 to 180 degrees")),
    ("[camera]\nfov = 400\n" + _SPHERE, ("fov", "from 0.1 to 180 degrees")),
    ("[camera]\neye = 42\n" + _SPHERE, ("eye", "three numbers", "integer")),
    ("[camera]\neye = {x = 1}\n" + _SPHERE, ("eye", "three numbers", "table")),
    ("[camera]\nup = [0, 0, inf]\n" + _SPHERE, ("up", "finite")),
    ("[sky]\nkind = 1\n" + _SPHERE, ("kind", "one of")),
    ("[sky]\nzenith = -1\n" + _SPHERE, ("zenith", "between 0 and 1e+06")),
    ("[sky]\nhorizon = nan\n" + _SPHERE, ("horizon", "finite")),
    ("[sky]\nspectrum = [1]\n" + _SPHERE, ("spectrum", "string")),
    ("[[light]]\nkind = 'area'\ndirection = [0, 0, 1]\n" + _SPHERE, ("kind", "directional, point")),
    ("[[light]]\ndirection = [0, 0, 0]\n" + _SPHERE, ("direction", "non-zero")),
    ("[[light]]\ndirection = 'up'\n" + _SPHERE, ("direction", "three numbers")),
    ("[[light]]\ndirection = [0, 0, 1]\nintensity = -2\n" + _SPHERE, ("intensity", "between 1e-09 and 1e+12")),
    ("[[light]]\ndirection = [0, 0, 1]\nintensity = 'bright'\n" + _SPHERE, ("intensity", "number")),
    ("[[light]]\ndirection = [0, 0, 1]\nspectrum = 65\n" + _SPHERE, ("spectrum", "string")),
]


@pytest.mark.parametrize("text, needles", BAD_SCENES, ids=[t for t, _ in BAD_SCENES])
def test_bad_scene_file_is_one_line_naming_the_key(tmp_path, capsys, text, needles):
    scene = tmp_path / "scene.toml"
    scene.write_text(text)
    out = tmp_path / "out.png"
    _one_line_error(capsys, ["render", scene, "--out", out, "--quiet"], "scene.toml", *needles)
    assert not out.exists()


def test_good_scene_values_still_load(tmp_path):
    from app.workflows.scene_spec import load_scene_file

    scene = tmp_path / "scene.toml"
    scene.write_text("[render]\nsize = '64x48'\npreset = 'draft'\n[camera]\nfov = 30\neye = [1, 2, 3]\n"
                     "[sky]\nkind = 'uniform'\nzenith = 0\n[[light]]\nkind = 'point'\nposition = [0, 0, 5]\n"
                     "intensity = 4000\n[[object]]\nprocedural = 'sphere'\nradius = 2\ntriangles = 2e3\n"
                     "scale = 1.5\nweave_angle = 45\n")
    spec = load_scene_file(scene)
    obj = spec.objects[0]
    assert obj.procedural_args == {"radius": 2.0, "triangles": 2000}
    assert (obj.scale, obj.weave_angle_deg, spec.camera.fov_deg, spec.size) == (1.5, 45.0, 30.0, (64, 48))


def test_procedural_spec_from_code_is_checked_too():
    from app.errors import UsageError
    from app.workflows.scene_build import object_mesh
    from app.workflows.scene_spec import ObjectSpec

    with pytest.raises(UsageError, match="radius"):
        object_mesh(ObjectSpec(procedural="sphere", procedural_args={"radius": -1.0}))
    with pytest.raises(UsageError, match="triangles"):
        object_mesh(ObjectSpec(procedural="hawk", procedural_args={"triangles": 10**12}))


# ----------------------------------------------------------------------------------------- memory bounds

def _sphere_scene(tmp_path):
    scene = tmp_path / "scene.toml"
    scene.write_text("[[object]]\nprocedural = 'sphere'\ntriangles = 200\n")
    return scene


def test_render_too_large_for_memory_is_refused_before_allocating(tmp_path, capsys, monkeypatch):
    import time

    import render.renderer as renderer

    monkeypatch.setattr(renderer, "available_memory_bytes", lambda: 2_000_000_000)
    out = tmp_path / "big.png"
    t0 = time.perf_counter()
    line = _one_line_error(capsys, ["render", _sphere_scene(tmp_path), "--size", "8000x8000", "--preset", "draft",
                                    "--out", out, "--quiet"], "8000x8000", "GB", "--size")
    assert time.perf_counter() - t0 < 10
    assert not out.exists()
    # the size it suggests fits
    fit = line.split("render at most ")[1].split()[0]
    w, h = (int(v) for v in fit.split("x"))
    assert w == h and renderer.estimate_peak_bytes(w, h, 200) <= 2_000_000_000


def test_memory_estimate_uses_the_measured_coefficients():
    from render.errors import RenderInputError
    from render.renderer import BYTES_PER_PIXEL, check_memory, estimate_peak_bytes

    assert estimate_peak_bytes(8000, 8000) >= 8000 * 8000 * BYTES_PER_PIXEL > 6.6e9
    check_memory(8000, 8000, 0, available=10**11)          # fits: no error
    with pytest.raises(RenderInputError, match="simplify the mesh"):
        check_memory(10, 10, 10**9, available=10**9)
    with pytest.raises(RenderInputError, match=r"4000x2000 render needs about"):
        check_memory(4000, 2000, 0, available=500_000_000)


def test_memory_error_on_cli_paths_is_one_line(tmp_path, capsys, monkeypatch):
    import app.cli.identify as identify
    import app.cli.register as register
    import app.cli.spectral as spectral
    import render.renderer as renderer

    def boom(*args, **kwargs):
        raise MemoryError

    monkeypatch.setattr(renderer, "render", boom)
    _one_line_error(capsys, ["render", _sphere_scene(tmp_path), "--size", "16x16", "--out", tmp_path / "o.png"],
                    "not enough memory", "--size")
    monkeypatch.setattr(register, "read_cloud", boom)
    _one_line_error(capsys, ["register", "a.ply", "b.ply", "--poses", tmp_path / "p.json"], "not enough memory")
    monkeypatch.setattr(spectral, "load_result", boom)
    _one_line_error(capsys, ["spectral", "at", "r.npz", "0", "0"], "not enough memory")
    monkeypatch.setattr(identify, "load_result", boom)
    _one_line_error(capsys, ["identify", "r.npz"], "not enough memory")


# ----------------------------------------------------------------------------------------- declared counts

_XYZ = "0 0 0\n1 0 0\n0 1 0\n0 0 1\n"

#: Files whose headers claim far more records than they hold (suffix, bytes).
HUGE_HEADERS = {
    "ascii.ply": b"ply\nformat ascii 1.0\nelement vertex 2000000000\nproperty float x\nproperty float y\n"
                 b"property float z\nend_header\n0 0 0\n1 0 0\n0 1 0\n",
    "binary.ply": b"ply\nformat binary_little_endian 1.0\nelement vertex 2000000000\nproperty float x\n"
                  b"property float y\nproperty float z\nend_header\n" + bytes(36),
    "ascii.pcd": b"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2000000000\n"
                 b"HEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2000000000\nDATA ascii\n0 0 0\n1 0 0\n",
    "binary.pcd": b"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2000000000\n"
                  b"HEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2000000000\nDATA binary\n" + bytes(24),
    "count.pts": b"100000000\n0 0 0\n1 0 0\n",
}


@pytest.mark.parametrize("name", sorted(HUGE_HEADERS))
def test_register_refuses_a_header_claiming_more_points_than_the_file_holds(tmp_path, capsys, name):
    import time

    bad = tmp_path / name
    bad.write_bytes(HUGE_HEADERS[name])
    good = tmp_path / "good.xyz"
    good.write_text(_XYZ)
    t0 = time.perf_counter()
    _one_line_error(capsys, ["register", good, bad, "--poses", tmp_path / "p.json", "--quiet"],
                    name, "header declares", "bytes follow the header")
    assert time.perf_counter() - t0 < 10
    assert not (tmp_path / "p.json").exists()


def test_register_refuses_a_cloud_larger_than_memory(tmp_path, capsys, monkeypatch):
    import render.renderer as renderer

    monkeypatch.setattr(renderer, "available_memory_bytes", lambda: 100)
    ply = tmp_path / "four.ply"
    ply.write_text("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
                   "end_header\n" + _XYZ)
    _one_line_error(capsys, ["register", ply, ply, "--poses", tmp_path / "p.json"], "4 points", "subsample")


def test_sane_headers_pass_the_count_check(tmp_path):
    from render.meshio import check_declared_counts

    ply = tmp_path / "four.ply"
    ply.write_text("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
                   "element face 1\nproperty list uchar int vertex_indices\nend_header\n" + _XYZ + "3 0 1 2\n")
    assert check_declared_counts(ply) == 4
    xyz = tmp_path / "a.xyz"
    xyz.write_text(_XYZ)
    assert check_declared_counts(xyz) is None


#: Mesh files whose headers claim more triangles or vertices than they hold.
HUGE_MESHES = {
    "huge.ply": HUGE_HEADERS["ascii.ply"].replace(b"end_header", b"element face 5\nproperty list uchar int "
                                                  b"vertex_indices\nend_header"),
    "huge.off": b"OFF\n2000000000 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
    "huge.stl": bytes(80) + (2_000_000_000).to_bytes(4, "little") + bytes(50),
    "bad.ply": b"ply\nformat ascii 1.0\nelement vertex many\nproperty float x\nend_header\n0\n",
}


@pytest.mark.parametrize("name", sorted(HUGE_MESHES))
def test_render_refuses_a_mesh_header_claiming_more_than_the_file_holds(tmp_path, capsys, name):
    mesh = tmp_path / name
    mesh.write_bytes(HUGE_MESHES[name])
    _one_line_error(capsys, ["render", mesh, "--size", "16x16", "--out", tmp_path / "o.png"], name, "header")


# ----------------------------------------------------------------------------------------- RESULT.npz

def _good_arrays(**change):
    import json

    import numpy as np

    wl = np.arange(400.0, 701.0, 10.0)
    arrays = {"weights": np.zeros((2, 3, 3), np.float32), "basis": np.ones((wl.size, 3)), "wavelengths": wl,
              "mask": np.ones((2, 3), bool), "camera": np.ones((2, 3, 3), np.float32),
              "sensitivities": np.ones((wl.size, 3)), "lights": np.ones((1, wl.size)),
              "method": np.array("rootpoly"), "metadata": np.array(json.dumps({"chart_rmse": 0.02}))}
    arrays.update(change)
    return arrays


def _write_npz(path, arrays):
    import numpy as np

    np.savez(path, **arrays)
    return path


def test_a_good_result_loads(tmp_path):
    from app.workflows.spectral import load_result

    res = load_result(_write_npz(tmp_path / "r.npz", _good_arrays()))
    assert res.weights.shape == (2, 3, 3) and res.method == "rootpoly" and res.method_error == 0.02


def _result_error(capsys, path, *needles):
    line = _one_line_error(capsys, ["spectral", "at", path, "0", "0"], path.name, *needles)
    _one_line_error(capsys, ["identify", path], path.name, *needles)
    return line


def test_text_file_named_npz_is_not_a_result(tmp_path, capsys):
    path = tmp_path / "notes.npz"
    path.write_text("hello, this is not a result\n")
    line = _result_error(capsys, path, "not a kogei spectral result", "text file")
    assert "pickled" not in line


@pytest.mark.parametrize("content, needle", [(b"", "empty file"), (b"\x00\x01\x02garbage\xff", "not a zip archive")])
def test_empty_or_binary_file_named_npz(tmp_path, capsys, content, needle):
    path = tmp_path / "junk.npz"
    path.write_bytes(content)
    _result_error(capsys, path, "not a kogei spectral result", needle)


def test_npy_named_npz(tmp_path, capsys):
    import numpy as np

    path = tmp_path / "one.npz"
    with open(path, "wb") as fh:
        np.save(fh, np.zeros(3))
    _result_error(capsys, path, "single NumPy array")


def test_zip_that_is_not_an_npz(tmp_path, capsys):
    import zipfile

    path = tmp_path / "photos.npz"
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("readme.txt", "hello")
    _result_error(capsys, path, "zip archive of no NumPy arrays")


def test_truncated_zip(tmp_path, capsys):
    path = _write_npz(tmp_path / "cut.npz", _good_arrays())
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    _result_error(capsys, path, "damaged")


def test_missing_key(tmp_path, capsys):
    arrays = _good_arrays()
    del arrays["lights"]
    _result_error(capsys, _write_npz(tmp_path / "part.npz", arrays), "missing lights")


def test_pickled_objects_are_refused_without_unpickling(tmp_path, capsys):
    import numpy as np

    arrays = _good_arrays(metadata=np.array([{"a": 1}], dtype=object))
    _result_error(capsys, _write_npz(tmp_path / "obj.npz", arrays), "'metadata'", "Python objects")


def test_array_header_claiming_more_than_the_member_holds(tmp_path, capsys):
    """A weights header of 100000 x 100000 x 8 float32 (320 GB) in a tiny member is refused before reading."""
    import io
    import zipfile

    import numpy as np

    path = _write_npz(tmp_path / "bomb.npz", _good_arrays())
    with zipfile.ZipFile(path) as zf:
        members = {n: zf.read(n) for n in zf.namelist()}
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f4", "fortran_order": False,
                                               "shape": (100000, 100000, 8)})
    members["weights.npy"] = buf.getvalue() + bytes(64)
    with zipfile.ZipFile(path, "w") as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    _result_error(capsys, path, "'weights'", "(100000, 100000, 8)", "member holds")


def _bad_value(name):
    import json

    import numpy as np

    wl = np.arange(400.0, 701.0, 10.0)
    return {"int-weights": ("weights", np.zeros((2, 3, 3), np.int32)), "float-mask": ("mask", np.ones((2, 3))),
            "1d-basis": ("basis", np.ones(31)), "number-method": ("method", np.array(3.0)),
            "bogus-method": ("method", np.array("bogus")), "reversed-wavelengths": ("wavelengths", wl[::-1].copy()),
            "short-lights": ("lights", np.ones((1, 5))),
            "list-metadata": ("metadata", np.array(json.dumps([1, 2]))),
            "text-rmse": ("metadata", np.array(json.dumps({"chart_rmse": "high"})))}[name]


BAD_ARRAYS = {
    "int-weights": ("'weights'", "floating-point"),
    "float-mask": ("'mask'", "boolean"),
    "1d-basis": ("'basis'", "2 dimension"),
    "number-method": ("'method'", "a string"),
    "bogus-method": ("method 'bogus'", "one of"),
    "reversed-wavelengths": ("'wavelengths'", "evenly spaced"),
    "short-lights": ("inconsistent",),
    "list-metadata": ("metadata", "JSON object"),
    "text-rmse": ("chart_rmse", "non-negative number"),
}


@pytest.mark.parametrize("name", sorted(BAD_ARRAYS))
def test_wrong_dtypes_and_shapes_are_one_line(tmp_path, capsys, name):
    key, value = _bad_value(name)
    arrays = _good_arrays(**{key: value})
    _result_error(capsys, _write_npz(tmp_path / "bad.npz", arrays), *BAD_ARRAYS[name])


@pytest.mark.parametrize("flag, value", [("--weave-angle", "nan"), ("--fov", "nan"), ("--fov", "inf")])
def test_non_finite_render_flags_are_one_line(tmp_path, capsys, flag, value):
    _one_line_error(capsys, ["render", _sphere_scene(tmp_path), flag, value, "--size", "16x16", "--preset", "draft",
                             "--out", tmp_path / "o.png"], flag)


def test_scene_path_that_is_a_fifo_or_huge_is_refused_without_blocking(tmp_path, capsys):
    import os
    import subprocess
    import sys
    from pathlib import Path

    fifo = tmp_path / "pipe.toml"
    os.mkfifo(fifo)
    # a subprocess with a timeout: reading a FIFO that nobody writes would block for ever
    root = str(Path(__file__).resolve().parents[2])
    proc = subprocess.run([sys.executable, "-c", "import sys; from app.cli import main; sys.exit(main(sys.argv[1:]))",
                           "render", str(fifo), "--out", str(tmp_path / "o.png")], capture_output=True, text=True,
                          timeout=60, cwd=root, env={**os.environ, "PYTHONPATH": root})
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert "pipe.toml" in proc.stderr and "not a regular file" in proc.stderr
    big = tmp_path / "big.toml"
    with open(big, "wb") as fh:
        fh.truncate(2 << 20)
    _one_line_error(capsys, ["render", big, "--out", tmp_path / "o.png"], "big.toml", "too large")


def test_picks_with_nan_or_too_large_are_one_line(tmp_path, capsys):
    good = tmp_path / "a.xyz"
    good.write_text(_XYZ)
    picks = tmp_path / "picks.json"
    picks.write_text('[{"pair": [0, 1], "points": [[[0, 0, NaN], [1, 0, 0], [0, 1, 0]], '
                     '[[0, 0, 0], [1, 0, 0], [0, 1, 0]]]}]')
    argv = ["register", good, good, "--picks", picks, "--poses", tmp_path / "p.json"]
    _one_line_error(capsys, argv, "picks.json", "finite")
    with open(picks, "wb") as fh:
        fh.truncate(2 << 20)
    _one_line_error(capsys, argv, "picks.json", "too large")


def test_render_under_an_address_space_limit_is_refused_with_a_size_that_fits(tmp_path):
    """``ulimit -v 3 GB``: the estimate counts the room under the limit, not the machine's free memory."""
    import os
    import resource
    import subprocess
    import sys
    from pathlib import Path

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))

    root = str(Path(__file__).resolve().parents[2])
    proc = subprocess.run([sys.executable, "-c", "import sys; from app.cli import main; sys.exit(main(sys.argv[1:]))",
                           "render", str(_sphere_scene(tmp_path)), "--size", "8000x8000", "--preset", "draft",
                           "--out", str(tmp_path / "o.png")], capture_output=True, text=True, timeout=120,
                          cwd=root, env={**os.environ, "PYTHONPATH": root}, preexec_fn=limit)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert "8000x8000 render needs about" in proc.stderr and "render at most" in proc.stderr


@pytest.mark.parametrize("mesh, needle", [("a\\u0000b.ply", "NUL byte"), ("x" * 5000 + ".ply", "cannot be used"),
                                          ("", "empty string")])
def test_scene_mesh_paths_the_os_cannot_take(tmp_path, capsys, mesh, needle):
    scene = tmp_path / "scene.toml"
    scene.write_text(f'[[object]]\nmesh = "{mesh}"\n')
    _one_line_error(capsys, ["render", scene, "--out", tmp_path / "o.png"], "scene.toml", "mesh", needle)


def test_command_line_mesh_path_too_long(tmp_path, capsys):
    _one_line_error(capsys, ["render", "y" * 5000 + ".ply", "--out", tmp_path / "o.png"], "cannot be used")
