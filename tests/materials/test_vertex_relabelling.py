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


def _patch_and_samples(two_metals):
    """The segmentation's error, staged: the gold cap's lower half (below z = 60 mm) labelled nami-shibuichi.

    Returns the simulation, the truth, those labels, the patch's observed vertices and the samples of
    every observed vertex.
    """
    sim, truth = two_metals
    v = sim.vertices
    labels = np.where(truth < 0, 0, truth)
    patch = (truth == 1) & (v[:, 2] < 60.0)
    labels[patch] = 0
    seen = np.diff(sim.observations.offsets) > 0
    samples = region_samples(sim.observations, v, sim.frames, np.flatnonzero(seen), triangles=sim.triangles)
    return sim, truth, labels, patch & seen, samples


def test_a_patch_given_the_wrong_region_returns_to_its_material(two_metals, model):
    # Each vertex's own observations, scored under the two materials, bring the patch back; vertices elsewhere
    # stay.
    sim, truth, labels, judged, samples = _patch_and_samples(two_metals)
    v = sim.vertices
    seen = np.diff(sim.observations.offsets) > 0
    mats = [get_material("nami-shibuichi"), get_material("gold")]
    cost = vertex_material_costs(samples, model, mats, len(v))
    assert cost.shape == (len(v), 2) and cost.min() == 0.0 and cost.max() <= UNARY_CAP_NATS
    out = relabel_vertices(cost, labels, sim.triangles)
    assert judged.sum() >= 50
    assert np.mean(out[judged] == 1) >= 0.9                              # measured: 1.00
    rest = ~judged & seen & (truth >= 0)
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


def test_light_the_model_does_not_follow_leaves_the_colour_to_decide(two_metals, model):
    # The gold patch as an underside is seen: no view near its highlight (those dropped), and every other
    # view brightened by light of gold's own colour that no material's prediction has (what a neighbour's
    # highlight spread by the lens, or a normal a few degrees off, adds; about 19 times the noise).  Both
    # materials miss that level alike; its misfit counts up to LEVEL_CAP_CHI2 per observation and the colour
    # brings most of the patch back.  Counted in full, the level decides nothing and all of it stays.
    import dataclasses

    sim, truth, labels, judged, samples = _patch_and_samples(two_metals)
    in_patch = np.isin(samples.vertex, np.flatnonzero(judged))
    underside = samples.subset(np.flatnonzero(~in_patch | (samples.cos_h < np.cos(np.radians(25.0)))))
    off = np.isin(underside.vertex, np.flatnonzero(judged))
    gold = get_material("gold")
    signal = underside.signal.copy()
    signal[off] += 0.1 * model.colour(gold.lobes[0].spectral, underside.cos_d[off]) * underside.cos_i[off, None]
    lit = dataclasses.replace(underside, signal=signal)
    mats = [get_material("nami-shibuichi"), gold]
    kept = relabel_vertices(vertex_material_costs(lit, model, mats, len(truth)), labels, sim.triangles)
    full = relabel_vertices(vertex_material_costs(lit, model, mats, len(truth), level_cap=np.inf), labels,
                            sim.triangles)
    assert np.mean(kept[judged] == 1) >= 0.5                              # measured: 0.63
    assert np.mean(full[judged] == 1) <= 0.05                             # measured: 0.00


def test_a_region_whose_material_is_unnamed_takes_no_vertex(two_metals, model):
    # A dull, dark third material (bronze with a hundredth of its gloss) explains a metal's dark views about
    # as well as the metal itself; flagged unnamed (its region's fit could not name it) it claims nothing,
    # and the part of the nami-shibuichi the segmentation gave it goes back to its neighbours' region.
    sim, truth, _, _, samples = _patch_and_samples(two_metals)
    v = sim.vertices
    labels = np.where(truth < 0, 0, truth)
    band = (truth == 0) & (v[:, 2] > 20.0) & (v[:, 2] < 30.0)
    labels[band] = 2
    mats = [get_material("nami-shibuichi"), get_material("gold"), get_material("bronze:gloss=0.005,roughness=0.3")]
    held = relabel_vertices(vertex_material_costs(samples, model, mats, len(truth)), labels, sim.triangles)
    assert np.mean(held[band] == 2) >= 0.95                               # not flagged, it keeps them all
    cost = vertex_material_costs(samples, model, mats, len(truth), unnamed=[False, False, True])
    out = relabel_vertices(cost, labels, sim.triangles)
    assert np.mean(out[band] == 0) >= 0.95 and not np.any(out == 2)      # measured: 1.00 and none
    with pytest.raises(FitError, match="unnamed"):
        vertex_material_costs(samples, model, mats, len(truth), unnamed=[True])


def test_with_the_level_counted_in_full_the_score_is_the_fits_chi_square(two_metals, model):
    # colour part + level part = the whole whitened residual: with a level cap no observation reaches (the split
    # made), the costs are half the differences of the fit's own per-vertex chi-square (pieces_chi2 without a
    # cap, one piece per vertex: the whole residual, no split)
    from processing.materials.region_consistency import pieces_chi2

    sim, truth, _, _, samples = _patch_and_samples(two_metals)
    mats = [get_material("nami-shibuichi"), get_material("gold")]
    cost = vertex_material_costs(samples, model, mats, len(truth), cap_nats=1e12, level_cap=1e300)
    ids, chi2, _, _ = pieces_chi2(samples, samples.vertex, model, mats)
    np.testing.assert_allclose(cost[ids], 0.5 * (chi2 - chi2.min(axis=1, keepdims=True)), rtol=1e-9, atol=1e-6)


def test_views_near_the_highlight_decide_a_vertex_and_dark_views_do_not(two_metals, model):
    # The gold patch seen with its highlights: nearly every vertex's own views favour gold by DECIDED_NATS or
    # more.  The same patch with only its views 25 deg or more from the mirror direction (an underside): both
    # metals predict almost nothing there, so its views cannot tell them apart and the label is the neighbours'.
    from processing.materials.vertex_relabelling import DECIDED_NATS

    sim, truth, _, judged, samples = _patch_and_samples(two_metals)
    mats = [get_material("nami-shibuichi"), get_material("gold")]

    def decided(s):
        c = np.sort(vertex_material_costs(s, model, mats, len(truth)), axis=1)
        return (c[:, 1] - c[:, 0]) >= DECIDED_NATS

    in_patch = np.isin(samples.vertex, np.flatnonzero(judged))
    underside = samples.subset(np.flatnonzero(~in_patch | (samples.cos_h < np.cos(np.radians(25.0)))))
    lit_views = np.bincount(samples.vertex[samples.cos_h >= np.cos(np.radians(15.0))], minlength=len(truth)) > 0
    with_highlight = judged & lit_views
    assert with_highlight.sum() >= 50
    assert np.mean(decided(samples)[with_highlight]) >= 0.9              # measured: 1.00 (124 vertices)
    assert np.mean(decided(underside)[judged]) <= 0.1                    # measured: 0.00


def _grid(n: int) -> np.ndarray:
    """Triangles of an n x n grid of vertices (row-major)."""
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    return np.concatenate([np.stack([a, a + 1, a + n], 1), np.stack([a + 1, a + n + 1, a + n], 1)])


def test_unexplained_pieces_find_a_patch_that_leans_a_little_and_not_the_noise_around_it():
    from processing.materials._forward_fit_samples import FitError
    from processing.materials.vertex_relabelling import unexplained_pieces

    rng = np.random.default_rng(3)
    n = 30
    tri = _grid(n)
    ii, jj = np.divmod(np.arange(n * n), n)
    patch = (ii >= 5) & (ii < 11) & (jj >= 5) & (jj < 11)          # 36 vertices of another material
    labels = np.where(jj < 20, 0, 1)                                 # two regions, the patch inside region 0
    # the rest: each vertex is explained by its own material, but the least cost over many rivals wins by
    # chance on a third of them, by up to 1 nat; the patch's vertices lean to a rival by only 0.5 nat each
    noise = np.where(rng.random(n * n) < 0.2, rng.uniform(0.0, 1.0, n * n), 0.0)
    own = np.where(patch, 0.5, noise)
    rival = np.where(patch, 0.0, np.where(noise > 0, 0.0, rng.uniform(0.0, 1.0, n * n)))
    area = np.ones(n * n)
    found = unexplained_pieces(own, rival, labels, tri, area, min_area=10, margins=(0.0,))
    assert len(found) == 1
    assert patch[found[0]].sum() >= 32 and (~patch[found[0]]).sum() <= 2      # measured: 34 of 36, none outside
    # without the neighbours' vote the vertices where a rival wins by chance are as many as the patch's and
    # scattered over both regions
    assert np.sum((rival < own) & ~patch) > patch.sum()
    # a margin above the patch's lean finds nothing; a margin list finds it once
    assert unexplained_pieces(own, rival, labels, tri, area, min_area=10, margins=(1.0,)) == []
    assert len(unexplained_pieces(own, rival, labels, tri, area, min_area=10, margins=(1.0, 0.0, 0.0))) == 1
    # a piece never crosses regions; a piece over max_share of its region is its region's own material
    strip = jj >= 18                                                 # two columns of region 0, eight of region 1
    pieces = unexplained_pieces(np.where(strip, 3.0, 0.0), np.where(strip, 0.0, 3.0), labels, tri, area,
                                min_area=10, margins=(0.0,))
    assert sorted(sorted(set(labels[p].tolist())) for p in pieces) == [[0]]
    assert unexplained_pieces(np.full(n * n, 3.0), np.zeros(n * n), labels, tri, area, min_area=1) == []
    with pytest.raises(FitError, match="do not agree"):
        unexplained_pieces(own[:5], rival, labels, tri, area, min_area=1)
    with pytest.raises(FitError, match="margins"):
        unexplained_pieces(own, rival, labels, tri, area, min_area=1, margins=(-1.0,))
    with pytest.raises(FitError, match="max_share"):
        unexplained_pieces(own, rival, labels, tri, area, min_area=1, max_share=0.0)