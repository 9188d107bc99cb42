"""Neighbourhood systems over the features of one frame."""

from __future__ import annotations

import numpy as np
from scipy.spatial import Delaunay, QhullError, cKDTree


def delaunay_edges(points: np.ndarray) -> np.ndarray:
    """Unique undirected edges ``(E, 2)`` int (i < j) of the Delaunay triangulation of ``points``.

    Fewer than 3 points, or points all on a line, give the chain of neighbours in sorted order,
    so that smoothness still links every feature.
    """
    points = np.asarray(points, dtype=np.float64)
    n = points.shape[0]
    if n < 2:
        return np.empty((0, 2), dtype=np.int64)
    try:
        tri = Delaunay(points)
        simplices = tri.simplices
    except (QhullError, ValueError):
        order = np.lexsort(points.T[::-1])
        return np.sort(np.stack([order[:-1], order[1:]], axis=1), axis=1).astype(np.int64)
    pairs = np.concatenate([simplices[:, [0, 1]], simplices[:, [1, 2]], simplices[:, [0, 2]]])
    pairs = np.sort(pairs, axis=1).astype(np.int64)
    # Coincident points are dropped by qhull: they are joined to nothing, which is harmless.
    # Each pair as one integer i * n + j: a 1-D unique is several times faster than axis=0.
    codes = np.unique(pairs[:, 0] * n + pairs[:, 1])
    return np.stack([codes // n, codes % n], axis=1)


def nearest_neighbours(points: np.ndarray, k: int) -> np.ndarray:
    """Indices ``(N, k')`` of the k' = min(k, N - 1) nearest other points of each point."""
    points = np.asarray(points, dtype=np.float64)
    n = points.shape[0]
    k = min(k, n - 1)
    if k < 1:
        return np.empty((n, 0), dtype=np.int64)
    _, idx = cKDTree(points).query(points, k=k + 1)
    # Drop each point itself. It is usually first, but not when another point coincides with
    # it; then the k+1 results hold it anywhere, or (among many coincident points) not at all.
    not_self = idx != np.arange(n)[:, None]
    keep = not_self & (np.cumsum(not_self, axis=1) <= k)
    return idx[keep].reshape(n, k).astype(np.int64)
