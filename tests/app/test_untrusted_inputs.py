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
    (_SPHERE + "scale = 0\n", ("scale", "> 0")),
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
    ("[camera]\nfov = 0\n" + _SPHERE, ("fov", "between 0 and 180")),
    ("[camera]\nfov = 400\n" + _SPHERE, ("fov", "between 0 and 180")),
    ("[camera]\neye = 42\n" + _SPHERE, ("eye", "three numbers", "integer")),
    ("[camera]\neye = {x = 1}\n" + _SPHERE, ("eye", "three numbers", "table")),
    ("[camera]\nup = [0, 0, inf]\n" + _SPHERE, ("up", "finite")),
    ("[sky]\nkind = 1\n" + _SPHERE, ("kind", "one of")),
    ("[sky]\nzenith = -1\n" + _SPHERE, ("zenith", ">= 0")),
    ("[sky]\nhorizon = nan\n" + _SPHERE, ("horizon", "finite")),
    ("[sky]\nspectrum = [1]\n" + _SPHERE, ("spectrum", "string")),
    ("[[light]]\nkind = 'area'\ndirection = [0, 0, 1]\n" + _SPHERE, ("kind", "directional, point")),
    ("[[light]]\ndirection = [0, 0, 0]\n" + _SPHERE, ("direction", "non-zero")),
    ("[[light]]\ndirection = 'up'\n" + _SPHERE, ("direction", "three numbers")),
    ("[[light]]\ndirection = [0, 0, 1]\nintensity = -2\n" + _SPHERE, ("intensity", "> 0")),
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
