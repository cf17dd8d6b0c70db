"""Cell labels of the registration's block statistics (processing.geometry.registration.cells) against
``np.unique(key, axis=0)``, the independent reference: the same labels and counts, exactly, on both of its
paths (packed into one integer, and too wide to pack)."""

from __future__ import annotations

import numpy as np
import pytest

from processing.geometry.registration.cells import cell_labels


@pytest.mark.parametrize(("n", "high"), [(1, 4), (9, 2), (5_000, 40), (20_000, 300), (2_000, 2 ** 21), (300, 2 ** 40)])
def test_labels_and_counts_are_numpys_row_unique(n, high):
    key = np.random.default_rng(n).integers(0, high, (n, 3))
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    cell, got_counts = cell_labels(key)
    assert np.array_equal(cell, inverse.ravel()) and np.array_equal(got_counts, counts)


def test_no_points_no_cells():
    cell, counts = cell_labels(np.zeros((0, 3), dtype=np.int64))
    assert cell.shape == (0,) and counts.shape == (0,)
