"""``pearl_play``: replay a bag's feature messages into a running ``pearl_node``, live, and score
the labels that come back against the bag's ground truth as they arrive.

Not a ``ros2 bag play``: it publishes one message, waits for that message's ``motion_labels``
(matched by stamp), then the next, at most at ``--rate`` Hz. So nothing is lost to queue depths
and every frame's answer is accounted for, whatever the node's speed. With ``--poses TOPIC``
the bag's camera poses on that topic are published too, on the same name, each before the
first frame whose stamp is not earlier than its own (a node with ``pose_topic`` takes them),
and so are its camera's ``sensor_msgs/msg/CameraInfo`` with ``--camera-info TOPIC`` (for a node
with ``camera_info_topic``).

Example (``make demo`` does this; ``--msg-type`` prints the bag's feature message type, which
the node must be told)::

    pearl_node --ros-args -r features:=/feature_tracker/feature \\
        -p msg_type:=$(pearl_play bags/1R2RCR_g12 --msg-type) &
    pearl_play bags/1R2RCR_g12
"""

from __future__ import annotations

import argparse
import functools
import operator
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import PointCloud2

from pearl_ros import scoring
from pearl_ros.bagio import cdr, decode, reader
from pearl_ros.core.errors import BagError, PearlError, UsageParser, one_line
from pearl_ros.pipeline.messages import MessagePipeline, Skipped, SkipWarnings
from pearl_ros.ros import convert

FEATURE_TOPIC = '/feature_tracker/feature'
TRUTH_TOPIC = scoring.TRUTH_TOPIC

LEGEND = """\
One line per message of the bag, as pearl_node answered it:
  features   tracked features in the message
  motions    motions the node found in this frame (true: how many the ground truth has)
  error      misclassification: the share of this frame's features labelled wrongly, after
             the node's motion numbers are matched one-to-one to the true ones (a feature
             labelled - counts as wrong); n/a = nothing labelled yet, or no ground truth
  labels     one character per feature, in the message's order: 0-9, a-z = the motion the
             node gave it (its own numbering), - = not labelled (an outlier, or a feature it
             cannot place yet); "+N more" = N features not shown (--width 0 shows all)
The first frame has no labels: a motion needs two frames to be seen."""


@dataclass(frozen=True)
class BagFeatures:
    """The feature messages of a bag, ready to publish.

    Attributes
    ----------
    msg_type : str
        ``'PointCloud'`` or ``'PointCloud2'``: the node's ``msg_type`` parameter for them.
    messages : list
        rclpy messages, in recording order.
    skipped : list of (int, Skipped)
        Position on the topic of each message ``pearl_node`` would skip, and why.
    """

    msg_type: str
    messages: list[Any]
    skipped: list[tuple[int, Skipped]] = field(default_factory=list)


@dataclass(frozen=True)
class BagPoses:
    """The camera poses of a bag (or its camera_info), ready to publish beside its feature
    messages.

    Attributes
    ----------
    topic : str
    msg_class : type, rclpy's ``Odometry``, ``PoseStamped`` or ``CameraInfo``
    stamps : list of int, ns, header stamps, in recording order
    raw : list of bytes, each message's ROS 2 CDR
    """

    topic: str
    msg_class: Any
    stamps: list[int]
    raw: list[bytes]


def load_poses(path: str | Path, topic: str, feature_topic: str = FEATURE_TOPIC,
               classes: dict[str, Any] | None = None) -> BagPoses:
    """The messages of the pose ``topic`` of a bag (``nav_msgs/msg/Odometry`` or
    ``geometry_msgs/msg/PoseStamped``; or those of ``classes``, type name -> rclpy class, such
    as :data:`~pearl_ros.ros.convert.CAMERA_INFO_CLASSES`), as ROS 2 CDR with their stamps.

    Raises
    ------
    BagError
        No such topic, or another type on it; a message that cannot be read.
    """
    classes = classes or convert.POSE_CLASSES
    kinds = reader.topics(path)
    if topic not in kinds:
        raise BagError(f'{path}: no topic {topic!r}; topics: {", ".join(kinds) or "none"}')
    if kinds[topic] not in classes:
        raise BagError(f'{path}: topic {topic} has type {kinds[topic]}, expected '
                       f'{" or ".join(classes)}')
    stamps, raw = [], []
    with reader.open_feature_stream(path, feature_topic, (topic,)) as stream:
        for item in stream:
            if not isinstance(item, reader.CopiedMessage):
                continue
            if item.cdr is None:
                raise BagError(f'{path}: a message on {topic} cannot be read: {item.error}')
            msg: Any = reader.TYPESTORE.deserialize_cdr(item.cdr, item.msgtype)
            stamps.append(decode.stamp_ns(msg.header))
            raw.append(item.cdr)
    return BagPoses(topic, classes[kinds[topic]], stamps, raw)


def bag_msg_type(path: str | Path, topic: str = FEATURE_TOPIC) -> str:
    """``'PointCloud'`` or ``'PointCloud2'``: what ``topic`` carries in the bag at ``path``.

    Raises
    ------
    BagError
        Missing or corrupt bag, no such topic, another type or several types on it.
    """
    kinds = reader.topics(path)
    if topic not in kinds:
        raise BagError(f'{path}: no topic {topic!r}; topics: {", ".join(kinds) or "none"}')
    name = kinds[topic].removeprefix('sensor_msgs/msg/')
    if name not in convert.MSG_CLASSES:
        raise BagError(f'{path}: topic {topic} has type {kinds[topic]}, expected '
                       f'{" or ".join(convert.TYPE_NAMES.values())}')
    return name


def load_bag(path: str | Path, topic: str = FEATURE_TOPIC) -> BagFeatures:
    """The messages of ``topic`` as rclpy messages, from a ROS 2 bag or a ROS 1 ``.bag`` file.

    Each message is read as ``pearl_replay`` reads it, serialised to ROS 2 CDR
    (:func:`pearl_ros.bagio.cdr.serialize`) and handed to rclpy's deserialiser: every field and
    channel comes through, and a ROS 1 message (whose bytes are not CDR) loses only its
    header's ``seq``. Messages the node would
    skip (:meth:`~pearl_ros.pipeline.messages.MessagePipeline.read`: malformed, empty) are left
    out and listed in ``skipped``, with the node's reason.

    Raises
    ------
    BagError
        Missing or corrupt bag, no such topic, not a PointCloud / PointCloud2 topic, several
        types on it, or no message that can be played.
    """
    msg_type = bag_msg_type(path, topic)
    msg_class = convert.MSG_CLASSES[msg_type]
    pipeline = MessagePipeline()  # pearl_node's defaults: layout auto, camera 0
    messages, skipped = [], []
    with reader.open_feature_stream(path, topic) as stream:
        for item in stream:
            if not isinstance(item, reader.FeatureMessage):
                continue
            played = _playable(item, pipeline, msg_class)
            if isinstance(played, Skipped):
                skipped.append((item.index, played))
            else:
                messages.append(played)
    if not messages:
        first = f' (first: {skipped[0][1].reason})' if skipped else ''
        raise BagError(f'{path}: no message on {topic} can be played{first}')
    return BagFeatures(msg_type, messages, skipped)


def _playable(item: reader.FeatureMessage, pipeline: MessagePipeline, msg_class: Any
              ) -> Any:
    """``item`` as an rclpy message, or the :class:`Skipped` pearl_node would give it."""
    if item.msg is None:
        return Skipped.because(item.error or 'unreadable')
    features = pipeline.read(item.msg)
    if isinstance(features, Skipped):
        return features
    try:
        raw = cdr.serialize(item.msg)
    except (TypeError, ValueError, AttributeError, OverflowError) as err:
        return Skipped.because(f'cannot convert to ROS 2: {one_line(err)}')
    return deserialize_message(raw, msg_class)


def bag_messages(path: str | Path, topic: str = FEATURE_TOPIC) -> list[Any]:
    """The playable messages of ``topic`` in a bag, in recording order (:func:`load_bag`)."""
    return load_bag(path, topic).messages


@dataclass(frozen=True)
class Answer:
    """The ``motion_labels`` that came back for one published message."""

    stamp_ns: int
    ids: np.ndarray  # (N,) int64
    labels: np.ndarray  # (N,) int64, -1 = outlier or undecided


class Player(Node):
    """Publishes feature messages on ``features`` and collects the node's ``motion_labels``.

    Parameters
    ----------
    messages : sequence of PointCloud or PointCloud2 (rclpy), in stamp order
    features_topic, labels_topic : str
        Where the node listens and answers.
    poses, camera_info : BagPoses, optional
        The bag's camera poses and camera_info, each message published (:class:`Beside`,
        the attributes ``poses`` and ``camera_info``) before the first frame not earlier.
    """

    def __init__(self, messages: Sequence[Any], *, features_topic: str = 'features',
                 labels_topic: str = 'motion_labels', node_name: str = 'pearl_play',
                 poses: BagPoses | None = None, camera_info: BagPoses | None = None,
                 **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        if not messages:
            raise PearlError('no messages to play')
        self.messages = list(messages)
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.publisher = self.create_publisher(type(self.messages[0]), features_topic, qos)
        self.poses = None if poses is None else Beside(self, poses)
        self.camera_info = None if camera_info is None else Beside(self, camera_info)
        self.answers: dict[int, Answer] = {}
        self._sub = self.create_subscription(PointCloud2, labels_topic, self._on_labels, qos)

    def _on_labels(self, msg: PointCloud2) -> None:
        ids = decode.integer_ids(decode.decode_fields(msg, ('id',))['id'], 'ids')
        labels = decode.integer_ids(decode.decode_fields(msg, ('label',))['label'], 'labels')
        stamp = decode.stamp_ns(msg.header)
        self.answers[stamp] = Answer(stamp, ids, labels)

    # Shadows rclpy's Node.wait_for_node(name, timeout), which the player never uses; the node
    # tests call this one by its name.
    def wait_for_node(self, executor: Executor, timeout_s: float,  # type: ignore[override]
                      settle_s: float = 0.5) -> bool:
        """Spin until the node's subscription and its labels publisher are both matched, then
        ``settle_s`` more.

        A match seen from this side does not mean the node has matched this publisher yet; a
        message sent in between is dropped by the node's best-effort reader (``make demo`` lost
        its first frame about one run in ten). The settling time lets discovery finish.
        """
        matched = spin_until(executor, lambda: self.publisher.get_subscription_count() > 0
                             and self._sub.get_publisher_count() > 0, timeout_s)
        if matched:
            spin_until(executor, lambda: False, settle_s)
        return matched

    def subscribed_types(self) -> list[str]:
        """Message types of the subscriptions on the features topic (any type, matched or not)."""
        infos = self.get_subscriptions_info_by_topic(self.publisher.topic_name)
        return sorted({info.topic_type for info in infos})

    def play(self, executor: Executor, *, rate_hz: float = 0.0, timeout_s: float = 5.0,
             on_answer: Callable[[int, Any, Answer | None], None] | None = None
             ) -> list[Answer | None]:
        """Publish each message and wait for its labels (``None`` if none came in ``timeout_s``).

        ``rate_hz`` > 0 also keeps at least ``1 / rate_hz`` s between publications.
        """
        out: list[Answer | None] = []
        for index, msg in enumerate(self.messages):
            sent = time.monotonic()
            stamp = decode.stamp_ns(msg.header)
            for beside in (self.camera_info, self.poses):
                if beside is not None:
                    beside.send_until(stamp)
            self.publisher.publish(msg)
            answered = functools.partial(operator.contains, self.answers, stamp)  # stamp in
            spin_until(executor, answered, timeout_s)
            answer = self.answers.get(stamp)
            out.append(answer)
            if on_answer is not None:
                on_answer(index, msg, answer)
            if rate_hz > 0:
                spin_until(executor, lambda: False, 1.0 / rate_hz - (time.monotonic() - sent))
        return out




class Beside:
    """A bag's messages of one topic (its camera poses, its camera_info) played beside its
    features by a :class:`Player` ``node``, on the same topic name."""

    def __init__(self, node: Node, messages: BagPoses) -> None:
        self.messages = messages
        qos = QoSProfile(depth=len(messages.raw) + 1, reliability=ReliabilityPolicy.RELIABLE)
        self.publisher = node.create_publisher(messages.msg_class, messages.topic, qos)
        self.sent = 0

    def send_until(self, stamp_ns: int) -> None:
        """Publish the messages not sent yet whose stamps are at most ``stamp_ns``: each
        frame's pose reaches the node before the frame (a pose that comes after its frame
        serves too, for the frames that follow)."""
        messages = self.messages
        while self.sent < len(messages.raw) and messages.stamps[self.sent] <= stamp_ns:
            self.publisher.publish(messages.raw[self.sent])
            self.sent += 1


def spin_until(executor: Executor, done: Callable[[], bool], timeout_s: float) -> bool:
    """Spin ``executor`` until ``done()`` or ``timeout_s`` s passed; returns ``done()``."""
    deadline = time.monotonic() + timeout_s
    while not done():
        left = deadline - time.monotonic()
        if left <= 0:
            return done()
        executor.spin_once(timeout_sec=min(left, 0.05))
    return True


def frame_line(index: int, row: scoring.FrameScore, labels: np.ndarray, width: int) -> str:
    """One frame of the printout (see :data:`LEGEND`)."""
    true = f' (true {row.true_motions})' if row.scored else ''
    error = '   n/a' if row.labelled == 0 else scoring.percent(row.error)
    return (f'frame {index:3d}  {row.features:4d} features  {row.motions} motions{true}  '
            f'error {error}  {scoring.label_string(labels, width)}')


def build_parser() -> argparse.ArgumentParser:
    parser = UsageParser(prog='pearl_play', description=(__doc__ or '').split('\n\n')[0])
    parser.add_argument('bag', help='ROS 2 bag folder, .mcap/.db3 file, or ROS 1 .bag file, '
                        'with feature messages')
    parser.add_argument('--msg-type', action='store_true',
                        help="print the feature topic's message type (PointCloud or PointCloud2: "
                        "pearl_node's msg_type parameter) and exit")
    parser.add_argument('--topic', default=FEATURE_TOPIC, help='feature topic in the bag')
    parser.add_argument('--truth-topic', default=TRUTH_TOPIC,
                        help="ground truth in the bag ('' for none)")
    parser.add_argument('--features', default=FEATURE_TOPIC,
                        help='topic to publish on (what pearl_node subscribes)')
    parser.add_argument('--labels', default='/motion_labels', help="pearl_node's labels topic")
    parser.add_argument('--poses', default='', metavar='TOPIC',
                        help="the bag's camera pose topic (nav_msgs/msg/Odometry, "
                        'geometry_msgs/msg/PoseStamped or PoseWithCovarianceStamped), published '
                        'on the same name before '
                        "each frame, for a pearl_node with pose_topic; empty = none")
    parser.add_argument('--camera-info', default='', metavar='TOPIC',
                        help="the bag's sensor_msgs/msg/CameraInfo topic, published on the same "
                        'name before each frame, for a pearl_node with camera_info_topic; '
                        'empty = none')
    parser.add_argument('--rate', type=float, default=10.0, help='Hz, at most (0 = no limit)')
    parser.add_argument('--timeout', type=float, default=5.0,
                        help='s, wait for the node (discovery) and for each answer')
    parser.add_argument('--width', type=int, default=60,
                        help='labels shown per frame (0 = all)')
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """``pearl_play BAG``: exit 0 when every message was answered, 1 otherwise."""
    parser = build_parser()
    try:
        try:
            args, ros_args = parser.parse_known_args(argv)
        except SystemExit as done:  # --help
            return int(done.code or 0)
        if args.msg_type:
            print(bag_msg_type(args.bag, args.topic))
            return 0
        bag = load_bag(args.bag, args.topic)
        truth = _truth(args.bag, args.truth_topic)
        poses = load_poses(args.bag, args.poses, args.topic) if args.poses else None
        info = (load_poses(args.bag, args.camera_info, args.topic, convert.CAMERA_INFO_CLASSES)
                if args.camera_info else None)
    except PearlError as err:
        print(f'error: {err}', file=sys.stderr)
        return 1
    warnings = SkipWarnings(args.topic)  # not played: pearl_node would skip them
    lines = [warnings.warn(index, skip) for index, skip in bag.skipped] + [warnings.summary()]
    for line in filter(None, lines):
        print(line, file=sys.stderr)
    rclpy.init(args=ros_args)
    player = None
    try:
        executor = SingleThreadedExecutor()
        player = Player(bag.messages, features_topic=args.features, labels_topic=args.labels,
                        poses=poses, camera_info=info)
        executor.add_node(player)
        if not player.wait_for_node(executor, args.timeout):
            print(f'error: {_not_found(player, bag.msg_type, args)}', file=sys.stderr)
            return 1
        return _play(player, executor, bag, truth, args)
    except (KeyboardInterrupt, ExternalShutdownException):
        print('error: interrupted', file=sys.stderr)
        return 1
    finally:
        if player is not None:
            player.destroy_node()
        rclpy.try_shutdown()


def _truth(bag: str, topic: str) -> scoring.GroundTruth | None:
    """The bag's ground truth, or None if it has no such topic (or ``topic`` is empty)."""
    if not topic or topic not in reader.topics(bag):
        return None
    return scoring.GroundTruth.from_bag(bag, topic)


def _play(player: Player, executor: Executor, bag: BagFeatures,
          truth: scoring.GroundTruth | None, args: argparse.Namespace) -> int:
    """Play every message, print a line per frame and the summary; the exit code."""
    source = 'no ground truth' if truth is None else (
        f'ground truth from {args.truth_topic}'
        + (', per frame (features change motion)' if truth.changes_over_time else ''))
    print(f'{args.bag}: {len(bag.messages)} {bag.msg_type} messages, played into pearl_node on '
          f'{args.features}\nlabels from {args.labels}; {source}')
    print(LEGEND, flush=True)
    rows: list[scoring.FrameScore] = []

    def show(index: int, msg: Any, answer: Answer | None) -> None:
        del msg
        if answer is None:
            print(f'frame {index:3d}  no labels within {args.timeout} s', flush=True)
            return
        row = scoring.score_frame(answer.stamp_ns, answer.ids, answer.labels, truth)
        rows.append(row)
        print(frame_line(index, row, answer.labels, args.width), flush=True)

    answers = player.play(executor, rate_hz=args.rate, timeout_s=args.timeout, on_answer=show)
    missing = sum(answer is None for answer in answers)
    print(f'{len(answers) - missing}/{len(answers)} frames answered by pearl_node')
    for beside, what in ((player.poses, 'camera poses'), (player.camera_info, 'camera_info')):
        if beside is not None:
            print(f'{beside.sent} {what} played on {beside.messages.topic}')
    if truth is not None:
        for line in scoring.summary_lines(scoring.summarise(rows)):
            print(line)
    return 0 if missing == 0 else 1


def _not_found(player: Player, msg_type: str, args: argparse.Namespace) -> str:
    """Why no pearl_node matched within the timeout, with the fix when it is a type mismatch."""
    wanted = convert.TYPE_NAMES[msg_type]
    others = [kind for kind in player.subscribed_types() if kind != wanted]
    if others:
        return (f'pearl_node subscribes {", ".join(others)} on {args.features} but the bag has '
                f'{wanted}: start it with -p msg_type:={msg_type}')
    return (f'no pearl_node subscribed to {args.features} and publishing {args.labels} '
            f'within {args.timeout} s')


if __name__ == '__main__':
    sys.exit(main())
