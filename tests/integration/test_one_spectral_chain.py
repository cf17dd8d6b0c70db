"""One chart -> spectral-estimate chain: the command line, the window's spectra panel and the batch agree exactly.

A simulated hawk (``mocks.world.World``) is shot with its ColorChecker through the simulated Nikon D5100
into two DNGs, the object at a quarter of the chart's exposure (so the chart must be brought to the
object's exposure).  ``kogei spectral estimate`` (through ``app.cli.main`` and its RESULT.npz), the
spectra panel's analysis (:func:`app.gui.spectra_panel.analyse_spectra`) and the batch's estimate of an
object frame from the colour step's chart report (:func:`app.batch.colour` writes it with
:func:`app.workflows.chart.chart_report`; :func:`app.batch.materials.estimate_frame` reads it back) all
call :func:`app.workflows.spectral.estimate_from_chart`, so the per-pixel weights, the mask and the
model-camera image are the same arrays, bit for bit.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.batch.materials import estimate_frame
from app.cli import main
from app.workflows.chart import chart_report
from app.workflows.spectral import load_result

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")

CHART_EXPOSURE_S = 0.01


@pytest.fixture(scope="module")
def shots(tmp_path_factory):
    from mocks.camera_sim import simulate_raw, write_raw
    from mocks.world import World

    out = tmp_path_factory.mktemp("one-chain")
    # cv2.mcc needs the chart frame at 600 x 400 or more
    world = World.hawk(2_000, chart_layout="classic24", width=600, height=400)
    chart = world.frame("chart")
    chart_path = write_raw(out / "chart.dng", simulate_raw(chart.radiance, chart.grid, chart.light, seed=1,
                                                           exposure_s=CHART_EXPOSURE_S))
    frame = world.frame("object", 0.0)
    object_path = write_raw(out / "object.dng", simulate_raw(frame.radiance, frame.grid, frame.light, seed=2,
                                                             exposure_s=CHART_EXPOSURE_S / 4))
    return out, object_path, chart_path


@pytest.mark.parametrize("method", ["rootpoly", "wiener"])
def test_cli_panel_and_batch_give_identical_weights(shots, method):
    pytest.importorskip("PySide6.QtWidgets", reason="the spectra panel needs PySide6")
    from app.gui.spectra_panel import analyse_spectra

    out, object_path, chart_path = shots
    npz = out / f"{method}.npz"
    assert main(["spectral", "estimate", str(object_path), "--chart", str(chart_path), "--method", method,
                 "--out", str(npz), "--quiet"]) == 0
    cli = load_result(npz)
    panel = analyse_spectra(object_path, chart_path, light="D65", method=method).estimate
    # the colour step stores chart_report's dict as JSON; the materials step reads it back
    report = json.loads(json.dumps(chart_report(chart_path, chart="classic24")))
    batch = estimate_frame(object_path, report, "classic24") if method == "rootpoly" else None

    assert cli.metadata["method"] == method and cli.weights.dtype == np.float32
    assert np.array_equal(cli.weights, panel.weights)
    assert np.array_equal(cli.mask, panel.mask)
    assert np.array_equal(cli.camera, panel.camera)
    assert cli.method_error == panel.chart_rmse
    if batch is not None:                    # the batch estimates with its one method (rootpoly)
        assert np.array_equal(cli.weights, batch.weights)
        assert np.array_equal(cli.mask, batch.mask)
        assert np.array_equal(cli.camera, batch.camera)
        assert batch.metadata["chart_rmse"] == cli.metadata["chart_rmse"]
    # the chain did bring the chart to the object's exposure: the chart calibrates within its usual error
    assert 0 < cli.method_error < 0.1
    assert cli.mask.mean() > 0.9
