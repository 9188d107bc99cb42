"""Message -> numpy decoding, on messages built with the rosbags typestore classes."""

from __future__ import annotations

import array
import struct
from types import SimpleNamespace

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from pearl_ros.bagio.decode import (
    carries_pixels,
    decode_labels,
    decode_pointcloud,
    decode_pointcloud2,
    stamp_ns,
)
from pearl_ros.core.errors import InputError

TS = get_typestore(Stores.ROS2_KILTED)
Header = TS.types['std_msgs/msg/Header']
Time = TS.types['builtin_interfaces/msg/Time']
Point32 = TS.types['geometry_msgs/msg/Point32']
ChannelFloat32 = TS.types['sensor_msgs/msg/ChannelFloat32']
PointField = TS.types['sensor_msgs/msg/PointField']
PointCloud = TS.types['sensor_msgs/msg/PointCloud']
PointCloud2 = TS.types['sensor_msgs/msg/PointCloud2']


def header(sec: int = 12, nanosec: int = 345) -> object:
    return Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id='camera')


def cloud(xy: list[tuple[float, float]], channels: list[tuple[str, list[float]]]) -> object:
    return PointCloud(
        header=header(),
        points=[Point32(x=x, y=y, z=1.0) for x, y in xy],
        channels=[ChannelFloat32(name=n, values=np.array(v, np.float32)) for n, v in channels],
    )


def cloud2(
    fields: list[tuple[str, int, int]],
    data: bytes,
    *,
    width: int,
    height: int = 1,
    point_step: int,
    row_step: int | None = None,
    bigendian: bool = False,
) -> object:
    return PointCloud2(
        header=header(),
        height=height,
        width=width,
        fields=[PointField(name=n, offset=o, datatype=d, count=1) for n, o, d in fields],
        is_bigendian=bigendian,
        point_step=point_step,
        row_step=point_step * width if row_step is None else row_step,
        data=np.frombuffer(data, dtype=np.uint8).copy(),
        is_dense=True,
    )


# Four features seen by two cameras; VINS-Fusion channel order: id, camera, u, v, vx, vy.
FUSION_CHANNELS = [
    ('', [5, 6, 5, 7]),
    ('', [0, 0, 1, 1]),
    ('', [10.5, 20.5, 30.5, 40.5]),
    ('', [11.0, 21.0, 31.0, 41.0]),
    ('', [0, 0, 0, 0]),
    ('', [0, 0, 0, 0]),
]
FOUR_POINTS = [(0.1, 0.2), (0.3, 0.4), (0.5, 0.6), (0.7, 0.8)]


@pytest.mark.parametrize('layout', ['vins_fusion', 'by_index', 'auto'])
def test_vins_fusion_layout_reads_channels_by_index_for_camera_zero(layout: str) -> None:
    ids, uv = decode_pointcloud(cloud(FOUR_POINTS, FUSION_CHANNELS), layout, camera_id=0)
    assert ids.dtype == np.int64
    np.testing.assert_array_equal(ids, [5, 6])
    np.testing.assert_array_equal(uv, [[10.5, 11.0], [20.5, 21.0]])


def test_vins_fusion_camera_id_selects_the_other_camera() -> None:
    ids, uv = decode_pointcloud(cloud(FOUR_POINTS, FUSION_CHANNELS), 'vins_fusion', camera_id=1)
    np.testing.assert_array_equal(ids, [5, 7])
    np.testing.assert_array_equal(uv, [[30.5, 31.0], [40.5, 41.0]])


def test_vins_fusion_camera_without_features_gives_zero_features() -> None:
    ids, uv = decode_pointcloud(cloud(FOUR_POINTS, FUSION_CHANNELS), 'vins_fusion', camera_id=3)
    assert ids.shape == (0,) and uv.shape == (0, 2)


def test_auto_picks_channels_by_name_whatever_their_order() -> None:
    # By index this would read the velocities as ids: only a by-name decode gives these values.
    channels = [
        ('velocity_x_of_point', [1.0, 2.0]),
        ('v_of_point', [200.0, 201.0]),
        ('u_of_point', [100.0, 101.0]),
        ('id_of_point', [42, 7]),
        ('velocity_y_of_point', [3.0, 4.0]),
    ]
    msg = cloud([(0.1, 0.2), (0.3, 0.4)], channels)
    for layout in ('auto', 'vins_mono', 'by_name'):
        ids, uv = decode_pointcloud(msg, layout)
        np.testing.assert_array_equal(ids, [42, 7])
        np.testing.assert_array_equal(uv, [[100.0, 200.0], [101.0, 201.0]])
        assert carries_pixels(msg, layout)


def test_vins_mono_cloud_without_pixel_channels_gives_normalised_points() -> None:
    msg = cloud([(0.25, -0.5), (0.75, 0.125)], [('id_of_point', [3, 4])])
    ids, uv = decode_pointcloud(msg)
    np.testing.assert_array_equal(ids, [3, 4])
    np.testing.assert_array_equal(uv, [[0.25, -0.5], [0.75, 0.125]])
    assert not carries_pixels(msg) and not carries_pixels(msg, 'vins_mono')
    assert carries_pixels(cloud(FOUR_POINTS, FUSION_CHANNELS))  # u, v by index


def test_auto_refuses_a_cloud_with_too_few_unnamed_channels() -> None:
    msg = cloud([(0.1, 0.2)], [('', [1]), ('', [2]), ('', [3])])
    with pytest.raises(InputError, match='layout'):
        decode_pointcloud(msg)


def test_vins_fusion_layout_needs_four_channels() -> None:
    msg = cloud([(0.1, 0.2)], [('', [1]), ('', [0]), ('', [3])])
    with pytest.raises(InputError, match='>= 4 channels'):
        decode_pointcloud(msg, 'vins_fusion')


def test_channel_length_mismatch_raises() -> None:
    msg = cloud(
        [(0.1, 0.2), (0.3, 0.4)],
        [('id_of_point', [1, 2]), ('u_of_point', [1.0]), ('v_of_point', [1.0, 2.0])],
    )
    with pytest.raises(InputError, match="'u_of_point' has 1 values for 2 points"):
        decode_pointcloud(msg)


def test_vins_mono_layout_without_id_channel_raises() -> None:
    msg = cloud([(0.1, 0.2)], [('u_of_point', [1.0]), ('v_of_point', [2.0])])
    with pytest.raises(InputError, match='id_of_point'):
        decode_pointcloud(msg, 'vins_mono')


def test_u_channel_without_v_channel_raises() -> None:
    msg = cloud([(0.1, 0.2)], [('id_of_point', [1]), ('u_of_point', [1.0])])
    with pytest.raises(InputError, match='only one of'):
        decode_pointcloud(msg)


def test_non_integer_ids_raise() -> None:
    msg = cloud(
        [(0.1, 0.2)], [('id_of_point', [1.5]), ('u_of_point', [1.0]), ('v_of_point', [2.0])]
    )
    with pytest.raises(InputError, match='integers'):
        decode_pointcloud(msg)


def test_duplicate_ids_raise() -> None:
    msg = cloud(
        [(0.1, 0.2), (0.3, 0.4)],
        [('id_of_point', [9, 9]), ('u_of_point', [1.0, 2.0]), ('v_of_point', [2.0, 3.0])],
    )
    with pytest.raises(InputError, match='repeats'):
        decode_pointcloud(msg)


def test_non_finite_pixels_raise() -> None:
    msg = cloud(
        [(0.1, 0.2)], [('id_of_point', [1]), ('u_of_point', [np.nan]), ('v_of_point', [2.0])]
    )
    with pytest.raises(InputError, match='non-finite'):
        decode_pointcloud(msg)


def test_empty_clouds_give_zero_features() -> None:
    for msg in (
        cloud([], []),
        cloud([], [('id_of_point', []), ('u_of_point', []), ('v_of_point', [])]),
    ):
        ids, uv = decode_pointcloud(msg)
        assert ids.shape == (0,) and ids.dtype == np.int64
        assert uv.shape == (0, 2) and uv.dtype == np.float64
    ids, uv = decode_pointcloud2(cloud2([], b'', width=0, point_step=0))
    assert ids.shape == (0,) and uv.shape == (0, 2)


def test_bad_layout_and_camera_id_raise() -> None:
    msg = cloud(FOUR_POINTS, FUSION_CHANNELS)
    with pytest.raises(InputError, match='layout'):
        decode_pointcloud(msg, 'vins')
    with pytest.raises(InputError, match='camera_id'):
        decode_pointcloud(msg, 'vins_fusion', camera_id=-1)


def test_pointcloud2_big_endian_with_padding_and_extra_fields() -> None:
    # Point of 24 bytes: float64 id at 0, int16 junk at 8, float32 u at 12, v at 16, 4 pad bytes.
    rows = [(11.0, -3, 1.5, 2.5), (12.0, 7, 3.25, 4.75), (2.0**30, 0, -1.0, 0.5)]
    data = b''.join(struct.pack('>dh2xff4x', *row) for row in rows)
    fields = [('id', 0, 8), ('junk', 8, 3), ('u', 12, 7), ('v', 16, 7)]
    msg = cloud2(fields, data, width=3, point_step=24, bigendian=True)
    ids, uv = decode_pointcloud2(msg)
    np.testing.assert_array_equal(ids, [11, 12, 2**30])
    np.testing.assert_array_equal(uv, [[1.5, 2.5], [3.25, 4.75], [-1.0, 0.5]])


def test_pointcloud2_organised_cloud_skips_row_padding() -> None:
    # 2 x 2 cloud, uint32 id and float32 u, v (12 bytes), rows padded to 30 bytes.
    point = '<Iff'
    row0 = struct.pack(point, 1, 10.0, 20.0) + struct.pack(point, 2, 11.0, 21.0) + b'\xff' * 6
    row1 = struct.pack(point, 3, 12.0, 22.0) + struct.pack(point, 4, 13.0, 23.0) + b'\xff' * 6
    fields = [('id', 0, 6), ('u', 4, 7), ('v', 8, 7)]
    msg = cloud2(fields, row0 + row1, width=2, height=2, point_step=12, row_step=30)
    ids, uv = decode_pointcloud2(msg)
    np.testing.assert_array_equal(ids, [1, 2, 3, 4])
    np.testing.assert_array_equal(uv, [[10, 20], [11, 21], [12, 22], [13, 23]])


def test_pointcloud2_prefers_pixels_and_falls_back_to_x_y() -> None:
    data = struct.pack('<Iffff', 8, 100.0, 200.0, 0.5, -0.25)
    both = [('id', 0, 6), ('u', 4, 7), ('v', 8, 7), ('x', 12, 7), ('y', 16, 7)]
    _, uv = decode_pointcloud2(cloud2(both, data, width=1, point_step=20))
    np.testing.assert_array_equal(uv, [[100.0, 200.0]])
    assert carries_pixels(cloud2(both, data, width=1, point_step=20))
    only_xy = [('id', 0, 6), ('x', 12, 7), ('y', 16, 7)]
    _, uv = decode_pointcloud2(cloud2(only_xy, data, width=1, point_step=20))
    np.testing.assert_array_equal(uv, [[0.5, -0.25]])
    assert not carries_pixels(cloud2(only_xy, data, width=1, point_step=20))


@pytest.mark.parametrize(
    ('fields', 'data', 'point_step', 'match'),
    [
        ([('u', 4, 7), ('v', 8, 7)], struct.pack('<Iff', 1, 2, 3), 12, 'no id field'),
        ([('id', 0, 6), ('u', 4, 7)], struct.pack('<Iff', 1, 2, 3), 12, r'no u, v \(or x, y\)'),
        (
            [('id', 0, 6), ('u', 4, 7), ('v', 10, 7)],
            struct.pack('<Iff', 1, 2, 3),
            12,
            'does not fit',
        ),
        (
            [('id', 0, 9), ('u', 4, 7), ('v', 8, 7)],
            struct.pack('<Iff', 1, 2, 3),
            12,
            'unknown datatype',
        ),
        (
            [('id', 0, 6), ('u', 4, 7), ('v', 8, 7)],
            struct.pack('<Iff', 1, 2, 3)[:10],
            12,
            'data has 10 bytes',
        ),
        (
            [('id', 0, 7), ('u', 4, 7), ('v', 8, 7)],
            struct.pack('<fff', 1.25, 2, 3),
            12,
            'integers',
        ),
    ],
)
def test_malformed_pointcloud2_raises(
    fields: list[tuple[str, int, int]], data: bytes, point_step: int, match: str
) -> None:
    with pytest.raises(InputError, match=match):
        decode_pointcloud2(cloud2(fields, data, width=1, point_step=point_step))


def test_decode_labels_reads_id_and_label_fields() -> None:
    data = b''.join(struct.pack('<Ii', i, label) for i, label in [(4, 0), (9, -1), (2, 2)])
    msg = cloud2([('id', 0, 6), ('label', 4, 5)], data, width=3, point_step=8)
    ids, labels = decode_labels(msg)
    np.testing.assert_array_equal(ids, [4, 9, 2])
    np.testing.assert_array_equal(labels, [0, -1, 2])
    with pytest.raises(InputError, match='label'):
        decode_labels(cloud2([('id', 0, 6)], data, width=3, point_step=8))


def test_decoders_accept_rclpy_style_containers() -> None:
    # rclpy gives array.array for float32[] and uint8[]: the decoders must not need numpy input.
    stamp = SimpleNamespace(stamp=SimpleNamespace(sec=3, nanosec=7))
    msg = SimpleNamespace(
        header=stamp,
        points=[SimpleNamespace(x=0.1, y=0.2, z=1.0)],
        channels=[
            SimpleNamespace(name='id_of_point', values=array.array('f', [5.0])),
            SimpleNamespace(name='u_of_point', values=array.array('f', [1.5])),
            SimpleNamespace(name='v_of_point', values=array.array('f', [2.5])),
        ],
    )
    ids, uv = decode_pointcloud(msg)
    np.testing.assert_array_equal(ids, [5])
    np.testing.assert_array_equal(uv, [[1.5, 2.5]])
    field = SimpleNamespace
    msg2 = SimpleNamespace(
        header=stamp,
        height=1,
        width=1,
        point_step=12,
        row_step=12,
        is_bigendian=False,
        fields=[
            field(name='id', offset=0, datatype=6, count=1),
            field(name='u', offset=4, datatype=7, count=1),
            field(name='v', offset=8, datatype=7, count=1),
        ],
        data=array.array('B', struct.pack('<Iff', 77, 3.5, 4.5)),
    )
    ids, uv = decode_pointcloud2(msg2)
    np.testing.assert_array_equal(ids, [77])
    np.testing.assert_array_equal(uv, [[3.5, 4.5]])
    assert stamp_ns(stamp) == 3_000_000_007


def test_stamp_ns_of_a_rosbags_header() -> None:
    assert stamp_ns(header(1_700_000_000, 999_999_999)) == 1_700_000_000_999_999_999
