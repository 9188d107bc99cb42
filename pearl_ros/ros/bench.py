"""``pearl_node_bench``: end-to-end latency of ``pearl_node``, publish -> labels received.

A benchmark, not a test. One process, one single-threaded executor: a source node publishes a
stream with ground truth (:func:`pearl_ros.evaluation.latency.make_stream`: by default the
robot-like stream, a moving camera with cars, a person and outlier tracks) as VINS-Mono
PointClouds at a fixed rate, the node under test answers each with ``motion_labels``, and the
source stamps each answer on arrival.

Frame ``i`` is due at ``start + i / rate`` (monotonic clock), as from a tracker in its own
process. Between two callbacks of the executor the source publishes every frame that has come
due, so a frame that came due while the node was busy is published as soon as the node returns,
and its latency, counted from when it was due, includes that wait, as on a robot. Frames the node
never answers (its input queue dropped them, or its queue policy) are counted, not timed.

For each size the same frames go first through a no-op node (:class:`NoopNode`: it decodes each
message with the node's decoder and answers ``motion_labels`` with every label -1, the floor of
transport, decoding and encoding), then through ``pearl_node``.

Example::

    pearl_node_bench --features 300 500 1000 2000@10 --rate 30 --frames 300 --set window=10
"""

from __future__ import annotations

import argparse
import gc
import math
import os
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import rclpy
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Point32, Pose, PoseWithCovariance, Quaternion
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.logging import LoggingSeverity
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from sensor_msgs.msg import ChannelFloat32, PointCloud, PointCloud2
from std_msgs.msg import Header

from pearl_ros.bagio import cdr, decode, encode
from pearl_ros.core.errors import InputError
from pearl_ros.evaluation import latency
from pearl_ros.pipeline import settings as pipeline_settings
from pearl_ros.pipeline.messages import MessagePipeline, Skipped
from pearl_ros.pipeline.threads import limit_blas_threads
from pearl_ros.ros import convert
from pearl_ros.ros.node import OUTPUT_DEPTH, PearlNode, input_qos
from pearl_ros.ros.play import spin_until

KINDS = ('no-op', 'pearl_node')
POSE_TOPIC = 'camera_pose'
QUIET_S = 3.0  # s without an answer after the last frame: the rest will not come


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


class NoopNode(Node):
    """The baseline: takes and decodes each feature message as ``pearl_node`` does (raw CDR,
    :meth:`MessagePipeline.deserialize` and :meth:`~MessagePipeline.read`) and publishes its
    ``motion_labels`` with every label -1, on the same topics and QoS. Keyword arguments go to
    ``rclpy.node.Node``.
    """

    def __init__(self, settings: pipeline_settings.Settings, **kwargs: Any) -> None:
        super().__init__('pearl_noop', **kwargs)
        self._pipeline = MessagePipeline(settings, cdr.TYPES)
        node = settings.node
        self._type_name = convert.TYPE_NAMES[node.msg_type]
        self.create_subscription(convert.MSG_CLASSES[node.msg_type], 'features',
                                 self._on_features, input_qos(node.qos, node.qos_depth),
                                 raw=True)
        self._labels_pub = self.create_publisher(
            PointCloud2, 'motion_labels',
            QoSProfile(depth=OUTPUT_DEPTH, reliability=ReliabilityPolicy.RELIABLE))

    def _on_features(self, raw: bytes) -> None:
        msg = self._pipeline.deserialize(raw, self._type_name)
        features = msg if isinstance(msg, Skipped) else self._pipeline.read(msg)
        if isinstance(features, Skipped):
            return
        ids, uv = features
        labels = np.full(ids.size, encode.UNLABELLED, dtype=np.int64)
        self._labels_pub.publish(cdr.serialize(encode.motion_labels(msg.header, ids, uv, labels,
                                                                    cdr.TYPES)))


class Source(Node):
    """Publishes prepared messages when they come due and times the labels that come back.

    The messages are serialised before the run and published as bytes: a tracker serialises
    its messages in its own process, and this one is the node's.
    """

    def __init__(self, messages: list[Any], rate_hz: float, poses: list[Any] | None = None,
                 **kwargs: Any) -> None:
        super().__init__('pearl_node_bench', **kwargs)
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.messages = [serialize_message(m) for m in messages]
        # Each frame's camera pose, published right after the frame, as VINS publishes its
        # camera_pose after the features it estimated it from.
        self.poses = None if poses is None else [serialize_message(m) for m in poses]
        if self.poses is not None:
            self.pose_publisher = self.create_publisher(Odometry, POSE_TOPIC, qos)
        self.period_s = 1.0 / rate_hz
        self.index = {decode.stamp_ns(m.header): i for i, m in enumerate(messages)}
        self.start = math.nan  # monotonic s when frame 0 is due
        self.sent = 0
        self.latency_s: dict[int, float] = {}  # frame index -> s
        self.labels: dict[int, np.ndarray] = {}
        self.last_answer = math.nan
        self.publisher = self.create_publisher(PointCloud, 'features', qos)
        self.create_subscription(PointCloud2, 'motion_labels', self._on_labels, qos)

    def due(self, i: int) -> float:
        """Monotonic s when frame ``i`` is due."""
        return self.start + i * self.period_s

    def publish_due(self) -> float:
        """Publish every frame that has come due; s until the next one is (inf: none left)."""
        now = time.monotonic()
        while self.sent < len(self.messages) and self.due(self.sent) <= now:
            self.publisher.publish(self.messages[self.sent])
            if self.poses is not None:
                self.pose_publisher.publish(self.poses[self.sent])
            self.sent += 1
        return self.due(self.sent) - now if self.sent < len(self.messages) else math.inf

    def _on_labels(self, msg: PointCloud2) -> None:
        arrived = time.monotonic()
        i = self.index.get(decode.stamp_ns(msg.header))
        if i is not None and i < self.sent and i not in self.latency_s:
            self.latency_s[i] = arrived - self.due(i)
            self.labels[i] = decode.decode_fields(msg, ('label',))['label']
            self.last_answer = arrived

    def run(self, executor: SingleThreadedExecutor) -> None:
        """Publish the frames on time while spinning; return when every frame was answered or
        none came for :data:`QUIET_S` after the last was sent."""
        self.start = time.monotonic()
        while True:
            wait = self.publish_due()
            if wait == math.inf:
                quiet_since = max(self.last_answer, self.due(len(self.messages) - 1))
                if (len(self.latency_s) == len(self.messages)
                        or time.monotonic() - quiet_since > QUIET_S):
                    return
            executor.spin_once(timeout_sec=max(0.0, min(wait, 0.05)))


@dataclass(frozen=True)
class Row:
    """One line of the table: a node kind at one size."""

    kind: str
    features: int
    rate_hz: float
    stats: latency.LatencyStats
    mean_pct: float
    final_pct: float
    cpu_ms: float  # CPU time of the whole process per frame sent, every thread's


def run_row(kind: str, make_node: Callable[[str], Node], messages: list[Any],
            truth: Sequence[np.ndarray], features: int, rate_hz: float, row: int,
            poses: list[Any] | None = None) -> Row:
    """Run ``messages`` through the node ``make_node(namespace)`` builds, in its own namespace.

    Raises
    ------
    InputError
        The node did not subscribe to the source within 10 s.
    """
    executor = SingleThreadedExecutor()
    ns = f'/pearl_bench_{os.getpid()}_{row}'
    node = make_node(ns)
    source = Source(messages, rate_hz, poses, namespace=ns)
    # As pearl_node's runner does once started; here it also keeps the source's messages (some
    # 1,000 Python objects each) out of the collector's full scans, which a node does not hold.
    gc.freeze()
    try:
        for item in (node, source):
            executor.add_node(item)
        if not spin_until(executor, lambda: source.publisher.get_subscription_count() > 0,
                          10.0):
            raise InputError(f'the {kind} node did not subscribe')
        cpu = time.process_time()
        source.run(executor)
        cpu_ms = 1e3 * (time.process_time() - cpu) / len(messages)
    finally:
        for item in (node, source):
            executor.remove_node(item)
            item.destroy_node()
        executor.shutdown()
    latency_ms = [1e3 * source.latency_s[i] for i in sorted(source.latency_s)]
    stats = latency.latency_stats(latency_ms, len(messages), 1e3 / rate_hz)
    mean, final = latency.accuracy(source.labels, truth)
    return Row(kind, features, rate_hz, stats, mean, final, cpu_ms)


def format_rows(rows: Sequence[Row], title: str) -> str:
    """The table, then a legend."""
    def cell(value: float, spec: str, width: int) -> str:
        return f'{"-":>{width}}' if math.isnan(value) else f'{value:{width}{spec}}'

    lines = [title, '', f'{"node":<10} {"features":>8} {"Hz":>4} {"answered":>9} {"p50 ms":>7} '
             f'{"p99 ms":>7} {"max ms":>7} {"over %":>6} {"p99/p50":>7} {"mean err %":>10} '
             f'{"final err %":>11} {"CPU ms":>6}']
    for r in rows:
        s = r.stats
        lines.append(f'{r.kind:<10} {r.features:>8} {r.rate_hz:>4g} '
                     f'{f"{s.answered}/{s.sent}":>9} {cell(s.p50, ".1f", 7)} '
                     f'{cell(s.p99, ".1f", 7)} {cell(s.max, ".1f", 7)} '
                     f'{cell(s.over_pct, ".1f", 6)} {cell(s.ratio, ".2f", 7)} '
                     f'{cell(r.mean_pct, ".2f", 10)} {cell(r.final_pct, ".2f", 11)} '
                     f'{cell(r.cpu_ms, ".1f", 6)}')
    lines += [
        'latency: labels received - frame due (waiting included), answered frames only.',
        'over %: answered frames whose latency exceeds the frame period. no-op: decode and',
        'answer all -1. mean err %: misclassification over the last three quarters of the',
        'frames (answered ones); final: the last answered frame. CPU ms: CPU time of the',
        'benchmark\'s process (every thread: source, node, DDS) per frame sent.',
    ]
    return '\n'.join(lines)


def camera_parameters() -> dict[str, Any]:
    """pearl_node's parameters for the robot stream's camera poses (:func:`camera_poses`)."""
    from pearl_ros.datasets.robot import INTRINSICS

    return {'pose_topic': POSE_TOPIC, 'camera_fx': float(INTRINSICS[0, 0]),
            'camera_fy': float(INTRINSICS[1, 1]), 'camera_cx': float(INTRINSICS[0, 2]),
            'camera_cy': float(INTRINSICS[1, 2])}


def camera_poses(stamps: Sequence[int], seed: int) -> list[Any]:
    """The true camera pose of each frame of the robot stream of ``seed``, as Odometry."""
    from pearl_ros.datasets.robot import robot_scene
    from pearl_ros.pipeline.poses import quaternion

    scene = robot_scene(len(stamps), seed)
    out = []
    for t, stamp in enumerate(stamps):
        c, q = scene.camera_position[t], quaternion(scene.camera_rotation[t])
        sec, nanosec = divmod(int(stamp), 1_000_000_000)
        out.append(Odometry(
            header=Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id='world'),
            child_frame_id='camera', pose=PoseWithCovariance(pose=Pose(
                position=Point(x=float(c[0]), y=float(c[1]), z=float(c[2])),
                orientation=Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]),
                                       w=float(q[3]))))))
    return out


def _quiet(node: Node) -> Node:
    """``node`` logging errors only: what it drops is counted in the table, not warned about."""
    node.get_logger().set_level(LoggingSeverity.ERROR)
    return node


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='pearl_node_bench', description=__doc__.split('\n')[0])
    parser.add_argument('--features', nargs='+', default=['300'], metavar='N[@HZ]',
                        help='features per frame, one run each (default 300); N@HZ publishes '
                        'that size at HZ instead of --rate (2000@10: 2000 features at 10 Hz)')
    parser.add_argument('--rate', type=float, default=30.0, metavar='HZ',
                        help='publication rate, Hz (default 30)')
    parser.add_argument('--frames', type=int, default=300, help='frames per run (default 300)')
    parser.add_argument('--seed', type=int, default=0, help='seed of the stream (default 0)')
    parser.add_argument('--stream', choices=latency.STREAMS, default='robot',
                        help='robot: moving camera, parallax, cars and a person, 10%% outlier '
                        'tracks (default); synthetic: rigid 2-D motions, births and deaths')
    parser.add_argument('--set', action='append', default=[], metavar='NAME=VALUE',
                        help='a parameter of pearl_node, repeatable (window=10, ...)')
    parser.add_argument('--cameras', action='store_true',
                        help="robot stream: also publish each frame's true camera pose "
                        f'(nav_msgs/msg/Odometry on {POSE_TOPIC}, after the frame) to a '
                        'pearl_node with pose_topic and the intrinsics set')
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    limit_blas_threads()  # as pearl_node runs
    try:
        overrides = pipeline_settings.parse_assignments(args.set)
        settings = pipeline_settings.build(overrides)  # checked before ROS starts
        if not 0 < args.rate < math.inf:
            raise InputError(f'--rate must be > 0 Hz, got {args.rate:g}')
        if args.frames < 2:
            raise InputError(f'--frames must be >= 2, got {args.frames}')
        if settings.node.msg_type != 'PointCloud':
            raise InputError('the benchmark publishes PointCloud: msg_type must stay PointCloud')
        sizes = [latency.parse_size(token, args.rate) for token in args.features]
        if args.cameras:
            if args.stream != 'robot':
                raise InputError('--cameras needs the robot stream (its scene knows its poses)')
            overrides = {**overrides, **camera_parameters()}
    except InputError as err:
        print(f'error: {err}', file=sys.stderr)
        return 1

    rows: list[Row] = []
    rclpy.init(args=[])
    try:
        for features, rate in sizes:
            stream = latency.make_stream(args.stream, features, args.frames, args.seed)
            messages = [vins_mono_cloud(f.stamp_ns, f.ids, f.uv) for f in stream]
            truth = [f.truth for f in stream]
            poses = (camera_poses([f.stamp_ns for f in stream], args.seed) if args.cameras
                     else None)
            makers: dict[str, Callable[[str], Node]] = {
                'no-op': lambda ns: NoopNode(settings, namespace=ns),
                'pearl_node': lambda ns: _quiet(PearlNode(namespace=ns, parameter_overrides=[
                    Parameter(name, value=value) for name, value in overrides.items()])),
            }
            for kind in KINDS:
                sys.stderr.write(f'\r{kind}: {features} features at {rate:g} Hz   ')
                rows.append(run_row(kind, makers[kind], messages, truth, features, rate,
                                    len(rows), poses))
        sys.stderr.write('\n')
    except InputError as err:
        print(f'\nerror: {err}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print('\nerror: interrupted', file=sys.stderr)
        return 1
    finally:
        rclpy.try_shutdown()

    title = (f'pearl_node end-to-end latency, frame due -> motion_labels received ({args.stream} '
             f'stream, {args.frames} frames, seed {args.seed}, in-process, pearl_node '
             f'queue_policy {settings.node.queue_policy}')
    title += ''.join(f', {k}={v}' for k, v in overrides.items()) + ')'
    print(format_rows(rows, title))
    silent = [f'{r.kind} at {r.features} features' for r in rows if r.stats.answered == 0]
    if silent:
        print(f'error: no frame answered by {", ".join(silent)}', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
