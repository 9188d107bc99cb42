"""Two views with mismatches: the points around isolated ones are bridged.

Over two frames a local subspace is one constraint in R^4, so isolated points may be a sparse
body's own, and a batch two-frame fit leaves them unbridged. Where the views hold many
mismatches (``SolverSettings.joint_neighbours``) the isolation test reads patches drawn on both
views' coordinates, where the mismatches stand apart; there the points around the isolated ones
are joined by the edges of a Delaunay triangulation without them (``bridge_isolated``), as over
three frames or more. Without the bridges the mismatches, half the points or more, lie among a
structure's points in the second view and their edges cut the structure's ties apart.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pearl_ros.core import pearl
from pearl_ros.core.config import PearlConfig, SolverSettings
from pearl_ros.core.labels import OUTLIER
from pearl_ros.core.neighbourhood import neighbourhood
from pearl_ros.datasets import adelaide

CONFIG = PearlConfig(model='fundamental')
UNBRIDGED = PearlConfig(model='fundamental', solver=SolverSettings(bridge_isolated=False))


@pytest.mark.parametrize('seed', [0, 3])
def test_bridges_join_the_points_of_one_structure_across_the_mismatches(two_view_scene, seed):
    tracks, truth = two_view_scene(seed, mismatches=0.5)
    bridged = pearl._setting(tracks, CONFIG, np.random.default_rng(0))
    plain = pearl._setting(tracks, UNBRIDGED, np.random.default_rng(0))
    assert bridged.views is not None  # the views hold mismatches enough
    count = plain.edges.shape[0]
    assert count == neighbourhood(tracks, settings=CONFIG.solver).edges.shape[0]
    np.testing.assert_array_equal(bridged.edges[:count], plain.edges)
    np.testing.assert_allclose(bridged.weights[:count], plain.weights)
    added = bridged.edges[count:]
    assert added.shape[0] > 0
    # A bridge joins two points not isolated, most of them true points of one structure, and
    # ties them; the isolated points are the mismatches, told apart on both views.
    isolated = bridged.outlier_cost < bridged.outlier_cost.max()
    bad = truth == OUTLIER
    assert np.mean(isolated[bad]) > 0.5 and np.mean(isolated[~bad]) < 0.1
    assert not isolated[added].any()
    true_pairs = ~bad[added].any(axis=1)
    same = true_pairs & (truth[added[:, 0]] == truth[added[:, 1]])
    assert same.sum() > 0.8 * true_pairs.sum() > 0
    assert np.mean(bridged.weights[count:][same] > 0) > 0.8
    # A structure's points keep more ties among themselves than without the bridges.
    def ties(setting: pearl._Setting) -> float:
        ends = setting.edges
        within = ~bad[ends].any(axis=1) & (truth[ends[:, 0]] == truth[ends[:, 1]])
        return float(np.clip(setting.weights[within], 0.0, None).sum())
    assert ties(bridged) > 1.1 * ties(plain)


def test_clean_views_are_not_bridged(two_view_scene):
    tracks, _ = two_view_scene(0, mismatches=0.0)
    setting = pearl._setting(tracks, CONFIG, np.random.default_rng(0))
    assert setting.views is None
    assert setting.edges.shape == neighbourhood(tracks, settings=CONFIG.solver).edges.shape


@pytest.mark.parametrize('name', ['carchipscube', 'cubebreadtoychips'])
def test_adelaide_pairs_keep_every_structure_with_the_bridges(adelaidermf_root: Path,
                                                              name: str) -> None:
    # Real data with ground truth: without the bridges one structure of each is merged or lost
    # (seed 0: two of three, three of four), with them every structure has its own model.
    pair = adelaide.load_pair(adelaidermf_root / f'{name}.mat')
    found = {}
    for config in (CONFIG, UNBRIDGED):
        labels = pearl.fit(pair.tracks, config, rng=0).labels
        found[config is CONFIG] = np.unique(labels[labels != OUTLIER]).size
    assert found[True] == pair.num_motions
    assert found[False] < pair.num_motions
