"""Stopping the node: SIGINT or SIGTERM at any moment exits 0 without a traceback, and a context
shut down under a frame that is about to be published ends that frame quietly."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from pearl_ros.bagio.reader import read_feature_frames

from ros_harness import BAG, Probe, Ros, vins_cloud

BIN = Path(sys.executable).parent
FRAMES = list(read_feature_frames(BAG))


def _shut_down_first(ros: Ros, function: Any) -> Any:
    """``function``, after shutting the context down: as a signal handler or launch would,
    while the callback that called it runs on."""
    def wrapped(*args: Any, **kwargs: Any) -> Any:
        ros.context.try_shutdown()
        return function(*args, **kwargs)
    return wrapped


def _spin_after_shutdown(ros: Ros, done: Any) -> None:
    """Spin until ``done()``; once the context is shut down rclpy says so by raising
    ExternalShutdownException from the next spin, and by nothing else."""
    from rclpy.executors import ExternalShutdownException

    for _ in range(200):
        if done():
            return
        try:
            ros.executor.spin_once(timeout_sec=0.05)
        except ExternalShutdownException:
            return


def test_a_context_shut_down_while_a_frame_is_published_ends_the_callback_quietly(
    ros: Ros,
) -> None:
    node = ros.pearl(qos='reliable', qos_depth=10)
    probe = Probe(ros)
    probe.wait_for(node)
    probe.send(vins_cloud(FRAMES[0].stamp_ns, FRAMES[0].ids, FRAMES[0].uv))
    pipeline = node._pipeline
    process = pipeline.process
    calls: list[int] = []

    def shut_down_then_process(msg: Any, header: Any = None, arrived: Any = None) -> Any:
        calls.append(1)
        return _shut_down_first(ros, process)(msg, header, arrived)

    pipeline.process = shut_down_then_process  # type: ignore[method-assign]
    probe.publisher.publish(vins_cloud(FRAMES[1].stamp_ns, FRAMES[1].ids, FRAMES[1].uv))
    _spin_after_shutdown(ros, lambda: calls)
    node._worker.join(10.0)  # the shutdown stops the worker once the frame is over
    assert calls and not ros.context.ok() and not node._worker.is_alive()
    assert node.stats.processed == 2  # counted: the frame was segmented, its outputs dropped
    assert node.stats.errors == 0  # a publish error not swallowed would be counted here


def test_a_context_shut_down_while_diagnostics_are_published_ends_the_timer_quietly(
    ros: Ros,
) -> None:
    node = ros.pearl(diagnostics_period=0.05)
    calls: list[int] = []
    diagnostics = node.diagnostics

    def shut_down_then_diagnose() -> Any:
        calls.append(1)
        return _shut_down_first(ros, diagnostics)()

    node.diagnostics = shut_down_then_diagnose  # type: ignore[method-assign]
    _spin_after_shutdown(ros, lambda: calls)
    assert calls and not ros.context.ok()


def test_the_publish_error_is_not_swallowed_while_the_context_is_running(ros: Ros) -> None:
    # The quiet end is for a shut-down context only: a publisher destroyed under a running
    # context is a bug, and it must show.
    node = ros.pearl()
    node.destroy_publisher(node._labels_pub)
    frame = FRAMES[0]
    with pytest.raises(Exception):  # noqa: B017 - rclpy's InvalidHandle, whatever its module
        node._answer(vins_cloud(frame.stamp_ns, frame.ids, frame.uv), time.perf_counter())
    # The worker thread counts it as an internal error, and goes on.
    node._on_features(vins_cloud(frame.stamp_ns + 1, frame.ids, frame.uv))
    assert ros.spin_until(lambda: node.stats.errors == 1, 10.0)
    assert node._worker.is_alive()


# ----------------------------------------------------------------- the real executable


def _flow_then_signal(ros: Ros, signum: int, delay_s: float) -> subprocess.Popen:
    """Start pearl_node, keep it busy with bag frames, and signal it ``delay_s`` after its
    first answer; returns the process (signalled, maybe not yet exited)."""
    process = subprocess.Popen(
        [str(BIN / 'pearl_node'), '--ros-args', '-r', f'__ns:={ros.ns}',
         '-p', 'qos:=reliable', '-p', 'qos_depth:=100'],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    probe = Probe(ros)  # a reliable publisher: every frame reaches the node
    sent = 0

    def publish() -> None:  # ~100 Hz of 153-feature frames: the node is never idle
        nonlocal sent
        frame = FRAMES[sent % len(FRAMES)]
        stamp = FRAMES[0].stamp_ns + sent * 10_000_000  # always forward in time
        probe.publisher.publish(vins_cloud(stamp, frame.ids, frame.uv))
        sent += 1

    timer = probe.node.create_timer(0.01, publish)
    assert ros.spin_until(lambda: process.poll() is not None or len(probe.labels) >= 3, 30.0)
    assert process.poll() is None, process.communicate()[1]
    ros.spin_until(lambda: False, delay_s)
    process.send_signal(signum)
    ros.spin_until(lambda: process.poll() is not None, 10.0)
    timer.cancel()
    return process


SIGNALS = [signal.SIGINT, signal.SIGTERM, signal.SIGINT, signal.SIGTERM, signal.SIGINT]


@pytest.mark.parametrize('attempt', range(len(SIGNALS)))
def test_a_signal_while_frames_flow_exits_0_without_a_traceback(ros: Ros, attempt: int) -> None:
    signum = SIGNALS[attempt]
    delay_s = float(np.random.default_rng(attempt).uniform(0.0, 0.5))
    process = _flow_then_signal(ros, signum, delay_s)
    try:
        _, err = process.communicate(timeout=15)
    except subprocess.TimeoutExpired:
        process.kill()
        _, err = process.communicate()
        pytest.fail(f'pearl_node did not stop on {signal.Signals(signum).name}: {err}')
    assert process.returncode == 0, err
    assert 'Traceback' not in err and 'RCLError' not in err, err
