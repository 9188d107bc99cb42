"""Local-subspace misses between image neighbours, and the signed Potts weights made of them."""

from __future__ import annotations

import numpy as np
import pytest

from pearl_ros.core.config import SolverSettings
from pearl_ros.core.contrast import (
    _core_patches,
    edge_weights,
    long_edge_stretch,
    patch_residuals,
)
from pearl_ros.core.models import get_model
from pearl_ros.core.neighbourhood import delaunay_edges, nearest_neighbours, neighbourhood


def misses(tracks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    edges = delaunay_edges(tracks[-1])
    data = get_model('affine').data(tracks)
    return edges, patch_residuals(data, edges, nearest_neighbours(tracks[-1], 10))


@pytest.mark.parametrize('frames', [slice(None), [0, -1]])
def test_neighbours_on_one_rigid_body_miss_nothing(affine_scene, frames):
    # Noise-free trajectories of one rigid body lie in one 3-D affine subspace, and so do those
    # of every patch of it (with two frames: one affine epipolar constraint).
    tracks, _ = affine_scene(sizes=(150,), noise=0.0, seed=1)
    _, miss = misses(tracks[frames])
    assert miss.max() < 1e-4  # px: rounding of a difference of squares


@pytest.mark.parametrize('frames', [slice(None), [0, -1]])
def test_neighbours_on_two_bodies_miss_by_their_relative_motion(affine_scene, frames):
    tracks, truth = affine_scene(sizes=(150, 150), noise=0.0, seed=2)
    edges, miss = misses(tracks[frames])
    cross = truth[edges[:, 0]] != truth[edges[:, 1]]
    assert cross.sum() >= 5
    assert miss[~cross].max() < 1e-4
    assert miss[cross].min() > 0.5  # px per frame


def test_few_points_and_no_edges_give_finite_misses():
    tracks = np.random.default_rng(0).uniform(0, 100, (5, 4, 2))
    edges, miss = misses(tracks)
    assert edges.shape[0] > 0 and np.all(miss < 1e-6)  # 4 points: the subspace holds them all
    assert patch_residuals(np.zeros((1, 10)), np.empty((0, 2), dtype=np.int64),
                           np.empty((1, 0), dtype=np.int64)).shape == (0,)


def test_weights_run_from_the_smoothness_to_minus_the_separation():
    smooth, sep, contrast = 256.0, 50.0, 10.0
    miss = np.array([0.0, 10.0, 1e6, 1.0, 1.0])  # median 1.0
    weights = edge_weights(miss, 0.5, smooth, sep, contrast, 0.5)
    alike = np.exp(-1.0)  # the miss at contrast x unit, unit = max(0.5, median 1.0) = 1.0
    assert weights[0] == pytest.approx(smooth)
    assert weights[1] == pytest.approx(smooth * alike - sep * (1 - alike))
    assert weights[2] == pytest.approx(-sep)
    # A noise level above the median miss is the unit instead.
    assert edge_weights(miss, 2.0, smooth, sep, contrast, 0.5)[1] == pytest.approx(
        smooth * np.exp(-0.25) - sep * (1 - np.exp(-0.25)))


def test_the_unit_is_the_given_quantile_of_the_misses():
    smooth, sep, contrast = 256.0, 50.0, 10.0
    # Eleven misses: the 0.6 quantile is the 7th smallest (7.0), the median the 6th (6.0).
    miss = np.array([70.0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10])
    for quantile, unit in ((0.6, 7.0), (0.5, 6.0)):
        alike = np.exp(-np.square(70.0 / (contrast * unit)))
        weights = edge_weights(miss, 0.5, smooth, sep, contrast, quantile)
        assert weights[0] == pytest.approx(smooth * alike - sep * (1 - alike))


def crowded_corner(frames: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Point 0 of body A has only 3 body-A points among its 10 nearest: the other 7 belong to a
    denser body B around it, moving otherwise. Point 4, far off, sits among body-A points only.
    Noise-free orthographic views; returns tracks (F, N, 2) and the body (0 = A, 1 = B)."""
    rng = np.random.default_rng(3)
    corner = np.array([[0.0, 0.0], [4.0, 0.0], [0.0, 4.0], [4.0, 4.0]])
    far = np.array([100.0, 0.0]) + rng.uniform(-6, 6, (11, 2))
    crowd = rng.uniform(-2.5, 2.5, (7, 2)) + [2.0, 2.0]
    image = np.vstack([corner, far, crowd])
    depth = rng.uniform(-20, 20, image.shape[0])
    body = np.repeat([0, 1], [15, 7])
    tracks = []
    for t in range(frames):
        points = []
        for k, (angle, shift) in enumerate([(0.03, [1.0, 0.5]), (-0.08, [-3.0, 2.0])]):
            c, s = np.cos(angle * t), np.sin(angle * t)
            on = body == k
            world = np.column_stack([image[on], depth[on]])
            turned = world @ np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]).T
            points.append(turned[:, :2] + np.multiply(shift, t))
        tracks.append(np.vstack(points))
    return np.stack(tracks), body


def test_a_denser_body_around_a_point_does_not_take_over_its_patch():
    tracks, body = crowded_corner()
    data = get_model('affine').data(tracks)
    neighbours = nearest_neighbours(tracks[-1], 10)
    assert np.count_nonzero(body[neighbours[0]] == 0) == 3  # the scene is as described
    edge = np.array([[0, 4]])  # two points of body A, far apart
    # Point 0's patch is itself and its 3 body-A neighbours, whose subspace is body A's: the
    # far point lies in it, as point 0 lies in the far point's.
    assert patch_residuals(data, edge, neighbours)[0] < 1e-4
    # Filled up to 8 points with the closest-moving of body B, the patch spans both motions and
    # misses the far point of its own body.
    assert patch_residuals(data, edge, neighbours, SolverSettings(stranger=np.inf))[0] > 0.1


def _core_patches_by_least_squares(data, ordered, gap, settings):
    """One point at a time: each neighbour's distance to the affine subspace through the point
    and its core, by least squares; the nearest first, then the stranger rules."""
    core, size = settings.patch_core - 1, settings.core_patch_size
    patches, members = [], []
    for p in range(data.shape[0]):
        basis = (data[ordered[p, :core]] - data[p]).T  # (D, core)
        offsets = (data[ordered[p]] - data[p]).T  # (D, k)
        coef = np.linalg.lstsq(basis, offsets, rcond=None)[0]
        distance = np.sum(np.square(offsets - basis @ coef), axis=0)
        distance[:core] = -1.0
        order = np.argsort(distance, kind='stable')[: size - 1]
        kept = [True] * (1 + core + 2)
        reference = distance[order[core + 1]]
        kept += [bool(d <= settings.stranger**2 * reference) for d in distance[order[core + 2:]]]
        kept = [kept[0]] + [k and bool(gap[p, j] <= settings.stranger * gap[p, core - 1])
                            for k, j in zip(kept[1:], order, strict=True)]
        patches.append(ordered[p, order])
        members.append(kept)
    return np.array(patches), np.array(members, dtype=float)


@pytest.mark.parametrize('seed', range(4))
def test_core_patches_match_a_per_point_least_squares(seed):
    rng = np.random.default_rng(seed)
    tracks = rng.normal(0.0, 20.0, (6, 40, 2))
    data = get_model('affine').data(tracks)
    ordered = nearest_neighbours(tracks[-1], 10)
    # Motion gaps, ascending along each row as local_subspaces orders them (values as given).
    gap = np.sort(rng.uniform(0.0, 10.0, ordered.shape), axis=1)
    settings = SolverSettings()
    got = _core_patches(data, ordered, gap, settings)
    want = _core_patches_by_least_squares(data, ordered, gap, settings)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])


def test_a_patch_drawn_around_its_core_ranks_a_dependent_body_last():
    # Body A turns and translates; body B, among its points, translates as A does on average,
    # so that B's points are often closer-moving to A's than A's own (dependent motions),
    # though off A's 3-D affine subspace. Noise-free orthographic views.
    rng = np.random.default_rng(5)
    image_a = rng.uniform(0, 20, (12, 2))
    image_b = rng.uniform(0, 20, (8, 2)) + 10.0
    depth = rng.uniform(-30, 30, 12)
    tracks = []
    for t in range(10):
        c, s = np.cos(0.02 * t), np.sin(0.02 * t)
        turned = np.column_stack([image_a, depth]) @ np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]).T
        a = turned[:, :2] + [0.5 * t, 0.2 * t]
        tracks.append(np.vstack([a, image_b + np.mean(a - image_a, axis=0)]))
    tracks = np.stack(tracks)
    body = np.repeat([0, 1], [12, 8])
    data = get_model('affine').data(tracks)
    neighbours = nearest_neighbours(tracks[-1], 10)
    # Closest-moving order: trajectories less their mean position, nearest first.
    moves = data.reshape(20, -1, 2) - data.reshape(20, -1, 2).mean(axis=1, keepdims=True)
    moves = moves.reshape(20, -1)
    gap = np.linalg.norm(moves[neighbours] - moves[:, None, :], axis=2)
    by_gap = np.argsort(gap, axis=1, kind='stable')
    ordered = np.take_along_axis(neighbours, by_gap, axis=1)
    gap = np.take_along_axis(gap, by_gap, axis=1)
    patches = _core_patches(data, ordered, gap, SolverSettings())[0]
    pure = [p for p in np.flatnonzero(body == 0) if np.all(body[ordered[p, :3]] == 0)]
    assert len(pure) >= 6
    mixed = 0
    for p in pure:
        # Around a core of A, every A neighbour ranks before every B one.
        ranks = body[patches[p]]
        assert not np.any(np.diff(ranks) < 0)
        mixed += int(np.any(np.diff(body[ordered[p]]) < 0))
    # By motion alone, B points come before A's own in some of those patches.
    assert mixed >= 2


def test_a_stretched_edge_measures_its_miss_in_a_larger_unit():
    smooth, sep, contrast = 256.0, 50.0, 10.0
    miss = np.array([20.0, 20.0, 20.0, 1, 1, 1, 1, 1, 1, 1, 1])  # median 1.0: the unit

    def weight(unit: float) -> float:
        alike = np.exp(-np.square(20.0 / (contrast * unit)))
        return smooth * alike - sep * (1 - alike)

    plain = edge_weights(miss, 0.5, smooth, sep, contrast, 0.5)
    stretch = np.array([1.0, 2.0, 3.0, 1, 1, 1, 1, 1, 1, 1, 1])
    grown = edge_weights(miss, 0.5, smooth, sep, contrast, 0.5, stretch)
    assert grown[0] == pytest.approx(weight(1.0)) == pytest.approx(plain[0])
    assert grown[1] == pytest.approx(weight(2.0))
    assert grown[2] == pytest.approx(weight(3.0))
    assert np.allclose(grown[3:], plain[3:])


@pytest.mark.parametrize('same_body', [True, False])
def test_long_edges_across_a_gap_stretch_only_within_one_body(gap_scene, same_body):
    tracks, cluster = gap_scene(same_body)
    graph = neighbourhood(tracks)
    edges, neighbours = graph.edges, graph.neighbours
    across = cluster[edges[:, 0]] != cluster[edges[:, 1]]
    assert np.any(across)
    stretch = long_edge_stretch(tracks, edges, neighbours, 3.0)
    assert np.all(stretch[~across] == 1.0)  # short edges inside the clusters
    if same_body:
        assert np.all(stretch[across] > 1.0) and np.all(stretch[across] <= 3.0)
    else:
        # Two small neighbourhoods of different motions can still share a 3-D subspace nearly
        # as well as each fits its own (here one edge of nine, at 1.98 times): most do not.
        assert np.mean(stretch[across] > 1.0) <= 0.2
    assert np.all(long_edge_stretch(tracks, edges, neighbours, 1.0) == 1.0)


@pytest.mark.parametrize('size', [4, 11, 30])
def test_a_groups_spread_is_its_rms_residual_to_its_own_best_affine_subspace(size):
    # Oracle: each group's best 3-D affine subspace from an SVD of its centred rows, and the
    # RMS of the residuals; groups narrower and wider than the rows' dimension (20). A group of
    # 4 spans its subspace exactly: zero, up to the square root of the Gram matrix's rounding
    # (1e-7 of rows some 10 long), far below any noise level.
    from pearl_ros.core.contrast import _spread

    rng = np.random.default_rng(size)
    rows = rng.normal(size=(50, 20)) * rng.uniform(0.1, 10.0, 20)
    groups = np.stack([rng.choice(50, size, replace=False) for _ in range(7)])
    for group, spread in zip(groups, _spread(rows, groups, 3), strict=True):
        centred = rows[group] - rows[group].mean(axis=0)
        _, _, vt = np.linalg.svd(centred, full_matrices=False)
        residual = centred - centred @ vt[:3].T @ vt[:3]
        assert spread == pytest.approx(np.sqrt(np.sum(residual**2) / size), rel=1e-9, abs=1e-6)
