"""Outliers on their own: isolated points, the bridges around them, and the pairs an outlier
keeps apart.

``SolverSettings.isolation`` gives a point that moves unlike every neighbour the outlier cost of
a uniform density over the image; ``SolverSettings.outlier_apart`` lets an outlier earn the
reward of every pair that moves apart, whatever its neighbour's label.
"""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest
from scipy.spatial import Delaunay

from pearl_ros.core import pearl
from pearl_ros.core.config import PearlConfig, SolverSettings
from pearl_ros.core.contrast import patch_residuals
from pearl_ros.core.energy import Problem, energy
from pearl_ros.core.labels import OUTLIER
from pearl_ros.core.metrics import misclassification
from pearl_ros.core.models import get_model
from pearl_ros.core.neighbourhood import neighbourhood
from pearl_ros.datasets.hopkins import load_sequence, sequence_names
from pearl_ros.datasets.outliers import add_outlier_tracks


def test_an_outlier_earns_the_reward_of_a_pair_that_moves_apart_whatever_its_neighbour():
    unary = np.zeros((3, 3))
    edges = np.array([[0, 1], [1, 2]])
    weights = np.array([-4.0, 6.0])  # pair 0-1 moves apart, pair 1-2 alike
    plain = Problem(unary, edges, weights, np.zeros(3), outlier_row=0)
    apart = dataclasses.replace(plain, outlier_apart=True)
    # Points 0 and 1 both outliers: plain Potts sees one label, no cut and no reward.
    assert energy(plain, np.array([0, 0, 0])) == 0.0
    assert energy(apart, np.array([0, 0, 0])) == pytest.approx(-4.0)
    # Sharing a motion forgoes the reward either way; an alike pair cut next to an outlier
    # still pays its weight.
    assert energy(apart, np.array([1, 1, 0])) == pytest.approx(6.0)
    assert energy(apart, np.array([0, 1, 1])) == pytest.approx(-4.0)
    assert energy(apart, np.array([2, 1, 1])) == pytest.approx(-4.0)


def test_isolated_points_pay_the_uniform_outlier_cost_and_leave_the_pair_unit(two_view_scene):
    tracks, truth = two_view_scene(seed=3, mismatches=0.4)
    bad = truth == OUTLIER
    config = PearlConfig(model='fundamental', solver=SolverSettings())
    setting = pearl._setting(tracks, config, np.random.default_rng(0))
    plain = pearl._setting(tracks, PearlConfig(model='fundamental',
                                               solver=SolverSettings(isolation=0.0)),
                           np.random.default_rng(0))
    # The uniform density over the larger side L of the points' bounding box, as twice its
    # negative log-likelihood per residual dimension, from the model's noise floor.
    side = np.ptp(tracks.reshape(-1, 2), axis=0).max()
    uniform = setting.dof * (2 * math.log(side / setting.floor) - math.log(2 * math.pi))
    isolated = setting.outlier_cost < plain.outlier_cost[0]
    assert np.allclose(setting.outlier_cost[isolated], uniform)
    # The others keep the threshold's cost (a residual of outlier_threshold noise scales, which
    # does not depend on the scale itself).
    assert np.allclose(setting.outlier_cost[~isolated], plain.outlier_cost[0])
    # The mismatches leave the noise scale: least squares over neighbourhoods holding them reads
    # it too high.
    assert setting.scale < plain.scale
    # Mismatches are found isolated, true matches seldom.
    assert np.mean(isolated[bad]) > 0.7
    assert np.mean(isolated[~bad]) < 0.1
    # With the mismatches' edges out of the pair unit, the unit shrinks to the true matches'
    # misses: most edges touching a mismatch now read as moving apart (a negative weight),
    # where the unit inflated by the mismatches read them as alike.
    # (The triangulation's own edges come first; bridges across the isolated points follow.)
    count = plain.edges.shape[0]
    np.testing.assert_array_equal(setting.edges[:count], plain.edges)
    touching = bad[plain.edges[:, 0]] | bad[plain.edges[:, 1]]
    weights = setting.weights[:count]
    assert np.mean(weights[touching] < 0) > 0.5
    assert np.mean(weights[touching] < 0) > np.mean(plain.weights[touching] < 0) + 0.2


def test_isolation_and_outliers_apart_find_the_motions_among_40_percent_mismatches(
        two_view_scene):
    # Eight scenes: a two-view search at 40% mismatches ends in a wrong minimum on some
    # (one of eight at 37%), so the scenes' median is judged. Scored with the mismatches as a
    # group of their own, as AdelaideRMF is.
    without = SolverSettings(isolation=0.0, outlier_apart=False)
    errors, recalls = [], []
    for seed in range(8):
        tracks, truth = two_view_scene(seed=seed, mismatches=0.4)
        bad = truth == OUTLIER
        found = pearl.fit(tracks, PearlConfig(model='fundamental'), rng=0)
        default = pearl.fit(tracks, PearlConfig(model='fundamental', solver=without), rng=0)
        errors.append(misclassification(found.labels, truth))
        assert errors[-1] < misclassification(default.labels, truth), seed
        recalls.append(np.mean(found.labels[bad] == OUTLIER))
    assert np.median(errors) < 0.1
    assert np.median(recalls) > 0.8


def test_the_online_scale_given_the_graph_is_the_scale_fit_reads(two_view_scene):
    # The online segmenter estimates the scale with noise_scale and passes it on: given the
    # same neighbourhood, it must leave out the same isolated points fit does.
    tracks, _ = two_view_scene(seed=5, mismatches=0.4)
    config = PearlConfig(model='fundamental')
    graph = neighbourhood(tracks, settings=config.solver)
    setting = pearl._setting(tracks, config, np.random.default_rng(0), graph)
    assert pearl.noise_scale(tracks, config, 0, graph) == setting.scale
    assert pearl.noise_scale(tracks, config, 0) > setting.scale



def _delaunay_pairs(points: np.ndarray) -> set[tuple[int, int]]:
    """Every pair of points that share a Delaunay triangle (scipy, read from the simplices)."""
    pairs = set()
    for a, b, c in Delaunay(points).simplices.tolist():
        for i, j in ((a, b), (b, c), (a, c)):
            pairs.add((min(i, j), max(i, j)))
    return pairs


def _walk_scene(affine_scene, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Two rigid bodies over 10 frames with 20% random-walk outlier tracks of 10 px steps
    (truth -1): about two fifths of the walks are isolated (patches drawn around their cores;
    about half with the closest-moving patches)."""
    tracks, truth = affine_scene(sizes=(90, 70), frames=10, noise=0.3, seed=seed)
    return add_outlier_tracks(tracks, truth, 0.2, rng=seed, step=10.0)


def test_bridges_are_the_new_edges_of_a_triangulation_without_the_isolated_points(affine_scene):
    tracks, _ = _walk_scene(affine_scene, seed=1)
    graph = neighbourhood(tracks, core_patches=False)  # closest-moving, as patch_residuals
    isolated = np.random.default_rng(2).random(tracks.shape[1]) < 0.25
    bridges, misses = graph.bridges(tracks, isolated)

    others = np.flatnonzero(~isolated)
    expected = {(int(others[i]), int(others[j])) for i, j in _delaunay_pairs(tracks[-1][others])}
    expected -= {tuple(edge) for edge in graph.edges.tolist()}
    assert expected and {tuple(edge) for edge in bridges.tolist()} == expected
    assert not isolated[bridges].any()
    np.testing.assert_allclose(misses, patch_residuals(get_model('affine').data(tracks), bridges,
                                                       graph.neighbours))
    # None isolated, or all: nothing to bridge.
    assert graph.bridges(tracks, np.zeros(tracks.shape[1], bool))[0].shape == (0, 2)
    assert graph.bridges(tracks, np.ones(tracks.shape[1], bool))[0].shape == (0, 2)


@pytest.mark.parametrize('seed', range(6))
def test_bridges_read_from_the_cavity_are_those_of_a_whole_new_triangulation(seed):
    # The bridges come from re-triangulating only the cavity the isolated points leave; the
    # oracle triangulates every other point anew. Isolated points alone, in clusters, at the
    # hull and most of the points; tracks jittered so that the last frame differs.
    rng = np.random.default_rng(seed)
    n = int(rng.integers(40, 400))
    last = rng.uniform(0, 640, (n, 2))
    tracks = np.stack([last + rng.normal(0, 2, (n, 2)) for _ in range(4)] + [last])
    share = (0.02, 0.1, 0.3, 0.6, 0.1, 0.3)[seed]
    isolated = rng.random(n) < share
    if seed >= 4:  # clusters: every point near an isolated centre is isolated too
        centres = last[isolated][:5]
        isolated = (np.linalg.norm(last[:, None] - centres[None], axis=2) < 60).any(axis=1)
    graph = neighbourhood(tracks)
    assert graph.triangulation is not None
    assert graph._cavity_edges(last, isolated) is not None  # read from the cavity
    bridges, misses = graph.bridges(tracks, isolated)
    others = np.flatnonzero(~isolated)
    expected = {(int(others[i]), int(others[j])) for i, j in _delaunay_pairs(last[others])}
    expected -= {tuple(edge) for edge in graph.edges.tolist()}
    assert {tuple(edge) for edge in bridges.tolist()} == expected
    plain = dataclasses.replace(graph, triangulation=None)  # the whole triangulation anew
    again, again_misses = plain.bridges(tracks, isolated)
    order = np.lexsort(bridges.T[::-1]), np.lexsort(again.T[::-1])
    np.testing.assert_array_equal(bridges[order[0]], again[order[1]])
    np.testing.assert_allclose(misses[order[0]], again_misses[order[1]])


def test_bridges_of_edges_kept_from_an_earlier_frame_triangulate_the_frame_given(affine_scene):
    # A neighbourhood reused for the same features a frame later keeps the earlier frame's
    # edges and triangulation; its bridges must still be those of the positions given.
    tracks, _ = _walk_scene(affine_scene, seed=1)
    earlier = neighbourhood(tracks[:-1], ids=np.arange(tracks.shape[1]))
    graph = neighbourhood(tracks[1:], ids=np.arange(tracks.shape[1]), previous=earlier)
    assert graph.triangulation is earlier.triangulation
    isolated = np.random.default_rng(3).random(tracks.shape[1]) < 0.2
    bridges, _ = graph.bridges(tracks[1:], isolated)
    others = np.flatnonzero(~isolated)
    expected = {(int(others[i]), int(others[j])) for i, j in _delaunay_pairs(tracks[-1][others])}
    expected -= {tuple(edge) for edge in graph.edges.tolist()}
    assert {tuple(edge) for edge in bridges.tolist()} == expected


def test_patches_drawn_again_take_their_points_from_those_not_isolated(affine_scene):
    tracks, _ = _walk_scene(affine_scene, seed=2)
    graph = neighbourhood(tracks, core_patches=False)  # closest-moving, as patch_residuals
    left = np.random.default_rng(4).random(tracks.shape[1]) < 0.25
    again = graph.without(tracks, left)
    # Oracle: each point's k nearest image neighbours among the points not left out, by
    # sorting every distance in the last frame.
    last = tracks[-1]
    k = graph.neighbours.shape[1]
    others = np.flatnonzero(~left)
    for p in range(tracks.shape[1]):
        candidates = others[others != p]
        distance = np.linalg.norm(last[candidates] - last[p], axis=1)
        assert set(again.neighbours[p].tolist()) == set(candidates[np.argsort(distance)[:k]])
    assert not left[again.neighbours].any()
    np.testing.assert_array_equal(again.edges, graph.edges)
    np.testing.assert_allclose(again.misses, patch_residuals(get_model('affine').data(tracks),
                                                             graph.edges, again.neighbours))
    assert not np.allclose(again.misses, graph.misses)


def test_batch_fits_draw_patches_again_and_the_online_segmenter_keeps_its_own(affine_scene):
    from pearl_ros.online.config import OnlineConfig
    from pearl_ros.online.segmenter import OnlineSegmenter

    tracks, truth = _walk_scene(affine_scene, seed=3)
    drawn = pearl._setting(tracks, PearlConfig(), np.random.default_rng(0))
    kept = pearl._setting(tracks, PearlConfig(solver=SolverSettings(redraw_isolated=False)),
                          np.random.default_rng(0))
    isolated = drawn.outlier_cost < drawn.outlier_cost.max()
    walks = truth == OUTLIER
    assert isolated[walks].any()
    assert not isolated[drawn.neighbours].any() and isolated[kept.neighbours].any()
    own = neighbourhood(tracks).edges.shape[0]  # the triangulation's edges, then bridges
    assert not np.allclose(drawn.weights[:own], kept.weights[:own])
    # Frame by frame the same tracks give the same labels whatever the setting: a stream's
    # isolated points change from frame to frame, and its patches stay as drawn.
    ids = np.arange(tracks.shape[1])
    labels = []
    for redraw in (True, False):
        config = PearlConfig(solver=SolverSettings(redraw_isolated=redraw))
        segmenter = OnlineSegmenter(config, OnlineConfig(budget_ms=0.0, seed=0))
        labels.append([segmenter.process(1_000_000_000 + 33_000_000 * t, ids, tracks[t]).labels
                       for t in range(tracks.shape[0])])
    np.testing.assert_array_equal(np.array(labels[0]), np.array(labels[1]))


def test_points_isolated_on_patches_that_held_walks_are_released_once_drawn_again(affine_scene):
    # Walks isolated by the first test, and true points taken for isolated as the first test
    # takes a true point whose patch held walks: drawn among the others, their patches hold
    # them within the noise again, while the walks stay isolated (all but two near the
    # threshold, here).
    tracks, truth = _walk_scene(affine_scene, seed=3)
    walks = truth == OUTLIER
    setting = pearl._setting(tracks, PearlConfig(), np.random.default_rng(0))
    solver = SolverSettings()
    graph = neighbourhood(tracks, settings=solver)
    floor = solver.isolation_floor * setting.scale
    nearest = graph.nearest_miss()
    found = pearl._suspects(nearest, solver.isolation) & (nearest > floor)
    assert found[walks].sum() >= 5 and not found[~walks].any()
    taken = np.random.default_rng(1).choice(np.flatnonzero(~walks), 6, replace=False)
    isolated = found.copy()
    isolated[taken] = True

    redrawn, still = pearl._redrawn(graph, tracks, isolated, solver, floor, None)

    assert not still[taken].any() and not still[~walks].any()
    assert still[walks].sum() >= 0.8 * found[walks].sum()
    assert not (still & ~isolated).any()
    assert not still[redrawn.neighbours].any()
    np.testing.assert_allclose(redrawn.misses, graph.without(tracks, still, solver).misses)


def test_bridges_join_the_points_around_outlier_walks_and_leave_the_other_ties_as_they_were(
        affine_scene):
    tracks, truth = _walk_scene(affine_scene, seed=3)
    rng = np.random.default_rng(0)
    bridged = pearl._setting(tracks, PearlConfig(), rng)
    plain = pearl._setting(tracks, PearlConfig(solver=SolverSettings(bridge_isolated=False)),
                           np.random.default_rng(0))
    walks = truth == OUTLIER
    isolated = bridged.outlier_cost < bridged.outlier_cost.max()
    assert np.mean(isolated[walks]) > 0.25 and not isolated[~walks].any()
    count = plain.edges.shape[0]
    np.testing.assert_array_equal(bridged.edges[:count], plain.edges)
    assert bridged.edges.shape[0] > count
    # Bridges join points that are not isolated; those between true points join mostly points
    # of one body, and tie them. The triangulation's own edges keep their weights (the unit
    # and the long-edge median are read over those alone).
    added = bridged.edges[count:]
    assert not isolated[added].any()
    true_pairs = ~walks[added].any(axis=1)
    same = true_pairs & (truth[added[:, 0]] == truth[added[:, 1]])
    assert same.sum() > 0.8 * true_pairs.sum() > 0
    np.testing.assert_allclose(bridged.weights[:count], plain.weights)
    assert np.mean(bridged.weights[count:][same] > 0) > 0.9  # ties, not rewards
    # Over two frames nothing is bridged, a local subspace there isolates true points too, but
    # where the views hold mismatches (joint_neighbours): the walks, seen at their ends, are
    # such mismatches, told apart on both views' coordinates.
    two = tracks[[0, -1]]
    config = PearlConfig(model='fundamental')
    drawn = neighbourhood(two, settings=config.solver).edges.shape[0]
    assert pearl._setting(two, config, np.random.default_rng(0)).edges.shape[0] > drawn
    single = PearlConfig(model='fundamental', solver=SolverSettings(joint_neighbours=0.0))
    assert pearl._setting(two, single, np.random.default_rng(0)).edges.shape[0] == drawn


@pytest.mark.parametrize('setting', ['bridge_isolated', 'redraw_isolated'])
def test_bridges_and_patches_drawn_again_lower_the_error_of_true_points_among_walks(
        hopkins_root, setting):
    # Real data with ground truth: every fifth sequence, 20% random-walk outlier tracks (the
    # robot-data benchmark's set), true points scored on their own; each of the two with the
    # other at its default. Two draws of the walks: on one alone, patches drawn again gain a
    # third of a point (4.54 against 4.87%), on the other 2.6 points.
    names = sequence_names(hopkins_root)[::5]
    errors: dict[bool, list[float]] = {True: [], False: []}
    for draw, (index, name) in itertools.product((0, 1000), enumerate(names)):
        sequence = load_sequence(hopkins_root, name)
        tracks, truth = add_outlier_tracks(sequence.tracks, sequence.labels, 0.2,
                                           rng=index + draw)
        true_points = truth != OUTLIER
        for on in (True, False):
            config = PearlConfig(solver=SolverSettings(**{setting: on}))
            labels = pearl.fit(tracks, config, rng=index + draw).labels
            errors[on].append(misclassification(labels[true_points], truth[true_points]))
    assert np.mean(errors[True]) < np.mean(errors[False]) - 0.005


def test_true_points_isolated_on_patches_that_held_walks_are_released_and_no_walk_is(
        hopkins_root):
    # Real data with ground truth: every fifth sequence with 20% random-walk outlier tracks.
    # Judged again on the patches drawn without them, a seventh of the true points the first
    # test isolated are released (106 -> 91 when measured; 112 -> 88 with the closest-moving
    # patches), and every walk stays isolated.
    names = sequence_names(hopkins_root)[::5]
    counts = np.zeros(4, dtype=int)  # true points isolated first / after, walks first / after
    for index, name in enumerate(names):
        sequence = load_sequence(hopkins_root, name)
        tracks, truth = add_outlier_tracks(sequence.tracks, sequence.labels, 0.2, rng=index)
        walks = truth == OUTLIER
        found = []
        for redraw in (False, True):
            config = PearlConfig(solver=SolverSettings(redraw_isolated=redraw))
            setting = pearl._setting(tracks, config, np.random.default_rng(index))
            found.append(setting.outlier_cost < setting.outlier_cost.max())
        counts += [found[0][~walks].sum(), found[1][~walks].sum(), found[0][walks].sum(),
                   found[1][walks].sum()]
        assert not (found[1] & ~found[0]).any()
    assert counts[1] < 0.9 * counts[0]
    assert counts[3] == counts[2] > 0.5 * len(names) * 20
