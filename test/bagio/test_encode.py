"""numpy -> output messages, with rosbags typestore classes and rclpy classes alike.

Every output is checked by decoding it again (pearl_ros.bagio.decode and an independent
struct-based reader) after a serialisation round trip through the library that built it.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from pearl_ros.bagio import cdr, decode
from pearl_ros.bagio.encode import (
    MessageTypes,
    background_motion,
    motion_labels,
    static_features,
    static_mask,
)
from pearl_ros.core.errors import InputError

TS = get_typestore(Stores.ROS2_KILTED)


@dataclass
class Library:
    """How one message library builds headers and clouds and round-trips them on the wire."""

    name: str
    types: MessageTypes
    Header: Any
    Time: Any
    Point32: Any = None  # None: points as an (N, 3) float32 array (pearl_ros.bagio.cdr)

    def header(self, sec: int = 12, nanosec: int = 345) -> Any:
        return self.Header(stamp=self.Time(sec=sec, nanosec=nanosec), frame_id='cam0')

    def cloud(self, xy: list[tuple[float, float]], channels: list[tuple[str, list[float]]]) -> Any:
        t = self.types
        return t.PointCloud(
            header=self.header(),
            points=(np.array([(x, y, 1.0) for x, y in xy], np.float32).reshape(-1, 3)
                    if self.Point32 is None
                    else [self.Point32(x=float(x), y=float(y), z=1.0) for x, y in xy]),
            channels=[
                t.ChannelFloat32(name=n, values=t.float32s(np.array(v, np.float32)))
                for n, v in channels
            ],
        )

    def cloud2(self, fields: list[tuple[str, int, int]], data: bytes, *, width: int,
               height: int = 1, point_step: int, row_step: int) -> Any:
        t = self.types
        return t.PointCloud2(
            header=self.header(),
            height=height,
            width=width,
            fields=[t.PointField(name=n, offset=o, datatype=d, count=1) for n, o, d in fields],
            is_bigendian=False,
            point_step=point_step,
            row_step=row_step,
            data=t.uint8s(np.frombuffer(data, dtype=np.uint8)),
            is_dense=False,
        )

    def wire(self, msg: Any) -> Any:
        """``msg`` serialised and deserialised by its own library."""
        if self.name == 'rosbags':
            typename = msg.__msgtype__
            return TS.deserialize_cdr(bytes(TS.serialize_cdr(msg, typename)), typename)
        if self.name == 'cdr':
            typename = cdr.POINTCLOUD if hasattr(msg, 'channels') else cdr.POINTCLOUD2
            return cdr.read(cdr.serialize(msg), typename)
        from rclpy.serialization import deserialize_message, serialize_message

        return deserialize_message(serialize_message(msg), type(msg))


def _rosbags() -> Library:
    return Library('rosbags', MessageTypes.from_typestore(TS),
                   TS.types['std_msgs/msg/Header'], TS.types['builtin_interfaces/msg/Time'],
                   TS.types['geometry_msgs/msg/Point32'])


def _rclpy() -> Library:
    import geometry_msgs.msg
    import sensor_msgs.msg
    from builtin_interfaces.msg import Time
    from std_msgs.msg import Header

    return Library('rclpy', MessageTypes.from_module(sensor_msgs.msg), Header, Time,
                   geometry_msgs.msg.Point32)


@pytest.fixture(params=['rosbags', 'rclpy', 'cdr'])
def lib(request: pytest.FixtureRequest) -> Library:
    if request.param == 'cdr':
        return Library('cdr', cdr.TYPES, cdr.Header, cdr.Time)
    return _rosbags() if request.param == 'rosbags' else _rclpy()


def _xyz(points: Any) -> list[tuple[float, float, float]]:
    """A PointCloud's points as (x, y, z) tuples: Point32 objects or an (N, 3) array."""
    if isinstance(points, np.ndarray):
        return [tuple(row) for row in points.tolist()]
    return [(p.x, p.y, p.z) for p in points]


def _unpack_labels(msg: Any) -> list[tuple[int, float, float, int]]:
    """Independent reader of the motion_labels layout: '<IffI' records of 16 bytes."""
    data = bytes(np.asarray(msg.data, dtype=np.uint8))
    return [struct.unpack_from('<Iffi', data, 16 * i) for i in range(int(msg.width))]


# ---------------------------------------------------------------------------- motion_labels


def test_motion_labels_hold_one_point_per_feature_in_input_order(lib: Library) -> None:
    ids = np.array([7, 3, 2**32 - 1, 0])
    uv = np.array([[10.25, 20.5], [-1.5, 300.0], [640.0, 480.0], [0.0, 0.125]])
    labels = np.array([2, -1, 0, 2])
    header = lib.header(sec=99, nanosec=123456789)
    msg = lib.wire(motion_labels(header, ids, uv, labels, lib.types))

    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (99, 123456789)
    assert msg.header.frame_id == 'cam0'
    assert (msg.height, msg.width, msg.point_step, msg.row_step) == (1, 4, 16, 64)
    assert not msg.is_bigendian and msg.is_dense
    pf = lib.types.PointField
    assert [(f.name, f.offset, f.datatype, f.count) for f in msg.fields] == [
        ('id', 0, pf.UINT32, 1), ('u', 4, pf.FLOAT32, 1), ('v', 8, pf.FLOAT32, 1),
        ('label', 12, pf.INT32, 1)]
    expected = [(int(i), float(u), float(v), int(k))
                for i, (u, v), k in zip(ids, uv, labels, strict=True)]
    assert _unpack_labels(msg) == expected  # the values chosen are exact in float32
    got_ids, got_uv = decode.decode_pointcloud2(msg)
    np.testing.assert_array_equal(got_ids, ids)
    np.testing.assert_array_equal(got_uv, uv)
    np.testing.assert_array_equal(decode.decode_fields(msg, ('label',))['label'], labels)


def test_motion_labels_of_an_empty_frame_is_an_empty_cloud(lib: Library) -> None:
    msg = lib.wire(motion_labels(lib.header(), np.empty(0, np.int64), np.empty((0, 2)),
                                 np.empty(0, np.int64), lib.types))
    assert (msg.width, msg.row_step, len(msg.data), len(msg.fields)) == (0, 0, 0, 4)


@pytest.mark.parametrize(
    ('ids', 'labels', 'words'),
    [
        ([-1, 2], [0, 0], 'uint32'),
        ([2**32, 2], [0, 0], 'uint32'),
        ([1, 2], [2**31, 0], 'int32'),
        ([1, 2], [0], 'labels (N,)'),
    ],
)
def test_motion_labels_refuse_values_the_fields_cannot_hold(
    ids: list[int], labels: list[int], words: str
) -> None:
    types = MessageTypes.from_typestore(TS)
    with pytest.raises(InputError, match=words.replace('(', r'\(').replace(')', r'\)')):
        motion_labels(_rosbags().header(), np.array(ids), np.zeros((2, 2)), np.array(labels),
                      types)


# ---------------------------------------------------------------------- background helper


def test_background_is_the_largest_motion_and_outliers_do_not_count() -> None:
    assert background_motion(np.array([-1, -1, -1, 4, 4, 2])) == 4
    np.testing.assert_array_equal(static_mask(np.array([-1, -1, -1, 4, 4, 2])),
                                  [False, False, False, True, True, False])


def test_background_tie_goes_to_the_lowest_motion_number() -> None:
    assert background_motion(np.array([5, 3, 5, 3, 9])) == 3


def test_nothing_is_static_when_every_feature_is_unlabelled() -> None:
    assert background_motion(np.array([-1, -1])) is None
    assert not static_mask(np.array([-1, -1])).any()
    assert static_mask(np.empty(0, np.int64)).shape == (0,)


def test_static_mask_with_a_given_background_keeps_only_that_motion() -> None:
    np.testing.assert_array_equal(static_mask(np.array([0, 1, 1, -1]), background=0),
                                  [True, False, False, False])


# ----------------------------------------------------------------------- static_features

# VINS-Mono layout with channels in a shuffled order (by-name lookup must not care).
MONO_XY = [(0.1, 0.2), (0.3, 0.4), (0.5, 0.6), (0.7, 0.8), (0.9, 1.0)]
MONO_CHANNELS = [
    ('velocity_x_of_point', [1.0, 2.0, 3.0, 4.0, 5.0]),
    ('u_of_point', [100.0, 101.0, 102.0, 103.0, 104.0]),
    ('id_of_point', [40, 41, 42, 43, 44]),
    ('v_of_point', [200.0, 201.0, 202.0, 203.0, 204.0]),
    ('velocity_y_of_point', [-1.0, -2.0, -3.0, -4.0, -5.0]),
]


def _channel_table(msg: Any) -> dict[str, list[float]]:
    return {str(c.name): [float(v) for v in c.values] for c in msg.channels}


def test_static_vins_mono_cloud_keeps_every_channel_of_the_kept_points(lib: Library) -> None:
    msg = lib.cloud(MONO_XY, MONO_CHANNELS)
    keep = np.array([True, False, True, True, False])
    out = lib.wire(static_features(msg, keep, lib.types, 'vins_mono'))

    assert (out.header.stamp.sec, out.header.stamp.nanosec, out.header.frame_id) == (
        12, 345, 'cam0')
    index = [0, 2, 3]
    assert [str(c.name) for c in out.channels] == [name for name, _ in MONO_CHANNELS]
    assert _channel_table(out) == {n: [v[i] for i in index] for n, v in MONO_CHANNELS}
    np.testing.assert_allclose(_xyz(out.points),
                               [(*MONO_XY[i], 1.0) for i in index], rtol=1e-6)
    ids, uv = decode.decode_pointcloud(out, 'auto')
    ids_in, uv_in = decode.decode_pointcloud(msg, 'vins_mono')
    np.testing.assert_array_equal(ids, ids_in[keep])
    np.testing.assert_array_equal(uv, uv_in[keep])


def test_static_cloud_keeping_nothing_is_an_empty_cloud_with_the_same_channels(
    lib: Library,
) -> None:
    msg = lib.cloud(MONO_XY, MONO_CHANNELS)
    out = lib.wire(static_features(msg, np.zeros(5, bool), lib.types))
    assert len(out.points) == 0
    assert _channel_table(out) == {name: [] for name, _ in MONO_CHANNELS}


# VINS-Fusion layout: id, camera, u, v, vx, vy by index; cameras 0 and 1 interleaved.
FUSION_XY = [(0.1, 0.1), (0.2, 0.2), (0.3, 0.3), (0.4, 0.4), (0.5, 0.5)]
FUSION_CHANNELS = [
    ('', [5, 5, 6, 7, 8]),
    ('', [0, 1, 0, 1, 1]),
    ('', [10.0, 11.0, 12.0, 13.0, 14.0]),
    ('', [20.0, 21.0, 22.0, 23.0, 24.0]),
    ('', [0.5, 0.25, 0.75, 0.125, 0.375]),
    ('', [1.5, 1.25, 1.75, 1.125, 1.375]),
]


@pytest.mark.parametrize('layout', ['vins_fusion', 'auto'])
def test_static_vins_fusion_cloud_filters_only_the_selected_camera(
    lib: Library, layout: str
) -> None:
    msg = lib.cloud(FUSION_XY, FUSION_CHANNELS)
    ids1, _ = decode.decode_pointcloud(msg, layout, camera_id=1)
    np.testing.assert_array_equal(ids1, [5, 7, 8])  # camera 1 holds points 1, 3, 4
    keep = np.array([False, True, True])  # drop point 1, keep points 3 and 4
    out = lib.wire(static_features(msg, keep, lib.types, layout, camera_id=1))

    index = [0, 2, 3, 4]  # camera 0's points 0 and 2 pass untouched
    assert len(out.channels) == 6
    columns = [[float(v) for v in c.values] for c in out.channels]
    assert columns == [[values[i] for i in index] for _, values in FUSION_CHANNELS]
    np.testing.assert_allclose([p[:2] for p in _xyz(out.points)],
                               [FUSION_XY[i] for i in index], rtol=1e-6)
    ids0, uv0 = decode.decode_pointcloud(out, layout, camera_id=0)
    np.testing.assert_array_equal(ids0, decode.decode_pointcloud(msg, layout, camera_id=0)[0])
    np.testing.assert_array_equal(ids0, [5, 6])
    np.testing.assert_array_equal(uv0, [[10.0, 20.0], [12.0, 22.0]])
    np.testing.assert_array_equal(decode.decode_pointcloud(out, layout, camera_id=1)[0], [7, 8])


def test_static_pointcloud2_keeps_the_layout_and_drops_row_padding(lib: Library) -> None:
    # An organised 2 x 2 cloud: fields id u4 @0, u f4 @4, v f4 @8, x f4 @16 (4 bytes of
    # padding at 12), point_step 20, and 8 bytes of padding at the end of each row.
    pf = lib.types.PointField
    fields = [('id', 0, pf.UINT32), ('u', 4, pf.FLOAT32), ('v', 8, pf.FLOAT32),
              ('x', 16, pf.FLOAT32)]
    rows = []
    for row in range(2):
        points = b''.join(
            struct.pack('<Iff4sf', 10 + 2 * row + col, 1.5 * (2 * row + col), -0.5 * col,
                        b'PAD!', 0.25 * row)
            for col in range(2))
        rows.append(points + b'ROWPADDI')
    msg = lib.cloud2(fields, b''.join(rows), width=2, height=2, point_step=20, row_step=48)
    keep = np.array([False, True, True, False])
    out = lib.wire(static_features(msg, keep, lib.types))

    assert (out.height, out.width, out.point_step, out.row_step) == (1, 2, 20, 40)
    assert [(f.name, f.offset, f.datatype) for f in out.fields] == fields
    assert not out.is_bigendian and not out.is_dense
    data = bytes(np.asarray(out.data, dtype=np.uint8))
    assert data == rows[0][20:40] + rows[1][0:20]  # points 1 and 2, bytes untouched
    ids, uv = decode.decode_pointcloud2(out)
    np.testing.assert_array_equal(ids, [11, 12])
    np.testing.assert_array_equal(uv, [[1.5, -0.5], [3.0, 0.0]])
    np.testing.assert_array_equal(decode.decode_fields(out, ('x',))['x'], [0.0, 0.25])


def test_static_features_of_a_motion_labels_cloud_is_its_background(lib: Library) -> None:
    # The two encoders compose: cut a labels cloud down to its own background.
    ids = np.arange(6)
    labels = np.array([3, 1, 1, -1, 3, 1])
    cloud = motion_labels(lib.header(), ids, np.zeros((6, 2)), labels, lib.types)
    out = lib.wire(static_features(cloud, static_mask(labels), lib.types))
    got = decode.decode_pointcloud2(out)[0]
    np.testing.assert_array_equal(got, [1, 2, 5])


@pytest.mark.parametrize(('layout', 'camera_id', 'flags', 'expected'), [
    ('vins_mono', 0, 4, 5),
    ('vins_fusion', 1, 5, 3),
])
def test_static_features_refuse_a_mask_of_the_wrong_length(
    layout: str, camera_id: int, flags: int, expected: int
) -> None:
    lib = _rosbags()
    msg = (lib.cloud(MONO_XY, MONO_CHANNELS) if layout == 'vins_mono'
           else lib.cloud(FUSION_XY, FUSION_CHANNELS))
    with pytest.raises(InputError, match=f'keep has {flags} flags for {expected} features'):
        static_features(msg, np.ones(flags, bool), lib.types, layout, camera_id)


def test_static_features_refuse_a_mask_that_is_not_boolean() -> None:
    lib = _rosbags()
    with pytest.raises(InputError, match='bool'):
        static_features(lib.cloud(MONO_XY, MONO_CHANNELS), np.ones(5, int), lib.types)


def test_rclpy_and_rosbags_outputs_decode_to_the_same_fields() -> None:
    # The replay tool (rosbags) and the node (rclpy) must publish the same message: take the
    # rclpy bytes, read them with rosbags, and compare field by field with rosbags' own output.
    from rclpy.serialization import serialize_message

    rb, rc = _rosbags(), _rclpy()
    ids, uv, labels = np.array([4, 9, 1]), np.array([[1.0, 2.0], [3.5, 4.5], [5.0, 6.0]]), \
        np.array([0, -1, 1])
    from_rclpy = TS.deserialize_cdr(
        serialize_message(motion_labels(rc.header(), ids, uv, labels, rc.types)),
        'sensor_msgs/msg/PointCloud2')
    from_rosbags = motion_labels(rb.header(), ids, uv, labels, rb.types)
    for name in ('height', 'width', 'point_step', 'row_step', 'is_bigendian', 'is_dense'):
        assert getattr(from_rclpy, name) == getattr(from_rosbags, name), name
    assert [(f.name, f.offset, f.datatype, f.count) for f in from_rclpy.fields] == [
        (f.name, f.offset, f.datatype, f.count) for f in from_rosbags.fields]
    np.testing.assert_array_equal(from_rclpy.data, from_rosbags.data)


# ------------------------------------------------------------------ shared input checks


def test_float32_ids_up_to_2_pow_24_pass_and_beyond_are_refused() -> None:
    from pearl_ros.bagio.encode import check_float32_ids

    check_float32_ids(np.array([0, 2**24, -(2**24)]))
    with pytest.raises(InputError, match='16777218'):
        check_float32_ids(np.array([5, 2**24 + 2]))


def test_subsample_keeps_the_same_ids_whatever_their_order_and_company() -> None:
    from pearl_ros.bagio.encode import subsample_mask

    rng = np.random.default_rng(1)
    ids = rng.choice(10**6, size=500, replace=False)
    keep = subsample_mask(ids, 100)
    assert keep.sum() == 100
    order = rng.permutation(ids.size)
    np.testing.assert_array_equal(subsample_mask(ids[order], 100), keep[order])
    # A kept id stays kept when unkept ids leave: the choice is a threshold on a hash of the id.
    fewer = np.concatenate((ids[keep], ids[~keep][:200]))
    assert subsample_mask(fewer, 100)[:100].all()
    assert subsample_mask(ids[:50], 100).all()
