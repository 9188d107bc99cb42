"""Real rclpy for the node tests: a private context and executor per test, a probe node.

Imported by conftest.py (the ``ros`` fixture) and by the tests (``from ros_harness import``).

Isolation: the domain id comes from the test process id and discovery stays on this machine
(set before rclpy is initialised anywhere), and each test puts its nodes in a namespace of its
own, so parallel runs and other workers' tests do not hear each other.
"""

from __future__ import annotations

import os

os.environ['ROS_DOMAIN_ID'] = str(1 + os.getpid() % 100)
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'

import uuid  # noqa: E402
from collections.abc import Callable  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
import rclpy  # noqa: E402
from builtin_interfaces.msg import Time  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import Point32  # noqa: E402
from rcl_interfaces.msg import Log  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import ChannelFloat32, PointCloud, PointCloud2  # noqa: E402
from std_msgs.msg import Header  # noqa: E402

from pearl_ros.bagio import decode, encode  # noqa: E402
from pearl_ros.ros.node import PearlNode  # noqa: E402
from pearl_ros.ros.play import spin_until  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
BAG = REPO / 'bags' / '1R2RCR_g12'
RELIABLE = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)


def header(stamp_ns: int, frame_id: str = 'cam0') -> Header:
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=frame_id)


def vins_cloud(stamp_ns: int, ids: Any, uv: Any, *, channels: dict[str, Any] | None = None
               ) -> PointCloud:
    """A VINS-Mono PointCloud (rclpy). ``channels`` replaces the default id/u/v channels."""
    ids = np.asarray(ids, dtype=np.float64)
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    if channels is None:
        channels = {'id_of_point': ids, 'u_of_point': uv[:, 0], 'v_of_point': uv[:, 1]}
    return PointCloud(
        header=header(stamp_ns),
        points=[Point32(x=float(u) / 500, y=float(v) / 500, z=1.0) for u, v in uv.tolist()],
        channels=[ChannelFloat32(name=name, values=encode.array_float32(np.asarray(values)))
                  for name, values in channels.items()],
    )


class Probe:
    """Everything a test sees of the node: publisher on ``features``, the three outputs, logs."""

    def __init__(self, ros: Ros, msg_class: Any = PointCloud) -> None:
        self.ros = ros
        self.node = ros.node('probe')
        self.publisher = self.node.create_publisher(msg_class, 'features', RELIABLE)
        self.labels: list[PointCloud2] = []
        self.static: list[Any] = []
        self.diagnostics: list[Any] = []  # DiagnosticStatus of the node under test
        self.logs: list[Log] = []
        self.node.create_subscription(PointCloud2, 'motion_labels', self.labels.append, RELIABLE)
        self.node.create_subscription(msg_class, 'static_features', self.static.append, RELIABLE)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 50)
        rosout = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.node.create_subscription(Log, '/rosout', self._on_log, rosout)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        self.diagnostics.extend(s for s in msg.status if s.hardware_id.startswith(self.ros.ns))

    def _on_log(self, msg: Log) -> None:
        if msg.name.startswith(self.ros.ns.strip('/') + '.'):
            self.logs.append(msg)

    def wait_for(self, node: Node, timeout: float = 10.0) -> None:
        """Both directions matched: the node hears us and we hear its labels."""
        assert self.ros.spin_until(
            lambda: self.publisher.get_subscription_count() > 0
            and self.node.count_publishers(f'{self.ros.ns}/motion_labels') > 0
            and self.node.count_publishers(f'{self.ros.ns}/static_features') > 0
            and self.node.count_subscribers(f'{self.ros.ns}/features') > 0, timeout)
        del node

    def handshake(self, stamp_ns: int, timeout: float = 30.0) -> None:
        """Across processes: publish one-feature clouds until one is answered.

        Matching is decided on each side separately: our writer may match the node's reader
        before the node's labels writer matches our reader, and an answer sent then is lost.
        Once one answer came back, both directions are matched. Stamps count up from
        ``stamp_ns`` in 1 ms steps (keep them before the test's own frames).
        """
        sent = 0
        def answered() -> bool:
            nonlocal sent
            if self.labels:
                return True
            self.publisher.publish(vins_cloud(stamp_ns + sent * 1_000_000, [0], [[1.0, 1.0]]))
            sent += 1
            self.ros.spin_until(lambda: bool(self.labels), 0.2)
            return bool(self.labels)
        assert self.ros.spin_until(answered, timeout), 'no answer from the node'
        self.ros.spin_until(lambda: len(self.static) >= len(self.labels), 2.0)
        self.labels.clear()
        self.static.clear()

    def send(self, msg: Any, *, answered: bool = True, timeout: float = 5.0) -> PointCloud2 | None:
        """Publish ``msg``; with ``answered``, spin until its labels and static features arrive
        and return the labels."""
        stamp = decode.stamp_ns(msg.header)
        self.publisher.publish(msg)
        if not answered:
            return None
        assert self.ros.spin_until(
            lambda: self.labels_for(stamp) is not None
            and any(decode.stamp_ns(m.header) == stamp for m in self.static), timeout), (
            f'no motion_labels or static_features for stamp {stamp}')
        return self.labels_for(stamp)

    def labels_for(self, stamp: int) -> PointCloud2 | None:
        return next((m for m in self.labels if decode.stamp_ns(m.header) == stamp), None)

    def warnings(self, text: str) -> list[str]:
        return [m.msg for m in self.logs if m.level == Log.WARN and text in m.msg]

    def diagnostics_where(self, done: Callable[[dict[str, str]], bool],
                          timeout: float = 5.0) -> dict[str, str]:
        """Spin until a diagnostics status of the node satisfies ``done``; its key -> value."""
        def found() -> dict[str, str] | None:
            for status in reversed(self.diagnostics):
                values = {kv.key: kv.value for kv in status.values}
                values['_level'] = status.level
                values['_message'] = status.message
                if done(values):
                    return values
            return None
        assert self.ros.spin_until(lambda: found() is not None, timeout), (
            f'no matching diagnostics; last: {self.diagnostics[-1:]}')
        result = found()
        assert result is not None
        return result


class Ros:
    """One rclpy context and single-threaded executor; every node in namespace ``ns``."""

    def __init__(self) -> None:
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.ns = '/t' + uuid.uuid4().hex[:10]
        self.nodes: list[Node] = []

    def node(self, name: str, **kwargs: Any) -> Node:
        node = Node(name, context=self.context, namespace=self.ns, **kwargs)
        return self.add(node)

    def add(self, node: Node) -> Any:
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def pearl(self, **overrides: Any) -> PearlNode:
        """The node under test, with parameter overrides (a short diagnostics period)."""
        overrides.setdefault('diagnostics_period', 0.1)
        parameters = [Parameter(name, value=value) for name, value in overrides.items()]
        return self.add(PearlNode(context=self.context, namespace=self.ns,
                                  parameter_overrides=parameters))

    def probe(self, msg_class: Any = PointCloud) -> Probe:
        return Probe(self, msg_class)

    def spin_until(self, done: Callable[[], Any], timeout: float = 5.0) -> bool:
        return spin_until(self.executor, lambda: bool(done()), timeout)

    def close(self) -> None:
        for node in self.nodes:
            self.executor.remove_node(node)
            node.destroy_node()
        self.executor.shutdown()
        rclpy.try_shutdown(context=self.context)  # a test may have shut it down already
