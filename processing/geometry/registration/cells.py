"""Labels of the cubic cells that points fall in, for the block statistics of the pose tests.

:func:`processing.geometry.registration.pose_evidence.pose_evidence` and the photo-consistency test group
points into cells and sum per cell, many times per registered pair.  ``np.unique(key, axis=0)`` on the
cells' integer coordinates sorts rows as a structured type, some 25 times slower than sorting one
``int64`` per point; :func:`cell_labels` packs the three coordinates into that integer (same order, same
labels) when they fit.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["cell_labels"]


def cell_labels(key: NDArray[np.int64]) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Cell of every point (``0 .. cells - 1``, cells in lexicographic order of ``key``) and points per cell.

    Parameters
    ----------
    key
        ``(N, 3)`` non-negative integer cell coordinates of the points, e.g.
        ``floor((p - p.min(axis=0)) / cell_mm)``.

    Returns
    -------
    cell : ndarray
        ``(N,)`` the label of each point's cell, as ``np.unique(key, axis=0, return_inverse=True)`` gives.
    counts : ndarray
        ``(cells,)`` points per cell, as its ``return_counts=True`` gives.

    Examples
    --------
    >>> key = np.array([[1, 0, 2], [0, 5, 1], [1, 0, 2], [0, 5, 0]])
    >>> cell, counts = cell_labels(key)
    >>> cell.tolist(), counts.tolist()
    ([2, 1, 2, 0], [1, 1, 2])
    """
    key = np.asarray(key, dtype=np.int64).reshape(-1, 3)
    if len(key) == 0:
        return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp)
    dims = key.max(axis=0).astype(np.float64) + 1.0
    if key.min() >= 0 and float(np.prod(dims)) < 2.0 ** 62:
        d1, d2 = int(dims[1]), int(dims[2])
        flat = (key[:, 0] * d1 + key[:, 1]) * d2 + key[:, 2]
        _, cell, counts = np.unique(flat, return_inverse=True, return_counts=True)
    else:
        _, cell, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return cell.ravel(), counts
