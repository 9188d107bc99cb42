"""Neighbourhoods: Delaunay edges and k nearest neighbours against brute force, and their reuse."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import Delaunay

from pearl_ros.core.config import SolverSettings
from pearl_ros.core.contrast import patch_residuals
from pearl_ros.core.errors import InputError
from pearl_ros.core.models import get_model
from pearl_ros.core.neighbourhood import delaunay_edges, nearest_neighbours, neighbourhood


def test_nearest_neighbours_match_brute_force_and_never_include_the_point_itself():
    rng = np.random.default_rng(0)
    points = rng.uniform(0, 100, (60, 2))
    points[10] = points[11]  # coincident points: the KD-tree may list either one first
    points[20] = points[21] = points[22]
    nb = nearest_neighbours(points, 5)
    assert nb.shape == (60, 5)
    dist = np.linalg.norm(points[:, None] - points[None], axis=2)
    np.fill_diagonal(dist, np.inf)
    for i in range(60):
        assert i not in nb[i]
        assert len(set(nb[i])) == 5
        # The k-th smallest distance to another point bounds every listed neighbour.
        assert dist[i, nb[i]].max() <= np.sort(dist[i])[4] + 1e-12


def test_nearest_neighbours_cap_k_at_the_other_points():
    assert nearest_neighbours(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), 10).shape == (3, 2)


def test_delaunay_edges_are_unique_sorted_pairs_linking_every_point():
    rng = np.random.default_rng(1)
    edges = delaunay_edges(rng.uniform(0, 100, (40, 2)))
    assert np.all(edges[:, 0] < edges[:, 1])
    assert len({tuple(e) for e in edges}) == len(edges)
    assert set(edges.ravel()) == set(range(40))
    # Euler: a planar triangulation of n points has at most 3n - 6 edges.
    assert len(edges) <= 3 * 40 - 6


@pytest.mark.parametrize('seed', range(4))
def test_delaunay_edges_are_the_sides_of_the_triangles_in_order(seed):
    # Oracle: every side of every triangle scipy returns, each pair once, sorted by (i, j);
    # coincident points (seed 3), which qhull drops, join nothing.
    rng = np.random.default_rng(seed)
    points = rng.uniform(0, 640, (int(rng.integers(3, 500)), 2))
    if seed == 3:
        points[1::7] = points[0]
    sides = sorted({(min(i, j), max(i, j)) for a, b, c in Delaunay(points).simplices.tolist()
                    for i, j in ((a, b), (b, c), (a, c))})
    assert delaunay_edges(points).tolist() == [list(side) for side in sides]


def test_collinear_points_fall_back_to_a_chain():
    points = np.column_stack([np.arange(6.0), 2 * np.arange(6.0)])
    edges = delaunay_edges(points[::-1])
    assert len(edges) == 5
    assert set(edges.ravel()) == set(range(6))


def test_neighbourhood_is_its_parts_over_the_last_frame():
    rng = np.random.default_rng(2)
    tracks = rng.uniform(0, 200, (6, 50, 2))
    graph = neighbourhood(tracks, core_patches=False)  # closest-moving patches, as the oracle's
    edges = delaunay_edges(tracks[-1])
    neighbours = nearest_neighbours(tracks[-1], SolverSettings().image_neighbours)
    np.testing.assert_array_equal(graph.edges, edges)
    np.testing.assert_array_equal(graph.neighbours, neighbours)
    np.testing.assert_allclose(
        graph.misses, patch_residuals(get_model('affine').data(tracks), edges, neighbours))


def test_the_same_features_a_frame_later_keep_their_edges_but_get_new_misses():
    rng = np.random.default_rng(3)
    tracks = rng.uniform(0, 200, (7, 50, 2))
    ids = np.arange(100, 150)
    before = neighbourhood(tracks[:-1], ids, core_patches=False)
    later = tracks[1:] + rng.normal(0, 5.0, tracks[1:].shape)  # enough to move some edges
    assert not np.array_equal(delaunay_edges(later[-1]), before.edges)
    after = neighbourhood(later, ids, previous=before, core_patches=False)
    assert after.edges is before.edges and after.neighbours is before.neighbours
    np.testing.assert_allclose(after.misses, patch_residuals(
        get_model('affine').data(later), before.edges, before.neighbours))
    # Other features (one id differs) get a neighbourhood of their own.
    other = neighbourhood(later, np.r_[ids[:-1], 999], previous=before)
    np.testing.assert_array_equal(other.edges, delaunay_edges(later[-1]))


def test_a_neighbourhood_of_other_points_is_refused():
    tracks = np.random.default_rng(4).uniform(0, 200, (5, 30, 2))
    graph = neighbourhood(tracks)
    with pytest.raises(InputError, match='neighbourhood'):
        graph.check(29)
    with pytest.raises(InputError, match='ids'):
        neighbourhood(tracks, np.arange(29))


@pytest.mark.parametrize('ordered', [True, False])
def test_among_finds_codes_as_isin_does_in_sorted_and_unsorted_tables(ordered):
    from pearl_ros.core.neighbourhood import _among

    rng = np.random.default_rng(int(ordered))
    known = rng.choice(10_000, 300, replace=False)
    if ordered:
        known = np.sort(known)
    codes = np.concatenate([rng.choice(known, 40), rng.integers(-5, 10_005, 200)])
    np.testing.assert_array_equal(_among(codes, known), np.isin(codes, known))
    assert not _among(codes, known[:0]).any()


def test_patches_are_drawn_around_their_cores_as_the_settings_say_and_never_over_two_frames(
        affine_scene):
    tracks, _ = affine_scene(sizes=(90, 70), frames=8, noise=0.5, seed=5)
    data = get_model('affine').data(tracks)
    default = neighbourhood(tracks)
    cores = neighbourhood(tracks, core_patches=True)
    closest = neighbourhood(tracks, settings=SolverSettings(core_patches=False))
    assert default.core_patches and not closest.core_patches
    np.testing.assert_array_equal(default.misses, cores.misses)
    np.testing.assert_allclose(closest.misses, patch_residuals(data, closest.edges,
                                                               closest.neighbours))
    assert not np.allclose(default.misses, closest.misses)
    # Over two frames (R^4) a subspace through four points ranks nothing: the same patches.
    two = tracks[[0, -1]]
    np.testing.assert_array_equal(neighbourhood(two).misses,
                                  neighbourhood(two, core_patches=False).misses)


def test_the_online_segmenter_keeps_the_closest_moving_patches(affine_scene):
    from pearl_ros.core.config import PearlConfig
    from pearl_ros.online.config import OnlineConfig
    from pearl_ros.online.segmenter import OnlineSegmenter

    # Over its windows patches drawn around their cores measured worse (docs/experiments.md).
    tracks, _ = affine_scene(sizes=(90, 70), frames=10, noise=0.5, seed=5)
    segmenter = OnlineSegmenter(PearlConfig(), OnlineConfig(budget_ms=0.0, seed=0))
    graph = segmenter._neighbourhood(tracks, np.arange(tracks.shape[1]), 'affine', None)[0]
    assert not graph.core_patches
    np.testing.assert_allclose(graph.misses, patch_residuals(
        get_model('affine').data(tracks), graph.edges, graph.neighbours))
