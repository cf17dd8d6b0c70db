"""Patch sampling and the chart checks, against the simulated shot's labels and sensor truth."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mocks.chart_scene import ChartPlacement
from processing.camera.chart_detection import chart_from_corners, detect_chart
from processing.camera.chart_sampling import (
    ChartRejectedError,
    ChartSamplingError,
    PatchSamples,
    check_patches,
    sample_patches,
)
from processing.camera.raw_decode import decode_raw
from tests.camera.chart_shots import chart_shot

PLACEMENT = ChartPlacement(size=0.6, rotation_deg=10, tilt_deg=(10, 0))


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    shot = chart_shot(tmp_path_factory.mktemp("good"), "classic24", chart_placement=PLACEMENT)
    img = decode_raw(shot.path)
    return shot, img, detect_chart(img)


def _label_means(shot, img):
    """Mean binned RGB over the pixels whose four photosites lie on each patch (ground truth region)."""
    lab = shot.frame.labels
    out = []
    for k in range(24):
        inside = ((lab[0::2, 0::2] == k) & (lab[0::2, 1::2] == k) & (lab[1::2, 0::2] == k) & (lab[1::2, 1::2] == k))
        out.append(img.rgb[inside].mean(axis=0))
    return np.array(out)


def test_samples_match_the_labelled_regions(good):
    shot, img, det = good
    s = sample_patches(img, det)
    np.testing.assert_allclose(s.mean, _label_means(shot, img), rtol=3e-3, atol=3e-4)
    assert np.all(s.clipped == 0) and np.all(s.count > 100)
    assert s.exposure_time == pytest.approx(0.01) and s.iso == 100
    # the std is the sensor noise: photon + read noise of the simulated sensor (electrons -> units of saturation)
    g, well_dn = 2.0, 16383 - 600
    mu_e = s.mean * well_dn * g
    # binned green averages two photosites
    expected_std = np.sqrt(mu_e + 16.0) / g / well_dn / np.sqrt([1.0, 2.0, 1.0])
    np.testing.assert_allclose(s.std[6:18], expected_std[6:18], rtol=0.25)
    assert s.nonuniformity.max() < 0.01
    check = check_patches(s)
    assert check.usable.all() and check.warnings == []


def test_trim_rejects_outliers(good):
    shot, img, det = good
    hot = img.rgb.copy()
    c = np.round(img.from_sensor(det.centres[7])).astype(int)
    hot[c[1] - 1:c[1] + 2, c[0] - 1:c[0] + 2] = 1.0          # a few hot pixels inside patch 8
    spoiled = type(img)(**{**img.__dict__, "rgb": hot})
    plain = sample_patches(spoiled, det, trim=0.0).mean[7]
    trimmed = sample_patches(spoiled, det, trim=0.1).mean[7]
    truth = sample_patches(img, det, trim=0.1).mean[7]
    assert np.all(np.abs(trimmed - truth) < 0.2 * np.abs(plain - truth))


def test_a_clipped_white_is_named_and_left_out(tmp_path):
    shot = chart_shot(tmp_path, "classic24", chart_placement=PLACEMENT, exposure_boost=2.0)
    img = decode_raw(shot.path)
    s = sample_patches(img, detect_chart(img))
    check = check_patches(s)
    assert not check.usable[18] and check.usable[19:].all() and check.usable[:18].all()
    assert check.warnings == ["patch 19 (white 9.5) is 100% clipped: lower the exposure"]


def test_an_over_exposed_chart_is_rejected(tmp_path):
    shot = chart_shot(tmp_path, "classic24", chart_placement=PLACEMENT, exposure_boost=6.0)
    img = decode_raw(shot.path)
    with pytest.raises(ChartRejectedError, match=r"unusable .*patch \d+ \([a-z ]+\) 100%.* clipped: lower the exposure") as err:
        check_patches(sample_patches(img, chart_from_corners(shot.frame.chart_corners, image_size=(600, 400))))
    assert len(str(err.value)) < 300         # one short line: the worst patches named, the rest counted


def test_a_shadow_across_a_patch_is_named(tmp_path):
    def shade(frame):
        rad = frame.radiance.copy()
        on = frame.labels == 13                                   # green
        xs = np.nonzero(on)[1]
        ramp = 1.0 - 0.4 * (np.arange(rad.shape[1]) - xs.min()) / max(xs.max() - xs.min(), 1)
        rad[on] *= ramp[np.nonzero(on)[1]][:, None]
        return rad

    shot = chart_shot(tmp_path, "classic24", chart_placement=PLACEMENT, radiance_fn=shade)
    img = decode_raw(shot.path)
    check = check_patches(sample_patches(img, detect_chart(img)))
    assert not check.usable[13] and check.usable.sum() == 23
    assert "patch 14 (green) is not uniform" in check.warnings[0] and "glare or a shadow" in check.warnings[0]


@pytest.mark.parametrize("order", [[2, 3, 0, 1], [1, 0, 3, 2], [3, 2, 1, 0]], ids=["rotated", "mirrored", "flipped"])
def test_mis_ordered_corners_are_rejected(good, order):
    shot, img, _ = good
    det = chart_from_corners(shot.frame.chart_corners[order], image_size=(600, 400))
    with pytest.raises(ChartRejectedError, match=r"out of order.*rotated or mirrored.*patch 1 \(dark skin\)"):
        check_patches(sample_patches(img, det))


def test_swapped_chromatic_patches_fail_the_hue_order(good):
    shot, img, det = good
    s = sample_patches(img, det)
    perm = np.arange(24)
    perm[:18] = np.roll(perm[:18], 6)                      # neutrals in place, colour rows shifted
    swapped = PatchSamples(s.chart, s.mean[perm], s.std[perm], s.clipped[perm], s.count[perm],
                           s.nonuniformity[perm])
    with pytest.raises(ChartRejectedError, match="chromatic patches have their expected hue"):
        check_patches(swapped)


@settings(max_examples=40, deadline=None)
@given(st.floats(1e-6, 1e6))
def test_the_verdict_does_not_depend_on_exposure_scale(good, factor):
    """Orderings and uniformity are ratios: any exposure scale gives the same usable set, never NaN."""
    _, img, det = good
    s = sample_patches(img, det)
    scaled = PatchSamples(s.chart, s.mean * factor, s.std * factor, s.clipped, s.count, s.nonuniformity)
    assert check_patches(scaled).usable.all()


def test_all_dark_chart_is_rejected_not_nan(good):
    _, img, det = good
    s = sample_patches(img, det)
    dark = PatchSamples(s.chart, np.zeros_like(s.mean), s.std, s.clipped, s.count, s.nonuniformity)
    with pytest.raises(ChartRejectedError, match="no signal in some channel: raise the exposure"):
        check_patches(dark)


def test_sampling_errors(good, tmp_path):
    shot, img, det = good
    with pytest.raises(ChartSamplingError, match="inset"):
        sample_patches(img, det, inset=0)
    with pytest.raises(ChartSamplingError, match="trim"):
        sample_patches(img, det, trim=0.5)
    other = chart_from_corners(shot.frame.chart_corners, image_size=(1200, 800))
    with pytest.raises(ChartSamplingError, match="located in a 1200 x 800 image"):
        sample_patches(img, other)
    tiny = chart_from_corners([[0, 0], [8, 0], [8, 5], [0, 5]])
    with pytest.raises(ChartSamplingError, match="patch 1 \\(dark skin\\) covers only"):
        sample_patches(img, tiny)
