"""Segmentation of an object's pixels into regions without ground truth (processing.materials.segmentation).

Synthetic frames with a known layout: a grey backdrop, patches of known colour, Gaussian noise; the
truth is the layout itself.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from processing.materials.segmentation import SegmentationError, border_backdrop, segment_regions


def _scene(rng: np.random.Generator, noise: float = 0.002) -> tuple[np.ndarray, np.ndarray]:
    """40 x 60 frame: backdrop 0.05 grey; a gold-like block (label 1), a blue block (2); truth labels."""
    rel = np.full((40, 60, 3), 0.05)
    truth = np.zeros((40, 60), int)
    rel[10:30, 10:30] = (0.5, 0.35, 0.08)
    truth[10:30, 10:30] = 1
    rel[12:28, 36:50] = (0.05, 0.12, 0.4)
    truth[12:28, 36:50] = 2
    return rel + rng.normal(0, noise, rel.shape), truth


def test_regions_and_backdrop_match_the_layout():
    rel, truth = _scene(np.random.default_rng(1))
    seg = segment_regions(rel, np.ones(truth.shape, bool), clusters=2)
    assert np.allclose(seg.backdrop_rgb, 0.05, atol=0.002)
    assert np.array_equal(seg.backdrop, truth == 0)
    # two colours, two clusters: each block is one label, the bigger block label 1
    assert np.array_equal(seg.labels, truth)
    # more clusters than colours split a block (merged later by identification) but never mix two blocks
    over = segment_regions(rel, np.ones(truth.shape, bool), clusters=5)
    for label in range(1, over.labels.max() + 1):
        assert len(np.unique(truth[over.labels == label])) == 1, label
    assert np.allclose(seg.centres[0], np.array([0.5, 0.35, 0.08]) / 0.93, atol=0.01)


def test_masked_and_dark_pixels_get_no_region():
    rel, truth = _scene(np.random.default_rng(2))
    mask = np.ones(truth.shape, bool)
    mask[15:20, 15:20] = False                     # saturated in the RAW
    rel[20:25, 15:20] = 0.0                        # black: off the highlight
    rel[0, 0] = np.nan                             # masked pixels may hold anything
    mask[0, 0] = False
    seg = segment_regions(rel, mask, clusters=2)
    assert not seg.labels[15:25, 15:20].any()
    assert seg.labels[10:15, 10:30].all()


def test_an_empty_scene_has_no_region_and_no_nan():
    seg = segment_regions(np.full((20, 20, 3), 0.05), np.ones((20, 20), bool))
    assert not seg.labels.any() and seg.backdrop.all() and seg.centres.shape == (0, 3)
    dark = segment_regions(np.zeros((20, 20, 3)), np.ones((20, 20), bool))
    assert not dark.labels.any() and np.all(np.isfinite(dark.backdrop_rgb))


@settings(max_examples=25, deadline=None)
@given(scale=st.floats(1e-6, 1e6), clusters=st.integers(1, 8))
def test_labels_are_valid_at_any_brightness(scale, clusters):
    rel, truth = _scene(np.random.default_rng(3), noise=0.0)
    seg = segment_regions(rel * scale, np.ones(truth.shape, bool), clusters=clusters)
    assert seg.labels.min() >= 0 and seg.labels.max() <= clusters
    assert np.all(np.isfinite(seg.centres)) and np.all(np.isfinite(seg.backdrop_rgb))
    # chromaticity does not depend on the scale: the blocks separate from the backdrop at any level
    assert np.array_equal(seg.backdrop, truth == 0)


@pytest.mark.parametrize("kwargs, message", [
    ({"rel": np.zeros((4, 4)), "mask": np.ones((4, 4), bool)}, "rel must be (H, W, 3)"),
    ({"rel": np.zeros((4, 4, 3)), "mask": np.ones((4, 4), bool), "clusters": 0}, "clusters must be"),
    ({"rel": np.zeros((4, 4, 3)), "mask": np.ones((4, 4), bool), "backdrop_factor": 0.5}, "backdrop_factor"),
    ({"rel": np.zeros((4, 4, 3)), "mask": np.zeros((4, 4), bool)}, "border shows no usable pixel"),
])
def test_bad_input_is_a_clear_error(kwargs, message):
    with pytest.raises(SegmentationError, match=message.replace("(", r"\(").replace(")", r"\)")):
        segment_regions(**kwargs)


def test_border_backdrop_ignores_masked_pixels():
    rel = np.full((10, 10, 3), 0.05)
    rel[0] = 0.9
    mask = np.ones((10, 10), bool)
    mask[0] = False
    assert np.allclose(border_backdrop(rel, mask), 0.05)
