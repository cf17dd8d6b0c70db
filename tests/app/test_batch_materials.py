"""The batch's ``materials`` step against the simulated world's truth.

The session is captured by the simulated station from a hawk whose head is gold and whose beak is red
urushi (``tests.app.batch_session.MATERIALS_WORLD``); the world's own per-pixel region labels (rendered
independently of the step) say which pixels of the material map belong to which true region.  The map's
colour of a material is its sRGB under D65 (``app.workflows.materials.preset_srgb``).
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from app.batch.materials import largest_material, material_colour
from app.batch.runner import process_one
from app.batch.steps import BatchOptions
from app.session import Session
from tests.app.batch_session import built_sessions, copy_session, materials_session, materials_world

OPTIONS = BatchOptions(preset="draft", render_size=(96, 72))


@pytest.fixture(scope="module")
def done(tmp_path_factory):
    src = materials_session(tmp_path_factory)
    root = copy_session(src, tmp_path_factory.mktemp("materials") / "s")
    result = process_one(str(root), ("colour", "materials"), OPTIONS)
    assert result.status == "ok", result
    return root


def _doc(root: Path) -> dict:
    rec = Session.read(root)["products"]["materials"]["report"]
    return json.loads((root / rec["file"]).read_text(encoding="utf-8"))


def _true_labels() -> np.ndarray:
    """The world's region index per pixel of the binned (2 x 2) frame; -1 backdrop."""
    return materials_world().frame("object", 0.0).labels[::2, ::2]


def test_largest_regions_get_their_true_materials(done):
    world = materials_world()
    doc = _doc(done)
    # the map of the one frame, against the world's labels of that frame
    rec = Session.read(done)["products"]["materials"]["maps"]["p01/frame/00"]
    img = np.asarray(Image.open(done / rec["file"]).convert("RGB"))
    truth = _true_labels()
    assert img.shape[:2] == truth.shape
    for name in ("head", "beak"):
        k = world.region_names.index(name)
        pixels = [tuple(c) for c in img[truth == k].tolist()]
        # few of the object's pixels are taken for backdrop (dark ones on the silhouette)
        assert pixels.count((40, 40, 40)) < 0.15 * len(pixels), name   # smooth shading: beak 13 of 102
        coloured = [c for c in pixels if c not in ((0, 0, 0), (40, 40, 40))]     # given a material
        assert len(coloured) >= 50, name              # enough lit pixels to speak of
        top, count = Counter(coloured).most_common(1)[0]
        assert top == material_colour(world.materials[name]), (name, Counter(coloured).most_common(3))
        assert count >= 0.6 * len(coloured)
    # the backdrop is recognised as such almost everywhere (silhouette cells included)
    back = img[truth == -1]
    assert np.mean(np.all(back == (40, 40, 40), axis=1)) > 0.99
    # the material over the most pixels is the true material of the largest lit region (the head)
    assert doc["largest"]["material"] == "gold"
    assert doc["largest"]["material"] == largest_material(doc["regions"])[0]


def test_region_records_are_complete_and_finite(done):
    doc = _doc(done)
    wl = doc["wavelengths"]
    assert wl[0] == 400 and wl[-1] == 700 and len(wl) == 31
    gold = [r for r in doc["regions"] if r["material"] == "gold"]
    assert len(gold) == 1                       # clusters identified alike are merged into one region
    g = gold[0]
    assert g["frames"] == ["p01/frame/00"] and g["pixels"] > 50 and 0.5 < g["confidence"] <= 1.0
    assert g["runner_up"] and g["runner_up"] != "gold"
    # gold is pure Au in the alloy model (Matsuda et al., eq. (3)-(4))
    assert max(g["alloy_weights"], key=g["alloy_weights"].get) == "Au"
    assert all(np.isfinite(v) and v >= 0 for v in g["alloy_std"].values())
    refl, unc = np.asarray(g["reflectance"]), np.asarray(g["uncertainty"])
    assert refl.shape == unc.shape == (31,) and np.all(np.isfinite(refl)) and np.all(unc > 0)
    # gold reflects red far more than blue (its Fresnel reflectance: about 0.95 at 650 nm, 0.4 at 450 nm)
    assert refl[wl.index(650)] > 1.5 * refl[wl.index(450)]


def test_materials_rerun_only_when_the_colour_product_changes(done, tmp_path):
    root = copy_session(done, tmp_path / "s")
    again = process_one(str(root), ("colour", "materials"), OPTIONS)
    assert {s.name: s.status for s in again.steps} == {"colour": "skipped", "materials": "skipped"}
    # a changed chart product (as a colour step of another version would write) reruns materials
    with Session.open(root) as session:
        rec = session.manifest["products"]["colour"]["passes"]["p01"]["chart"]
        chart = json.loads((root / rec["file"]).read_text(encoding="utf-8"))
        chart["note"] = "rewritten"
        info = session.write_file(rec["file"], (json.dumps(chart) + "\n").encode())
        products = json.loads(json.dumps(session.manifest["products"]))
        products["colour"]["passes"]["p01"]["chart"] = {"file": info.path, "sha256": info.sha256, "bytes": info.bytes}
        session.update("products", products)
    r = process_one(str(root), ("materials",), OPTIONS)
    assert [(s.name, s.status, s.reason) for s in r.steps] == [("materials", "ran", "inputs changed")]


def test_render_and_report_use_the_identified_materials(done, tmp_path, tmp_path_factory):
    from tests.app.test_report import _chromium_counts, _images

    base = built_sessions(tmp_path_factory)
    root = copy_session(done, tmp_path / "s")
    options = BatchOptions(preset="draft", calibration=str(base.cal), render_size=(96, 72))
    r = process_one(str(root), ("geometry", "colour", "materials", "render", "report"), options)
    assert r.status == "ok", r
    renders = Session.read(root)["products"]["renders"]
    assert renders["material"] == "gold" and renders["material_source"].startswith("identified")
    html = (root / "products/report.html").read_text(encoding="utf-8")
    assert "alt='material map p01/frame/00'" in html and "alt='region spectra'" in html
    assert "Not in this session:</b> identified materials" not in html
    shown, broken = _chromium_counts(root / "products/report.html", tmp_path)
    assert shown == len(_images(html)) and broken == 0


def test_session_without_chart_frames_fails_the_step(tmp_path, tmp_path_factory):
    base = built_sessions(tmp_path_factory)
    root = copy_session(base.cal, tmp_path / "cal")          # captured without camera
    r = process_one(str(root), ("materials",), OPTIONS)
    assert r.status == "failed"
    assert r.steps[0].status == "failed" and "has no colour-chart frame" in r.steps[0].reason
    assert "capture with the camera on" in r.steps[0].reason


def test_materials_step_needs_the_colour_product(tmp_path, tmp_path_factory):
    root = copy_session(materials_session(tmp_path_factory), tmp_path / "s")
    r = process_one(str(root), ("materials",), OPTIONS)
    assert r.status == "failed" and "the colour step has not run" in r.steps[0].reason
