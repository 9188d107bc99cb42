"""The installed executables in processes of their own: the venv's console script, and the
colcon install layout found the way ``ros2 run`` finds it."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from ament_index_python.packages import get_package_prefix

from pearl_ros.bagio import decode
from pearl_ros.bagio.reader import read_feature_frames
from pearl_ros.ros import params

from ros_harness import BAG, REPO, Ros, vins_cloud

BIN = Path(sys.executable).parent
FRAMES = list(read_feature_frames(BAG))[:3]


def _start(command: list[str], ros: Ros, env: dict[str, str] | None = None) -> subprocess.Popen:
    # label_cost:=600 is the default, given as an integer: taken for the float it means.
    return subprocess.Popen(
        [*command, '--ros-args', '-r', f'__ns:={ros.ns}', '-p', 'diagnostics_period:=0.2',
         '-p', 'label_cost:=600'],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, **(env or {})},
    )


def _stop(process: subprocess.Popen) -> tuple[str, str]:
    """Ctrl-C, as a user would; returns the process' stdout and stderr."""
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
    try:
        return process.communicate(timeout=15)
    except subprocess.TimeoutExpired:
        process.kill()
        return process.communicate()


def _exchange_labels(ros: Ros, process: subprocess.Popen) -> None:
    """Wait for the node across processes (discovery), send three bag frames, check labels."""
    probe = ros.probe()
    matched = ros.spin_until(
        lambda: process.poll() is not None
        or (probe.publisher.get_subscription_count() > 0
            and probe.node.count_publishers(f'{ros.ns}/motion_labels') > 0
            and probe.node.count_publishers(f'{ros.ns}/static_features') > 0), 30.0)
    assert matched and process.poll() is None, 'the node did not come up'
    probe.handshake(FRAMES[0].stamp_ns - 10**10)
    for frame in FRAMES:
        answer = probe.send(vins_cloud(frame.stamp_ns, frame.ids, frame.uv), timeout=15.0)
        ids = decode.decode_fields(answer, ('id',))['id']
        np.testing.assert_array_equal(ids, frame.ids)
    labels = decode.decode_fields(answer, ('label',))['label']
    assert labels.shape == (153,) and (labels >= -1).all()


def test_console_script_answers_another_process_and_stops_cleanly_on_ctrl_c(ros: Ros) -> None:
    executable = BIN / 'pearl_node'
    assert executable.is_file(), f'{executable} missing: pip install -e . (make venv)'
    process = _start([str(executable)], ros)
    try:
        _exchange_labels(ros, process)
    finally:
        _, err = _stop(process)
    assert process.returncode == 0, err
    assert 'Traceback' not in err


def test_a_bad_parameter_stops_the_executable_with_a_one_line_error() -> None:
    done = subprocess.run([str(BIN / 'pearl_node'), '--ros-args', '-p', 'model:=bogus'],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 1
    lines = done.stderr.strip().splitlines()
    assert lines[-1] == ("error: model must be one of ('affine', 'fundamental', "
                         "'homography'), got 'bogus'")
    assert 'Traceback' not in done.stderr


def test_help_lists_topics_and_every_parameter_without_starting_ros() -> None:
    # With a domain id rcl refuses, starting ROS fails (one line, exit 1); the help does not.
    env = {**os.environ, 'ROS_DOMAIN_ID': 'none'}
    assert _first_error([str(BIN / 'pearl_node')], env) == (
        'error: failed to initialize rcl: ROS_DOMAIN_ID is not an integral number')
    done = subprocess.run([str(BIN / 'pearl_node'), '--help'], capture_output=True, text=True,
                          timeout=60, env=env)
    assert done.returncode == 0 and done.stderr == '', done.stderr
    for topic in ('features (in)', 'motion_labels (out)', 'static_features (out)', '~/reset'):
        assert topic in done.stdout
    for item in params.ALL_SPECS:
        assert f'\n  {item.name}: ' in done.stdout, item.name
        assert item.doc.split()[0] in done.stdout


def _first_error(command: list[str], env: dict[str, str] | None = None) -> str:
    done = subprocess.run(command, capture_output=True, text=True, timeout=60, env=env)
    assert done.returncode == 1, done.stderr
    assert 'Traceback' not in done.stderr
    lines = done.stderr.strip().splitlines()
    assert lines[-1].startswith('error: '), done.stderr
    return lines[-1]


@pytest.mark.parametrize(('text', 'expected'), [
    ('other_node:\n  ros__parameters:\n    label_cost: 300.0\n',
     "has no parameters for /pearl_node: its entries are for /other_node (name the node as "
     "'pearl_node:' or '/**:')"),
    ('/**:\n  ros__parameters:\n    label_cots: 300.0\n',
     "unknown parameter 'label_cots' (did you mean 'label_cost'?)"),
    ('/**:\n  ros__parameters:\n    window: 1\n', 'window must be >= 2, got 1'),
])
def test_node_and_replay_refuse_a_parameter_file_with_the_same_line(
    tmp_path: Path, text: str, expected: str
) -> None:
    path = tmp_path / 'p.yaml'
    path.write_text(text)
    node = _first_error([str(BIN / 'pearl_node'), '--ros-args', '--params-file', str(path)])
    replay = _first_error([str(BIN / 'pearl_replay'), str(REPO / 'bags' / '1R2RCR_g12_pair'),
                           '-o', str(tmp_path / 'out'), '--params', str(path)])
    assert node == replay
    assert expected in node
    assert not (tmp_path / 'out').exists()


def test_node_and_replay_refuse_a_misspelt_name_with_the_same_line(tmp_path: Path) -> None:
    node = _first_error([str(BIN / 'pearl_node'), '--ros-args', '-p', 'label_cots:=300'])
    replay = _first_error([str(BIN / 'pearl_replay'), str(REPO / 'bags' / '1R2RCR_g12_pair'),
                           '-o', str(tmp_path / 'out'), '--set', 'label_cots=300'])
    assert node == replay == "error: unknown parameter 'label_cots' (did you mean 'label_cost'?)"


@pytest.mark.parametrize(('args', 'expected'), [
    (['--ros-args', '--params-file', 'no_such_file.yaml'],
     'error: cannot read parameter file no_such_file.yaml: No such file or directory'),
    (['--ros-args', '-r'], 'error: '),  # rcl refuses the arguments: one line still
    (['--frobnicate'], 'error: unrecognized arguments: --frobnicate'),
])
def test_bad_arguments_stop_the_executable_with_a_one_line_error(
    args: list[str], expected: str
) -> None:
    assert _first_error([str(BIN / 'pearl_node'), *args]).startswith(expected)


def _copy_sources(target: Path) -> None:
    shutil.copytree(REPO, target, ignore=shutil.ignore_patterns(
        '.venv', '.git', 'bags', 'test', 'build', 'install', 'log', '*.egg-info',
        '__pycache__', '.pytest_cache', '.mypy_cache', '.ruff_cache'))


def test_colcon_build_installs_the_node_where_ros2_run_finds_it(
    ros: Ros, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _copy_sources(tmp_path / 'src' / 'pearl_ros')  # colcon writes egg-info beside setup.py
    done = subprocess.run(
        [str(BIN / 'colcon'), 'build', '--base-paths', 'src', '--build-base', 'build',
         '--install-base', 'install'],
        cwd=tmp_path, capture_output=True, text=True, timeout=300,
        env={**os.environ, 'COLCON_LOG_PATH': str(tmp_path / 'log')},
    )
    assert done.returncode == 0, done.stdout + done.stderr
    prefix = tmp_path / 'install' / 'pearl_ros'
    assert (prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' / 'pearl_ros'
            ).is_file()
    for shared in ('package.xml', 'config/pearl.yaml', 'launch/pearl.launch.py'):
        assert (prefix / 'share' / 'pearl_ros' / shared).is_file(), shared
    for name in ('pearl_node', 'pearl_play', 'pearl_node_bench'):
        assert os.access(prefix / 'lib' / 'pearl_ros' / name, os.X_OK), name

    # What `ros2 run pearl_ros pearl_node` does: find the prefix in the ament index, then
    # run <prefix>/lib/pearl_ros/pearl_node.
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(prefix))
    found = Path(get_package_prefix('pearl_ros'))
    assert found == prefix
    site = next((found / 'lib').glob('python3*/site-packages'))
    env = {'AMENT_PREFIX_PATH': str(found), 'PYTHONPATH': str(site)}
    where = subprocess.run([sys.executable, '-c', 'import pearl_ros; print(pearl_ros.__file__)'],
                           capture_output=True, text=True, env={**os.environ, **env}, check=True,
                           cwd=tmp_path)  # not the repo: '' on sys.path would find its copy
    assert Path(where.stdout.strip()).is_relative_to(site)  # the installed copy runs
    process = _start([str(found / 'lib' / 'pearl_ros' / 'pearl_node')], ros, env)
    try:
        _exchange_labels(ros, process)
    finally:
        _, err = _stop(process)
    assert process.returncode == 0, err
