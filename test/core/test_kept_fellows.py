"""Two views with mismatches: a model must keep its points' fellows (``kept_fellows``).

A rigid motion keeps the image neighbours of its points from one view to the other; a
mismatch lands anywhere in the second view. Where the views hold many mismatches, a model whose
points keep no more of their nearest fellow points (of the same model) than chance does is a
model of mismatches, and its points become outliers.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pearl_ros.core import pearl
from pearl_ros.core.config import PearlConfig, SolverSettings
from pearl_ros.core.errors import InputError
from pearl_ros.core.labels import OUTLIER
from pearl_ros.core.metrics import misclassification
from pearl_ros.core.neighbourhood import kept_neighbours
from pearl_ros.datasets import adelaide

CONFIG = PearlConfig(model='fundamental')
OFF = PearlConfig(model='fundamental', solver=SolverSettings(kept_fellows=0.0))
MISMATCHES = 2  # the segment the mismatches of a scene are given in these tests


def _beyond_chance(kept: np.ndarray, k: int) -> float:
    """The share of each point's k nearest others kept from the first view to the second,
    beyond chance k / (M - 1), from ``kept`` (M,), the brute-force counts (``kept_by_sets``)."""
    m = kept.size
    chance = k / (m - 1)
    return (kept.sum() / (m * k) - chance) / (1.0 - chance)


def _search(tracks: np.ndarray, segments: np.ndarray, config: PearlConfig = CONFIG):
    """A batch two-view search whose models are ``segments`` (0..K-1), each refitted to its
    points, as a warm start makes them."""
    setting = pearl._setting(tracks, config, np.random.default_rng(0))
    return pearl._start(setting, segments, 0.0)


def _opaque_bodies(seed: int, mismatches: float) -> tuple[np.ndarray, np.ndarray]:
    """Two planar bodies (opaque surfaces: what a camera sees of an object) that turn by 0.6
    and 1.0 rad in the image, shift and grow, 0.3 px noise; a share ``mismatches`` of the
    points moved anywhere in the second view. Tracks (2, N, 2) and labels (N,)."""
    rng = np.random.default_rng(seed)
    first, second, labels = [], [], []
    for k, (size, angle) in enumerate(((110, 0.6), (90, 1.0))):
        points = rng.uniform(-70, 70, (size, 2)) + [150.0 + 320.0 * k, 240.0]
        turn = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
        centre = points.mean(axis=0)
        first.append(points)
        second.append((points - centre) @ turn.T * 1.2 + centre + rng.normal(0, 20, 2))
        labels.append(np.full(size, k))
    tracks = np.stack([np.concatenate(first), np.concatenate(second)])
    tracks += rng.normal(0, 0.3, tracks.shape)
    truth = np.concatenate(labels)
    bad = rng.random(truth.size) < mismatches
    low, high = tracks.reshape(-1, 2).min(axis=0), tracks.reshape(-1, 2).max(axis=0)
    tracks[1, bad] = rng.uniform(low, high, (int(bad.sum()), 2))
    return tracks, np.where(bad, OUTLIER, truth)


@pytest.mark.parametrize('seed', [0, 1])
def test_kept_neighbours_counts_what_a_brute_force_count_finds(two_view_scene, kept_by_sets,
                                                               seed):
    tracks, _ = two_view_scene(seed=seed, mismatches=0.4)
    kept, k = kept_neighbours(tracks, 5)
    assert k == 5
    brute = kept_by_sets(tracks, 5)
    assert np.array_equal(kept, brute)
    beyond = _beyond_chance(brute, 5)
    chance = 5 / (tracks.shape[1] - 1)
    assert (kept.mean() / 5 - chance) / (1 - chance) == pytest.approx(beyond)


@pytest.mark.parametrize('scene', ['opaque', 'seen through'])
def test_a_segment_of_mismatches_is_freed_and_the_bodies_kept(two_view_scene, kept_by_sets,
                                                              scene):
    # The bodies: planar ones, and clouds of points seen through (make_affine_scene's, turned
    # by 38 degrees between the views, which scramble many image neighbours).
    tracks, truth = (_opaque_bodies(3, 0.4) if scene == 'opaque'
                     else two_view_scene(seed=3, mismatches=0.4))
    segments = np.where(truth == OUTLIER, MISMATCHES, truth)
    search = _search(tracks, segments)
    assert search.setting.views is not None  # the scene holds mismatches enough
    before = search.labels.copy()
    assert np.unique(before[before != pearl.OUTLIER_ROW]).size == 3
    # The oracle: each segment's share kept beyond chance, by brute force.
    beyond = {label: _beyond_chance(kept_by_sets(tracks[:, segments == label], pearl.FELLOWS),
                                    pearl.FELLOWS)
              for label in range(3)}
    assert beyond[MISMATCHES] < SolverSettings().kept_fellows < min(beyond[0], beyond[1])
    assert pearl._drop_scattered(search) == 1
    freed = truth == OUTLIER
    assert np.all(search.labels[freed] == pearl.OUTLIER_ROW)
    assert np.array_equal(search.labels[~freed], before[~freed])


def test_no_model_is_tested_without_mismatches_or_with_the_test_off(two_view_scene):
    tracks, truth = two_view_scene(seed=3, mismatches=0.4)
    segments = np.where(truth == OUTLIER, MISMATCHES, truth)
    search = _search(tracks, segments, OFF)
    assert search.setting.views is None
    assert pearl._drop_scattered(search) == 0
    clean, clean_truth = _opaque_bodies(3, 0.0)
    assert _search(clean, clean_truth).setting.views is None


def test_small_models_are_not_tested(two_view_scene):
    # A model of FELLOWS + 1 points: each point's fellows are all the others, whatever it is.
    tracks, truth = two_view_scene(seed=3, mismatches=0.4)
    segments = np.where(truth == OUTLIER, MISMATCHES, truth)
    search = _search(tracks, segments)
    few = np.flatnonzero(search.labels == MISMATCHES + 1)[pearl.FELLOWS + 1:]
    search.labels[few] = pearl.OUTLIER_ROW
    assert np.count_nonzero(search.labels == MISMATCHES + 1) == pearl.FELLOWS + 1
    assert pearl._drop_scattered(search) == 0


def test_mismatch_heavy_scenes_no_worse_with_the_test(two_view_scene):
    # Synthetic two-view scenes (seen-through clouds) at 50% and 60% mismatches, seeds 0-3:
    # where a model of mismatches forms, its points go back to the outlier label.
    errors, plain = [], []
    for seed in range(4):
        for share in (0.5, 0.6):
            tracks, truth = two_view_scene(seed=seed, mismatches=share)
            errors.append(misclassification(pearl.fit(tracks, CONFIG, rng=seed).labels, truth))
            plain.append(misclassification(pearl.fit(tracks, OFF, rng=seed).labels, truth))
    assert np.mean(errors) <= np.mean(plain) + 1e-9


def test_game_has_no_model_of_mismatches(adelaidermf_root: Path) -> None:
    # Real data with ground truth: AdelaideRMF's `game`, 73% mismatches. Without the test, and
    # without the bridges across the isolated mismatches (bridge_isolated), which alone keep
    # such a model from forming on these seeds, a model of mismatches forms beside its
    # structure on most seeds (0, 3, 5, 7, 8, 10, 11 of 0-11); with the test none holds mostly
    # mismatches.
    pair = adelaide.load_pair(adelaidermf_root / 'game.mat')
    unbridged = PearlConfig(model='fundamental',
                            solver=SolverSettings(kept_fellows=0.0, bridge_isolated=False))
    mostly_bad = {}
    for config in (CONFIG, unbridged):
        for seed in (0, 3):
            labels = pearl.fit(pair.tracks, config, rng=seed).labels
            mostly_bad[config is CONFIG, seed] = any(
                np.mean(pair.labels[labels == m] == OUTLIER) > 0.5
                for m in np.unique(labels[labels != OUTLIER]))
    assert not mostly_bad[True, 0] and not mostly_bad[True, 3]
    assert mostly_bad[False, 0] or mostly_bad[False, 3]


def test_kept_fellows_is_a_share():
    with pytest.raises(InputError, match='kept_fellows'):
        SolverSettings(kept_fellows=-0.1)
