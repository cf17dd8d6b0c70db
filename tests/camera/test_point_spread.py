"""The camera's point spread from renderings and photos: truth is the Gaussian the test blurs its photo with."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from processing.camera.point_spread import PointSpreadError, fit_point_spread, spread_within


def _scene(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A sharp rendering: a dim textured disc with a few one-pixel glints; its mask."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:96, 0:96]
    mask = (yy - 48) ** 2 + (xx - 48) ** 2 < 40 ** 2
    img = np.where(mask[..., None], 0.05 + 0.05 * rng.random((96, 96, 3)), 0.0)
    glints = rng.integers(20, 76, size=(30, 2))
    img[glints[:, 0], glints[:, 1]] = 3.0
    return img, mask


@pytest.mark.parametrize("truth_px", [0.6, 1.0, 1.4])
def test_the_spread_the_photo_was_blurred_with_is_found(truth_px):
    sharp, mask = _scene()
    photo = gaussian_filter(sharp, (truth_px, truth_px, 0)) + np.random.default_rng(1).normal(0, 0.002, sharp.shape)
    fit = fit_point_spread([photo], [sharp], [mask])
    assert fit.sigma_px == pytest.approx(truth_px, abs=0.05)
    assert fit.rms_at_sigma < 0.5 * fit.rms_pinhole
    assert fit.n_pixels > 2000 and len(fit.curve) == 17


def test_a_misfit_highlight_does_not_decide_the_spread():
    """A rendering whose glints are 3 times too bright (a material fitted too smooth) against a photo blurred by
    1 px: in linear least squares the glints ask for the most blur tried; on the asinh scale the rest of the image
    weighs in (measured 0.77 px; a gross misfit, 20 times, pulls it the other way, to 0.34)."""
    sharp, mask = _scene(5)
    photo = gaussian_filter(sharp, (1.0, 1.0, 0))
    hot = np.where(sharp > 1.0, 3 * sharp, sharp)
    assert fit_point_spread([photo], [hot], [mask], level=1e6).at_limit           # ~linear: the glints decide
    assert fit_point_spread([photo], [hot], [mask]).sigma_px == pytest.approx(1.0, abs=0.25)


def test_clipped_glints_are_left_out_and_do_not_bias_the_spread():
    sharp, mask = _scene(2)
    photo = np.minimum(gaussian_filter(sharp, (1.0, 1.0, 0)), 0.3)       # the brightest glints saturate
    fit = fit_point_spread([photo], [sharp], [mask], clip_level=0.3)
    assert fit.sigma_px == pytest.approx(1.0, abs=0.05)
    unclipped = fit_point_spread([photo], [sharp], [mask])
    assert unclipped.n_pixels > fit.n_pixels


def test_a_spread_beyond_the_grid_is_flagged_not_hidden():
    sharp, mask = _scene(4)
    photo = gaussian_filter(sharp, (2.6, 2.6, 0))
    fit = fit_point_spread([photo], [sharp], [mask])
    assert fit.sigma_px == 2.0 and fit.at_limit
    assert not fit_point_spread([gaussian_filter(sharp, (1.0, 1.0, 0))], [sharp], [mask]).at_limit


def test_a_sharp_photo_gives_no_spread():
    sharp, mask = _scene(3)
    assert fit_point_spread([sharp], [sharp], [mask]).sigma_px == 0.0


def test_the_spread_stays_inside_the_mask():
    img = np.ones((20, 20, 3))
    img[:, 10:] = 100.0                                    # the unrendered side is bright: it must not leak in
    mask = np.zeros((20, 20), bool)
    mask[:, :10] = True
    out = spread_within(img, mask, 1.5)
    assert np.allclose(out[mask], 1.0) and np.array_equal(out[~mask], img[~mask])


@pytest.mark.parametrize("case, message", [
    ("shape", "differ"), ("nan", "NaN"), ("small", "need 200"), ("grid", "ascending"), ("count", "one rendering"),
    ("level", "level"),
])
def test_bad_input_is_refused_in_one_line(case, message):
    sharp, mask = _scene()
    photos, renders, masks, kw = [sharp.copy()], [sharp], [mask], {}
    if case == "shape":
        renders = [sharp[:50]]
    elif case == "nan":
        photos[0][48, 48] = np.nan
    elif case == "small":
        masks = [np.zeros_like(mask)]
        masks[0][40:50, 40:50] = True
    elif case == "grid":
        kw = {"sigmas_px": [1.0, 0.5, 2.0]}
    elif case == "level":
        kw = {"level": 0.0}
    else:
        masks = []
    with pytest.raises(PointSpreadError, match=message) as err:
        fit_point_spread(photos, renders, masks, **kw)
    assert "\n" not in str(err.value)
