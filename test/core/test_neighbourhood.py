"""Neighbourhoods: Delaunay edges and k nearest neighbours against brute force."""

from __future__ import annotations

import numpy as np

from pearl_ros.core.neighbourhood import delaunay_edges, nearest_neighbours


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


def test_collinear_points_fall_back_to_a_chain():
    points = np.column_stack([np.arange(6.0), 2 * np.arange(6.0)])
    edges = delaunay_edges(points[::-1])
    assert len(edges) == 5
    assert set(edges.ravel()) == set(range(6))
