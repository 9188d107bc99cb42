"""``pearl_tracker`` on a real executor: rendered frames in as ``sensor_msgs/Image``, VINS-Mono
features out, checked against the tracker run offline on the same frames (the oracle)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import Log
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import CameraInfo, Image, PointCloud, PointCloud2

from pearl_ros.bagio import cdr, decode
from pearl_ros.core.config import parameter_specs
from pearl_ros.core.errors import InputError
from pearl_ros.ros.node import PearlNode
from pearl_ros.ros.tracker_node import CHANNELS, NAMES, TrackerNode, features_message
from pearl_ros.tracking.image import array_to_image_fields
from pearl_ros.tracking.render import render_scene
from pearl_ros.tracking.tracker import FeatureTracker, TrackerConfig, Tracks

from ros_harness import RELIABLE, Ros, header

BIN = Path(sys.executable).parent
SCENE = render_scene(3, frames=6, size=(240, 320))
STAMPS = [1_000_000_000 + k * 33_000_000 for k in range(len(SCENE.frames))]
MAX_FEATURES = 120
K = np.array([[400.0, 0.0, 160.0], [0.0, 410.0, 120.0], [0.0, 0.0, 1.0]])


def as_encoding(gray: np.ndarray, encoding: str) -> np.ndarray:
    """The grey image in ``encoding``, converting back to the same grey levels."""
    if encoding == 'mono16':
        return gray.astype(np.uint16) << 8
    channels = {'mono8': 1, 'rgb8': 3, 'bgr8': 3, 'bgra8': 4, 'rgba8': 4}[encoding]
    return gray if channels == 1 else np.repeat(gray[:, :, None], channels, axis=2)


def image_msg(gray: np.ndarray, stamp_ns: int, encoding: str = 'mono8') -> Image:
    return Image(header=header(stamp_ns), **array_to_image_fields(as_encoding(gray, encoding),
                                                                  encoding))


class Camera:
    """A camera driver and a consumer of the tracker: image and camera_info out, features,
    diagnostics and log in."""

    def __init__(self, ros: Ros) -> None:
        self.ros = ros
        self.node = ros.node('camera')
        self.images = self.node.create_publisher(Image, 'image', RELIABLE)
        self.info = self.node.create_publisher(CameraInfo, 'camera_info', RELIABLE)
        self.features: list[PointCloud] = []
        self.diagnostics: list[DiagnosticStatus] = []
        self.logs: list[Log] = []
        self.node.create_subscription(PointCloud, 'features', self.features.append, RELIABLE)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 50)
        rosout = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.node.create_subscription(Log, '/rosout', self.logs.append, rosout)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        self.diagnostics.extend(s for s in msg.status if s.hardware_id.startswith(self.ros.ns))

    def wait_for(self, tracker: TrackerNode) -> None:
        assert self.ros.spin_until(
            lambda: self.images.get_subscription_count() > 0
            and self.info.get_subscription_count() > 0
            and self.node.count_publishers(f'{self.ros.ns}/features') > 0
            and tracker.count_subscribers(f'{self.ros.ns}/features') > 0, 10.0)

    def send(self, msg: Image, timeout: float = 10.0) -> PointCloud:
        """Publish an image; spin until its features arrive and return them."""
        stamp = decode.stamp_ns(msg.header)
        self.images.publish(msg)
        assert self.ros.spin_until(lambda: self.features_for(stamp) is not None, timeout), (
            f'no features for stamp {stamp}')
        found = self.features_for(stamp)
        assert found is not None
        return found

    def features_for(self, stamp: int) -> PointCloud | None:
        return next((m for m in self.features if decode.stamp_ns(m.header) == stamp), None)

    def last_diagnostics(self, key: str, value: str) -> dict[str, str]:
        def found() -> dict[str, str] | None:
            for status in reversed(self.diagnostics):
                values = {kv.key: kv.value for kv in status.values}
                if values.get(key) == value:
                    return {**values, '_level': status.level, '_message': status.message}
            return None
        assert self.ros.spin_until(lambda: found() is not None, 5.0), self.diagnostics[-1:]
        result = found()
        assert result is not None
        return result


def start(ros: Ros, **overrides: Any) -> tuple[TrackerNode, Camera]:
    overrides.setdefault('diagnostics_period', 0.1)
    overrides.setdefault('max_features', MAX_FEATURES)
    node = ros.add(TrackerNode(context=ros.context, namespace=ros.ns, parameter_overrides=[
        Parameter(name, value=value) for name, value in overrides.items()]))
    camera = Camera(ros)
    camera.wait_for(node)
    return node, camera


def columns(msg: PointCloud) -> dict[str, np.ndarray]:
    """Channel name -> values (float64), and ``points`` (N, 3)."""
    out = {c.name: np.asarray(c.values, dtype=np.float64) for c in msg.channels}
    out['points'] = np.array([[p.x, p.y, p.z] for p in msg.points]).reshape(-1, 3)
    return out


@pytest.mark.parametrize('encoding', ['mono8', 'rgb8', 'bgra8', 'mono16'])
def test_features_have_the_vins_layout_and_the_offline_trackers_ids_and_pixels(
    ros: Ros, encoding: str
) -> None:
    _, camera = start(ros)
    oracle = FeatureTracker(TrackerConfig(max_features=MAX_FEATURES))
    previous: set[int] = set()
    for frame, stamp in zip(SCENE.frames, STAMPS, strict=True):
        msg = camera.send(image_msg(frame, stamp, encoding))
        expected = oracle.track(frame, stamp)
        got = columns(msg)
        assert [c.name for c in msg.channels] == list(CHANNELS)
        assert msg.header.frame_id == 'cam0'
        np.testing.assert_array_equal(got['id_of_point'], expected.ids)
        uv = expected.uv.astype(np.float32)
        np.testing.assert_array_equal(got['u_of_point'], uv[:, 0])
        np.testing.assert_array_equal(got['v_of_point'], uv[:, 1])
        # Without camera_info the points are the pixels, and velocities px per second.
        np.testing.assert_array_equal(got['points'][:, :2], uv)
        assert np.all(got['points'][:, 2] == 1.0)
        np.testing.assert_allclose(got['velocity_x_of_point'], expected.velocity[:, 0],
                                   rtol=1e-6, atol=1e-3)
        np.testing.assert_allclose(got['velocity_y_of_point'], expected.velocity[:, 1],
                                   rtol=1e-6, atol=1e-3)
        ids = set(got['id_of_point'].astype(int).tolist())
        if previous:  # ids persist (the oracle loses 40-60% a frame in this small clip)
            assert len(ids & previous) >= 0.3 * len(previous)
        previous = ids
    # The first frame is published too (all features new).
    assert len(camera.features) == len(SCENE.frames)


def _project(xy: np.ndarray, model: str, distortion: np.ndarray) -> np.ndarray:
    """Pixels of normalised points: the forward camera model, the inverse of what the node
    computes (OpenCV's projection, not its undistortion)."""
    xy = np.ascontiguousarray(xy)  # OpenCV misreads a strided view
    if model == 'equidistant':
        return cv2.fisheye.distortPoints(xy.reshape(-1, 1, 2), K, distortion).reshape(-1, 2)
    points = np.column_stack([xy, np.ones(len(xy))])
    uv, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), K, distortion)
    return uv.reshape(-1, 2)


@pytest.mark.parametrize(('model', 'distortion'), [
    ('plumb_bob', [0.0, 0.0, 0.0, 0.0, 0.0]),
    ('plumb_bob', [-0.2, 0.05, 0.001, -0.002, 0.0]),
    ('equidistant', [0.05, -0.01, 0.002, 0.0]),
])
def test_with_camera_info_points_are_normalised_and_undistorted(
    ros: Ros, model: str, distortion: list[float]
) -> None:
    node, camera = start(ros)
    camera.info.publish(CameraInfo(header=header(STAMPS[0]), height=240, width=320,
                                   distortion_model=model, d=distortion, k=K.ravel().tolist()))
    assert ros.spin_until(lambda: node.camera is not None, 5.0)
    clouds = [columns(camera.send(image_msg(frame, stamp)))
              for frame, stamp in zip(SCENE.frames[:3], STAMPS[:3], strict=True)]
    for got in clouds:
        uv = np.column_stack([got['u_of_point'], got['v_of_point']])
        xy = got['points'][:, :2]
        assert np.all(got['points'][:, 2] == 1.0)
        if not any(distortion):  # an undistorted camera: K^-1 (u, v, 1)
            expected = (np.linalg.inv(K) @ np.column_stack([uv, np.ones(len(uv))]).T).T
            np.testing.assert_allclose(xy, expected[:, :2], atol=1e-6)
        np.testing.assert_allclose(_project(xy, model, np.asarray(distortion)), uv, atol=2e-3)
    # Velocities are those of the normalised points, per second.
    before, after = clouds[1], clouds[2]
    common, i, j = np.intersect1d(before['id_of_point'], after['id_of_point'],
                                  return_indices=True)
    assert common.size > 0.5 * MAX_FEATURES
    dt = (STAMPS[2] - STAMPS[1]) * 1e-9
    moved = (after['points'][j, :2] - before['points'][i, :2]) / dt
    np.testing.assert_allclose(after['velocity_x_of_point'][j], moved[:, 0], atol=1e-4)
    np.testing.assert_allclose(after['velocity_y_of_point'][j], moved[:, 1], atol=1e-4)


def test_a_bad_encoding_is_warned_about_and_counted_and_the_node_goes_on(ros: Ros) -> None:
    node, camera = start(ros)
    bad = Image(header=header(STAMPS[0]), height=240, width=320, encoding='32FC1',
                step=320 * 4, data=bytes(240 * 320 * 4))
    camera.images.publish(bad)
    values = camera.last_diagnostics('bad encodings', '1')
    assert values['_level'] == DiagnosticStatus.WARN and 'refused' in values['_message']
    assert values['frames published'] == '0'
    short = image_msg(SCENE.frames[0], STAMPS[0])
    short.step = 100  # shorter than a row: malformed
    camera.images.publish(short)
    camera.last_diagnostics('malformed images', '1')
    msg = camera.send(image_msg(SCENE.frames[1], STAMPS[1]))
    assert len(msg.points) > 0
    assert ros.spin_until(lambda: any('32FC1' in m.msg for m in camera.logs), 5.0)
    warning = next(m for m in camera.logs if '32FC1' in m.msg)
    assert warning.level == Log.WARN and '\n' not in warning.msg
    assert camera.features_for(STAMPS[0]) is None
    assert (node.stats.received, node.stats.published) == (3, 1)


@pytest.mark.parametrize(('overrides', 'reason'), [
    ({'max_feature': 30}, "unknown parameter 'max_feature' (did you mean 'max_features'?)"),
    ({'fb_threshold': -1.0}, 'fb_threshold must be >= 0.0, got -1.0'),
    ({'qos': 'fast'}, "qos must be one of ('sensor_data', 'reliable'), got 'fast'"),
    ({'window_size': 16}, 'window_size must be odd, got 16'),
])
def test_a_bad_start_up_value_stops_the_node_with_its_reason(
    ros: Ros, overrides: dict[str, Any], reason: str
) -> None:
    with pytest.raises(InputError) as caught:
        TrackerNode(context=ros.context, namespace=ros.ns, parameter_overrides=[
            Parameter(name, value=value) for name, value in overrides.items()])
    assert str(caught.value) == reason


def test_parameters_are_the_tracker_settings_with_descriptions_ranges_and_read_only(
    ros: Ros
) -> None:
    node = ros.add(TrackerNode(context=ros.context, namespace=ros.ns, parameter_overrides=[
        Parameter('min_distance', value=12)]))  # an integer for a float: that float
    for item in parameter_specs(TrackerConfig):
        desc = node.describe_parameter(item.name)
        assert desc.description == item.doc and desc.read_only
        bounds = desc.floating_point_range if item.type is float else desc.integer_range
        assert (bounds[0].from_value, bounds[0].to_value) == (item.low, item.high)
    assert node.get_parameter('min_distance').value == 12.0
    assert node.tracker_config.min_distance == 12.0
    result = node.set_parameters_atomically([Parameter('max_feature', value=3)])
    assert not result.successful
    assert result.reason == "unknown parameter 'max_feature' (did you mean 'max_features'?)"
    assert not node.set_parameters_atomically([Parameter('max_features', value=3)]).successful


def test_help_lists_topics_and_every_parameter_without_starting_ros() -> None:
    env = {**os.environ, 'ROS_DOMAIN_ID': 'none'}  # starting ROS would fail
    done = subprocess.run([str(BIN / 'pearl_tracker'), '--help'], capture_output=True,
                          text=True, timeout=60, env=env)
    assert done.returncode == 0 and done.stderr == '', done.stderr
    for topic in ('image (in)', 'camera_info (in)', 'features (out)', '/diagnostics (out)'):
        assert topic in done.stdout
    for name in NAMES:
        assert f'\n  {name}: ' in done.stdout, name
    bad = subprocess.run([str(BIN / 'pearl_tracker'), '--ros-args', '-p', 'max_feature:=3'],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 1 and 'Traceback' not in bad.stderr
    assert bad.stderr.strip().splitlines()[-1] == (
        "error: unknown parameter 'max_feature' (did you mean 'max_features'?)")


def test_tracker_feeds_pearl_node_which_labels_every_frame(ros: Ros) -> None:
    scene = render_scene(1, frames=12, size=(240, 320))
    stamps = [2_000_000_000 + k * 66_000_000 for k in range(len(scene.frames))]
    tracker, camera = start(ros)
    pearl = ros.add(PearlNode(context=ros.context, namespace=ros.ns, parameter_overrides=[
        Parameter('diagnostics_period', value=0.1)]))
    labels: list[PointCloud2] = []
    camera.node.create_subscription(PointCloud2, 'motion_labels', labels.append, RELIABLE)
    assert ros.spin_until(lambda: tracker.count_subscribers(f'{ros.ns}/features') >= 2
                          and camera.node.count_publishers(f'{ros.ns}/motion_labels') > 0, 10.0)
    del pearl
    for frame, stamp in zip(scene.frames, stamps, strict=True):
        features = camera.send(image_msg(frame, stamp))
        assert ros.spin_until(
            lambda s=stamp: any(decode.stamp_ns(m.header) == s for m in labels), 10.0), stamp
        answer = next(m for m in labels if decode.stamp_ns(m.header) == stamp)
        got = decode.decode_fields(answer, ('id', 'u', 'label'))
        np.testing.assert_array_equal(got['id'], columns(features)['id_of_point'])
        np.testing.assert_array_equal(got['u'], columns(features)['u_of_point'])
        assert np.all(got['label'] >= -1)
    assert len(labels) == len(scene.frames)


def test_a_stamp_back_in_time_ends_every_track_and_ids_count_on(ros: Ros) -> None:
    node, camera = start(ros)
    before = [columns(camera.send(image_msg(frame, stamp)))['id_of_point']
              for frame, stamp in zip(SCENE.frames[:2], STAMPS[:2], strict=True)]
    again = columns(camera.send(image_msg(SCENE.frames[0], STAMPS[0] - 1)))
    # All features new: ids never reused, velocities 0.
    assert again['id_of_point'].min() > max(ids.max() for ids in before)
    assert not np.any(again['velocity_x_of_point']) and not np.any(again['velocity_y_of_point'])
    camera.last_diagnostics('track resets (stamp went back)', '1')
    assert ros.spin_until(lambda: any('went back in time' in m.msg for m in camera.logs), 5.0)
    assert node.stats.resets == 1


def test_the_executable_tracks_for_another_process_and_stops_on_ctrl_c(ros: Ros) -> None:
    process = subprocess.Popen(
        [str(BIN / 'pearl_tracker'), '--ros-args', '-r', f'__ns:={ros.ns}',
         '-p', 'max_features:=60', '-p', 'diagnostics_period:=0.2'],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        camera = Camera(ros)
        assert ros.spin_until(
            lambda: process.poll() is not None
            or (camera.images.get_subscription_count() > 0
                and camera.node.count_publishers(f'{ros.ns}/features') > 0), 30.0)
        assert process.poll() is None, 'the node did not come up'
        # Matching is decided on each side separately: send until one image is answered.
        sent = 0

        def answered() -> bool:
            nonlocal sent
            if not camera.features:
                camera.images.publish(image_msg(SCENE.frames[0], STAMPS[0] + sent))
                sent += 1
                ros.spin_until(lambda: bool(camera.features), 0.3)
            return bool(camera.features)
        assert ros.spin_until(answered, 30.0), 'no features from the node'
        msg = camera.send(image_msg(SCENE.frames[1], STAMPS[1]), timeout=15.0)
        assert [c.name for c in msg.channels] == list(CHANNELS) and 0 < len(msg.points) <= 60
    finally:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
        try:
            _, err = process.communicate(timeout=15)
        except subprocess.TimeoutExpired:
            process.kill()
            _, err = process.communicate()
    assert process.returncode == 0, err
    assert 'Traceback' not in err


def test_an_uncalibrated_camera_info_is_refused_once_and_points_stay_pixels(ros: Ros) -> None:
    node, camera = start(ros)
    for _ in range(3):  # an uncalibrated driver: all-zero K with every image
        camera.info.publish(CameraInfo(header=header(STAMPS[0]), distortion_model='plumb_bob',
                                       d=[0.0] * 5))
    camera.last_diagnostics('camera_info refused', '1')
    got = columns(camera.send(image_msg(SCENE.frames[0], STAMPS[0])))
    np.testing.assert_array_equal(got['points'][:, 0], got['u_of_point'])
    assert node.camera is None and node.stats.bad_camera_info == 1
    assert ros.spin_until(lambda: any('camera_info refused' in m.msg for m in camera.logs), 5.0)


def test_a_parameter_file_sets_the_tracker_and_a_misspelt_name_in_it_is_refused(
    ros: Ros, tmp_path: Path
) -> None:
    good = tmp_path / 'good.yaml'
    good.write_text(f'{ros.ns}/pearl_tracker:\n  ros__parameters:\n    max_features: 50\n'
                    '    fb_threshold: 2\n')  # an integer for a float: that float
    node = ros.add(TrackerNode(context=ros.context, namespace=ros.ns,
                               cli_args=['--ros-args', '--params-file', str(good)]))
    assert node.tracker_config.max_features == 50
    assert node.tracker_config.fb_threshold == 2.0
    bad = tmp_path / 'bad.yaml'
    bad.write_text('/**:\n  ros__parameters:\n    max_featurs: 50\n')
    with pytest.raises(InputError) as caught:
        TrackerNode('other', context=ros.context, namespace=ros.ns,
                    cli_args=['--ros-args', '--params-file', str(bad)])
    assert str(caught.value) == (f"parameter file {bad}: unknown parameter 'max_featurs' "
                                 "(did you mean 'max_features'?)")


def test_ids_wrap_at_2_to_the_24_where_float32_stops_being_exact() -> None:
    ids = np.array([5, 2**24 - 1, 2**24, 2**24 + 7, 3 * 2**24 + 1])
    uv = np.arange(10.0).reshape(5, 2)
    tracks = Tracks(ids, uv, None, np.zeros((5, 2)), None, np.ones(5, np.int64))
    got = columns(deserialize_message(cdr.serialize(features_message(header(0), tracks)),
                                      PointCloud))
    np.testing.assert_array_equal(got['id_of_point'], [5, 2**24 - 1, 0, 7, 1])
    np.testing.assert_array_equal(got['points'][:, :2], uv)
