"""The colour demo on a small hawk: files written, materials compared with the world's truth."""

from __future__ import annotations

import contextlib
import io
import json

import cv2
import pytest

from app.cli import main
from app.demo.colour import colour_demo
from mocks.procedural_hawk import DEFAULT_MATERIALS, hawk_head
from processing.materials.alloys import alloy_weights

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


def test_colour_demo_identifies_the_hawks_metals(tmp_path):
    # one view, a coarse mesh; cv2.mcc needs the chart frame at 600 x 400
    summary = colour_demo(tmp_path, triangles=4_000, angles=(-25.0,))   # 2000: too coarse for the small beak
    saved = json.loads((tmp_path / "identify.json").read_text())
    assert saved["regions"] == summary["regions"]
    for name in ("chart.dng", "object_-025.dng", "labels_-025.png"):
        assert (tmp_path / name).stat().st_size > 0
    fig = cv2.imread(str(tmp_path / "spectra.png"))
    assert fig is not None and fig.shape[0] > 300 and fig.shape[1] > 600
    regions = {r["region"]: r for r in summary["regions"]}
    # the truth is the procedural hawk's own material table, not the demo's
    assert {k: r["true_material"] for k, r in regions.items()} == DEFAULT_MATERIALS
    beak = regions["beak"]
    assert beak["material"] == "gold" and beak["confidence"] > 0.9 and beak["alloy_weights"]["Au"] > 0.9
    head = regions["head"]
    assert head["material"] in ("nami-shibuichi", "nami-shibuichi-soto-sanbu", "nami-shibuichi-uchi-sanbu")
    truth_ag = alloy_weights("nami-shibuichi")["Ag"]
    assert abs(truth_ag - 0.25) < 0.01                      # Matsuda et al. Table 1
    assert abs(head["alloy_weights"]["Ag"] - truth_ag) < 0.05
    assert head["true_alloy_weights"]["Ag"] == pytest.approx(truth_ag)
    assert summary["correct"] == sum(r["material"] == r["true_material"] for r in summary["regions"])
    for r in summary["regions"]:
        if r["material"] is None:                           # a region without a usable pixel says so
            assert r["pixels"] == 0 and r["note"]
        else:
            assert 0 < r["confidence"] <= 1 and r["runner_up"] != r["material"]
    # the same files through the command line, with the world's label image as the regions: the same answers
    out = tmp_path / "result.npz"
    assert main(["spectral", "estimate", str(tmp_path / "object_-025.dng"), "--chart", str(tmp_path / "chart.dng"),
                 "--out", str(out), "--quiet"]) == 0
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert main(["identify", str(out), "--regions", str(tmp_path / "labels_-025.png"), "--light-deg",
                     str(summary["light_deg"]), "--model-error", str(summary["model_error"]), "--json"]) == 0
    cli = {r["label"]: r for r in json.loads(buf.getvalue())["regions"]}
    for k, name in enumerate(hawk_head(2_000).region_names, start=1):
        assert cli[k]["material"] == regions[name]["material"] and cli[k]["pixels"] == regions[name]["pixels"]
        if cli[k]["confidence"] is not None:
            assert cli[k]["confidence"] == pytest.approx(regions[name]["confidence"], rel=1e-9)
