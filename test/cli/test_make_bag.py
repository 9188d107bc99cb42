"""pearl_make_bag on Hopkins-format files, checked against the .mat contents read by scipy.

The real Hopkins155 files (``hopkins_root``, data tests) for what only they hold; a file written
from a synthetic scene (``hopkins_like``) where any valid file will do.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from pearl_ros.bagio import read_feature_frames, read_ground_truth, topics
from pearl_ros.cli.make_bag import EPOCH_NS, main

from bag_oracles import as_float32, raw_messages


def truth_file(root: Path, name: str) -> Path:
    return root / name / f'{name}_truth.mat'


def test_pointcloud_bag_matches_the_mat_file(
    hopkins_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    mat = scipy.io.loadmat(str(truth_file(hopkins_root, '1R2RCR_g12')))
    y, x, s = mat['y'], mat['x'], mat['s'].ravel()
    num_points, num_frames = y.shape[1], y.shape[2]
    out = tmp_path / 'checker'
    assert main([str(truth_file(hopkins_root, '1R2RCR_g12')), str(out)]) == 0
    assert 'wrote' in capsys.readouterr().out
    assert topics(out) == {
        '/feature_tracker/feature': 'sensor_msgs/msg/PointCloud',
        '/ground_truth/labels': 'sensor_msgs/msg/PointCloud2',
    }

    frames = list(read_feature_frames(out))
    assert len(frames) == num_frames
    for f, frame in enumerate(frames):
        assert frame.stamp_ns == EPOCH_NS + round(f * 1e9 / 30)
        np.testing.assert_array_equal(frame.ids, np.arange(num_points))
        np.testing.assert_array_equal(frame.uv, as_float32((y[:2, :, f] / y[2, :, f]).T))

    # Normalised points come from the file's x field.
    for f, msg in enumerate(raw_messages(out, '/feature_tracker/feature')):
        xy = np.array([(p.x, p.y) for p in msg.points])
        np.testing.assert_allclose(xy, (x[:2, :, f] / x[2, :, f]).T, rtol=0, atol=1e-6)

    # Labels: the file's groups 1..k renumbered 0..k-1, same partition.
    labels = read_ground_truth(out)
    assert sorted(labels) == list(range(num_points))
    got = np.array([labels[p] for p in range(num_points)])
    np.testing.assert_array_equal(got, s - s.min())


def test_pointcloud2_sqlite3_at_another_rate(hopkins_root: Path, tmp_path: Path) -> None:
    mat = scipy.io.loadmat(str(truth_file(hopkins_root, 'cars2')))
    y, x = mat['y'], mat['x']
    out = tmp_path / 'cars'
    args = [
        str(truth_file(hopkins_root, 'cars2')),
        str(out),
        '--format',
        'pointcloud2',
        '--storage',
        'sqlite3',
        '--rate',
        '10',
    ]
    assert main(args) == 0
    assert [p.suffix for p in out.iterdir() if p.name != 'metadata.yaml'] == ['.db3']
    assert topics(out)['/feature_tracker/feature'] == 'sensor_msgs/msg/PointCloud2'
    frames = list(read_feature_frames(out))
    assert [f.stamp_ns - EPOCH_NS for f in frames] == [k * 100_000_000 for k in range(y.shape[2])]
    np.testing.assert_array_equal(frames[-1].uv, as_float32((y[:2, :, -1] / y[2, :, -1]).T))
    msg = raw_messages(out, '/feature_tracker/feature')[-1]
    points = np.frombuffer(msg.data.tobytes(), dtype='<u4,<f4,<f4,<f4,<f4')
    np.testing.assert_allclose(
        np.column_stack((points['f3'], points['f4'])),
        (x[:2, :, -1] / x[2, :, -1]).T,
        rtol=0,
        atol=1e-6,
    )


def test_normalised_points_follow_x_where_k_disagrees(hopkins_root: Path, tmp_path: Path) -> None:
    # three-cars carries a K that does not produce its x field: x is the authority.
    mat = scipy.io.loadmat(str(truth_file(hopkins_root, 'three-cars')))
    y, x, k = mat['y'].astype(float), mat['x'], mat['K'].astype(float)
    from_k = np.linalg.solve(k, y[:, :, 0])
    assert np.abs(from_k[:2] / from_k[2] - x[:2, :, 0] / x[2, :, 0]).max() > 0.05
    out = tmp_path / 'three'
    assert main([str(truth_file(hopkins_root, 'three-cars')), str(out)]) == 0
    msg = raw_messages(out, '/feature_tracker/feature')[0]
    xy = np.array([(p.x, p.y) for p in msg.points])
    np.testing.assert_allclose(xy, (x[:2, :, 0] / x[2, :, 0]).T, rtol=0, atol=1e-6)
    assert len(set(read_ground_truth(out).values())) == 3


def test_missing_mat_file_is_a_one_line_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main([str(tmp_path / 'none_truth.mat'), str(tmp_path / 'out')]) == 1
    err = capsys.readouterr().err
    assert err.startswith('error: ') and err.count('\n') == 1
    assert 'none_truth.mat' in err
    assert not (tmp_path / 'out').exists()


def test_existing_output_needs_force(
    hopkins_like, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / 'bag'
    mat = str(hopkins_like('scene'))
    assert main([mat, str(out), '--rate', '10']) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    capsys.readouterr()
    assert main([mat, str(out)]) == 1
    err = capsys.readouterr().err
    assert err.startswith('error: ') and err.count('\n') == 1 and '--force' in err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert main([mat, str(out), '--force']) == 0  # 30 Hz now: the bag was replaced
    frames = list(read_feature_frames(out))
    assert frames[0].stamp_ns == EPOCH_NS
    assert frames[1].stamp_ns - frames[0].stamp_ns == 33_333_333
    assert sorted(p.name for p in tmp_path.iterdir()) == ['bag', 'hopkins155']  # no staging


def test_force_never_deletes_something_that_is_not_a_bag(
    hopkins_like, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    precious = tmp_path / 'notes'
    precious.mkdir()
    (precious / 'thesis.tex').write_text('keep me')
    assert main([str(hopkins_like('scene')), str(precious), '--force']) == 1
    assert 'not a bag' in capsys.readouterr().err
    assert (precious / 'thesis.tex').read_text() == 'keep me'


@pytest.mark.parametrize(
    ('args', 'named'),
    [
        (['--rate', '0'], 'rate'),
        (['--rate', 'nan'], 'rate'),
        (['--format', 'image'], "'image'"),
        (['--storage', 'rosbag1'], "'rosbag1'"),
        (['--no-such-flag'], '--no-such-flag'),
    ],
)
def test_bad_command_lines_return_1(
    hopkins_like, tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], named: str
) -> None:
    mat = str(hopkins_like('scene'))
    # The file and output are good (the same command line without the bad option succeeds):
    # the option alone is what is refused.
    assert main([mat, str(tmp_path / 'good')]) == 0
    capsys.readouterr()
    assert main([mat, str(tmp_path / 'out'), *args]) == 1
    err = capsys.readouterr().err
    error_lines = [line for line in err.splitlines() if line.startswith('error: ')]
    assert len(error_lines) == 1 and named in error_lines[0], err
    assert 'Traceback' not in err
    assert not (tmp_path / 'out').exists()


def test_not_a_hopkins_file_is_a_one_line_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bogus = tmp_path / 'bogus_truth.mat'
    scipy.io.savemat(str(bogus), {'z': np.zeros(3)})
    assert main([str(bogus), str(tmp_path / 'out')]) == 1
    err = capsys.readouterr().err
    assert err.startswith('error: ') and err.count('\n') == 1 and 'missing field' in err


def test_help_exits_0_and_the_module_runs_as_a_script(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(['--help']) == 0
    assert 'pearl_make_bag' in capsys.readouterr().out
    done = subprocess.run(
        [sys.executable, '-m', 'pearl_ros.cli.make_bag', 'missing.mat', 'x'],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 1
    assert done.stderr.startswith('error: ')
