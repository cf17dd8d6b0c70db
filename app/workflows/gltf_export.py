"""The measured object as glTF 2.0: one primitive per material region, metallic-roughness PBR materials.

:func:`export_gltf` reads a session's ``products/object-materials.json`` (the
regions' answers) and ``products/object-mesh.ply`` (the mesh with a region per
face, :mod:`render.material_mesh`) and writes a binary glTF (``.glb``, through
trimesh) that any viewer shows:

* one glTF mesh per region that has faces, each one triangle primitive (faces
  of no region, -1, form one more, of the neutral grey material);
  positions in metres (glTF 2.0, section 3.4; the session's millimetres /
  1000), the session's vertex normals;
* per region a ``pbrMetallicRoughness`` material named by the region's answer
  (``"gold"``, ``"alloy"``, ...):

  - ``baseColorFactor``: linear sRGB (IEC 61966-2-1) of a reflectance under
    D65, integrated to XYZ with the CIE 1931 observer
    (:func:`processing.spectral.display.spectra_to_xyz`) and scaled so the
    perfect white diffuser has Y = 1, clipped to [0, 1].  Metals and alloys:
    their Fresnel reflectance at normal incidence (the gloss lobe's
    ``spectral.reflectance(1.0, wl)``, what glTF's metallic base colour is);
    dielectrics: the Lambert lobe's diffuse albedo (its weight times its
    pigment reflectance, what glTF's dielectric base colour is);
  - ``metallicFactor`` 1 for metals and alloys, 0 otherwise;
  - ``roughnessFactor`` ``sqrt(m)`` with ``m`` the Beckmann RMS slope of the
    gloss lobe: glTF's GGX uses ``alpha = roughness^2`` and the usual match of
    a Beckmann lobe by a GGX lobe sets ``alpha_GGX ~= m`` (Walter et al. 2007);
  - ``extras.kogei``: ``index``, ``spec`` (what :func:`processing.materials.presets.get_material`
    rebuilds the exact spectral material from), ``material``, ``confidence``,
    ``group``, ``parameters``, ``uncertainties`` (1 sigma), ``measured``
    and the region's counts.

  The scene's ``extras.kogei`` holds the materials file's ``validation``
  (the held-out photo comparison).

  A region without a measured material gets a neutral grey (base colour 0.5,
  metallic 0, roughness 1) with ``extras.kogei.measured = false``.

References
----------
.. [1] Walter, Marschner, Li, Torrance (2007). Microfacet models for refraction
   through rough surfaces. EGSR, doi:10.2312/EGWR/EGSR07/195-206.
.. [2] Khronos Group (2021). glTF 2.0 specification, appendix B (BRDF
   implementation), https://registry.khronos.org/glTF/specs/2.0/glTF-2.0.html.
.. [3] CIE 015:2018 Colorimetry, doi:10.25039/TR.015.2018.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from app.errors import UsageError
from app.workflows.object_materials import OBJECT_MATERIALS

__all__ = ["export_gltf", "pbr_factors", "NEUTRAL_GREY",
           "read_object_model"]

#: Base colour of a region without a measured material (linear, sRGB primaries).
NEUTRAL_GREY = (0.5, 0.5, 0.5)

_METRES_PER_MM = 1e-3


def pbr_factors(spec: str) -> dict[str, Any]:
    """glTF metallic-roughness factors of a material spec (see the module notes).

    Parameters
    ----------
    spec
        A material spec :func:`processing.materials.presets.get_material` accepts.

    Returns
    -------
    dict
        ``base_color`` (linear sRGB, 3 floats in [0, 1]), ``metallic`` (0 or 1),
        ``roughness`` (in [0, 1]).

    Examples
    --------
    >>> f = pbr_factors("gold:roughness=0.1")
    >>> f["metallic"], round(f["roughness"], 4), f["base_color"][0] > f["base_color"][2]
    (1.0, 0.3162, True)
    """
    from processing.materials.presets import get_material
    from processing.spectral.display import spectra_to_xyz, white_xyz, xyz_scale, xyz_to_linear_srgb
    from processing.spectral.spectra import REFERENCE_GRID, light_spectrum

    material = get_material(spec)
    grid = REFERENCE_GRID
    wl = grid.wavelengths
    metal = material.family in ("metal", "alloy")
    gloss = next((lobe for lobe in material.lobes if lobe.kind != "lambert" and not lobe.mirror), None)
    lambert = next((lobe for lobe in material.lobes if lobe.kind == "lambert"), None)
    if metal and gloss is not None:
        reflectance = np.asarray(gloss.spectral.reflectance(1.0, wl), dtype=np.float64).reshape(-1)
    elif lambert is not None:
        reflectance = lambert.weight * np.asarray(lambert.spectral.reflectance(1.0, wl), dtype=np.float64).reshape(-1)
    else:
        reflectance = np.zeros(grid.size)
    e = light_spectrum("D65", grid)
    xyz = xyz_scale(e, grid) * spectra_to_xyz(reflectance * e / math.pi, grid)
    rgb = np.clip(xyz_to_linear_srgb(xyz, white_xyz(e, grid)), 0.0, 1.0)
    roughness = math.sqrt(gloss.roughness) if gloss is not None and gloss.roughness > 0 else 1.0
    return {"base_color": [float(c) for c in rgb], "metallic": 1.0 if metal else 0.0,
            "roughness": float(min(1.0, roughness))}


def read_object_model(session_dir: str | os.PathLike[str]) -> tuple[dict[str, Any], Any]:
    """A measured session's materials document and its mesh (:class:`render.material_mesh.MaterialMesh`).

    Raises :class:`UsageError` naming the session when it has not been
    measured (``run kogei fit-materials SESSION``) or its files are
    damaged or disagree (region counts).
    """
    from app.workflows.object_materials import object_mesh_file, read_object_materials
    from render.errors import MeshError
    from render.material_mesh import read_material_mesh

    root = Path(session_dir)
    if not root.is_dir():
        raise UsageError(f"{root}: no such session folder")
    doc = read_object_materials(root)
    where = str(root / OBJECT_MATERIALS)
    mesh_path = object_mesh_file(root, doc)
    try:
        mesh = read_material_mesh(mesh_path)
    except MeshError as exc:
        raise UsageError(str(exc)) from None
    if mesh.n_regions != len(doc["regions"]):
        raise UsageError(f"{where}: {len(doc['regions'])} regions but {mesh_path} declares {mesh.n_regions}; the "
                         "files belong to different runs, rerun kogei fit-materials")
    return doc, mesh


def _material_json(region: dict[str, Any] | None, index: int) -> dict[str, Any]:
    """The glTF material of one region (None: the faces of no region)."""
    spec = region.get("spec") if region else None
    keep = ("material", "confidence", "group", "parameters", "uncertainties", "area_mm2", "faces",
            "n_observations", "n_lit", "chi2_per_dof", "reason")
    extras = {"index": index, "spec": spec, "measured": spec is not None}
    extras.update({k: region[k] for k in keep if region and k in region})
    if spec is None:
        factors = {"base_color": list(NEUTRAL_GREY), "metallic": 0.0, "roughness": 1.0}
        name = "not measured"
    else:
        factors = pbr_factors(spec)
        name = str(region.get("material") or spec)
    return {"name": name, "doubleSided": False, "extras": {"kogei": extras},
            "pbrMetallicRoughness": {"baseColorFactor": [*factors["base_color"], 1.0],
                                     "metallicFactor": factors["metallic"],
                                     "roughnessFactor": factors["roughness"]}}


def _check_out(out_path: str | os.PathLike[str], force: bool) -> Path:
    """The output ``.glb`` path: its folder exists and is writable, an existing file only with ``force``."""
    out = Path(out_path)
    if out.suffix.lower() != ".glb":
        raise UsageError(f"--gltf {out}: the export is a binary glTF; name it *.glb")
    if not out.parent.is_dir():
        raise UsageError(f"--gltf {out}: the folder {out.parent} does not exist; create it first")
    if not os.access(out.parent, os.W_OK):
        raise UsageError(f"--gltf {out}: the folder {out.parent} is not writable; choose another place")
    if out.exists() and (not force or not out.is_file()):
        raise UsageError(f"--gltf {out}: the file exists; add --force to replace it" if out.is_file()
                         else f"--gltf {out}: exists and is not a file; choose another name")
    return out


def _scene(mesh: Any, n_regions: int) -> tuple[Any, list[int]]:
    """A trimesh scene with one mesh per region with faces (metres), and the region of each, in order."""
    import trimesh
    from trimesh.visual import TextureVisuals
    from trimesh.visual.material import PBRMaterial

    scene = trimesh.Scene()
    order = []
    for region in range(-1, n_regions):
        sel = np.flatnonzero(mesh.face_material == region)
        if sel.size == 0:
            continue
        tri = mesh.triangles[sel]
        used, local = np.unique(tri, return_inverse=True)
        part = trimesh.Trimesh(mesh.vertices[used] * _METRES_PER_MM, local.reshape(-1, 3),
                               vertex_normals=mesh.normals[used], process=False)
        part.visual = TextureVisuals(material=PBRMaterial(name=f"region-{region}"))
        part.metadata = {"kogei": {"region": int(region)}}
        scene.add_geometry(part, geom_name=f"region-{region}" if region >= 0 else "not-measured")
        order.append(int(region))
    return scene, order


def export_gltf(session_dir: str | os.PathLike[str], out_path: str | os.PathLike[str], *,
                force: bool = False) -> dict[str, Any]:
    """Write a measured session's object as a ``.glb`` (see the module notes); atomic.

    Parameters
    ----------
    session_dir
        A session with ``products/object-materials.json`` and its mesh.
    out_path
        The ``.glb`` to write (its folder must exist and be writable).
    force
        Replace an existing file.

    Returns
    -------
    dict
        ``out``, ``vertices``, ``triangles``, ``bytes`` and ``regions``: per
        primitive ``index`` (-1: faces of no region), ``name``, ``spec``,
        ``faces``, ``base_color``, ``metallic``, ``roughness``, ``measured``.
    """
    import trimesh

    from processing.common.files import atomic_write_bytes

    doc, mesh = read_object_model(session_dir)
    out = _check_out(out_path, force)
    regions = doc["regions"]
    scene, order = _scene(mesh, len(regions))
    materials = [_material_json(regions[r] if r >= 0 else None, r) for r in order]

    def post(tree: dict[str, Any]) -> None:
        tree["materials"] = materials
        for sc in tree.get("scenes", []):
            sc["extras"] = {"kogei": {"schema": doc["schema"], "version": doc["version"],
                                      "units": "metres (session millimetres / 1000)",
                                      "validation": doc.get("validation", {})}}
        for m in tree.get("meshes", []):
            region = (m.get("extras") or {}).get("kogei", {}).get("region")
            for prim in m.get("primitives", []):
                prim["material"] = order.index(region)

    data = trimesh.exchange.gltf.export_glb(scene, include_normals=True, tree_postprocessor=post)
    atomic_write_bytes(out, data, make_parents=False)
    summary = [{"index": r, "name": mat["name"], "spec": mat["extras"]["kogei"]["spec"],
                "faces": int(np.count_nonzero(mesh.face_material == r)),
                "base_color": mat["pbrMetallicRoughness"]["baseColorFactor"][:3],
                "metallic": mat["pbrMetallicRoughness"]["metallicFactor"],
                "roughness": mat["pbrMetallicRoughness"]["roughnessFactor"],
                "measured": mat["extras"]["kogei"]["measured"]} for r, mat in zip(order, materials)]
    return {"out": str(out), "vertices": int(len(mesh.vertices)), "triangles": int(len(mesh.triangles)),
            "bytes": len(data), "regions": summary}
