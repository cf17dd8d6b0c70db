"""Turned objects of the simulated world (mocks.turned_objects) against their construction."""

from __future__ import annotations

import numpy as np
import pytest

from mocks.turned_objects import BOSS_HEIGHT_MM, INLAY_DEPTH_MM, TURNED_OBJECTS, revolve, turned_object
from mocks.world import World


def _edges_twice(triangles: np.ndarray) -> bool:
    """Every undirected edge is shared by exactly two triangles (closed two-manifold)."""
    e = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return bool(np.all(counts == 2))


def test_revolve_makes_a_closed_outward_cylinder_of_the_right_volume():
    v, t = revolve([0, 10, 10, 0], [0, 0, 20, 20], 256)
    assert _edges_twice(t)
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    volume = np.sum(np.einsum("ij,ij->i", a, np.cross(b, c))) / 6.0
    # inscribed 256-gon: pi r^2 h times sin(2 pi / n) n / (2 pi), exact to rounding
    expected = 0.5 * 256 * np.sin(2 * np.pi / 256) * 100.0 * 20.0
    assert volume == pytest.approx(expected, rel=1e-9)


@pytest.mark.parametrize("name", TURNED_OBJECTS)
def test_turned_objects_are_closed_and_stand_on_the_table(name):
    m = turned_object(name, step_mm=1.5)
    assert _edges_twice(m.triangles)
    assert m.vertices[:, 2].min() == pytest.approx(0.0, abs=1e-9)
    assert set(m.materials) == set(m.region_names)


def test_the_boss_stands_its_height_above_the_surface_of_revolution():
    m = turned_object("vase", step_mm=1.0)
    # far from the boss the vertices lie on the surface of revolution: the radius at the boss's
    # height elsewhere round the axis is the bare radius
    r = np.linalg.norm(m.vertices[:, :2], axis=1)
    near_z = np.abs(m.vertices[:, 2] - 30.0) < 0.6
    az = np.degrees(np.arctan2(m.vertices[:, 1], m.vertices[:, 0]))
    top = r[near_z & (np.abs(az) < 1.0)].max()
    base = np.median(r[near_z & (np.abs(az) > 60.0)])
    # the belly's normal there is nearly horizontal: the radial rise is the height within 2 %
    assert top - base == pytest.approx(BOSS_HEIGHT_MM, rel=0.02)


def test_the_motif_breaks_the_symmetry_and_the_inlay_is_sunk():
    plain = turned_object("plain-bowl", step_mm=1.5)
    inlaid = turned_object("inlaid-bowl", step_mm=1.5)
    motif = plain.region == 1
    az = np.degrees(np.arctan2(*plain.vertices[plain.triangles[motif]].mean(axis=1)[:, 1::-1].T))
    hist, _ = np.histogram(az, bins=12, range=(-180, 180))
    assert hist.max() > 5 * max(np.sort(hist)[len(hist) // 2], 1), "the motif is concentrated at some azimuths"
    d = np.linalg.norm(inlaid.vertices - plain.vertices, axis=1)
    assert d.max() == pytest.approx(INLAY_DEPTH_MM, rel=1e-6)
    assert np.array_equal(plain.region, inlaid.region)
    assert np.allclose(turned_object("plain-bowl:bare", step_mm=1.5).vertices, plain.vertices)


def test_worlds_round_trip_and_bad_names_are_refused():
    w = World.turned("vase")
    again = World.from_dict(w.to_dict())
    assert again.mesh_source == "vase" and np.allclose(again.vertices, w.vertices)
    with pytest.raises(ValueError, match="unknown turned object"):
        turned_object("teapot")
