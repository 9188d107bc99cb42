"""Malformed input (issue 4's list): a throttled warning, a diagnostics count, no output for
the unreadable message, and the node goes on answering good messages."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.node import Node
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import StoragePlugin, Writer
from sensor_msgs.msg import PointCloud2

from pearl_ros.bagio import decode, encode
from pearl_ros.bagio.reader import TYPESTORE as TS
from pearl_ros.bagio.reader import read_feature_frames
from pearl_ros.pipeline.replay import replay
from pearl_ros.ros import convert

from ros_harness import BAG, RELIABLE, Probe, Ros, vins_cloud

T0 = 1_700_000_000_000_000_000  # ns
STEP = 33_333_333  # ns, 30 Hz
FEATURES = '/feature_tracker/feature'
IDS = np.arange(10, 22)
UV = np.column_stack((np.linspace(10, 300, 12), np.linspace(40, 200, 12)))


def good(k: int) -> object:
    return vins_cloud(T0 + k * STEP, IDS, UV + k)


def nan_cloud(k: int) -> object:
    uv = UV.copy()
    uv[3, 0] = np.nan
    return vins_cloud(T0 + k * STEP, IDS, uv)


def inf_cloud(k: int) -> object:
    uv = UV.copy()
    uv[5, 1] = np.inf
    return vins_cloud(T0 + k * STEP, IDS, uv)


def duplicate_ids(k: int) -> object:
    ids = IDS.copy()
    ids[4] = ids[7]
    return vins_cloud(T0 + k * STEP, ids, UV)


def short_channel(k: int) -> object:
    return vins_cloud(T0 + k * STEP, IDS, UV, channels={
        'id_of_point': IDS, 'u_of_point': UV[:-1, 0], 'v_of_point': UV[:, 1]})


def missing_id_channel(k: int) -> object:
    return vins_cloud(T0 + k * STEP, IDS, UV, channels={
        'u_of_point': UV[:, 0], 'v_of_point': UV[:, 1]})


def huge_float32_ids(k: int) -> object:
    # 2**24 + 2 is exact in float32, but its neighbour 2**24 + 1 is not: such ids are unsafe.
    ids = IDS.copy()
    ids[0] = 2**24 + 2
    return vins_cloud(T0 + k * STEP, ids, UV)


# case -> (message maker, kind of skip, words of the reason)
MALFORMED = {
    'nan coordinates': (nan_cloud, 'non_finite', 'non-finite'),
    'inf coordinates': (inf_cloud, 'non_finite', 'non-finite'),
    'duplicate ids': (duplicate_ids, 'duplicate_ids', 'repeats feature id'),
    'channel length differs from the point count': (short_channel, 'layout',
                                                    '11 values for 12 points'),
    'missing channels': (missing_id_channel, 'layout', 'cannot tell the PointCloud layout'),
    'ids above 2**24 as float32': (huge_float32_ids, 'ids', 'above 2**24'),
}


def _start(ros: Ros, **overrides: object) -> tuple[Node, Probe]:
    # Reliable input, so that a burst of messages sent between two spins cannot be dropped,
    # and every message answered (or counted as malformed), however slow the node.
    node = ros.pearl(qos='reliable', qos_depth=50, queue_policy='all', **overrides)
    probe = ros.probe()
    probe.wait_for(node)
    return node, probe


@pytest.mark.parametrize('case', sorted(MALFORMED))
def test_malformed_message_is_warned_once_counted_and_left_unanswered(
    ros: Ros, case: str
) -> None:
    make, kind, reason = MALFORMED[case]
    _, probe = _start(ros)
    probe.send(good(0))
    # Three bad messages in a row: three counts, one warning (throttled), no labels.
    for k in (1, 2, 3):
        probe.send(make(k), answered=False)
    probe.send(good(4))  # answered: the node kept running, and went through 1-3 before it
    assert [decode.stamp_ns(m.header) for m in probe.labels] == [T0, T0 + 4 * STEP]
    assert [decode.stamp_ns(m.header) for m in probe.static] == [T0, T0 + 4 * STEP]
    values = probe.diagnostics_where(lambda v: v['messages processed'] == '2')
    assert values['malformed messages'] == '3'
    assert values['messages received'] == '5'
    assert values['skipped messages'] == '0'
    assert ros.spin_until(lambda: probe.warnings(f'skipped ({kind})'))
    ros.spin_until(lambda: False, 0.2)  # let any further warning arrive
    warnings = probe.warnings('skipped')
    assert len(warnings) == 1, warnings
    assert warnings[0].startswith(f'PointCloud message skipped ({kind}): ')
    assert reason in warnings[0]


def test_node_and_replay_answer_a_bad_message_with_the_same_line(
    ros: Ros, tmp_path: Path
) -> None:
    # The same messages, live to the node and recorded in a bag for the replay engine.
    makers = [make for make, _, _ in MALFORMED.values()]
    sent = [good(0), *(make(k + 1) for k, make in enumerate(makers)), empty(len(makers) + 1)]
    bag = tmp_path / 'bad'
    cloud = 'sensor_msgs/msg/PointCloud'
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection(FEATURES, cloud, typestore=TS)
        for msg in sent:
            writer.write(connection, decode.stamp_ns(msg.header), serialize_message(msg))
    replayed: dict[str, str] = {}  # kind -> the first line, as pearl_replay prints it
    replay(bag, tmp_path / 'out', warn=lambda index, skip: replayed.setdefault(skip.kind,
                                                                               skip.line))
    assert len(replayed) == 5

    _, probe = _start(ros)
    for msg in sent:
        probe.send(msg, answered=msg is sent[0])
    probe.send(good(len(sent)))
    assert ros.spin_until(lambda: len(probe.warnings('skipped')) == len(replayed))
    # One warning per kind in both front ends, the same words after their own context.
    node_lines = [line.removeprefix('PointCloud message ') for line in probe.warnings('skipped')]
    assert sorted(node_lines) == sorted(replayed.values())


def test_a_period_with_malformed_messages_is_reported_as_a_warning(ros: Ros) -> None:
    _, probe = _start(ros)
    probe.send(nan_cloud(0), answered=False)
    values = probe.diagnostics_where(lambda v: v['malformed messages'] == '1')
    assert values['_level'] == DiagnosticStatus.WARN
    assert 'malformed or skipped' in values['_message']


def empty(k: int) -> object:
    return vins_cloud(T0 + k * STEP, [], np.empty((0, 2)))


def test_empty_cloud_is_skipped_without_output(ros: Ros) -> None:
    _, probe = _start(ros)
    probe.send(empty(0), answered=False)
    probe.send(good(1))
    assert [decode.stamp_ns(m.header) for m in probe.labels] == [T0 + STEP]
    values = probe.diagnostics_where(lambda v: v['messages processed'] == '1')
    assert (values['skipped messages'], values['malformed messages']) == ('1', '0')
    assert ros.spin_until(lambda: probe.warnings('skipped (empty): empty cloud: no features'))


def test_repeated_stamp_is_skipped_without_output(ros: Ros) -> None:
    _, probe = _start(ros)
    probe.send(good(0))
    probe.send(vins_cloud(T0, IDS, UV + 5), answered=False)
    probe.send(good(1))
    assert len(probe.labels) == 2
    values = probe.diagnostics_where(lambda v: v['messages processed'] == '2')
    assert values['skipped messages'] == '1'
    assert ros.spin_until(lambda: probe.warnings('skipped (stamp): stamp'))
    assert 'repeats the previous frame' in probe.warnings('skipped (stamp)')[0]


def test_stamp_going_back_empties_the_window_and_is_logged_once(ros: Ros) -> None:
    frames = list(read_feature_frames(BAG))[:6]
    # Unbudgeted: the labels of the first frames are then the frames' own, however slow the
    # machine (a budgeted cold start answers its labels some frames late).
    _, probe = _start(ros, budget_ms=0.0)
    for frame in frames[:4]:
        answer = probe.send(vins_cloud(frame.stamp_ns, frame.ids, frame.uv))
    assert (decode.decode_fields(answer, ('label',))['label'] >= 0).any()
    # The bag again from its start (a looped replay): answered, from an emptied window.
    answer = probe.send(vins_cloud(frames[0].stamp_ns, frames[0].ids, frames[0].uv))
    labels = decode.decode_fields(answer, ('label',))['label']
    assert (labels == -1).all()  # one frame in the window: nothing can be fitted yet
    values = probe.diagnostics_where(lambda v: v['messages processed'] == '5')
    assert values['window resets (stamp went back)'] == '1'
    assert values['frames in window'] == '1'
    answer = probe.send(vins_cloud(frames[1].stamp_ns, frames[1].ids, frames[1].uv))
    assert ros.spin_until(lambda: probe.warnings('went back in time'))
    ros.spin_until(lambda: False, 0.2)
    assert len(probe.warnings('went back in time')) == 1


def test_message_larger_than_max_features_is_subsampled_by_id(ros: Ros) -> None:
    frames = list(read_feature_frames(BAG))[:6]
    _, probe = _start(ros, max_features=40)
    kept = []
    rng = np.random.default_rng(3)
    for frame in frames:
        order = rng.permutation(frame.ids.size)  # the subsample must not depend on the order
        answer = probe.send(vins_cloud(frame.stamp_ns, frame.ids[order], frame.uv[order]))
        ids = decode.decode_fields(answer, ('id',))['id']
        labels = decode.decode_fields(answer, ('label',))['label']
        assert ids.size == frame.ids.size == 153  # one label per input feature, still
        np.testing.assert_array_equal(ids, frame.ids[order])
        kept.append(set(ids[labels >= 0].tolist()))
    # The last frames are fitted: at most 40 features labelled, always the same ones.
    assert 0 < len(kept[-1]) <= 40
    assert kept[-1] == kept[-2]
    values = probe.diagnostics_where(lambda v: v['messages processed'] == '6')
    assert values['capped messages'] == '6'
    assert (values['features'], values['features segmented']) == ('153', '40')
    assert ros.spin_until(lambda: probe.warnings('max_features 40'))
    assert len(probe.warnings('max_features 40')) == 1


def test_publisher_of_another_type_is_reported_and_delivers_nothing(ros: Ros) -> None:
    # rclpy refuses a second type on one topic name within a context, so the wrong publisher
    # lives in a context (a DDS participant) of its own, as another process would.
    node, probe = _start(ros)
    other = rclpy.Context()
    rclpy.init(context=other)
    stranger = Node('stranger', context=other, namespace=ros.ns)
    try:
        wrong = stranger.create_publisher(PointCloud2, 'features', RELIABLE)
        cloud = encode.motion_labels(vins_cloud(T0, [], np.empty((0, 2))).header, IDS, UV,
                                     np.zeros(12, np.int64), convert.TYPES)
        assert ros.spin_until(
            lambda: len(node.get_publishers_info_by_topic(f'{ros.ns}/features')) == 2, 10.0)
        for _ in range(3):
            wrong.publish(cloud)
        values = probe.diagnostics_where(lambda v: v['publishers of another type'] == '1')
        assert values['_level'] == DiagnosticStatus.WARN
        assert 'another type' in values['_message']
        assert ros.spin_until(lambda: probe.warnings('sensor_msgs/msg/PointCloud2'))
        warning = probe.warnings('sensor_msgs/msg/PointCloud2')[0]
        assert 'msg_type is PointCloud' in warning
        assert values['messages received'] == '0'  # DDS matched nothing across types
        probe.send(good(1))  # and the right publisher is still served
    finally:
        stranger.destroy_node()
        rclpy.shutdown(context=other)



def test_records_that_are_not_a_pointcloud_are_counted_and_the_node_goes_on(ros: Ros) -> None:
    # Raw bytes on the wire, as a broken publisher or a bridge could send them: the node reads
    # CDR itself (a raw subscription), so a broken record must be its error, not rclpy's.
    _, probe = _start(ros)
    probe.send(good(0))
    whole = serialize_message(good(1))
    broken = [whole[:40],  # truncated inside the points
              b'\x00\x07' + whole[2:],  # not an encapsulation CDR has
              # the point count (bytes 24-27, after the header with frame 'cam0') past the end
              whole[:24] + b'\xff\xff\xff\x7f' + whole[28:]]
    for raw in broken:
        probe.publisher.publish(raw)
    probe.send(good(2))
    assert [decode.stamp_ns(m.header) for m in probe.labels] == [T0, T0 + 2 * STEP]
    values = probe.diagnostics_where(lambda v: v['messages processed'] == '2')
    assert values['malformed messages'] == '3'
    assert ros.spin_until(lambda: probe.warnings('skipped (deserialise)'))
    line = probe.warnings('skipped (deserialise)')[0]
    assert 'cannot deserialise sensor_msgs/msg/PointCloud' in line and '\n' not in line
