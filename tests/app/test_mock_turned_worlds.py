"""``kogei mock --world vase|inlaid-bowl|plain-bowl[:bare]`` builds the turned objects at the station's settings."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from app.cli.mock import _build_world, add_parser
from app.errors import UsageError
from mocks.turned_objects import turned_object
from mocks.world import station_world_settings


def _args(*argv):
    parser = argparse.ArgumentParser(prog="kogei")
    add_parser(parser.add_subparsers(dest="command"))
    return parser.parse_args(["mock", *argv])


@pytest.mark.parametrize("name", ["vase", "inlaid-bowl", "plain-bowl", "plain-bowl:bare"])
def test_turned_worlds_are_the_objects_at_the_station_settings(name):
    w = _build_world(_args("--world", name))
    truth = turned_object(name)
    assert w.mesh_source == name and np.array_equal(w.vertices, truth.vertices)
    assert w.materials == truth.materials
    assert {k: getattr(w, k) for k in station_world_settings()} == station_world_settings()


def test_material_overrides_every_region_and_triangles_is_refused():
    w = _build_world(_args("--world", "plain-bowl", "--material", "gold"))
    assert set(w.materials.values()) == {"gold"}
    with pytest.raises(UsageError, match="--triangles"):
        _build_world(_args("--world", "vase", "--triangles", "2000"))
