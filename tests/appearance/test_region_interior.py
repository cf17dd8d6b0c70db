"""A region's interior: geodesic distance to its border on a mesh, against the geometry of a grid."""

from __future__ import annotations

import numpy as np
import pytest

from processing.appearance.frame_poses import AppearanceError
from processing.appearance.region_interior import border_distance_mm, interior_vertices


def _grid(n: int, step_mm: float) -> tuple[np.ndarray, np.ndarray]:
    x, y = np.meshgrid(np.arange(float(n)), np.arange(float(n)))
    v = step_mm * np.stack([x.ravel(), y.ravel(), 0 * x.ravel()], axis=1)
    q = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).ravel()
    t = np.concatenate([np.stack([q, q + 1, q + n + 1], 1), np.stack([q, q + n + 1, q + n], 1)])
    return v, t


def test_distance_to_a_straight_border_is_the_distance_across_it():
    # Two materials meeting along x = 10 (columns 0-10 and 11-20, 0.5 mm apart): the nearest border vertex of a
    # vertex is straight across, so its geodesic distance along the edges is its x offset from column 10 / 11.
    v, t = _grid(21, 0.5)
    col = np.rint(v[:, 0] / 0.5).astype(int)
    label = (col > 10).astype(int)
    d = border_distance_mm(label, v, t)
    expected = 0.5 * np.where(col <= 10, 10 - col, col - 11)
    assert np.allclose(d, expected)
    inner = interior_vertices(np.flatnonzero(label == 0), d, 1.5)
    assert set(np.unique(col[inner])) == set(range(0, 8))            # 3 columns (1.5 mm) from the border
    assert interior_vertices([], d, 1.0).size == 0


def test_a_region_without_interior_keeps_its_innermost_quarter():
    v, t = _grid(21, 1.0)
    col = np.rint(v[:, 0]).astype(int)
    label = np.where((col >= 9) & (col <= 11), 1, 0)                 # a strip three vertices wide
    d = border_distance_mm(label, v, t)
    strip = np.flatnonzero(label == 1)
    kept = interior_vertices(strip, d, 5.0)
    assert len(kept) == int(np.ceil(0.25 * len(strip)))
    assert set(np.unique(col[kept])) == {10}                          # the centre line: farthest from both borders


def test_one_label_everywhere_has_no_border():
    v, t = _grid(5, 1.0)
    d = border_distance_mm(np.zeros(len(v), int), v, t)
    assert np.isinf(d).all()
    assert len(interior_vertices(np.arange(len(v)), d, 2.0)) == len(v)


def test_bad_input_is_named():
    v, t = _grid(5, 1.0)
    with pytest.raises(AppearanceError, match="one per vertex"):
        border_distance_mm(np.zeros(3, int), v, t)
    with pytest.raises(AppearanceError, match="margin"):
        interior_vertices([0, 1], np.zeros(len(v)), -1.0)
