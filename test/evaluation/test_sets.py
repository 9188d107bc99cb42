"""Benchmark tasks on robot-shaped data: the scoring rule, each task on files written here, and
the ``pearl_bench`` commands that run them."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from pearl_ros.cli.bench import main
from pearl_ros.core.config import PearlConfig
from pearl_ros.core.errors import InputError
from pearl_ros.core.metrics import LabelIdentity
from pearl_ros.evaluation.sets import Task, format_summaries, run_task, score, summarise
from pearl_ros.online.config import OnlineConfig


def test_score_counts_outliers_as_a_group_of_their_own() -> None:
    truth = np.array([0, 0, 0, 1, 1, -1, -1, -1])
    same = score('s', 'x', np.array([5, 5, 5, 2, 2, -1, -1, -1]), truth, 1.0, 2)
    assert same.error_pct == 0.0 and same.outlier_recall_pct == 100.0
    assert same.rejected_pct == 0.0 and same.motions_true == 2
    # One true outlier given to motion 5 and one true point rejected: 2 of 8 wrong.
    two = score('s', 'x', np.array([5, 5, -1, 2, 2, 5, -1, -1]), truth, 1.0, 2)
    assert two.error_pct == pytest.approx(100.0 * 2 / 8)
    assert two.outlier_recall_pct == pytest.approx(100.0 * 2 / 3)
    assert two.rejected_pct == pytest.approx(100.0 * 1 / 5)


def test_score_with_outliers_apart_judges_true_points_alone() -> None:
    truth = np.array([0, 0, 1, 1, -1, -1])
    # Outliers given to motions cost nothing in the error, only in the recall.
    result = score('s', 'x', np.array([0, 0, 1, -1, 0, 1]), truth, 1.0, 2, outliers_apart=True)
    assert result.error_pct == pytest.approx(25.0)  # one of four true points rejected
    assert result.outlier_recall_pct == 0.0


def test_summaries_average_per_set_and_count_right_motion_numbers() -> None:
    scores = [score('a', 'x', np.array([0, 1]), np.array([0, 1]), 1.0, 2),
              score('a', 'y', np.array([0, 0]), np.array([0, 1]), 3.0, 1),
              score('b', 'z', np.array([0, 0]), np.array([0, 0]), 2.0, 1)]
    a, b = summarise(scores)
    assert (a.dataset, a.items, a.mean_pct, a.motions_right_pct, a.seconds) == (
        'a', 2, 25.0, 50.0, 2.0)
    assert math.isnan(a.outlier_recall_pct)
    assert (b.dataset, b.items, b.mean_pct) == ('b', 1, 0.0)
    assert math.isnan(a.half_pct) and math.isnan(b.half_pct)  # no stream items


def test_the_second_half_column_averages_the_stream_items_only() -> None:
    truth = np.array([0, 1])
    scores = [score('s', 'x', truth, truth, 1.0, 2, half_pct=10.0),
              score('s', 'y', truth, truth, 1.0, 2, half_pct=30.0),
              score('b', 'z', truth, truth, 1.0, 2)]
    streams, batch = summarise(scores)
    assert streams.half_pct == pytest.approx(20.0) and math.isnan(batch.half_pct)
    table = format_summaries([streams, batch]).splitlines()
    assert table[0].split()[-4:] == ['2nd', 'half', '%', 'switches/100']
    assert table[1].split()[-2] == '20.00' and table[2].split()[-2] == '-'


def test_the_switches_column_counts_every_frame_of_a_set_s_streams() -> None:
    truth = np.array([0, 1])
    first, second = LabelIdentity(), LabelIdentity()
    for pred in ([0, 1], [0, 2], [0, 2], [3, 2]):  # two switches in four frames
        first.add(np.array(pred), truth)
    for _ in range(6):  # none in six
        second.add(truth, truth)
    scores = [score('s', 'x', truth, truth, 1.0, 2, half_pct=0.0, identity=first),
              score('s', 'y', truth, truth, 1.0, 2, half_pct=0.0, identity=second),
              score('b', 'z', truth, truth, 1.0, 2)]
    assert (scores[0].switches, scores[0].frames, scores[2].frames) == (2, 4, 0)
    streams, batch = summarise(scores)
    assert streams.switches_per_100 == pytest.approx(20.0)  # 2 in 10 frames
    assert math.isnan(batch.switches_per_100)
    table = format_summaries([streams, batch]).splitlines()
    assert table[1].split()[-1] == '20.00' and table[2].split()[-1] == '-'


def _write_clip(path: Path, affine_scene, frames: int = 8) -> np.ndarray:
    """A KT3DMoSeg-format clip of two affine bodies (conftest ``affine_scene``), some tracks
    missing at either end."""
    tracks, labels = affine_scene((60, 50), frames, noise=0.3, seed=2)
    visible = np.ones(tracks.shape[:2], dtype=bool)
    visible[:2, ::7] = False  # born late
    visible[-2:, 3::9] = False  # lost early
    y = np.concatenate([tracks, np.ones(tracks.shape[:2] + (1,))], axis=2)
    y = np.transpose(y, (2, 1, 0)) * visible.T[None]
    scipy.io.savemat(str(path), {'Data': {'ySparse': y, 'visibleSparse': visible.T.astype(float),
                                          'GtLabel': labels + 1.0}})
    return labels


@pytest.mark.parametrize('mode', ['all', 'two', 'stream'])
def test_a_clip_of_two_bodies_is_segmented_in_every_mode(
    tmp_path: Path, mode: str, affine_scene
) -> None:
    _write_clip(tmp_path / 'Seq001_Clip01_Tracks.mat', affine_scene)
    task = Task('kt3dmoseg', str(tmp_path / 'Seq001_Clip01_Tracks.mat'), mode, PearlConfig(),
                OnlineConfig(budget_ms=0.0))
    result = run_task(task)
    assert result.dataset == f'kt3dmoseg_{mode}' and result.name == 'Seq001_Clip01'
    assert result.motions_true == 2
    assert result.error_pct < 5.0, result
    assert math.isnan(result.half_pct) == (mode != 'stream')


def test_a_streamed_clip_reports_the_mean_error_of_its_second_half(tmp_path: Path,
                                                                  affine_scene) -> None:
    # The mean of the per-frame errors of frames 4-7 of an 8-frame clip, measured here with the
    # online segmenter and the metric directly.
    from pearl_ros.core.metrics import misclassification
    from pearl_ros.datasets.kt3dmoseg import load_clip
    from pearl_ros.online.segmenter import OnlineSegmenter

    path = tmp_path / 'Seq001_Clip01_Tracks.mat'
    _write_clip(path, affine_scene)
    online = OnlineConfig(budget_ms=0.0)
    result = run_task(Task('kt3dmoseg', str(path), 'stream', PearlConfig(), online))
    segmenter = OnlineSegmenter(PearlConfig(), online)
    errors = [misclassification(segmenter.process(1_000_000_000 + t, ids, uv).labels, truth)
              for t, (ids, uv, truth) in enumerate(load_clip(str(path)).frames())]
    assert len(errors) == 8 and max(errors[4:]) > 0.0  # not a mean of zeros
    assert result.half_pct == pytest.approx(100.0 * np.mean(errors[4:]))


def _write_pair(path: Path, mismatches: int = 0) -> np.ndarray:
    """An AdelaideRMF-format pair: two boxes of points moved apart between the shots, seen by
    a pinhole camera (f 500 px), plus ``mismatches`` random matches labelled 0."""
    rng = np.random.default_rng(4)
    k = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    views, labels = [], []
    for body, (shift, turn) in enumerate((([0.4, 0.0, 0.1], 0.10), ([-0.5, 0.2, 0.0], -0.15))):
        points = rng.uniform(-1, 1, (70, 3)) * [1.0, 0.8, 0.6] + [1.6 * body - 0.8, 0, 6.0]
        c, s = np.cos(turn), np.sin(turn)
        moved = points @ np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]).T + shift
        views.append([(p @ k.T)[:, :2] / p[:, 2:] for p in (points, moved)])
        labels.append(np.full(70, body + 1))
    x1 = np.concatenate([v[0] for v in views]) + rng.normal(0, 0.3, (140, 2))
    x2 = np.concatenate([v[1] for v in views]) + rng.normal(0, 0.3, (140, 2))
    x1 = np.concatenate([x1, rng.uniform(0, 640, (mismatches, 2))])
    x2 = np.concatenate([x2, rng.uniform(0, 640, (mismatches, 2))])
    label = np.concatenate(labels + [np.zeros(mismatches, int)])
    one = np.ones((1, x1.shape[0]))
    scipy.io.savemat(str(path), {'data': np.vstack([x1.T, one, x2.T, one]), 'label': label[None]})
    return label


def test_a_clean_pair_of_two_motions_is_segmented(tmp_path: Path) -> None:
    _write_pair(tmp_path / 'boxes.mat')
    result = run_task(Task('adelaide', str(tmp_path / 'boxes.mat'), 'two', PearlConfig(),
                           OnlineConfig()))
    assert result.dataset == 'adelaidermf_f' and result.motions_true == 2
    assert result.error_pct < 5.0, result


def test_pearl_bench_adelaide_prints_one_line_per_set(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    _write_pair(tmp_path / 'boxes.mat', mismatches=20)
    _write_pair(tmp_path / 'boxes2.mat', mismatches=40)
    assert main(['adelaide', str(tmp_path), '--items', '--jobs', '1']) == 0
    out = capsys.readouterr().out
    lines = [line for line in out.splitlines() if line.startswith('adelaidermf_f ')]
    assert len(lines) == 3  # two items and the summary line
    assert lines[-1].split()[1] == '2'


def test_pearl_bench_hopkins_with_outliers_reports_recall(
        hopkins_like, capsys: pytest.CaptureFixture[str]) -> None:
    path = hopkins_like('1R2RC_x', sizes=(50, 40), frames=8)
    assert main(['hopkins155', str(path.parents[1]), '--outliers', '0.2']) == 0
    line = next(x for x in capsys.readouterr().out.splitlines()
                if x.startswith('hopkins155_outliers'))
    assert line.split()[1] == '1'
    assert float(line.split()[5]) >= 0.0  # an outlier recall is reported, not '-'
    assert main(['hopkins155', str(path.parents[1]), '--outliers', '0.2', '--items']) == 0
    rows = [x for x in capsys.readouterr().out.splitlines() if x.startswith('hopkins155_outliers')]
    assert len(rows) == 2 and rows[0].split()[1] == '1R2RC_x'  # the sequence, then the summary


def test_pearl_bench_hopkins_with_mismatches_scores_them_as_a_group(
        hopkins_like, capsys: pytest.CaptureFixture[str]) -> None:
    # Oracle: the task's own two views and truth, scored here by the misclassification with
    # the mismatches as a group of their own (a point labelled -1 is right only where added).
    import zlib

    from pearl_ros.core.metrics import misclassification
    from pearl_ros.core.pearl import fit
    from pearl_ros.datasets.hopkins import load_mat
    from pearl_ros.datasets.outliers import add_mismatches

    path = hopkins_like('1R2RC_x', sizes=(60, 50), frames=8)
    assert main(['hopkins155', str(path.parents[1]), '--frames', 'two', '--mismatches', '0.4',
                 '--items', '--seed', '2']) == 0
    rows = [x for x in capsys.readouterr().out.splitlines()
            if x.startswith('hopkins155_mismatches')]
    assert len(rows) == 2 and rows[0].split()[1] == '1R2RC_x'
    seq = load_mat(path)
    rng = np.random.default_rng(np.random.SeedSequence([2, zlib.crc32(seq.name.encode())]))
    views, truth = add_mismatches(seq.tracks[[0, -1]], seq.labels, 0.4, rng)
    assert np.count_nonzero(truth == -1) == round(0.4 * 110 / 0.6)
    labels = fit(views, PearlConfig(model='fundamental'), np.random.default_rng(2)).labels
    expected = 100.0 * misclassification(labels, truth)
    assert rows[0].split()[2] == f'{expected:.2f}%'
    assert float(rows[-1].split()[5]) > 50.0  # most mismatches labelled -1


@pytest.mark.parametrize('argv, message', [
    (['suite', '--data', '/nonexistent/data'], 'data folder not found'),
    (['hopkins155', '.', '--mismatches', '0.4'], '--mismatches goes with --frames two'),
    (['hopkins155', '.', '--frames', 'two', '--mismatches', '-0.1'],
     '--mismatches must be in [0, 1)'),
    (['hopkins155', '.', '--frames', 'two', '--mismatches', '0.4', '--outliers', '0.2'],
     'give one'),
    (['hopkins155', '.', '--frames', 'two', '--mismatches', '0.4', '--csv', 'x.csv'],
     '--mismatches prints per sequence with --items; it does not take --csv'),
    (['hopkins155', '.', '--outliers', '1.5'], '--outliers must be in [0, 1)'),
    (['hopkins155', '.', '--outliers', '0.2', '--csv', 'x.csv'], 'does not take --csv'),
    (['hopkins155', '.', '--outliers', '0.2', '--oracle', '--frames', 'two'],
     'does not take --oracle, --frames two'),
    (['hopkins155', '.', '--items'], '--items goes with --outliers or --mismatches'),
    (['synthetic', '--scenes', '-1'], '--scenes must be >= 0'),
    (['adelaide', '/nonexistent/pairs'], 'AdelaideRMF folder not found'),
    (['kt3dmoseg', '/nonexistent/clips', '--frames', 'two'], 'KT3DMoSeg folder not found'),
])
def test_bad_bench_arguments_are_one_line_errors(argv: list[str], message: str,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    assert main(argv) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith('error:') and '\n' not in err and message in err


def test_a_task_error_names_its_item(tmp_path: Path) -> None:
    (tmp_path / 'broken.mat').write_bytes(b'junk')
    with pytest.raises(InputError, match='broken.mat'):
        run_task(Task('adelaide', str(tmp_path / 'broken.mat'), 'two', PearlConfig(),
                      OnlineConfig()))


def _empty_suite_files(root: Path) -> None:
    """One empty file of each set the suite lists from disk (it lists them, never reads them)."""
    from pearl_ros.cli.bench_sets import SET_FOLDERS

    for path in (f'{SET_FOLDERS["hopkins155"]}/seqa/seqa_truth.mat',
                 f'{SET_FOLDERS["kt3dmoseg"]}/Seq001_Clip01_Tracks.mat',
                 f'{SET_FOLDERS["adelaide"]}/pair.mat'):
        (root / path).parent.mkdir(parents=True, exist_ok=True)
        (root / path).touch()


def test_every_suite_item_takes_the_seed_given(tmp_path: Path) -> None:
    import argparse

    from pearl_ros.cli.bench_sets import _suite_items

    _empty_suite_files(tmp_path)
    items = _suite_items(tmp_path, argparse.Namespace(seed=7, set=[]))
    kinds = {kind for kind, _ in items}
    assert kinds == {'hopkins', 'stream', 'set'}
    for kind, task in items:
        seed = task.online.seed if kind == 'stream' else task.seed
        assert seed == 7, (kind, task)


def test_the_suite_scores_robot_scenes_beyond_the_first_three_on_their_own_line(
        tmp_path: Path) -> None:
    import argparse

    from pearl_ros.cli.bench_sets import _dataset_of, _suite_items

    _empty_suite_files(tmp_path)
    # Oracle: the scene numbers each robot line is built from, listed here.
    items = _suite_items(tmp_path, argparse.Namespace(seed=0, set=[]))
    scenes: dict[str, list[int]] = {}
    for item in items:
        kind, task = item
        if kind == 'set' and task.kind == 'robot':
            scenes.setdefault(_dataset_of(item), []).append(int(task.source))
    assert scenes == {'robot_synthetic': [0, 1, 2], 'robot_synthetic_cameras': [0, 1, 2],
                      'robot_synthetic_3_20': list(range(3, 21))}
    held_out = next(t for k, t in items if k == 'set' and t.source == '3')
    assert held_out.mode == 'stream'  # no cameras


def test_the_suite_adds_mismatches_to_the_two_frames_of_every_fifth_hopkins_sequence(
        tmp_path: Path) -> None:
    import argparse

    from pearl_ros.cli.bench_sets import _dataset_of, _suite_items

    _empty_suite_files(tmp_path)
    for name in ('seqb', 'seqc', 'seqd', 'seqe', 'seqf', 'seqg'):
        (tmp_path / 'hopkins155' / name).mkdir()
        (tmp_path / 'hopkins155' / name / f'{name}_truth.mat').touch()
    items = _suite_items(tmp_path, argparse.Namespace(seed=0, set=[]))
    two = [t for item in items if _dataset_of(item) == 'hopkins155_mismatches'
           for t in [item[1]]]
    # Seven sequences seqa..seqg: the first and the sixth, as the outlier-track row takes them.
    assert [Path(t.source).parent.name for t in two] == ['seqa', 'seqf']
    assert all(t.mode == 'two' and t.outliers == 0.5 for t in two)
    walks = [item[1] for item in items if _dataset_of(item) == 'hopkins155_outliers']
    assert [Path(t.source).parent.name for t in walks] == ['seqa', 'seqf']


def test_a_robot_stream_scored_for_another_line_carries_its_name() -> None:
    online = OnlineConfig(budget_ms=0.0)
    task = Task('robot', '3', 'stream', PearlConfig(), online, dataset='robot_synthetic_3_20')
    result = run_task(task)
    assert result.dataset == 'robot_synthetic_3_20' and result.name == 'seed3'
    plain = run_task(Task('robot', '3', 'stream', PearlConfig(), online))
    assert plain.dataset == 'robot_synthetic'
    assert plain.error_pct == result.error_pct  # the same stream, only its line differs


def test_a_robot_stream_through_a_lens_and_undistorted_again_is_the_pinhole_stream(capsys):
    from pearl_ros.datasets.robot import INTRINSICS, robot_stream
    from pearl_ros.evaluation.sets import _through_lens

    frames = [(f.ids, f.uv, f.truth) for f in robot_stream(80, 5, seed=0)]
    bent = _through_lens(frames, -0.2, False)
    back = _through_lens(frames, -0.2, True)
    for (_, uv, _), (_, seen, _), (_, undone, _) in zip(frames, bent, back, strict=True):
        # Barrel distortion: every point moves towards the centre, by r^3 k1 f.
        r = np.linalg.norm((uv - INTRINSICS[:2, 2]) / INTRINSICS[0, 0], axis=1)
        moved = np.linalg.norm(seen - uv, axis=1)
        assert np.allclose(moved, 0.2 * r**3 * INTRINSICS[0, 0])
        assert np.allclose(undone, uv, atol=1e-6)
    assert main(['synthetic', '--scenes', '0', '--undistort']) == 1
    assert '--undistort needs --lens' in capsys.readouterr().err


def test_the_suite_over_several_seeds_gives_each_seeds_mean_and_theirs(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # Oracle: the suite run once per seed, each run's own table.
    from pearl_ros.cli.bench_sets import SET_FOLDERS

    # The other sets' files are listed, not read (--only): empty ones will do.
    for path in (f'{SET_FOLDERS["hopkins155"]}/seqa/seqa_truth.mat',
                 f'{SET_FOLDERS["kt3dmoseg"]}/Seq001_Clip01_Tracks.mat'):
        (tmp_path / path).parent.mkdir(parents=True)
        (tmp_path / path).touch()
    pairs = tmp_path / SET_FOLDERS['adelaide']
    pairs.mkdir()
    _write_pair(pairs / 'boxes.mat', mismatches=40)
    _write_pair(pairs / 'boxes2.mat', mismatches=60)
    common = ['suite', '--data', str(tmp_path), '--only', 'adelaidermf_f']
    alone = []
    for seed in ('0', '3'):
        assert main([*common, '--seed', seed]) == 0
        line = next(x for x in capsys.readouterr().out.splitlines()
                    if x.startswith('adelaidermf_f'))
        alone.append(float(line.split()[2]))
    assert main([*common, '--seeds', '0', '3']) == 0
    rows = [x.split() for x in capsys.readouterr().out.splitlines()
            if x.startswith('adelaidermf_f')]
    # Each seed's own table, then the line of means: items, seed 0, seed 3, their mean, '-'.
    assert [float(r[2]) for r in rows[:2]] == alone
    items, first, second, mean, half = rows[2][1:]
    assert items == '2' and half == '-'
    assert (float(first), float(second)) == pytest.approx(alone, abs=0.005)
    assert float(mean) == pytest.approx(np.mean(alone), abs=0.005)
    assert main([*common, '--seeds', '3', '3']) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith('error:') and '--seeds must be distinct' in err
