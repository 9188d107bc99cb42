"""Misclassification rate against a brute-force oracle over every one-to-one label matching;
label identity over a stream against switches counted by hand."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from pearl_ros.core.errors import InputError
from pearl_ros.core.metrics import (
    LabelIdentity,
    contingency,
    match_labels,
    misclassification,
    relabel_to_truth,
)


def brute_force_misclassification(pred: list[int], truth: list[int]) -> float:
    """Try every injective pairing of predicted labels with true labels, point by point."""
    pred_groups = sorted({p for p in pred if p != -1})
    true_groups = sorted({t for t in truth if t != -1})
    best = 0
    if len(pred_groups) <= len(true_groups):
        pairings = (
            dict(zip(pred_groups, image, strict=True))
            for image in itertools.permutations(true_groups, len(pred_groups))
        )
    else:
        pairings = (
            dict(zip(chosen, true_groups, strict=True))
            for chosen in itertools.permutations(pred_groups, len(true_groups))
        )
    for pairing in pairings:
        right = 0
        for p, t in zip(pred, truth, strict=True):
            if p == -1:
                right += t == -1
            else:
                right += pairing.get(p) == t
        best = max(best, right)
    return 1.0 - best / len(pred)


def test_misclassification_matches_brute_force_on_random_labelings():
    rng = np.random.default_rng(20120601)
    for _ in range(400):
        n = int(rng.integers(1, 25))
        k_true = int(rng.integers(1, 5))
        k_pred = int(rng.integers(1, 6))
        truth = rng.integers(0, k_true, size=n)
        # Predicted labels need not be 0..k-1: spread them out, and make some outliers.
        pred = rng.choice(np.array([0, 3, 7, 8, 11, 20])[:k_pred], size=n)
        pred[rng.random(n) < 0.15] = -1
        if rng.random() < 0.2:
            truth[rng.random(n) < 0.2] = -1
        expected = brute_force_misclassification(pred.tolist(), truth.tolist())
        assert misclassification(pred, truth) == pytest.approx(expected, abs=1e-12)


def test_perfect_prediction_with_renamed_labels_has_no_error():
    truth = np.array([0, 0, 1, 1, 1, 2, 2, 0])
    renamed = np.array([5, 2, 9])[truth]
    assert misclassification(renamed, truth) == 0.0


def test_outliers_of_true_groups_count_as_wrong():
    truth = np.array([0, 0, 0, 0, 1, 1, 1, 1])
    pred = np.array([0, 0, -1, 0, 1, -1, 1, 1])
    assert misclassification(pred, truth) == pytest.approx(2 / 8)


def test_all_outliers_are_all_wrong():
    assert misclassification(np.full(6, -1), np.array([0, 0, 0, 1, 1, 1])) == 1.0


def test_outlier_called_outlier_is_right():
    truth = np.array([0, 0, 1, 1, -1, -1])
    pred = np.array([4, 4, 2, 2, -1, 4])
    assert misclassification(pred, truth) == pytest.approx(1 / 6)


def test_predicted_groups_beyond_the_true_number_count_as_wrong():
    # Group 1 is split in two: the smaller half has no partner left.
    truth = np.array([0, 0, 0, 0, 1, 1, 1, 1, 1, 1])
    pred = np.array([0, 0, 0, 0, 1, 1, 1, 1, 2, 2])
    assert misclassification(pred, truth) == pytest.approx(2 / 10)


def test_fewer_predicted_groups_leave_a_true_group_wrong():
    truth = np.array([0, 0, 0, 1, 1, 2, 2, 2, 2])
    pred = np.zeros(9, dtype=int)
    assert misclassification(pred, truth) == pytest.approx(5 / 9)


def test_matching_is_one_to_one_not_majority_vote():
    # Majority vote would send both predicted groups to true group 0 and score 0 errors.
    truth = np.array([0, 0, 0, 0, 0, 0, 1, 1])
    pred = np.array([0, 0, 0, 1, 1, 1, 1, 1])
    assert misclassification(pred, truth) == pytest.approx(3 / 8)


def test_contingency_counts_pairs_and_drops_outliers():
    pred = np.array([7, 7, 3, 3, 3, -1])
    truth = np.array([0, 1, 1, 1, 0, 0])
    table, pred_labels, true_labels = contingency(pred, truth)
    np.testing.assert_array_equal(pred_labels, [3, 7])
    np.testing.assert_array_equal(true_labels, [0, 1])
    np.testing.assert_array_equal(table, [[1, 2], [1, 1]])
    assert table.dtype == np.int64


def test_match_labels_and_relabel_agree_with_the_best_matching():
    truth = np.array([0, 0, 0, 1, 1, 1, 2, 2])
    pred = np.array([4, 4, 4, 9, 9, 1, 1, -1])
    assert match_labels(pred, truth) == {4: 0, 9: 1, 1: 2}
    np.testing.assert_array_equal(relabel_to_truth(pred, truth), [0, 0, 0, 1, 1, 2, 2, -1])


def test_relabel_gives_unmatched_groups_fresh_labels():
    truth = np.array([0, 0, 1, 1, 1, 1])
    pred = np.array([5, 5, 6, 6, 8, 8])
    relabelled = relabel_to_truth(pred, truth)
    assert set(relabelled[:2]) == {0}
    assert relabelled[2] == relabelled[3] and relabelled[4] == relabelled[5]
    assert {relabelled[2], relabelled[4]} == {1, 2}


@pytest.mark.parametrize(
    ('pred', 'truth', 'message'),
    [
        (np.zeros(3, dtype=int), np.zeros(4, dtype=int), 'same points'),
        (np.zeros((2, 2), dtype=int), np.zeros(4, dtype=int), '1-D'),
        (np.zeros(3, dtype=int), np.zeros((3, 1), dtype=int), '1-D'),
        (np.array([0.5, 1.0]), np.array([0, 1]), 'integer'),
        (np.array([0, -2]), np.array([0, 1]), '>= -1'),
        (np.array([], dtype=int), np.array([], dtype=int), 'at least one'),
    ],
)
def test_bad_input_raises_input_error(pred, truth, message):
    with pytest.raises(InputError, match=message):
        misclassification(pred, truth)


def count_switches(frames):
    identity = LabelIdentity()
    for pred, truth in frames:
        identity.add(np.array(pred), np.array(truth))
    return identity


def test_identity_numbers_that_follow_their_motions_do_not_switch():
    truth = [0, 0, 0, 1, 1, 2, 2, -1]
    frames = [([5, 5, 5, 9, 9, 3, 3, 9], truth)] * 4 + [([5, 5, 9, 9, 9, 3, 3, -1], truth)]
    identity = count_switches(frames)
    assert (identity.frames, identity.switches, identity.matched) == (5, 0, 15)


def test_identity_a_motion_renumbered_switches_once_and_its_new_number_then_holds():
    truth = [0, 0, 0, 1, 1, 1]
    frames = [([0, 0, 0, 1, 1, 1], truth), ([0, 0, 0, 4, 4, 4], truth),
              ([0, 0, 0, 4, 4, 4], truth)]
    assert count_switches(frames).switches == 1
    assert count_switches(frames).switches_per_100 == pytest.approx(100 / 3)


def test_identity_a_merged_motion_is_unmatched_and_switches_only_under_a_new_number():
    # Frame 2 merges motion 1 into motion 0's number 0: the matching gives number 0 to motion
    # 0 (four points against three), so motion 1 is unmatched there, not switched.
    truth = [0, 0, 0, 0, 1, 1, 1]
    back = [([0, 0, 0, 0, 1, 1, 1], truth), ([0, 0, 0, 0, 0, 0, 0], truth),
            ([0, 0, 0, 0, 1, 1, 1], truth)]
    renumbered = back[:2] + [([0, 0, 0, 0, 2, 2, 2], truth)]
    assert count_switches(back).switches == 0
    assert count_switches(renumbered).switches == 1


def test_identity_a_motion_out_of_view_keeps_its_last_number():
    frames = [([0, 0, 1, 1], [0, 0, 1, 1]), ([0, 0], [0, 0]), ([0, 0, 7], [0, 0, 1]),
              ([0, 0, 1], [0, 0, 1])]
    # Motion 1 leaves, comes back as 7 (a switch), then is 1 again (another).
    assert count_switches(frames).switches == 2


def test_identity_ignores_outliers_and_pairs_the_matching_makes_up():
    # Three true motions, two numbers: the matching pairs every number, but motion 2's points
    # are all -1, so no number is its own; true outliers carry no identity whatever they get.
    truth = [0, 0, 1, 1, 2, 2, -1, -1]
    frames = [([3, 3, 4, 4, -1, -1, 3, 4], truth), ([3, 3, 4, 4, -1, -1, 4, 3], truth)]
    identity = count_switches(frames)
    assert (identity.switches, identity.matched) == (0, 4)


def test_identity_of_an_empty_run_is_nan_per_100_frames():
    assert np.isnan(LabelIdentity().switches_per_100)
