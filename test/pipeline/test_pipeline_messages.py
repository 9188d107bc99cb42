"""The per-message pipeline on rosbags messages, against the segmenter called directly."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from static_scene import camera_info

from pearl_ros.bagio import encode
from pearl_ros.bagio.decode import decode_fields, decode_labels, decode_pointcloud, point_array
from pearl_ros.bagio.reader import TYPESTORE
from pearl_ros.core.metrics import misclassification
from pearl_ros.online.config import build_configs
from pearl_ros.online.segmenter import OnlineSegmenter
from pearl_ros.pipeline.messages import Labelled, MessagePipeline, Skipped
from pearl_ros.pipeline.settings import build

from bag_oracles import raw_messages

BAG = Path(__file__).resolve().parents[2] / 'bags' / '1R2RCR_g12'
MESSAGES = raw_messages(BAG, '/feature_tracker/feature')


def labelled(out: Labelled | Skipped) -> Labelled:
    assert isinstance(out, Labelled), out
    return out


def test_capped_messages_segment_the_same_ids_every_frame_as_the_segmenter_would() -> None:
    pipeline = MessagePipeline(build({'budget_ms': 0.0, 'max_features': 60}))
    segmenter = OnlineSegmenter(*build_configs({'budget_ms': 0.0}))
    kept = []
    for msg in MESSAGES[:6]:
        out = labelled(pipeline.process(msg))
        ids, uv = decode_pointcloud(msg)
        assert out.capped and int(out.segmented.sum()) == 60
        kept.append(set(ids[out.segmented].tolist()))
        expected = segmenter.process(out.stamp_ns, ids[out.segmented], uv[out.segmented])
        np.testing.assert_array_equal(out.labels[out.segmented], expected.labels)
        assert (out.labels[~out.segmented] == -1).all()
        label_ids, labels = decode_labels(out.labels_msg)
        np.testing.assert_array_equal(label_ids, ids)  # every feature, in input order
        np.testing.assert_array_equal(labels, out.labels)
    assert all(ids == kept[0] for ids in kept)  # the subsample follows the ids


@pytest.mark.parametrize('background', [-1, 0, 1])
def test_static_features_are_the_chosen_or_the_largest_motion(background: int) -> None:
    pipeline = MessagePipeline(build({'budget_ms': 0.0, 'background_motion': background}))
    for msg in MESSAGES[:5]:
        out = labelled(pipeline.process(msg))
    numbers, counts = np.unique(out.labels[out.labels >= 0], return_counts=True)
    assert numbers.size == 2
    chosen = numbers[np.argmax(counts)] if background < 0 else background
    np.testing.assert_array_equal(out.static, out.labels == chosen)
    ids, _ = decode_pointcloud(out.static_msg)
    np.testing.assert_array_equal(ids, out.ids[out.labels == chosen])


def test_a_skipped_message_says_why_and_leaves_the_window_alone() -> None:
    pipeline = MessagePipeline(build({'budget_ms': 0.0}))
    labelled(pipeline.process(MESSAGES[0]))
    repeated = pipeline.process(MESSAGES[0])
    assert isinstance(repeated, Skipped)
    assert (repeated.kind, repeated.malformed) == ('stamp', False)
    assert repeated.line.startswith('skipped (stamp): stamp ')
    broken = MESSAGES[1].__class__(header=MESSAGES[1].header, points=MESSAGES[1].points,
                                   channels=MESSAGES[1].channels[1:3])
    skip = pipeline.process(broken)
    assert isinstance(skip, Skipped) and skip.malformed and skip.kind == 'layout'
    assert pipeline.frames_in_window == 1
    labelled(pipeline.process(MESSAGES[1]))
    assert pipeline.frames_in_window == 2


def test_reconfigure_keeps_the_window_and_reset_empties_it() -> None:
    pipeline = MessagePipeline(build({'budget_ms': 0.0}))
    for msg in MESSAGES[:4]:
        labelled(pipeline.process(msg))
    pipeline.reconfigure(build({'budget_ms': 0.0, 'window': 3}))
    labelled(pipeline.process(MESSAGES[4]))
    assert pipeline.frames_in_window == 3 and pipeline.settings.online.window == 3
    pipeline.reset()
    out = labelled(pipeline.process(MESSAGES[5]))
    assert pipeline.frames_in_window == 1 and (out.labels == -1).all()


def test_the_outputs_carry_the_header_given() -> None:
    pipeline = MessagePipeline()
    header = MESSAGES[0].header.__class__(stamp=MESSAGES[0].header.stamp, frame_id='other')
    out = labelled(pipeline.process(MESSAGES[0], header))
    assert out.labels_msg.header is header and out.static_msg.header is header


# The bag's normalised coordinates are those of a nominal camera of this matrix (make_bag).
BAG_CAMERA = np.array([[320.0, 0.0, 320.0], [0.0, 240.0, 240.0], [0.0, 0.0, 1.0]])
XY_FIELDS = (('id', '<u4', 6), ('x', '<f4', 7), ('y', '<f4', 7))  # PointField UINT32, FLOAT32


def decode_fields_uv(msg) -> tuple[np.ndarray, np.ndarray]:
    """The ids and ``u``, ``v`` of a ``motion_labels`` message."""
    columns = decode_fields(msg, ('id', 'u', 'v'))
    return columns['id'].astype(np.int64), np.column_stack([columns['u'], columns['v']])


def xy_cloud(header, ids: np.ndarray, xy: np.ndarray):
    """A PointCloud2 of fields id, x, y (the coordinates it names normalised)."""
    return encode.packed_cloud2(header, {'id': ids, 'x': xy[:, 0], 'y': xy[:, 1]}, XY_FIELDS,
                                encode.MessageTypes.from_typestore(TYPESTORE))


def without_pixels(msg, kind: str):
    """The features of ``msg`` as normalised coordinates alone: a VINS-Mono cloud without its
    pixel channels, or a PointCloud2 of fields id, x, y."""
    if kind == 'PointCloud':
        channels = [c for c in msg.channels if c.name not in ('u_of_point', 'v_of_point')]
        return msg.__class__(header=msg.header, points=msg.points, channels=channels)
    return xy_cloud(msg.header, decode_pointcloud(msg)[0], point_array(msg.points)[:, :2])


def test_the_bag_camera_maps_its_normalised_coordinates_to_its_pixels() -> None:
    ids, uv = decode_pointcloud(MESSAGES[0])
    xy = point_array(MESSAGES[0].points)[:, :2].astype(np.float64)
    np.testing.assert_allclose(xy @ BAG_CAMERA[:2, :2].T + BAG_CAMERA[:2, 2], uv, atol=0.05)


@pytest.mark.parametrize('kind', ['PointCloud', 'PointCloud2'])
def test_normalised_coordinates_are_segmented_as_their_pixels_are(kind: str) -> None:
    # Taken as pixels, normalised coordinates put every scale floor of the segmenter at
    # hundreds of pixels: this sequence came out as one motion.
    pixels = MessagePipeline(build({'budget_ms': 0.0}))
    normalised = MessagePipeline(build({'budget_ms': 0.0}))
    for msg in MESSAGES:
        expected = labelled(pixels.process(msg))
        out = labelled(normalised.process(without_pixels(msg, kind)))
    assert np.unique(expected.labels).size == 2
    assert misclassification(out.labels, expected.labels) <= 0.01
    assert out.image_uv is None  # no intrinsics: nowhere to draw them
    label_ids, published = decode_fields_uv(out.labels_msg)
    np.testing.assert_array_equal(label_ids, decode_pointcloud(MESSAGES[-1])[0])
    xy = point_array(MESSAGES[-1].points)[:, :2]
    np.testing.assert_allclose(out.uv, xy)
    np.testing.assert_allclose(published, xy)  # no intrinsics: published as they came


def test_pixels_in_fields_named_normalised_are_taken_as_pixels() -> None:
    # A PointCloud2 whose x, y a tracker filled with pixels: beyond any normalised coordinate.
    pixels = MessagePipeline(build({'budget_ms': 0.0}))
    in_xy = MessagePipeline(build({'budget_ms': 0.0, 'camera_fx': 320.0, 'camera_fy': 240.0,
                                   'camera_cx': 320.0, 'camera_cy': 240.0}))
    for msg in MESSAGES[:6]:
        ids, uv = decode_pointcloud(msg)
        cloud = xy_cloud(msg.header, ids, uv)
        expected = labelled(pixels.process(msg))
        out = labelled(in_xy.process(cloud))
        np.testing.assert_array_equal(out.labels, expected.labels)
        np.testing.assert_allclose(out.image_uv, uv, atol=1e-3)  # float32 in the message


def test_normalised_coordinates_become_the_pixels_of_the_intrinsics() -> None:
    fx, fy, cx, cy = BAG_CAMERA[0, 0], BAG_CAMERA[1, 1], BAG_CAMERA[0, 2], BAG_CAMERA[1, 2]
    pipeline = MessagePipeline(build({'budget_ms': 0.0, 'camera_fx': fx, 'camera_fy': fy,
                                      'camera_cx': cx, 'camera_cy': cy}))
    out = labelled(pipeline.process(without_pixels(MESSAGES[0], 'PointCloud')))
    _, uv = decode_pointcloud(MESSAGES[0])
    assert out.image_uv is not None
    np.testing.assert_allclose(out.image_uv, uv, atol=0.05)
    _, published = decode_fields_uv(out.labels_msg)
    np.testing.assert_allclose(published, uv, atol=0.05)  # motion_labels carries pixels


def test_new_intrinsics_empty_a_window_of_normalised_coordinates() -> None:
    pipeline = MessagePipeline(build({'budget_ms': 0.0, 'camera_info_topic': '/camera_info'}))
    for msg in MESSAGES[:3]:  # no camera_info yet: a nominal camera's pixels
        labelled(pipeline.process(without_pixels(msg, 'PointCloud')))
    assert pipeline.frames_in_window == 3
    assert pipeline.add_camera_info(camera_info(0, BAG_CAMERA)) is None
    out = labelled(pipeline.process(without_pixels(MESSAGES[3], 'PointCloud')))
    assert pipeline.frames_in_window == 1 and (out.labels == -1).all()
    assert out.image_uv is not None
    assert pipeline.add_camera_info(camera_info(0, BAG_CAMERA)) is None  # the same: kept
    labelled(pipeline.process(without_pixels(MESSAGES[4], 'PointCloud')))
    assert pipeline.frames_in_window == 2
