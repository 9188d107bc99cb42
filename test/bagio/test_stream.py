"""The replay's bag I/O: a feature stream that reports bad messages, and an atomic output bag."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from pearl_ros.bagio import (
    CopiedMessage,
    FeatureFrame,
    FeatureMessage,
    decode_feature_message,
    open_feature_stream,
    open_output_bag,
    read_feature_frames,
    write_feature_bag,
)
from pearl_ros.bagio.decode import decode_labels
from pearl_ros.bagio.writer import write_ros1_bag
from pearl_ros.core.errors import BagError, InputError

from bag_oracles import raw_messages

TS = get_typestore(Stores.ROS2_KILTED)
T0 = 1_700_000_000_000_000_000
FEATURES = '/feature_tracker/feature'
TRUTH = '/ground_truth/labels'
BAGS = Path(__file__).resolve().parents[2] / 'bags'


def frames(count: int = 4, points: int = 20) -> list[FeatureFrame]:
    rng = np.random.default_rng(5)
    return [FeatureFrame(T0 + k * 10**8, np.arange(points), rng.uniform(0, 640, (points, 2)))
            for k in range(count)]


def test_stream_yields_frames_and_copies_in_log_time_order(tmp_path: Path) -> None:
    bag = tmp_path / 'bag'
    source = frames()
    write_feature_bag(bag, source, [(f.stamp_ns, f.ids, f.ids % 3) for f in source])
    with open_feature_stream(bag, copy_topics=(TRUTH, '/absent')) as stream:
        assert stream.count == 4 and stream.msgtypes == ('sensor_msgs/msg/PointCloud',)
        assert stream.copied == {TRUTH: 'sensor_msgs/msg/PointCloud2'}
        assert not stream.ros1
        items = list(stream)
    times = [item.log_time_ns for item in items]
    assert times == sorted(times)
    got = [item for item in items if isinstance(item, FeatureMessage)]
    copies = [item for item in items if isinstance(item, CopiedMessage)]
    assert [item.index for item in got] == [0, 1, 2, 3] and len(copies) == 4
    for item, frame in zip(got, source, strict=True):
        assert item.error is None and item.msg is not None
        decoded = decode_feature_message(item.msg, item.msgtype)
        np.testing.assert_array_equal(decoded.ids, frame.ids)
        assert decoded.stamp_ns == frame.stamp_ns == item.log_time_ns
    for copy, truth in zip(copies, raw_messages(bag, TRUTH), strict=True):
        msg = TS.deserialize_cdr(copy.cdr, copy.msgtype)
        np.testing.assert_array_equal(decode_labels(msg)[1], decode_labels(truth)[1])


def test_stream_reports_an_undeserialisable_message_instead_of_raising(tmp_path: Path) -> None:
    bag = tmp_path / 'bad'
    cloud2 = 'sensor_msgs/msg/PointCloud2'
    good = raw_messages(BAGS / '1R2RCR_g12_pc2', FEATURES)[:2]
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection(FEATURES, cloud2, typestore=TS)
        writer.write(connection, 1, bytes(TS.serialize_cdr(good[0], cloud2)))
        writer.write(connection, 2, b'\x00\x01\x00\x00not a cloud')
        truncated = good[1]
        truncated.data = truncated.data[:-5]
        writer.write(connection, 3, bytes(TS.serialize_cdr(truncated, cloud2)))
    with open_feature_stream(bag) as stream:
        first, second, third = list(stream)
    assert first.msg is not None and first.error is None
    assert second.msg is None
    assert second.error.startswith('cannot deserialise sensor_msgs/msg/PointCloud2')
    # Deserialised, but malformed: the stream passes it on, decoding refuses it.
    assert third.msg is not None and third.error is None
    with pytest.raises(InputError, match='data has'):
        decode_feature_message(third.msg, third.msgtype)
    # The strict reader stops at the same message.
    with pytest.raises(BagError):
        list(read_feature_frames(bag))


def test_stream_from_a_ros1_bag_copies_truth_as_ros2_cdr() -> None:
    with open_feature_stream(BAGS / '1R2RCR_g12_ros1.bag', copy_topics=(TRUTH,)) as stream:
        assert stream.ros1
        items = list(stream)
    copies = [item for item in items if isinstance(item, CopiedMessage)]
    originals = raw_messages(BAGS / '1R2RCR_g12', TRUTH)
    assert len(copies) == len(originals) == 24
    for copy, original in zip(copies, originals, strict=True):
        msg = TS.deserialize_cdr(copy.cdr, copy.msgtype)
        assert msg.header.stamp == original.header.stamp
        for a, b in zip(decode_labels(msg), decode_labels(original), strict=True):
            np.testing.assert_array_equal(a, b)


def test_stream_refuses_missing_bags_topics_and_types(tmp_path: Path) -> None:
    with pytest.raises(BagError, match='bag not found'), open_feature_stream(tmp_path / 'none'):
        pass
    with (
        pytest.raises(BagError, match="no topic '/x'"),
        open_feature_stream(BAGS / '1R2RCR_g12_pair', topic='/x'),
    ):
        pass


def pointcloud(ids: list[float], uv: list[tuple[float, float]]) -> object:
    cloud = TS.types['sensor_msgs/msg/PointCloud']
    header = TS.types['std_msgs/msg/Header']
    stamp = TS.types['builtin_interfaces/msg/Time']
    channel = TS.types['sensor_msgs/msg/ChannelFloat32']
    point = TS.types['geometry_msgs/msg/Point32']
    u = [p[0] for p in uv]
    v = [p[1] for p in uv]
    return cloud(
        header=header(stamp=stamp(sec=3, nanosec=5), frame_id='cam'),
        points=[point(x=0.0, y=0.0, z=1.0) for _ in ids],
        channels=[channel(name=n, values=np.asarray(c, np.float32))
                  for n, c in (('id_of_point', ids), ('u_of_point', u), ('v_of_point', v))],
    )


def test_decode_feature_message_refuses_what_the_node_refuses() -> None:
    kind = 'sensor_msgs/msg/PointCloud'
    frame = decode_feature_message(pointcloud([4, 7], [(1, 2), (3, 4)]), kind)
    assert frame.stamp_ns == 3_000_000_005 and frame.ids.tolist() == [4, 7]
    with pytest.raises(InputError, match='empty cloud'):
        decode_feature_message(pointcloud([], []), kind)
    with pytest.raises(InputError, match='2\\*\\*24'):
        decode_feature_message(pointcloud([2**25, 7], [(1, 2), (3, 4)]), kind)
    with pytest.raises(InputError, match=r'\[0, 2\*\*32\)'):
        decode_feature_message(pointcloud([-1, 7], [(1, 2), (3, 4)]), kind)
    with pytest.raises(InputError, match='not a feature message type'):
        decode_feature_message(pointcloud([1], [(1, 2)]), 'std_msgs/msg/String')


def write_two(out: object) -> None:
    string = TS.types['std_msgs/msg/String']
    out.add_topic('/a', 'std_msgs/msg/String')
    out.write('/a', 1, string(data='one'))
    out.write_cdr('/a', 2, bytes(TS.serialize_cdr(string(data='two'), 'std_msgs/msg/String')))


def test_output_bag_appears_only_when_complete(tmp_path: Path) -> None:
    target = tmp_path / 'out'
    with open_output_bag(target) as out:
        write_two(out)
        assert not target.exists()
        assert out.counts == {'/a': 2}
    assert [m.data for m in raw_messages(target, '/a')] == ['one', 'two']
    assert sorted(p.name for p in tmp_path.iterdir()) == ['out']


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_output_bag_failure_leaves_nothing_and_keeps_an_old_bag(
    tmp_path: Path, storage: str
) -> None:
    target = tmp_path / 'out'
    with pytest.raises(RuntimeError), open_output_bag(target, storage=storage) as out:
        write_two(out)
        raise RuntimeError('boom')
    assert list(tmp_path.iterdir()) == []
    with open_output_bag(target, storage=storage) as out:
        write_two(out)
    before = {p.name: p.read_bytes() for p in target.iterdir()}
    with (
        pytest.raises(KeyboardInterrupt),
        open_output_bag(target, storage=storage, replace=True) as out,
    ):
        write_two(out)
        raise KeyboardInterrupt
    assert {p.name: p.read_bytes() for p in target.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ['out']


def test_output_bag_replaces_only_a_bag_and_only_when_asked(tmp_path: Path) -> None:
    target = tmp_path / 'out'
    with open_output_bag(target) as out:
        write_two(out)
    with pytest.raises(BagError, match='exists'), open_output_bag(target):
        pass
    with open_output_bag(target, replace=True) as out:
        out.add_topic('/b', 'std_msgs/msg/String')
    assert raw_messages(target, '/a') == []
    folder = tmp_path / 'folder'
    folder.mkdir()
    with pytest.raises(BagError, match='not a bag'), open_output_bag(folder, replace=True):
        pass
    with (
        pytest.raises(InputError, match='must not end in .bag'),
        open_output_bag(tmp_path / 'x.bag'),
    ):
        pass
    with (
        pytest.raises(BagError, match='output folder does not exist'),
        open_output_bag(tmp_path / 'no' / 'out'),
    ):
        pass
    with (
        pytest.raises(InputError, match='storage'),
        open_output_bag(tmp_path / 'y', storage='rosbag1'),
    ):
        pass
    with open_output_bag(tmp_path / 'z') as out:
        with pytest.raises(InputError, match='not a ROS 2 Kilted message type'):
            out.add_topic('/c', 'my_msgs/msg/Thing')
        with pytest.raises(InputError, match='was not added'):
            out.write_cdr('/d', 1, b'')


def test_write_ros1_bag_checks_its_target(tmp_path: Path) -> None:
    with pytest.raises(InputError, match='must end in .bag'):
        write_ros1_bag(BAGS / '1R2RCR_g12_pair', tmp_path / 'x')
    target = tmp_path / 'x.bag'
    write_ros1_bag(BAGS / '1R2RCR_g12_pair', target)
    assert len(list(read_feature_frames(target))) == 2
    with pytest.raises(BagError, match='exists'):
        write_ros1_bag(BAGS / '1R2RCR_g12_pair', target)
    assert sorted(p.name for p in tmp_path.iterdir()) == ['x.bag']
