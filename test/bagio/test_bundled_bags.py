"""Bundled bags: they read back, agree with their sources and regenerate from the README."""

from __future__ import annotations

import shlex
from pathlib import Path

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
HOPKINS = REPO.parent / 'shared' / 'data' / 'hopkins155'
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


@pytest.mark.data
@pytest.mark.parametrize('name', sorted(HOPKINS_BAGS))
def test_hopkins_bag_matches_its_mat_file(name: str) -> None:
    sequence, motions, msgtype, kept = HOPKINS_BAGS[name]
    bag = REPO / 'bags' / name
    mat = scipy.io.loadmat(str(HOPKINS / sequence / f'{sequence}_truth.mat'))
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
    before = dict(zip(per_frame[29][1].tolist(), per_frame[29][2].tolist()))
    after = dict(zip(per_frame[30][1].tolist(), per_frame[30][2].tolist()))
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


def raw_messages(path: Path) -> list[tuple[str, int, bytes]]:
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_KILTED)) as reader:
        return [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]


def test_readme_regenerates_every_bag() -> None:
    assert sorted(readme_commands()) == ALL_BAGS


@pytest.mark.data
@pytest.mark.parametrize('name', ALL_BAGS)
def test_readme_command_rebuilds_the_bag_message_for_message(
    name: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    args = readme_commands()[name]
    (tmp_path / 'bags').mkdir()
    monkeypatch.chdir(tmp_path)
    # The README's paths are relative to the repository root.
    args = [str(REPO / a) if a.startswith('../') else a for a in args]
    assert make_bag_main(args) == 0, capsys.readouterr().err
    assert raw_messages(tmp_path / 'bags' / name) == raw_messages(REPO / 'bags' / name)
