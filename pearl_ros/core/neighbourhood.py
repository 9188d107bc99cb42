"""Neighbourhood systems over the features of one frame, and how alike neighbours move."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import Delaunay, QhullError, cKDTree

from pearl_ros.core.config import SolverSettings, default_solver
from pearl_ros.core.contrast import (
    LocalSubspaces,
    local_subspaces,
    subspace_misses,
)
from pearl_ros.core.errors import InputError
from pearl_ros.core.models import get_model


@dataclass(frozen=True)
class Neighbourhood:
    """The neighbour systems of one set of tracks, built by :func:`neighbourhood`.

    Attributes
    ----------
    edges : (E, 2) int64, Delaunay edges (i < j) of the points in the last frame
    neighbours : (N, k) int64, each point's nearest image neighbours in the last frame
    misses : (E,) float64, pixels, how far each edge's ends miss each other's local subspace
        over every frame (:func:`pearl_ros.core.contrast.patch_residuals`)
    ids : (N,) int64 or None, the points' identities, which let a later call reuse the edges
    subspaces : LocalSubspaces or None, the local subspaces the misses were measured against
        (kept for :meth:`bridges`; None: fitted again when needed)
    """

    edges: np.ndarray
    neighbours: np.ndarray
    misses: np.ndarray
    ids: np.ndarray | None = None
    subspaces: LocalSubspaces | None = field(default=None, repr=False, compare=False)

    def check(self, num_points: int) -> None:
        """Raise InputError unless this neighbourhood is one of ``num_points`` points."""
        if self.neighbours.shape[0] != num_points:
            raise InputError(f'neighbourhood holds {self.neighbours.shape[0]} points, the tracks '
                             f'{num_points}')
        if self.misses.shape != (self.edges.shape[0],) or (
                self.edges.size and not 0 <= self.edges.min() <= self.edges.max() < num_points):
            raise InputError('neighbourhood edges and misses do not match')

    def bridges(self, tracks: np.ndarray, isolated: np.ndarray,
                settings: SolverSettings | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The edges that join the points around ``isolated`` ones: those of a Delaunay
        triangulation of the other points that this one lacks ``(B, 2)`` (i < j), and their
        misses ``(B,)`` over ``tracks`` (F, N, 2), the tracks this neighbourhood was built on.

        An isolated point (a gross outlier, most often) sits between points that its own edges
        would otherwise have joined; with these edges they are tied to each other across it.
        """
        tracks = np.asarray(tracks, dtype=np.float64)
        n = self.neighbours.shape[0]
        others = np.flatnonzero(~np.asarray(isolated, dtype=bool))
        if others.size < 3 or others.size == n:
            return np.empty((0, 2), dtype=np.int64), np.zeros(0)
        extra = others[delaunay_edges(tracks[-1][others])]  # others ascend: i < j holds
        new = ~np.isin(extra[:, 0] * n + extra[:, 1], self.edges[:, 0] * n + self.edges[:, 1])
        extra = extra[new]
        data = get_model('affine').data(tracks)
        subspaces = self.subspaces or local_subspaces(data, self.neighbours, settings)
        return extra, subspace_misses(data, subspaces, extra)

    def nearest_miss(self) -> np.ndarray:
        """Each point's least miss over its edges ``(N,)``, pixels (inf for a point with none):
        how far it is from moving like its most alike neighbour."""
        nearest = np.full(self.neighbours.shape[0], np.inf)
        for end in (0, 1):
            np.minimum.at(nearest, self.edges[:, end], self.misses)
        return nearest


def neighbourhood(tracks: np.ndarray, ids: np.ndarray | None = None,
                  previous: Neighbourhood | None = None,
                  settings: SolverSettings | None = None) -> Neighbourhood:
    """Delaunay edges, nearest neighbours and edge misses of ``tracks`` (F, N, 2).

    Each point gets its ``settings.image_neighbours`` nearest image neighbours (10), and the
    misses are measured over patches shaped by ``settings`` (:func:`patch_residuals`).

    With ``ids`` (N,) equal to those of a ``previous`` neighbourhood (the same features, in the
    same order, as a tracker delivers them a frame later), its edges and neighbours are reused:
    the features moved little since. The misses are always measured anew, over ``tracks``:
    reusing misses a frame or two old cost the Hopkins155 stream half a point of error
    (BENCHMARKS.md), and they are the larger part of the cost.
    """
    settings = settings or default_solver()
    tracks = np.asarray(tracks, dtype=np.float64)
    trajectories = get_model('affine').data(tracks)  # validates tracks
    if ids is not None:
        ids = np.asarray(ids, dtype=np.int64)
        if ids.shape != (tracks.shape[1],):
            raise InputError(f'ids must have shape ({tracks.shape[1]},), got {ids.shape}')
    if previous is not None and previous.ids is not None and ids is not None \
            and np.array_equal(previous.ids, ids):
        edges, neighbours = previous.edges, previous.neighbours
    else:
        anchor = tracks[-1]
        edges = delaunay_edges(anchor)
        neighbours = nearest_neighbours(anchor, settings.image_neighbours)
    subspaces = local_subspaces(trajectories, neighbours, settings)
    return Neighbourhood(edges, neighbours, subspace_misses(trajectories, subspaces, edges), ids,
                         subspaces)


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
    nearest: np.ndarray = idx[keep].reshape(n, k).astype(np.int64)
    return nearest
