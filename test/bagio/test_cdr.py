"""CDR bytes <-> feature messages (pearl_ros.bagio.cdr), against rclpy's and rosbags' own
serialisers as oracles: what they write is read back field for field, what we write they read
back field for field, and broken records give InputError, never another exception."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from pearl_ros.bagio import cdr
from pearl_ros.core.errors import InputError

TS = get_typestore(Stores.ROS2_KILTED)
RNG_SEED = 3


def _rclpy_cloud(rng: np.random.Generator, points: int, names: list[str]) -> Any:
    from builtin_interfaces.msg import Time
    from geometry_msgs.msg import Point32
    from sensor_msgs.msg import ChannelFloat32, PointCloud
    from std_msgs.msg import Header

    xyz = rng.normal(size=(points, 3)).astype(np.float32)
    return PointCloud(
        header=Header(stamp=Time(sec=1_700_000_123, nanosec=987_654_321), frame_id='cam_ü'),
        points=[Point32(x=float(x), y=float(y), z=float(z)) for x, y, z in xyz.tolist()],
        channels=[ChannelFloat32(name=name, values=rng.normal(size=points).astype(np.float32)
                                 .tolist()) for name in names],
    )


def _rclpy_cloud2(rng: np.random.Generator, height: int, width: int, pad: int) -> Any:
    from builtin_interfaces.msg import Time
    from sensor_msgs.msg import PointCloud2, PointField
    from std_msgs.msg import Header

    point_step = 13  # odd on purpose: fields need not be aligned inside a point
    row_step = width * point_step + pad
    return PointCloud2(
        header=Header(stamp=Time(sec=-5, nanosec=7), frame_id=''),
        height=height, width=width,
        fields=[PointField(name='id', offset=0, datatype=PointField.UINT32, count=1),
                PointField(name='u', offset=4, datatype=PointField.FLOAT32, count=1),
                PointField(name='v', offset=8, datatype=PointField.FLOAT32, count=1),
                PointField(name='k', offset=12, datatype=PointField.UINT8, count=1)],
        is_bigendian=True, point_step=point_step, row_step=row_step,
        data=rng.integers(0, 256, height * row_step).astype(np.uint8).tolist(),
        is_dense=True,
    )


def _same_header(a: Any, b: Any) -> None:
    assert (a.stamp.sec, a.stamp.nanosec, a.frame_id) == (b.stamp.sec, b.stamp.nanosec,
                                                          b.frame_id)


def _same_cloud(ours: Any, theirs: Any) -> None:
    _same_header(ours.header, theirs.header)
    xyz = np.array([(p.x, p.y, p.z) for p in theirs.points], np.float32).reshape(-1, 3)
    np.testing.assert_array_equal(np.asarray(ours.points).reshape(-1, 3), xyz)
    assert [c.name for c in ours.channels] == [c.name for c in theirs.channels]
    for mine, other in zip(ours.channels, theirs.channels, strict=True):
        np.testing.assert_array_equal(np.asarray(mine.values, np.float32),
                                      np.asarray(other.values, np.float32))


def _same_cloud2(ours: Any, theirs: Any) -> None:
    _same_header(ours.header, theirs.header)
    for name in ('height', 'width', 'is_bigendian', 'point_step', 'row_step', 'is_dense'):
        assert getattr(ours, name) == getattr(theirs, name), name
    assert ([(f.name, f.offset, f.datatype, f.count) for f in ours.fields]
            == [(f.name, f.offset, f.datatype, f.count) for f in theirs.fields])
    np.testing.assert_array_equal(np.asarray(ours.data, np.uint8),
                                  np.asarray(theirs.data, np.uint8))


@pytest.mark.parametrize(('points', 'names'), [
    (0, []), (1, ['id_of_point']), (7, ['id_of_point', 'u_of_point', 'v_of_point']),
    (500, ['a', 'bb', 'ccc', 'dddd', 'eeeee', 'ffffff'])])
def test_pointcloud_read_and_written_as_rclpy_does(points: int, names: list[str]) -> None:
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import PointCloud

    theirs = _rclpy_cloud(np.random.default_rng(RNG_SEED), points, names)
    ours = cdr.read(serialize_message(theirs), cdr.POINTCLOUD)
    _same_cloud(ours, theirs)
    back = deserialize_message(cdr.serialize(ours), PointCloud)
    _same_cloud(ours, back)
    # rosbags reads our bytes too (the replay writes them into bags)
    _same_cloud(ours, TS.deserialize_cdr(cdr.serialize(ours), cdr.POINTCLOUD))


@pytest.mark.parametrize(('height', 'width', 'pad'), [(0, 0, 0), (1, 1, 0), (1, 40, 0),
                                                     (3, 5, 3)])
def test_pointcloud2_read_and_written_as_rclpy_does(height: int, width: int, pad: int) -> None:
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import PointCloud2

    theirs = _rclpy_cloud2(np.random.default_rng(RNG_SEED), height, width, pad)
    ours = cdr.read(serialize_message(theirs), cdr.POINTCLOUD2)
    _same_cloud2(ours, theirs)
    _same_cloud2(ours, deserialize_message(cdr.serialize(ours), PointCloud2))
    _same_cloud2(ours, TS.deserialize_cdr(cdr.serialize(ours), cdr.POINTCLOUD2))


@pytest.mark.parametrize('msgtype', [cdr.POINTCLOUD, cdr.POINTCLOUD2])
def test_big_endian_records_are_read(msgtype: str) -> None:
    from rclpy.serialization import serialize_message

    rng = np.random.default_rng(RNG_SEED)
    msg = (_rclpy_cloud(rng, 9, ['id_of_point', 'u_of_point']) if msgtype == cdr.POINTCLOUD
           else _rclpy_cloud2(rng, 2, 4, 1))
    little = TS.deserialize_cdr(serialize_message(msg), msgtype)
    big = bytes(TS.serialize_cdr(little, msgtype, little_endian=False))
    assert big[:2] == b'\x00\x00'
    ours = cdr.read(big, msgtype)
    (_same_cloud if msgtype == cdr.POINTCLOUD else _same_cloud2)(ours, msg)


def test_stamp_is_read_without_the_rest() -> None:
    from rclpy.serialization import serialize_message

    msg = _rclpy_cloud(np.random.default_rng(RNG_SEED), 3, ['id_of_point'])
    assert cdr.stamp_ns(serialize_message(msg)) == 1_700_000_123 * 10**9 + 987_654_321


@pytest.mark.parametrize('msgtype', [cdr.POINTCLOUD, cdr.POINTCLOUD2])
def test_every_truncation_and_corruption_is_an_input_error(msgtype: str) -> None:
    from rclpy.serialization import serialize_message

    rng = np.random.default_rng(RNG_SEED)
    msg = (_rclpy_cloud(rng, 4, ['id_of_point', 'u_of_point']) if msgtype == cdr.POINTCLOUD
           else _rclpy_cloud2(rng, 1, 3, 0))
    raw = serialize_message(msg)
    for cut in range(len(raw) - 1):  # the last byte may be padding-free bool: keep >= 1 short
        with pytest.raises(InputError):
            cdr.read(raw[:cut], msgtype)
    for _ in range(300):  # random damage: read or refused, never another exception
        damaged = bytearray(raw)
        for at in rng.integers(4, len(raw), 3):
            damaged[at] = int(rng.integers(0, 256))
        try:
            cdr.read(bytes(damaged), msgtype)
        except InputError as err:
            assert '\n' not in str(err)
    with pytest.raises(InputError, match='encapsulation'):
        cdr.read(b'\x00\x02\x00\x00' + raw[4:], msgtype)
    with pytest.raises(InputError, match='not a feature message type'):
        cdr.read(raw, 'std_msgs/msg/String')
