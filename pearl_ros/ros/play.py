"""``pearl_play``: replay a bag's feature messages into a running ``pearl_node``, live, and score
the labels that come back against the bag's ground truth as they arrive.

Not a ``ros2 bag play``: it publishes one message, waits for that message's ``motion_labels``
(matched by stamp), then the next, at most at ``--rate`` Hz. So nothing is lost to queue depths
and every frame's answer is accounted for, whatever the node's speed.

Example (``make demo`` does this)::

    pearl_node --ros-args -r features:=/feature_tracker/feature &
    pearl_play bags/1R2RCR_g12
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from rclpy.executors import Executor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rosbags.highlevel import AnyReader
from sensor_msgs.msg import PointCloud2

from pearl_ros.bagio import decode, reader
from pearl_ros.core.errors import BagError, PearlError
from pearl_ros.core.metrics import misclassification
from pearl_ros.ros import convert

FEATURE_TOPIC = '/feature_tracker/feature'
TRUTH_TOPIC = '/ground_truth/labels'
_SYMBOLS = '0123456789abcdefghijklmnopqrstuvwxyz'


def bag_messages(path: str | Path, topic: str = FEATURE_TOPIC) -> list[Any]:
    """The messages of ``topic`` in a bag, in recording order, as rclpy message objects.

    The bag's own bytes are handed to rclpy's deserialiser, so the node sees exactly what was
    recorded (points, every channel, velocities), not a re-encoding.

    Raises
    ------
    BagError
        Missing or corrupt bag, no such topic, not a PointCloud / PointCloud2 topic.
    """
    kinds = reader.topics(path)  # BagError for a missing or unreadable bag
    if topic not in kinds:
        raise BagError(f'{path}: no topic {topic!r}; topics: {", ".join(kinds) or "none"}')
    name = kinds[topic].removeprefix('sensor_msgs/msg/')
    if name not in convert.MSG_CLASSES:
        raise BagError(f'{path}: topic {topic} has type {kinds[topic]}, expected '
                       f'{" or ".join(convert.TYPE_NAMES.values())}')
    msg_class = convert.MSG_CLASSES[name]
    try:
        with AnyReader([Path(path)], default_typestore=reader.TYPESTORE) as bag:
            connections = [c for c in bag.connections if c.topic == topic]
            return [deserialize_message(bytes(raw), msg_class)
                    for _, _, raw in bag.messages(connections=connections)]
    except Exception as err:  # rosbags and the storage libraries raise many kinds
        raise BagError(f'cannot read bag {path}: {" ".join(str(err).split())}') from err


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
    """

    def __init__(self, messages: Sequence[Any], *, features_topic: str = 'features',
                 labels_topic: str = 'motion_labels', node_name: str = 'pearl_play',
                 **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        if not messages:
            raise PearlError('no messages to play')
        self.messages = list(messages)
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.publisher = self.create_publisher(type(self.messages[0]), features_topic, qos)
        self.answers: dict[int, Answer] = {}
        self._sub = self.create_subscription(PointCloud2, labels_topic, self._on_labels, qos)

    def _on_labels(self, msg: PointCloud2) -> None:
        ids = decode.integer_ids(decode.decode_fields(msg, ('id',))['id'], 'ids')
        labels = decode.integer_ids(decode.decode_fields(msg, ('label',))['label'], 'labels')
        stamp = decode.stamp_ns(msg.header)
        self.answers[stamp] = Answer(stamp, ids, labels)

    def wait_for_node(self, executor: Executor, timeout_s: float, settle_s: float = 0.5
                      ) -> bool:
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
            self.publisher.publish(msg)
            spin_until(executor, lambda stamp=stamp: stamp in self.answers, timeout_s)
            answer = self.answers.get(stamp)
            out.append(answer)
            if on_answer is not None:
                on_answer(index, msg, answer)
            if rate_hz > 0:
                spin_until(executor, lambda: False, 1.0 / rate_hz - (time.monotonic() - sent))
        return out


def spin_until(executor: Executor, done: Callable[[], bool], timeout_s: float) -> bool:
    """Spin ``executor`` until ``done()`` or ``timeout_s`` s passed; returns ``done()``."""
    deadline = time.monotonic() + timeout_s
    while not done():
        left = deadline - time.monotonic()
        if left <= 0:
            return done()
        executor.spin_once(timeout_sec=min(left, 0.05))
    return True


def label_string(labels: np.ndarray, width: int = 64) -> str:
    """One character per label (``-`` for -1, ``?`` beyond 35), cut at ``width``."""
    text = ''.join('-' if k < 0 else _SYMBOLS[k] if k < len(_SYMBOLS) else '?'
                   for k in labels.tolist())
    return text if len(text) <= width else text[: width - 3] + '...'


def score(answer: Answer, truth: dict[int, int]) -> float | None:
    """Misclassification of the labelled features that have ground truth (None if none have)."""
    known = np.array([int(i) in truth for i in answer.ids.tolist()], dtype=bool)
    if not known.any():
        return None
    gt = np.array([truth[int(i)] for i in answer.ids[known].tolist()], dtype=np.int64)
    return misclassification(answer.labels[known], gt)


def main(argv: Sequence[str] | None = None) -> int:
    """``pearl_play BAG``: exit 0 when every message was answered, 1 otherwise."""
    parser = argparse.ArgumentParser(prog='pearl_play', description=__doc__.split('\n\n')[0])
    parser.add_argument('bag', help='ROS 2 bag folder (or ROS 1 .bag) with feature messages')
    parser.add_argument('--topic', default=FEATURE_TOPIC, help='feature topic in the bag')
    parser.add_argument('--truth-topic', default=TRUTH_TOPIC, help='ground truth in the bag')
    parser.add_argument('--features', default=FEATURE_TOPIC,
                        help='topic to publish on (what pearl_node subscribes)')
    parser.add_argument('--labels', default='/motion_labels', help="pearl_node's labels topic")
    parser.add_argument('--rate', type=float, default=10.0, help='Hz, at most (0 = no limit)')
    parser.add_argument('--timeout', type=float, default=5.0,
                        help='s, wait for the node (discovery) and for each answer')
    args, ros_args = parser.parse_known_args(argv)

    try:
        messages = bag_messages(args.bag, args.topic)
        kinds = reader.topics(args.bag)
        truth = reader.read_ground_truth(args.bag, args.truth_topic) \
            if args.truth_topic in kinds else {}
    except PearlError as err:
        print(f'error: {err}', file=sys.stderr)
        return 1

    rclpy.init(args=ros_args)
    player = None
    try:
        executor = SingleThreadedExecutor()
        player = Player(messages, features_topic=args.features, labels_topic=args.labels)
        executor.add_node(player)
        if not player.wait_for_node(executor, args.timeout):
            print(f'error: no pearl_node subscribed to {args.features} within {args.timeout} s',
                  file=sys.stderr)
            return 1
        print(f'{args.bag}: {len(messages)} messages -> {args.features}, labels <- {args.labels}')

        def show(index: int, msg: Any, answer: Answer | None) -> None:
            del msg
            if answer is None:
                print(f'frame {index:3d}  no labels within {args.timeout} s')
                return
            error = score(answer, truth)
            motions = np.unique(answer.labels[answer.labels >= 0]).size
            shown = '   n/a' if error is None else f'{100 * error:5.1f}%'
            print(f'frame {index:3d}  {answer.ids.size:4d} features  {motions} motions  '
                  f'error {shown}  {label_string(answer.labels)}', flush=True)

        answers = player.play(executor, rate_hz=args.rate, timeout_s=args.timeout,
                              on_answer=show)
        missing = sum(answer is None for answer in answers)
        last = next((a for a in reversed(answers) if a is not None), None)
        final = score(last, truth) if last is not None else None
        summary = 'n/a' if final is None else f'{100 * final:.1f}%'
        print(f'{len(answers) - missing}/{len(answers)} frames answered; '
              f'misclassification on the last frame: {summary}')
        # The output bag of the same frames is pearl_replay's job (make demo runs it next).
        return 0 if missing == 0 else 1
    except KeyboardInterrupt:
        return 1
    finally:
        if player is not None:
            player.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    sys.exit(main())
