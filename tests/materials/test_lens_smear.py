"""The roughness a pinhole fit overstates through a lens: simulated gold spheres, through a pinhole and a lens."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from mocks.observation_sim import simulated_observations
from mocks.world import World
from processing.camera.response import camera_sensitivities
from processing.materials.forward_fit import FitError, ForwardModel, fit_region, region_samples
from processing.materials.lens_smear import mesh_curvature, normal_smear_rad, roughness_overstatement
from processing.spectral.spectra import SpectralGrid, light_spectrum


@pytest.fixture(scope="module")
def model():
    g = SpectralGrid(400, 700, 10)
    return ForwardModel(camera_sensitivities(g), light_spectrum("D65", g), g)


def _fit_sphere(radius_mm: float, lens_px: float, model):
    m = o3d.geometry.TriangleMesh.create_sphere(radius=radius_mm, resolution=40)
    v = np.asarray(m.vertices) + [0.0, 0.0, 37.0]
    t = np.asarray(m.triangles)
    w = World(v, t, np.zeros(len(t), int), ("body",), {"body": "gold"}, light_position_mm=(-150.0, -250.0, 300.0),
              width=240, height=160, lens_sigma_px=lens_px)
    sim = simulated_observations(w, np.arange(0.0, 360.0, 20.0), exposure_s=0.0005, sensitivities="Nikon 5100 (NPL)")
    fit = fit_region(region_samples(sim.observations, sim.vertices, sim.frames, np.arange(len(v)),
                                    triangles=sim.triangles), model)
    obs = sim.observations
    focal = np.array([0.5 * (float(f.K[0][0]) + float(f.K[1][1])) for f in sim.frames])
    curvature = mesh_curvature(sim.vertices, sim.triangles, (sim.vertices - [0.0, 0.0, 37.0]) / radius_mm)
    near = obs.half_angle_deg[:, 0] < 15.0
    smear = float(np.median(normal_smear_rad(lens_px, (obs.distance_mm / focal[obs.frame])[near],
                                             curvature[obs.vertex[near]])))
    return fit, smear


@pytest.mark.parametrize("radius_mm", [8.0, 15.0])
def test_the_lens_widens_a_small_sphere_highlight_as_predicted(model, radius_mm):
    # The simulation's gold (Beckmann 0.10) on spheres of 8 and 15 mm at 0.47 mm per photo pixel, through a
    # pinhole and through the simulated lens (one photosite).  The lens's fit overstates the roughness by what
    # the normal smear predicts: measured 0.1055 -> 0.1349 (8 mm, predicted 0.1341) and 0.1014 -> 0.1120
    # (15 mm, predicted 0.1103); the overstatement predicted from the lens's own fit is within 25 % of the
    # two fits' difference.
    pinhole, _ = _fit_sphere(radius_mm, 0.0, model)
    lens, smear = _fit_sphere(radius_mm, 1.0, model)
    assert pinhole.material == lens.material == "gold"
    m0, m1 = pinhole.parameters["roughness"], lens.parameters["roughness"]
    assert m1 > m0
    predicted = roughness_overstatement(m1, smear)
    assert abs(predicted - (m1 - m0)) <= 0.25 * (m1 - m0)
    assert abs(np.sqrt(m0 ** 2 + 2 * smear ** 2) - m1) <= 0.05 * m1


def test_curvature_and_bad_arguments():
    m = o3d.geometry.TriangleMesh.create_sphere(radius=20.0, resolution=30)
    v, t = np.asarray(m.vertices), np.asarray(m.triangles)
    assert np.median(mesh_curvature(v, t, v / 20.0)) == pytest.approx(1 / 20.0, rel=0.02)
    flat = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    assert np.all(mesh_curvature(flat, [[0, 1, 2]], np.tile([0.0, 0.0, 1.0], (3, 1))) == 0.0)
    assert roughness_overstatement(0.05, 1.0) == pytest.approx(0.05)       # the smear alone explains it
    with pytest.raises(FitError, match="do not agree"):
        mesh_curvature(v, t, v[:10])
    with pytest.raises(FitError, match="spread_px"):
        normal_smear_rad(-1.0, 0.5, 0.1)
    with pytest.raises(FitError, match="roughness"):
        roughness_overstatement(0.0, 0.01)
