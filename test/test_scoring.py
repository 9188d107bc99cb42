"""pearl_ros.scoring on hand-counted cases (the CLI tests in test/cli/test_score.py use bags)."""

from __future__ import annotations

import numpy as np
import pytest

from pearl_ros.core.errors import InputError
from pearl_ros.scoring import GroundTruth, label_string, score_frame, summarise, summary_lines

IDS = np.array([10, 11, 12, 13])


def test_label_string_shows_every_label_or_says_how_many_it_left_out() -> None:
    labels = np.array([0, 1, -1, 10, 35, 36, 2])
    assert label_string(labels) == '01-az?2'
    assert label_string(labels, 7) == '01-az?2'
    assert label_string(labels, 3) == '01- +4 more'


def test_truth_is_looked_up_per_frame_and_merged_only_where_it_never_changes() -> None:
    steady = GroundTruth([(1, IDS, np.array([0, 0, 1, 1])), (2, IDS[:2], np.array([0, 0]))])
    assert not steady.changes_over_time and steady.frames == 2
    assert steady.at(2) == {10: 0, 11: 0}  # its own frame
    assert steady.at(3) == {10: 0, 11: 0, 12: 1, 13: 1}  # no truth at 3: the merged map
    moving = GroundTruth([(1, IDS, np.array([0, 0, 1, 1])), (2, IDS, np.array([0, 1, 1, 1]))])
    assert moving.changes_over_time
    assert moving.at(2) == {10: 0, 11: 1, 12: 1, 13: 1}
    assert moving.at(3) is None


def test_a_frame_is_scored_on_the_features_that_have_truth() -> None:
    truth = GroundTruth([(1, IDS[:3], np.array([0, 0, 1]))])
    row = score_frame(1, IDS, np.array([5, 5, -1, 5]), truth)  # feature 13: no truth
    assert (row.features, row.labelled, row.motions, row.scored) == (4, 3, 1, 3)
    assert (row.true_motions, row.wrong) == (2, 1)  # feature 12 labelled -1: wrong
    unscored = score_frame(9, IDS, np.zeros(4, dtype=int), GroundTruth([]))
    assert (unscored.scored, unscored.error) == (0, None)
    with pytest.raises(InputError, match='same points|>= -1'):
        score_frame(1, IDS, np.array([0, 0, -2, 0]), truth)
    with pytest.raises(InputError, match='shape'):
        score_frame(1, IDS, np.zeros(3, dtype=int), truth)


def test_the_summary_counts_frames_with_labels_and_truth_only() -> None:
    truth = GroundTruth([(k, IDS, np.array([0, 0, 1, 1])) for k in range(3)])
    rows = [score_frame(0, IDS, np.full(4, -1), truth),
            score_frame(1, IDS, np.array([0, 0, 0, 1]), truth),  # 1 wrong of 4
            score_frame(7, IDS, np.array([0, 0, 1, 1]), GroundTruth([]))]  # no truth
    summary = summarise(rows)
    assert (summary.unlabelled, summary.untruthed, summary.counted) == ([0], 1, 1)
    assert (summary.overall, summary.mean, summary.last) == (0.25, 0.25, 0.25)
    assert summary_lines(summary) == [
        'misclassification over the 1 frame with labels and ground truth: 25.0% of their '
        'features,',
        '  25.0% mean per frame, 25.0% on the last frame',
        'motions: as many found as true in 1 of 1 frames',
        'identity: 0 switches (a true motion matched to another label than the one it last '
        'had)',
        'not counted: frame 0, without labels (a motion needs two frames: the first has none)',
        'not counted: 1 frame(s) without ground truth',
    ]
    assert summary_lines(summarise(rows[:1])) == ['misclassification: n/a (nothing was labelled)']
    # Frames after the first without labels: a budgeted first fit still under way.
    late = summarise([score_frame(k, IDS, np.full(4, -1), truth) for k in range(2)] + rows[1:2])
    assert summary_lines(late)[-1] == (
        'not counted: frames 0, 1, without labels (a motion needs two frames: the first has '
        'none; under a time budget the first fit can take a few frames more)')


def test_the_summary_counts_identity_switches_over_the_counted_frames() -> None:
    truth = GroundTruth([(k, IDS, np.array([0, 0, 1, 1])) for k in range(5)])
    labels = ([0, 0, 1, 1], [-1, -1, -1, -1], [0, 0, 1, 1], [0, 0, 2, 2], [0, 0, 2, 2])
    summary = summarise([score_frame(k, IDS, np.array(x), truth) for k, x in enumerate(labels)])
    # Motion 1 goes from label 1 to 2 once; the unlabelled frame is not counted.
    assert summary.switches == 1
    assert 'identity: 1 switch (' in '\n'.join(summary_lines(summary))
