"""Missing, corrupt and mismatched bags fail with one-line BagErrors; writes never half-succeed."""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from pearl_ros.bagio import FeatureFrame, read_feature_frames, read_ground_truth, topics
from pearl_ros.bagio.writer import write_feature_bag
from pearl_ros.core.errors import BagError, InputError

TS = get_typestore(Stores.ROS2_KILTED)
T0 = 1_700_000_000_000_000_000


def frames(count: int = 5, points: int = 40) -> list[FeatureFrame]:
    rng = np.random.default_rng(7)
    return [
        FeatureFrame(T0 + k * 33_000_000, np.arange(points), rng.uniform(0, 640, (points, 2)))
        for k in range(count)
    ]


def truth(count: int = 5, points: int = 40) -> list[tuple[int, np.ndarray, np.ndarray]]:
    return [(f.stamp_ns, f.ids, f.ids % 2) for f in frames(count, points)]


@pytest.fixture
def bag(tmp_path: Path) -> Path:
    path = tmp_path / 'good'
    write_feature_bag(path, frames(), truth())
    return path


def read_all(path: Path, **kwargs: object) -> list[FeatureFrame]:
    return list(read_feature_frames(path, **kwargs))


def assert_one_line(err: pytest.ExceptionInfo[BaseException]) -> None:
    assert '\n' not in str(err.value)


def test_missing_bag_raises_bag_error(tmp_path: Path) -> None:
    for call in (read_all, read_ground_truth, topics):
        with pytest.raises(BagError, match='bag not found') as err:
            call(tmp_path / 'nowhere')
        assert_one_line(err)


def test_folder_with_garbage_metadata_raises_bag_error(tmp_path: Path) -> None:
    path = tmp_path / 'garbage'
    path.mkdir()
    (path / 'metadata.yaml').write_text('{{ this: is [ not yaml\n  - at all\n')
    with pytest.raises(BagError, match='cannot open bag') as err:
        read_all(path)
    assert_one_line(err)
    (path / 'metadata.yaml').write_text('just: a mapping\n')
    with pytest.raises(BagError, match='cannot open bag'):
        topics(path)


def test_folder_without_metadata_is_not_a_bag(tmp_path: Path) -> None:
    with pytest.raises(BagError, match=r'no metadata\.yaml'):
        topics(tmp_path)


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
@pytest.mark.parametrize('keep', [0.0, 0.3, 0.95])
def test_truncated_storage_file_raises_bag_error(
    tmp_path: Path, storage: str, keep: float
) -> None:
    path = tmp_path / 'cut'
    write_feature_bag(path, frames(count=30, points=200), storage=storage)
    (data,) = [p for p in path.iterdir() if p.name != 'metadata.yaml']
    content = data.read_bytes()
    data.write_bytes(content[: int(len(content) * keep)])
    # Some damage is seen on opening, some only when the damaged messages are reached.
    with pytest.raises(BagError) as err:
        read_all(path)
    assert_one_line(err)


def test_garbage_file_with_storage_suffix_raises_bag_error(tmp_path: Path) -> None:
    path = tmp_path / 'junk.mcap'
    path.write_bytes(b'not an mcap file' * 8)
    with pytest.raises(BagError, match='cannot open bag'):
        read_all(path)


def test_unknown_topic_lists_the_topics_that_exist(bag: Path) -> None:
    with pytest.raises(BagError, match="no topic '/camera/features'") as err:
        read_all(bag, topic='/camera/features')
    message = str(err.value)
    assert '/feature_tracker/feature (sensor_msgs/msg/PointCloud)' in message
    assert '/ground_truth/labels (sensor_msgs/msg/PointCloud2)' in message
    with pytest.raises(BagError, match='/feature_tracker/feature'):
        read_ground_truth(bag, topic='/truth')


def test_wrong_message_type_raises_bag_error(bag: Path, tmp_path: Path) -> None:
    with pytest.raises(BagError, match='has type sensor_msgs/msg/PointCloud, expected'):
        read_ground_truth(bag, topic='/feature_tracker/feature')
    path = tmp_path / 'strings'
    string = TS.types['std_msgs/msg/String']
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection(
            '/feature_tracker/feature', 'std_msgs/msg/String', typestore=TS
        )
        writer.write(
            connection, T0, bytes(TS.serialize_cdr(string(data='hi'), 'std_msgs/msg/String'))
        )
    with pytest.raises(BagError, match='std_msgs/msg/String'):
        read_all(path)


def test_malformed_message_in_a_bag_names_the_message(tmp_path: Path) -> None:
    path = tmp_path / 'malformed'
    cloud = TS.types['sensor_msgs/msg/PointCloud']
    header = TS.types['std_msgs/msg/Header']
    time = TS.types['builtin_interfaces/msg/Time']
    channel = TS.types['sensor_msgs/msg/ChannelFloat32']
    point = TS.types['geometry_msgs/msg/Point32']
    good = [
        channel(name=n, values=np.array([1.0, 2.0], np.float32))
        for n in ('id_of_point', 'u_of_point', 'v_of_point')
    ]
    bad = [*good[:2], channel(name='v_of_point', values=np.array([1.0], np.float32))]
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection(
            '/feature_tracker/feature', cloud.__msgtype__, typestore=TS
        )
        for k, channels in enumerate((good, bad)):
            msg = cloud(
                header=header(stamp=time(sec=k, nanosec=0), frame_id=''),
                points=[point(x=0.0, y=0.0, z=1.0)] * 2,
                channels=channels,
            )
            writer.write(connection, k, bytes(TS.serialize_cdr(msg, cloud.__msgtype__)))
    iterator = read_feature_frames(path)
    assert next(iterator).ids.tolist() == [1, 2]
    with pytest.raises(BagError, match='message 1 on /feature_tracker/feature') as err:
        next(iterator)
    assert isinstance(err.value.__cause__, InputError)


def test_conflicting_ground_truth_labels_raise(tmp_path: Path) -> None:
    path = tmp_path / 'conflict'
    items = truth(count=2, points=3)
    items[1] = (items[1][0], items[1][1], np.array([0, 1, 1]))  # id 2 was labelled 0
    write_feature_bag(path, frames(count=2, points=3), items)
    with pytest.raises(BagError, match='feature 2 has labels 0 and 1'):
        read_ground_truth(path)


def test_ros2_bag_folder_named_dot_bag_is_refused_with_a_reason(bag: Path) -> None:
    renamed = bag.with_name('good.bag')
    shutil.copytree(bag, renamed)
    with pytest.raises(BagError, match='ROS 1'):
        topics(renamed)
    with pytest.raises(InputError, match=r'\.bag'):
        write_feature_bag(bag.with_name('new.bag'), frames())
    assert not bag.with_name('new.bag').exists()


def test_writer_refuses_to_overwrite(bag: Path) -> None:
    before = {p.name: p.read_bytes() for p in bag.iterdir()}
    with pytest.raises(BagError, match='exists already'):
        write_feature_bag(bag, frames(count=1))
    assert {p.name: p.read_bytes() for p in bag.iterdir()} == before
    shutil.rmtree(bag)
    write_feature_bag(bag, frames(count=1))  # once the caller deleted it
    assert len(read_all(bag)) == 1


def test_writer_needs_an_existing_parent_folder(tmp_path: Path) -> None:
    with pytest.raises(BagError, match='output folder does not exist'):
        write_feature_bag(tmp_path / 'a' / 'b', frames())


def failing_frames() -> Iterator[FeatureFrame]:
    yield from frames(count=3)
    raise RuntimeError('tracker crashed')


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_failure_while_writing_leaves_nothing_behind(tmp_path: Path, storage: str) -> None:
    with pytest.raises(RuntimeError, match='tracker crashed'):
        write_feature_bag(tmp_path / 'out', failing_frames(), storage=storage)
    assert list(tmp_path.iterdir()) == []
    # A bad frame in the middle (stamps going back) is an InputError, with the same guarantee.
    bad = frames(count=4)
    bad[2] = FeatureFrame(bad[0].stamp_ns, bad[2].ids, bad[2].uv)
    with pytest.raises(InputError, match=r'frame 2: stamp_ns .* does not increase'):
        write_feature_bag(tmp_path / 'out', bad, truth(count=4), storage=storage)
    assert list(tmp_path.iterdir()) == []


def test_bad_writer_arguments_raise_input_error(tmp_path: Path) -> None:
    with pytest.raises(InputError, match='msg_format'):
        write_feature_bag(tmp_path / 'x', frames(), msg_format='image')
    with pytest.raises(InputError, match='storage'):
        write_feature_bag(tmp_path / 'x', frames(), storage='rosbag1')
    with pytest.raises(InputError, match='normalized'):
        write_feature_bag(tmp_path / 'x', frames(), normalized=lambda uv: uv[:, :1])
    with pytest.raises(InputError, match='truth_topic'):
        write_feature_bag(
            tmp_path / 'x', frames(), truth(), truth_topic='/feature_tracker/feature'
        )
    assert list(tmp_path.iterdir()) == []


def test_bad_reader_arguments_raise_input_error(bag: Path) -> None:
    with pytest.raises(InputError, match='layout'):
        read_feature_frames(bag, layout='orb')
    with pytest.raises(InputError, match='camera_id'):
        read_feature_frames(bag, camera_id=-2)
