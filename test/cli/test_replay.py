"""pearl_replay on the bundled bags and on broken input, checked against independent oracles.

Oracles: the input bag read by rosbags alone (bag_oracles), OnlineSegmenter called directly on
the same frames with the same configuration, the ground truth recorded in the bags, and the
PointCloud2 / ROS 1 twins of 1R2RCR_g12, which must give exactly its labels.

Every replay here sets ``budget_ms=0``: with a time budget the optimiser stops when the machine
says so and labels would depend on the load, so no oracle could match them.
"""

from __future__ import annotations

import json
import shlex
import shutil
import subprocess
import sys
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from pearl_ros.bagio.decode import (
    decode_fields,
    decode_labels,
    decode_pointcloud,
    decode_pointcloud2,
    stamp_ns,
)
from pearl_ros.cli.replay import main
from pearl_ros.core.metrics import misclassification
from pearl_ros.online.config import build_configs
from pearl_ros.online.segmenter import OnlineSegmenter
from pearl_ros.pipeline.replay import ReplaySettings, replay, replay_throughput
from pearl_ros.pipeline.settings import (
    NODE_NAMES,
    NODE_SPECS,
    PIPELINE_NAMES,
    Settings,
    from_sources,
    load_file,
)

REPO = Path(__file__).resolve().parents[2]
BAGS = REPO / 'bags'
FEATURES = '/feature_tracker/feature'
LABELS = '/motion_labels'
STATIC = '/static_features'
TRUTH = '/ground_truth/labels'
TS = get_typestore(Stores.ROS2_KILTED)

DETERMINISTIC = ['--set', 'budget_ms=0']

# Largest misclassification allowed on the final frame, measured with budget_ms=0 and the
# default parameters of the online segmenter.
# Each bound is that level plus a margin, with the reason it is not lower; tighten them as the
# segmenter improves.
ACCURACY_BOUNDS = {
    # Both motions found, 0 errors of 153 (the batch fit is below 2% too,
    # test_regression_bags.py): 2 points of slack.
    '1R2RCR_g12': 0.02,
    # Two of the three motions found (21.8%): the window of 10 frames does not yet separate
    # the third. Labelling everything one motion scores 31.7%, above the bound.
    '1R2RCR': 0.25,
    # The car and the handheld camera's motions are nearly dependent (BENCHMARKS.md, "What
    # limits accuracy now": merged motions): 0.8%; one motion would score 12.0%.
    'cars2': 0.03,
    # Two views, fundamental matrices: both motions found (0.0%).
    '1R2RCR_g12_pair': 0.02,
    # In the last frame two motions, both found (0.0%): features seen in one frame only are
    # still voted by their neighbours and can err at the object's edge. One motion would score
    # about 20%.
    'synthetic_births_deaths': 0.02,
}
# Same features as 1R2RCR_g12, other message type or container: same labels.
TWINS = {'1R2RCR_g12_pc2': '1R2RCR_g12', '1R2RCR_g12_ros1.bag': '1R2RCR_g12'}
ALL = sorted([*ACCURACY_BOUNDS, *TWINS])


def messages(path: Path, topic: str) -> list[tuple[int, Any]]:
    """(log time, message) of ``topic``, read by rosbags alone."""
    with AnyReader([path], default_typestore=TS) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        return [
            (t, reader.deserialize(raw, c.msgtype))
            for c, t, raw in reader.messages(connections=connections)
        ]


def features(msg: Any) -> tuple[np.ndarray, np.ndarray]:
    if hasattr(msg, 'channels'):
        return decode_pointcloud(msg)
    return decode_pointcloud2(msg)


def label_columns(msg: Any) -> dict[str, np.ndarray]:
    assert [f.name for f in msg.fields] == ['id', 'u', 'v', 'label']
    return decode_fields(msg, ('id', 'u', 'v', 'label'))


@pytest.fixture(scope='module')
def replayed(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, dict]]:
    """Every bundled bag replayed once through main(): name -> (output bag, stats)."""
    out = {}
    root = tmp_path_factory.mktemp('replayed')
    for name in ALL:
        bag, stats = root / f'{name.removesuffix(".bag")}_out', root / f'{name}.json'
        code = main([str(BAGS / name), '--output', str(bag), '--stats', str(stats),
                     *DETERMINISTIC])
        assert code == 0
        out[name] = (bag, json.loads(stats.read_text()))
    return out


@pytest.mark.parametrize('name', ALL)
def test_one_labels_message_per_input_message_with_its_header_and_log_time(
    name: str, replayed: dict
) -> None:
    out, stats = replayed[name]
    inputs = messages(BAGS / name, FEATURES)
    for topic in (LABELS, STATIC):
        outputs = messages(out, topic)
        assert len(outputs) == len(inputs) == stats['counts']['frames']
        for (t_in, msg_in), (t_out, msg_out) in zip(inputs, outputs, strict=True):
            assert t_out == t_in
            assert stamp_ns(msg_out.header) == stamp_ns(msg_in.header)
            assert msg_out.header.frame_id == msg_in.header.frame_id


@pytest.mark.parametrize('name', ALL)
def test_labels_cover_every_input_feature_in_input_order(name: str, replayed: dict) -> None:
    out, _ = replayed[name]
    for (_, msg_in), (_, msg_out) in zip(messages(BAGS / name, FEATURES),
                                         messages(out, LABELS), strict=True):
        ids, uv = features(msg_in)
        label_ids, labels = decode_labels(msg_out)
        np.testing.assert_array_equal(label_ids, ids)
        columns = label_columns(msg_out)
        np.testing.assert_array_equal(columns['u'], uv[:, 0].astype(np.float32))
        np.testing.assert_array_equal(columns['v'], uv[:, 1].astype(np.float32))
        assert labels.min() >= -1


@pytest.mark.parametrize('name', sorted(ACCURACY_BOUNDS))
def test_labels_equal_the_online_segmenter_called_directly(name: str, replayed: dict) -> None:
    out, _ = replayed[name]
    segmenter = OnlineSegmenter(*build_configs({'budget_ms': 0.0}))
    for (_, msg_in), (_, msg_out) in zip(messages(BAGS / name, FEATURES),
                                         messages(out, LABELS), strict=True):
        ids, uv = features(msg_in)
        expected = segmenter.process(stamp_ns(msg_in.header), ids, uv).labels
        np.testing.assert_array_equal(decode_labels(msg_out)[1], expected)


@pytest.mark.parametrize('name', sorted(TWINS))
def test_pointcloud2_and_ros1_twins_give_the_same_labels(name: str, replayed: dict) -> None:
    twin, original = replayed[name][0], replayed[TWINS[name]][0]
    got, want = messages(twin, LABELS), messages(original, LABELS)
    assert len(got) == len(want) == 24
    for (_, a), (_, b) in zip(got, want, strict=True):
        np.testing.assert_array_equal(decode_labels(a)[1], decode_labels(b)[1])


@pytest.mark.parametrize('name', sorted(ACCURACY_BOUNDS))
def test_final_frame_accuracy_against_ground_truth(name: str, replayed: dict) -> None:
    out, _ = replayed[name]
    (_, last), = messages(out, LABELS)[-1:]
    truth = {stamp_ns(msg.header): decode_labels(msg) for _, msg in messages(BAGS / name, TRUTH)}
    truth_ids, truth_labels = truth[stamp_ns(last.header)]  # the truth of that very frame
    ids, labels = decode_labels(last)
    by_id = dict(zip(truth_ids.tolist(), truth_labels.tolist(), strict=True))
    expected = np.array([by_id[i] for i in ids.tolist()])
    assert misclassification(labels, expected) <= ACCURACY_BOUNDS[name]


@pytest.mark.parametrize('name', ALL)
def test_static_features_hold_exactly_the_largest_motion(name: str, replayed: dict) -> None:
    out, _ = replayed[name]
    inputs = messages(BAGS / name, FEATURES)
    for (_, msg_in), (_, labels_msg), (_, static) in zip(
            inputs, messages(out, LABELS), messages(out, STATIC), strict=True):
        assert static.__msgtype__ == msg_in.__msgtype__
        ids, uv = features(msg_in)
        labels = decode_labels(labels_msg)[1]
        counts = Counter(label for label in labels.tolist() if label >= 0)
        if counts:
            most = max(counts.values())
            background = min(label for label, n in counts.items() if n == most)
            keep = labels == background
        else:
            keep = np.zeros(labels.size, dtype=bool)
        static_ids, static_uv = features(static) if keep.any() else (np.empty(0), None)
        np.testing.assert_array_equal(static_ids, ids[keep])
        if keep.any():
            np.testing.assert_array_equal(static_uv, uv[keep])
        if hasattr(msg_in, 'channels'):  # the same layout: every channel, in order
            assert [c.name for c in static.channels] == [c.name for c in msg_in.channels]
            kept = np.flatnonzero(keep)
            for c_in, c_out in zip(msg_in.channels, static.channels, strict=True):
                np.testing.assert_array_equal(c_out.values, c_in.values[kept])
            assert [(p.x, p.y) for p in static.points] == [
                (msg_in.points[k].x, msg_in.points[k].y) for k in kept]
        else:
            assert [f.name for f in static.fields] == [f.name for f in msg_in.fields]


@pytest.mark.parametrize('name', ALL)
def test_ground_truth_is_copied_through(name: str, replayed: dict) -> None:
    out, stats = replayed[name]
    original, copied = messages(BAGS / name, TRUTH), messages(out, TRUTH)
    assert len(copied) == len(original) == stats['counts']['copied'][TRUTH]
    for (t_a, a), (t_b, b) in zip(original, copied, strict=True):
        assert t_a == t_b and stamp_ns(a.header) == stamp_ns(b.header)
        for x, y in zip(decode_labels(a), decode_labels(b), strict=True):
            np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize('name', ALL)
def test_stats_count_frames_features_and_latency(name: str, replayed: dict) -> None:
    _, stats = replayed[name]
    inputs = messages(BAGS / name, FEATURES)
    counts = stats['counts']
    assert counts['messages'] == counts['frames'] == len(inputs)
    assert counts['skipped'] == 0 and stats['skipped'] == []
    assert counts['features'] == sum(features(msg)[0].size for _, msg in inputs)
    assert [row['stamp_ns'] for row in stats['frames']] == [
        stamp_ns(msg.header) for _, msg in inputs]
    assert all(row['latency_ms'] >= 0 for row in stats['frames'])
    assert stats['summary']['frames_per_second'] > 0
    assert stats['parameters']['budget_ms'] == 0.0
    expected_type = 'sensor_msgs/msg/PointCloud2' if name.endswith('pc2') else \
        'sensor_msgs/msg/PointCloud'
    assert stats['input_types'] == [expected_type]


def test_the_installed_console_script_replays_a_bag(tmp_path: Path) -> None:
    script = Path(sys.executable).parent / 'pearl_replay'
    assert script.is_file(), 'pearl_replay is not installed in the venv (make venv)'
    out = tmp_path / 'out'
    done = subprocess.run(
        [str(script), str(BAGS / '1R2RCR_g12_pair'), '--output', str(out), *DETERMINISTIC],
        capture_output=True, text=True, check=False,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f'wrote {out}: 2 frames of 2 messages')
    assert len(messages(out, LABELS)) == 2
    done = subprocess.run([str(script), str(tmp_path / 'none'), '-o', str(tmp_path / 'x')],
                          capture_output=True, text=True, check=False)
    assert done.returncode == 1
    assert done.stderr.splitlines() == [f'error: bag not found: {tmp_path / "none"}']


def test_sqlite3_output_and_other_topic_names(tmp_path: Path) -> None:
    out = tmp_path / 'out'
    assert main([str(BAGS / '1R2RCR_g12_pair'), '-o', str(out), '--storage', 'sqlite3',
                 '--output-topic', '/pearl/labels', '--static-topic', '/pearl/static',
                 '--truth-topic', '', *DETERMINISTIC]) == 0
    assert [p.suffix for p in out.iterdir() if p.name != 'metadata.yaml'] == ['.db3']
    with AnyReader([out]) as reader:
        assert sorted(c.topic for c in reader.connections) == ['/pearl/labels', '/pearl/static']


# --------------------------------------------------------------------------- parameters


def test_the_nodes_parameter_file_is_accepted() -> None:
    # config/pearl.yaml is the node's ROS parameter file (`/**: ros__parameters:`) and holds
    # the defaults: read by the replay it gives the default settings.
    assert from_sources([REPO / 'config' / 'pearl.yaml']) == Settings()
    assert load_file(REPO / 'config' / 'pearl.yaml') == Settings().values()


def test_the_replay_applies_the_pipelines_node_parameters_with_the_nodes_defaults() -> None:
    defaults = {item.name: item.default for item in NODE_SPECS}
    assert set(PIPELINE_NAMES) < set(NODE_NAMES)
    settings = ReplaySettings().settings
    for name in NODE_NAMES:
        assert getattr(settings.node, name) == defaults[name]
    # The transport parameters are taken (the node's own file holds them) but not reported.
    values = from_sources([], ['qos=reliable', 'max_features=7']).values()
    assert (values['qos'], values['max_features']) == ('reliable', 7)


@pytest.mark.parametrize('text', [
    'pearl_node:\n  ros__parameters:\n    label_cost: 500\n    window: 4\n',
    '/**:\n  ros__parameters:\n    label_cost: 500.0\n    window: 4\n    qos: reliable\n',
    '/pearl_node:\n  ros__parameters:\n    label_cost: 500\n    window: 4\n',
    '/**/pearl_node:\n  ros__parameters:\n    label_cost: 500\n    window: 4\n',
    'other_node:\n  ros__parameters:\n    window: 9\n'
    '/**:\n  ros__parameters:\n    label_cost: 500\n    window: 4\n    use_sim_time: true\n',
    'label_cost: 500\nwindow: 4\n',
])
def test_ros_style_and_flat_parameter_files_set_the_same_values(
    tmp_path: Path, text: str
) -> None:
    path = tmp_path / 'p.yaml'
    path.write_text(text)
    settings = from_sources([path], ['window=5'])
    assert settings.config.label_cost == 500.0
    assert type(settings.config.label_cost) is float  # an integer is taken as the float
    assert settings.online.window == 5  # --set wins over the file
    assert from_sources([path]).online.window == 4


def test_parameters_and_options_reach_the_replay(tmp_path: Path) -> None:
    params = tmp_path / 'p.yaml'
    params.write_text('pearl_node:\n  ros__parameters:\n    window: 3\n    seed: 7\n')
    stats = tmp_path / 's.json'
    assert main([str(BAGS / '1R2RCR_g12_pair'), '-o', str(tmp_path / 'out'), '--params',
                 str(params), '--set', 'seed=9', 'budget_ms=0', 'solver.max_passes=4',
                 '--stats', str(stats)]) == 0
    values = json.loads(stats.read_text())['parameters']
    assert (values['window'], values['seed'], values['budget_ms']) == (3, 9, 0.0)
    assert values['solver.max_passes'] == 4  # the solver's settings are recorded too
    assert 'qos' not in values  # transport parameters play no part in a replay


def test_max_features_caps_what_is_segmented_as_the_node_does(tmp_path: Path) -> None:
    stats = tmp_path / 's.json'
    out = tmp_path / 'out'
    assert main([str(BAGS / '1R2RCR_g12'), '-o', str(out), '--set', 'max_features=100',
                 *DETERMINISTIC, '--stats', str(stats)]) == 0
    rows = json.loads(stats.read_text())['frames']
    assert {row['segmented'] for row in rows} == {100}
    assert {row['features'] for row in rows} == {153}
    for _, msg in messages(out, LABELS)[1:]:
        ids, labels = decode_labels(msg)
        assert ids.size == 153 and np.count_nonzero(labels >= 0) <= 100


# --------------------------------------------------------------------------- errors


def run(capsys: pytest.CaptureFixture[str], *args: str) -> str:
    """main(args) must fail with exactly one ``error:`` line; returns it."""
    assert main(list(args)) == 1
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert len(lines) == 1 and lines[0].startswith('error: '), captured.err
    assert 'Traceback' not in captured.err and captured.out == ''
    return lines[0]


def assert_nothing_left(folder: Path, *allowed: str) -> None:
    assert sorted(p.name for p in folder.iterdir()) == sorted(allowed)


def test_missing_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    line = run(capsys, str(tmp_path / 'nowhere'), '-o', str(tmp_path / 'out'))
    assert 'bag not found' in line
    assert_nothing_left(tmp_path)


@pytest.mark.parametrize('keep', [0.0, 0.4, 0.9])
def test_truncated_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str], keep: float) -> None:
    bag = tmp_path / 'cut'
    shutil.copytree(BAGS / 'cars2', bag)
    data = bag / 'cars2.mcap'
    content = data.read_bytes()
    data.write_bytes(content[: int(len(content) * keep)])
    line = run(capsys, str(bag), '-o', str(tmp_path / 'out'), *DETERMINISTIC)
    assert 'bag' in line
    assert_nothing_left(tmp_path, 'cut')


def test_truncated_ros1_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag = tmp_path / 'cut.bag'
    content = (BAGS / '1R2RCR_g12_ros1.bag').read_bytes()
    bag.write_bytes(content[: len(content) // 2])
    run(capsys, str(bag), '-o', str(tmp_path / 'out'))
    assert_nothing_left(tmp_path, 'cut.bag')


def test_a_ros2_bag_folder_named_dot_bag_is_explained(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = tmp_path / 'pair.bag'
    shutil.copytree(BAGS / '1R2RCR_g12_pair', bag)
    line = run(capsys, str(bag), '-o', str(tmp_path / 'out'))
    assert 'folder named *.bag' in line
    assert_nothing_left(tmp_path, 'pair.bag')


def test_unknown_topic_lists_the_bags_topics(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    line = run(capsys, str(BAGS / '1R2RCR_g12_pair'), '-o', str(tmp_path / 'out'),
               '--input-topic', '/camera/features')
    assert "no topic '/camera/features'" in line and FEATURES in line
    assert_nothing_left(tmp_path)


def test_wrong_message_type(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag = tmp_path / 'strings'
    string = TS.types['std_msgs/msg/String']
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection(FEATURES, 'std_msgs/msg/String', typestore=TS)
        writer.write(connection, 1, bytes(TS.serialize_cdr(string(data='hi'),
                                                           'std_msgs/msg/String')))
    line = run(capsys, str(bag), '-o', str(tmp_path / 'out'))
    assert 'std_msgs/msg/String' in line
    assert_nothing_left(tmp_path, 'strings')


def test_a_topic_of_the_right_type_but_no_readable_message(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # The ground truth is PointCloud2, but it has no u, v: every message is skipped, and said
    # so once (the first of its kind), then the error.
    assert main([str(BAGS / '1R2RCR_g12'), '-o', str(tmp_path / 'out'),
                 '--input-topic', TRUTH, '--truth-topic', '']) == 1
    err = capsys.readouterr().err.splitlines()
    reason = "PointCloud2 has no u, v (or x, y) fields; fields: ['id', 'label']"
    assert err == [
        f'warning: message 0 on /ground_truth/labels skipped (layout): {reason}',
        f'error: none of the 24 messages on /ground_truth/labels could be read (first: {reason})',
    ]
    assert_nothing_left(tmp_path)


@pytest.mark.parametrize('args,expected', [
    (['--set', 'no_such_parameter=1'], "unknown parameter 'no_such_parameter'"),
    (['--set', 'label_cots=1'], "unknown parameter 'label_cots' (did you mean 'label_cost'?)"),
    (['--set', 'max_feature=1'], "unknown parameter 'max_feature' (did you mean 'max_features'?)"),
    (['--set', 'label_cost=cheap'], 'invalid value for label_cost'),
    (['--set', 'window=1'], 'window must be >= 2'),
    (['--set', 'model=quadric'], 'model must be one of'),
    (['--set', 'background_motion=-2'], 'background_motion must be >= -1'),
    (['--set', 'max_features=0'], 'max_features must be >= 1'),
    (['--set', 'window'], 'expected NAME=VALUE'),
    (['--layout', 'vins_stereo'], 'invalid choice'),
    (['--storage', 'rosbag1'], 'invalid choice'),
    (['--camera-id', '-1'], 'camera_id must be >= 0, got -1'),
    (['--no-such-flag'], 'unrecognized arguments'),
])
def test_bad_parameters_and_options(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], expected: str
) -> None:
    line = run(capsys, str(BAGS / '1R2RCR_g12_pair'), '-o', str(tmp_path / 'out'), *args)
    assert expected in line
    assert_nothing_left(tmp_path)


@pytest.mark.parametrize('text,expected', [
    ('label_cost: [1, 2\n', 'not valid YAML'),
    ('- label_cost\n- 3\n', 'must hold a mapping'),
    (('other_node:\n  ros__parameters:\n    window: 3\n'
      'another:\n  ros__parameters:\n    window: 4\n'),
     'has no parameters for /pearl_node: its entries are for /other_node, /another'),
    ('other_node:\n  ros__parameters:\n    window: 3\n', 'has no parameters for /pearl_node'),
    ('/robot/pearl_node:\n  ros__parameters:\n    window: 3\n',
     'has no parameters for /pearl_node'),
    ('pearl_node:\n  ros__parameters:\n    lable_cost: 3.0\n',
     "unknown parameter 'lable_cost' (did you mean 'label_cost'?)"),
    ('label_cost: expensive\n', 'label_cost must be of type float'),
    ('warm_start: 3\n', 'warm_start must be of type bool'),
])
def test_bad_parameter_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str, expected: str
) -> None:
    params = tmp_path / 'p.yaml'
    params.write_text(text)
    line = run(capsys, str(BAGS / '1R2RCR_g12_pair'), '-o', str(tmp_path / 'out'),
               '--params', str(params))
    assert expected in line
    assert_nothing_left(tmp_path, 'p.yaml')


def test_missing_parameter_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    line = run(capsys, str(BAGS / '1R2RCR_g12_pair'), '-o', str(tmp_path / 'out'),
               '--params', str(tmp_path / 'none.yaml'))
    assert 'cannot read parameter file' in line


def test_existing_output_is_replaced_only_with_force(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / 'out'
    pair = str(BAGS / '1R2RCR_g12_pair')
    assert main([pair, '-o', str(out), *DETERMINISTIC]) == 0
    capsys.readouterr()
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert '--force' in run(capsys, pair, '-o', str(out), *DETERMINISTIC)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    # A failing replay with --force leaves the old output in place.
    run(capsys, pair, '-o', str(out), '--force', '--input-topic', '/nothing')
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert main([str(BAGS / '1R2RCR_g12'), '-o', str(out), '--force', *DETERMINISTIC]) == 0
    assert len(messages(out, LABELS)) == 24
    assert_nothing_left(tmp_path, 'out')


def test_force_never_replaces_what_is_not_a_bag(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    precious = tmp_path / 'notes'
    precious.mkdir()
    (precious / 'thesis.tex').write_text('keep me')
    assert 'not a bag' in run(capsys, str(BAGS / '1R2RCR_g12_pair'), '-o', str(precious),
                              '--force')
    assert (precious / 'thesis.tex').read_text() == 'keep me'
    assert 'is the input bag' in run(capsys, str(BAGS / '1R2RCR_g12_pair'), '-o',
                                     str(BAGS / '1R2RCR_g12_pair'), '--force')


def test_an_output_named_dot_bag_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert 'must not end in .bag' in run(capsys, str(BAGS / '1R2RCR_g12_pair'), '-o',
                                         str(tmp_path / 'out.bag'))
    assert_nothing_left(tmp_path)


def test_stats_in_a_missing_folder_fails_before_any_work(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    line = run(capsys, str(BAGS / '1R2RCR_g12_pair'), '-o', str(tmp_path / 'out'), '--stats',
               str(tmp_path / 'no' / 's.json'))
    assert '--stats folder does not exist' in line
    assert_nothing_left(tmp_path)


def test_an_interrupted_replay_leaves_nothing_behind(tmp_path: Path) -> None:
    def interrupt(done: int, total: int) -> None:
        if done == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        replay(BAGS / '1R2RCR_g12', tmp_path / 'out', progress=interrupt)
    assert_nothing_left(tmp_path)


# --------------------------------------------------------------- malformed messages


T0 = 1_700_000_000_000_000_000


def malformed_bag(path: Path) -> dict[int, str]:
    """A PointCloud bag of 12 messages, 6 of them unreadable; index -> expected skip kind."""
    cloud = TS.types['sensor_msgs/msg/PointCloud']
    header = TS.types['std_msgs/msg/Header']
    stamp_type = TS.types['builtin_interfaces/msg/Time']
    channel = TS.types['sensor_msgs/msg/ChannelFloat32']
    point = TS.types['geometry_msgs/msg/Point32']
    rng = np.random.default_rng(3)
    base = rng.uniform(0, 640, (30, 2))

    def message(stamp: int, ids: np.ndarray, uv: np.ndarray, cut: bool = False) -> Any:
        columns = {'id_of_point': ids, 'u_of_point': uv[:, 0], 'v_of_point': uv[:, 1]}
        if cut:
            columns['v_of_point'] = columns['v_of_point'][:-1]
        sec, nanosec = divmod(stamp, 10**9)
        return cloud(
            header=header(stamp=stamp_type(sec=sec, nanosec=nanosec), frame_id='c'),
            points=[point(x=0.0, y=0.0, z=1.0)] * len(ids),
            channels=[channel(name=n, values=np.asarray(v, np.float32))
                      for n, v in columns.items()],
        )

    ids = np.arange(30)
    expected = {}
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection(FEATURES, cloud.__msgtype__, typestore=TS)
        for k in range(12):
            stamp = T0 + k * 33_000_000
            uv = base + k * np.where(np.arange(30)[:, None] < 15, 1.0, -1.0)
            msg, raw = message(stamp, ids, uv), None
            if k == 2:
                msg, expected[k] = message(stamp, ids, uv, cut=True), 'layout'
            elif k == 3:
                raw, expected[k] = b'\x00\x01\x00\x00garbage', 'deserialise'
            elif k == 4:
                msg, expected[k] = message(stamp, np.r_[ids[:-1], 0], uv), 'duplicate_ids'
            elif k == 5:
                msg, expected[k] = message(stamp, ids[:0], uv[:0]), 'empty'
            elif k == 6:
                bad = uv.copy()
                bad[4, 1] = np.nan
                msg, expected[k] = message(stamp, ids, bad), 'non_finite'
            elif k == 7:  # the stamp of the last frame processed (1): refused by the segmenter
                msg, expected[k] = message(T0 + 33_000_000, ids, uv), 'stamp'
            elif k == 8:
                # Distinct as float32 (4 apart), but beyond 2**24: ids may have merged upstream.
                msg, expected[k] = message(stamp, 2**25 + 4 * ids, uv), 'ids'
            if raw is None:
                raw = bytes(TS.serialize_cdr(msg, cloud.__msgtype__))
            writer.write(connection, stamp, raw)
    return expected


def test_malformed_messages_are_skipped_counted_and_the_rest_processed(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = tmp_path / 'malformed'
    expected = malformed_bag(bag)
    out, stats_path = tmp_path / 'out', tmp_path / 's.json'
    assert main([str(bag), '-o', str(out), '--stats', str(stats_path), *DETERMINISTIC]) == 0
    captured = capsys.readouterr()
    warnings = captured.err.splitlines()
    assert len(set(expected.values())) == len(expected)  # one message of each kind
    assert len(warnings) == len(expected)  # so one warning each, and no count
    for line, index in zip(warnings, sorted(expected), strict=True):
        assert line.startswith(f'warning: message {index} on {FEATURES} skipped '
                               f'({expected[index]}): ')
    assert f'12 messages on {FEATURES}, {len(expected)} skipped' in captured.out

    stats = json.loads(stats_path.read_text())
    counts = stats['counts']
    assert counts['messages'] == 12 and counts['frames'] == 12 - len(expected)
    assert counts['skipped'] == len(expected)
    assert counts['skip_reasons'] == dict(Counter(expected.values()))
    assert {row['index']: row for row in stats['skipped']}.keys() == expected.keys()
    processed = [k for k in range(12) if k not in expected]
    assert [row['index'] for row in stats['frames']] == processed
    # The readable messages got their labels, at their own log times.
    outputs = messages(out, LABELS)
    assert [t for t, _ in outputs] == [T0 + k * 33_000_000 for k in processed]


def test_one_warning_per_kind_then_every_skip_is_counted(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cloud = 'sensor_msgs/msg/PointCloud'
    pair = messages(BAGS / '1R2RCR_g12_pair', FEATURES)
    with Writer(tmp_path / 'mixed', version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection(FEATURES, cloud, typestore=TS)
        for k in range(30):  # 30 undecodable messages first, then the two good ones
            writer.write(connection, k, b'\x00\x01\x00\x00broken')
        for t, msg in pair:
            writer.write(connection, t, bytes(TS.serialize_cdr(msg, cloud)))
    stats_path = tmp_path / 's.json'
    assert main([str(tmp_path / 'mixed'), '-o', str(tmp_path / 'out'), '--stats',
                 str(stats_path)]) == 0
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2  # the first of the kind, then the count
    assert err[0].startswith(f'warning: message 0 on {FEATURES} skipped (deserialise): '
                             'cannot deserialise sensor_msgs/msg/PointCloud')
    assert err[1] == 'warning: 30 messages skipped in all (deserialise 30)'
    counts = json.loads(stats_path.read_text())['counts']
    assert counts['skipped'] == 30 and counts['frames'] == 2
    assert counts['skip_reasons'] == {'deserialise': 30}


def test_the_progress_bar_goes_to_stderr(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main([str(BAGS / '1R2RCR_g12_pair'), '-o', str(tmp_path / 'out'), '--progress',
                 'on']) == 0
    captured = capsys.readouterr()
    assert '\r[' in captured.err and '2/2 messages' in captured.err
    assert captured.out.startswith('wrote ')
    assert main([str(BAGS / '1R2RCR_g12_pair'), '-o', str(tmp_path / 'o2')]) == 0
    assert capsys.readouterr().err == ''  # auto: stderr is not a terminal here


def test_replay_throughput_gives_one_row_per_bag() -> None:
    bags = [BAGS / '1R2RCR_g12_pair', BAGS / '1R2RCR_g12_ros1.bag']
    settings = ReplaySettings(settings=from_sources([], ['budget_ms=0']))
    rows = replay_throughput(bags, settings)
    assert [row['bag'] for row in rows] == ['1R2RCR_g12_pair', '1R2RCR_g12_ros1.bag']
    assert [row['frames'] for row in rows] == [2, 24]
    assert [row['features'] for row in rows] == [153, 153]
    assert all(row['fps'] > 0 and row['latency_p99_ms'] >= row['latency_p50_ms'] for row in rows)


def test_the_replay_runs_without_ros() -> None:
    # pearl_replay reads and writes bags with rosbags alone: it must import without rclpy,
    # so that it runs where no ROS is installed (test_layers.py holds the other modules).
    program = (
        'import sys\n'
        'class Tripwire:\n'
        '    def find_spec(self, name, path=None, target=None):\n'
        "        if name.split('.')[0] in ('rclpy', 'sensor_msgs', 'std_msgs'):\n"
        '            raise ImportError(name)\n'
        'sys.meta_path.insert(0, Tripwire())\n'
        'import pearl_ros.cli.replay\n'
        "print('ok')\n"
    )
    done = subprocess.run([sys.executable, '-c', program], capture_output=True, text=True,
                          check=False)
    assert done.returncode == 0, done.stderr
    assert done.stdout == 'ok\n'


def test_the_readme_examples_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                 capsys: pytest.CaptureFixture[str]) -> None:
    text = (REPO / 'README.md').read_text()
    section = text[text.index('## Replaying bags'):]
    section = section[:section.index('\n## ', 1)]
    commands = [line for line in section.splitlines()
                if line.startswith('.venv/bin/pearl_replay ')]
    assert len(commands) == 2
    assert 'mkdir -p build\n' in section
    monkeypatch.chdir(tmp_path)  # outputs are relative paths; inputs are in the repository
    (tmp_path / 'build').mkdir()
    for line in commands:
        args = shlex.split(line)[1:]
        args = [str(REPO / a) if a.startswith(('bags/', 'config/')) else a for a in args]
        assert main(args) == 0, capsys.readouterr().err
    stats = json.loads((tmp_path / 'build' / 'labels_1R2RCR_g12.json').read_text())
    assert stats['counts']['frames'] == 24
    assert len(messages(tmp_path / 'build' / 'labels_ros1', LABELS)) == 24


def vins_fusion_bag(path: Path, frames: int = 3) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """1R2RCR_g12's first frames as camera 1 of a VINS-Fusion cloud, with 5 camera-0 points
    interleaved; returns camera 1's (stamp, ids, uv)."""
    cloud = 'sensor_msgs/msg/PointCloud'
    types = TS.types
    source = messages(BAGS / '1R2RCR_g12', FEATURES)[:frames]
    out = []
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection(FEATURES, cloud, typestore=TS)
        for t, msg in source:
            ids, uv = decode_pointcloud(msg)
            out.append((stamp_ns(msg.header), ids, uv))
            other = np.arange(5)
            camera = np.r_[np.ones(ids.size), np.zeros(5)]
            order = np.argsort(np.r_[np.arange(ids.size) * 2.0, np.arange(5) * 2.0 + 1.5])
            columns = [np.r_[ids, other], camera, np.r_[uv[:, 0], other * 10.0],
                       np.r_[uv[:, 1], other * 10.0], np.zeros(ids.size + 5),
                       np.zeros(ids.size + 5)]
            fused = types[cloud](
                header=msg.header,
                points=[types['geometry_msgs/msg/Point32'](x=float(k), y=0.0, z=1.0)
                        for k in range(ids.size + 5)],
                # Unnamed channels by index, as VINS-Fusion: id, camera, u, v, vx, vy.
                channels=[types['sensor_msgs/msg/ChannelFloat32'](
                    name='', values=np.asarray(c[order], np.float32)) for c in columns],
            )
            writer.write(connection, t, bytes(TS.serialize_cdr(fused, cloud)))
    return out


def test_vins_fusion_layout_segments_one_camera_and_passes_the_others_through(
    tmp_path: Path
) -> None:
    bag, out = tmp_path / 'fusion', tmp_path / 'out'
    camera1 = vins_fusion_bag(bag)
    assert main([str(bag), '-o', str(out), '--layout', 'vins_fusion', '--camera-id', '1',
                 *DETERMINISTIC]) == 0
    segmenter = OnlineSegmenter(*build_configs({'budget_ms': 0.0}))
    for (stamp, ids, uv), (_, labels_msg), (_, static), (_, msg_in) in zip(
            camera1, messages(out, LABELS), messages(out, STATIC), messages(bag, FEATURES),
            strict=True):
        label_ids, labels = decode_labels(labels_msg)
        np.testing.assert_array_equal(label_ids, ids)  # camera 1 only, in input order
        np.testing.assert_array_equal(labels, segmenter.process(stamp, ids, uv).labels)
        # static_features: the same cloud, camera 0's points untouched, camera 1's background.
        camera = np.asarray(static.channels[1].values)
        assert np.count_nonzero(camera == 0) == 5
        counts = Counter(label for label in labels.tolist() if label >= 0)
        expected = set()
        if counts:
            most = max(counts.values())
            background = min(label for label, n in counts.items() if n == most)
            expected = set(ids[labels == background].tolist())
        assert set(np.asarray(static.channels[0].values)[camera == 1].astype(int)) == expected
        assert len(static.channels) == len(msg_in.channels) == 6
