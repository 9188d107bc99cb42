"""pearl_make_bag's other sources and containers: frame subsets, synthetic streams, ROS 1 files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.io

from pearl_ros.bagio import read_feature_frames, read_ground_truth_frames, topics
from pearl_ros.cli.make_bag import EPOCH_NS, main
from pearl_ros.datasets.synthetic import BodySpec, synthetic_stream

from bag_oracles import as_float32, raw_messages

FRAMES = 12  # of the Hopkins-format file the .mat tests use


@pytest.fixture
def mat_file(hopkins_like) -> Path:
    """A Hopkins-format file of two motions over FRAMES frames (a synthetic scene)."""
    return hopkins_like('scene', sizes=(40, 30), frames=FRAMES)


def one_error_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith('error: ')]
    assert len(lines) == 1 and 'Traceback' not in err, err
    return lines[0]


def test_frames_keeps_the_chosen_frames_with_their_stamps(mat_file: Path, tmp_path: Path) -> None:
    y = scipy.io.loadmat(str(mat_file))['y']
    out = tmp_path / 'pair'
    assert main([str(mat_file), str(out), '--frames', '1,-2', '--rate', '10']) == 0
    frames = list(read_feature_frames(out))
    last = FRAMES - 2
    assert [f.stamp_ns for f in frames] == [EPOCH_NS + 100_000_000, EPOCH_NS + last * 100_000_000]
    for f, frame in zip((1, last), frames, strict=True):
        np.testing.assert_array_equal(frame.uv, as_float32((y[:2, :, f] / y[2, :, f]).T))
    assert len(read_ground_truth_frames(out)) == 2


@pytest.mark.parametrize('frames', ['0,0', '3,1', f'0,{FRAMES}', 'a,b', f'-{FRAMES + 1}'])
def test_bad_frame_lists_are_one_line_errors(
    mat_file: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], frames: str
) -> None:
    out = tmp_path / 'out'
    assert main([str(mat_file), str(out), f'--frames={frames}']) == 1
    assert 'frame' in one_error_line(capsys)
    assert not out.exists() and not list(tmp_path.glob('.out.*'))  # no staging left
    # The last frame and the first, from the end, are in range: the bounds are where they are.
    assert main([str(mat_file), str(out), f'--frames=0,{FRAMES - 1}']) == 0
    assert main([str(mat_file), str(tmp_path / 'end'), f'--frames=-{FRAMES}']) == 0


def test_synthetic_source_writes_the_stream_with_per_frame_truth(tmp_path: Path) -> None:
    out = tmp_path / 'synthetic'
    args = ['synthetic', str(out), '--num-features', '40', '--num-frames', '6',
            '--object', '0.25:2', '--seed', '3', '--format', 'pointcloud2']
    assert main(args) == 0
    stream = list(synthetic_stream(40, 6, (BodySpec(0.25, start=2),), 0.02, 0.5, 3,
                                   start_ns=EPOCH_NS))
    assert topics(out)['/feature_tracker/feature'] == 'sensor_msgs/msg/PointCloud2'
    frames = list(read_feature_frames(out))
    truth = read_ground_truth_frames(out)
    for expected, frame, (stamp, ids, labels) in zip(stream, frames, truth, strict=True):
        assert frame.stamp_ns == stamp == expected.stamp_ns
        np.testing.assert_array_equal(frame.ids, expected.ids)
        np.testing.assert_array_equal(ids, expected.ids)
        np.testing.assert_array_equal(labels, expected.truth)
    # x, y: the nominal camera, f = 500 px, principal point (320, 240).
    msg = raw_messages(out, '/feature_tracker/feature')[0]
    points = np.frombuffer(msg.data.tobytes(), dtype='<u4,<f4,<f4,<f4,<f4')
    np.testing.assert_allclose(points['f3'], (points['f1'] - 320) / 500, atol=1e-6)
    np.testing.assert_allclose(points['f4'], (points['f2'] - 240) / 500, atol=1e-6)


@pytest.mark.parametrize('args', [
    ['--object', '1.5'],
    ['--object', '0.2:5:3'],
    ['--object', 'x'],
    ['--object', '0.6', '--object', '0.5'],
    ['--num-frames', '0'],
    ['--noise', '-1'],
    ['--death-rate', '1'],
])
def test_bad_synthetic_options_are_one_line_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str]
) -> None:
    assert main(['synthetic', str(tmp_path / 'out'), *args]) == 1
    one_error_line(capsys)
    assert not any(tmp_path.iterdir())


def test_a_dot_bag_output_is_a_ros1_bag_file_with_the_same_messages(
    mat_file: Path, tmp_path: Path
) -> None:
    folder = tmp_path / 'out'  # apart from the .mat file's folder
    folder.mkdir()
    assert main([str(mat_file), str(folder / 'ros2')]) == 0
    assert main([str(mat_file), str(folder / 'ros1.bag')]) == 0
    ros1 = folder / 'ros1.bag'
    assert ros1.is_file() and ros1.read_bytes().startswith(b'#ROSBAG V2.0\n')
    assert topics(ros1) == topics(folder / 'ros2')
    for a, b in zip(read_feature_frames(ros1), read_feature_frames(folder / 'ros2'),
                    strict=True):
        assert a.stamp_ns == b.stamp_ns
        np.testing.assert_array_equal(a.ids, b.ids)
        np.testing.assert_array_equal(a.uv, b.uv)
    header = raw_messages(ros1, '/feature_tracker/feature')[0].header
    assert header.seq == 0 and header.frame_id == 'camera'  # a ROS 1 Header
    assert sorted(p.name for p in folder.iterdir()) == ['ros1.bag', 'ros2']  # no staging


def test_a_ros1_bag_file_is_replaced_only_with_force(
    mat_file: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / 'x.bag'
    assert main([str(mat_file), str(out), '--frames', '0,1']) == 0
    before = out.read_bytes()
    assert main([str(mat_file), str(out)]) == 1
    assert '--force' in one_error_line(capsys)
    assert out.read_bytes() == before
    assert main([str(mat_file), str(out), '--force']) == 0
    assert len(list(read_feature_frames(out))) == FRAMES
