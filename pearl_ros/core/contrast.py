"""Do two image neighbours move alike? Each one's trajectory against the other's local subspace.

The trajectories of the points of one rigid body under an affine camera lie in a 3-D affine
subspace (Tomasi & Kanade 1992), and so do those of any patch of it, planar or not. Fitted to a
point and a few image neighbours, that local subspace holds the trajectory of a neighbour on the
same body within the noise, and misses one on another body by their relative motion, however
slow or dependent the two motions are (local subspaces as in LSA, Yan & Pollefeys, ECCV 2006).
With two frames, R^4, the local subspace is an affine epipolar constraint.

The energy turns the miss into a contrast-sensitive Potts weight, as image segmentation weights
its Potts term by colour differences (Boykov & Jolly, ICCV 2001), and into a small reward for
cutting a pair that moves apart: the term that keeps one subspace from taking two dependent
motions, which it fits about as well as two subspaces do. A long edge, across a featureless
band, extrapolates its local subspaces far: where its two ends move coherently its miss is
read in a larger unit (:func:`long_edge_stretch`), so that perspective does not cut a body
along the band.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pearl_ros.core.config import SolverSettings, default_solver
from pearl_ros.core.parallel import eigh_batch, worthwhile


def patch_residuals(data: np.ndarray, edges: np.ndarray, neighbours: np.ndarray,
                    settings: SolverSettings | None = None) -> np.ndarray:
    """The miss of each edge's points from each other's local subspace, ``(E,)`` pixels.

    Parameters
    ----------
    data : (N, 2F) float64, trajectories scaled by 1/sqrt(F) (``AffineSubspace.data``)
    edges : (E, 2) int, neighbour pairs
    neighbours : (N, k) int, each point's nearest image neighbours
    settings : SolverSettings, optional
        ``patch_size`` (8), ``patch_core`` (4), ``stranger`` (5) and ``subspace_dim`` (3).

    Returns
    -------
    (E,) float64: for edge (p, q), the mean of the distance from q's trajectory to the 3-D
    affine subspace fitted to p's patch and that of p to q's. A patch is the point and the
    ``patch_size - 1`` of its neighbours whose motion (trajectory less its mean position) is
    closest to its own: near a boundary, the nearest points are often on the other body, most
    often where that body's features are denser. Of those, a neighbour whose motion gap is more
    than ``stranger`` times that of the point's third closest-moving neighbour (the last of the
    ``patch_core`` points) is left out too: next to a denser body, the patch of a point near
    the boundary would otherwise take several of that body's points, and its subspace, spanning
    both motions, would hold the other side's trajectories. Zero where patches hold at most 4
    points.
    """
    if edges.shape[0] == 0:
        return np.zeros(0)
    return subspace_misses(data, local_subspaces(data, neighbours, settings), edges)


@dataclass(frozen=True)
class LocalSubspaces:
    """Each point's local subspace (:func:`local_subspaces`): its patch's mean ``(N, 2F)`` and
    orthonormal directions ``(N, <=3, 2F)`` (a direction without spread is zero)."""

    mean: np.ndarray
    basis: np.ndarray


def local_subspaces(data: np.ndarray, neighbours: np.ndarray,
                    settings: SolverSettings | None = None,
                    core_patches: bool = False) -> LocalSubspaces:
    """The local subspace of every point's patch, as :func:`patch_residuals` fits them; with
    ``core_patches``, over three frames or more, patches as :func:`_core_patches` draws them."""
    settings = settings or default_solver()
    size, core_size, dim = settings.patch_size, settings.patch_core, settings.subspace_dim
    n = data.shape[0]
    rows = data.reshape(n, -1, 2)
    moves = (rows - rows.mean(axis=1, keepdims=True)).reshape(n, -1)
    # The norms of the motion gaps, worked in place: a fresh (N, k, 2F) temporary is fresh
    # pages from the system at 2,000 features, 4x the arithmetic's time (the same values).
    gap = moves[neighbours]
    gap -= moves[:, None, :]
    gap *= gap
    gap = np.sqrt(gap.sum(axis=2))
    order = np.argsort(gap, axis=1, kind='stable')
    if core_patches and data.shape[1] > 4 and neighbours.shape[1] >= core_size:
        neighbours, member = _core_patches(data, np.take_along_axis(neighbours, order, axis=1),
                                           np.take_along_axis(gap, order, axis=1), settings)
    else:
        closest = order[:, : size - 1]
        neighbours = np.take_along_axis(neighbours, closest, axis=1)
        gap = np.take_along_axis(gap, closest, axis=1)
        member = np.ones((n, 1 + neighbours.shape[1]))  # 1 in the patch, 0 left out
        if neighbours.shape[1] >= core_size:
            core = gap[:, core_size - 2 : core_size - 1]
            member[:, core_size:] = gap[:, core_size - 1 :] <= settings.stranger * core
    patch = np.concatenate([np.arange(n)[:, None], neighbours], axis=1)
    points = data[patch]  # (N, k, 2F)
    mean = np.einsum('nk,nkd->nd', member, points) / member.sum(axis=1)[:, None]
    centred = (points - mean[:, None, :]) * member[:, :, None]  # rows left out are zero
    # Principal directions from each patch's k x k Gram matrix (cheaper than an SVD of the
    # patch): with G = C C^T = U S^2 U^T, the directions are S^-1 U^T C.
    values, vectors = eigh_batch(centred @ np.transpose(centred, (0, 2, 1)), worthwhile(n))
    top = vectors[:, :, ::-1][:, :, :dim]  # (N, k, <=3), largest first
    lengths = np.sqrt(np.maximum(values[:, ::-1][:, :dim], 0.0))
    basis = np.einsum('nkj,nkd->njd', top, centred)
    # A direction without spread (a patch of at most 3 points) spans nothing.
    basis /= np.where(lengths > 1e-12, lengths, np.inf)[:, :, None]  # (N, <=3, 2F)
    return LocalSubspaces(mean, basis)


def _core_patches(data: np.ndarray, ordered: np.ndarray, gap: np.ndarray,
                  settings: SolverSettings) -> tuple[np.ndarray, np.ndarray]:
    """Patches drawn around each point's core: its neighbours ``(N, k)`` ordered closest-moving
    first (their motion gaps ``gap``, ascending), of which the first ``patch_core - 1`` are the
    core. The patch is the point, its core and the ``core_patch_size - patch_core`` neighbours
    nearest the affine subspace through the core's trajectories (exact through its four
    points); of those, a neighbour is left out where it lies farther from that subspace than
    ``stranger`` times the second nearest, or where its motion gap exceeds ``stranger`` times
    the last core neighbour's (the closest-moving patches' own rule: where fewer than two of the
    point's body lie beyond its core, the nearest are the other body's).

    Next to a body that moves almost as the point's own does (dependent motions: two objects
    translating alike), the closest-moving neighbours beyond the core are often the other
    body's, and a patch of both spans both motions, so that pairs across the boundary read
    alike; the other body's points lie off the core's subspace. Over two frames (R^4) a
    subspace through four points is too loose to rank by, and over the online segmenter's
    10-frame windows this ranking measured worse (docs/experiments.md).

    Returns the patch's neighbours ``(N, core_patch_size - 1)`` (fewer where ``k`` is) and the
    member mask ``(N, 1 + that)``, 1 in the patch (the point first).
    """
    core = settings.patch_core - 1
    offsets = data[ordered] - data[:, None, :]  # (N, k, D), each neighbour from the point
    gram = offsets @ np.transpose(offsets, (0, 2, 1))  # (N, k, k)
    # Squared distance of every neighbour to the span of the core's offsets: its squared
    # length less that of its projection, g^T G_cc^-1 g (a small ridge keeps a degenerate
    # core, its points on a line, solvable).
    ridge = 1e-9 * np.trace(gram, axis1=1, axis2=2) / gram.shape[1]
    core_gram = gram[:, :core, :core] + ridge[:, None, None] * np.eye(core)
    along = gram[:, :, :core]  # (N, k, c)
    solved = np.linalg.solve(core_gram[:, None], along[..., None])[..., 0]
    distance = np.diagonal(gram, axis1=1, axis2=2) - np.einsum('nkc,nkc->nk', along, solved)
    distance = np.maximum(distance, 0.0)
    distance[:, :core] = -1.0  # the core first, whatever the rounding
    nearest = np.argsort(distance, axis=1, kind='stable')[:, : settings.core_patch_size - 1]
    neighbours = np.take_along_axis(ordered, nearest, axis=1)
    distance = np.take_along_axis(distance, nearest, axis=1)
    member = np.ones((ordered.shape[0], 1 + neighbours.shape[1]))
    if neighbours.shape[1] > core + 2:
        # Squared distances: the stranger factor squared. Column j + 1 of member is neighbour j.
        reference = distance[:, core + 1 : core + 2]
        member[:, core + 3 :] = distance[:, core + 2 :] <= settings.stranger**2 * reference
    moved = np.take_along_axis(gap, nearest, axis=1)
    member[:, 1:] *= moved <= settings.stranger * gap[:, core - 1 : core]
    return neighbours, member


def subspace_misses(data: np.ndarray, subspaces: LocalSubspaces, edges: np.ndarray
                    ) -> np.ndarray:
    """``(E,)`` pixels: for edge (p, q), the mean of q's distance from p's local subspace and
    p's from q's (:func:`patch_residuals`)."""
    if edges.shape[0] == 0:
        return np.zeros(0)
    mean, basis = subspaces.mean, subspaces.basis

    def miss(owner: np.ndarray, other: np.ndarray) -> np.ndarray:
        offset = data[other] - mean[owner]
        along = np.einsum('ejd,ed->ej', basis[owner], offset)
        sq = np.einsum('ed,ed->e', offset, offset) - np.einsum('ej,ej->e', along, along)
        distance: np.ndarray = np.sqrt(np.maximum(sq, 0.0))
        return distance

    p, q = edges[:, 0], edges[:, 1]
    both: np.ndarray = 0.5 * (miss(p, q) + miss(q, p))
    return both


def edge_weights(residuals: np.ndarray, scale: float, smoothness: float, separation: float,
                 contrast: float, quantile: float, stretch: np.ndarray | None = None,
                 counted: np.ndarray | None = None) -> np.ndarray:
    """Signed Potts weights ``lambda w - mu (1 - w)``, ``w = exp(-(r / (contrast u))^2)``.

    A cut edge between neighbours that move alike (``w`` near 1) costs ``smoothness``; one
    between neighbours that miss each other's subspace by many units earns up to ``separation``
    (a negative weight). The unit ``u`` is the noise level ``scale`` (px), or the ``quantile``
    quantile of all edges' misses (0.5: the median) where that is larger: most edges join
    points of one body, and their miss also holds what the noise level leaves out
    (perspective, non-rigid parts, tracker drift). ``residuals`` from :func:`patch_residuals`;
    ``contrast`` in units; ``quantile`` is ``PearlConfig.unit_quantile``; ``stretch`` (E,) >= 1
    multiplies each edge's unit (:func:`long_edge_stretch`); ``counted`` (E,) bool, if given,
    the edges whose misses the quantile is taken over (the others touch an isolated point, and
    the misses of gross outliers would otherwise set the unit of every edge).
    """
    unit: float | np.ndarray = pair_unit(residuals, scale, quantile, counted)
    if stretch is not None:
        unit = unit * stretch
    alike = np.exp(-np.square(residuals / (contrast * unit)))
    return smoothness * alike - separation * (1.0 - alike)


def pair_unit(residuals: np.ndarray, scale: float, quantile: float,
              counted: np.ndarray | None = None) -> float:
    """The unit of :func:`edge_weights`: the noise level ``scale``, or the ``quantile`` quantile
    of the misses ``residuals`` (of the edges ``counted``, if given) where that is larger."""
    sample = residuals if counted is None else residuals[counted]
    return max(scale, float(np.quantile(sample, quantile))) if sample.size else scale


def long_edge_stretch(tracks: np.ndarray, edges: np.ndarray, neighbours: np.ndarray,
                      growth: float, settings: SolverSettings | None = None,
                      measured: int | None = None) -> np.ndarray:
    """How much each edge's unit grows with its length, ``(E,)`` >= 1.

    A local subspace extrapolated far from its patch misses a point of the same body by more
    the farther it reaches (perspective across a featureless band: on Hopkins155 the misses of
    long edges within one body grow about in proportion to their length). An edge longer than
    ``growth_from`` median edge lengths (in the last frame) has its unit grown in proportion
    to its length, up to ``growth`` times (``PearlConfig.long_edge_growth``), but only if its
    two ends' neighbourhoods (each point and its ``neighbours``) are coherent: one 3-D affine
    subspace fits both together within ``coherence`` times their own fits (RMS residuals).
    Two bodies far apart on a featureless background are not, and keep the plain unit
    (ungated, such edges tied three independent bodies into one model). Of Hopkins155's edges
    longer than 4 median lengths, 90% of those within one body are coherent at the default 2
    (median ratio 1.4), and half of those between bodies are not (median 2.7).

    Parameters
    ----------
    tracks : (F, N, 2) float64, pixels
    edges : (E, 2) int
    neighbours : (N, k) int, each point's nearest image neighbours
    growth : float >= 1
    settings : SolverSettings, optional
        ``growth_from`` (6), ``coherence`` (2) and ``subspace_dim`` (3).
    measured : int >= 1, optional
        Only the first ``measured`` edges set the median length (the triangulation's own, not
        the bridges added after them: :meth:`~pearl_ros.core.neighbourhood.Neighbourhood.bridges`).

    Returns
    -------
    (E,) float64
    """
    stretch = np.ones(edges.shape[0])
    if growth <= 1.0 or edges.shape[0] == 0:
        return stretch
    settings = settings or default_solver()
    tracks = np.asarray(tracks, dtype=np.float64)
    last = tracks[-1]
    lengths = np.linalg.norm(last[edges[:, 0]] - last[edges[:, 1]], axis=1)
    median = float(np.median(lengths[:measured]))
    reach = np.clip(lengths / (settings.growth_from * max(median, 1e-12)), 1.0, growth)
    long = np.flatnonzero(reach > 1.0)
    if long.size == 0:
        return stretch
    rows = np.transpose(tracks, (1, 0, 2)).reshape(tracks.shape[1], -1)
    ends = [np.concatenate([edges[long, i : i + 1], neighbours[edges[long, i]]], axis=1)
            for i in (0, 1)]
    dim = settings.subspace_dim
    # Each end's own spread once: long edges share their ends (most run along the hull).
    points, which = np.unique(edges[long], return_inverse=True)
    alone = _spread(rows, np.concatenate([points[:, None], neighbours[points]], axis=1), dim)
    first, second = alone[which.reshape(-1, 2)].T
    own = np.sqrt(0.5 * (first**2 + second**2))
    both = _spread(rows, np.concatenate(ends, axis=1), dim)
    coherent = both <= settings.coherence * np.maximum(own, 1e-12)
    stretch[long[coherent]] = reach[long[coherent]]
    return stretch


def _spread(rows: np.ndarray, groups: np.ndarray, dim: int) -> np.ndarray:
    """RMS residual of each group of ``rows`` to its own best ``dim``-D affine subspace,
    ``(G,)``."""
    points = rows[groups]
    centred = points - points.mean(axis=1, keepdims=True)
    # The squared singular values are the eigenvalues of the smaller Gram matrix (ascending):
    # twice as fast as an SVD of these small matrices.
    if centred.shape[1] <= centred.shape[2]:
        gram = centred @ np.transpose(centred, (0, 2, 1))
    else:
        gram = np.transpose(centred, (0, 2, 1)) @ centred
    squares = np.maximum(np.linalg.eigvalsh(gram), 0.0)
    rest = squares[:, : max(squares.shape[1] - dim, 0)].sum(axis=1)
    spread: np.ndarray = np.sqrt(rest / groups.shape[1])
    return spread
