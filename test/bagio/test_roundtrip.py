"""Frames -> bag -> frames, for both storages and both message formats."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pearl_ros.bagio import FeatureFrame, read_feature_frames, read_ground_truth, topics
from pearl_ros.bagio.writer import write_feature_bag
from pearl_ros.core.errors import InputError

from bag_oracles import as_float32, raw_messages

TOPIC = '/feature_tracker/feature'
TRUTH = '/ground_truth/labels'
T0 = 1_700_000_000_123_456_789  # ns: a stamp whose nanoseconds survive only integer arithmetic


def normalise(uv: np.ndarray) -> np.ndarray:
    """A stand-in calibration, pixels -> normalised (f = 500 px, c = (320, 240) px)."""
    return (uv - np.array([320.0, 240.0])) / 500.0


def random_frames(seed: int, num_frames: int = 6, max_id: int = 2**24) -> list[FeatureFrame]:
    """Frames whose feature sets change: ids leave, come back, and new ones appear."""
    rng = np.random.default_rng(seed)
    pool = rng.choice(max_id, size=60, replace=False)
    frames = []
    stamp = T0
    for _ in range(num_frames):
        ids = rng.permutation(pool[rng.random(60) < 0.7])
        uv = rng.uniform([0, 0], [640, 480], size=(ids.size, 2))
        frames.append(FeatureFrame(stamp, ids, uv))
        stamp += int(rng.integers(20_000_000, 50_000_000))  # 20-50 ms, uneven
    return frames


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
@pytest.mark.parametrize('msg_format', ['pointcloud', 'pointcloud2'])
def test_frames_read_back_equal(tmp_path: Path, storage: str, msg_format: str) -> None:
    frames = random_frames(seed=1)
    path = tmp_path / 'features'
    write_feature_bag(path, frames, msg_format=msg_format, storage=storage, normalized=normalise)
    expected_type = {'pointcloud': 'PointCloud', 'pointcloud2': 'PointCloud2'}[msg_format]
    assert topics(path) == {TOPIC: f'sensor_msgs/msg/{expected_type}'}
    back = list(read_feature_frames(path))
    assert len(back) == len(frames)
    for sent, got in zip(frames, back, strict=True):
        assert got.stamp_ns == sent.stamp_ns
        np.testing.assert_array_equal(got.ids, sent.ids)
        assert got.ids.dtype == np.int64 and got.uv.dtype == np.float64
        # Pixels travel as float32: exactly the float32 rounding of what was sent.
        np.testing.assert_array_equal(got.uv, as_float32(sent.uv))
        assert np.abs(got.uv - sent.uv).max() <= 640 * np.finfo(np.float32).eps


@pytest.mark.parametrize('msg_format', ['pointcloud', 'pointcloud2'])
def test_normalised_coordinates_are_written_from_the_callable(
    tmp_path: Path, msg_format: str
) -> None:
    frames = random_frames(seed=2)
    path = tmp_path / 'features'
    write_feature_bag(path, frames, msg_format=msg_format, normalized=normalise)
    for frame, msg in zip(frames, raw_messages(path, TOPIC), strict=True):
        if msg_format == 'pointcloud':
            xyz = np.array([(p.x, p.y, p.z) for p in msg.points])
            np.testing.assert_array_equal(xyz[:, 2], 1.0)
            xy = xyz[:, :2]
        else:
            names = [f.name for f in msg.fields]
            assert names == ['id', 'u', 'v', 'x', 'y']
            points = np.frombuffer(msg.data.tobytes(), dtype='<u4,<f4,<f4,<f4,<f4')
            xy = np.column_stack((points['f3'], points['f4'])).astype(np.float64)
        expected = (frame.uv - [320.0, 240.0]) / 500.0
        np.testing.assert_allclose(xy, expected, rtol=0, atol=1e-6)


def test_without_normalised_callable_points_hold_pixels(tmp_path: Path) -> None:
    frames = random_frames(seed=3, num_frames=2)
    path = tmp_path / 'features'
    write_feature_bag(path, frames)
    msg = raw_messages(path, TOPIC)[0]
    xy = np.array([(p.x, p.y) for p in msg.points])
    np.testing.assert_array_equal(xy, as_float32(frames[0].uv))


def test_velocity_channels_are_finite_differences_against_the_previous_frame(
    tmp_path: Path,
) -> None:
    frames = random_frames(seed=4, num_frames=8)
    path = tmp_path / 'features'
    write_feature_bag(path, frames)
    messages = raw_messages(path, TOPIC)
    reappeared = 0
    for index, (frame, msg) in enumerate(zip(frames, messages, strict=True)):
        channels = {c.name: np.asarray(c.values, dtype=np.float64) for c in msg.channels}
        assert list(channels) == [
            'id_of_point',
            'u_of_point',
            'v_of_point',
            'velocity_x_of_point',
            'velocity_y_of_point',
        ]
        # Independent oracle: a dict of the previous frame's positions, one id at a time.
        previous = {}
        seen_before = set()
        if index > 0:
            last = frames[index - 1]
            previous = dict(zip(last.ids.tolist(), last.uv.tolist(), strict=True))
            seen_before = {i for f in frames[: index - 1] for i in f.ids.tolist()}
            dt = (frame.stamp_ns - last.stamp_ns) / 1e9
        for k, feature in enumerate(frame.ids.tolist()):
            if feature in previous:
                expected = [(frame.uv[k, c] - previous[feature][c]) / dt for c in (0, 1)]
            else:
                expected = [0.0, 0.0]
                reappeared += feature in seen_before
            got = [channels['velocity_x_of_point'][k], channels['velocity_y_of_point'][k]]
            np.testing.assert_allclose(got, expected, rtol=1e-6, atol=1e-3)
    # The scene must exercise ids that skip a frame and come back (velocity 0, not a long jump).
    assert reappeared > 0


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_ground_truth_round_trip(tmp_path: Path, storage: str) -> None:
    frames = random_frames(seed=5)
    labels_of = {int(i): int(i) % 3 - 1 for f in frames for i in f.ids}  # labels -1, 0, 1
    truth = [(f.stamp_ns, f.ids, np.array([labels_of[int(i)] for i in f.ids])) for f in frames]
    path = tmp_path / 'features'
    write_feature_bag(path, frames, truth, storage=storage)
    assert topics(path) == {
        TOPIC: 'sensor_msgs/msg/PointCloud',
        TRUTH: 'sensor_msgs/msg/PointCloud2',
    }
    assert read_ground_truth(path) == labels_of
    # One truth message per frame, at the frame's stamp.
    stamps = [
        m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in raw_messages(path, TRUTH)
    ]
    assert stamps == [f.stamp_ns for f in frames]


def test_custom_topics_round_trip(tmp_path: Path) -> None:
    frames = random_frames(seed=6, num_frames=3)
    truth = [(f.stamp_ns, f.ids, np.zeros(f.ids.size, int)) for f in frames]
    path = tmp_path / 'features'
    write_feature_bag(
        path,
        frames,
        truth,
        topic='/cam0/features',
        truth_topic='/cam0/truth',
        msg_format='pointcloud2',
        frame_id='cam0',
    )
    assert len(list(read_feature_frames(path, topic='/cam0/features'))) == 3
    assert set(read_ground_truth(path, topic='/cam0/truth').values()) == {0}
    assert raw_messages(path, '/cam0/features')[0].header.frame_id == 'cam0'


def test_empty_frames_round_trip(tmp_path: Path) -> None:
    frames = [
        FeatureFrame(T0, np.empty(0, int), np.empty((0, 2))),
        FeatureFrame(T0 + 1, [3, 1], [[1.0, 2.0], [3.0, 4.0]]),
    ]
    for msg_format in ('pointcloud', 'pointcloud2'):
        path = tmp_path / msg_format
        write_feature_bag(path, frames, msg_format=msg_format)
        back = list(read_feature_frames(path))
        assert [f.ids.tolist() for f in back] == [[], [3, 1]]


def test_ids_beyond_float32_precision_need_pointcloud2(tmp_path: Path) -> None:
    frames = [FeatureFrame(T0, [2**24 + 1, 5], [[1.0, 2.0], [3.0, 4.0]])]
    with pytest.raises(InputError, match='2\\*\\*24'):
        write_feature_bag(tmp_path / 'cloud', frames, msg_format='pointcloud')
    write_feature_bag(tmp_path / 'cloud2', frames, msg_format='pointcloud2')
    (back,) = read_feature_frames(tmp_path / 'cloud2')
    np.testing.assert_array_equal(back.ids, [2**24 + 1, 5])


def test_feature_frame_checks_shapes_and_coerces_types() -> None:
    frame = FeatureFrame(np.int64(5), [1.0, 2.0], [[1, 2], [3, 4]])
    assert type(frame.stamp_ns) is int and frame.ids.dtype == np.int64
    assert frame.uv.dtype == np.float64
    with pytest.raises(InputError, match='uv must have shape'):
        FeatureFrame(0, [1, 2], [[1.0, 2.0]])
    with pytest.raises(InputError, match='integers'):
        FeatureFrame(0, [1.5], [[1.0, 2.0]])
    with pytest.raises(InputError, match='repeats'):
        FeatureFrame(0, [1, 1], [[1.0, 2.0], [3.0, 4.0]])


def test_extra_messages_are_written_as_they_are_on_their_topics(tmp_path: Path) -> None:
    from static_scene import camera_info

    frames = random_frames(seed=7, num_frames=3)
    k = np.array([[400.0, 0.0, 320.0], [0.0, 410.0, 240.0], [0.0, 0.0, 1.0]])
    # Given out of order: written in log-time order, beside the features.
    extra = [('/cam/info', f.stamp_ns + 5, camera_info(f.stamp_ns, k * [[i + 1], [1], [1]]))
             for i, f in enumerate(frames)][::-1]
    path = tmp_path / 'features'
    write_feature_bag(path, frames, extra=extra)
    assert topics(path)['/cam/info'] == 'sensor_msgs/msg/CameraInfo'
    back = raw_messages(path, '/cam/info')
    assert [m.k[0] for m in back] == [400.0, 800.0, 1200.0]
    assert [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in back] == [
        f.stamp_ns for f in frames]
    with pytest.raises(InputError, match='extra topics must differ'):
        write_feature_bag(tmp_path / 'clash', frames, extra=[(TOPIC, T0, extra[0][2])])
