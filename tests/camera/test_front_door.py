"""The camera front door exports its modules' public names."""

from __future__ import annotations

import importlib

import processing.camera as camera


def test_the_front_door_exports_each_name_of_its_modules():
    for name in camera.__all__:
        obj = getattr(camera, name)
        home = getattr(obj, "__module__", None)
        if home and home.startswith("processing.camera"):
            assert getattr(importlib.import_module(home), name) is obj


def test_the_chart_layout_attribute_stays_the_module():
    import processing.camera.chart_layout as module

    assert camera.chart_layout is module and module.chart_layout("classic24").size == 24
