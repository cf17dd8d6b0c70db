"""Binary PLY output of triangle meshes with per-vertex normals.

The format is the Stanford polygon file format (Turk 1994, "The PLY Polygon
File Format"): an ASCII header, then ``binary_little_endian`` vertex records
``x y z nx ny nz`` (float32) and face records ``uchar count, int index x 3``.
This is what Open3D, MeshLab and Blender read; ``render.meshio.load_mesh``
reads it back.  The file is written atomically
(:func:`processing.common.files.atomic_write_bytes`: a temporary file in the
same folder, renamed into place), so a crash never leaves a truncated mesh
behind.

References
----------
.. [1] Turk, G. (1994). The PLY polygon file format.

Examples
--------
>>> import tempfile, pathlib
>>> path = pathlib.Path(tempfile.mkdtemp()) / "tri.ply"
>>> write_mesh_ply(path, [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], [[0, 0, 1]] * 3)
>>> path.read_bytes().startswith(b"ply")
True
>>> path.stat().st_size
308
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from processing.common.files import atomic_write_bytes
from processing.errors import InputError

__all__ = ["write_mesh_ply"]


def write_mesh_ply(
    path: str | os.PathLike[str],
    vertices: ArrayLike,
    triangles: ArrayLike,
    vertex_normals: ArrayLike | None = None,
    *,
    comment: str | None = None,
) -> None:
    """Write a triangle mesh as binary little-endian PLY.

    Parameters
    ----------
    path
        Output file (``.ply``); its folder must exist.
    vertices
        ``(V, 3)`` finite positions (mm); stored as float32.
    triangles
        ``(T, 3)`` vertex indices in 0..V-1.
    vertex_normals
        Optional ``(V, 3)`` finite normals (stored as float32 ``nx ny nz``).
    comment
        Optional one-line comment for the header (e.g. units).

    Raises
    ------
    ValueError
        Wrong shapes, non-finite values, indices out of range, a suffix other
        than ``.ply``, a comment with a line break.
    FileNotFoundError
        The folder does not exist.
    """
    p = Path(path)
    if p.suffix.lower() != ".ply":
        raise InputError(f"path: '{p}' must end in .ply")
    if not p.parent.is_dir():
        raise FileNotFoundError(f"path: the folder '{p.parent}' does not exist")
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles)
    if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] == 0:
        raise InputError(f"vertices must be a non-empty (V, 3) array, got shape {v.shape}")
    if t.ndim != 2 or t.shape[1] != 3 or t.shape[0] == 0:
        raise InputError(f"triangles must be a non-empty (T, 3) array, got shape {t.shape}")
    if t.dtype.kind not in "iu":
        raise InputError(f"triangles must be integer indices, got dtype {t.dtype}")
    if not np.all(np.isfinite(v)):
        raise InputError("vertices hold NaN or infinite coordinates")
    if t.min() < 0 or t.max() >= v.shape[0]:
        raise InputError(f"triangles index vertices outside 0..{v.shape[0] - 1}")
    n = None
    if vertex_normals is not None:
        n = np.asarray(vertex_normals, dtype=np.float64)
        if n.shape != v.shape:
            raise InputError(f"vertex_normals must have the shape of vertices {v.shape}, got {n.shape}")
        if not np.all(np.isfinite(n)):
            raise InputError("vertex_normals hold NaN or infinite values")
    if comment is not None and ("\n" in comment or "\r" in comment):
        raise InputError("comment must be a single line")

    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if n is not None:
        fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
    vrec = np.empty(v.shape[0], dtype=fields)
    for k, name in enumerate("xyz"):
        vrec[name] = v[:, k]
        if n is not None:
            vrec["n" + name] = n[:, k]
    frec = np.empty(t.shape[0], dtype=[("n", "u1"), ("i", "<i4", (3,))])
    frec["n"] = 3
    frec["i"] = t
    header = ["ply", "format binary_little_endian 1.0"]
    if comment:
        header.append(f"comment {comment}")
    header.append(f"element vertex {v.shape[0]}")
    header += [f"property float {name}" for name, _ in fields]
    header += [f"element face {t.shape[0]}", "property list uchar int vertex_indices", "end_header"]
    data = ("\n".join(header) + "\n").encode("ascii") + vrec.tobytes() + frec.tobytes()

    atomic_write_bytes(p, data, make_parents=False)
