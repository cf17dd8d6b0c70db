"""Chart-calibrated spectral estimation and identification on values from the simulated camera (mocks)."""

from __future__ import annotations

import numpy as np

from mocks.camera_sim import channel_signal
from processing.camera.response import camera_rgb, camera_sensitivities
from processing.camera.transfer import fit_chart_transform
from processing.materials.identification import candidate_set, identify_regions
from processing.materials.metal_model import ConductorFresnel
from processing.spectral.estimation.estimator import fit_estimator, region_spectra
from processing.spectral.reflectance_database import load_reflectances, without_near_duplicates
from processing.spectral.spectra import SpectralGrid, light_spectrum

G = SpectralGrid(400, 700, 10)


def test_simulated_shot_is_calibrated_by_its_chart_then_estimated_and_identified():
    e = light_spectrum("D65", G)
    chart = load_reflectances("colorchecker", G)
    db = without_near_duplicates(load_reflectances("training", G), chart).spectra
    sens = camera_sensitivities(G)
    exposure = 0.0137                                       # arbitrary radiance scale of the shot
    # the simulated camera sees radiance R E / pi; the chart's patch means carry 0.1 % noise
    rng = np.random.default_rng(0)
    chart_rgb = channel_signal(chart.spectra * e / np.pi * exposure, G) * (1 + 1e-3 * rng.standard_normal((24, 3)))
    fit = fit_estimator("rootpoly", db, sens, e, G, chart_rgb=chart_rgb, chart_reflectance=chart.spectra)
    assert fit.condition["chart"] < 20
    # an image: left half a chart patch (orange), right half jo-shibuichi seen at the identification geometry
    cos_d = np.cos(np.radians(15))
    metal = ConductorFresnel({"Ag": 0.396, "Cu": 0.594, "Au": 0.01}).reflectance(cos_d, G.wavelengths)
    orange = chart.spectra[chart.names.index("orange")]
    img = np.zeros((10, 20, G.size))
    img[:, :10] = orange
    img[:, 10:] = 0.3 * metal
    rgb = channel_signal(img * e / np.pi * exposure, G) * (1 + 0.01 * rng.standard_normal((10, 20, 3)))
    labels = np.zeros((10, 20), int)
    labels[:, :10], labels[:, 10:] = 1, 2
    weights = fit.estimate_weights(rgb)
    regions = region_spectra(weights, labels, fit.basis, method_error=0.044)
    # the orange patch's spectrum is recovered to the method's held-out accuracy
    err = np.sqrt(np.mean((regions.mean[0] - orange) ** 2))
    assert err < 0.05
    # identification in the model camera's units: the chart transform is applied first
    transform = fit_chart_transform(chart_rgb, camera_rgb(chart.spectra, e, sens, G))
    model_rgb = np.maximum(rgb.reshape(-1, 3) @ transform.matrix, 0.0)
    cands = candidate_set(sens, e, G, light_deg=30.0)
    found = identify_regions(model_rgb.reshape(10, 20, 3), np.where(labels == 2, 1, 0), cands)
    assert found[1].material == "jo-shibuichi", (found[1].material, found[1].runner_up)
