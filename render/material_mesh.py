"""Triangle meshes that carry a material per face: the PLY of the digitised object and glTF files.

The object's mesh with its measured materials is a binary little-endian PLY
(Turk 1994): vertex records ``x y z nx ny nz`` (float32, millimetres), face
records ``uchar 3, int i0 i1 i2, int material`` (the region index; -1 = not
measured) and one header line per region::

    comment kogei material <index> <spec>

with ``<spec>`` a material spec :func:`processing.materials.presets.get_material`
accepts (no spaces), or nothing for a region without a measured material.
:func:`write_material_ply` writes it atomically; :func:`read_material_mesh`
reads it back with NumPy and trusts nothing: the header's counts against the
file's size, indices and material ids against their ranges, sizes against
:data:`MAX_VERTICES` / :data:`MAX_TRIANGLES`.  It also reads a plain PLY whose
faces have an integer property ``material`` and no such comments (every spec
None), and glTF 2.0 (``.glb`` / ``.gltf``, through trimesh): one primitive per
region, the region's spec from its material's ``extras["kogei"]["spec"]``, or
else the material's name when that is a material spec; region names are the
material names.  glTF positions are metres (glTF 2.0, section 3.4) and are
returned in millimetres.

References
----------
.. [1] Turk, G. (1994). The PLY polygon file format (no DOI).
.. [2] Khronos Group (2021). glTF 2.0 specification,
   https://registry.khronos.org/glTF/specs/2.0/glTF-2.0.html (no DOI).

Examples
--------
>>> import tempfile, pathlib
>>> path = pathlib.Path(tempfile.mkdtemp()) / "two.ply"
>>> v = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]
>>> write_material_ply(path, v, [[0, 1, 2], [1, 3, 2]], [[0, 0, 1]] * 4, [0, 1], ["gold", None])
>>> m = read_material_mesh(path)
>>> m.face_material.tolist(), m.specs, m.names
([0, 1], ('gold', None), ('region-0', 'region-1'))
"""

from __future__ import annotations

import json
import os
import re
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.common.files import atomic_write_bytes
from render.errors import MeshError
from render.meshio import check_ply_header

__all__ = [
    "MaterialMesh",
    "write_material_ply",
    "read_material_mesh",
    "material_mesh_or_none",
    "MAX_VERTICES",
    "MAX_TRIANGLES",
    "MAX_REGIONS",
    "MM_PER_GLTF_UNIT",
]

#: Most vertices / triangles / regions a file may declare.
MAX_VERTICES = 50_000_000
MAX_TRIANGLES = 100_000_000
MAX_REGIONS = 4096

#: glTF positions are metres; the project's meshes are millimetres.
MM_PER_GLTF_UNIT = 1000.0

#: Most header bytes read before ``end_header``.
_HEADER_BYTES = 1 << 16

#: Largest glTF file read (bytes).
_MAX_GLTF_BYTES = 1 << 31

_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}

_COMMENT = re.compile(r"comment kogei material (\S+)(?: (\S+))?\s*$")


@dataclass(frozen=True, eq=False)
class MaterialMesh:
    """A triangle mesh with a material region per face.

    Attributes
    ----------
    vertices
        float64 ``(V, 3)`` positions, millimetres.
    triangles
        int64 ``(T, 3)`` vertex indices.
    normals
        float64 ``(V, 3)`` unit vertex normals.
    face_material
        int64 ``(T,)`` region index per face, -1 = not measured.
    specs
        One material spec per region (None: no measured material).
    names
        One name per region (``region-<i>`` for a PLY, the material names of a glTF file).
    """

    vertices: NDArray[np.float64]
    triangles: NDArray[np.int64]
    normals: NDArray[np.float64]
    face_material: NDArray[np.int64]
    specs: tuple[str | None, ...]
    names: tuple[str, ...]

    @property
    def n_regions(self) -> int:
        """Number of regions R (face ids are -1..R-1)."""
        return len(self.specs)


def _check_spec(spec: str | None, where: str) -> str | None:
    """``spec`` when :func:`get_material` accepts it (None passes); a MeshError naming ``where`` otherwise."""
    if spec is None:
        return None
    from processing.materials.presets import get_material

    if not isinstance(spec, str) or not spec or any(c.isspace() for c in spec):
        raise MeshError(f"{where}: material spec must be a string without spaces, got {spec!r}")
    try:
        get_material(spec)
    except ValueError as exc:
        raise MeshError(f"{where}: {exc}") from None
    return spec


def write_material_ply(path: str | os.PathLike[str], vertices: ArrayLike, triangles: ArrayLike,
                       normals: ArrayLike, face_material: ArrayLike, specs: Sequence[str | None]) -> None:
    """Write a mesh with one material region per face as binary little-endian PLY (atomically).

    Parameters
    ----------
    path
        Output ``.ply`` file; its folder must exist.
    vertices
        ``(V, 3)`` finite positions (mm).
    triangles
        ``(T, 3)`` vertex indices in 0..V-1.
    normals
        ``(V, 3)`` finite vertex normals.
    face_material
        ``(T,)`` region index per face in -1..R-1 (-1 = not measured).
    specs
        R material specs (None for a region without a measured material); each
        must be accepted by :func:`processing.materials.presets.get_material`.

    Raises
    ------
    MeshError
        Wrong suffix or folder, shapes, non-finite values, indices or
        material ids out of range, an invalid spec.
    """
    p = Path(path)
    if p.suffix.lower() != ".ply":
        raise MeshError(f"'{p}': a material mesh is written as .ply; change the suffix")
    if not p.parent.is_dir():
        raise MeshError(f"'{p}': the folder '{p.parent}' does not exist; create it first")
    v = np.asarray(vertices, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    t = np.asarray(triangles)
    fm = np.asarray(face_material)
    specs = tuple(specs)
    if v.ndim != 2 or v.shape[1] != 3 or not 0 < len(v) <= MAX_VERTICES or not np.all(np.isfinite(v)):
        raise MeshError(f"'{p}': vertices must be finite (V, 3), 1 <= V <= {MAX_VERTICES}, got shape {v.shape}")
    if n.shape != v.shape or not np.all(np.isfinite(n)):
        raise MeshError(f"'{p}': normals must be finite with the shape of vertices {v.shape}, got {n.shape}")
    if t.ndim != 2 or t.shape[1] != 3 or not 0 < len(t) <= MAX_TRIANGLES or t.dtype.kind not in "iu":
        raise MeshError(f"'{p}': triangles must be integer (T, 3), 1 <= T <= {MAX_TRIANGLES}, got {t.dtype} {t.shape}")
    if t.min() < 0 or t.max() >= len(v):
        raise MeshError(f"'{p}': triangles index vertices outside 0..{len(v) - 1}")
    if len(specs) > MAX_REGIONS:
        raise MeshError(f"'{p}': {len(specs)} regions is more than {MAX_REGIONS}")
    if fm.shape != (len(t),) or fm.dtype.kind not in "iu" or (fm.size and (fm.min() < -1 or fm.max() >= len(specs))):
        raise MeshError(f"'{p}': face_material must hold one integer in -1..{len(specs) - 1} per triangle")
    header = ["ply", "format binary_little_endian 1.0"]
    for i, spec in enumerate(specs):
        _check_spec(spec, f"'{p}' region {i}")
        header.append(f"comment kogei material {i} {spec}" if spec else f"comment kogei material {i}")
    header += [f"element vertex {len(v)}"] + [f"property float {c}" for c in ("x", "y", "z", "nx", "ny", "nz")]
    header += [f"element face {len(t)}", "property list uchar int vertex_indices", "property int material",
               "end_header"]
    vrec = np.concatenate([v, n], axis=1).astype("<f4")
    frec = np.empty(len(t), dtype=[("n", "u1"), ("i", "<i4", (3,)), ("m", "<i4")])
    frec["n"], frec["i"], frec["m"] = 3, t, fm
    data = ("\n".join(header) + "\n").encode("ascii") + vrec.tobytes() + frec.tobytes()
    atomic_write_bytes(p, data, make_parents=False)


# ----------------------------------------------------------------------------------------------- PLY
def _ply_header(head: bytes, name: str) -> tuple[list[str], int]:
    """The header's lines (without ``end_header``) and the byte offset of the body."""
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        raise MeshError(f"'{name}' is not a PLY file (no 'ply' magic or no end_header in its first "
                        f"{_HEADER_BYTES} bytes)")
    check_ply_header(head, name)
    body = head.find(b"\n", end)
    if body < 0:
        raise MeshError(f"'{name}': the PLY header ends without a line break; the file is truncated")
    try:
        lines = head[:end].decode("ascii").splitlines()
    except UnicodeDecodeError:
        raise MeshError(f"'{name}': the PLY header is not ASCII; the file is damaged") from None
    return [ln.strip() for ln in lines], body + 1


def _ply_elements(lines: list[str], name: str) -> tuple[list[tuple[str, int, list[list[str]]]], list[str]]:
    """``(element name, count, property word lists)`` in order, and the comment lines."""
    elements: list[tuple[str, int, list[list[str]]]] = []
    comments = []
    for ln in lines[1:]:
        words = ln.split()
        if not words:
            continue
        if words[0] == "format":
            if words[1:2] != ["binary_little_endian"]:
                raise MeshError(f"'{name}': PLY format {' '.join(words[1:])!r} is not read; save it as "
                                "binary_little_endian")
        elif words[0] == "comment":
            comments.append(ln)
        elif words[0] == "element" and len(words) == 3 and words[2].isdigit():
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements and len(words) >= 3:
            elements[-1][2].append(words[1:])
        elif words[0] not in ("obj_info",):
            raise MeshError(f"'{name}': PLY header line {ln[:60]!r} is not understood; the header is damaged")
    return elements, comments


def _scalar(words: list[str], name: str) -> str:
    """The little-endian NumPy type of a scalar PLY property."""
    if len(words) != 2 or words[0] not in _PLY_TYPES or not words[1].isidentifier():
        raise MeshError(f"'{name}': PLY property {' '.join(words)!r} is not a scalar of a known type")
    return "<" + _PLY_TYPES[words[0]]


def _record_dtypes(elements: list, name: str) -> tuple[np.dtype, np.dtype]:
    """Structured dtypes of one vertex and one face record (faces: triangles only)."""
    if [e[0] for e in elements] != ["vertex", "face"]:
        raise MeshError(f"'{name}': expected the elements 'vertex' then 'face', got "
                        f"{', '.join(e[0] for e in elements) or 'none'}")
    vfields = [(w[-1], _scalar(w, name)) for w in elements[0][2]]
    if not {"x", "y", "z"} <= {f for f, _ in vfields}:
        raise MeshError(f"'{name}': the vertices have no x, y, z properties")
    ffields = []
    for w in elements[1][2]:
        if w[0] == "list":
            if len(w) != 4 or w[1] not in _PLY_TYPES or w[2] not in _PLY_TYPES or w[3] not in (
                    "vertex_indices", "vertex_index"):
                raise MeshError(f"'{name}': face list property {' '.join(w)!r} is not understood")
            ffields += [("count", "<" + _PLY_TYPES[w[1]]), ("index", "<" + _PLY_TYPES[w[2]], (3,))]
        else:
            ffields.append((w[-1], _scalar(w, name)))
    if "index" not in [f[0] for f in ffields]:
        raise MeshError(f"'{name}': the faces have no vertex_indices list")
    try:
        return np.dtype(vfields), np.dtype(ffields)
    except (TypeError, ValueError) as exc:
        raise MeshError(f"'{name}': PLY properties cannot be read ({exc}); the header is damaged") from None


def _region_specs(comments: list[str], name: str) -> dict[int, str | None]:
    """Region index -> spec from the ``comment kogei material`` lines (unique indices, valid specs)."""
    out: dict[int, str | None] = {}
    for ln in comments:
        if not ln.startswith("comment kogei material"):
            continue
        m = _COMMENT.match(ln)
        if m is None or not m.group(1).isdigit():
            raise MeshError(f"'{name}': header line {ln[:80]!r} is not 'comment kogei material <index> <spec>'")
        index = int(m.group(1))
        if index >= MAX_REGIONS or index in out:
            raise MeshError(f"'{name}': region {index} is declared twice or is not below {MAX_REGIONS}")
        out[index] = _check_spec(m.group(2), f"'{name}' region {index}")
    return out


def _read_ply(path: Path) -> MaterialMesh | None:
    """The PLY's mesh and face materials, or None when its faces have no ``material`` property."""
    name = str(path)
    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(_HEADER_BYTES)
    lines, body = _ply_header(head, name)
    elements, comments = _ply_elements(lines, name)
    vdt, fdt = _record_dtypes(elements, name)
    nv, nt = elements[0][1], elements[1][1]
    if not (0 < nv <= MAX_VERTICES and 0 < nt <= MAX_TRIANGLES):
        raise MeshError(f"'{name}': {nv} vertices and {nt} faces; a mesh needs 1..{MAX_VERTICES} vertices and "
                        f"1..{MAX_TRIANGLES} faces")
    need = nv * vdt.itemsize + nt * fdt.itemsize
    if size - body != need:
        raise MeshError(f"'{name}': the header declares {nv} vertices and {nt} triangles ({need} bytes) but "
                        f"{size - body} bytes follow it; the file is truncated, damaged or has non-triangle faces")
    if "material" not in fdt.names:
        return None
    raw = np.fromfile(path, dtype=np.uint8, offset=body)
    vrec = raw[: nv * vdt.itemsize].view(vdt)
    frec = raw[nv * vdt.itemsize:].view(fdt)
    if np.any(frec["count"] != 3):
        raise MeshError(f"'{name}': {int(np.count_nonzero(frec['count'] != 3))} faces are not triangles; "
                        "triangulate the mesh")
    if fdt["material"].kind not in "iu":
        raise MeshError(f"'{name}': the face property 'material' must be an integer type")
    regions = _region_specs(comments, name)
    return _assemble(name, vrec, frec["index"], frec["material"], regions)


def _assemble(name: str, vrec: np.ndarray, index: np.ndarray, material: np.ndarray,
              regions: dict[int, str | None]) -> MaterialMesh:
    """Checked arrays of a PLY's records: indices and material ids in range, finite values, unit normals."""
    from render.meshio import smooth_vertex_normals

    v = np.stack([vrec[c] for c in "xyz"], axis=1).astype(np.float64)
    t = index.astype(np.int64)
    fm = material.astype(np.int64)
    if not np.all(np.isfinite(v)):
        raise MeshError(f"'{name}': vertices hold NaN or infinite coordinates")
    if t.min() < 0 or t.max() >= len(v):
        raise MeshError(f"'{name}': faces index vertices outside 0..{len(v) - 1}")
    n_regions = (max(regions) + 1) if regions else max(int(fm.max()) + 1, 0)
    if fm.min() < -1 or fm.max() >= n_regions:
        raise MeshError(f"'{name}': face material ids {int(fm.min())}..{int(fm.max())} are outside -1.."
                        f"{n_regions - 1} (the regions its header declares); the file is damaged")
    if n_regions > MAX_REGIONS:
        raise MeshError(f"'{name}': {n_regions} regions is more than {MAX_REGIONS}")
    if {"nx", "ny", "nz"} <= set(vrec.dtype.names):
        n = np.stack([vrec[c] for c in ("nx", "ny", "nz")], axis=1).astype(np.float64)
        length = np.linalg.norm(n, axis=1)
        good = np.isfinite(length) & (length > 0)
        n = n / np.where(good, length, 1.0)[:, None] if np.all(good) else smooth_vertex_normals(v, t)
    else:
        n = smooth_vertex_normals(v, t)
    specs = tuple(regions.get(i) for i in range(n_regions))
    return MaterialMesh(v, t, n, fm, specs, tuple(f"region-{i}" for i in range(n_regions)))


# ---------------------------------------------------------------------------------------------- glTF
def _gltf_json(path: Path) -> dict:
    """The glTF's JSON document (of a ``.gltf`` file or the first chunk of a ``.glb``)."""
    name = str(path)
    data = path.read_bytes()
    if path.suffix.lower() == ".glb":
        if len(data) < 20 or data[:4] != b"glTF":
            raise MeshError(f"'{name}' is not a binary glTF file (no 'glTF' magic)")
        version, total, chunk, kind = struct.unpack_from("<IIII", data, 4)
        if version != 2 or total != len(data) or kind != 0x4E4F534A or 20 + chunk > len(data):
            raise MeshError(f"'{name}': the GLB header (version {version}, {total} bytes, JSON chunk {chunk} "
                            f"bytes) does not match the file ({len(data)} bytes); the file is damaged")
        data = data[20:20 + chunk]
    try:
        doc = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MeshError(f"'{name}': the glTF JSON cannot be read ({exc}); the file is damaged") from None
    if not isinstance(doc, dict):
        raise MeshError(f"'{name}': the glTF JSON is not an object; the file is damaged")
    _check_uris(doc, name)
    return doc


def _check_uris(doc: dict, name: str) -> None:
    """Refuse buffers and images outside the file's folder: absolute paths, ``..``, URLs other than ``data:``."""
    for key in ("buffers", "images"):
        items = doc.get(key, [])
        for item in items if isinstance(items, list) else []:
            uri = item.get("uri") if isinstance(item, dict) else None
            if uri is None or (isinstance(uri, str) and uri.startswith("data:")):
                continue
            parts = uri.replace("\\", "/").split("/") if isinstance(uri, str) else [".."]
            if not uri or uri.startswith("/") or ":" in uri or ".." in parts:
                raise MeshError(f"'{name}': {key[:-1]} uri {str(uri)[:60]!r} points outside the file's folder; "
                                "keep buffers and images next to the .gltf (or use a .glb)")


def _kogei_extras(mat: dict) -> dict:
    """A glTF material's ``extras.kogei`` table (empty when absent)."""
    extras = mat.get("extras")
    kogei = extras.get("kogei") if isinstance(extras, dict) else None
    return kogei if isinstance(kogei, dict) else {}


def _material_spec(mat: dict, label: str) -> str | None:
    """The spec of a glTF material: ``extras.kogei.spec``, else its name when that is a spec."""
    from processing.materials.presets import get_material

    kogei = _kogei_extras(mat)
    if "spec" in kogei or kogei.get("measured") is False:
        return kogei.get("spec")
    if " " in label:
        return None
    try:
        get_material(label)
    except ValueError:
        return None
    return label


def _material_regions(doc: dict, name: str) -> tuple[tuple[str | None, ...], tuple[str, ...], list[int]]:
    """Spec and name of every region, and the region of every glTF material.

    The region of a material is its ``extras.kogei.index`` when every material
    has one (-1: faces of no region), else the material's own index.
    """
    materials = doc.get("materials", [])
    if not isinstance(materials, list) or len(materials) > MAX_REGIONS:
        raise MeshError(f"'{name}': 'materials' must be a list of at most {MAX_REGIONS} materials")
    materials = [m if isinstance(m, dict) else {} for m in materials]
    labels = [m["name"] if isinstance(m.get("name"), str) and m["name"] else f"material-{i}"
              for i, m in enumerate(materials)]
    specs = [_check_spec(_material_spec(m, lab), f"'{name}' material {i} ({lab!r})")
             for i, (m, lab) in enumerate(zip(materials, labels))]
    index = [_kogei_extras(m).get("index") for m in materials]
    if not materials or not all(isinstance(i, int) and -1 <= i < MAX_REGIONS for i in index):
        return tuple(specs), tuple(labels), list(range(len(materials)))
    n_regions = max(index) + 1
    if len({i for i in index if i >= 0}) != sum(1 for i in index if i >= 0):
        raise MeshError(f"'{name}': two materials claim the same extras.kogei.index; the file is damaged")
    out_specs: list[str | None] = [None] * n_regions
    out_names = [f"region-{i}" for i in range(n_regions)]
    for i, spec, lab in zip(index, specs, labels):
        if i >= 0:
            out_specs[i], out_names[i] = spec, lab
    return tuple(out_specs), tuple(out_names), index


def _primitive_materials(doc: dict, name: str) -> list[tuple[int, int]]:
    """``(material index or -1, triangle count)`` of every triangle primitive, in file order."""
    out = []
    accessors = doc.get("accessors", [])
    for mesh in doc.get("meshes", []) if isinstance(doc.get("meshes"), list) else []:
        for prim in mesh.get("primitives", []) if isinstance(mesh, dict) else []:
            if not isinstance(prim, dict) or prim.get("mode", 4) != 4:
                continue
            mat = prim.get("material", -1)
            idx = prim.get("indices")
            try:
                count = accessors[idx]["count"] // 3 if idx is not None else accessors[
                    prim["attributes"]["POSITION"]]["count"] // 3
            except (KeyError, IndexError, TypeError):
                raise MeshError(f"'{name}': a primitive's accessors are missing; the file is damaged") from None
            if not isinstance(mat, int) or mat < -1:
                raise MeshError(f"'{name}': a primitive's material {mat!r} is not a material index")
            out.append((mat, int(count)))
    return out


def _read_gltf(path: Path) -> MaterialMesh:
    """A glTF's triangle primitives as one mesh (mm), the region of a face its primitive's material."""
    import trimesh

    name = str(path)
    if path.stat().st_size > _MAX_GLTF_BYTES:
        raise MeshError(f"'{name}' is larger than {_MAX_GLTF_BYTES} bytes; it is not read")
    doc = _gltf_json(path)
    specs, names, remap = _material_regions(doc, name)
    prims = _primitive_materials(doc, name)
    if sum(c for _, c in prims) > MAX_TRIANGLES:
        raise MeshError(f"'{name}' has more than {MAX_TRIANGLES} triangles")
    if any(m >= len(remap) for m, _ in prims):
        raise MeshError(f"'{name}': a primitive uses a material beyond the {len(remap)} the file has")
    try:
        scene = trimesh.load(path, force="scene", process=False)
    except Exception as exc:  # trimesh raises many kinds for a damaged file
        raise MeshError(f"'{name}' could not be read as glTF: {exc}") from None
    geoms = [g for g in scene.geometry.values() if isinstance(g, trimesh.Trimesh)]
    if [len(g.faces) for g in geoms] != [c for _, c in prims] or not geoms or any(
            len(g.faces) and (g.faces.min() < 0 or g.faces.max() >= len(g.vertices)) for g in geoms):
        raise MeshError(f"'{name}': its {len(prims)} triangle primitives do not match the {len(geoms)} meshes "
                        "read from it, index vertices it does not have, or there are none; the file is damaged")
    region = {id(g): (remap[m] if m >= 0 else -1) for g, (m, _) in zip(geoms, prims)}
    parts_v, parts_n, parts_t, parts_m, offset = [], [], [], [], 0
    for node in scene.graph.nodes_geometry:
        transform, geom_name = scene.graph[node]
        g = scene.geometry[geom_name]
        if id(g) not in region:
            continue
        m = np.asarray(transform, dtype=np.float64)
        v = np.asarray(g.vertices, dtype=np.float64) @ m[:3, :3].T + m[:3, 3]
        n = np.asarray(g.vertex_normals, dtype=np.float64) @ np.linalg.inv(m[:3, :3])
        parts_v.append(v * MM_PER_GLTF_UNIT)
        parts_n.append(n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300))
        parts_t.append(np.asarray(g.faces, dtype=np.int64) + offset)
        parts_m.append(np.full(len(g.faces), region[id(g)], dtype=np.int64))
        offset += len(v)
    if not parts_v:
        raise MeshError(f"'{name}': no node of its scene shows a triangle mesh; the file is damaged")
    v = np.concatenate(parts_v)
    if not np.all(np.isfinite(v)):
        raise MeshError(f"'{name}': vertices hold NaN or infinite coordinates")
    return MaterialMesh(v, np.concatenate(parts_t), np.concatenate(parts_n), np.concatenate(parts_m), specs, names)


# -------------------------------------------------------------------------------------------- public
def _checked_path(path: str | os.PathLike[str]) -> Path:
    """An existing, readable, non-empty ``.ply`` / ``.glb`` / ``.gltf`` file."""
    p = Path(path)
    if p.suffix.lower() not in (".ply", ".glb", ".gltf"):
        raise MeshError(f"'{p}': per-face materials are read from .ply, .glb or .gltf files, not {p.suffix!r}")
    if not p.is_file():
        raise MeshError(f"mesh file '{p}' does not exist or is not a file")
    if not os.access(p, os.R_OK) or p.stat().st_size == 0:
        raise MeshError(f"mesh file '{p}' is not readable or empty")
    return p


def _declares_face_material(path: Path) -> bool:
    """Whether a PLY's header gives its faces a property ``material`` (any format; False for no PLY header)."""
    with open(path, "rb") as fh:
        head = fh.read(_HEADER_BYTES)
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        return False
    element = None
    for words in (ln.split() for ln in head[:end].decode("ascii", "replace").splitlines()):
        if words[:1] == ["element"]:
            element = words[1:2]
        elif words[:1] == ["property"] and words[-1:] == ["material"] and element == ["face"]:
            return True
    return False


def material_mesh_or_none(path: str | os.PathLike[str]) -> MaterialMesh | None:
    """The mesh with its per-face materials, or None when the file carries none.

    A PLY carries them when its header declares a face property ``material``
    (then it is read strictly); a
    glTF file when it has more than one primitive or a material whose spec is
    known (``extras.kogei`` or a material name that is a spec).  OBJ, STL and
    OFF files never do.

    Parameters
    ----------
    path
        A mesh file.

    Returns
    -------
    MaterialMesh or None
        As :func:`read_material_mesh`; None for a file without per-face materials.

    Raises
    ------
    MeshError
        As :func:`read_material_mesh`.
    """
    p = Path(path)
    if p.suffix.lower() not in (".ply", ".glb", ".gltf"):
        return None
    p = _checked_path(p)
    if p.suffix.lower() == ".ply":
        return _read_ply(p) if _declares_face_material(p) else None
    mesh = _read_gltf(p)
    regions = np.unique(mesh.face_material)
    if len(regions) < 2 and not any(mesh.specs[int(r)] for r in regions if r >= 0):
        return None
    return mesh


def read_material_mesh(path: str | os.PathLike[str]) -> MaterialMesh:
    """Read a mesh with one material region per face (PLY with a face ``material`` property, glTF).

    Parameters
    ----------
    path
        A ``.ply`` (binary little-endian; see the module notes) or ``.glb`` /
        ``.gltf`` file.

    Returns
    -------
    MaterialMesh
        Vertices in millimetres (glTF metres are converted), unit normals
        (computed when the file has none), face regions, specs and names.

    Raises
    ------
    MeshError
        One line naming the file: missing or unreadable, a header that does
        not match the file's size, indices or material ids out of range,
        faces that are not triangles, an invalid material spec, no
        per-face materials at all.

    Examples
    --------
    >>> read_material_mesh("missing.ply")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    render.errors.MeshError: mesh file 'missing.ply' does not exist or is not a file
    """
    p = _checked_path(path)
    mesh = _read_ply(p) if p.suffix.lower() == ".ply" else _read_gltf(p)
    if mesh is None:
        raise MeshError(f"'{p}': its faces have no 'material' property; write it with "
                        "render.material_mesh.write_material_ply or give the material separately")
    return mesh
