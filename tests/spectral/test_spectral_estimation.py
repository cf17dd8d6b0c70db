"""Spectral estimators checked against closed forms and constructed ground truth."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from processing.camera.from_chart import estimate_sensitivities
from processing.camera.response import camera_rgb, camera_sensitivities, channel_matrix
from processing.camera.transfer import ChartConditionError, fit_chart_transform
from processing.spectral.estimation.estimator import (
    fit_estimator,
    reflectance_from_weights,
    region_spectra,
    spectral_image,
)
from processing.spectral.estimation.fit import SpectralEstimationError
from processing.spectral.estimation.pca_matsuda import fit_paper
from processing.spectral.estimation.root_polynomial_finlayson import fit_rootpoly
from processing.spectral.estimation.two_light import fit_two_light
from processing.spectral.estimation.wiener import fit_wiener
from processing.spectral.reflectance_database import load_reflectances, without_near_duplicates
from processing.spectral.spectra import SpectralGrid, light_spectrum

G = SpectralGrid(400, 700, 10)
WL = G.wavelengths


@pytest.fixture(scope="module")
def setup():
    train = load_reflectances("training", G)
    chart = load_reflectances("colorchecker", G)
    return {
        "db": without_near_duplicates(train, chart).spectra,
        "chart": chart.spectra,
        "sens": camera_sensitivities(G),
        "d65": light_spectrum("D65", G),
        "a": light_spectrum("A", G),
    }


def test_paper_method_reproduces_spectra_that_lie_in_a_three_vector_basis(setup):
    # a database spanned by three smooth spectra: w -> rho is an invertible 3 x 3 map, so M is exact
    rng = np.random.default_rng(2)
    gens = np.stack([np.ones(G.size), (WL - 550) / 150, np.cos((WL - 400) / 300 * np.pi * 2)])
    db = rng.uniform(0.1, 0.4, (60, 3)) @ gens
    db = db - min(0.0, db.min()) + 0.01
    fit = fit_paper(db, setup["sens"], setup["d65"], G)
    est = fit.estimate_spectra(camera_rgb(db, setup["d65"], setup["sens"], G))
    assert np.abs(est - db).max() < 1e-5 * db.max()          # float32 weights
    assert fit.training_rmse < 1e-10
    # the basis spans the generators: projecting them on it leaves nothing
    resid = gens.T - fit.basis @ (fit.basis.T @ gens.T)
    assert np.abs(resid).max() < 1e-10


def test_paper_method_is_not_exact_on_real_spectra(setup):
    fit = fit_paper(setup["db"], setup["sens"], setup["d65"], G)
    assert 0.01 < fit.training_rmse < 0.15
    assert fit.p == 3 and fit.matrix.shape == (3, 3)


def _smooth_covariance(n: int, length: float) -> np.ndarray:
    x = np.arange(n)
    return 0.04 * np.exp(-0.5 * ((x[:, None] - x[None, :]) / length) ** 2) + 1e-6 * np.eye(n)


def test_wiener_equals_the_closed_form_linear_mmse_for_a_gaussian_prior(setup):
    cov = _smooth_covariance(G.size, 4.0)
    k = channel_matrix(setup["sens"], setup["d65"], G)
    noise_cov = np.diag([1e-4, 2e-4, 1.5e-4])
    fit = fit_wiener(None, setup["sens"], setup["d65"], G, second_moment=cov, noise_covariance=noise_cov)
    # information form of the posterior mean (matrix inversion lemma): an independent formula
    h = k.T                                              # rho = H s (column form)
    post = np.linalg.inv(np.linalg.inv(cov) + h.T @ np.linalg.inv(noise_cov) @ h)
    gain = post @ h.T @ np.linalg.inv(noise_cov)          # (L, c)
    rho = np.random.default_rng(0).uniform(0.0, 2.0, (5, 3))
    assert np.allclose(fit.estimate_spectra(rho), rho @ gain.T, rtol=1e-4, atol=1e-5)
    # Monte Carlo: on draws from the prior the mean squared error is the posterior covariance's trace
    rng = np.random.default_rng(1)
    s = rng.multivariate_normal(np.zeros(G.size), cov, size=20000)
    y = s @ k + rng.multivariate_normal(np.zeros(3), noise_cov, size=s.shape[0])
    est = y @ gain.T
    mse = np.mean(np.sum((est - s) ** 2, axis=1))
    assert mse == pytest.approx(np.trace(post), rel=0.03)
    # and it beats a perturbed linear estimator
    worse = y @ (gain.T * 1.05)
    assert np.mean(np.sum((worse - s) ** 2, axis=1)) > mse


def test_wiener_with_a_singular_system_says_so(setup):
    flat = np.zeros((G.size, G.size))
    with pytest.raises(SpectralEstimationError, match="singular"):
        fit_wiener(None, setup["sens"], setup["d65"], G, second_moment=flat, noise=0.0)
    with pytest.raises(SpectralEstimationError, match="symmetric"):
        fit_wiener(None, setup["sens"], setup["d65"], G, second_moment=np.triu(np.ones((G.size, G.size))))


def test_wiener_cross_validation_picks_a_level_and_fits(setup):
    fit = fit_wiener(setup["db"], setup["sens"], setup["d65"], G, noise=None)
    assert 1e-4 <= fit.details["noise"] <= 1.0
    assert fit.basis.shape == (G.size, 3)
    assert np.allclose(fit.basis.T @ fit.basis, np.eye(3), atol=1e-10)


@settings(max_examples=25, deadline=None)
@given(scale=st.floats(min_value=1e-3, max_value=1e3), patch=st.integers(0, 23))
def test_root_polynomial_weights_scale_with_exposure(rootpoly_fit, scale, patch):
    fit, rho = rootpoly_fit
    w1 = fit.estimate_weights(rho[patch]).astype(np.float64)
    w2 = fit.estimate_weights(rho[patch] * scale).astype(np.float64)
    assert np.allclose(w2, scale * w1, rtol=2e-4, atol=1e-6 * scale * np.abs(w1).max())


@settings(max_examples=40, deadline=None)
@given(exponent=st.floats(min_value=-30, max_value=30), patch=st.integers(0, 23))
def test_root_polynomial_weights_stay_finite_and_proportional_over_sixty_decades(rootpoly_fit, exponent, patch):
    fit, rho = rootpoly_fit
    w1 = fit.estimate_weights(rho[patch].astype(np.float32)).astype(np.float64)
    scaled = (rho[patch] * 10.0**exponent).astype(np.float32)
    w2 = fit.estimate_weights(scaled).astype(np.float64)
    assert np.all(np.isfinite(w2))
    ratio = float(scaled[1]) / float(np.float32(rho[patch][1]))
    assert np.allclose(w2, ratio * w1, rtol=1e-3, atol=1e-6 * ratio * np.abs(w1).max())


@pytest.fixture(scope="module")
def rootpoly_fit(setup):
    fit = fit_rootpoly(setup["db"], setup["sens"], setup["d65"], G, p=8, degree=2)
    return fit, camera_rgb(setup["chart"], setup["d65"], setup["sens"], G)


def test_root_polynomial_beats_the_paper_on_held_out_chart(setup, rootpoly_fit):
    fit, rho = rootpoly_fit
    paper = fit_paper(setup["db"], setup["sens"], setup["d65"], G)
    err_rp = np.sqrt(np.mean((fit.estimate_spectra(rho) - setup["chart"]) ** 2))
    err_paper = np.sqrt(np.mean((paper.estimate_spectra(rho) - setup["chart"]) ** 2))
    assert err_rp < err_paper
    assert err_rp < 0.06


def test_two_lights_separate_a_metameric_pair_that_one_light_cannot(setup):
    k = channel_matrix(setup["sens"], setup["d65"], G)
    base = setup["chart"][21]                                  # neutral 5
    v = 0.12 * np.sin((WL - 400) / 300 * 3 * np.pi)
    black = v - k @ np.linalg.solve(k.T @ k, k.T @ v)         # metameric black: black @ k = 0
    pair = np.stack([base + black, base - black])
    assert pair.min() > 0
    rho1 = camera_rgb(pair, setup["d65"], setup["sens"], G)
    assert np.allclose(rho1[0], rho1[1], rtol=1e-9)          # metamers under D65
    lights = np.stack([setup["d65"], setup["a"]])
    rho2 = camera_rgb(pair, lights, setup["sens"], G)
    assert not np.allclose(rho2[0, 3:], rho2[1, 3:], rtol=1e-3)
    one = fit_estimator("rootpoly", setup["db"], setup["sens"], setup["d65"], G)
    two = fit_two_light(setup["db"], setup["sens"], lights, G)
    err_one = np.sqrt(np.mean((one.estimate_spectra(rho1) - pair) ** 2, axis=1))
    err_two = np.sqrt(np.mean((two.estimate_spectra(rho2) - pair) ** 2, axis=1))
    assert err_two.max() < err_one.max()
    # the two-light estimates differ in the direction of the true difference
    d_est = np.diff(two.estimate_spectra(rho2), axis=0)[0]
    assert d_est @ (pair[1] - pair[0]) > 0


def test_camera_from_chart_recovers_known_sensitivities_on_noiseless_data(setup):
    rho = camera_rgb(setup["chart"], setup["d65"], setup["sens"], G)
    fit = estimate_sensitivities(rho, setup["chart"], setup["d65"], G)
    rel = np.linalg.norm(fit.sensitivities - setup["sens"], axis=0) / np.linalg.norm(setup["sens"], axis=0)
    assert np.all(rel < 0.06), rel                           # stated tolerance: 6 % (L2, per channel)
    assert np.all(fit.sensitivities >= 0)
    assert fit.condition < 10


def test_camera_from_chart_with_known_noise_uses_the_discrepancy_principle(setup):
    rho = camera_rgb(setup["chart"], setup["d65"], setup["sens"], G)
    noisy = rho * (1 + 0.001 * np.random.default_rng(2).standard_normal(rho.shape))
    fit = estimate_sensitivities(noisy, setup["chart"], setup["d65"], G, noise=0.001)
    rel = np.linalg.norm(fit.sensitivities - setup["sens"], axis=0) / np.linalg.norm(setup["sens"], axis=0)
    assert np.all(rel < 0.15), rel                          # stated tolerance at 0.1 % noise: 15 %
    assert fit.residual <= 0.001 * 1.01                      # the residual stays within the noise
    # the estimated camera predicts the training reflectances' values within 0.2 % of full scale
    pred = camera_rgb(setup["db"], setup["d65"], fit.sensitivities, G)
    true = camera_rgb(setup["db"], setup["d65"], setup["sens"], G)
    assert np.sqrt(np.mean(((pred - true) / true.max(axis=0)) ** 2)) < 0.002


def test_camera_from_chart_with_only_grey_patches_raises_with_the_condition_number(setup):
    greys = setup["chart"][18:]
    rho = camera_rgb(greys, setup["d65"], setup["sens"], G)
    with pytest.raises(ChartConditionError, match=r"condition number \d") as info:
        estimate_sensitivities(rho, greys, setup["d65"], G)
    assert info.value.condition > 50


def test_chart_transform_with_only_grey_patches_raises_with_the_condition_number(setup):
    greys = setup["chart"][18:]
    rho = camera_rgb(greys, setup["d65"], setup["sens"], G)
    with pytest.raises(ChartConditionError, match=r"condition number \d"):
        fit_estimator("paper", setup["db"], setup["sens"], setup["d65"], G, chart_rgb=rho * 1.3,
                      chart_reflectance=greys)


def test_chart_calibration_undoes_an_object_camera_that_is_a_linear_mix_of_the_model(setup):
    mix = np.array([[0.9, 0.1, 0.0], [0.05, 1.1, 0.05], [0.0, 0.2, 0.7]]) * 3.0
    obj_sens = setup["sens"] @ mix
    chart_obj = camera_rgb(setup["chart"], setup["d65"], obj_sens, G)
    for method in ("paper", "rootpoly"):
        plain = fit_estimator(method, setup["db"], setup["sens"], setup["d65"], G)
        cal = fit_estimator(method, setup["db"], setup["sens"], setup["d65"], G,
                            chart_rgb=chart_obj, chart_reflectance=setup["chart"])
        assert cal.details["chart_residual"] < 1e-9
        test = setup["db"][:20]
        a = cal.estimate_weights(camera_rgb(test, setup["d65"], obj_sens, G))
        b = plain.estimate_weights(camera_rgb(test, setup["d65"], setup["sens"], G))
        assert np.allclose(a, b, rtol=1e-3, atol=1e-4 * np.abs(b).max())


def test_fit_chart_transform_is_block_diagonal_for_two_exposures():
    rng = np.random.default_rng(4)
    model = rng.uniform(0.05, 1.0, (24, 6))
    t1, t2 = np.diag([1.2, 0.8, 1.1]), np.array([[1.0, 0.1, 0.0], [0.0, 0.9, 0.0], [0.1, 0.0, 1.3]])
    obj = np.concatenate([model[:, :3] @ np.linalg.inv(t1), model[:, 3:] @ np.linalg.inv(t2)], axis=1)
    fit = fit_chart_transform(obj, model)
    assert np.allclose(fit.matrix[:3, :3], t1) and np.allclose(fit.matrix[3:, 3:], t2)
    assert np.all(fit.matrix[:3, 3:] == 0) and np.all(fit.matrix[3:, :3] == 0)


def test_region_spectra_mean_and_spread_of_known_regions():
    basis = np.stack([np.ones(G.size), (WL - 550) / 150], axis=1)
    w = np.zeros((4, 6, 2))
    w[:, :3] = [0.5, 0.1]
    w[:2, 3:] = [0.2, 0.0]
    w[2:, 3:] = [0.4, 0.0]
    labels = np.zeros((4, 6), int)
    labels[:, :3] = 1
    labels[:, 3:] = 7
    labels[0, 0] = 0                                           # background pixel
    r = region_spectra(w, labels, basis, method_error=0.03)
    assert r.labels.tolist() == [1, 7] and r.count.tolist() == [11, 12]
    assert np.allclose(r.mean[0], 0.5 + 0.1 * (WL - 550) / 150)
    assert np.allclose(r.mean[1], 0.3) and np.allclose(r.std[1], 0.1)      # half 0.2, half 0.4
    assert np.allclose(r.std[0], 0.0, atol=1e-12)
    assert np.allclose(r.uncertainty[0], 0.03) and np.allclose(r.uncertainty[1], np.hypot(0.1, 0.03))
    assert np.allclose(reflectance_from_weights(r.mean_weights, basis), r.mean)


def test_region_spectra_match_a_direct_computation_on_random_float32_weights():
    rng = np.random.default_rng(9)
    basis = np.linalg.qr(rng.standard_normal((G.size, 4)))[0]
    w = (rng.standard_normal((30, 40, 4)) * [0.3, 0.05, 0.02, 0.01] + [3.0, 0.2, 0.0, 0.1]).astype(np.float32)
    labels = rng.integers(0, 4, (30, 40))
    r = region_spectra(w, labels, basis, method_error=0.0)
    spectra = w.astype(np.float64) @ basis.T
    for k, lab in enumerate(r.labels):
        sel = spectra[labels == lab]
        assert np.allclose(r.mean[k], sel.mean(axis=0), atol=1e-9)
        assert np.allclose(r.std[k], sel.std(axis=0), rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize(
    "rgb, words",
    [
        (np.array([[0.1, np.nan, 0.2]]), "NaN or infinite"),
        (np.array([[0.1, np.inf, 0.2]]), "NaN or infinite"),
        (np.array([[0.1, -0.2, 0.2]]), "negative"),
        (np.zeros((0, 3)), "empty"),
        (np.ones((2, 4)), "3 channels"),
        (np.array([["a", "b", "c"]]), "numeric"),
    ],
)
def test_bad_camera_values_raise_clear_errors(rootpoly_fit, rgb, words):
    fit, _ = rootpoly_fit
    with pytest.raises(SpectralEstimationError, match=words):
        fit.estimate_weights(rgb)


def test_bad_estimator_arguments_raise_clear_errors(setup):
    args = (setup["db"], setup["sens"], setup["d65"], G)
    with pytest.raises(SpectralEstimationError, match="unknown spectral estimation method"):
        fit_estimator("magic", *args)
    with pytest.raises(SpectralEstimationError, match="two lights"):
        fit_estimator("twolight", *args)
    with pytest.raises(SpectralEstimationError, match="chart_reflectance"):
        fit_estimator("paper", *args, chart_rgb=np.ones((24, 3)))
    with pytest.raises(SpectralEstimationError, match="NaN"):
        fit_estimator("paper", np.full((30, G.size), np.nan), *args[1:])
    with pytest.raises(SpectralEstimationError, match="same spectrum"):
        fit_two_light(setup["db"], setup["sens"], np.stack([setup["d65"], 2 * setup["d65"]]), G)
    with pytest.raises(SpectralEstimationError, match="labels"):
        region_spectra(np.zeros((2, 2, 3)), np.zeros((3, 3), int), np.ones((G.size, 3)), 0.0)
    with pytest.raises(SpectralEstimationError, match="no region"):
        region_spectra(np.zeros((2, 2, 3)), np.zeros((2, 2), int), np.ones((G.size, 3)), 0.0)


def test_masked_pixels_are_skipped_and_unmasked_bad_pixels_refused(rootpoly_fit):
    fit, rho = rootpoly_fit
    img = np.broadcast_to(rho[:3, None, :], (3, 4, 3)).copy()
    img[0, 0] = np.nan                                         # e.g. a dead photosite
    img[1, 1] = -5.0
    mask = np.ones((3, 4), bool)
    mask[0, 0] = mask[1, 1] = False
    out = spectral_image(fit, img, mask)
    assert np.all(out.weights[~mask] == 0) and out.mask is not None
    assert np.allclose(out.weights[2, 3], fit.estimate_weights(rho[2]), rtol=1e-5)
    with pytest.raises(SpectralEstimationError, match="NaN"):
        spectral_image(fit, img)
    with pytest.raises(SpectralEstimationError, match="every pixel"):
        spectral_image(fit, img, np.zeros((3, 4), bool))


def test_weights_of_an_image_are_float32_and_shaped_like_it(rootpoly_fit):
    fit, rho = rootpoly_fit
    img = np.broadcast_to(rho[:4, None, :], (4, 5, 3)).astype(np.float32)
    w = fit.estimate_weights(img)
    assert w.dtype == np.float32 and w.shape == (4, 5, 8)
    assert np.allclose(w[:, 0], fit.estimate_weights(rho[:4]), rtol=1e-5, atol=1e-6)
    assert np.all(fit.estimate_weights(np.zeros((2, 3), np.float32)) == 0)      # black: zero weights, no NaN
