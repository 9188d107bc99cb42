"""``pearl_node_bench`` end to end: a no-op row and a pearl_node row per size, both answered.
No assertion on a measured time."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np

from pearl_ros.evaluation.latency import make_stream
from pearl_ros.ros.bench import main

from ros_harness import REPO  # sets the test's domain id and local discovery first

FRAMES = 20


def test_node_bench_answers_every_frame_with_a_no_op_row_and_a_pearl_node_row() -> None:
    # A reliable input queue deep enough for the whole stream, and every message answered
    # however late (queue_policy all): no frame can be lost on the way.
    done = subprocess.run(
        [sys.executable, '-m', 'pearl_ros.ros.bench', '--features', '60', '--frames',
         str(FRAMES), '--set', 'qos=reliable', '--set', f'qos_depth={FRAMES}',
         '--set', 'queue_policy=all'],
        capture_output=True, text=True, timeout=300, cwd=REPO, env=dict(os.environ))
    assert done.returncode == 0, done.stderr
    rows = {line.split()[0]: line.split() for line in done.stdout.splitlines()
            if line.split()[:1] in (['no-op'], ['pearl_node'])}
    assert set(rows) == {'no-op', 'pearl_node'}
    for row in rows.values():
        kind, features, rate, answered, p50, p99, top, over, ratio, mean, final, cpu = row
        assert (features, rate, answered) == ('60', '30', f'{FRAMES}/{FRAMES}')
        assert 0 < float(p50) <= float(p99) <= float(top)
        assert 0 <= float(over) <= 100
        assert float(cpu) > 0  # the process worked, at least to decode and answer
    # The no-op node labels every feature -1: wrong exactly where the truth is not an outlier,
    # over frames 5-19 (the last three quarters) of the same stream.
    truth = [frame.truth for frame in make_stream('robot', 60, FRAMES, 0)]
    expected = 100 * np.mean([np.mean(t != -1) for t in truth[FRAMES // 4:]])
    assert float(rows['no-op'][9]) == round(expected, 2)
    assert float(rows['no-op'][10]) == round(100 * np.mean(truth[-1] != -1), 2)
    # pearl_node segments: it gets more right than labelling nothing.
    assert float(rows['pearl_node'][9]) < float(rows['no-op'][9])


def test_node_bench_refuses_a_bad_size_in_one_line_before_starting_ros(capsys) -> None:
    assert main(['--features', '300@fast']) == 1
    err = capsys.readouterr().err
    assert err.startswith('error: a size is FEATURES or FEATURES@HZ') and err.count('\n') == 1


def test_node_bench_with_cameras_feeds_the_true_poses_to_the_node() -> None:
    from pearl_ros.datasets.robot import robot_scene
    from pearl_ros.pipeline.poses import camera_matrix, intrinsics_matrix, read_pose
    from pearl_ros.ros.bench import camera_parameters, camera_poses

    stream = make_stream('robot', 60, FRAMES, 3)
    poses = camera_poses([frame.stamp_ns for frame in stream], 3)
    scene = robot_scene(FRAMES, 3)
    values = camera_parameters()
    k = intrinsics_matrix(values['camera_fx'], values['camera_fy'], values['camera_cx'],
                          values['camera_cy'])
    for t, msg in enumerate(poses):
        # The camera the node rebuilds from each message is the scene's own.
        assert np.allclose(camera_matrix(*read_pose(msg, 'odometry'), k), scene.camera(t))
    done = subprocess.run(
        [sys.executable, '-m', 'pearl_ros.ros.bench', '--features', '60', '--frames',
         str(FRAMES), '--cameras', '--set', 'qos=reliable', '--set', f'qos_depth={FRAMES}',
         '--set', 'queue_policy=all'],
        capture_output=True, text=True, timeout=300, cwd=REPO, env=dict(os.environ))
    assert done.returncode == 0, done.stderr
    assert 'pose_topic=camera_pose' in done.stdout
    answered = [line.split()[3] for line in done.stdout.splitlines()
                if line.split()[:1] == ['pearl_node'] and line.split()[1].isdigit()]
    assert answered == [f'{FRAMES}/{FRAMES}']
    assert main(['--cameras', '--stream', 'synthetic']) == 1
