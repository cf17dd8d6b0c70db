"""``kogei identify`` names the misfit and says "no candidate fits" rather than a confident name.

Truth: a small spectral result whose left half holds gold's own camera values (its Fresnel reflectance at
the identification geometry, not the candidate table) and whose right half holds a monochromatic green
(530 nm alone) that no metal or lacquer reflects.
"""

from __future__ import annotations

import json
import re

import cv2
import numpy as np

from app.cli import main
from app.workflows.spectral import SpectralResult, save_result
from processing.camera.response import camera_rgb, camera_sensitivities
from processing.materials.presets import get_material
from processing.spectral.spectra import SpectralGrid, light_spectrum

G = SpectralGrid(400, 700, 10)


def _result(tmp_path):
    sens, d65 = camera_sensitivities(G), light_spectrum("D65", G)
    gold = camera_rgb(get_material("gold").lobes[0].spectral.reflectance(np.cos(np.radians(15.0)), G.wavelengths),
                      d65, sens, G)
    line = np.zeros(G.size)
    line[G.wavelengths.tolist().index(530.0)] = 1.0
    green = camera_rgb(line, d65, sens, G)
    cam = np.zeros((8, 8, 3), np.float32)
    cam[:, :4] = 0.5 * gold
    cam[:, 4:] = 20.0 * green
    rng = np.random.default_rng(0)
    cam *= (1 + 0.01 * rng.standard_normal(cam.shape)).astype(np.float32)
    basis = np.linalg.qr(np.random.default_rng(1).standard_normal((G.size, 3)))[0]
    res = SpectralResult(np.full((8, 8, 3), 0.1, np.float32), basis, G.wavelengths, np.ones((8, 8), bool), cam,
                         sens, d65[None, :], "rootpoly", {"chart_rmse": 0.01})
    path = save_result(res, tmp_path / "r.npz")
    labels = np.ones((8, 8), np.uint8)
    labels[:, 4:] = 2
    cv2.imwrite(str(tmp_path / "labels.png"), labels)
    return path, tmp_path / "labels.png"


def test_identify_prints_the_misfit_and_no_candidate_fits(tmp_path, capsys):
    path, labels = _result(tmp_path)
    assert main(["identify", str(path), "--regions", str(labels)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert re.fullmatch(r"region 1: gold \(confidence (0\.9\d|1\.00); runner-up [\w-]+; reduced chi-square "
                        r"[0-9.e+-]+\), 32 pixels(; alloy .*)?", out[0]), out[0]
    m = re.fullmatch(r"region 2: no candidate fits \(best: ([\w-]+), reduced chi-square ([0-9.e+-]+)\), 32 pixels",
                     out[1])
    assert m, out[1]
    assert float(m.group(2)) > 25
    assert main(["identify", str(path), "--regions", str(labels), "--json"]) == 0
    regions = json.loads(capsys.readouterr().out)["regions"]
    assert regions[0]["misfit"] < 1.0 and regions[1]["misfit"] > 25
    assert regions[1]["material"] == "no candidate fits" and regions[1]["alloy_weights"] is None
    assert regions[1]["group"][0] == m.group(1)
