"""The session report reads correctly to a curator: a summary box with the session's real figures,
unreliable material answers flagged, plain units, and every render captioned with the materials it shows.

Two generated sessions: the simulated hawk of ``tests/app/batch_session.py`` (gold head, red-urushi beak)
run through ``kogei batch`` without a camera calibration, so its materials are identified in the photos
only and the renders are a one-material stand-in; and the hawk posed on its mesh
(``tests/integration/object_session.py``) with its materials fitted on the mesh and rendered region by
region.  Expected figures are read from the sessions' own product files (JSON written by the processing
steps), never from the report code; the rule "unreliable" is the materials code's documented one (no
candidate fits, or a reduced chi-square above ``MAX_MISFIT``), applied here independently.
"""

from __future__ import annotations

import html as htmllib
import json
import re
from pathlib import Path

import pytest

from app.batch.runner import process_one, run_batch
from app.batch.steps import BatchOptions
from app.report.html import build_report
from app.session import Session
from processing.materials.confidence import MAX_MISFIT, NO_FIT, NOT_MEASURED
from tests.app.batch_session import built_sessions, copy_session, materials_session


@pytest.fixture(scope="module")
def image_only(tmp_path_factory):
    """A processed session whose materials were identified in the photos only (no camera calibration)."""
    base = built_sessions(tmp_path_factory)
    root = copy_session(materials_session(tmp_path_factory), tmp_path_factory.mktemp("readable") / "image-only")
    r = process_one(str(root), ("geometry", "colour", "materials", "render"),
                    BatchOptions(preset="draft", calibration=str(base.cal), render_size=(96, 72)))
    assert r.status == "ok", r
    return root, build_report(root)


@pytest.fixture(scope="module")
def on_mesh(tmp_path_factory):
    """The hawk posed on its mesh, materials fitted per region, rendered with them."""
    from tests.integration.object_session import measured_hawk_session

    # measured once per run, shared with tests/app/test_object_materials.py
    root, _ = measured_hawk_session(tmp_path_factory, tmp_path_factory.mktemp("readable") / "on-mesh")
    result = run_batch([root], "render", options=BatchOptions(preset="draft", render_size=(96, 72)),
                       workers=1).results[0]
    assert result.status == "ok", result.reason
    return root, build_report(root)


def _product(root: Path, *keys: str) -> dict:
    rec = Session.read(root)["products"]
    for k in keys:
        rec = rec[k]
    return json.loads((root / rec["file"]).read_text(encoding="utf-8"))


def _text(fragment: str) -> str:
    """Visible text of an HTML fragment (tags dropped, entities decoded, spaces collapsed)."""
    return re.sub(r"\s+", " ", htmllib.unescape(re.sub(r"<[^>]+>", " ", fragment))).strip()


def _summary(page: str) -> str:
    m = re.search(r"<div class='glance' id='summary'>(.*?)</div>", page, re.S)
    assert m, "no summary box"
    assert page.index("id='summary'") < page.index("<section"), "the summary box is not at the top"
    return _text(m.group(1))


def _row(page: str, first_cell: str) -> tuple[str, str]:
    """(class, text) of the first table row whose first cell is ``first_cell``."""
    m = re.search(rf"<tr class='([^']*)'><td>{re.escape(first_cell)}</td>(.*?)</tr>", page, re.S)
    assert m, f"no row for {first_cell}"
    return m.group(1), _text(m.group(2))


def _render_captions(page: str) -> list[str]:
    return [_text(c) for c in re.findall(r"<figure class='render'><img [^>]*>(?:<figcaption>(.*?)</figcaption>)?"
                                         r"</figure>", page, re.S)]


def _poor(misfit, material) -> bool:
    return material in (None, NO_FIT) or (misfit is not None and float(misfit) > MAX_MISFIT)


def test_summary_states_the_image_only_sessions_figures(image_only):
    root, page = image_only
    box = _summary(page)
    proc = _product(root, "process_report")
    assert f"3-D mesh of {proc['mesh']['triangles']:,} triangles" in box
    cal = json.loads((root / Session.read(root)["calibration"]["path"]).read_text(encoding="utf-8"))
    assert f"{1000 * cal['rms_mm']:.1f} µm" in box
    chart = _product(root, "colour", "passes", "p01", "chart")
    assert f"ΔE00 {chart['patch_errors']['mean']:.2f}" in box
    regions = _product(root, "materials", "report")["regions"]
    poor = [r for r in regions if _poor(r.get("misfit"), r.get("material"))]
    # the rule of the report's docs: below 0.8, or sharing its answer with other candidates, is uncertain
    doubtful = [r for r in regions if r not in poor and (r["confidence"] < 0.8 or len(r.get("group") or []) > 1)]
    assert poor or doubtful, "the session must hold a region in doubt for this check to mean anything"
    assert f"{len(regions)} regions in the photos only" in box
    assert f"{len(poor)} unreliable" in box and f"{len(doubtful)} uncertain" in box
    flagged = box.split("What is uncertain", 1)[1]
    for r in poor + doubtful:
        assert r["region"] in flagged, r["region"]                          # listed as in doubt
    largest = _product(root, "materials", "report")["largest"]["material"]
    assert f"a stand-in -- one material, {largest}, for the whole object" in box


def test_poorly_fitting_regions_are_flagged(image_only):
    root, page = image_only
    for r in _product(root, "materials", "report")["regions"]:
        cls, text = _row(page, r["region"])
        if _poor(r.get("misfit"), r.get("material")):
            assert cls == "v-unreliable" and "unreliable" in text, (r["region"], text)
        elif r.get("misfit") is not None and r["misfit"] < 1.0 and r["confidence"] > 0.95 and len(r["group"]) == 1:
            assert cls == "v-reliable" and "unreliable" not in text, (r["region"], text)
    assert "<p class='caveat'><b>Caution:</b>" in page


def test_an_old_confident_name_that_fits_nothing_is_flagged(image_only, tmp_path):
    """A region written before the confidence rules: "lead" at 0.99 with a reduced chi-square of 159."""
    root = copy_session(image_only[0], tmp_path / "old")
    doc = _product(root, "materials", "report")
    reg = doc["regions"][0]
    reg.update(material="lead", confidence=0.99, group=["lead"], misfit=159.0, chi2=318.0,
               alloy_weights={"Ag": 1.0, "Cu": 0.0, "Au": 0.0}, alloy_std={"Ag": 0.0, "Cu": 0.0, "Au": 0.0})
    with Session.open(root) as s:
        info = s.write_file("products/materials.json", (json.dumps(doc) + "\n").encode())
        products = json.loads(json.dumps(s.manifest["products"]))
        products["materials"]["report"]["sha256"] = info.sha256
        s.update("products", products)
    page = build_report(root)
    cls, text = _row(page, reg["region"])
    assert cls == "v-unreliable" and text.startswith("lead unreliable fits poorly")
    assert "Ag 100" not in page                        # no alloy composition for a pure metal, let alone a misfit
    assert f"{reg['region']} (lead) is unreliable" in _summary(page)


def test_units_exposure_and_plan_read_plainly(image_only):
    _, page = image_only
    text = _text(page)
    assert "f/0.0" not in text and "f/0 " not in text
    chart = re.search(r"<th>exposure</th><td>([^<]*)</td>", page)
    assert chart and re.fullmatch(r"(1/\d+ s|[\d.]+ s|time unknown), (ISO \d+|ISO unknown), "
                                  r"(f/[\d.]+|aperture unknown)", htmllib.unescape(chart.group(1)))
    assert not re.search(r"\d um\b", text) and "µm" in text
    assert "mm2" not in text and "mm²" in text
    assert "{'" not in text and "'kind':" not in text                  # no Python dict anywhere
    plan = Session.read(image_only[0])["plan"]
    assert "<h3>Capture plan</h3>" in page
    assert f"placements of the object (passes) {plan['passes']}" in text
    assert f"table positions per turn {plan['steps']}" in text


def test_render_captions_name_the_stand_in(image_only):
    root, page = image_only
    captions = _render_captions(page)
    assert len(captions) == 3 + 2                                        # three mesh views, D65 and A
    largest = _product(root, "materials", "report")["largest"]["material"]
    for cap in captions:
        assert "Materials shown:" in cap and "stand-in" in cap, cap
    assert sum(f"one material, {largest}, for the whole object" in c for c in captions) == 2
    assert "Caution:</b> these renders show a stand-in" in page


def test_spectra_one_plot_per_identified_material(image_only):
    root, page = image_only
    regions = _product(root, "materials", "report")["regions"]
    identified = {r["material"] for r in regions if r.get("material") not in (None, NO_FIT) and r.get("reflectance")}
    assert page.count("alt='region spectra'") == 1
    caption = re.search(r"alt='region spectra'>(?:<figcaption>(.*?)</figcaption>)", page, re.S)
    assert caption and "clipped to the physical range" in caption.group(1)
    assert identified and "One plot per material" in page


def test_summary_and_renders_of_the_measured_object(on_mesh):
    root, page = on_mesh
    box = _summary(page)
    doc = _product(root, "object_materials")
    regions = doc["regions"]
    assert f"{len(regions)} regions on the 3-D mesh" in box
    poor = [r for r in regions if _poor(r.get("chi2_per_dof"), r.get("material")) and r["material"] != NOT_MEASURED]
    assert f"{len(poor)} unreliable" in box
    val = doc["validation"]
    assert f"ΔE00 {val['mean_de2000']:.2f}" in box and f"{val['baseline_mean_de2000']:.2f}" in box
    assert "show the measured materials, region by region" in box
    nm = doc["not_measured"]            # the cut face the hawk stands on: how much, which way it faces, what to capture
    assert nm["faces"] and nm["facing"][2] < -0.9 and "facing down" in nm["advice"]
    assert f"{nm['area_mm2']:,.0f} mm² of the surface has no measured material (shown grey): {nm['advice']}" in box
    for r in regions:
        cls, _ = _row(page, str(r["index"]))
        assert (cls == "v-unreliable") == (r in poor), (r["index"], cls)
    captions = _render_captions(page)
    renders = [c for c in captions if c.startswith("Under ")]
    triptychs = [c for c in captions if "photo | render" in c]
    assert len(renders) == 2 and triptychs
    for cap in renders + triptychs:
        assert "the measured materials, region by region" in cap, cap
        for r in regions:                   # what is drawn: the fitted material, or the closest one, starred
            if r["material"] == NO_FIT:
                assert f"region {r['index']}: {r['spec'].split(':')[0]}*" in cap, (r["index"], cap)
                assert "* no candidate fits: its closest candidate is drawn; unreliable" in cap
            elif r["material"] != NOT_MEASURED:
                assert f"region {r['index']}: {r['material']}" in cap, (r["index"], cap)
    for cap in captions:
        if cap not in renders + triptychs:
            assert "grey stand-in" in cap, cap                           # the mesh views
