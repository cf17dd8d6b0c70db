"""Pieces of a region tested against fixed materials: simulated spheres whose material is known."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from mocks.observation_sim import simulated_observations
from mocks.world import World
from processing.camera.response import camera_sensitivities
from processing.materials.forward_fit import (
    FitError,
    ForwardModel,
    RegionSamples,
    fit_region,
    grouped_observations,
    region_samples,
)
from processing.materials.presets import get_material
from processing.materials.region_consistency import (
    disagreeing_pieces,
    face_regions,
    fixed_material_chi2,
    joining_pieces,
    mesh_components,
    pieces_chi2,
)
from processing.spectral.spectra import SpectralGrid, light_spectrum

ANGLES = np.arange(0.0, 360.0, 30.0)
EXPOSURE_S = 0.0005          # highlights unclipped


@pytest.fixture(scope="module")
def model():
    g = SpectralGrid(400, 700, 10)
    return ForwardModel(camera_sensitivities(g), light_spectrum("D65", g), g)


_CACHE: dict = {}


def _sphere(material: str, model):
    """Samples of a simulated sphere of ``material`` and their fit (the simulation's truth is ``material``)."""
    if material not in _CACHE:
        m = o3d.geometry.TriangleMesh.create_sphere(radius=30.0, resolution=40)
        v = np.asarray(m.vertices) + [0.0, 0.0, 37.0]
        t = np.asarray(m.triangles)
        w = World(v, t, np.zeros(len(t), int), ("body",), {"body": material},
                  light_position_mm=(-150.0, -250.0, 300.0), width=240, height=160)
        sim = simulated_observations(w, ANGLES, exposure_s=EXPOSURE_S, sensitivities="Nikon 5100 (NPL)")
        s = region_samples(sim.observations, sim.vertices, sim.frames, np.arange(len(sim.vertices)),
                           triangles=sim.triangles)
        _CACHE[material] = (s, fit_region(s, model))
    return _CACHE[material]


def test_pieces_are_the_connected_parts_of_each_region():
    # two triangles sharing an edge, a third apart: region 0 has two pieces, region 1 one, -1 none
    tri = np.array([[0, 1, 2], [1, 3, 2], [4, 5, 6], [7, 8, 9]])
    region = [0, 0, 0, 0, 0, 0, 0, 1, 1, -1]
    piece = mesh_components(region, tri)
    assert piece[:4].tolist() == [piece[0]] * 4
    assert len({piece[0], piece[4], piece[7]}) == 3 and piece[4] == piece[5] == piece[6]
    assert piece[9] == -1 and piece.max() == 2
    with pytest.raises(FitError, match="triangles"):
        mesh_components(region, [[0, 1, 20]])


def test_fixed_material_scores_like_the_fit(model):
    # The fitted material, scored as it is, gives the fit's own chi-square: the same observations, weights
    # and noise model; the spec rounds the amplitudes down to 1e-4 (a relative change of 1e-3 at most), so
    # the two agree within 5 %.  The other material (nami-shibuichi on a gold sphere) is far worse.
    samples, fit = _sphere("gold", model)
    best = min(c["chi2"] for c in fit.candidates)
    nami = get_material("nami-shibuichi")
    chi2, n, n_hl = fixed_material_chi2(samples, model, [get_material(fit.spec), nami, None], max_samples=20_000)
    assert n == fit.n_observations and n_hl == fit.n_lit
    assert abs(chi2[0] / best - 1.0) <= 0.05
    assert chi2[1] > 10 * chi2[0] and np.isnan(chi2[2])


def test_a_piece_of_another_material_disagrees_with_its_region(model):
    # A "region" fitted as gold holds a second piece that is truly nami-shibuichi; another region's fit is
    # nami-shibuichi.  The nami piece disagrees (the other region explains it better by far more than the
    # margin) and names that region; the gold piece agrees.
    gold, gold_fit = _sphere("gold", model)
    nami, nami_fit = _sphere("nami-shibuichi", model)
    mats = [get_material(gold_fit.spec), get_material(nami_fit.spec)]
    rows = [fixed_material_chi2(s, model, mats) for s in (gold, nami)]
    disagrees, better = disagreeing_pieces(np.array([r[0] for r in rows]), [r[1] for r in rows], [0, 0])
    assert disagrees.tolist() == [False, True] and better.tolist() == [-1, 1]
    # the same pieces each in their own region: no disagreement
    disagrees, better = disagreeing_pieces(np.array([r[0] for r in rows]), [r[1] for r in rows], [0, 1])
    assert not disagrees.any() and (better == -1).all()


def test_disagreement_needs_a_margin_and_scores():
    # scaled chi-squares (n = 400: scale 1): 1000 vs 960 is within the margin of 50; 1000 vs 900 is not
    d, b = disagreeing_pieces([[1000.0, 960.0], [1000.0, 900.0], [1000.0, np.nan]], [400, 400, 400], [0, 0, 0])
    assert d.tolist() == [False, True, False] and b.tolist() == [-1, 1, -1]
    # 4000 observations count as 400: a drop of 400 in chi-square is 40 after scaling, within the margin
    d, _ = disagreeing_pieces([[4000.0, 3600.0]], [4000], [0])
    assert not d.any()
    with pytest.raises(FitError, match="chi2"):
        disagreeing_pieces([[1.0, 2.0]], [1, 2], [0])


def test_a_piece_joins_the_region_whose_material_explains_it(model):
    # Target: a region fitted as nami-shibuichi.  A truly nami piece (labelled with a gold region) joins it;
    # a truly gold piece of a gold region does not (its own material is better by far and nami-shibuichi
    # misses it beyond the misfit limit); a truly nami piece of a region without a material joins; a piece
    # without observations never joins.
    gold, gold_fit = _sphere("gold", model)
    nami, nami_fit = _sphere("nami-shibuichi", model)
    target, own_gold = get_material(nami_fit.spec), get_material(gold_fit.spec)
    c_nami, n_nami, _ = fixed_material_chi2(nami, model, [target, own_gold])
    c_gold, n_gold, _ = fixed_material_chi2(gold, model, [target, own_gold])
    join = joining_pieces([c_nami[0], c_gold[0], c_nami[0], np.nan], [c_nami[1], c_gold[1], np.nan, np.nan],
                          [n_nami, n_gold, n_nami, 0])
    assert join.tolist() == [True, False, True, False]
    with pytest.raises(FitError, match="one value per piece"):
        joining_pieces([1.0], [1.0, 2.0], [1])


def test_faces_take_the_region_of_most_corners():
    tri = np.array([[0, 1, 2], [0, 3, 3], [3, 3, 3], [1, 2, 0]])
    assert face_regions([0, 1, 1, -1], tri).tolist() == [1, 0, -1, 1]


def _joined(a: RegionSamples, b: RegionSamples) -> RegionSamples:
    """The observations of two simulations as one region's."""
    cat = {f: np.concatenate([getattr(a, f), getattr(b, f)]) for f in
           ("signal", "sigma", "cos_i", "cos_o", "cos_h", "cos_d", "irradiance", "vertex", "frame")}
    return RegionSamples(**cat, clipped_share=0.0)


def test_scoring_all_pieces_at_once_equals_scoring_each(model):
    # Reference: each piece's observations scored on their own (their own prediction, their rows of the
    # whitener); the one-pass sums per piece must equal it to rounding (rtol 1e-9: the same arithmetic,
    # summed in another order).  Each piece keeps what fixed_material_chi2 keeps for it alone: the same
    # count, also for the pieces cut to max_samples by the random draw.
    gold, gold_fit = _sphere("gold", model)
    nami, _ = _sphere("nami-shibuichi", model)
    both = _joined(gold, nami)
    piece = np.concatenate([gold.vertex % 7, 7 + nami.vertex % 3])          # 10 pieces of unequal size
    mats = [get_material(gold_fit.spec), get_material("nami-shibuichi"), None]
    ids, chi2, n, n_hl = pieces_chi2(both, piece, model, mats, max_samples=600)
    fitted, kept, y, w = grouped_observations(both, piece, model, max_samples=600)
    assert ids.tolist() == list(range(10)) and np.isnan(chi2[:, 2]).all()
    for i, p in enumerate(ids):
        rows = np.flatnonzero(kept == p)
        sub = fitted.subset(rows)
        y_p = y.reshape(-1, 3)[rows].reshape(-1)
        for k in range(2):
            r = w.take(rows)(y_p - model.predict(mats[k], sub).reshape(-1))
            assert chi2[i, k] == pytest.approx(float(r @ r), rel=1e-9)
        alone = both.subset(np.flatnonzero(piece == p))
        _, n_alone, hl_alone = fixed_material_chi2(alone, model, [None], max_samples=600)
        assert n[i] == n_alone and n_hl[i] == hl_alone
    assert n.max() == 600                                                    # some pieces were cut


def test_one_pass_scoring_keeps_the_decisions(model):
    # A region fitted as gold holds a gold piece and a truly nami-shibuichi piece.  Weighted once for the
    # whole region (the provisional fits shared, the robust scale per piece), the nami piece still
    # disagrees and names the nami region, and the gold piece agrees -- as when each piece is weighted alone.
    gold, gold_fit = _sphere("gold", model)
    nami, nami_fit = _sphere("nami-shibuichi", model)
    mats = [get_material(gold_fit.spec), get_material(nami_fit.spec)]
    both = _joined(gold, nami)
    piece = np.concatenate([np.zeros(len(gold), int), np.ones(len(nami), int)])
    _, chi2, n, _ = pieces_chi2(both, piece, model, mats)
    disagrees, better = disagreeing_pieces(chi2, n, [0, 0])
    assert disagrees.tolist() == [False, True] and better.tolist() == [-1, 1]
    join = joining_pieces(chi2[:, 1], chi2[:, 0], n)
    assert join.tolist() == [False, True]
