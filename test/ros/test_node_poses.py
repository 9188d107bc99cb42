"""pearl_node with a camera pose topic: odometry published after each frame's features (as VINS
publishes its camera_pose), the static world found as a motion of known parameters."""

from __future__ import annotations

import numpy as np
import pytest
from geometry_msgs.msg import (
    Point,
    Pose,
    PoseStamped,
    PoseWithCovariance,
    PoseWithCovarianceStamped,
    Quaternion,
)
from nav_msgs.msg import Odometry
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo
from static_scene import FOCAL, INTRINSICS, camera_info, pose_of, static_scene, write_scene_bag

from pearl_ros.bagio import decode
from pearl_ros.core.errors import BagError, InputError
from pearl_ros.core.metrics import misclassification
from pearl_ros.ros.convert import CAMERA_INFO_CLASSES
from pearl_ros.ros.play import Player, bag_messages, load_poses

from ros_harness import RELIABLE, Ros, header, vins_cloud

STEP_NS = 33_333_333
START_NS = 1_000_000_000
INTRINSIC_PARAMETERS = {'camera_fx': FOCAL, 'camera_fy': FOCAL, 'camera_cx': 320.0,
                        'camera_cy': 240.0}


def _pose(camera: np.ndarray) -> Pose:
    centre, q = pose_of(camera)
    return Pose(position=Point(x=centre[0], y=centre[1], z=centre[2]),
                orientation=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]))


def _run(ros: Ros, pose_type: str | None, info: bool = False) -> tuple[float, dict[str, str]]:
    """The scene through the node (poses on ``camera_pose`` after each frame's features, if
    ``pose_type``; with ``info`` the intrinsics on ``camera_info`` with each frame, as a camera
    driver publishes them, instead of parameters); the final frame's misclassification and the
    node's last diagnostics."""
    tracks, truth, cameras = static_scene(frames=16, seed=8)
    intrinsics = {'camera_info_topic': 'camera_info'} if info else INTRINSIC_PARAMETERS
    extra = {} if pose_type is None else {'pose_topic': 'camera_pose', 'pose_type': pose_type,
                                          **intrinsics}
    node = ros.pearl(budget_ms=0.0, **extra)
    probe = ros.probe()
    kind = {'odometry': Odometry, 'pose_stamped': PoseStamped,
            'pose_with_covariance_stamped': PoseWithCovarianceStamped}.get(pose_type, Odometry)
    poses = probe.node.create_publisher(kind, 'camera_pose', RELIABLE)
    infos = probe.node.create_publisher(CameraInfo, 'camera_info', qos_profile_sensor_data)
    probe.wait_for(node)
    if pose_type is not None:
        assert ros.spin_until(lambda: poses.get_subscription_count() > 0)
    if info:
        assert ros.spin_until(lambda: infos.get_subscription_count() > 0)
    ids = np.arange(truth.size)
    for t in range(tracks.shape[0]):
        stamp = START_NS + t * STEP_NS
        if info:
            infos.publish(CameraInfo(header=header(stamp), width=640, height=480,
                                     k=INTRINSICS.ravel().tolist()))
        labels_msg = probe.send(vins_cloud(stamp, ids, tracks[t]))
        if pose_type == 'odometry':
            poses.publish(Odometry(header=header(stamp), child_frame_id='cam0',
                                   pose=PoseWithCovariance(pose=_pose(cameras[t]))))
        elif pose_type == 'pose_stamped':
            poses.publish(PoseStamped(header=header(stamp), pose=_pose(cameras[t])))
        elif pose_type == 'pose_with_covariance_stamped':
            poses.publish(PoseWithCovarianceStamped(
                header=header(stamp), pose=PoseWithCovariance(pose=_pose(cameras[t]))))
    assert labels_msg is not None
    columns = decode.decode_fields(labels_msg, ('id', 'label'))
    labels = columns['label'][np.argsort(columns['id'])]
    values = probe.diagnostics_where(lambda v: v.get('messages processed') == '16')
    return misclassification(labels, truth), values


@pytest.mark.parametrize('pose_type', ['odometry', 'pose_stamped',
                                       'pose_with_covariance_stamped'])
def test_poses_after_their_frames_let_the_node_find_the_static_world(ros: Ros, pose_type):
    error, values = _run(ros, pose_type)
    assert error < 0.05
    # Each frame is segmented before its pose comes; the poses are all taken, late.
    assert int(values['camera poses taken']) >= 14 and values['camera poses refused'] == '0'
    assert int(values['frames given a camera pose']) >= 14


def test_a_camera_info_topic_gives_the_node_its_intrinsics(ros: Ros):
    error, values = _run(ros, 'odometry', info=True)
    assert error < 0.05
    assert int(values['camera_info taken']) >= 1 and values['camera_info refused'] == '0'
    assert int(values['frames given a camera pose']) >= 14


def test_a_camera_info_that_is_no_calibration_is_counted_and_warned_about(ros: Ros):
    node = ros.pearl(pose_topic='camera_pose', camera_info_topic='camera_info')
    probe = ros.probe()
    infos = probe.node.create_publisher(CameraInfo, 'camera_info', qos_profile_sensor_data)
    probe.wait_for(node)
    assert ros.spin_until(lambda: infos.get_subscription_count() > 0)
    infos.publish(CameraInfo(header=header(START_NS)))  # k all zero: uncalibrated
    assert ros.spin_until(lambda: node._pending_info is not None)
    probe.send(vins_cloud(START_NS, [0, 1, 2], [[1.0, 1.0], [5.0, 2.0], [3.0, 9.0]]))
    assert ros.spin_until(lambda: node.stats.bad_camera_infos == 1)
    assert node.stats.camera_infos == 0
    assert ros.spin_until(lambda: probe.warnings('uncalibrated'))
    for t in range(1, 10):
        probe.send(vins_cloud(START_NS + t * STEP_NS, [0, 1, 2],
                              [[1.0, 1.0], [5.0, 2.0], [3.0, 9.0]]))
    values = probe.diagnostics_where(lambda v: v.get('messages processed') == '10')
    assert 'no valid camera_info on camera_info' in values['_message']


def test_camera_info_alone_gives_the_node_its_lens(ros: Ros):
    node = ros.pearl(camera_info_topic='camera_info')
    subscriptions = node.get_subscriber_names_and_types_by_node(node.get_name(), ros.ns)
    assert any('CameraInfo' in ''.join(types) for _, types in subscriptions)
    probe = ros.probe()
    infos = probe.node.create_publisher(CameraInfo, 'camera_info', qos_profile_sensor_data)
    probe.wait_for(node)
    assert ros.spin_until(lambda: infos.get_subscription_count() > 0)
    infos.publish(CameraInfo(header=header(START_NS), distortion_model='plumb_bob',
                             d=[-0.3, 0.08, 0.0, 0.0, 0.0], k=INTRINSICS.ravel().tolist()))
    assert ros.spin_until(lambda: node._pending_info is not None)
    probe.send(vins_cloud(START_NS, [0, 1, 2], [[1.0, 1.0], [5.0, 2.0], [3.0, 9.0]]))
    assert ros.spin_until(lambda: node.stats.camera_infos == 1)
    assert node._pipeline._lens is not None and node.stats.frames_with_camera == 0
    values = {kv.key: kv.value for kv in node.diagnostics().status[0].values}
    assert values['camera_info taken'] == '1' and 'camera poses taken' not in values


def test_without_a_pose_topic_there_is_no_pose_subscription(ros: Ros):
    node = ros.pearl()
    subscriptions = node.get_subscriber_names_and_types_by_node(node.get_name(), ros.ns)
    assert not any('Odometry' in ''.join(types) or 'PoseStamped' in ''.join(types)
                   or 'CameraInfo' in ''.join(types) for _, types in subscriptions)
    assert 'camera poses taken' not in {kv.key for kv in node.diagnostics().status[0].values}


def test_pose_topic_needs_intrinsics_is_read_only_and_a_bad_pose_is_counted(ros: Ros):
    with pytest.raises(InputError, match='camera_info_topic, or camera_fx and camera_fy'):
        ros.pearl(pose_topic='camera_pose')
    node = ros.pearl(pose_topic='camera_pose', **INTRINSIC_PARAMETERS)
    result = node.set_parameters([Parameter('pose_topic', value='other')])[0]
    assert not result.successful and 'read-only' in result.reason
    probe = ros.probe()
    poses = probe.node.create_publisher(Odometry, 'camera_pose', RELIABLE)
    probe.wait_for(node)
    assert ros.spin_until(lambda: poses.get_subscription_count() > 0)
    zero = Pose(orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=0.0))
    poses.publish(Odometry(header=header(START_NS), pose=PoseWithCovariance(pose=zero)))
    assert ros.spin_until(lambda: len(node._pending_poses) == 1)
    probe.send(vins_cloud(START_NS, [0, 1, 2], [[1.0, 1.0], [5.0, 2.0], [3.0, 9.0]]))
    assert ros.spin_until(lambda: node.stats.bad_poses == 1)
    assert ros.spin_until(lambda: probe.warnings('non-zero quaternion'))


def test_pearl_play_plays_a_bags_poses_beside_its_features(ros: Ros, tmp_path):
    topic = f'{ros.ns}/camera_pose'
    truth = write_scene_bag(tmp_path / 'scene', 16, 9, topic)
    node = ros.pearl(budget_ms=0.0, pose_topic=topic, **INTRINSIC_PARAMETERS)
    poses = load_poses(tmp_path / 'scene', topic)
    assert len(poses.stamps) == 16 and poses.msg_class is Odometry
    player = ros.add(Player(bag_messages(tmp_path / 'scene'), context=ros.context,
                            namespace=ros.ns, poses=poses))
    assert player.wait_for_node(ros.executor, 10.0)
    assert player.poses is not None
    assert ros.spin_until(lambda: player.poses.publisher.get_subscription_count() > 0)
    answers = player.play(ros.executor, timeout_s=10.0)
    assert all(answer is not None for answer in answers)
    # Each pose is stamped 1 us after its frame: it goes out before the next frame.
    assert player.poses.sent == 15 and node.stats.poses == 15
    final = answers[-1]
    assert final is not None
    assert misclassification(final.labels[np.argsort(final.ids)], truth) < 0.05


def test_pearl_play_plays_a_bags_camera_info_for_a_node_that_takes_it(ros: Ros, tmp_path):
    topic, info_topic = f'{ros.ns}/camera_pose', f'{ros.ns}/camera_info'
    stamps = [START_NS + t * STEP_NS for t in range(16)]
    truth = write_scene_bag(tmp_path / 'scene', 16, 9, topic,
                            extra=[(info_topic, s, camera_info(s, INTRINSICS)) for s in stamps])
    node = ros.pearl(budget_ms=0.0, pose_topic=topic, camera_info_topic=info_topic)
    info = load_poses(tmp_path / 'scene', info_topic, classes=CAMERA_INFO_CLASSES)
    assert info.msg_class is CameraInfo and len(info.stamps) == 16
    player = ros.add(Player(bag_messages(tmp_path / 'scene'), context=ros.context,
                            namespace=ros.ns, poses=load_poses(tmp_path / 'scene', topic),
                            camera_info=info))
    assert player.wait_for_node(ros.executor, 10.0)
    assert player.camera_info is not None
    assert ros.spin_until(lambda: player.camera_info.publisher.get_subscription_count() > 0)
    answers = player.play(ros.executor, timeout_s=10.0)
    assert all(answer is not None for answer in answers)
    assert player.camera_info.sent == 16 and node.stats.camera_infos >= 1
    assert node.stats.frames_with_camera >= 14
    final = answers[-1]
    assert final is not None
    assert misclassification(final.labels[np.argsort(final.ids)], truth) < 0.05
    with pytest.raises(BagError, match='expected sensor_msgs/msg/CameraInfo'):
        load_poses(tmp_path / 'scene', topic, classes=CAMERA_INFO_CLASSES)


def test_poses_on_another_clock_are_reported_in_the_diagnostics(ros: Ros):
    tracks, _, cameras = static_scene(frames=12, seed=10)
    node = ros.pearl(budget_ms=0.0, pose_topic='camera_pose', **INTRINSIC_PARAMETERS)
    probe = ros.probe()
    poses = probe.node.create_publisher(Odometry, 'camera_pose', RELIABLE)
    probe.wait_for(node)
    assert ros.spin_until(lambda: poses.get_subscription_count() > 0)
    ids = np.arange(tracks.shape[1])
    for t in range(tracks.shape[0]):
        stamp = START_NS + t * STEP_NS
        probe.send(vins_cloud(stamp, ids, tracks[t]))
        # Stamped on a clock 100 s ahead: no pose is near any frame.
        poses.publish(Odometry(header=header(stamp + 100 * 10**9),
                               pose=PoseWithCovariance(pose=_pose(cameras[t]))))
    values = probe.diagnostics_where(lambda v: v.get('messages processed') == '12')
    assert values['frames given a camera pose'] == '0' and int(values['camera poses taken']) >= 10
    assert 'no camera pose within pose_tolerance_ms' in values['_message']
