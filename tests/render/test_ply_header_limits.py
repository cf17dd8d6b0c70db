"""PLY headers Open3D's reader (RPly) cannot take are refused in Python first (render.meshio.check_ply_header).

RPly keeps a header line in 1024 bytes and a name in 256; a longer comment
line aborted the whole process ("*** buffer overflow detected ***", exit 134),
so the CLI cases run in a subprocess.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from app.errors import UsageError
from app.workflows.cloud_registration import read_cloud
from render.errors import MeshError
from render.material_mesh import read_material_mesh
from render.meshio import PLY_MAX_LINE_BYTES, PLY_MAX_WORD_BYTES, check_ply_header, load_mesh

ROOT = Path(__file__).resolve().parents[2]


def _ply(path: Path, *, comment: str = "ok", prop: str = "z", face_material: bool = False) -> Path:
    """A binary tetrahedron with one comment line and a third vertex property named ``prop``."""
    v = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10]], dtype="<f4")
    faces = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
    head = ["ply", "format binary_little_endian 1.0", f"comment {comment}", "element vertex 4",
            "property float x", "property float y", f"property float {prop}", "element face 4",
            "property list uchar int vertex_indices"]
    body = v.tobytes()
    if face_material:
        head.append("property int material")
    for f in faces:
        body += bytes([3]) + np.array(f, dtype="<i4").tobytes()
        if face_material:
            body += np.array([0], dtype="<i4").tobytes()
    path.write_bytes(("\n".join([*head, "end_header"]) + "\n").encode() + body)
    return path


def _kogei(*argv: object, cwd: Path) -> subprocess.CompletedProcess:
    code = "import sys; from app.cli import main; sys.exit(main(sys.argv[1:]))"
    return subprocess.run([sys.executable, "-c", code, *map(str, argv)], cwd=cwd, capture_output=True, text=True,
                          timeout=120, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})


def test_limits_are_rplys_and_a_line_at_the_limit_passes():
    assert (PLY_MAX_LINE_BYTES, PLY_MAX_WORD_BYTES) == (1023, 255)
    line = b"comment " + b"x" * (PLY_MAX_LINE_BYTES - 8)
    check_ply_header(b"ply\nformat ascii 1.0\n" + line + b"\nend_header\n", "a.ply")
    check_ply_header(b"ply\nelement vertex 1\nproperty float " + b"n" * PLY_MAX_WORD_BYTES + b"\nend_header\n", "a.ply")
    # the binary body after end_header is not looked at, nor a file that is no PLY
    check_ply_header(b"ply\nend_header\n" + b"\x01" * 5000, "a.ply")
    check_ply_header(b"x" * 5000, "a.ply")


@pytest.mark.parametrize("head, match", [
    (b"ply\ncomment " + b"x" * 1100 + b"\nend_header\n", r"'a\.ply': PLY header line 2 is 1108 bytes long; .*at most "
                                                          r"1023 bytes a line: shorten or remove that line"),
    (b"ply\ncomment " + b"x" * 70000, r"'a\.ply': PLY header line 2 is \d+ bytes long"),
    (b"ply\nelement vertex 1\nproperty float " + b"n" * 300 + b"\nend_header\n",
     r"'a\.ply': PLY header line 3 has a 300-byte word 'nnnn.*names of at most 255 bytes: rename that element"),
])
def test_header_beyond_the_limits_is_refused(head, match):
    with pytest.raises(MeshError, match=match):
        check_ply_header(head, "a.ply")


def test_every_ply_reader_refuses_a_long_header_line(tmp_path):
    long = "x" * 1100
    with pytest.raises(MeshError, match=r"mesh\.ply': PLY header line 3 is 1108 bytes long"):
        load_mesh(_ply(tmp_path / "mesh.ply", comment=long))
    with pytest.raises(UsageError, match=r"cloud\.ply': PLY header line 3 is 1108 bytes long"):
        read_cloud(_ply(tmp_path / "cloud.ply", comment=long))
    with pytest.raises(MeshError, match=r"mat\.ply': PLY header line 3 is 1108 bytes long"):
        read_material_mesh(_ply(tmp_path / "mat.ply", comment=long, face_material=True))
    with pytest.raises(UsageError, match=r"name\.ply': PLY header line 7 has a 300-byte word"):
        read_cloud(_ply(tmp_path / "name.ply", prop="z" * 300))
    assert load_mesh(_ply(tmp_path / "fine.ply", comment="x" * 900)).n_triangles == 4


def test_cli_long_comment_is_one_line_and_exit_2(tmp_path):
    ply = _ply(tmp_path / "long.ply", comment="x" * 1100)
    xyz = tmp_path / "a.xyz"
    xyz.write_text("".join(f"{x} {y} {z}\n" for x, y, z in np.random.default_rng(0).uniform(0, 10, (20, 3))))
    for argv in (("render", ply, "--size", "64x48", "--out", tmp_path / "o.png"),
                 ("register", xyz, ply, "--poses", tmp_path / "p.json")):
        proc = _kogei(*argv, cwd=tmp_path)
        assert proc.returncode == 2, proc.stderr
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and "long.ply': PLY header line 3 is 1108 bytes long" in lines[0], proc.stderr
