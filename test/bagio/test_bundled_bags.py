"""The bags shipped in bags/ read back and agree with the Hopkins155 files they were made from."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.io

from pearl_ros.bagio import read_feature_frames, read_ground_truth, topics

REPO = Path(__file__).resolve().parents[2]
HOPKINS = REPO.parent / 'shared' / 'data' / 'hopkins155'
BAGS = {'1R2RCR_g12': 2, '1R2RCR': 3, 'cars2': 2}  # bag -> number of motions


def test_bags_folder_holds_exactly_the_documented_bags() -> None:
    bags = sorted(p.name for p in (REPO / 'bags').iterdir() if p.is_dir())
    assert bags == sorted(BAGS)
    readme = (REPO / 'bags' / 'README.md').read_text()
    for name in BAGS:
        assert f'bags/{name}' in readme


@pytest.mark.parametrize('name', sorted(BAGS))
def test_bundled_bag_matches_its_mat_file(name: str) -> None:
    bag = REPO / 'bags' / name
    mat = scipy.io.loadmat(str(HOPKINS / name / f'{name}_truth.mat'))
    y, s = mat['y'], mat['s'].ravel()
    num_points, num_frames = int(mat['points'].item()), int(mat['frames'].item())
    assert y.shape == (3, num_points, num_frames)
    assert len(np.unique(s)) == BAGS[name]

    assert topics(bag) == {
        '/feature_tracker/feature': 'sensor_msgs/msg/PointCloud',
        '/ground_truth/labels': 'sensor_msgs/msg/PointCloud2',
    }
    frames = list(read_feature_frames(bag))
    assert len(frames) == num_frames
    stamps = [frame.stamp_ns for frame in frames]
    assert stamps == sorted(set(stamps))
    for f, frame in enumerate(frames):
        assert frame.ids.tolist() == list(range(num_points))
        pixels = (y[:2, :, f] / y[2, :, f]).T
        np.testing.assert_array_equal(frame.uv, pixels.astype(np.float32).astype(np.float64))

    labels = read_ground_truth(bag)
    assert sorted(labels) == list(range(num_points))
    assert len(set(labels.values())) == BAGS[name]
    # Same partition as s: the label of a point is a function of its group, and vice versa.
    pairs = {(labels[p], int(s[p])) for p in range(num_points)}
    assert len(pairs) == BAGS[name]


@pytest.mark.parametrize('name', sorted(BAGS))
def test_bundled_bags_stay_small(name: str) -> None:
    size = sum(p.stat().st_size for p in (REPO / 'bags' / name).iterdir())
    assert size < 2_000_000
