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

HOPKINS = Path(__file__).resolve().parents[2].parent / 'shared' / 'data' / 'hopkins155'
G12 = HOPKINS / '1R2RCR_g12' / '1R2RCR_g12_truth.mat'


def one_error_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith('error: ')]
    assert len(lines) == 1 and 'Traceback' not in err, err
    return lines[0]


@pytest.mark.data
def test_frames_keeps_the_chosen_frames_with_their_stamps(tmp_path: Path) -> None:
    y = scipy.io.loadmat(str(G12))['y']
    out = tmp_path / 'pair'
    assert main([str(G12), str(out), '--frames', '1,-2', '--rate', '10']) == 0
    frames = list(read_feature_frames(out))
    last = y.shape[2] - 2
    assert [f.stamp_ns for f in frames] == [EPOCH_NS + 100_000_000, EPOCH_NS + last * 100_000_000]
    for f, frame in zip((1, last), frames, strict=True):
        np.testing.assert_array_equal(frame.uv, as_float32((y[:2, :, f] / y[2, :, f]).T))
    assert len(read_ground_truth_frames(out)) == 2


@pytest.mark.data
@pytest.mark.parametrize('frames', ['0,0', '3,1', '0,99', 'a,b', '-99'])
def test_bad_frame_lists_are_one_line_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], frames: str
) -> None:
    assert main([str(G12), str(tmp_path / 'out'), f'--frames={frames}']) == 1
    assert 'frame' in one_error_line(capsys)
    assert not any(tmp_path.iterdir())


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


@pytest.mark.data
def test_a_dot_bag_output_is_a_ros1_bag_file_with_the_same_messages(tmp_path: Path) -> None:
    assert main([str(G12), str(tmp_path / 'ros2')]) == 0
    assert main([str(G12), str(tmp_path / 'ros1.bag')]) == 0
    ros1 = tmp_path / 'ros1.bag'
    assert ros1.is_file() and ros1.read_bytes().startswith(b'#ROSBAG V2.0\n')
    assert topics(ros1) == topics(tmp_path / 'ros2')
    for a, b in zip(read_feature_frames(ros1), read_feature_frames(tmp_path / 'ros2'),
                    strict=True):
        assert a.stamp_ns == b.stamp_ns
        np.testing.assert_array_equal(a.ids, b.ids)
        np.testing.assert_array_equal(a.uv, b.uv)
    header = raw_messages(ros1, '/feature_tracker/feature')[0].header
    assert header.seq == 0 and header.frame_id == 'camera'  # a ROS 1 Header
    assert sorted(p.name for p in tmp_path.iterdir()) == ['ros1.bag', 'ros2']  # no staging


@pytest.mark.data
def test_a_ros1_bag_file_is_replaced_only_with_force(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / 'x.bag'
    assert main([str(G12), str(out), '--frames', '0,1']) == 0
    before = out.read_bytes()
    assert main([str(G12), str(out)]) == 1
    assert '--force' in one_error_line(capsys)
    assert out.read_bytes() == before
    assert main([str(G12), str(out), '--force']) == 0
    assert len(list(read_feature_frames(out))) == 24
