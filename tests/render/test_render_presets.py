"""Render settings validation and the named presets."""

from __future__ import annotations

import pytest

from render.errors import RenderInputError
from render.presets import PRESETS, RenderSettings, get_preset


def test_presets_order_cost_and_accuracy():
    d, s, r = PRESETS["draft"], PRESETS["standard"], PRESETS["reference"]
    assert set(PRESETS) == {"draft", "standard", "reference"}
    assert (r.spectral_step, r.use_tables, r.mirror_bounces) == (5.0, False, 1)           # 61 bands per sample
    assert (s.spectral_step, s.use_tables, s.mirror_bounces) == (5.0, True, 1)            # exact tables
    assert d.spectral_step > s.spectral_step and d.use_tables
    assert d.samples_per_pixel < s.samples_per_pixel < r.samples_per_pixel
    assert all(p.shadows for p in PRESETS.values())
    assert get_preset("standard") is s and s.name == "standard"


@pytest.mark.parametrize(
    "kw, message",
    [
        (dict(spectral_step=7), "divide 400-700 nm evenly"),
        (dict(spectral_step=0), "divide"),
        (dict(spectral_step="fine"), "number of nm"),
        (dict(samples_per_pixel=0), r"samples_per_pixel must be in 1\.\.4096, got 0"),
        (dict(samples_per_pixel=2.5), "whole number"),
        (dict(mirror_bounces=2), r"mirror_bounces must be in 0\.\.1"),
        (dict(mirror_rays=-1), "mirror_rays"),
        (dict(table_size=1), "table_size"),
        (dict(tile_size=0), "tile_size"),
        (dict(use_tables="yes"), "True or False"),
        (dict(jitter=1), "True or False"),
    ],
)
def test_bad_settings_name_the_setting(kw, message):
    with pytest.raises(RenderInputError, match=message):
        RenderSettings(**kw)


def test_replace_validates_and_reports_unknown_names():
    s = PRESETS["standard"].replace(samples_per_pixel=9, spectral_step=10)
    assert (s.samples_per_pixel, s.spectral_step, s.use_tables) == (9, 10.0, True)
    with pytest.raises(RenderInputError, match="unknown render setting"):
        PRESETS["standard"].replace(bounces=2)
    with pytest.raises(RenderInputError, match="samples_per_pixel"):
        PRESETS["standard"].replace(samples_per_pixel=-4)
    with pytest.raises(RenderInputError, match="unknown render preset 'fast'; choose one of draft, standard, reference"):
        get_preset("fast")
