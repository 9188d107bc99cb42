"""Neighbourhood systems over the features of one frame, and how alike neighbours move."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

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
from pearl_ros.core.parallel import in_background, worthwhile


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
    triangulation : scipy.spatial.Delaunay or None, the triangulation ``edges`` came from
        (kept for :meth:`bridges`; None: none, or edges that came otherwise)
    core_patches : bool, the patches were drawn around their cores
        (``SolverSettings.core_patches``), and :meth:`bridges` and :meth:`without` draw theirs so
    isolation_misses : (E,) float64 or None, pixels, the misses :meth:`nearest_miss` reads in
        place of ``misses``: those over patches drawn in every frame's coordinates together
        (:func:`neighbourhood` with ``joint``); None: ``misses``
    """

    edges: np.ndarray
    neighbours: np.ndarray
    misses: np.ndarray
    ids: np.ndarray | None = None
    subspaces: LocalSubspaces | None = field(default=None, repr=False, compare=False)
    triangulation: Delaunay | None = field(default=None, repr=False, compare=False)
    core_patches: bool = False
    isolation_misses: np.ndarray | None = field(default=None, repr=False, compare=False)

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
        extra = self._cavity_edges(tracks[-1], isolated)
        if extra is None:
            extra = others[delaunay_edges(tracks[-1][others])]  # others ascend: i < j holds
        own = self.edges[:, 0] * n + self.edges[:, 1]
        extra = extra[~_among(extra[:, 0] * n + extra[:, 1], own)]
        data = get_model('affine').data(tracks)
        subspaces = self.subspaces or local_subspaces(data, self.neighbours, settings,
                                                      self.core_patches)
        return extra, subspace_misses(data, subspaces, extra)

    def _cavity_edges(self, anchor: np.ndarray, isolated: np.ndarray) -> np.ndarray | None:
        """The edges ``(B, 2)`` (i < j) that a Delaunay triangulation of the points not
        ``isolated`` has inside the cavity the isolated points leave in this one's triangulation
        (the triangles that touch them), or None where that cannot be read from it.

        Every triangle of this triangulation that touches no isolated point stays Delaunay
        without them; what changes is the cavity, and the triangles that fill it have empty
        circles among the other points, so they are those of a triangulation of the cavity's
        own corners (the points on its triangles, isolated ones left out) that lie in it. That
        triangulation is of a few corners per isolated point instead of every point: the same
        edges in general position, for half the time at 2,000 features.
        """
        tri = self.triangulation
        if tri is None or tri.coplanar.size or not np.array_equal(tri.points, anchor):
            return None  # other positions than the triangulation's, or points qhull dropped
        simplices = tri.simplices
        cavity = isolated[simplices].any(axis=1)
        removed = simplices[cavity]
        corners = np.unique(removed)
        corners = corners[~isolated[corners]]
        if corners.size < 3:
            return None
        pairs = corners[delaunay_edges(anchor[corners])]  # corners ascend: i < j holds
        # An edge of the corners' triangulation lies in the cavity or outside it whole (the
        # cavity's rim is made of edges of both triangulations), so its first few pixels tell:
        # in the cavity where it leaves its first end p inside the angle at p of a triangle of
        # the cavity.
        angles = np.concatenate([np.roll(removed, -k, axis=1) for k in range(3)])  # (p, u, v)
        angles = angles[~isolated[angles[:, 0]]]
        angles = angles[np.argsort(angles[:, 0], kind='stable')]
        first = np.searchsorted(angles[:, 0], pairs[:, 0])
        count = np.searchsorted(angles[:, 0], pairs[:, 0], side='right') - first
        edge = np.repeat(np.arange(pairs.shape[0]), count)
        angle = np.repeat(first - np.cumsum(count) + count, count) + np.arange(edge.size)
        corner = anchor[angles[angle, 0]]
        u, v = anchor[angles[angle, 1]] - corner, anchor[angles[angle, 2]] - corner
        d = anchor[pairs[edge, 1]] - corner
        turn = _cross(u, v)
        within = (_cross(u, d) * turn > 0) & (_cross(d, v) * turn > 0)
        inside = np.bincount(edge[within], minlength=pairs.shape[0]) > 0
        bridged: np.ndarray = pairs[inside]
        return bridged

    def without(self, tracks: np.ndarray, left: np.ndarray,
                settings: SolverSettings | None = None) -> Neighbourhood:
        """This neighbourhood with every point's patch drawn from its nearest image
        neighbours among the points not ``left`` (N,) bool, and every miss measured again."""
        tracks = np.asarray(tracks, dtype=np.float64)
        settings = settings or default_solver()
        neighbours = nearest_neighbours(tracks[-1], self.neighbours.shape[1], among=~left)
        data = get_model('affine').data(tracks)
        subspaces = local_subspaces(data, neighbours, settings, self.core_patches)
        return Neighbourhood(self.edges, neighbours, subspace_misses(data, subspaces, self.edges),
                             self.ids, subspaces, self.triangulation, self.core_patches)

    def nearest_miss(self) -> np.ndarray:
        """Each point's least miss over its edges ``(N,)``, pixels (inf for a point with none):
        how far it is from moving like its most alike neighbour. Read-only, worked out once
        (the online segmenter and the fit both read it)."""
        return self._nearest

    @cached_property
    def _nearest(self) -> np.ndarray:
        nearest = np.full(self.neighbours.shape[0], np.inf)
        misses = self.misses if self.isolation_misses is None else self.isolation_misses
        for end in (0, 1):
            np.minimum.at(nearest, self.edges[:, end], misses)
        nearest.setflags(write=False)
        return nearest


def neighbourhood(tracks: np.ndarray, ids: np.ndarray | None = None,
                  previous: Neighbourhood | None = None,
                  settings: SolverSettings | None = None,
                  core_patches: bool | None = None, joint: bool = False) -> Neighbourhood:
    """Delaunay edges, nearest neighbours and edge misses of ``tracks`` (F, N, 2).

    Each point gets its ``settings.image_neighbours`` nearest image neighbours (10), and the
    misses are measured over patches shaped by ``settings`` (:func:`patch_residuals`), drawn
    around their cores with ``core_patches`` (:func:`local_subspaces`; None: as
    ``settings.core_patches`` says, as a batch fit draws them; the online segmenter passes
    False). With ``joint``, the isolation test (:meth:`Neighbourhood.nearest_miss`) reads the
    misses over patches drawn from each point's nearest neighbours in every frame's coordinates
    together (for two frames (x, y, x', y'): ``SolverSettings.joint_neighbours``); the pair
    term's misses, the neighbours and the edges stay those of the last frame.

    With ``ids`` (N,) equal to those of a ``previous`` neighbourhood (the same features, in the
    same order, as a tracker delivers them a frame later), its edges and neighbours are reused:
    the features moved little since. The misses are always measured anew, over ``tracks``:
    reusing misses a frame or two old cost the Hopkins155 stream half a point of error
    (BENCHMARKS.md), and they are the larger part of the cost.
    """
    settings = settings or default_solver()
    if core_patches is None:
        core_patches = settings.core_patches
    tracks = np.asarray(tracks, dtype=np.float64)
    trajectories = get_model('affine').data(tracks)  # validates tracks
    if ids is not None:
        ids = np.asarray(ids, dtype=np.int64)
        if ids.shape != (tracks.shape[1],):
            raise InputError(f'ids must have shape ({tracks.shape[1]},), got {ids.shape}')
    if previous is not None and previous.ids is not None and ids is not None \
            and np.array_equal(previous.ids, ids):
        edges, neighbours = previous.edges, previous.neighbours
        subspaces = local_subspaces(trajectories, neighbours, settings, core_patches)
        triangulation = previous.triangulation
    else:
        anchor = tracks[-1]
        # The triangulation depends on nothing else here: it runs beside the rest.
        triangulated = in_background(_triangulate, anchor) if worthwhile(anchor.shape[0]) \
            else None
        neighbours = nearest_neighbours(anchor, settings.image_neighbours)
        subspaces = local_subspaces(trajectories, neighbours, settings, core_patches)
        edges, triangulation = (triangulated.result() if triangulated is not None
                                else _triangulate(anchor))
    isolation = None
    if joint:
        near = nearest_neighbours(np.concatenate(list(tracks), axis=1), settings.image_neighbours)
        isolation = subspace_misses(
            trajectories, local_subspaces(trajectories, near, settings, core_patches), edges)
    return Neighbourhood(edges, neighbours, subspace_misses(trajectories, subspaces, edges), ids,
                         subspaces, triangulation, core_patches, isolation)


def lost_neighbours(tracks: np.ndarray, k: int) -> float:
    """The share of the points of ``tracks`` (F, N, 2) that keep fewer than a third of their
    ``k`` nearest image neighbours from the first frame to the last. Rigid motions keep a
    point's neighbours (Hopkins155's and KT3DMoSeg's first and last frames: at most 3.4 and
    6.6% of the points lose them); a mismatch, which lands anywhere in the other view, loses
    them, and so does a point that mismatches surround (AdelaideRMF's pairs: 26-83%)."""
    kept, k = kept_neighbours(tracks, k)
    if k == 0:
        return 0.0
    return float(np.mean(3 * kept < k))


def kept_neighbours(tracks: np.ndarray, k: int) -> tuple[np.ndarray, int]:
    """How many of each point's ``k`` nearest image neighbours in the first frame of ``tracks``
    (F, N, 2) are among its ``k`` nearest in the last, ``(N,)`` int; and the k used (at most
    N - 1)."""
    tracks = np.asarray(tracks, dtype=np.float64)
    first = nearest_neighbours(tracks[0], k)
    last = nearest_neighbours(tracks[-1], k)
    kept = (first[:, :, None] == last[:, None, :]).any(axis=1).sum(axis=1)
    return kept, first.shape[1]


def delaunay_edges(points: np.ndarray) -> np.ndarray:
    """Unique undirected edges ``(E, 2)`` int (i < j) of the Delaunay triangulation of ``points``.

    Fewer than 3 points, or points all on a line, give the chain of neighbours in sorted order,
    so that smoothness still links every feature.
    """
    return _triangulate(points)[0]


def _triangulate(points: np.ndarray) -> tuple[np.ndarray, Delaunay | None]:
    """:func:`delaunay_edges`, and the triangulation they came from (None: the chain)."""
    points = np.asarray(points, dtype=np.float64)
    n = points.shape[0]
    if n < 2:
        return np.empty((0, 2), dtype=np.int64), None
    try:
        tri = Delaunay(points)
        indptr, indices = tri.vertex_neighbor_vertices
    except (QhullError, ValueError):
        order = np.lexsort(points.T[::-1])
        chain = np.sort(np.stack([order[:-1], order[1:]], axis=1), axis=1).astype(np.int64)
        return chain, None
    # Each point's neighbours in the triangulation, each edge once (i < j). Coincident points
    # are dropped by qhull: they are joined to nothing, which is harmless. Each pair as one
    # integer i * n + j, sorted: the edges in the order of (i, j).
    first = np.repeat(np.arange(n, dtype=np.int64), np.diff(indptr))
    second = indices.astype(np.int64)
    once = first < second
    codes = np.sort(first[once] * n + second[once])
    return np.stack([codes // n, codes % n], axis=1), tri


def _among(codes: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Whether each of ``codes`` (M,) int is one of ``known`` (K,) int, ``(M,)`` bool. A
    triangulation's edge codes come sorted: a binary search then, 30 times faster than
    ``np.isin``, which sorts both."""
    if known.size == 0:
        return np.zeros(codes.size, dtype=bool)
    if known.size > 1 and not np.all(known[1:] > known[:-1]):
        known = np.unique(known)
    at = np.minimum(np.searchsorted(known, codes), known.size - 1)
    found: np.ndarray = known[at] == codes
    return found


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The z component of the cross products of 2-D vectors ``a`` and ``b`` (rows)."""
    out: np.ndarray = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def nearest_neighbours(points: np.ndarray, k: int, among: np.ndarray | None = None
                       ) -> np.ndarray:
    """Indices ``(N, k')`` of the k' = min(k, M - 1) nearest other points of each point, of
    the M points ``among`` marks ``(N,)`` bool (default: all of them)."""
    points = np.asarray(points, dtype=np.float64)
    n = points.shape[0]
    candidates = None if among is None else np.flatnonzero(among)
    k = min(k, (n if candidates is None else candidates.size) - 1)
    if k < 1:
        return np.empty((n, 0), dtype=np.int64)
    if candidates is None:
        _, idx = cKDTree(points).query(points, k=k + 1)
    else:
        _, found = cKDTree(points[candidates]).query(points, k=k + 1)
        idx = candidates[found]
    # Drop each point itself. It is usually first, but not when another point coincides with
    # it; then the k+1 results hold it anywhere, or (among many coincident points) not at all.
    not_self = idx != np.arange(n)[:, None]
    keep = not_self & (np.cumsum(not_self, axis=1) <= k)
    nearest: np.ndarray = idx[keep].reshape(n, k).astype(np.int64)
    return nearest
