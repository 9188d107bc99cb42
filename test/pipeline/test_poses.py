"""Camera poses as the segmenter takes them: projection matrices from odometry, poses matched to
frames by stamp, and a replay of a bag whose camera poses are recorded beside its features."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from scipy.spatial.transform import Rotation
from static_scene import FOCAL, INTRINSICS, camera_info, pose_of, static_scene, write_scene_bag

from pearl_ros.bagio.decode import decode_fields
from pearl_ros.bagio.reader import TYPESTORE, FeatureFrame
from pearl_ros.bagio.writer import write_feature_bag
from pearl_ros.cli.replay import main
from pearl_ros.core.errors import InputError
from pearl_ros.core.metrics import misclassification
from pearl_ros.pipeline.poses import (
    PoseBuffer,
    camera_matrix,
    intrinsics_matrix,
    mounted,
    quaternion,
    read_intrinsics,
    read_pose,
    rotation_matrix,
)
from pearl_ros.pipeline.settings import NodeConfig

POSE_TOPIC = '/vins_estimator/camera_pose'
INTRINSIC_SETTINGS = [f'camera_fx={FOCAL}', f'camera_fy={FOCAL}', 'camera_cx=320',
                      'camera_cy=240']


def test_quaternions_and_rotations_agree_with_scipy():
    for seed in range(50):
        rotation = Rotation.random(random_state=seed)
        expected = rotation.as_quat()  # (x, y, z, w)
        expected = expected if expected[3] >= 0 else -expected
        assert np.allclose(quaternion(rotation.as_matrix()), expected)
        assert np.allclose(rotation_matrix(rotation.as_quat()), rotation.as_matrix())
        assert np.allclose(rotation_matrix(3.0 * rotation.as_quat()), rotation.as_matrix())


def test_camera_matrix_projects_as_a_pinhole_in_the_optical_frame():
    rng = np.random.default_rng(0)
    rotation = Rotation.random(random_state=1).as_matrix()  # world from camera
    centre = np.array([2.0, -1.0, 0.5])
    k = intrinsics_matrix(400.0, 410.0, 320.0, 240.0)
    camera = camera_matrix(centre, quaternion(rotation), k)
    # Points placed in front of the camera, in its own frame, then moved to the world.
    local = np.column_stack([rng.uniform(-2, 2, 20), rng.uniform(-2, 2, 20),
                             rng.uniform(3, 9, 20)])
    world = local @ rotation.T + centre
    projected = np.hstack([world, np.ones((20, 1))]) @ camera.T
    uv = projected[:, :2] / projected[:, 2:]
    expected = np.column_stack([400.0 * local[:, 0] / local[:, 2] + 320.0,
                                410.0 * local[:, 1] / local[:, 2] + 240.0])
    assert np.allclose(uv, expected)


@pytest.mark.parametrize('call, message', [
    (lambda: rotation_matrix(np.zeros(4)), 'non-zero quaternion'),
    (lambda: rotation_matrix([0.0, 0.0, np.nan, 1.0]), 'finite'),
    (lambda: camera_matrix([0.0, np.inf, 0.0], [0, 0, 0, 1], np.eye(3)), 'position'),
    (lambda: intrinsics_matrix(0.0, 500.0, 320.0, 240.0), 'fx, fy > 0'),
    (lambda: read_pose(object(), 'odometry'), 'not a nav_msgs/msg/Odometry'),
    (lambda: read_pose(object(), 'pose_with_covariance_stamped'),
     'not a geometry_msgs/msg/PoseWithCovarianceStamped'),
    (lambda: read_pose(object(), 'twist'), 'pose_type'),
])
def test_bad_poses_are_refused_in_one_line(call, message):
    with pytest.raises(InputError, match=message):
        call()


def test_pose_topic_needs_the_intrinsics():
    with pytest.raises(InputError, match='camera_fx and camera_fy'):
        NodeConfig(pose_topic='/odom')
    NodeConfig(pose_topic='/odom', camera_fx=500.0, camera_fy=500.0)


def test_a_frame_takes_the_nearest_pose_within_the_tolerance():
    buffer = PoseBuffer(tolerance_ns=10)
    cameras = {stamp: np.full((3, 4), float(stamp)) for stamp in (100, 130, 200)}
    for stamp, camera in cameras.items():
        buffer.add(stamp, camera)
    assert buffer.find(108) is cameras[100] and buffer.find(125) is cameras[130]
    assert buffer.find(115) is None and buffer.find(215) is None
    buffer.add(50, cameras[100])  # a bag played again: the rest is forgotten
    assert len(buffer) == 1 and buffer.find(200) is None


@pytest.fixture(scope='module')
def scene_bag(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, np.ndarray]:
    """The static scene (a driving camera, a crossing box) as a bag with VINS-like camera poses
    recorded beside the features, each pose logged just after its frame."""
    path = tmp_path_factory.mktemp('poses') / 'scene'
    return path, write_scene_bag(path, 20, 7, POSE_TOPIC)


def _final_labels(bag: Path) -> np.ndarray:
    with AnyReader([bag], default_typestore=TYPESTORE) as reader:
        connections = [c for c in reader.connections if c.topic == '/motion_labels']
        last = list(reader.messages(connections=connections))[-1]
        msg = reader.deserialize(last[2], last[0].msgtype)
    columns = decode_fields(msg, ('id', 'label'))
    return columns['label'][np.argsort(columns['id'])]


def test_a_replay_with_recorded_poses_finds_the_static_world_and_the_box(tmp_path, scene_bag):
    bag, truth = scene_bag
    stats_path = tmp_path / 'stats.json'
    settings = [f'pose_topic={POSE_TOPIC}', 'pose_tolerance_ms=1', 'budget_ms=0',
                *INTRINSIC_SETTINGS]
    args = [str(bag), '--output', str(tmp_path / 'out'), '--stats', str(stats_path)]
    for item in settings:
        args += ['--set', item]
    assert main(args) == 0
    stats = json.loads(stats_path.read_text())
    assert stats['counts']['poses'] == 20 and stats['counts']['bad_poses'] == 0
    # Each pose comes 1 us after its frame and goes to it then: every frame got its camera.
    assert stats['counts']['frames_with_camera'] == 20
    assert POSE_TOPIC in stats['counts']['copied']
    assert misclassification(_final_labels(tmp_path / 'out'), truth) < 0.05


def test_poses_beyond_the_tolerance_are_not_used(tmp_path, scene_bag, capsys):
    bag, truth = scene_bag
    stats_path = tmp_path / 'stats.json'
    # Poses come 1 us after their frames: with a tolerance of 0 ms no frame takes one, and
    # the replay segments as without poses (the driving scene then reads as one motion).
    args = [str(bag), '--output', str(tmp_path / 'out'), '--stats', str(stats_path),
            '--set', f'pose_topic={POSE_TOPIC}', '--set', 'pose_tolerance_ms=0',
            '--set', 'budget_ms=0', *sum((['--set', s] for s in INTRINSIC_SETTINGS), [])]
    assert main(args) == 0
    plain = tmp_path / 'plain'
    assert main([str(bag), '--output', str(plain), '--set', 'budget_ms=0']) == 0
    assert np.array_equal(_final_labels(tmp_path / 'out'), _final_labels(plain))
    assert json.loads(stats_path.read_text())['counts']['frames_with_camera'] == 0
    assert 'none of the 20 poses on /vins_estimator/camera_pose is within pose_tolerance_ms' \
        in capsys.readouterr().err


def test_poses_of_another_type_are_warned_about_counted_and_left_out(tmp_path, scene_bag,
                                                                      capsys):
    bag, truth = scene_bag
    stats_path = tmp_path / 'stats.json'
    # The bag's poses are Odometry; told they are PoseStamped, the replay takes none of them,
    # says so once, and segments as without poses.
    args = [str(bag), '--output', str(tmp_path / 'out'), '--stats', str(stats_path),
            '--set', f'pose_topic={POSE_TOPIC}', '--set', 'pose_type=pose_stamped',
            '--set', 'budget_ms=0', *sum((['--set', s] for s in INTRINSIC_SETTINGS), [])]
    assert main(args) == 0
    counts = json.loads(stats_path.read_text())['counts']
    assert counts['poses'] == 0 and counts['bad_poses'] == 20
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if 'nav_msgs/msg/Odometry, not' in line]
    assert len(lines) == 1, err
    assert 'geometry_msgs/msg/PoseStamped (pose_type pose_stamped)' in lines[0]


def test_a_mounted_camera_pose_composes_the_body_pose_with_the_mounting():
    body_position, body_q = np.array([5.0, -2.0, 0.3]), Rotation.random(random_state=3).as_quat()
    # A camera 1.2 m up and 0.4 m ahead on a base_link (x forward, z up), looking forward:
    # its optical z along the body's x, its optical x along the body's -y.
    mount_position = np.array([0.4, 0.0, 1.2])
    mount_q = Rotation.from_matrix(np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]])).as_quat()
    position, q = mounted(body_position, body_q, mount_position, mount_q)
    expected = _matrix(body_position, body_q) @ _matrix(mount_position, mount_q)
    assert np.allclose(position, expected[:3, 3])
    assert np.allclose(rotation_matrix(q), expected[:3, :3])


def test_the_replay_applies_the_mounting_to_body_poses(tmp_path, scene_bag):
    bag, truth = scene_bag
    # The same scene with the poses of a body that carries the camera 1 m to its side, turned
    # a quarter: composed with that mounting they are the camera's again, and the labels are
    # those of the camera's own poses.
    mount_position = np.array([1.0, 0.0, 0.0])
    mount_q = Rotation.from_euler('z', 90, degrees=True).as_quat()
    tracks, truth, cameras = static_scene(frames=20, seed=7)
    ids = np.arange(truth.size)
    stamps = [1_000_000_000 + t * 33_333_333 for t in range(20)]
    inverse = np.linalg.inv(_matrix(mount_position, mount_q))
    body = []
    for t, s in enumerate(stamps):
        camera = _matrix(*pose_of(cameras[t])) @ inverse
        body.append((s + 1_000, camera[:3, 3], Rotation.from_matrix(camera[:3, :3]).as_quat()))
    body_bag = tmp_path / 'body'
    write_feature_bag(body_bag, [FeatureFrame(s, ids, tracks[t]) for t, s in enumerate(stamps)],
                      [(s, ids, truth) for s in stamps], poses=body, pose_topic=POSE_TOPIC)
    common = ['--set', f'pose_topic={POSE_TOPIC}', '--set', 'pose_tolerance_ms=1', '--set',
              'budget_ms=0', *sum((['--set', s] for s in INTRINSIC_SETTINGS), [])]
    mount = ['--set', 'mount_x=1', *sum((['--set', f'mount_q{axis}={value}'] for axis, value
                                         in zip('xyzw', mount_q, strict=True)), [])]
    assert main([str(body_bag), '--output', str(tmp_path / 'mounted'), *common, *mount]) == 0
    assert main([str(bag), '--output', str(tmp_path / 'own'), *common]) == 0
    assert np.array_equal(_final_labels(tmp_path / 'mounted'), _final_labels(tmp_path / 'own'))
    assert misclassification(_final_labels(tmp_path / 'mounted'), truth) < 0.05
    with pytest.raises(InputError, match='must not be zero'):
        NodeConfig(mount_qw=0.0)


def _matrix(position, q):
    out = np.eye(4)
    out[:3, :3] = Rotation.from_quat(q).as_matrix()
    out[:3, 3] = position
    return out


def test_with_poses_static_features_are_the_static_worlds_not_the_largest_motions(tmp_path):
    # A truck fills most of the view: 100 of its features against 60 of the static world's.
    bag = tmp_path / 'truck'
    truth = write_scene_bag(bag, 20, 11, POSE_TOPIC, static=60, moving=100)
    common = ['--set', 'budget_ms=0']
    poses = ['--set', f'pose_topic={POSE_TOPIC}', '--set', 'pose_tolerance_ms=1',
             *sum((['--set', s] for s in INTRINSIC_SETTINGS), [])]
    assert main([str(bag), '--output', str(tmp_path / 'poses'), *common, *poses]) == 0
    assert main([str(bag), '--output', str(tmp_path / 'plain'), *common]) == 0

    def static_ids(out: Path) -> np.ndarray:
        with AnyReader([out], default_typestore=TYPESTORE) as reader:
            connections = [c for c in reader.connections if c.topic == '/static_features']
            last = list(reader.messages(connections=connections))[-1]
            msg = reader.deserialize(last[2], last[0].msgtype)
        ids = [c.values for c in msg.channels if c.name == 'id_of_point'][0]
        return np.sort(np.asarray(ids, dtype=np.int64))

    world = np.flatnonzero(truth == 0)
    with_poses = static_ids(tmp_path / 'poses')
    assert np.mean(np.isin(with_poses, world)) > 0.95 and with_poses.size > 0.9 * world.size
    # Without poses the largest motion is taken for the background: the truck, where it was
    # found apart.
    assert not np.array_equal(static_ids(tmp_path / 'plain'), with_poses)


def test_camera_info_gives_the_intrinsics_of_the_binned_cropped_image_it_describes():
    k = np.array([[410.0, 0.5, 330.0], [0.0, 400.0, 250.0], [0.0, 0.0, 1.0]])
    assert np.array_equal(read_intrinsics(camera_info(0, k)), k)
    # A full-resolution pixel, and the same pixel in the image cropped at (40, 30) and binned
    # by 2 x 4: ((u - 40) / 2, (v - 30) / 4).
    rng = np.random.default_rng(0)
    points = np.column_stack([rng.uniform(-2, 2, 10), rng.uniform(-2, 2, 10),
                              rng.uniform(3, 9, 10)])
    full = points @ k.T
    full = full[:, :2] / full[:, 2:]
    binned = points @ read_intrinsics(camera_info(0, k, (2, 4), (40, 30))).T
    assert np.allclose(binned[:, :2] / binned[:, 2:],
                       np.column_stack([(full[:, 0] - 40) / 2, (full[:, 1] - 30) / 4]))


@pytest.mark.parametrize('k, words', [
    (np.zeros((3, 3)), 'uncalibrated'),
    (np.array([[400.0, 0, 320], [0, -400.0, 240], [0, 0, 1]]), 'fx, fy > 0'),
    (np.array([[np.nan, 0, 320], [0, 400.0, 240], [0, 0, 1]]), 'finite'),
    (np.array([[400.0, 0, 320], [5.0, 400.0, 240], [0, 0, 1]]), '0 fy cy'),
])
def test_camera_info_that_is_no_calibration_is_refused_in_one_line(k, words):
    with pytest.raises(InputError, match=words) as err:
        read_intrinsics(camera_info(0, k))
    assert '\n' not in str(err.value)
    with pytest.raises(InputError, match='9 numbers'):
        read_intrinsics(type('Info', (), {'k': [1.0, 2.0]})())
    with pytest.raises(InputError, match='CameraInfo'):
        read_intrinsics(object())


INFO_TOPIC = '/camera/camera_info'


def _replay_counts(bag, out, settings):
    stats_path = out.parent / f'{out.name}.json'
    args = [str(bag), '--output', str(out), '--stats', str(stats_path)]
    for item in settings:
        args += ['--set', item]
    assert main(args) == 0
    return json.loads(stats_path.read_text())['counts']


def test_camera_info_in_the_bag_stands_in_for_the_intrinsics_parameters(tmp_path):
    # The scene's camera_info comes once, at the 6th frame: the poses of the five frames
    # before it wait, and those frames get their cameras then, as later ones do on arrival.
    stamps = [1_000_000_000 + t * 33_333_333 for t in range(20)]
    bag = tmp_path / 'scene'
    truth = write_scene_bag(bag, 20, 7, POSE_TOPIC,
                            extra=[(INFO_TOPIC, stamps[5] + 500, camera_info(stamps[5],
                                                                            INTRINSICS))])
    common = [f'pose_topic={POSE_TOPIC}', 'pose_tolerance_ms=1', 'budget_ms=0']
    counts = _replay_counts(bag, tmp_path / 'info', [*common, f'camera_info_topic={INFO_TOPIC}'])
    assert counts['camera_infos'] == 1 and counts['bad_camera_infos'] == 0
    assert counts['frames_with_camera'] == 20
    assert INFO_TOPIC in counts['copied']
    assert misclassification(_final_labels(tmp_path / 'info'), truth) < 0.05
    # Without the camera_info parameter the scene needs the intrinsics as parameters.
    with pytest.raises(InputError, match='camera_info_topic, or camera_fx'):
        NodeConfig(pose_topic=POSE_TOPIC)
    assert NodeConfig(pose_topic=POSE_TOPIC, camera_info_topic=INFO_TOPIC).camera_fx == 0.0


def test_a_camera_info_that_is_no_calibration_leaves_the_frames_without_cameras(tmp_path,
                                                                                capsys):
    stamps = [1_000_000_000 + t * 33_333_333 for t in range(12)]
    bag = tmp_path / 'scene'
    write_scene_bag(bag, 12, 7, POSE_TOPIC,
                    extra=[(INFO_TOPIC, s + 500, camera_info(s, np.zeros((3, 3))))
                           for s in stamps])
    common = ['budget_ms=0']
    counts = _replay_counts(bag, tmp_path / 'info', [*common, f'pose_topic={POSE_TOPIC}',
                                                     f'camera_info_topic={INFO_TOPIC}'])
    assert counts['camera_infos'] == 0 and counts['bad_camera_infos'] == 12
    assert counts['poses'] == 12 and counts['frames_with_camera'] == 0
    err = capsys.readouterr().err
    assert 'uncalibrated' in err and f'no valid sensor_msgs/msg/CameraInfo on {INFO_TOPIC}' in err
    # Segmented as without poses.
    _replay_counts(bag, tmp_path / 'plain', common)
    assert np.array_equal(_final_labels(tmp_path / 'info'), _final_labels(tmp_path / 'plain'))


LENS = (-0.3, 0.08)  # k1, k2: a wide lens, up to 20 px at the edge of the image


def test_a_lens_with_distortion_is_undone_before_the_features_are_segmented(tmp_path,
                                                                             monkeypatch):
    from static_scene import FOCAL, radial

    from pearl_ros.online.segmenter import OnlineSegmenter
    from pearl_ros.pipeline.poses import read_lens

    # The lens model inverts the scene's own distortion formula.
    ideal = np.random.default_rng(0).uniform([70, 50], [570, 430], (50, 2))
    lens = read_lens(camera_info(0, INTRINSICS, d=(*LENS, 0, 0, 0)), INTRINSICS)
    assert lens is not None
    assert np.allclose(lens.undistort(radial(ideal, *LENS)), ideal, atol=1e-6)
    assert read_lens(camera_info(0, INTRINSICS), INTRINSICS) is None

    given = []
    process = OnlineSegmenter.process

    def spy(self, stamp_ns, ids, uv, camera=None, arrived=None):
        given.append(np.array(uv))
        return process(self, stamp_ns, ids, uv, camera, arrived)

    monkeypatch.setattr(OnlineSegmenter, 'process', spy)
    tracks, truth, _ = static_scene(frames=20, seed=7)
    inside = np.linalg.norm((tracks - INTRINSICS[:2, 2]) / FOCAL, axis=2).max(axis=0) < 0.8
    stamps = [1_000_000_000 + t * 33_333_333 for t in range(20)]

    def replay_with(d, name):
        given.clear()
        bag = tmp_path / f'{name}_bag'
        write_scene_bag(bag, 20, 7, POSE_TOPIC, lens=LENS,
                        extra=[(INFO_TOPIC, s - 500, camera_info(s, INTRINSICS, d=d))
                               for s in stamps])
        counts = _replay_counts(bag, tmp_path / name, [
            f'pose_topic={POSE_TOPIC}', 'pose_tolerance_ms=1', 'budget_ms=0',
            f'camera_info_topic={INFO_TOPIC}'])
        assert counts['camera_infos'] == 20 and counts['frames_with_camera'] == 20
        return misclassification(_final_labels(tmp_path / name), truth[inside])

    # Told the lens, the segmenter gets the pixels of the ideal pinhole camera (the bag's
    # features stay as they came); told none, the pixels as recorded.
    assert replay_with((*LENS, 0, 0, 0), 'lens') < 0.05
    assert len(given) == 20
    assert all(np.allclose(uv, tracks[t, inside], atol=1e-4) for t, uv in enumerate(given))
    replay_with((0, 0, 0, 0, 0), 'pinhole')
    recorded = radial(tracks[:, inside], *LENS).astype(np.float32)  # as the message holds them
    assert all(np.allclose(uv, recorded[t], atol=1e-3) for t, uv in enumerate(given))
    assert np.abs(recorded - tracks[:, inside]).max() > 20


def test_a_new_lens_empties_the_window():
    from pearl_ros.pipeline.messages import MessagePipeline
    from pearl_ros.pipeline.settings import Settings, build

    settings = build({'pose_topic': POSE_TOPIC, 'camera_info_topic': INFO_TOPIC}, Settings())
    pipeline = MessagePipeline(settings)
    tracks, _, _ = static_scene(frames=4, seed=7)
    ids = np.arange(tracks.shape[1])
    frames = [_cloud(1_000_000_000 + t * 33_333_333, ids, tracks[t]) for t in range(4)]
    assert pipeline.add_camera_info(camera_info(0, INTRINSICS)) is None
    for msg in frames[:2]:
        pipeline.process(msg)
    assert pipeline.frames_in_window == 2
    assert pipeline.add_camera_info(camera_info(0, INTRINSICS)) is None  # the same: kept
    assert pipeline.frames_in_window == 2
    assert pipeline.add_camera_info(camera_info(0, INTRINSICS, d=(*LENS, 0, 0, 0))) is None
    assert pipeline.frames_in_window == 0
    pipeline.process(frames[2])
    skip = pipeline.add_camera_info(camera_info(0, INTRINSICS, d=(0.1, 0.2, 0.3)))
    assert skip is not None and 'plumb_bob' in skip.line and pipeline.frames_in_window == 1


def _cloud(stamp, ids, uv):
    """A VINS-Mono PointCloud (rosbags) of the features ``ids`` at pixels ``uv``."""
    from pearl_ros.bagio.writer import stamped_header, vins_pointcloud

    frame = FeatureFrame(stamp, ids, uv)
    return vins_pointcloud(frame, uv, None, stamped_header(stamp, 'camera'))


def test_camera_info_without_poses_undistorts_the_features_alone(tmp_path, monkeypatch,
                                                                 capsys):
    from static_scene import radial

    from pearl_ros.online.segmenter import OnlineSegmenter

    given = []
    process = OnlineSegmenter.process

    def spy(self, stamp_ns, ids, uv, camera=None, arrived=None):
        given.append((np.array(uv), camera))
        return process(self, stamp_ns, ids, uv, camera, arrived)

    monkeypatch.setattr(OnlineSegmenter, 'process', spy)
    tracks, _, _ = static_scene(frames=12, seed=7)
    inside = np.linalg.norm((tracks - INTRINSICS[:2, 2]) / FOCAL, axis=2).max(axis=0) < 0.8
    stamps = [1_000_000_000 + t * 33_333_333 for t in range(12)]
    bag = tmp_path / 'bag'
    write_scene_bag(bag, 12, 7, POSE_TOPIC, lens=LENS,
                    extra=[(INFO_TOPIC, s - 500, camera_info(s, INTRINSICS, d=(*LENS, 0, 0, 0)))
                           for s in stamps])
    counts = _replay_counts(bag, tmp_path / 'out', ['budget_ms=0',
                                                   f'camera_info_topic={INFO_TOPIC}'])
    assert counts['camera_infos'] == 12 and counts['frames_with_camera'] == 0
    assert counts['poses'] == 0 and INFO_TOPIC in counts['copied']
    assert len(given) == 12 and all(camera is None for _, camera in given)
    assert all(np.allclose(uv, tracks[t, inside], atol=1e-4) for t, (uv, _) in enumerate(given))
    # With a camera_info that is no calibration, the replay says the lens is not used.
    bad = tmp_path / 'bad'
    write_scene_bag(bad, 12, 7, POSE_TOPIC, lens=LENS,
                    extra=[(INFO_TOPIC, s - 500, camera_info(s, np.zeros((3, 3))))
                           for s in stamps])
    given.clear()
    counts = _replay_counts(bad, tmp_path / 'bad_out', [f'camera_info_topic={INFO_TOPIC}'])
    assert counts['bad_camera_infos'] == 12
    assert 'segmented without the lens' in capsys.readouterr().err
    recorded = radial(tracks[:, inside], *LENS).astype(np.float32)
    assert all(np.allclose(uv, recorded[t], atol=1e-3) for t, (uv, _) in enumerate(given))
