"""pearl_segment_bag: stacking frames into tracks, label strings, and runs on the bundled bags."""

from __future__ import annotations

import re
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest

from pearl_ros.cli.segment_bag import label_string, main, stack_tracks
from pearl_ros.core.errors import InputError

BAGS = Path(__file__).resolve().parents[2] / 'bags'
SMALL_BAG = BAGS / '1R2RCR_g12'


class Frame(NamedTuple):
    """Stands in for bagio's FeatureFrame: the stacking needs only ``ids`` and ``uv``."""

    stamp_ns: int
    ids: np.ndarray
    uv: np.ndarray


def test_stack_tracks_keeps_features_seen_in_every_frame_in_id_order():
    rng = np.random.default_rng(7)
    positions = {i: rng.uniform(0, 640, size=(3, 2)) for i in (2, 5, 11, 40, 41)}
    present = [(2, 5, 11, 40, 41), (41, 11, 2, 5), (5, 2, 41, 11, 99)]
    frames = []
    for f, ids in enumerate(present):
        uv = [positions[i][f] if i in positions else (0.0, 0.0) for i in ids]
        frames.append(Frame(f, np.array(ids), np.array(uv)))
    ids, tracks = stack_tracks(frames)
    np.testing.assert_array_equal(ids, [2, 5, 11, 41])
    assert tracks.shape == (3, 4, 2)
    for k, i in enumerate((2, 5, 11, 41)):
        np.testing.assert_array_equal(tracks[:, k], positions[i])


def test_stack_tracks_rejects_repeated_ids_and_no_frames():
    frame = Frame(0, np.array([1, 1]), np.zeros((2, 2)))
    with pytest.raises(InputError, match='repeated'):
        stack_tracks([frame])
    with pytest.raises(InputError, match='no feature frames'):
        stack_tracks([])


def test_label_string_uses_one_character_per_point_and_wraps():
    labels = np.array([0] * 50 + [-1] + [1] * 40 + [2, 11, 40])
    lines = label_string(labels, width=80).splitlines()
    assert [len(line) for line in lines] == [80, 14]
    assert ''.join(lines) == '0' * 50 + '-' + '1' * 40 + '2b?'


def assert_one_line_error(capsys, expected: str) -> None:
    err = capsys.readouterr().err
    assert err.startswith('error: ') and expected in err
    assert len(err.strip().splitlines()) == 1
    assert 'Traceback' not in err


def test_missing_bag_is_an_error(tmp_path, capsys):
    assert main([str(tmp_path / 'no_such_bag')]) == 1
    assert_one_line_error(capsys, 'no_such_bag')


def test_no_bag_given_is_a_usage_error(capsys):
    assert main([]) == 1
    assert_one_line_error(capsys, 'BAG')




def test_segment_bag_reports_the_segmentation_of_a_bundled_bag(capsys):
    from pearl_ros.bagio.reader import read_feature_frames, read_ground_truth
    from pearl_ros.core.config import PearlConfig
    from pearl_ros.core.pearl import fit

    # Expected values from the bag itself, stacked here with plain dicts and sets.
    frames = list(read_feature_frames(SMALL_BAG))
    by_frame = [dict(zip(np.asarray(f.ids).tolist(), np.asarray(f.uv).tolist(), strict=True))
                for f in frames]
    common = sorted(set.intersection(*(set(d) for d in by_frame)))
    tracks = np.array([[d[i] for i in common] for d in by_frame], dtype=np.float64)
    truth_map = read_ground_truth(SMALL_BAG)
    truth = np.array([truth_map[i] for i in common])
    result = fit(tracks, config=PearlConfig(model='affine'), rng=0)

    assert main([str(SMALL_BAG) + '/']) == 0
    out = capsys.readouterr().out
    assert out.startswith(f'1R2RCR_g12: {len(frames)} frames, {len(common)} points')
    found = re.search(r'motions found (\d+) \(true (\d+)\)', out)
    assert found and int(found[1]) == result.num_models
    assert int(found[2]) == np.unique(truth[truth >= 0]).size
    error = re.search(r'misclassification ([0-9.]+)%', out)
    # The printed rate is that of the fit, scored point by point with the best matching.
    best = 0
    for perm in _matchings(result.labels, truth):
        pairs = zip(result.labels.tolist(), truth.tolist(), strict=True)
        best = max(best, sum(perm.get(p) == t or p == t == -1 for p, t in pairs))
    assert error and float(error[1]) == pytest.approx(100 * (1 - best / len(common)), abs=0.005)
    label_lines = [line for line in out.splitlines() if re.fullmatch(r'\s+[-0-9a-z]+', line)]
    symbols = ''.join(line.strip() for line in label_lines)
    assert len(symbols) == 2 * len(common)  # the truth, then the labels found
    # Found labels are shown renamed to their matched true motion: they differ from the truth
    # exactly at the misclassified points.
    shown_truth, shown_found = symbols[: len(common)], symbols[len(common) :]
    assert sorted(shown_truth) == sorted(''.join(str(t) for t in truth))
    wrong = sum(a != b for a, b in zip(shown_truth, shown_found, strict=True))
    assert wrong == len(common) - best


def _matchings(pred: np.ndarray, truth: np.ndarray):
    import itertools

    pred_groups = sorted({int(p) for p in pred if p >= 0})
    true_groups = sorted({int(t) for t in truth if t >= 0})
    if len(pred_groups) <= len(true_groups):
        for image in itertools.permutations(true_groups, len(pred_groups)):
            yield dict(zip(pred_groups, image, strict=True))
    else:
        for chosen in itertools.permutations(pred_groups, len(true_groups)):
            yield dict(zip(chosen, true_groups, strict=True))


def test_segment_bag_reports_every_bag_given(capsys):
    assert main([str(SMALL_BAG), str(BAGS / 'cars2')]) == 0
    out = capsys.readouterr().out
    assert re.search(r'^1R2RCR_g12: ', out, re.M) and re.search(r'^cars2: ', out, re.M)


def test_segment_bag_without_ground_truth_reports_labels_only(tmp_path, capsys):
    from pearl_ros.bagio.reader import FeatureFrame, read_feature_frames
    from pearl_ros.bagio.writer import write_feature_bag

    frames = list(read_feature_frames(SMALL_BAG))
    # Features 0..4 of the fourth frame are lost: they must drop out of the tracks.
    lost = frames[3]
    frames[3] = FeatureFrame(lost.stamp_ns, lost.ids[5:], lost.uv[5:])
    bag = tmp_path / 'no_truth'
    write_feature_bag(bag, frames)

    assert main([str(bag)]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f'no_truth: {len(frames)} frames, {lost.ids.size - 5} points')
    assert 'no ground truth' in out and 'misclassification' not in out
    label_lines = [line for line in out.splitlines() if re.fullmatch(r'\s+[-0-9a-z]+', line)]
    assert len(''.join(line.strip() for line in label_lines)) == lost.ids.size - 5
