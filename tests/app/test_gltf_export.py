"""``kogei export --gltf``: a measured session as glTF 2.0, checked by reading the file back.

The expected factors are computed here from the spectra with colour-science (not with the exporter's
code): gold's base colour is its normal-incidence Fresnel reflectance under D65 in linear sRGB,
urushi-red's the diffuse albedo of its pigment, roughness sqrt(m) of the gloss lobe's RMS slope m.
"""

from __future__ import annotations

import json
import struct

import colour
import numpy as np
import pytest
import trimesh

from app.cli import main
from processing.materials.presets import get_material
from render.material_mesh import read_material_mesh, write_material_ply

SPECS = ["gold:roughness=0.1", "urushi-red", None]
REGIONS = [
    {"index": 0, "material": "gold", "spec": SPECS[0], "confidence": 0.91, "group": ["gold"],
     "parameters": {"roughness": 0.1}, "uncertainties": {"roughness": 0.004}, "area_mm2": 600.0, "faces": 0,
     "n_observations": 1200, "n_lit": 300, "chi2_per_dof": 1.1, "reason": ""},
    {"index": 1, "material": "urushi-red", "spec": SPECS[1], "confidence": 0.8, "group": ["urushi-red"],
     "parameters": {"diffuse": 0.7}, "uncertainties": {"diffuse": 0.02}, "area_mm2": 500.0, "faces": 0,
     "n_observations": 900, "n_lit": 250, "chi2_per_dof": 0.9, "reason": ""},
    {"index": 2, "material": "not measured", "spec": None, "confidence": 0.0, "group": [], "parameters": {},
     "uncertainties": {}, "area_mm2": 50.0, "faces": 0, "n_observations": 3, "n_lit": 0,
     "chi2_per_dof": 0.0, "reason": "no lit observation; add a placement"},
]


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    from app.session import Session

    root = tmp_path_factory.mktemp("sess") / "session"
    Session.create(root, plan={"kind": "scan", "steps": 4, "passes": 1}).close()
    (root / "products").mkdir(exist_ok=True)
    s = trimesh.creation.icosphere(3, radius=20.0)
    v, t = np.asarray(s.vertices), np.asarray(s.faces)
    c = v[t].mean(axis=1)
    fm = np.where(c[:, 2] > 0, 0, 1)
    fm[(c[:, 2] < 0) & (c[:, 0] > 12)] = 2
    fm[np.abs(c[:, 1]) < 1.0] = -1
    write_material_ply(root / "products/object-mesh.ply", v, t, np.asarray(s.vertex_normals), fm, SPECS)
    regions = [dict(r, faces=int(np.count_nonzero(fm == r["index"]))) for r in REGIONS]
    blob = json.dumps({"schema": "kogei.object_materials", "version": 1, "mesh": "products/object-mesh.ply",
                       "regions": regions, "validation": {"median_delta_e00": 2.1}}).encode()
    with Session.open(root) as sess:
        info = sess.write_file("products/object-materials.json", blob)
        sess.update("products", {"object_materials": {"file": info.path, "sha256": info.sha256}})
    return root, fm


def _expected_base_colour(reflectance_on_400_700_by_5):
    """Linear sRGB of a reflectance under D65 (colour-science's CIE 1931 2-degree observer), white Y = 1."""
    sd = colour.SpectralDistribution(dict(zip(np.arange(400, 701, 5), reflectance_on_400_700_by_5)))
    shape = colour.SpectralShape(400, 700, 5)
    d65 = colour.SDS_ILLUMINANTS["D65"].copy().align(shape)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape)
    xyz = colour.sd_to_XYZ(sd, cmfs, d65, shape=shape, method="Integration") / 100.0
    white = colour.sd_to_XYZ(colour.SpectralDistribution(dict(zip(np.arange(400, 701, 5), np.ones(61)))),
                             cmfs, d65, shape=shape, method="Integration") / 100.0
    rgb = colour.XYZ_to_RGB(xyz, "sRGB", colour.XYZ_to_xy(white), chromatic_adaptation_transform="CAT02")
    return np.clip(rgb, 0.0, 1.0)


def _glb_json(path):
    data = path.read_bytes()
    assert data[:4] == b"glTF"
    chunk = struct.unpack_from("<I", data, 12)[0]
    return json.loads(data[20:20 + chunk])


def test_export_writes_one_pbr_primitive_per_region(session, tmp_path, capsys):
    root, fm = session
    out = tmp_path / "object.glb"
    assert main(["export", str(root), "--gltf", str(out)]) == 0
    assert "wrote" in capsys.readouterr().out
    doc = _glb_json(out)
    mats = doc["materials"]
    prims = [p for m in doc["meshes"] for p in m["primitives"]]
    assert len(prims) == 4 == len(mats)          # three regions and the faces of none
    by_index = {m["extras"]["kogei"]["index"]: m for m in mats}
    wl = np.arange(400, 701, 5, dtype=float)
    gold = get_material(SPECS[0])
    expect_gold = _expected_base_colour(gold.lobes[0].spectral.reflectance(1.0, wl).reshape(-1))
    red = get_material(SPECS[1])
    lam = next(lobe for lobe in red.lobes if lobe.kind == "lambert")
    expect_red = _expected_base_colour(lam.weight * lam.spectral.reflectance(1.0, wl).reshape(-1))
    g = by_index[0]["pbrMetallicRoughness"]
    r = by_index[1]["pbrMetallicRoughness"]
    # colour-science's sd_to_XYZ and the project's 5 nm sum differ by well under 0.01
    assert np.allclose(g["baseColorFactor"][:3], expect_gold, atol=0.01)
    assert g["baseColorFactor"][0] > g["baseColorFactor"][1] > g["baseColorFactor"][2]     # yellow
    assert np.allclose(r["baseColorFactor"][:3], expect_red, atol=0.01)
    assert r["baseColorFactor"][0] > 3 * r["baseColorFactor"][1]                             # red
    assert g["metallicFactor"] == 1.0 and r["metallicFactor"] == 0.0
    assert g["roughnessFactor"] == pytest.approx(np.sqrt(0.1), abs=1e-12)
    assert r["roughnessFactor"] == pytest.approx(np.sqrt(red.parameters["roughness"]), abs=1e-12)
    for k in (2, -1):
        assert by_index[k]["extras"]["kogei"]["measured"] is False
        assert by_index[k]["pbrMetallicRoughness"]["baseColorFactor"] == [0.5, 0.5, 0.5, 1.0]
    assert by_index[0]["name"] == "gold" and by_index[0]["extras"]["kogei"]["spec"] == SPECS[0]
    assert by_index[0]["extras"]["kogei"]["uncertainties"] == {"roughness": 0.004}
    assert by_index[1]["extras"]["kogei"]["confidence"] == 0.8
    assert doc["scenes"][0]["extras"]["kogei"]["validation"] == {"median_delta_e00": 2.1}


def test_exported_file_reads_back_with_trimesh_and_the_project_reader(session, tmp_path):
    root, fm = session
    out = tmp_path / "object.glb"
    assert main(["export", str(root), "--gltf", str(out)]) == 0
    scene = trimesh.load(out, force="scene")
    assert sum(len(g.faces) for g in scene.geometry.values()) == len(fm)
    names = sorted(g.visual.material.name for g in scene.geometry.values())
    assert names == ["gold", "not measured", "not measured", "urushi-red"]
    # metres: the 20 mm sphere has radius 0.02
    assert np.max(np.abs(np.vstack([g.vertices for g in scene.geometry.values()]))) == pytest.approx(0.02, rel=1e-4)
    m = read_material_mesh(out)
    assert m.specs == tuple(SPECS) and m.names == ("gold", "urushi-red", "not measured")
    assert np.bincount(m.face_material + 1).tolist() == np.bincount(fm + 1).tolist()


def test_export_errors_are_one_line(session, tmp_path, capsys):
    root, _ = session
    from app.session import Session

    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["export", str(empty), "--gltf", str(tmp_path / "a.glb")]) == 2
    assert "is not a kogei session" in capsys.readouterr().err
    Session.create(tmp_path / "unmeasured", plan={"kind": "scan", "steps": 4, "passes": 1}).close()
    assert main(["export", str(tmp_path / "unmeasured"), "--gltf", str(tmp_path / "a.glb")]) == 2
    assert f"run kogei fit-materials {tmp_path / 'unmeasured'}" in capsys.readouterr().err
    out = tmp_path / "b.glb"
    out.write_bytes(b"old")
    assert main(["export", str(root), "--gltf", str(out)]) == 2
    assert "add --force" in capsys.readouterr().err and out.read_bytes() == b"old"
    assert main(["export", str(root), "--gltf", str(out), "--force"]) == 0
    assert out.read_bytes()[:4] == b"glTF"
    assert main(["export", str(root), "--gltf", str(tmp_path / "nofolder" / "c.glb")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main(["export", str(root), "--gltf", str(tmp_path / "c.gltf")]) == 2
    assert "*.glb" in capsys.readouterr().err
    assert not list(tmp_path.glob("*.tmp*"))


def test_exported_json_is_valid_against_the_gltf_schema(session, tmp_path):
    pytest.importorskip("jsonschema")
    root, _ = session
    out = tmp_path / "object.glb"
    assert main(["export", str(root), "--gltf", str(out)]) == 0
    trimesh.exchange.gltf.validate(_glb_json(out))       # raises on a schema violation
