"""Bundled bags: they read back, agree with their sources and regenerate from the README."""

from __future__ import annotations

import dataclasses
import shlex
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import scipy.io
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from pearl_ros.bagio import (
    read_feature_frames,
    read_ground_truth,
    read_ground_truth_frames,
    topics,
)
from pearl_ros.cli.make_bag import EPOCH_NS
from pearl_ros.cli.make_bag import main as make_bag_main
from pearl_ros.core.errors import BagError
from pearl_ros.datasets.synthetic import BodySpec, synthetic_stream

REPO = Path(__file__).resolve().parents[2]
FEATURES = '/feature_tracker/feature'
TRUTH = '/ground_truth/labels'

# Hopkins bags: bag -> (sequence, number of motions, feature type, frames kept or None for all).
HOPKINS_BAGS = {
    '1R2RCR_g12': ('1R2RCR_g12', 2, 'sensor_msgs/msg/PointCloud', None),
    '1R2RCR': ('1R2RCR', 3, 'sensor_msgs/msg/PointCloud', None),
    'cars2': ('cars2', 2, 'sensor_msgs/msg/PointCloud', None),
    '1R2RCR_g12_pc2': ('1R2RCR_g12', 2, 'sensor_msgs/msg/PointCloud2', None),
    '1R2RCR_g12_pair': ('1R2RCR_g12', 2, 'sensor_msgs/msg/PointCloud', [0, 23]),
    '1R2RCR_g12_ros1.bag': ('1R2RCR_g12', 2, 'sensor_msgs/msg/PointCloud', None),
}
SYNTHETIC = 'synthetic_births_deaths'
ALL_BAGS = sorted([*HOPKINS_BAGS, SYNTHETIC])


def test_bags_folder_holds_exactly_the_documented_bags() -> None:
    bags = sorted(p.name for p in (REPO / 'bags').iterdir() if p.name != 'README.md')
    assert bags == ALL_BAGS
    readme = (REPO / 'bags' / 'README.md').read_text()
    for name in ALL_BAGS:
        assert f'`bags/{name}`' in readme


@pytest.mark.parametrize('name', sorted(HOPKINS_BAGS))
def test_hopkins_bag_matches_its_mat_file(name: str, hopkins_root: Path) -> None:
    sequence, motions, msgtype, kept = HOPKINS_BAGS[name]
    bag = REPO / 'bags' / name
    mat = scipy.io.loadmat(str(hopkins_root / sequence / f'{sequence}_truth.mat'))
    y, s = mat['y'], mat['s'].ravel()
    num_points, num_frames = int(mat['points'].item()), int(mat['frames'].item())
    assert y.shape == (3, num_points, num_frames)
    assert len(np.unique(s)) == motions
    kept = kept if kept is not None else list(range(num_frames))

    assert topics(bag) == {FEATURES: msgtype, TRUTH: 'sensor_msgs/msg/PointCloud2'}
    frames = list(read_feature_frames(bag))
    assert [frame.stamp_ns for frame in frames] == [
        EPOCH_NS + round(f * 1e9 / 30) for f in kept
    ]
    for f, frame in zip(kept, frames, strict=True):
        assert frame.ids.tolist() == list(range(num_points))
        pixels = (y[:2, :, f] / y[2, :, f]).T
        np.testing.assert_array_equal(frame.uv, pixels.astype(np.float32).astype(np.float64))

    labels = read_ground_truth(bag)
    assert sorted(labels) == list(range(num_points))
    assert len(set(labels.values())) == motions
    # Same partition as s: the label of a point is a function of its group, and vice versa.
    pairs = {(labels[p], int(s[p])) for p in range(num_points)}
    assert len(pairs) == motions
    # One truth message per frame, stamped as its frame.
    per_frame = read_ground_truth_frames(bag)
    assert [stamp for stamp, _, _ in per_frame] == [frame.stamp_ns for frame in frames]


def test_synthetic_bag_holds_the_stream_it_was_made_from() -> None:
    bag = REPO / 'bags' / SYNTHETIC
    stream = list(synthetic_stream(300, 90, (BodySpec(0.2, start=30), BodySpec(0.15, stop=60)),
                                   0.02, 0.5, 0, start_ns=EPOCH_NS))
    frames = list(read_feature_frames(bag))
    truth = read_ground_truth_frames(bag)
    assert len(frames) == len(truth) == 90
    for expected, frame, (stamp, ids, labels) in zip(stream, frames, truth, strict=True):
        assert frame.stamp_ns == stamp == expected.stamp_ns
        np.testing.assert_array_equal(frame.ids, expected.ids)
        np.testing.assert_array_equal(ids, expected.ids)
        np.testing.assert_array_equal(labels, expected.truth)
        np.testing.assert_array_equal(frame.uv, expected.uv.astype(np.float32).astype(float))
    # What the bag is for: births, deaths, reused ids, an object starting and one stopping.
    assert len({i for f in frames for i in f.ids.tolist()}) > 300
    motions = [set(labels.tolist()) for _, _, labels in truth]
    assert motions[0] == {0, 2} and motions[45] == {0, 1, 2} and motions[-1] == {0, 1}


def test_truth_that_changes_over_time_cannot_be_merged_but_reads_per_frame() -> None:
    bag = REPO / 'bags' / SYNTHETIC
    with pytest.raises(BagError, match='has labels'):
        read_ground_truth(bag)
    per_frame = read_ground_truth_frames(bag)
    # Object 1 starts moving at frame 30: a feature it carries from the start changes label.
    before = dict(zip(per_frame[29][1].tolist(), per_frame[29][2].tolist(), strict=True))
    after = dict(zip(per_frame[30][1].tolist(), per_frame[30][2].tolist(), strict=True))
    changed = [i for i in before if i in after and before[i] != after[i]]
    assert changed and all(before[i] == 0 and after[i] == 1 for i in changed)


@pytest.mark.parametrize('name', ALL_BAGS)
def test_bundled_bags_stay_small(name: str) -> None:
    path = REPO / 'bags' / name
    files = [path] if path.is_file() else list(path.iterdir())
    assert sum(p.stat().st_size for p in files) < 2_000_000


def readme_commands() -> dict[str, list[str]]:
    """Bag name -> the pearl_make_bag arguments bags/README.md gives to regenerate it."""
    commands = {}
    for line in (REPO / 'bags' / 'README.md').read_text().splitlines():
        if line.startswith('.venv/bin/pearl_make_bag '):
            args = shlex.split(line)[1:]
            out = [a for a in args if a.startswith('bags/')]
            assert len(out) == 1, line
            commands[out[0].removeprefix('bags/')] = args
    return commands


# pearl_make_bag's normalised coordinates are its pixels through an affine map fitted by least
# squares to the .mat file's x field (make_bag.normaliser). The last bits of that fit depend on
# the LAPACK build: on another machine the coordinates (|x| < 2, a float64 step <= 4.4e-16) come
# out a few float64 steps away. The float32 message keeps such a difference where a coordinate
# is near 0, and elsewhere it can move the float32 rounding by one step. So a rebuilt coordinate
# agrees with the bundled one when it is within NORMALISED_ATOL (10^-12 of a focal length: under
# a nanopixel at f = 1000 px, and 1000 times the rounding above) or is the adjacent float32.
# A real change is far larger: a normalisation by K instead of x moves three-cars by 0.05, and
# float32 itself rounds x ~ 1 to 6e-8. Everything else in the messages must be equal.
NORMALISED_ATOL = 1e-12


def coordinates_agree(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Elementwise: float32 coordinates within NORMALISED_ATOL, or adjacent float32 values."""
    a32, b32 = np.asarray(a, dtype=np.float32), np.asarray(b, dtype=np.float32)
    close = np.abs(a32.astype(np.float64) - b32.astype(np.float64)) <= NORMALISED_ATOL
    result: np.ndarray = close | (np.nextafter(a32, b32) == b32)
    return result


def test_coordinate_tolerance_accepts_rounding_and_nothing_more() -> None:
    a = np.array([0.25, -1.5, 0.7, 3e-17], dtype=np.float32)
    up = np.nextafter(a, np.float32(np.inf))
    assert coordinates_agree(a, a).all() and coordinates_agree(a, up).all()
    assert coordinates_agree(a[3:], np.float32(2.5e-16)).all()  # float64 rounding near 0
    two_steps = np.nextafter(up, np.float32(np.inf))
    assert not coordinates_agree(a[:3], two_steps[:3]).any()  # two float32 roundings apart
    assert not coordinates_agree(a[3:], np.float32(2e-12)).any()


def plain(value: Any) -> Any:
    """A decoded message as nested tuples of plain values, comparable with ``==``."""
    if dataclasses.is_dataclass(value):
        fields = dataclasses.fields(value)
        return (type(value).__name__, *((f.name, plain(getattr(value, f.name))) for f in fields))
    if isinstance(value, np.ndarray):
        return (value.dtype.str, value.shape, value.tobytes())
    if isinstance(value, list | tuple):
        return tuple(plain(item) for item in value)
    return value


def split_normalised(msg: Any) -> tuple[Any, np.ndarray]:
    """A feature message without its normalised x, y (zeroed), and those (N, 2) float32."""
    if hasattr(msg, 'points'):  # sensor_msgs/PointCloud: x, y of each Point32
        xy = np.array([(point.x, point.y) for point in msg.points], dtype=np.float32)
        points = [dataclasses.replace(point, x=0.0, y=0.0) for point in msg.points]
        return dataclasses.replace(msg, points=points), xy.reshape(-1, 2)
    names = [field.name for field in msg.fields]
    if 'x' not in names:  # a ground-truth PointCloud2: ids and labels only
        return msg, np.zeros((0, 2), dtype=np.float32)
    # sensor_msgs/PointCloud2: the float32 fields x and y of each point (little-endian).
    assert not msg.is_bigendian
    layout = np.dtype({'names': ['x', 'y'],
                       'formats': ['<f4', '<f4'],
                       'offsets': [msg.fields[names.index('x')].offset,
                                   msg.fields[names.index('y')].offset],
                       'itemsize': msg.point_step})
    assert all(msg.fields[names.index(n)].datatype == 7 for n in 'xy')  # PointField.FLOAT32
    data = np.array(msg.data, dtype=np.uint8)  # a copy; the view below writes into it
    points = data.view(layout)
    xy = np.column_stack((points['x'], points['y']))
    points['x'] = points['y'] = 0.0
    return dataclasses.replace(msg, data=data), xy


def decoded_messages(path: Path) -> tuple[list[Any], list[np.ndarray]]:
    """Every message of a bag as (topic, log time, type, plain fields without the normalised
    coordinates), in order; and the normalised coordinates of each."""
    rest, coordinates = [], []
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_KILTED)) as reader:
        for connection, stamp, raw in reader.messages():
            msg, xy = split_normalised(reader.deserialize(raw, connection.msgtype))
            rest.append((connection.topic, stamp, connection.msgtype, plain(msg)))
            coordinates.append(xy)
    return rest, coordinates


def test_readme_regenerates_every_bag() -> None:
    assert sorted(readme_commands()) == ALL_BAGS


# The Hopkins bags need the dataset; the synthetic one is made from its seed alone.
@pytest.mark.parametrize('name', [
    pytest.param(name, marks=pytest.mark.data) if name in HOPKINS_BAGS else name
    for name in ALL_BAGS
])
def test_readme_command_rebuilds_the_bag_message_for_message(
    name: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str], request: pytest.FixtureRequest,
) -> None:
    args = readme_commands()[name]
    if name in HOPKINS_BAGS:
        # The README's .mat paths are those of the default data folder beside the repository.
        prefix = '../shared/data/hopkins155/'
        (source,) = [a for a in args if a.endswith('_truth.mat')]
        assert source.startswith(prefix), source
        hopkins_root = request.getfixturevalue('hopkins_root')
        args = [str(hopkins_root / a.removeprefix(prefix)) if a == source else a for a in args]
    (tmp_path / 'bags').mkdir()
    monkeypatch.chdir(tmp_path)
    assert make_bag_main(args) == 0, capsys.readouterr().err
    rebuilt, rebuilt_xy = decoded_messages(tmp_path / 'bags' / name)
    bundled, bundled_xy = decoded_messages(REPO / 'bags' / name)
    # Topics, log times, types, headers, ids, pixels, velocities, labels: equal.
    assert rebuilt == bundled
    assert any(xy.size for xy in bundled_xy)
    for index, (ours, theirs) in enumerate(zip(rebuilt_xy, bundled_xy, strict=True)):
        assert ours.shape == theirs.shape, index
        bad = ~coordinates_agree(ours, theirs)
        assert not bad.any(), (index, ours[bad], theirs[bad])
