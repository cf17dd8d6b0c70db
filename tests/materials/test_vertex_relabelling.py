"""Vertices relabelled by the fitted materials: a simulated sphere whose two materials are known."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from mocks.observation_sim import simulated_observations
from mocks.world import World
from processing.camera.response import camera_sensitivities
from processing.materials.forward_fit import FitError, ForwardModel, region_samples
from processing.materials.presets import get_material
from processing.materials.vertex_relabelling import UNARY_CAP_NATS, relabel_vertices, vertex_material_costs
from processing.spectral.spectra import SpectralGrid, light_spectrum

ANGLES = np.arange(0.0, 360.0, 30.0)


@pytest.fixture(scope="module")
def model():
    g = SpectralGrid(400, 700, 10)
    return ForwardModel(camera_sensitivities(g), light_spectrum("D65", g), g)


@pytest.fixture(scope="module")
def two_metals():
    """A sphere, nami-shibuichi below z = 52 mm and gold above, its observations, and each vertex's truth.

    Truth (from the simulation's faces): 1 where every face of the vertex is gold, 0 where every one is
    nami-shibuichi, -1 on the border between them (its pixels show both).
    """
    m = o3d.geometry.TriangleMesh.create_sphere(radius=30.0, resolution=40)
    v = np.asarray(m.vertices) + [0.0, 0.0, 37.0]
    t = np.asarray(m.triangles)
    face_gold = v[t].mean(axis=1)[:, 2] > 52.0
    w = World(v, t, face_gold.astype(int), ("head", "beak"), {"head": "nami-shibuichi", "beak": "gold"},
              light_position_mm=(-150.0, -250.0, 300.0), width=240, height=160)
    sim = simulated_observations(w, ANGLES, exposure_s=0.0005, sensitivities="Nikon 5100 (NPL)")
    gold = np.bincount(t[face_gold].ravel(), minlength=len(v)) > 0
    nami = np.bincount(t[~face_gold].ravel(), minlength=len(v)) > 0
    return sim, np.where(gold & nami, -1, np.where(gold, 1, 0)).astype(np.int32)


def test_a_patch_given_the_wrong_region_returns_to_its_material(two_metals, model):
    # The segmentation's error, staged: the gold cap's lower half labelled as the nami-shibuichi region.
    # Each vertex's own observations, scored under the two materials, bring it back; vertices elsewhere stay.
    sim, truth = two_metals
    v = sim.vertices
    labels = np.where(truth < 0, 0, truth)
    patch = (truth == 1) & (v[:, 2] < 60.0)
    labels[patch] = 0
    seen = np.diff(sim.observations.offsets) > 0
    samples = region_samples(sim.observations, v, sim.frames, np.flatnonzero(seen), triangles=sim.triangles)
    mats = [get_material("nami-shibuichi"), get_material("gold")]
    cost = vertex_material_costs(samples, model, mats, len(v))
    assert cost.shape == (len(v), 2) and cost.min() == 0.0 and cost.max() <= UNARY_CAP_NATS
    out = relabel_vertices(cost, labels, sim.triangles)
    judged = patch & seen
    assert judged.sum() >= 50
    assert np.mean(out[judged] == 1) >= 0.9                              # measured: 1.00
    rest = ~patch & seen & (truth >= 0)
    assert np.mean(out[rest] == truth[rest]) >= 0.99                     # measured: 1.00


def test_observations_that_cannot_tell_leave_the_labels_to_the_neighbours(two_metals, model):
    # The same material offered twice: every vertex costs 0 for both, so only the Potts term acts (a lone
    # vertex of another label inside a region joins it; a region's interior keeps its label).
    sim, truth = two_metals
    samples = region_samples(sim.observations, sim.vertices, sim.frames,
                             np.flatnonzero(np.diff(sim.observations.offsets) > 0), triangles=sim.triangles)
    nami = get_material("nami-shibuichi")
    cost = vertex_material_costs(samples, model, [nami, nami], len(sim.vertices))
    assert np.all(cost == 0.0)
    start = np.where(truth < 0, 0, truth)
    labels = start.copy()
    lone = int(np.flatnonzero(truth == 0)[len(truth) // 3])
    labels[lone] = 1
    out = relabel_vertices(cost, labels, sim.triangles)
    assert out[lone] == 0 and np.mean(out == start) >= 0.99


def test_a_region_without_material_is_neither_given_nor_left():
    tri = [[0, 1, 2], [1, 2, 3]]
    cost = np.array([[0.0, np.inf], [0.0, np.inf], [5.0, np.inf], [5.0, np.inf]])    # region 1 has no material
    out = relabel_vertices(cost, [0, 0, 0, 1], tri)
    assert out.tolist() == [0, 0, 0, 1]          # vertex 3 keeps its region; nobody is moved into it
    assert relabel_vertices(cost, [-1, 0, 0, 0], tri)[0] == -1


def test_bad_arguments_say_what_to_give(model):
    with pytest.raises(FitError, match="do not agree"):
        relabel_vertices(np.zeros((3, 2)), [0, 0], [[0, 1, 2]])
    with pytest.raises(FitError, match="labels must be"):
        relabel_vertices(np.zeros((3, 2)), [0, 2, 0], [[0, 1, 2]])
    with pytest.raises(FitError, match="smoothness"):
        relabel_vertices(np.zeros((3, 2)), [0, 0, 0], [[0, 1, 2]], smoothness=-1.0)
    with pytest.raises(FitError, match="materials"):
        vertex_material_costs(None, model, [], 3)
    with pytest.raises(FitError, match="cap_nats"):
        vertex_material_costs(None, model, [None], 3, cap_nats=0.0)
