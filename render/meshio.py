"""Triangle meshes for rendering: loading, validation and smooth vertex normals.

Files are read with Open3D's legacy reader (``open3d.io.read_triangle_mesh``:
PLY, OBJ, STL, OFF, glTF ``.gltf`` / ``.glb``) and checked before they reach
the ray tracer: an unreadable or empty file, non-finite vertices or
out-of-range indices raise :class:`~render.errors.MeshError` naming the file;
zero-area triangles are dropped and counted (an error if none remain).

Smooth shading needs one normal per vertex.  When a file has none (or
invalid ones) they are computed as the area-weighted mean of the adjacent
face normals (Max 1999, "Weights for computing vertex normals from facet
normals": the unnormalised cross product of two edges is twice the face area
times its unit normal, so summing cross products weights faces by area).
STL stores only facet normals and repeats each vertex per facet, so STL
vertices are merged by position and smooth normals are computed.

References
----------
Max, N. (1999), "Weights for computing vertex normals from facet normals",
Journal of Graphics Tools 4(2), 1-6 (DOI not verified).

Examples
--------
>>> v = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]
>>> m = make_mesh(v, [[0, 1, 2], [1, 3, 2]])
>>> m.vertex_normals[0].tolist(), m.n_triangles
([0.0, 0.0, 1.0], 2)
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from render.errors import MeshError, MeshWarning
from render.limits import MAX_COORDINATE_MM, MAX_MESH_OFFSET_EXTENTS, MIN_MESH_EXTENT_MM

__all__ = [
    "Mesh",
    "MeshError",
    "MeshWarning",
    "MESH_SUFFIXES",
    "load_mesh",
    "make_mesh",
    "smooth_vertex_normals",
    "face_normals",
    "check_declared_counts",
    "check_ply_header",
    "PLY_MAX_LINE_BYTES",
    "PLY_MAX_WORD_BYTES",
]

#: File name suffixes :func:`load_mesh` accepts.
MESH_SUFFIXES: tuple[str, ...] = (".ply", ".obj", ".stl", ".off", ".gltf", ".glb")

#: A triangle is degenerate when twice its area is at most this fraction of
#: its longest edge squared (collinear or repeated vertices, within rounding).
_DEGENERATE_RTOL = 1e-12


@dataclass(frozen=True, eq=False)
class Mesh:
    """A validated triangle mesh.

    Attributes
    ----------
    vertices
        float64 ``(V, 3)``, finite.
    triangles
        int64 ``(T, 3)`` vertex indices, counter-clockwise seen from outside
        for outward normals, no zero-area triangle.
    vertex_normals
        float64 ``(V, 3)`` unit normals used for smooth shading.
    material_index
        Optional int64 material index per vertex ``(V,)`` or per triangle
        ``(T,)``, see ``material_index_on``.
    material_index_on
        ``"vertex"``, ``"triangle"`` or None.
    source
        File path or a description of where the arrays came from.
    dropped_triangles
        Number of zero-area triangles removed on loading.
    normals_computed
        True when the vertex normals were computed rather than read.
    """

    vertices: NDArray[np.float64]
    triangles: NDArray[np.int64]
    vertex_normals: NDArray[np.float64]
    material_index: NDArray[np.int64] | None = None
    material_index_on: str | None = None
    source: str = "<arrays>"
    dropped_triangles: int = 0
    normals_computed: bool = False
    _bounds: tuple[NDArray[np.float64], NDArray[np.float64]] | None = field(default=None, repr=False)

    @property
    def n_vertices(self) -> int:
        """Number of vertices V."""
        return int(self.vertices.shape[0])

    @property
    def n_triangles(self) -> int:
        """Number of triangles T."""
        return int(self.triangles.shape[0])

    def bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Axis-aligned bounds ``(min, max)`` of the vertices used by triangles.

        Returns
        -------
        tuple of ndarray
            Two ``(3,)`` copies: the lowest and highest coordinates.
        """
        if self._bounds is None:
            used = np.zeros(self.vertices.shape[0], dtype=bool)
            used[self.triangles.ravel()] = True
            pts = self.vertices[used]
            object.__setattr__(self, "_bounds", (pts.min(axis=0), pts.max(axis=0)))
        lo, hi = self._bounds
        return lo.copy(), hi.copy()


def face_normals(vertices: ArrayLike, triangles: ArrayLike, *, unit: bool = True) -> NDArray[np.float64]:
    """Normals of the triangles, right-handed with the vertex order.

    Parameters
    ----------
    vertices
        ``(V, 3)`` positions.
    triangles
        ``(T, 3)`` vertex indices.
    unit
        Normalise to unit length (zero for a zero-area triangle); False
        keeps the cross product, whose length is twice the triangle's area.

    Returns
    -------
    ndarray
        float64 ``(T, 3)``.

    Examples
    --------
    >>> face_normals([[0, 0, 0], [2, 0, 0], [0, 2, 0]], [[0, 1, 2]], unit=False).tolist()
    [[0.0, 0.0, 4.0]]
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    v0 = v[t[:, 0]]
    n = np.cross(v[t[:, 1]] - v0, v[t[:, 2]] - v0)
    if unit:
        length = np.linalg.norm(n, axis=1, keepdims=True)
        n = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
    return n


def smooth_vertex_normals(vertices: ArrayLike, triangles: ArrayLike) -> NDArray[np.float64]:
    """Area-weighted vertex normals (unit length).

    Each vertex gets the normalised sum of the unnormalised normals (twice the
    area times the unit normal) of the triangles that use it.  A vertex whose
    sum vanishes (two opposite faces) takes the normal of one adjacent face;
    a vertex used by no triangle gets (0, 0, 1).

    Parameters
    ----------
    vertices
        ``(V, 3)`` positions.
    triangles
        ``(T, 3)`` indices.

    Returns
    -------
    ndarray
        float64 ``(V, 3)``.

    Examples
    --------
    >>> v = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]
    >>> n = smooth_vertex_normals(v, [[0, 2, 1], [0, 1, 3]])   # faces -z and -y
    >>> np.round(n[0], 4).tolist()
    [0.0, -0.7071, -0.7071]
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    fn = face_normals(v, t, unit=False)
    nv = v.shape[0]
    flat = t.ravel()
    acc = np.empty((nv, 3))
    for c in range(3):
        acc[:, c] = np.bincount(flat, weights=np.repeat(fn[:, c], 3), minlength=nv)
    length = np.linalg.norm(acc, axis=1)
    bad = length <= 1e-300
    out = np.divide(acc, length[:, None], out=np.zeros_like(acc), where=~bad[:, None])
    if np.any(bad):
        fallback = np.zeros((nv, 3))
        fallback[:, 2] = 1.0
        unit_fn = face_normals(v, t, unit=True)
        fallback[flat] = np.repeat(unit_fn, 3, axis=0)
        out[bad] = fallback[bad]
    return out


def _as_index_array(value: ArrayLike, name: str, source: str) -> NDArray[np.int64]:
    arr = np.asarray(value)
    if arr.dtype.kind == "f":
        if not np.all(np.isfinite(arr)) or not np.all(arr == np.round(arr)):
            raise MeshError(f"{source}: {name} must hold whole numbers (indices), got non-integer values")
    elif arr.dtype.kind not in "iu" and arr.size:
        raise MeshError(f"{source}: {name} must be an integer array, got dtype {arr.dtype}")
    return arr.astype(np.int64)


def make_mesh(
    vertices: ArrayLike,
    triangles: ArrayLike,
    vertex_normals: ArrayLike | None = None,
    material_index: ArrayLike | None = None,
    material_index_on: str | None = None,
    *,
    source: str = "<arrays>",
) -> Mesh:
    """Validate arrays and build a :class:`Mesh`.

    Parameters
    ----------
    vertices
        ``(V, 3)`` positions (scene units).
    triangles
        ``(T, 3)`` vertex indices.
    vertex_normals
        Optional ``(V, 3)`` normals; computed (area-weighted) when None, and
        recomputed with a :class:`MeshWarning` when some used ones are zero
        or non-finite.
    material_index
        Optional material index per vertex ``(V,)`` or per triangle ``(T,)``.
    material_index_on
        ``"vertex"`` or ``"triangle"``; inferred from the length when None
        (required when V == T).
    source
        Name used in messages (the file path when loading).

    Returns
    -------
    Mesh
        Without zero-area triangles, with unit vertex normals.

    Raises
    ------
    MeshError
        No vertices or triangles, wrong shapes, non-finite vertices,
        out-of-range indices, no triangle of non-zero area.

    Warns
    -----
    MeshWarning
        When zero-area triangles were dropped (counted in
        ``Mesh.dropped_triangles``) or normals were recomputed.
    """
    v, t = _checked_arrays(vertices, triangles, source)
    mat, on = _checked_material_index(material_index, material_index_on, v.shape[0], t.shape[0], source)
    t, mat, dropped = _drop_degenerate(v, t, mat, on, source)
    normals, computed = _vertex_normals(vertex_normals, v, t, source)
    return Mesh(
        vertices=v,
        triangles=t,
        vertex_normals=normals,
        material_index=mat,
        material_index_on=on if mat is not None else None,
        source=source,
        dropped_triangles=dropped,
        normals_computed=computed,
    )


def _checked_arrays(vertices: ArrayLike, triangles: ArrayLike,
                    source: str) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Vertices ``(V, 3)`` and triangles ``(T, 3)``, refused when empty, non-finite or out of range."""
    v = np.asarray(vertices, dtype=np.float64) if np.size(vertices) else np.zeros((0, 3))
    if v.ndim != 2 or v.shape[1] != 3:
        raise MeshError(f"{source}: vertices must have shape (V, 3), got {np.shape(vertices)}")
    t = _as_index_array(triangles, "triangles", source) if np.size(triangles) else np.zeros((0, 3), np.int64)
    if t.ndim != 2 or t.shape[1] != 3:
        raise MeshError(f"{source}: triangles must have shape (T, 3), got {np.shape(triangles)}")
    if v.shape[0] == 0 or t.shape[0] == 0:
        what = "a point cloud" if v.shape[0] else "empty"
        raise MeshError(
            f"{source}: the mesh has {v.shape[0]} vertices and {t.shape[0]} triangles ({what}); "
            "the renderer needs a triangle mesh (reconstruct a surface or export the faces)"
        )
    finite = np.all(np.isfinite(v), axis=1)
    if not np.all(finite):
        bad = np.flatnonzero(~finite)
        raise MeshError(
            f"{source}: {bad.size} vertices have NaN or infinite coordinates (first: vertex {bad[0]} = "
            f"{v[bad[0]].tolist()}); remove or repair them before rendering"
        )
    _check_extent(v, source)
    lo, hi = int(t.min()), int(t.max())
    if lo < 0 or hi >= v.shape[0]:
        bad_tri = int(np.flatnonzero(np.any((t < 0) | (t >= v.shape[0]), axis=1))[0])
        raise MeshError(
            f"{source}: triangle {bad_tri} uses vertex index {t[bad_tri].tolist()} outside 0..{v.shape[0] - 1} "
            "(the file's face list does not match its vertex list)"
        )
    return v, t


def _check_extent(v: NDArray[np.float64], source: str) -> None:
    """Refuse coordinates beyond ``render.limits.MAX_COORDINATE_MM`` (float32 ray casting; squares overflow)."""
    reach = float(np.abs(v).max())
    if reach > MAX_COORDINATE_MM:
        raise MeshError(f"{source}: coordinates reach {reach:.3g} mm; the renderer takes coordinates within "
                        f"+-{MAX_COORDINATE_MM:g} mm (float32 ray casting): scale or move the mesh into that range")


def check_mesh_extent(lo: NDArray[np.float64], hi: NDArray[np.float64], name: str) -> None:
    """Refuse a mesh float32 ray casting cannot resolve, given its bounds (limits in :mod:`render.limits`).

    An extent (largest side of the bounding box) below ``MIN_MESH_EXTENT_MM``
    (geometric optics does not hold below a micrometre, and float32 normals
    underflow) and a mesh more than ``MAX_MESH_OFFSET_EXTENTS`` extents from
    the origin are refused.

    Parameters
    ----------
    lo, hi
        ``(3,)`` lowest and highest coordinates, mm.
    name
        The mesh (its file) in messages.

    Raises
    ------
    MeshError
        One line naming ``name``, its extent and its offset.
    """
    extent = float(np.max(np.asarray(hi) - np.asarray(lo)))
    if extent < MIN_MESH_EXTENT_MM:
        raise MeshError(f"{name}: the mesh spans only {extent:.3g} mm; the renderer takes meshes of at least "
                        f"{MIN_MESH_EXTENT_MM:g} mm (coordinates are millimetres): scale it up")
    centre = float(np.abs(0.5 * (np.asarray(lo) + np.asarray(hi))).max())
    if centre > MAX_MESH_OFFSET_EXTENTS * extent:
        raise MeshError(f"{name}: the mesh spans {extent:.3g} mm but lies {centre:.3g} mm from the origin; float32 "
                        f"ray casting resolves a mesh at most {MAX_MESH_OFFSET_EXTENTS:g} times its extent from the "
                        "origin: translate it toward the origin")


def _checked_material_index(material_index: ArrayLike | None, material_index_on: str | None, n_vertices: int,
                            n_triangles: int, source: str) -> tuple[NDArray[np.int64] | None, str | None]:
    """The material index per vertex or per triangle and which of the two it is (None, None: no index)."""
    if material_index is None:
        return None, None
    on = material_index_on
    mat = _as_index_array(material_index, "material_index", source).ravel()
    if on is None:
        if mat.size == n_vertices and mat.size != n_triangles:
            on = "vertex"
        elif mat.size == n_triangles and mat.size != n_vertices:
            on = "triangle"
        elif mat.size == n_vertices:
            raise MeshError(
                f"{source}: material_index has {mat.size} entries and the mesh has as many vertices as "
                "triangles; say material_index_on='vertex' or 'triangle'"
            )
        else:
            raise MeshError(
                f"{source}: material_index has {mat.size} entries; expected one per vertex "
                f"({n_vertices}) or one per triangle ({n_triangles})"
            )
    expected = {"vertex": n_vertices, "triangle": n_triangles}.get(on)
    if expected is None:
        raise MeshError(f"{source}: material_index_on must be 'vertex' or 'triangle', got {on!r}")
    if mat.size != expected:
        raise MeshError(
            f"{source}: material_index has {mat.size} entries but material_index_on={on!r} needs {expected}"
        )
    if mat.size and mat.min() < 0:
        raise MeshError(f"{source}: material_index must be >= 0, found {int(mat.min())}")
    return mat, on


def _drop_degenerate(v: NDArray[np.float64], t: NDArray[np.int64], mat: NDArray[np.int64] | None, on: str | None,
                     source: str) -> tuple[NDArray[np.int64], NDArray[np.int64] | None, int]:
    """Triangles and material index without the zero-area triangles (warned about), and how many were dropped."""
    e0 = v[t[:, 1]] - v[t[:, 0]]
    e1 = v[t[:, 2]] - v[t[:, 0]]
    e2 = v[t[:, 2]] - v[t[:, 1]]
    twice_area = np.linalg.norm(np.cross(e0, e1), axis=1)
    longest2 = np.max(np.stack([np.einsum("ij,ij->i", e, e) for e in (e0, e1, e2)]), axis=0)
    degenerate = (twice_area <= _DEGENERATE_RTOL * longest2) | (longest2 == 0.0)
    dropped = int(np.count_nonzero(degenerate))
    if dropped == t.shape[0]:
        raise MeshError(
            f"{source}: all {dropped} triangles have zero area (repeated or collinear vertices); "
            "nothing is left to render"
        )
    if dropped:
        t = t[~degenerate]
        if mat is not None and on == "triangle":
            mat = mat[~degenerate]
        warnings.warn(
            f"{source}: dropped {dropped} zero-area triangles of {dropped + t.shape[0]}",
            MeshWarning,
            stacklevel=3,   # the caller of make_mesh
        )
    return t, mat, dropped


def _vertex_normals(vertex_normals: ArrayLike | None, v: NDArray[np.float64], t: NDArray[np.int64],
                    source: str) -> tuple[NDArray[np.float64], bool]:
    """Unit vertex normals (the given ones, or computed when absent or unusable) and whether they were computed."""
    if vertex_normals is None:
        return smooth_vertex_normals(v, t), True
    n = np.asarray(vertex_normals, dtype=np.float64)
    if n.shape != v.shape:
        raise MeshError(f"{source}: vertex_normals must have shape {v.shape}, got {n.shape}")
    length = np.linalg.norm(n, axis=1)
    used = np.zeros(v.shape[0], dtype=bool)
    used[t.ravel()] = True
    bad = used & ~(np.isfinite(length) & (length > 0))
    if np.any(bad):
        warnings.warn(
            f"{source}: {int(bad.sum())} vertex normals are zero or non-finite; "
            "recomputing all normals from the faces",
            MeshWarning,
            stacklevel=3,   # the caller of make_mesh
        )
        return smooth_vertex_normals(v, t), True
    safe = np.where(length > 0, length, 1.0)
    return np.where(np.isfinite(n), n, 0.0) / np.where(np.isfinite(safe), safe, 1.0)[:, None], False


def load_mesh(path: str | os.PathLike[str]) -> Mesh:
    """Read and validate a mesh file.

    Parameters
    ----------
    path
        A ``.ply``, ``.obj``, ``.stl``, ``.off``, ``.gltf`` or ``.glb`` file.
        Triangle material ids of OBJ / glTF files (more than one distinct
        id) become a per-triangle material index, renumbered 0..k-1 in the
        order of the file's material list.

    Returns
    -------
    Mesh
        As :func:`make_mesh` builds it, ``source`` the file path.

    Raises
    ------
    MeshError
        The file does not exist, is not readable, has an unsupported suffix,
        is empty or not a valid mesh of its format, or fails the checks of
        :func:`make_mesh`.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "tri.obj"
    >>> _ = path.write_text(chr(10).join(["v 0 0 0", "v 1 0 0", "v 0 1 0", "f 1 2 3", ""]))
    >>> m = load_mesh(path)
    >>> m.n_triangles, m.vertex_normals[0].tolist(), m.normals_computed
    (1, [0.0, 0.0, 1.0], True)
    >>> load_mesh(path.with_suffix(".ply"))  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    render.errors.MeshError: mesh file '...tri.ply' does not exist
    """
    import open3d as o3d

    p = Path(path)
    name = str(p)
    if not p.exists():
        raise MeshError(f"mesh file '{name}' does not exist")
    if not p.is_file():
        raise MeshError(f"mesh path '{name}' is not a file")
    suffix = p.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise MeshError(
            f"mesh file '{name}' has suffix {p.suffix!r}; supported formats are "
            + ", ".join(MESH_SUFFIXES)
        )
    if not os.access(p, os.R_OK):
        raise MeshError(f"mesh file '{name}' is not readable (permission denied)")
    size = p.stat().st_size
    if size == 0:
        raise MeshError(f"mesh file '{name}' is empty (0 bytes)")
    check_declared_counts(p)
    try:
        with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
            raw = o3d.io.read_triangle_mesh(name)
    except Exception as exc:  # Open3D raises RuntimeError or plain Exception subclasses
        raise MeshError(f"mesh file '{name}' could not be read: {exc}") from exc
    n_v, n_t = len(raw.vertices), len(raw.triangles)
    if n_v == 0:
        raise MeshError(
            f"mesh file '{name}' could not be read as {suffix[1:].upper()} or holds no vertices "
            f"({size} bytes): the file is corrupt, truncated or not in the format its suffix says"
        )
    if n_t == 0:
        raise MeshError(
            f"mesh file '{name}' has {n_v} vertices but no triangles (a point cloud?); "
            "reconstruct a surface before rendering"
        )
    if suffix == ".stl":
        # STL repeats vertices per facet and stores facet normals only.
        raw.vertex_normals = o3d.utility.Vector3dVector(np.zeros((0, 3)))
        raw = raw.remove_duplicated_vertices()
    vertices = np.asarray(raw.vertices, dtype=np.float64)
    triangles = np.asarray(raw.triangles, dtype=np.int64)
    normals = np.asarray(raw.vertex_normals, dtype=np.float64) if raw.has_vertex_normals() else None
    mat = None
    if raw.has_triangle_material_ids():
        ids = np.asarray(raw.triangle_material_ids, dtype=np.int64)
        if ids.size == triangles.shape[0] and np.unique(ids).size > 1:
            mat = np.unique(ids, return_inverse=True)[1].reshape(-1)
    return make_mesh(
        vertices,
        triangles,
        normals,
        mat,
        "triangle" if mat is not None else None,
        source=name,
    )


# ----------------------------------------------------------------------------------- header checks
#: Bytes of one PLY scalar of each type name.
_PLY_SIZES = {"char": 1, "int8": 1, "uchar": 1, "uint8": 1, "short": 2, "int16": 2, "ushort": 2, "uint16": 2,
              "int": 4, "int32": 4, "uint": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}

#: The most header bytes read to find a PLY's ``end_header`` or a PCD's ``DATA`` line.
_HEADER_BYTES = 1 << 16

#: Largest expansion of LZF (binary_compressed PCD) data: a 3-byte back reference yields at most 264 bytes.
_LZF_MAX_RATIO = 88


#: Longest PLY header line (bytes, without its line break) Open3D's reader takes: RPly's ``LINESIZE`` (1024) less
#: its terminating NUL.  A longer line makes RPly abort the process (buffer overflow), not fail.
PLY_MAX_LINE_BYTES = 1023

#: Longest word of a PLY header (an element / property name, a type; bytes): RPly's ``WORDSIZE`` (256) less the NUL.
PLY_MAX_WORD_BYTES = 255


def check_ply_header(head: bytes, name: str) -> None:
    r"""Refuse a PLY header that Open3D's PLY reader (RPly) cannot take, before it is handed to it.

    RPly keeps a header line in a 1024-byte buffer and a word in a 256-byte
    one; a longer ``comment`` line aborts the whole process and a longer name
    fails with lines of C-library noise.  Every header line up to
    ``end_header`` is checked: at most :data:`PLY_MAX_LINE_BYTES` bytes, and
    outside ``comment`` / ``obj_info`` lines words of at most
    :data:`PLY_MAX_WORD_BYTES` bytes.  Anything not starting with the ``ply``
    magic is left to the reader.

    Parameters
    ----------
    head
        The file's first bytes (at least its header, when it has one).
    name
        The file, for the message.

    Raises
    ------
    MeshError
        One line naming the file, the header line and the limit.

    Examples
    --------
    >>> check_ply_header(b"ply\nformat ascii 1.0\ncomment ok\nend_header\n", "a.ply")
    >>> check_ply_header(b"ply\ncomment " + b"x" * 1100 + b"\nend_header\n", "a.ply")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    render.errors.MeshError: 'a.ply': PLY header line 2 is 1108 bytes long; ...at most 1023 bytes a line...
    """
    if not head.startswith(b"ply"):
        return
    for number, line in enumerate(head.split(b"\n"), start=1):
        if len(line) > PLY_MAX_LINE_BYTES:
            raise MeshError(
                f"'{name}': PLY header line {number} is {len(line)} bytes long; Open3D's PLY reader takes at most "
                f"{PLY_MAX_LINE_BYTES} bytes a line: shorten or remove that line (e.g. a long comment)"
            )
        words = line.split()
        if words[:1] == [b"end_header"]:
            return
        if words[:1] in ([b"comment"], [b"obj_info"]):
            continue
        word = next((w for w in words if len(w) > PLY_MAX_WORD_BYTES), None)
        if word is not None:
            raise MeshError(
                f"'{name}': PLY header line {number} has a {len(word)}-byte word "
                f"{word[:20].decode('ascii', 'replace')!r}...; Open3D's PLY reader takes names of at most "
                f"{PLY_MAX_WORD_BYTES} bytes: rename that element or property"
            )


def check_declared_counts(path: str | os.PathLike[str]) -> int | None:
    r"""Check the element counts a file's header declares against the file's size, before a reader allocates.

    PLY (``element`` lines), OFF (the counts line), binary STL (the triangle
    count), PCD (``POINTS``) and PTS (the first line) say how many records
    follow; Open3D's readers allocate that many at once, so a header that
    claims 2e9 vertices in a 200-byte file would exhaust memory.  Each record
    needs at least some bytes (binary: the size of its fields; text: one
    character and a separator per value), so a count the rest of the file
    cannot hold is refused.  Other formats (OBJ, glTF, XYZ) carry no counts.

    Parameters
    ----------
    path
        A mesh or point-cloud file; the suffix selects the format.

    Returns
    -------
    int or None
        The number of vertices / points the header declares (None: the
        format declares none).

    Raises
    ------
    MeshError
        One line naming the file, the declared count and the bytes there are.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "big.ply"
    >>> _ = p.write_text("ply\nformat ascii 1.0\nelement vertex 2000000000\nproperty float x\nend_header\n0\n")
    >>> check_declared_counts(p)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    render.errors.MeshError: ...declares 2000000000 vertex records (at least 4000000000 bytes) but only 2 bytes...
    """
    p = Path(path)
    suffix = p.suffix.lower()
    reader = {".ply": _ply_counts, ".off": _off_counts, ".stl": _stl_counts, ".pcd": _pcd_counts,
              ".pts": _pts_counts}.get(suffix)
    if reader is None:
        return None
    try:
        size = p.stat().st_size
        with open(p, "rb") as fh:
            head = fh.read(_HEADER_BYTES)
    except OSError as exc:
        raise MeshError(f"'{p}' could not be read: {exc.strerror or exc}") from None
    if suffix == ".ply":
        check_ply_header(head, str(p))
    try:
        found = reader(head, size)
    except MeshError as exc:
        raise MeshError(f"'{p}': {exc}; the header is damaged") from None
    if found is None:
        return None
    declared, need, have, count = found
    if need > have:
        raise MeshError(
            f"'{p}': its header declares {declared} (at least {need} bytes) but only {max(have, 0)} bytes follow "
            "the header; the file is truncated or its header is damaged"
        )
    return count


#: What a header declares: its text, the least bytes that needs, the bytes there are, the vertex / point count.
_Found = tuple[str, int, int, int] | None


def _whole_count(text: str, what: str) -> int:
    """A header count: a non-negative whole number."""
    try:
        value = int(text)
    except ValueError:
        raise MeshError(f"header count of {what} is {text!r}, not a whole number") from None
    if value < 0:
        raise MeshError(f"header count of {what} is negative ({value})")
    return value


def _ply_counts(head: bytes, size: int) -> _Found:
    """PLY: every element's count times its smallest record."""
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        return None
    body_start = head.find(b"\n", end)
    body_start = len(head) if body_start < 0 else body_start + 1
    lines = head[:end].decode("ascii", "replace").splitlines()
    binary = any(ln.split()[:2] in (["format", "binary_little_endian"], ["format", "binary_big_endian"])
                 for ln in lines if ln.strip())
    elements: list[list] = []          # [name, count, smallest record bytes]
    for ln in lines:
        words = ln.split()
        if len(words) >= 3 and words[0] == "element":
            elements.append([words[1], _whole_count(words[2], f"PLY element {words[1]}"), 0])
        elif len(words) >= 3 and words[0] == "property" and elements:
            if not binary:
                elements[-1][2] += 2
            elif words[1] == "list":
                elements[-1][2] += _PLY_SIZES.get(words[2], 1)
            else:
                elements[-1][2] += _PLY_SIZES.get(words[1], 1)
    need = sum(count * least for _, count, least in elements)
    names = ", ".join(f"{count} {name}" for name, count, _ in elements)
    vertices = next((count for name, count, _ in elements if name == "vertex"), 0)
    return f"{names} records", need, size - body_start, vertices


def _text_lines(head: bytes) -> list[tuple[str, int]]:
    """The first lines of a text header with the byte offset just after each."""
    out, pos = [], 0
    for raw in head.splitlines(keepends=True):
        pos += len(raw)
        if raw.endswith((b"\n", b"\r")):
            out.append((raw.decode("ascii", "replace").strip(), pos))
    return out


def _off_counts(head: bytes, size: int) -> _Found:
    """OFF: ``nv nf ne`` after the keyword; at least 6 bytes per vertex and 8 per triangle."""
    lines = [(t, pos) for t, pos in _text_lines(head) if t and not t.startswith("#")]
    if not lines or not lines[0][0].upper().endswith("OFF"):
        return None
    words = lines[0][0].split()[1:] or (lines[1][0].split() if len(lines) > 1 else [])
    pos = lines[0][1] if len(lines[0][0].split()) > 1 else (lines[1][1] if len(lines) > 1 else size)
    if len(words) < 2:
        return None
    nv, nf = _whole_count(words[0], "OFF vertices"), _whole_count(words[1], "OFF faces")
    return f"{nv} vertices and {nf} faces", 6 * nv + 8 * nf, size - pos, nv


def _stl_counts(head: bytes, size: int) -> _Found:
    """Binary STL: 50 bytes per triangle after the 84-byte header (text STL: no count)."""
    if len(head) < 84 or (head.lstrip().startswith(b"solid") and b"facet" in head[:1024]):
        return None
    n = int.from_bytes(head[80:84], "little")
    return f"{n} binary STL triangles", 50 * n, size - 84, 3 * n


def _pcd_counts(head: bytes, size: int) -> _Found:
    """PCD: ``POINTS`` times the bytes of one point (ASCII: 2 per value; compressed: LZF's largest ratio)."""
    fields: dict[str, list[str]] = {}
    pos = None
    for text, after in _text_lines(head):
        words = text.split()
        if words and not text.startswith("#"):
            fields[words[0].upper()] = words[1:]
            if words[0].upper() == "DATA":
                pos = after
                break
    if pos is None or "POINTS" not in fields or not fields["POINTS"]:
        return None
    n = _whole_count(fields["POINTS"][0], "PCD points")
    counts = [_whole_count(c, "PCD COUNT") for c in fields.get("COUNT", [])] or [1] * len(fields.get("SIZE", []))
    sizes = [_whole_count(s, "PCD SIZE") for s in fields.get("SIZE", [])]
    kind = (fields["DATA"] or ["ascii"])[0].lower()
    if kind == "ascii":
        least = 2 * max(1, sum(counts))
    else:
        least = max(1, sum(s * c for s, c in zip(sizes, counts)))
    have = size - pos
    if kind == "binary_compressed":
        have *= _LZF_MAX_RATIO
    return f"{n} points of DATA {kind}", n * least, have, n


def _pts_counts(head: bytes, size: int) -> _Found:
    """PTS: the first line is the point count; each point is a line of at least three values."""
    lines = _text_lines(head)
    if not lines or len(lines[0][0].split()) != 1:
        return None
    try:
        n = _whole_count(lines[0][0], "PTS points")
    except MeshError:
        return None
    return f"{n} points", 6 * n, size - lines[0][1], n
