"""``pearl_node_bench``: end-to-end latency of ``pearl_node``, publish -> labels received.

A benchmark, not a test. One process, one single-threaded executor: a publisher node sends a
synthetic stream (:func:`pearl_ros.datasets.synthetic.synthetic_stream`, ground truth known) as
VINS-Mono PointClouds on a 30 Hz timer, ``pearl_node`` segments it, and the publisher's
subscription stamps each ``motion_labels`` on arrival. The latency of a frame is arrival minus
publication (monotonic clock); a frame the node is still busy with when the next one is due
waits, and that wait is part of its successor's latency, as on a robot.

Example::

    pearl_node_bench --features 300 --rate 30 --frames 300
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
import rclpy
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point32
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import ChannelFloat32, PointCloud, PointCloud2
from std_msgs.msg import Header

from pearl_ros.bagio import decode, encode
from pearl_ros.core.errors import InputError
from pearl_ros.core.metrics import misclassification
from pearl_ros.datasets.synthetic import synthetic_stream
from pearl_ros.pipeline import settings
from pearl_ros.ros.node import PearlNode
from pearl_ros.ros.play import spin_until


def vins_mono_cloud(stamp_ns: int, ids: np.ndarray, uv: np.ndarray) -> PointCloud:
    """A VINS-Mono PointCloud: pixels in u/v channels, points = pixels / 500 (a stand-in
    for the normalised coordinates, which the node does not use when pixels are there)."""
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return PointCloud(
        header=Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id='camera'),
        points=[Point32(x=u / 500, y=v / 500, z=1.0) for u, v in uv.tolist()],
        channels=[ChannelFloat32(name=name, values=encode.array_float32(values))
                  for name, values in (('id_of_point', ids), ('u_of_point', uv[:, 0]),
                                       ('v_of_point', uv[:, 1]))],
    )


class Source(Node):
    """Publishes prepared messages on a timer and times the labels that come back."""

    def __init__(self, messages: list[PointCloud], rate_hz: float, **kwargs: Any) -> None:
        super().__init__('pearl_node_bench', **kwargs)
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.messages = messages
        self.sent: dict[int, float] = {}  # stamp -> monotonic time published
        self.latency: dict[int, float] = {}  # stamp -> s
        self.labels: dict[int, np.ndarray] = {}
        self.publisher = self.create_publisher(PointCloud, 'features', qos)
        self.create_subscription(PointCloud2, 'motion_labels', self._on_labels, qos)
        self.timer = self.create_timer(1.0 / rate_hz, self._tick)
        self.timer.cancel()  # started once the node is matched

    def _tick(self) -> None:
        if len(self.sent) == len(self.messages):
            self.timer.cancel()
            return
        msg = self.messages[len(self.sent)]
        self.sent[decode.stamp_ns(msg.header)] = time.monotonic()
        self.publisher.publish(msg)

    def _on_labels(self, msg: PointCloud2) -> None:
        arrived = time.monotonic()
        stamp = decode.stamp_ns(msg.header)
        if stamp in self.sent:
            self.latency[stamp] = arrived - self.sent[stamp]
            self.labels[stamp] = decode.decode_fields(msg, ('label',))['label']


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='pearl_node_bench', description=__doc__.split('\n')[0])
    parser.add_argument('--features', type=int, default=300, help='features per frame')
    parser.add_argument('--rate', type=float, default=30.0, help='Hz, publication rate')
    parser.add_argument('--frames', type=int, default=300, help='frames to publish')
    parser.add_argument('--seed', type=int, default=0, help='seed of the synthetic stream')
    parser.add_argument('--set', action='append', default=[], metavar='NAME=VALUE',
                        help='a parameter of pearl_node, repeatable')
    args = parser.parse_args(argv)
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    try:
        overrides = settings.parse_assignments(args.set)
        settings.build(overrides)  # checked before ROS starts
    except InputError as err:
        print(f'error: {err}', file=sys.stderr)
        return 1

    stream = list(synthetic_stream(num_features=args.features, frames=args.frames,
                                   seed=args.seed))
    messages = [vins_mono_cloud(f.stamp_ns, f.ids, f.uv) for f in stream]
    truth = {f.stamp_ns: f.truth for f in stream}

    rclpy.init(args=[])
    executor = SingleThreadedExecutor()
    ns = f'/pearl_bench_{os.getpid()}'
    node = PearlNode(namespace=ns, parameter_overrides=[
        Parameter(name, value=value) for name, value in overrides.items()])
    source = Source(messages, args.rate, namespace=ns)
    try:
        for item in (node, source):
            executor.add_node(item)
        if not spin_until(executor, lambda: source.publisher.get_subscription_count() > 0,
                          10.0):
            print('error: the node did not subscribe', file=sys.stderr)
            return 1
        source.timer.reset()
        spin_until(executor, lambda: len(source.latency) == len(messages),
                   len(messages) / args.rate + 30.0)
    except KeyboardInterrupt:
        print('error: interrupted', file=sys.stderr)
        return 1
    finally:
        executor.remove_node(node)
        executor.remove_node(source)
        node.destroy_node()
        source.destroy_node()
        rclpy.try_shutdown()

    latency_ms = np.array([source.latency[s] for s in source.sent if s in source.latency]) * 1e3
    settled = list(source.labels)[len(source.labels) // 4:]  # skip the warm-up
    errors = [misclassification(source.labels[s], truth[s]) for s in settled]
    print(f'pearl_node end-to-end latency, publish -> motion_labels received '
          f'({args.features} features, {args.rate:g} Hz, {len(messages)} frames, in-process)')
    print(f'{"answered":>10} {"p50 ms":>8} {"p90 ms":>8} {"p99 ms":>8} {"max ms":>8} '
          f'{"mean ms":>8} {"error":>7}')
    if latency_ms.size == 0:
        print('no frame answered')
        return 1
    p50, p90, p99 = np.percentile(latency_ms, [50, 90, 99])
    error = f'{100 * np.mean(errors):6.1f}%' if errors else '    n/a'
    print(f'{latency_ms.size:>6}/{len(messages):<3} {p50:8.1f} {p90:8.1f} {p99:8.1f} '
          f'{latency_ms.max():8.1f} {latency_ms.mean():8.1f} {error}')
    print('error: mean misclassification of the last three quarters of the frames')
    return 0 if latency_ms.size == len(messages) else 1


if __name__ == '__main__':
    sys.exit(main())
