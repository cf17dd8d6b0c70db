"""Forward fit of mesh regions against simulated spheres of known material (truth: the World's specs)."""

from __future__ import annotations

import json

import numpy as np
import open3d as o3d
import pytest

from mocks.observation_sim import simulated_observations
from mocks.world import World
from processing.camera.response import camera_sensitivities
from processing.materials._forward_fit_report import COMPOSITION_SD
from processing.materials.confidence import NO_FIT, NOT_MEASURED, decide
from processing.materials.forward_fit import ForwardModel, fit_region, region_samples
from processing.materials.presets import get_material
from processing.spectral.spectra import light_spectrum

ANGLES = np.arange(0.0, 360.0, 20.0)
EXPOSURE_S = 0.0005          # highlights unclipped (the default 0.01 s clips every metal highlight)


def _sphere(material: str, camera: str):
    m = o3d.geometry.TriangleMesh.create_sphere(radius=30.0, resolution=50)
    v = np.asarray(m.vertices) + [0.0, 0.0, 37.0]
    t = np.asarray(m.triangles)
    w = World(v, t, np.zeros(len(t), int), ("body",), {"body": material},
              light_position_mm=(-150.0, -250.0, 300.0), width=240, height=160)
    return simulated_observations(w, ANGLES, exposure_s=EXPOSURE_S, sensitivities=camera)


@pytest.fixture(scope="module")
def model():
    from processing.spectral.spectra import SpectralGrid

    g = SpectralGrid(400, 700, 10)
    return ForwardModel(camera_sensitivities(g), light_spectrum("D65", g), g)


_CACHE: dict = {}


def _fit(material: str, model, camera: str = "Nikon 5100 (NPL)"):
    key = (material, camera)
    if key not in _CACHE:
        sim = _sphere(material, camera)
        s = region_samples(sim.observations, sim.vertices, sim.frames, np.arange(len(sim.vertices)),
                           triangles=sim.triangles)
        _CACHE[key] = (sim, s, fit_region(s, model))
    return _CACHE[key]


def test_gold_sphere_is_gold_with_its_roughness(model):
    _, _, f = _fit("gold", model)
    assert f.material == "gold" and f.confidence >= 0.9
    assert abs(f.parameters["roughness"] - 0.10) <= 0.010       # preset 0.10, tolerance 10 %
    assert f.uncertainties["roughness"] > 0 and f.reason == ""
    json.dumps(f.to_dict())


def test_nami_shibuichi_sphere_gives_its_silver_share(model):
    _, _, f = _fit("nami-shibuichi", model)
    # right, but not sure: soto-sanbu (Ag 22.7 %) and uchi-sanbu (29.7 %) are within the composition's
    # systematic error (COMPOSITION_SD, 2 points, on top of the statistics): the answer is the likeliest of the
    # three, not a certainty
    assert f.material == "nami-shibuichi" and 1 / 3 < f.confidence < 0.9
    assert "nami-shibuichi-soto-sanbu" in f.group
    assert abs(f.parameters["Ag"] - 0.25) <= 0.03                # Table 1: Ag 25 %, +-3 percentage points
    assert abs(f.parameters["roughness"] - 0.15) <= 0.015       # preset 0.15, tolerance 10 %
    assert f.spec.startswith("nami-shibuichi:Ag=")


def test_an_alloy_between_two_grades_is_not_named_with_confidence(model):
    # Ag 27.35 %, Au 0.55 %: midway between nami-shibuichi (Ag 25.0, Au 0.1) and nami-shibuichi-uchi-sanbu
    # (Ag 29.7, Au 1.0), 2.35 points from each: the composition's systematic error (2 points) cannot
    # decide, however many observations the region has
    _, _, f = _fit("nami-shibuichi:Ag=0.2735,Cu=0.721,Au=0.0055", model)
    assert f.confidence < 0.9, (f.material, f.confidence, f.group)
    assert {"nami-shibuichi", "nami-shibuichi-uchi-sanbu"} <= set(f.group)
    assert abs(f.parameters["Ag"] - 0.2735) <= 0.03
    assert f.uncertainties["Ag"] >= COMPOSITION_SD              # the systematic error is in the stated one


def test_a_grade_read_through_a_camera_model_off_by_10_nm_is_not_named_with_confidence():
    # a nami-shibuichi sphere's highlight observations only (within 25 deg of the mirror direction: the
    # colour-rich evidence a large region of a scanned object has plenty of), fitted with a camera model
    # whose sensitivities are 10 nm off: the Ag share reads ~28 %, nearer uchi-sanbu (29.7 %) than the
    # truth (25 %).  Named at its nominal composition, each grade's chi-square made that 0.99 sure.
    from processing.spectral.spectra import SpectralGrid

    g = SpectralGrid(400, 700, 10)
    s0 = camera_sensitivities(g)
    shifted = np.stack([np.interp(g.wavelengths - 10.0, g.wavelengths, s0[:, c]) for c in range(3)], axis=1)
    off = ForwardModel(shifted + 1e-6, light_spectrum("D65", g), g)
    exact = ForwardModel(s0, light_spectrum("D65", g), g)
    _, s, _ = _fit("nami-shibuichi", exact)
    near = s.subset(np.flatnonzero(s.cos_h >= np.cos(np.radians(25.0))))
    f = fit_region(near, off)
    assert abs(f.parameters["Ag"] - 0.25) > 0.02                 # the camera's error moved the reading
    assert not (f.material != "nami-shibuichi" and f.confidence >= 0.9), (f.material, f.confidence)
    assert "nami-shibuichi" in f.group
    assert f.uncertainties["Ag"] >= COMPOSITION_SD

def test_grades_ten_points_apart_are_told_apart(model):
    # jo-shibuichi (Ag 39.6 %) is 9.9 points from the nearest other grade: more than 3 systematic errors
    _, _, f = _fit("jo-shibuichi", model)
    assert f.material == "jo-shibuichi" and f.confidence >= 0.9, (f.material, f.confidence, f.group)


def test_urushi_black_sphere_is_urushi_black(model):
    _, _, f = _fit("urushi-black", model)
    assert f.material == "urushi-black" and f.confidence >= 0.9
    assert f.parameters["diffuse"] > 0


@pytest.mark.parametrize("metal", ["silver", "aluminium", "tin"])
def test_neutral_metals_are_told_or_grouped_never_wrong(model, metal):
    _, _, f = _fit(metal, model)
    d = decide([c["name"] for c in f.candidates], [1.0] * len(f.candidates), [1] * len(f.candidates),
               [1] * len(f.candidates))
    assert d.answer  # decide accepts the candidates' names
    if f.material == "neutral metal":
        assert metal in f.group
    else:
        assert f.material == metal
    # Right, and never stated as more certain than the evidence: silver and tin come out named at 0.22 and
    # 0.26 with the other neutral metals listed as indistinguishable (reduced chi-square 1.8 widens the
    # posterior); aluminium at >= 0.9.
    assert metal in f.group and (f.confidence >= 0.9 or len(f.group) > 1)


def test_spec_reproduces_the_fitted_brightness(model):
    sim, s, f = _fit("gold", model)
    pred = model.predict(get_material(f.spec), s)
    # the highlights' flanks the fit uses (the mirror spike's 5 degrees are not fitted)
    hl = (s.cos_h > np.cos(np.radians(15.0))) & (s.cos_h < np.cos(np.radians(5.0)))
    ratio = np.median(s.signal[hl].sum(axis=1) / np.maximum(pred[hl].sum(axis=1), 1e-9))
    assert abs(ratio - 1.0) < 0.05                                 # within 5 % on the highlights


@pytest.mark.parametrize("name", ["gold", "nami-shibuichi", "urushi-black", "aluminium", "shakudo"])
def test_prediction_matches_the_spectral_brdf(model, name):
    """The prediction's tabulated spectral factors against the full spectrum at every angle (any cos_d)."""
    from types import SimpleNamespace

    from processing.materials.lobes import material_brdf

    rng = np.random.default_rng(1)
    n = 20_000
    ci, co, ch, cd = rng.uniform(0.01, 1, n), rng.uniform(0.01, 1, n), rng.uniform(0.3, 1, n), rng.uniform(0, 1, n)
    cd[:4] = [0.0, 1e-6, 0.5, 1.0]                                      # the table's ends and a node
    s = SimpleNamespace(cos_i=ci, cos_o=co, cos_h=ch, cos_d=cd, irradiance=rng.uniform(0.5, 2.0, n))
    m = get_material(name)
    exact = (material_brdf(m, ci, co, ch, cd, model.wavelengths) @ model._weights) * (np.pi * s.irradiance * ci)[:, None]
    # linear interpolation on 257 nodes: step^2 / 8 |F''| ~ 1e-5 of the colour, far below the 1e-2 noise
    np.testing.assert_allclose(model.predict(m, s), exact, rtol=2e-4, atol=1e-12 * float(exact.max()))  # atol: denormals


def test_region_without_highlights_is_not_measured(model):
    sim, _, _ = _fit("gold", model)
    obs = sim.observations
    lit = obs.half_angle_deg[:, 0] < 20.0                          # truth geometry, not the fit
    seen = np.bincount(obs.vertex[lit], minlength=obs.n_vertices) > 0
    ids = np.flatnonzero(~seen & (np.diff(obs.offsets) > 0))
    s = region_samples(obs, sim.vertices, sim.frames, ids, triangles=sim.triangles)
    assert len(s) > 100
    f = fit_region(s, model)
    assert f.material == NOT_MEASURED and f.spec is None and "mirror direction" in f.reason


def test_camera_mismatch_is_not_a_confident_wrong_answer(model):
    # the data are the Nikon's; the model believes in a camera whose sensitivities sit 15 nm to the red
    from processing.spectral.spectra import SpectralGrid

    g = SpectralGrid(400, 700, 10)
    s0 = camera_sensitivities(g)
    shifted = np.stack([np.interp(g.wavelengths - 15.0, g.wavelengths, s0[:, c]) for c in range(3)], axis=1)
    wrong_camera = ForwardModel(shifted + 1e-6, light_spectrum("D65", g), g)
    # (a shibuichi grade is NOT safe under this mismatch: the Ag share biases by ~5 points and a
    # neighbouring grade is answered confidently; docs/materials.md says so)
    for metal in ("gold", "urushi-black"):
        _, s, right = _fit(metal, model)
        f = fit_region(s, wrong_camera)
        confident_wrong = f.material not in (NO_FIT, metal) and f.confidence >= 0.9
        assert not confident_wrong, (metal, f.material, f.confidence, f.chi2_per_dof)
        if metal == "gold":                                             # the mismatch shows as misfit
            assert f.chi2_per_dof > right.chi2_per_dof
        else:   # a near-neutral black hides a 15 nm shift (misfit changes < 0.1 %): the answer stays right
            assert f.material == metal


def _mixed(a, b, share: float, seed: int = 0):
    """The samples of ``a`` plus a random ``share`` (of ``a``'s count) of ``b``'s: a region with a neighbour's pixels."""
    import dataclasses

    rng = np.random.default_rng(seed)
    take = np.sort(rng.choice(len(b.signal), int(share * len(a.signal)), replace=False))
    fields = {}
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray) and x.shape[:1] == a.signal.shape[:1]:
            fields[f.name] = np.concatenate([x, y[take]])
        else:
            fields[f.name] = x
    return dataclasses.replace(a, **fields)


def test_a_few_observations_of_a_neighbour_do_not_pull_the_fit(model):
    # A nami-shibuichi region (Ag 25 %, Au 0.1 %: the simulation's truth) with 3 % of a gold sphere's observations
    # mixed in, as at a border the segmentation placed a few vertices off.  Least squares bends toward the gold
    # (measured: Au 8.7 %, answered soto-sanbu); the robust weights keep the composition within the target's
    # 3 points and the roughness within 10 %.
    _, nami, _ = _fit("nami-shibuichi", model)
    _, gold, _ = _fit("gold", model)
    mixed = _mixed(nami, gold, 0.03)
    plain = fit_region(mixed, model, robust=False)
    robust = fit_region(mixed, model)
    assert abs(robust.parameters["Ag"] - 0.25) <= 0.03 and robust.parameters["Au"] <= 0.03
    assert abs(robust.parameters["roughness"] - 0.15) <= 0.015
    assert robust.material == "nami-shibuichi" or "nami-shibuichi" in robust.group
    assert plain.parameters["Au"] > robust.parameters["Au"] + 0.03              # the premise: the gold pulls


def test_dark_observations_where_the_lobe_predicts_light_do_not_move_the_composition(model):
    # 1 % of a nami-shibuichi sphere's observations 10-20 deg from the mirror direction read dark (a dark pixel's
    # noise), as where another material's narrower lobe or a shadow the mesh misses sits inside the region.  The
    # provisional fit that sets every observation's normal error was made by plain squares: they widened its lobe,
    # the highlights were weighed by the wrong lobe's slope, and the silver share read 28 % (truth 25 %, answered
    # uchi-sanbu).  Fitted robustly, it stays within 1 point of the clean sphere's and the roughness within 10 %.
    import dataclasses

    _, nami, clean = _fit("nami-shibuichi", model)
    rng = np.random.default_rng(0)
    cos_h = nami.cos_h
    near = np.flatnonzero((cos_h < np.cos(np.radians(10.0))) & (cos_h >= np.cos(np.radians(20.0))))
    take = np.sort(rng.choice(near, int(0.01 * len(nami)), replace=False))
    floor = np.median(nami.sigma[cos_h < np.cos(np.radians(30.0))], axis=0)       # a dark pixel's noise
    dark = dataclasses.replace(nami.subset(take), signal=rng.normal(0.0, 1.0, (len(take), 3)) * floor,
                               sigma=np.tile(floor, (len(take), 1)))
    assert np.median(nami.signal[take].sum(axis=1)) > 30 * floor.sum()           # the premise: light expected
    f = fit_region(_mixed(nami, dark, len(take) / len(nami)), model)
    assert abs(f.parameters["Ag"] - clean.parameters["Ag"]) <= 0.01
    assert abs(f.parameters["roughness"] - 0.15) <= 0.015
    assert f.material == "nami-shibuichi"


@pytest.mark.parametrize("candidate", ["alloy", "urushi-black", "silver"])
def test_normal_equations_give_the_design_matrix_solution(model, candidate):
    # The roughness search solves each candidate's NNLS from per-observation products formed once
    # (w(geo * colour) = geo * w(colour)); it must give what whitening and solving the full design
    # matrix gives, at every roughness.  Tolerance 1e-9 relative: the two sum the same products in a
    # different order (rounding ~1e-16 per term, the chi-square's cancellation y.y - q.q adds ~1e-12).
    from processing.materials._forward_fit_core import (
        _columns,
        _geometry,
        _NormalEquations,
        _small_nnls,
    )
    from processing.materials.forward_fit import _basis, prepared_observations

    _, s, _ = _fit("nami-shibuichi", model)
    fitted, y, w = prepared_observations(s, model)
    basis = _basis(candidate, model, fitted.cos_d)[0]
    normal = _NormalEquations(basis, fitted, w(y), w)
    shade = np.pi * fitted.irradiance * fitted.cos_i
    for r in (0.03, 0.15, 0.5):
        geo = _geometry(fitted, r, basis)
        a_ref, chi2_ref = _small_nnls(w(_columns(basis, geo, shade)), w(y))
        a, chi2 = normal.solve(geo)
        assert chi2 == pytest.approx(chi2_ref, rel=1e-9)
        np.testing.assert_allclose(a, a_ref, rtol=1e-9, atol=1e-12 * np.abs(a_ref).max())


def _hl_samples(signal: np.ndarray, sigma: float):
    """Observations all at the mirror direction (cos_h = 1) with the given signal and noise."""
    from processing.materials.forward_fit import RegionSamples

    n = len(signal)
    return RegionSamples(signal, np.full((n, 3), sigma), *np.ones((5, n)), np.zeros(n, np.int64),
                         np.zeros(n, np.int64), 0.0)


def test_highlight_colours_within_their_noise_have_a_scatter_ratio_of_one():
    from processing.materials.forward_fit import highlight_colour_scatter

    rng = np.random.default_rng(3)
    n, sd = 4000, 0.002
    s = _hl_samples(np.array([0.5, 0.4, 0.3]) + rng.normal(0.0, sd, (n, 3)), sd)
    # Gaussian noise of the stated sigma: the variance ratio's expectation is 1 (median of z^2 over 4000
    # draws: about 3 % standard error)
    assert highlight_colour_scatter(s, 0.0) <= 1.12


def test_highlight_colour_scatter_measures_a_false_colour_of_known_size():
    from processing.materials.forward_fit import highlight_colour_scatter

    rng = np.random.default_rng(4)
    n, sd, fringe = 4000, 0.002, 0.05
    rgb = np.array([0.5, 0.4, 0.3])
    x = rgb + rng.normal(0.0, sd, (n, 3))
    x[:, 0] *= 1.0 + rng.normal(0.0, fringe, n)           # red off by 5 % per view, as a demosaic's false colour
    # first order: r = R / S moves by r (1 - r) dlnR, b by -b r dlnR; the noise's chromaticity sd by propagation
    s_tot, r, b = rgb.sum(), rgb[0] / rgb.sum(), rgb[2] / rgb.sum()
    noise_r = np.sqrt((1 - r) ** 2 + 2 * r ** 2) * sd / s_tot
    noise_b = np.sqrt((1 - b) ** 2 + 2 * b ** 2) * sd / s_tot
    expected = 0.5 * (1 + (r * (1 - r) * fringe / noise_r) ** 2 + 1 + (b * r * fringe / noise_b) ** 2)
    got = highlight_colour_scatter(_hl_samples(x, sd), 0.0)
    assert abs(got / expected - 1.0) <= 0.2, (got, expected)


def test_false_colour_in_the_highlights_lowers_the_confidence_never_to_a_wrong_answer(model):
    """Gold's highlights with red and blue +-25 % per view in opposite directions (a demosaic's false colour
    of highlights narrower than a CFA cell): weaker evidence, still gold or grouped with it."""
    import dataclasses

    from processing.materials.forward_fit import HIGHLIGHT_DEG

    _, s, clean = _fit("gold", model)
    rng = np.random.default_rng(5)
    hl = s.cos_h >= np.cos(np.radians(HIGHLIGHT_DEG))
    e = rng.normal(0.0, 0.25, int(hl.sum()))
    signal = s.signal.copy()
    signal[hl, 0] *= 1.0 + e
    signal[hl, 2] *= np.maximum(1.0 - e, 0.0)
    fringed = fit_region(dataclasses.replace(s, signal=signal), model)
    # the clean sphere's highlights scatter within their noise (5 % of the signal at this exposure), the
    # fringed ones several times beyond it
    assert clean.colour_scatter <= 1.5 and fringed.colour_scatter >= 5.0
    assert fringed.confidence < clean.confidence
    assert fringed.material == "gold" or "gold" in fringed.group
