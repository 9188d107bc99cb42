"""pearl_score against oracles: labels bags written here, with labels known in advance.

The bags are written with rosbags alone (not pearl_ros.bagio.writer), and every expected figure
is counted by hand from the labels written: a relabelling of the truth scores 0 %, one flipped
feature exactly 1/N, a feature that changes motion is scored with the label of its own frame.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from pearl_ros.cli.score import SNIPPET, main, score_bag

from bag_oracles import raw_messages

REPO = Path(__file__).resolve().parents[2]
BAGS = REPO / 'bags'
LABELS = '/motion_labels'
TRUTH = '/ground_truth/labels'
TS = get_typestore(Stores.ROS2_KILTED)
_PointCloud2 = TS.types['sensor_msgs/msg/PointCloud2']
_PointField = TS.types['sensor_msgs/msg/PointField']
_Header = TS.types['std_msgs/msg/Header']
_Time = TS.types['builtin_interfaces/msg/Time']
_DATATYPES = {'<u4': 6, '<i4': 5, '<f4': 7}
START = 1_700_000_000 * 10**9

Frame = tuple[int, np.ndarray, np.ndarray]  # stamp_ns, ids, labels


def _cloud(stamp_ns: int, ids: np.ndarray, labels: np.ndarray, pixels: bool) -> object:
    names = [('id', '<u4')] + ([('u', '<f4'), ('v', '<f4')] if pixels else []) + \
        [('label', '<i4')]
    dtype = np.dtype(names)
    points = np.zeros(len(ids), dtype=dtype)
    points['id'], points['label'] = ids, labels
    fields = [_PointField(name=name, offset=dtype.fields[name][1], datatype=_DATATYPES[code],
                          count=1) for name, code in names]
    stamp = _Time(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    return _PointCloud2(header=_Header(stamp=stamp, frame_id='camera'), height=1,
                        width=len(ids), fields=fields, is_bigendian=False,
                        point_step=dtype.itemsize, row_step=dtype.itemsize * len(ids),
                        data=points.view(np.uint8), is_dense=True)


def _write(path: Path, topics: dict[str, list[Frame]]) -> Path:
    """A ROS 2 bag with one PointCloud2 per frame on each topic (labels carry u, v as well)."""
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        for topic, frames in topics.items():
            connection = writer.add_connection(topic, 'sensor_msgs/msg/PointCloud2', typestore=TS)
            for stamp, ids, labels in frames:
                msg = _cloud(stamp, ids, labels, pixels=topic == LABELS)
                writer.write(connection, stamp, TS.serialize_cdr(msg, msg.__msgtype__))
    return path


def _truth_frames(bag: Path) -> list[Frame]:
    """A bundled bag's ground truth, read with rosbags and numpy alone."""
    out = []
    for msg in raw_messages(bag, TRUTH):
        points = np.frombuffer(bytes(msg.data), dtype=[('id', '<u4'), ('label', '<i4')])
        stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        out.append((stamp, points['id'].astype(np.int64), points['label'].astype(np.int64)))
    return out


def _run(capsys: pytest.CaptureFixture[str], *argv: object) -> tuple[int, str, str]:
    code = main([str(arg) for arg in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_a_relabelling_of_the_per_frame_truth_scores_zero_in_every_frame(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = BAGS / 'synthetic_births_deaths'
    truth = _truth_frames(bag)
    rng = np.random.default_rng(0)
    renamed = []
    for stamp, ids, labels in truth:  # other motion numbers in every frame
        names = rng.permutation(10)
        renamed.append((stamp, ids, names[labels]))
    labels_bag = _write(tmp_path / 'labels', {LABELS: renamed})

    scores = score_bag(labels_bag, bag)
    assert len(scores) == 90
    assert all(row.error == 0.0 and row.scored == 300 for row in scores)
    assert [row.motions for row in scores] == [row.true_motions for row in scores]
    assert {row.true_motions for row in scores} == {2, 3}  # objects start and stop moving
    code, out, err = _run(capsys, labels_bag, '--truth', bag)
    assert (code, err) == (0, '')
    assert 'over the 90 frames with labels and ground truth: 0.0% of their features' in out
    assert 'as many found as true in 90 of 90 frames' in out


def test_one_flipped_feature_costs_exactly_one_feature_of_its_frame(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    truth = _truth_frames(BAGS / '1R2RCR_g12')  # 24 frames of the same 153 features
    labels = [(stamp, ids, values.copy()) for stamp, ids, values in truth]
    labels[5][2][7] = 1 - labels[5][2][7]  # two motions: feature 7 of frame 5 to the other one
    bag = _write(tmp_path / 'labels', {LABELS: labels, TRUTH: truth})  # truth in the same bag

    scores = score_bag(bag, bag)
    assert [(row.wrong, row.scored) for row in scores] == [(0, 153)] * 5 + [(1, 153)] + \
        [(0, 153)] * 18
    assert scores[5].error == pytest.approx(1 / 153, rel=1e-12)
    code, out, _ = _run(capsys, bag)
    assert code == 0
    lines = out.splitlines()
    assert lines[0] == f'{bag}: {LABELS} against {TRUTH} of {bag}'
    assert lines[2].split() == ['0', '153', '153', '2', '(2)', '0.0%']
    assert lines[7].split() == ['5', '153', '153', '2', '(2)', '0.7%']
    overall = f'{100 / (153 * 24):.1f}%'  # 0.0%: one feature in 3672
    assert f'24 frames with labels and ground truth: {overall} of their features' in out
    assert f'{100 / 153 / 24:.1f}% mean per frame, 0.0% on the last frame' in out


def test_a_feature_that_changes_motion_is_scored_with_its_frame_truth(tmp_path: Path) -> None:
    ids = np.array([1, 2, 3, 4])
    truth = [(START, ids, np.array([0, 0, 1, 1])),
             (START + 10**8, ids, np.array([0, 0, 0, 1]))]  # feature 3 joins motion 0
    stale = [(stamp, ids, np.array([0, 0, 1, 1])) for stamp, _, _ in truth]
    bag = _write(tmp_path / 'labels', {LABELS: stale, TRUTH: truth})
    # Frame 1: motion 0 = {1, 2} (+3 in the truth), motion 1 = {4}; feature 3 is wrong.
    assert [row.error for row in score_bag(bag, bag)] == [0.0, 0.25]
    following = _write(tmp_path / 'following', {LABELS: truth, TRUTH: truth})
    assert [row.error for row in score_bag(following, following)] == [0.0, 0.0]


def test_true_outliers_are_a_group_of_their_own(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    ids = np.arange(6)
    truth = [(START, ids, np.array([0, 0, 1, 1, -1, -1]))]
    # Feature 4 called an outlier (right), feature 5 put in a motion (wrong).
    labels = [(START, ids, np.array([3, 3, 7, 7, -1, 3]))]
    bag = _write(tmp_path / 'labels', {LABELS: labels, TRUTH: truth})
    (row,) = score_bag(bag, bag)
    assert (row.wrong, row.true_motions, row.true_outliers, row.outliers_found) == (1, 2, 2, 1)
    code, out, _ = _run(capsys, bag)
    assert code == 0
    assert 'outliers labelled -1: 1/2' in out.splitlines()[2]
    assert 'outliers: 1 of the 2 features the truth calls outliers were labelled -1' in out


def test_a_frame_without_labels_is_named_and_not_counted(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    ids = np.arange(4)
    truth = [(START + k, ids, np.array([0, 0, 1, 1])) for k in range(3)]
    labels = [(START, ids, np.full(4, -1)), (START + 1, ids, np.array([0, 0, 1, 1])),
              (START + 2, ids, np.array([0, 0, 0, 0]))]  # one motion found of two: 2 wrong
    bag = _write(tmp_path / 'labels', {LABELS: labels, TRUTH: truth})
    code, out, _ = _run(capsys, bag, '--summary')
    assert code == 0
    assert out.splitlines()[1:] == [
        'misclassification over the 2 frames with labels and ground truth: 25.0% of their '
        'features,',
        '  25.0% mean per frame, 50.0% on the last frame',
        'motions: as many found as true in 1 of 2 frames',
        'identity: 0 switches (a true motion matched to another label than the one it last '
        'had)',
        'not counted: frame 0, without labels (a motion needs two frames: the first has none)',
    ]


def test_a_frame_whose_stamp_has_no_truth_uses_the_truth_that_never_changes(
    tmp_path: Path,
) -> None:
    ids = np.arange(4)
    truth = [(START, ids, np.array([0, 0, 1, 1]))]  # one truth message for the whole run
    labels = [(START + k, ids, np.array([1, 1, 0, 0])) for k in range(3)]
    bag = _write(tmp_path / 'labels', {LABELS: labels, TRUTH: truth})
    assert [row.error for row in score_bag(bag, bag)] == [0.0, 0.0, 0.0]
    changing = truth + [(START + 1, ids, np.array([0, 1, 1, 1]))]
    bag = _write(tmp_path / 'changing', {LABELS: labels, TRUTH: changing})
    # Frame 2 has no truth of its own, and the truth changes over time: not scored.
    assert [row.error for row in score_bag(bag, bag)] == [0.0, 0.25, None]


def test_bad_input_gets_one_error_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    ids = np.arange(3)
    labels_only = _write(tmp_path / 'labels_only', {LABELS: [(START, ids, np.zeros(3))]})
    truth_only = _write(tmp_path / 'truth_only', {TRUTH: [(START, ids, np.zeros(3))]})
    (tmp_path / 'empty').mkdir()
    cases = {
        (tmp_path / 'missing',): f'error: bag not found: {tmp_path / "missing"}',
        (labels_only,): f'error: {labels_only}: no ground truth topic {TRUTH}; pass --truth BAG '
                        f'(the input bag); topics: {LABELS}',
        (truth_only,): f"error: {truth_only}: no topic '{LABELS}'; topics: {TRUTH} "
                       '(sensor_msgs/msg/PointCloud2)',
        (labels_only, '--truth', tmp_path / 'empty'):
            f'error: {tmp_path / "empty"} is not a ROS 2 bag folder: it has no metadata.yaml',
        (labels_only, '--bogus'): 'error: unrecognized arguments: --bogus',
    }
    for argv, expected in cases.items():
        code, out, err = _run(capsys, *argv)
        assert (code, out, err) == (1, '', expected + '\n'), argv


def test_help_prints_usage_and_exits_0(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = _run(capsys, '--help')
    assert code == 0
    assert out.startswith('usage: pearl_score [-h] [--truth BAG]')


def test_explain_names_the_topics_and_its_python_snippet_reads_the_bag(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    truth = _truth_frames(BAGS / '1R2RCR_g12_pair')
    bag = _write(tmp_path / 'labels', {LABELS: truth, TRUTH: truth})
    code, out, _ = _run(capsys, bag, '--summary', '--explain')
    assert code == 0
    assert f'  {LABELS} (2): the labels: one PointCloud2 per input frame, with its header;' in out
    assert f'  {TRUTH} (2): ' in out
    assert f'pearl_score {bag}' in out
    snippet = SNIPPET.format(bag=bag, topic=LABELS)
    assert '\n'.join('    ' + line for line in snippet.splitlines()) in out
    done = subprocess.run([sys.executable, '-c', snippet], capture_output=True, text=True,
                          timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    first = truth[0][2][:10].tolist()
    assert done.stdout.splitlines() == [
        f'1700000000 0 {np.array(first, dtype=np.int32)}',
        f'1700000000 766666667 {np.array(first, dtype=np.int32)}',
    ]


def test_the_score_modules_import_without_rclpy() -> None:
    program = ('import sys, pearl_ros.cli.score, pearl_ros.scoring\n'
               "assert 'rclpy' not in sys.modules, 'rclpy imported'\n")
    done = subprocess.run([sys.executable, '-c', program], capture_output=True, text=True,
                          timeout=120, check=False)
    assert done.returncode == 0, done.stderr


def test_the_console_script_runs() -> None:
    script = Path(sys.executable).parent / 'pearl_score'
    assert script.is_file(), f'{script} missing: pip install -e . (make venv)'
    done = subprocess.run([str(script), str(BAGS / 'missing')], capture_output=True, text=True,
                          timeout=120, check=False)
    assert (done.returncode, done.stderr) == (1, f'error: bag not found: {BAGS / "missing"}\n')
