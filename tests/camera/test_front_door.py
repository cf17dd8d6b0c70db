"""The camera front door exports its modules' public names."""

from __future__ import annotations

import importlib

import processing.camera as camera
from processing.camera import chart_layout as chart_layout_function


def test_the_front_door_exports_each_name_of_its_modules():
    for name in camera.__all__:
        obj = getattr(camera, name)
        home = getattr(obj, "__module__", None)
        if home and home.startswith("processing.camera"):
            assert getattr(importlib.import_module(home), name) is obj


def test_chart_layout_is_the_function():
    assert chart_layout_function("classic24").size == 24
