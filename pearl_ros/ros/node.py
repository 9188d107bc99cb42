"""``pearl_node``: online motion segmentation between a feature tracker and its consumers.

Topics (names relative to the node's namespace unless absolute)

``features`` (in)
    ``sensor_msgs/msg/PointCloud`` (VINS-Mono or VINS-Fusion layout) or ``PointCloud2`` (fields
    ``id`` and ``u``, ``v`` or ``x``, ``y``), parameter ``msg_type``. Remap it to the tracker's
    topic (``features:=/feature_tracker/feature``).
``motion_labels`` (out)
    ``sensor_msgs/msg/PointCloud2``, one point per input feature in input order: ``id`` uint32,
    ``u``, ``v`` float32 (pixels), ``label`` int32 (-1 = outlier or undecided).
``static_features`` (out)
    The input message, same type and layout, with only the background motion's features.
``/diagnostics`` (out)
    ``diagnostic_msgs/msg/DiagnosticArray`` every ``diagnostics_period`` s.

Service ``~/reset`` (``std_srvs/srv/Trigger``) empties the window.

Every input message that can be read gets exactly one ``motion_labels`` and one
``static_features`` with its header. One that cannot (see :meth:`PearlNode._on_features`) gets
none: it is counted in the diagnostics and answered by a throttled warning.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from pearl_ros.bagio import decode, encode
from pearl_ros.core.errors import InputError
from pearl_ros.online.segmenter import OnlineSegmenter
from pearl_ros.ros import convert, params

WARN_PERIOD_S = 5.0  # at most one warning of each kind this often
OUTPUT_DEPTH = 10  # messages, keep-last depth of the (reliable) outputs


def input_qos(kind: str, depth: int) -> QoSProfile:
    """Input QoS: ``'sensor_data'`` (best effort) or ``'reliable'``, keep last ``depth``.

    A best-effort subscription takes messages from reliable and best-effort publishers alike; a
    reliable one gets nothing from a best-effort publisher (counted as incompatible QoS).
    """
    if kind == 'reliable':
        return QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE)
    profile = QoSProfile(depth=depth)
    profile.reliability = qos_profile_sensor_data.reliability
    profile.durability = qos_profile_sensor_data.durability
    return profile


@dataclass
class Stats:
    """Counters since start-up, and what the current diagnostics period saw."""

    received: int = 0
    processed: int = 0
    malformed: int = 0  # unreadable: decode refused it
    skipped: int = 0  # readable, not segmented: empty, repeated stamp
    capped: int = 0  # more than max_features: a subsample was segmented
    resets: int = 0  # stamp went back in time: window emptied
    reset_requests: int = 0  # ~/reset calls
    errors: int = 0  # unexpected exceptions (a bug), the node carried on
    mismatched_publishers: int = 0  # publishers of another type on `features`, last check
    incompatible_qos: int = 0  # publishers whose QoS the subscription cannot match
    motions: int = 0  # last segmented frame
    features: int = 0
    segmented: int = 0
    period_start: float = field(default_factory=time.monotonic)
    period_received: int = 0
    period_problems: int = 0
    period_latency_s: list[float] = field(default_factory=list)


class PearlNode(Node):
    """The segmentation node (module docstring). Keyword arguments go to ``rclpy.node.Node``.

    Raises
    ------
    InputError, rclpy.exceptions.ParameterException
        A parameter override of the wrong type, out of range, or not among its choices.
    """

    def __init__(self, node_name: str = 'pearl_node', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._values = params.declare(self)
        self._config, self._online, self._settings = params.build(self._values)
        self._seg = OnlineSegmenter(self._config, self._online)
        self.stats = Stats()
        self._warned: dict[str, tuple[float, int]] = {}  # kind -> (last time, suppressed)

        settings = self._settings
        self._msg_class = convert.MSG_CLASSES[settings.msg_type]
        self._sub = self.create_subscription(
            self._msg_class, 'features', self._on_features,
            input_qos(settings.qos, settings.qos_depth),
            event_callbacks=SubscriptionEventCallbacks(incompatible_qos=self._on_incompatible_qos),
        )
        output_qos = QoSProfile(depth=OUTPUT_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
        self._labels_pub = self.create_publisher(PointCloud2, 'motion_labels', output_qos)
        self._static_pub = self.create_publisher(self._msg_class, 'static_features', output_qos)
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._reset_srv = self.create_service(Trigger, '~/reset', self._on_reset)
        self.add_pre_set_parameters_callback(_ints_as_floats)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._timer = self.create_timer(settings.diagnostics_period, self._on_timer)
        self.get_logger().info(
            f'segmenting {settings.msg_type} on {self._sub.topic_name} '
            f'(layout {settings.layout}, qos {settings.qos} depth {settings.qos_depth})'
        )

    # ------------------------------------------------------------------------------ input

    def _on_features(self, msg: Any) -> None:
        """Segment one message; publish its labels and static features.

        Malformed (decode refuses it: channel lengths, missing channels or fields, NaN or inf
        coordinates, duplicate or non-integer ids, PointCloud ids beyond 2**24): no output.
        Skipped (readable but nothing to segment: an empty cloud, a stamp equal to the last):
        no output. Capped (more than ``max_features``): a hashed subsample is segmented, the
        rest labelled -1. A stamp earlier than the last empties the window first (one warning
        per jump) and the message is segmented.
        """
        start = time.perf_counter()
        stats, settings = self.stats, self._settings
        stats.received += 1
        stats.period_received += 1
        try:
            ids, uv = convert.read_features(msg, settings.msg_type, settings.layout,
                                            settings.camera_id)
        except InputError as err:
            stats.malformed += 1
            stats.period_problems += 1
            self._warn('malformed', f'malformed {settings.msg_type} skipped: {err}')
            return
        if ids.size == 0:
            stats.skipped += 1
            stats.period_problems += 1
            self._warn('empty', f'{settings.msg_type} with no features skipped')
            return
        keep = encode.subsample_mask(ids, settings.max_features)
        if not keep.all():
            stats.capped += 1
            self._warn('capped', f'{ids.size} features > max_features {settings.max_features}: '
                       'segmenting a hashed subsample, the rest labelled -1')
        stamp = decode.stamp_ns(msg.header)
        try:
            result = self._seg.process(stamp, ids[keep], uv[keep])
        except InputError as err:
            stats.skipped += 1
            stats.period_problems += 1
            self._warn('rejected', f'{settings.msg_type} skipped: {err}')
            return
        if result.reset:
            stats.resets += 1
            self.get_logger().warning(
                f'stamp {stamp} ns went back in time: window emptied (bag replayed in a loop?)'
            )
        try:
            labels = np.full(ids.size, encode.UNLABELLED, dtype=np.int64)
            labels[keep] = result.labels
            background = settings.background_motion if settings.background_motion >= 0 else None
            static = encode.static_mask(labels, background)
            labels_msg = encode.motion_labels(msg.header, ids, uv, labels, convert.TYPES)
            static_msg = encode.static_features(msg, static, convert.TYPES, settings.layout,
                                                settings.camera_id)
        except Exception as err:  # a bug must not take the node down with it
            stats.errors += 1
            self._warn('error', f'internal error, message dropped: {type(err).__name__}: {err}')
            return
        self._labels_pub.publish(labels_msg)
        self._static_pub.publish(static_msg)
        stats.processed += 1
        stats.motions = result.motions
        stats.features = int(ids.size)
        stats.segmented = int(keep.sum())
        stats.period_latency_s.append(time.perf_counter() - start)

    def _on_incompatible_qos(self, info: Any) -> None:
        self.stats.incompatible_qos = int(info.total_count)
        self._warn('qos', f'{info.total_count} publisher(s) on {self._sub.topic_name} have a QoS '
                   f'this {self._settings.qos} subscription cannot match '
                   f'({info.last_policy_kind.name}): nothing is received from them')

    # ------------------------------------------------------------------------- services

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response
                  ) -> Trigger.Response:
        del request
        frames = self._seg.frames_in_window
        self._seg.reset()
        self.stats.reset_requests += 1
        response.success = True
        response.message = f'window emptied ({frames} frames dropped)'
        self.get_logger().info(response.message)
        return response

    def _on_set_parameters(self, parameters: list[Parameter[Any]]) -> SetParametersResult:
        """Validate a change through the configuration objects; apply it from the next frame."""
        values = {**self._values, **{p.name: p.value for p in parameters}}
        try:
            config, online, settings = params.build(values)
        except InputError as err:
            return SetParametersResult(successful=False, reason=str(err))
        self._seg.reconfigure(config, online)
        self._values, self._config, self._online = values, config, online
        self._settings = settings
        return SetParametersResult(successful=True, reason='')

    # ---------------------------------------------------------------------- diagnostics

    def _on_timer(self) -> None:
        self._check_publisher_types()
        self._diagnostics_pub.publish(self.diagnostics())

    def _check_publisher_types(self) -> None:
        """Warn about publishers of another type on ``features``.

        DDS delivers nothing across types, and rclpy refuses a second subscription of another
        type on the same name in one process, so the graph is the only place to see them.
        """
        topic = self._sub.topic_name
        expected = convert.TYPE_NAMES[self._settings.msg_type]
        wrong = [info for info in self.get_publishers_info_by_topic(topic)
                 if info.topic_type != expected]
        self.stats.mismatched_publishers = len(wrong)
        if wrong:
            kinds = ', '.join(sorted({info.topic_type for info in wrong}))
            self._warn('type', f'{len(wrong)} publisher(s) send {kinds} on {topic} but msg_type '
                       f'is {self._settings.msg_type}: none of their messages arrive')

    def diagnostics(self) -> DiagnosticArray:
        """The status of the last period, and starts a new period."""
        stats = self.stats
        now = time.monotonic()
        elapsed = max(now - stats.period_start, 1e-9)
        latency_ms = np.asarray(stats.period_latency_s) * 1e3
        problems = []
        if stats.mismatched_publishers:
            problems.append(f'{stats.mismatched_publishers} publisher(s) of another type')
        if stats.incompatible_qos:
            problems.append(f'{stats.incompatible_qos} publisher(s) with incompatible QoS')
        if stats.period_problems:
            problems.append(f'{stats.period_problems} message(s) malformed or skipped')
        if not stats.period_received:
            problems.append('no input')
        values = {
            'input rate (Hz)': f'{stats.period_received / elapsed:.2f}',
            'latency mean (ms)': f'{latency_ms.mean():.2f}' if latency_ms.size else '',
            'latency max (ms)': f'{latency_ms.max():.2f}' if latency_ms.size else '',
            'motions': stats.motions,
            'features': stats.features,
            'features segmented': stats.segmented,
            'frames in window': self._seg.frames_in_window,
            'messages received': stats.received,
            'messages processed': stats.processed,
            'malformed messages': stats.malformed,
            'skipped messages': stats.skipped,
            'capped messages': stats.capped,
            'window resets (stamp went back)': stats.resets,
            'reset requests': stats.reset_requests,
            'internal errors': stats.errors,
            'publishers of another type': stats.mismatched_publishers,
            'publishers with incompatible QoS': stats.incompatible_qos,
        }
        status = DiagnosticStatus(
            level=DiagnosticStatus.WARN if problems else DiagnosticStatus.OK,
            name=f'{self.get_name()}: motion segmentation',
            message='; '.join(problems) if problems else 'segmenting',
            hardware_id=self.get_fully_qualified_name(),
            values=[KeyValue(key=key, value=str(value)) for key, value in values.items()],
        )
        stats.period_start, stats.period_received, stats.period_problems = now, 0, 0
        stats.period_latency_s = []
        return DiagnosticArray(header=_header(self), status=[status])

    def _warn(self, kind: str, text: str) -> None:
        """A warning, at most one of each ``kind`` per :data:`WARN_PERIOD_S`."""
        now = time.monotonic()
        last, suppressed = self._warned.get(kind, (-np.inf, 0))
        if now - last < WARN_PERIOD_S:
            self._warned[kind] = (last, suppressed + 1)
            return
        if suppressed:
            text += f' ({suppressed} more like it in the last {now - last:.0f} s)'
        self._warned[kind] = (now, 0)
        self.get_logger().warning(text)


_FLOAT_NAMES = frozenset(item.name for item in params.ALL_SPECS if item.type is float)


def _ints_as_floats(parameters: list[Parameter[Any]]) -> list[Parameter[Any]]:
    """An integer given for a float parameter is that float (``ros2 param set ... 500``).

    Runs before rclpy's type check, which would refuse it with a reason that names no
    parameter; ``build_configs`` does the same for YAML files and ``--set``.
    """
    return [Parameter(p.name, Parameter.Type.DOUBLE, float(p.value))
            if p.name in _FLOAT_NAMES and p.type_ == Parameter.Type.INTEGER else p
            for p in parameters]


def _header(node: Node) -> Header:
    return Header(stamp=node.get_clock().now().to_msg())


def main(args: list[str] | None = None) -> int:
    """``pearl_node`` console script: spin until Ctrl-C; exit 1 on a bad parameter."""
    rclpy.init(args=args)
    node = None
    try:
        node = PearlNode()
        rclpy.spin(node)
    except (InputError, ParameterException) as err:
        print(f'error: {err}', file=sys.stderr)
        return 1
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
