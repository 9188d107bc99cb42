"""``pearl_node``: online motion segmentation between a feature tracker and its consumers.

Topics (names relative to the node's namespace unless absolute)

``features`` (in)
    ``sensor_msgs/msg/PointCloud`` (VINS-Mono or VINS-Fusion layout) or ``PointCloud2`` (fields
    ``id`` and ``u``, ``v`` or ``x``, ``y``), parameter ``msg_type``. Remap it to the tracker's
    topic (``features:=/feature_tracker/feature``). Normalised coordinates alone (no pixels in
    the message) are segmented as the pixels of the intrinsics, or of a nominal camera.
``motion_labels`` (out)
    ``sensor_msgs/msg/PointCloud2``, one point per input feature in input order: ``id`` uint32,
    ``u``, ``v`` float32 (pixels; normalised coordinates that no intrinsics project stay as
    they came), ``label`` int32 (-1 = outlier or undecided).
``static_features`` (out)
    The input message, same type and layout, with only the background motion's features.
``image_labels`` (out, when the parameter ``image_topic`` names an image topic)
    ``sensor_msgs/msg/Image``, bgr8, the size and header of the image on ``image_topic`` whose
    stamp is that of a feature message: its features drawn as dots in their motion's colour
    (:class:`~pearl_ros.tracking.draw.Overlay`). Images and labels wait for each other in a
    small buffer (:class:`StampMatcher`); one that finds no partner is dropped and counted.
``/diagnostics`` (out)
    ``diagnostic_msgs/msg/DiagnosticArray`` every ``diagnostics_period`` s.
``pose_topic`` (in, when the parameter names one)
    The camera's pose in a fixed world frame (its optical frame: z forward, x right, y down),
    ``nav_msgs/msg/Odometry``, ``geometry_msgs/msg/PoseStamped`` or
    ``geometry_msgs/msg/PoseWithCovarianceStamped`` (parameter ``pose_type``),
    such as VINS' ``camera_pose``; with the intrinsics of the features' pixels, from
    ``camera_info_topic`` or the parameters ``camera_fx``, ``camera_fy``, ``camera_cx``,
    ``camera_cy``. Each pose goes to the feature frame
    of the nearest stamp (within ``pose_tolerance_ms``), whether it comes before or after it
    (:class:`~pearl_ros.pipeline.poses.PoseBuffer`); the static world is then a motion of known
    parameters (:mod:`pearl_ros.core.models.ego`). Poses wait for the worker, which takes them
    before its next frame.
``camera_info_topic`` (in, when the parameter names one)
    ``sensor_msgs/msg/CameraInfo`` of the camera whose features are segmented (best effort, as
    camera drivers publish it), the latest valid one: its lens distortion is undone on the
    features before they are segmented, and with ``pose_topic`` its ``k`` (with its binning
    and region of interest) gives the intrinsics.

Service ``~/reset`` (``std_srvs/srv/Trigger``) empties the window.

The subscription callback only hands each message to a worker thread of the node
(:class:`Mailbox`), which segments it and publishes the answer, so that messages keep being taken
(and counted) while a frame is computed. When the node is slower than its input, parameter
``queue_policy`` says what it answers:

``newest`` (the default)
    The newest message it has: a message that a newer one replaced before the worker got to it
    is dropped and never answered. A message waits at most for the frame the worker was on
    when it came.
``all``
    Every message, in arrival order, with at most ``qos_depth`` waiting; beyond, the oldest
    waiting message is dropped. For bag replays and offline users: the lag grows with the
    backlog.

A node that keeps up answers every message under either policy. A dropped message is counted
in the diagnostics (``messages dropped (late)``, and a WARN status for the period) and warned
about (throttled). Every message the worker takes that can be read gets exactly one
``motion_labels`` and one ``static_features`` with its header, in arrival order. One that
cannot (see :meth:`PearlNode._answer`) gets none: it is counted in the diagnostics and answered
by a throttled warning. The per-message work is
:class:`~pearl_ros.pipeline.messages.MessagePipeline`, the code ``pearl_replay`` runs. Feature
messages are taken and sent as their CDR bytes (a raw subscription, raw publishing), read into
arrays and written from them by :mod:`pearl_ros.bagio.cdr`, with no Python object per point.
Drawing never delays ``motion_labels``: a frame's labels are published before its image is
drawn.

SIGINT or SIGTERM stops the node between two callbacks, with exit status 0: the worker ends the
frame it is on, and the messages waiting for it are not answered.
"""

from __future__ import annotations

import sys
import threading
import time
from collections import Counter, deque
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.exceptions import NameValidationException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_srvs.srv import Trigger

from pearl_ros.bagio import cdr, decode
from pearl_ros.core.errors import InputError, one_line
from pearl_ros.online.config import unknown_parameter
from pearl_ros.pipeline import settings as pipeline_settings
from pearl_ros.pipeline.messages import Labelled, MessagePipeline, Skipped
from pearl_ros.pipeline.poses import POSE_TYPES
from pearl_ros.ros import convert, params, runner
from pearl_ros.tracking import image as image_io
from pearl_ros.tracking.draw import Overlay, to_bgr

OUTPUT_DEPTH = 10  # messages, keep-last depth of the (reliable) outputs
# Images, and label results, waiting for their partner of the same stamp (each kind): a tracker
# answers an image within a frame or two, so 30 outlasts any normal delay.
MATCH_DEPTH = 30
# Poses waiting for the worker: a second of 200 Hz odometry (the oldest go first).
POSE_BACKLOG = 200
# Frames segmented with poses coming but none matched before the diagnostics say so.
UNMATCHED_FRAMES = 10


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
    dropped: int = 0  # late: replaced by a newer message (newest) or pushed out of the backlog
    malformed: int = 0  # unreadable: decode refused it
    skipped: int = 0  # readable, not segmented: empty, repeated stamp
    capped: int = 0  # more than max_features: a subsample was segmented
    resets: int = 0  # stamp went back in time: window emptied
    reset_requests: int = 0  # ~/reset calls
    errors: int = 0  # unexpected exceptions (a bug), the node carried on
    mismatched_publishers: int = 0  # publishers of another type on `features`, last check
    images: int = 0  # received on image_topic
    poses: int = 0  # camera poses taken from pose_topic
    bad_poses: int = 0  # unreadable poses (zero quaternion, non-finite position)
    frames_with_camera: int = 0  # feature frames that got a camera pose
    camera_infos: int = 0  # camera_info messages taken from camera_info_topic
    bad_camera_infos: int = 0  # camera_info messages refused (uncalibrated, non-finite k)
    annotated: int = 0  # image_labels published
    bad_images: int = 0  # unsupported encoding, or step / data that do not fit
    incompatible_qos: int = 0  # publishers whose QoS the subscription cannot match
    window: int = 0  # frames in the window, after the last frame or ~/reset
    motions: int = 0  # last segmented frame
    features: int = 0
    segmented: int = 0
    period_start: float = field(default_factory=time.monotonic)
    period_received: int = 0
    period_dropped: int = 0
    period_problems: int = 0
    period_bad_images: int = 0
    period_latency_s: list[float] = field(default_factory=list)


class StampMatcher:
    """Pairs images with label results of the same stamp, whichever comes first.

    Each stream comes in stamp order, so when a pair is made at stamp ``s`` whatever waits with
    an earlier stamp will never find its partner (the tracker skipped that image, or the node
    that message): it is dropped. At most ``depth`` of each kind wait; beyond, the oldest is
    dropped. :attr:`dropped` counts the drops by kind, :attr:`overflows` those of a full buffer
    (stamps that never match, as when a tracker stamps its features with its own clock).

    Parameters
    ----------
    depth : int
        Items of each kind that may wait.
    """

    KINDS = ('image', 'labels')

    def __init__(self, depth: int = MATCH_DEPTH) -> None:
        self.depth = depth
        self._waiting: dict[str, dict[int, Any]] = {kind: {} for kind in self.KINDS}
        self.dropped: Counter[str] = Counter()
        self.overflows = 0

    def add(self, kind: str, stamp_ns: int, item: Any) -> tuple[Any, Any] | None:
        """Offer an ``item`` of ``kind`` (``'image'`` or ``'labels'``); the pair
        ``(image, labels)`` when its partner was waiting, else None (it waits)."""
        other = self.KINDS[1 - self.KINDS.index(kind)]
        partner = self._waiting[other].pop(stamp_ns, None)
        if partner is None:
            mine = self._waiting[kind]
            if mine.pop(stamp_ns, None) is not None:  # a repeated stamp: the newer one waits
                self.dropped[kind] += 1
            mine[stamp_ns] = item
            if len(mine) > self.depth:
                del mine[next(iter(mine))]  # dicts keep arrival order: the oldest
                self.dropped[kind] += 1
                self.overflows += 1
            return None
        self.discard(lambda stamp: stamp < stamp_ns)
        return (item, partner) if kind == 'image' else (partner, item)

    def discard(self, which: Any) -> None:
        """Drop (and count) what waits with a stamp for which ``which(stamp)`` is true."""
        for kind, waiting in self._waiting.items():
            for stamp in [stamp for stamp in waiting if which(stamp)]:
                del waiting[stamp]
                self.dropped[kind] += 1

    def waiting(self, kind: str) -> int:
        """How many items of ``kind`` wait."""
        return len(self._waiting[kind])


class Mailbox:
    """The messages the subscription callback hands to the node's worker thread.

    Policy ``'newest'``: one slot; an item put while one waits replaces it. ``'all'``: up to
    ``depth`` items wait and are taken in arrival order; one more pushes the oldest out (as a
    keep-last DDS history does). Thread-safe.

    Parameters
    ----------
    policy : {'newest', 'all'}
    depth : int
        Items that may wait under ``'all'``.
    """

    def __init__(self, policy: str, depth: int) -> None:
        self.capacity = 1 if policy == 'newest' else depth
        self._items: deque[Any] = deque()
        self._ready = threading.Condition()
        self._closed = False

    @property
    def closed(self) -> bool:
        return self._closed

    def put(self, item: Any) -> Any:
        """Hand ``item`` over; the item it pushed out (dropped), or None."""
        with self._ready:
            dropped = self._items.popleft() if len(self._items) >= self.capacity else None
            self._items.append(item)
            self._ready.notify()
        return dropped

    def take(self) -> Any:
        """The oldest waiting item, once there is one; None once :meth:`close` was called."""
        with self._ready:
            self._ready.wait_for(lambda: self._items or self._closed)
            return None if self._closed else self._items.popleft()

    def close(self) -> None:
        """Make :meth:`take` return None, now and from now on (what waits is left)."""
        with self._ready:
            self._closed = True
            self._ready.notify_all()

    def __len__(self) -> int:
        with self._ready:
            return len(self._items)


class PearlNode(Node):
    """The segmentation node (module docstring). Keyword arguments go to ``rclpy.node.Node``.

    Parameters
    ----------
    node_name : str
    params_files : sequence of str
        The ``--params-file`` files of the process' ROS arguments (``main`` passes them): each
        must have an entry for this node, or it would be ignored without a word. Files in
        ``cli_args`` are checked too.

    Raises
    ------
    InputError
        A parameter override (``-p``, a parameter file, ``parameter_overrides``) of an unknown
        name, of the wrong type, out of range or not among its choices; a parameter file
        without an entry for this node.
    """

    def __init__(self, node_name: str = pipeline_settings.NODE_NAME, *,
                 params_files: Sequence[str] = (), **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        try:
            files = [*params_files, *params.params_files(kwargs.get('cli_args') or ())]
            params.check_params_files(files, self.get_fully_qualified_name())
            # rclpy keeps the overrides it parsed (files, -p, parameter_overrides) here and
            # offers no public accessor; declare() checks and applies them.
            self._values = params.declare(self, self._parameter_overrides)
            settings = pipeline_settings.build(self._values)
        except BaseException:
            self.destroy_node()
            raise
        self._pipeline = MessagePipeline(settings, cdr.TYPES)
        self.stats = Stats()
        self._warn = runner.Throttle(self).warn  # one warning per kind per WARN_PERIOD_S
        # Shared between the executor's thread and the worker's. Taken in this order when
        # nested; `_lock` is only held for a few statements.
        self._pipeline_lock = threading.Lock()  # the pipeline: a frame, ~/reset, a new setting
        self._image_lock = threading.Lock()  # the StampMatcher and the Overlay
        self._lock = threading.Lock()  # self.stats

        node = settings.node
        self._mailbox = Mailbox(node.queue_policy, node.qos_depth)
        self._msg_class = convert.MSG_CLASSES[node.msg_type]
        self._type_name = convert.TYPE_NAMES[node.msg_type]
        # raw: the CDR bytes, read into arrays by pearl_ros.bagio.cdr (rclpy would build a
        # Python object per point first: 0.6 ms at 500 points, 2.4 ms at 2,000).
        self._sub = self.create_subscription(
            self._msg_class, 'features', self._on_features, input_qos(node.qos, node.qos_depth),
            event_callbacks=SubscriptionEventCallbacks(incompatible_qos=self._on_incompatible_qos),
            raw=True,
        )
        output_qos = QoSProfile(depth=OUTPUT_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
        self._labels_pub = self.create_publisher(PointCloud2, 'motion_labels', output_qos)
        self._static_pub = self.create_publisher(self._msg_class, 'static_features', output_qos)
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._reset_srv = self.create_service(Trigger, '~/reset', self._on_reset)
        self._overlay: Overlay | None = None
        if node.image_topic:
            self._subscribe_images(node)
        # Poses wait here for the worker, which hands them to the pipeline before its next
        # frame: the executor's thread never waits for a frame being segmented.
        self._pending_poses: deque[Any] = deque(maxlen=POSE_BACKLOG)
        self._pending_info: Any = None  # the newest camera_info not yet taken
        if node.pose_topic:
            self._subscribe_poses(node)
        if node.camera_info_topic:
            self._info_sub = self._subscribe('camera_info_topic', CameraInfo,
                                             node.camera_info_topic, self._on_camera_info,
                                             input_qos('sensor_data', 1))
            use = 'the lens and intrinsics' if node.pose_topic else 'the lens'
            self.get_logger().info(f'taking {use} from {self._info_sub.topic_name}')
        self.add_pre_set_parameters_callback(_ints_as_floats)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._timer = self.create_timer(node.diagnostics_period, self._on_timer)
        self._worker = threading.Thread(target=self._work, daemon=True,
                                        name=f'{self.get_fully_qualified_name()} worker')
        self._worker.start()
        self.get_logger().info(
            f'segmenting {node.msg_type} on {self._sub.topic_name} '
            f'(layout {node.layout}, qos {node.qos} depth {node.qos_depth}, '
            f'queue_policy {node.queue_policy})'
        )

    def _subscribe(self, parameter: str, kind: Any, topic: str, callback: Any,
                   qos: QoSProfile) -> Any:
        """A subscription to the topic a ``parameter`` names; the node is destroyed and
        InputError raised for a name that is not a valid topic name."""
        try:
            return self.create_subscription(kind, topic, callback, qos)
        except NameValidationException as err:
            self.destroy_node()
            reason = str(err).splitlines()[0].rstrip(':').split(': ', 1)[-1]
            raise InputError(f'{parameter} {topic!r} is not a valid topic name: '
                             f'{reason}') from err

    def _subscribe_images(self, node: pipeline_settings.NodeConfig) -> None:
        """The ``image_topic`` subscription and ``image_labels``; InputError for a bad name."""
        self._image_sub = self._subscribe('image_topic', Image, node.image_topic, self._on_image,
                                          input_qos(node.qos, node.qos_depth))
        output_qos = QoSProfile(depth=OUTPUT_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
        self._image_pub = self.create_publisher(Image, 'image_labels', output_qos)
        self._overlay = Overlay()
        self._matcher = StampMatcher(MATCH_DEPTH)
        self.get_logger().info(f'drawing labels on {self._image_sub.topic_name} into '
                               f'{self._image_pub.topic_name}')

    def _subscribe_poses(self, node: pipeline_settings.NodeConfig) -> None:
        """The ``pose_topic`` subscription; InputError for a bad name."""
        kind = convert.POSE_CLASSES[POSE_TYPES[node.pose_type]]
        # Reliable, as odometry is published (VINS, robot_localization): a best-effort
        # subscriber takes both.
        self._pose_sub = self._subscribe(
            'pose_topic', kind, node.pose_topic, self._on_pose,
            QoSProfile(depth=POSE_BACKLOG, reliability=ReliabilityPolicy.RELIABLE))
        self.get_logger().info(f'taking camera poses ({node.pose_type}) from '
                               f'{self._pose_sub.topic_name}')

    def _on_pose(self, msg: Any) -> None:
        self._pending_poses.append(msg)

    def _on_camera_info(self, msg: Any) -> None:
        self._pending_info = msg  # only the newest matters

    def _take_poses(self) -> None:
        """Hand the newest camera_info and the poses that came since the last frame to the
        pipeline (under ``_pipeline_lock``); count them, and warn about unreadable ones."""
        info, self._pending_info = self._pending_info, None
        if info is not None:
            skip = self._pipeline.add_camera_info(info)
            if skip is not None:
                self._warn('camera_info',
                           f'{skip.line}: the lens and intrinsics stay as they were')
            with self._lock:
                self.stats.camera_infos += skip is None
                self.stats.bad_camera_infos += skip is not None
        taken = bad = 0
        while self._pending_poses:
            skip = self._pipeline.add_pose(self._pending_poses.popleft())
            taken += skip is None
            if skip is not None:
                bad += 1
                self._warn('pose', f'{self.settings.node.pose_type} message {skip.line}')
        if taken or bad:
            with self._lock:
                self.stats.poses += taken
                self.stats.bad_poses += bad

    @property
    def settings(self) -> pipeline_settings.Settings:
        """The settings in force (they change with ``set_parameters``)."""
        return self._pipeline.settings

    # ------------------------------------------------------------------------------ input

    def _on_features(self, raw: bytes) -> None:
        """Hand a message to the worker (:class:`Mailbox`); count, and warn about, the message
        it pushed out, if any (``queue_policy``)."""
        arrival = time.perf_counter()  # a frame's latency includes its wait for the worker
        with self._lock:
            self.stats.received += 1
            self.stats.period_received += 1
        dropped = self._mailbox.put((raw, arrival))
        if dropped is None:
            return
        with self._lock:
            self.stats.dropped += 1
            self.stats.period_dropped += 1
        node = self.settings.node
        why = ('a newer message came before the node got to it' if node.queue_policy == 'newest'
               else f'{self._mailbox.capacity} messages (qos_depth) were already waiting')
        self._warn('late', f'message of stamp {_stamp_text(dropped[0])} dropped unanswered: '
                   f'{why} (the node is slower than the input; queue_policy '
                   f'{node.queue_policy})')

    def _work(self) -> None:
        """The worker thread: answer what the mailbox hands over until it is closed."""
        while (item := self._mailbox.take()) is not None:
            try:
                self._answer(*item)
            except Exception as err:  # a bug must not silence the node: count it, go on
                with self._lock:
                    self.stats.errors += 1
                self._warn('error', f'internal error, message dropped: {type(err).__name__}: '
                           f'{err}')

    def _answer(self, raw: bytes, arrival: float) -> None:
        """Segment one message (:meth:`MessagePipeline.process`); publish its two outputs.

        A message the pipeline skips gets no output: it is counted (malformed, or skipped when
        it was read but had nothing to segment) and warned about, once per kind of problem per
        :data:`runner.WARN_PERIOD_S`. A capped message (more than ``max_features``) and a stamp
        going back in time (the window is emptied first) are warned about too. ``arrival`` is
        the :func:`time.perf_counter` time the subscription callback took the message at.
        """
        msg = self._pipeline.deserialize(raw, self._type_name)
        with self._pipeline_lock:
            self._take_poses()
            out = msg if isinstance(msg, Skipped) else self._pipeline.process(msg,
                                                                              arrived=arrival)
            with self._lock:
                self.stats.window = self._pipeline.frames_in_window
                self.stats.frames_with_camera = self._pipeline.frames_with_camera
        node = self.settings.node
        if isinstance(out, Skipped):
            with self._lock:
                self.stats.malformed += out.malformed
                self.stats.skipped += not out.malformed
                self.stats.period_problems += 1
            self._warn(out.kind, f'{node.msg_type} message {out.line}')
            return
        if out.capped:
            self._warn('capped', f'{out.ids.size} features > max_features '
                       f'{node.max_features}: segmenting a hashed subsample, the rest labelled -1')
        if out.result.reset:
            self.get_logger().warning(f'stamp {out.stamp_ns} ns went back in time: window '
                                      'emptied (bag replayed in a loop?)')
        with self._quiet_after_shutdown():
            self._labels_pub.publish(cdr.serialize(out.labels_msg))
            self._static_pub.publish(cdr.serialize(out.static_msg))
        with self._pipeline_lock:  # publishing counts in the budget of the frames after
            self._pipeline.delivered()
        latency = time.perf_counter() - arrival
        with self._lock:
            stats = self.stats
            stats.capped += out.capped
            stats.resets += bool(out.result.reset)
            stats.processed += 1
            stats.motions = out.result.motions
            stats.features = int(out.ids.size)
            stats.segmented = int(out.segmented.sum())
            stats.period_latency_s.append(latency)
        if self._overlay is not None:  # after motion_labels is out: drawing delays nothing
            self._offer_labels(out)

    # ------------------------------------------------------------------- image_labels

    def _on_image(self, msg: Image) -> None:
        """Keep an image until the labels of its stamp come, or draw it if they came first.

        An encoding :mod:`pearl_ros.tracking.image` does not read is counted and warned about
        (throttled), and the image dropped.
        """
        with self._lock:
            self.stats.images += 1
        encoding = str(msg.encoding)
        if encoding not in image_io.ENCODINGS:
            self._bad_image(f'image encoding {encoding!r} on {self._image_sub.topic_name} not '
                            f'supported (supported: {", ".join(image_io.ENCODINGS)}): no '
                            'image_labels for it')
            return
        self._pair('image', decode.stamp_ns(msg.header), msg)

    def _offer_labels(self, out: Labelled) -> None:
        """Offer a frame's labels to the matcher (a stamp gone back: forget colours, trails and
        what waited for a later stamp)."""
        assert self._overlay is not None
        if out.result.reset:
            with self._image_lock:
                self._overlay.reset()
                self._matcher.discard(lambda stamp: stamp > out.stamp_ns)
        if out.image_uv is None:
            self._warn('normalised', 'features carry normalised coordinates and no intrinsics '
                       'are known (camera_info_topic, or camera_fx, camera_fy, camera_cx, '
                       'camera_cy): their labels are not drawn on image_labels')
            return
        self._pair('labels', out.stamp_ns, (out.ids, out.image_uv, out.labels))

    def _pair(self, kind: str, stamp_ns: int, item: Any) -> None:
        """Offer an image or a frame's labels to the matcher; draw the pair it makes, if any.

        Runs in the executor's thread (an image) and in the worker's (labels): the matcher and
        the overlay change under :attr:`_image_lock`, so pairs are drawn in the order made.
        """
        with self._image_lock:
            overflows = self._matcher.overflows
            pair = self._matcher.add(kind, stamp_ns, item)
            overflowed = self._matcher.overflows > overflows
            if pair is not None:
                self._draw(*pair)
        if overflowed:
            self._warn('unmatched', f'{self._matcher.depth} {kind} messages wait for a partner '
                       f'of the same stamp (is {self._image_sub.topic_name} the image the '
                       'features were tracked in?): dropping the oldest')

    def _draw(self, msg: Image, labels: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
        """Publish ``msg`` with the labels drawn on it, on ``image_labels``, with its header."""
        assert self._overlay is not None
        try:
            bgr = to_bgr(image_io.image_to_array(msg), str(msg.encoding))
            drawn = self._overlay.draw(bgr, *labels)
            out = Image(header=msg.header, **image_io.array_to_image_fields(drawn, 'bgr8'))
        except InputError as err:
            self._bad_image(f'malformed image on {self._image_sub.topic_name}, no image_labels '
                            f'for it: {one_line(err)}')
            return
        except Exception as err:  # a bug must not take the node down with it
            with self._lock:
                self.stats.errors += 1
            self._warn('error', f'internal error, image dropped: {type(err).__name__}: {err}')
            return
        with self._quiet_after_shutdown():
            self._image_pub.publish(out)
        with self._lock:
            self.stats.annotated += 1

    def _bad_image(self, text: str) -> None:
        with self._lock:
            self.stats.bad_images += 1
            self.stats.period_bad_images += 1
        self._warn('image', text)

    @contextmanager
    def _quiet_after_shutdown(self) -> Iterator[None]:
        """Let a callback, or the worker, end quietly when the node is being destroyed or the
        context was shut down under it.

        A signal handler or a launch system may shut the context down while a frame is
        published; rclpy then refuses to publish (``RCLError: publisher's context is
        invalid``). Nobody is left to receive the message: that is the end of the frame, not an
        error. The mailbox is closed first: while the context's shutdown destroys the node and
        waits for the worker, it holds the lock that :meth:`Context.ok` takes.
        """
        try:
            yield
        except Exception:
            if not self._mailbox.closed and self.context.ok():
                raise

    def _on_incompatible_qos(self, info: Any) -> None:
        with self._lock:
            self.stats.incompatible_qos = int(info.total_count)
        self._warn('qos', f'{info.total_count} publisher(s) on {self._sub.topic_name} have a QoS '
                   f'this {self.settings.node.qos} subscription cannot match '
                   f'({info.last_policy_kind.name}): nothing is received from them')

    def destroy_node(self) -> None:
        """Stop the worker, then destroy the node as rclpy does.

        The worker ends the frame it is on (its answer is published); the messages waiting for
        it are not answered. A context's shutdown calls this too (rclpy destroys the nodes of a
        context first), maybe from the worker itself.
        """
        mailbox: Mailbox | None = getattr(self, '_mailbox', None)  # None: __init__ failed
        worker: threading.Thread | None = getattr(self, '_worker', None)
        if mailbox is not None:
            mailbox.close()
        if (worker is not None and worker.ident is not None
                and worker is not threading.current_thread()):
            worker.join()
        super().destroy_node()

    # ------------------------------------------------------------------------- services

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response
                  ) -> Trigger.Response:
        del request
        with self._pipeline_lock:  # after the frame the worker is on, if any
            frames = self._pipeline.frames_in_window
            self._pipeline.reset()
            with self._lock:
                self.stats.window = self._pipeline.frames_in_window
                self.stats.reset_requests += 1
        response.success = True
        response.message = f'window emptied ({frames} frames dropped)'
        self.get_logger().info(response.message)
        return response

    def set_parameters_atomically(self, parameter_list: list[Parameter[Any]]
                                  ) -> SetParametersResult:
        """As rclpy's, but an undeclared name is refused naming it and the closest known one.

        The parameter services (``ros2 param set``) come through here; rclpy's own answer names
        no parameter.
        """
        unknown = [p.name for p in parameter_list if not self.has_parameter(p.name)]
        if unknown:
            reason = str(unknown_parameter(unknown[0], params.NAMES))
            return SetParametersResult(successful=False, reason=reason)
        return super().set_parameters_atomically(parameter_list)

    def _on_set_parameters(self, parameters: list[Parameter[Any]]) -> SetParametersResult:
        """Validate a change through the settings builder; apply it from the next frame."""
        values = {**self._values, **{p.name: p.value for p in parameters}}
        try:
            settings = pipeline_settings.build(values)
        except InputError as err:
            return SetParametersResult(successful=False, reason=str(err))
        with self._pipeline_lock:  # after the frame the worker is on, if any
            self._pipeline.reconfigure(settings)
        self._values = values
        return SetParametersResult(successful=True, reason='')

    # ---------------------------------------------------------------------- diagnostics

    def _on_timer(self) -> None:
        with self._quiet_after_shutdown():
            self._check_publisher_types()
            self._diagnostics_pub.publish(self.diagnostics())

    def _check_publisher_types(self) -> None:
        """Warn about publishers of another type on ``features``.

        DDS delivers nothing across types, and rclpy refuses a second subscription of another
        type on the same name in one process, so the graph is the only place to see them.
        """
        topic = self._sub.topic_name
        expected = convert.TYPE_NAMES[self.settings.node.msg_type]
        wrong = [info for info in self.get_publishers_info_by_topic(topic)
                 if info.topic_type != expected]
        with self._lock:
            self.stats.mismatched_publishers = len(wrong)
        if wrong:
            kinds = ', '.join(sorted({info.topic_type for info in wrong}))
            self._warn('type', f'{len(wrong)} publisher(s) send {kinds} on {topic} but msg_type '
                       f'is {self.settings.node.msg_type}: none of their messages arrive')

    def diagnostics(self) -> DiagnosticArray:
        """The status of the last period, and starts a new period."""
        image_values = self._image_values()
        with self._lock:
            stats = self.stats
            now = time.monotonic()
            elapsed = max(now - stats.period_start, 1e-9)
            latency_ms = np.asarray(stats.period_latency_s) * 1e3
            problems = self._problems()
            values = {
                'input rate (Hz)': f'{stats.period_received / elapsed:.2f}',
                'latency mean (ms)': f'{latency_ms.mean():.2f}' if latency_ms.size else '',
                'latency max (ms)': f'{latency_ms.max():.2f}' if latency_ms.size else '',
                'motions': stats.motions,
                'features': stats.features,
                'features segmented': stats.segmented,
                'frames in window': stats.window,
                'messages received': stats.received,
                'messages processed': stats.processed,
                'messages dropped (late)': stats.dropped,
                'malformed messages': stats.malformed,
                'skipped messages': stats.skipped,
                'capped messages': stats.capped,
                'window resets (stamp went back)': stats.resets,
                'reset requests': stats.reset_requests,
                'internal errors': stats.errors,
                'publishers of another type': stats.mismatched_publishers,
                'publishers with incompatible QoS': stats.incompatible_qos,
                **({'camera poses taken': stats.poses, 'camera poses refused': stats.bad_poses,
                    'frames given a camera pose': stats.frames_with_camera}
                   if self.settings.node.pose_topic else {}),
                **({'camera_info taken': stats.camera_infos,
                    'camera_info refused': stats.bad_camera_infos}
                   if self.settings.node.camera_info_topic else {}),
                **image_values,
            }
            stats.period_start, stats.period_received, stats.period_problems = now, 0, 0
            stats.period_dropped = stats.period_bad_images = 0
            stats.period_latency_s = []
        return runner.diagnostics(self, 'motion segmentation', 'segmenting', problems, values)

    def _problems(self) -> list[str]:
        """What makes the period's status WARN (under :attr:`_lock`)."""
        stats, problems = self.stats, []
        if stats.mismatched_publishers:
            problems.append(f'{stats.mismatched_publishers} publisher(s) of another type')
        if stats.incompatible_qos:
            problems.append(f'{stats.incompatible_qos} publisher(s) with incompatible QoS')
        if stats.period_dropped:
            problems.append(f'{stats.period_dropped} message(s) dropped: the node is slower '
                            'than the input')
        if stats.period_problems:
            problems.append(f'{stats.period_problems} message(s) malformed or skipped')
        if stats.period_bad_images:
            problems.append(f'{stats.period_bad_images} image(s) of an unsupported encoding '
                            'or malformed')
        if not stats.period_received:
            problems.append('no input')
        node = self.settings.node
        # Without poses a camera_info only refines the pixels (the camera launch file names
        # one whether the camera publishes it or not): its absence is counted, not warned of.
        if (node.pose_topic and node.camera_info_topic and stats.processed >= UNMATCHED_FRAMES
                and not stats.camera_infos):
            problems.append(f'no valid camera_info on {node.camera_info_topic}: frames get no '
                            'camera')
        elif stats.poses and stats.processed >= UNMATCHED_FRAMES and not stats.frames_with_camera:
            problems.append('no camera pose within pose_tolerance_ms of any feature frame '
                            '(clocks that differ?)')
        return problems

    def _image_values(self) -> dict[str, Any]:
        """The diagnostics of ``image_labels`` (none when ``image_topic`` is empty)."""
        if self._overlay is None:
            return {}
        with self._image_lock, self._lock:
            matcher, stats = self._matcher, self.stats
            return {
                'images received': stats.images,
                'annotated images': stats.annotated,
                'images refused (encoding, malformed)': stats.bad_images,
                'images without labels (dropped)': matcher.dropped['image'],
                'labels without image (dropped)': matcher.dropped['labels'],
                'images waiting': matcher.waiting('image'),
                'labels waiting': matcher.waiting('labels'),
            }


_FLOAT_NAMES = frozenset(item.name for item in params.ALL_SPECS if item.type is float)


def _stamp_text(raw: bytes) -> str:
    """``'<stamp> ns'`` of a serialised feature message, for a warning; never raises."""
    try:
        return f'{cdr.stamp_ns(raw)} ns'
    except InputError:
        return '(unreadable)'


def _ints_as_floats(parameters: list[Parameter[Any]]) -> list[Parameter[Any]]:
    """An integer given for a float parameter is that float (``ros2 param set ... 500``).

    Runs before rclpy's type check, which would refuse it with a reason that names no
    parameter; ``build_configs`` does the same for YAML files and ``--set``.
    """
    return [Parameter(p.name, Parameter.Type.DOUBLE, float(p.value))
            if p.name in _FLOAT_NAMES and p.type_ == Parameter.Type.INTEGER else p
            for p in parameters]


USAGE = """usage: pearl_node [-h] [--ros-args [-r features:=TOPIC] [--params-file FILE]
                  [-p NAME:=VALUE] ...]

Online motion segmentation of tracked features (PEaRL): labels each feature of each message on
`features` with its motion, and passes the background motion's features on. When segmenting is
slower than the input, the node answers the newest message and drops (and counts) those a newer
one replaced; with queue_policy all it answers every message, in arrival order.

topics (relative to the node's namespace; remap `features` to the tracker's topic):
  features (in)          sensor_msgs/msg/PointCloud (VINS-Mono, VINS-Fusion) or PointCloud2
                         (fields id and u, v or x, y), parameter msg_type
  motion_labels (out)    sensor_msgs/msg/PointCloud2, fields id, u, v, label (-1 = outlier or
                         undecided), one point per input feature in input order
  static_features (out)  the input message with the background motion's features only
  image_labels (out)     sensor_msgs/msg/Image, bgr8: the image of parameter image_topic (when
                         set) with its features coloured by motion, the image's header
  /diagnostics (out)     diagnostic_msgs/msg/DiagnosticArray every diagnostics_period s
service:
  ~/reset                std_srvs/srv/Trigger: empty the window

parameters (NAME: default (range), description; set with -p NAME:=VALUE or a parameter file
whose top key is pearl_node or /**; an unknown name is refused):
{parameters}

example:
  pearl_node --ros-args -r features:=/feature_tracker/feature \\
      --params-file config/pearl.yaml -p label_cost:=300.0
"""


def main(args: list[str] | None = None) -> int:
    """``pearl_node`` console script: spin until SIGINT or SIGTERM, then exit 0.

    ``args`` as ``sys.argv`` (the program first; default ``sys.argv``). Exit 1 with one
    ``error:`` line for a bad parameter, parameter file or argument; ``-h`` / ``--help`` prints
    the usage and exits 0 without starting ROS.
    """
    return runner.run(args, 'pearl_node', lambda: USAGE.format(parameters=params.help_text()),
                      lambda files: PearlNode(params_files=files))


if __name__ == '__main__':
    sys.exit(main())
