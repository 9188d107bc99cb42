"""pearl_play's bag side: ROS 1 and PointCloud2 bags, the message type it tells the node, and
the one-line errors. ``test/test_demo.py`` plays every bundled bag into a real pearl_node."""

from __future__ import annotations

import os
import subprocess
import sys
import uuid
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from pearl_ros.pipeline.replay import replay
from pearl_ros.ros.play import load_bag, main

from bag_oracles import raw_messages
from ros_harness import REPO, Ros

BAGS = REPO / 'bags'
FEATURES = '/feature_tracker/feature'
TS = get_typestore(Stores.ROS2_KILTED)


def _points(msg: object) -> np.ndarray:
    return np.array([(p.x, p.y, p.z) for p in msg.points], dtype=np.float32)


def test_a_ros1_bag_gives_the_messages_of_its_ros2_twin() -> None:
    played = load_bag(BAGS / '1R2RCR_g12_ros1.bag')
    twin = raw_messages(BAGS / '1R2RCR_g12', FEATURES)  # rosbags alone
    assert (played.msg_type, played.skipped, len(played.messages)) == ('PointCloud', [], 24)
    for msg, expected in zip(played.messages, twin, strict=True):
        assert type(msg).__module__.startswith('sensor_msgs.msg')  # rclpy's class
        assert (msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id) == (
            expected.header.stamp.sec, expected.header.stamp.nanosec, expected.header.frame_id)
        np.testing.assert_array_equal(_points(msg), _points(expected))
        assert [c.name for c in msg.channels] == [c.name for c in expected.channels]
        for channel, other in zip(msg.channels, expected.channels, strict=True):
            np.testing.assert_array_equal(np.asarray(channel.values, dtype=np.float32),
                                          np.asarray(other.values, dtype=np.float32))


def test_a_pointcloud2_bag_plays_pointcloud2_messages_with_their_bytes() -> None:
    played = load_bag(BAGS / '1R2RCR_g12_pc2')
    twin = raw_messages(BAGS / '1R2RCR_g12_pc2', FEATURES)
    assert played.msg_type == 'PointCloud2'
    for msg, expected in zip(played.messages, twin, strict=True):
        assert bytes(msg.data) == bytes(expected.data)
        assert [f.name for f in msg.fields] == [f.name for f in expected.fields]


@pytest.mark.parametrize(('bag', 'expected'), [
    ('1R2RCR_g12', 'PointCloud'), ('1R2RCR_g12_pc2', 'PointCloud2'),
    ('1R2RCR_g12_ros1.bag', 'PointCloud'), ('synthetic_births_deaths', 'PointCloud'),
])
def test_msg_type_prints_the_type_the_node_must_be_told(
    bag: str, expected: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main([str(BAGS / bag), '--msg-type']) == 0
    assert capsys.readouterr() == (expected + '\n', '')


def test_bad_input_gets_one_error_line(capsys: pytest.CaptureFixture[str]) -> None:
    bag = BAGS / '1R2RCR_g12'
    cases = {
        (str(BAGS / 'missing'),): f'error: bag not found: {BAGS / "missing"}',
        (str(bag), '--msg-type', '--topic', '/nope'):
            f"error: {bag}: no topic '/nope'; topics: {FEATURES}, /ground_truth/labels",
        # A PointCloud2 topic without pixels: the node would refuse every message.
        (str(bag), '--topic', '/ground_truth/labels'):
            f'error: {bag}: no message on /ground_truth/labels can be played (first: '
            'PointCloud2 has no',  # ... pixel fields: the decoder's own words follow
        (str(bag), '--rate', 'fast'): "error: argument --rate: invalid float value: 'fast'",
    }
    for argv, expected in cases.items():
        assert main(list(argv)) == 1, argv
        out, err = capsys.readouterr()
        assert out == '' and err.startswith(expected) and err.count('\n') == 1, (argv, err)


def test_help_prints_usage_and_exits_0(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(['--help']) == 0
    assert capsys.readouterr().out.startswith('usage: pearl_play [-h] [--msg-type]')


def test_a_node_told_another_type_is_named_with_the_fix(ros: Ros) -> None:
    ros.pearl()  # msg_type PointCloud, the default
    done = subprocess.run(
        [str(Path(sys.executable).parent / 'pearl_play'), str(BAGS / '1R2RCR_g12_pc2'),
         '--features', f'{ros.ns}/features', '--labels', f'{ros.ns}/motion_labels',
         '--timeout', '5'],
        capture_output=True, text=True, timeout=120, env=dict(os.environ), check=False)
    assert done.returncode == 1
    assert done.stderr == (
        f'error: pearl_node subscribes sensor_msgs/msg/PointCloud on {ros.ns}/features but the '
        'bag has sensor_msgs/msg/PointCloud2: start it with -p msg_type:=PointCloud2\n')


def _bag_with_bad_messages(path: Path) -> None:
    """Seven messages: 0 and 5 good, 1 and 3 with a NaN pixel, 2 with a repeated id, 4 empty,
    6 not a PointCloud at all."""
    cloud = 'sensor_msgs/msg/PointCloud'
    msgs = raw_messages(BAGS / '1R2RCR_g12', FEATURES)[:6]

    def set_channel(msg: object, name: str, index: int, value: float) -> None:
        channel = next(c for c in msg.channels if c.name == name)
        channel.values = np.array(channel.values, dtype=np.float32)
        channel.values[index] = value

    set_channel(msgs[1], 'u_of_point', 0, np.nan)
    set_channel(msgs[3], 'u_of_point', 7, np.nan)
    set_channel(msgs[2], 'id_of_point', 1, msgs[2].channels[0].values[0])
    msgs[4].points = []
    for channel in msgs[4].channels:
        channel.values = np.zeros(0, dtype=np.float32)
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection(FEATURES, cloud, typestore=TS)
        for k, msg in enumerate(msgs):
            writer.write(connection, k + 1, bytes(TS.serialize_cdr(msg, cloud)))
        writer.write(connection, 7, b'\x00\x01\x00\x00not a cloud')


def test_a_bad_message_is_held_back_with_the_line_pearl_replay_gives_it(tmp_path: Path) -> None:
    bag = tmp_path / 'bad'
    _bag_with_bad_messages(bag)
    replayed: list[tuple[int, str]] = []  # what pearl_replay says of each message it skips
    replay(bag, tmp_path / 'out', warn=lambda index, skip: replayed.append((index, skip.line)))
    played = load_bag(bag)
    assert [index for index, _ in replayed] == [1, 2, 3, 4, 6]
    assert [(index, skip.line) for index, skip in played.skipped] == replayed
    good = raw_messages(BAGS / '1R2RCR_g12', FEATURES)
    assert [(msg.header.stamp.sec, msg.header.stamp.nanosec) for msg in played.messages] == [
        (good[k].header.stamp.sec, good[k].header.stamp.nanosec) for k in (0, 5)]


def test_bad_messages_are_warned_once_per_kind_then_counted(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = tmp_path / 'bad'
    _bag_with_bad_messages(bag)
    lines = dict(((index, skip.kind), skip.line) for index, skip in load_bag(bag).skipped)
    ns = f'/play_{uuid.uuid4().hex[:8]}'  # no node listens there: the player gives up
    argv = [str(bag), '--features', f'{ns}/features', '--labels', f'{ns}/labels', '--timeout',
            '0.2']
    assert main(argv) == 1
    out, err = capsys.readouterr()
    assert out == ''
    assert err.splitlines() == [
        f'warning: message 1 on {FEATURES} {lines[1, "non_finite"]}',
        f'warning: message 2 on {FEATURES} {lines[2, "duplicate_ids"]}',
        f'warning: message 4 on {FEATURES} {lines[4, "empty"]}',
        f'warning: message 6 on {FEATURES} {lines[6, "deserialise"]}',
        'warning: 5 messages skipped in all (deserialise 1, duplicate_ids 1, empty 1, '
        'non_finite 2)',
        f'error: no pearl_node subscribed to {ns}/features and publishing {ns}/labels within '
        '0.2 s',
    ]
