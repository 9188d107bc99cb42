"""``pearl_score``: score the motion labels in a bag against ground truth, frame by frame.

The labels bag is what ``pearl_replay`` writes (``make demo`` writes ``build/demo_labels``), or a
recording of ``pearl_node``'s ``/motion_labels``. Each labels message is scored against the
ground-truth message with the same stamp, from the labels bag itself (``pearl_replay`` copies
``/ground_truth/labels`` into it) or from ``--truth BAG``, usually the input bag. Scoring is
:mod:`pearl_ros.scoring`, the misclassification rate of Hopkins155
(:func:`pearl_ros.core.metrics.misclassification`).

Example::

    pearl_score build/demo_labels
    pearl_score my_recording --truth bags/1R2RCR_g12
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from pearl_ros import scoring
from pearl_ros.bagio import reader
from pearl_ros.core.errors import BagError, PearlError, UsageParser

# Python that reads an output bag, printed by --explain (a test runs it).
SNIPPET = """\
from pathlib import Path
from rosbags.highlevel import AnyReader
from pearl_ros.bagio.decode import decode_fields

with AnyReader([Path('{bag}')]) as bag:
    topic = [c for c in bag.connections if c.topic == '{topic}']
    for connection, _, raw in bag.messages(connections=topic):
        msg = bag.deserialize(raw, connection.msgtype)
        columns = decode_fields(msg, ('id', 'u', 'v', 'label'))  # numpy arrays
        print(msg.header.stamp.sec, msg.header.stamp.nanosec, columns['label'][:10])"""

_CONTENTS = {
    '/motion_labels': 'the labels: one PointCloud2 per input frame, with its header;\n'
                      '    fields id, u, v (pixels), label (the motion; -1 = not labelled)',
    '/static_features': "the input message cut down to the background motion's features",
    '/ground_truth/labels': "the input bag's ground truth, copied: fields id, label",
}


def build_parser() -> argparse.ArgumentParser:
    parser = UsageParser(prog='pearl_score', description=(__doc__ or '').split('\n\n')[0])
    parser.add_argument('labels_bag', type=Path, metavar='LABELS_BAG',
                        help='bag with motion labels (pearl_replay output, a recording)')
    parser.add_argument('--truth', type=Path, metavar='BAG',
                        help='bag with the ground truth (default: LABELS_BAG itself)')
    parser.add_argument('--labels-topic', default=scoring.LABELS_TOPIC,
                        help=f'labels topic (default {scoring.LABELS_TOPIC})')
    parser.add_argument('--truth-topic', default=scoring.TRUTH_TOPIC,
                        help=f'ground-truth topic (default {scoring.TRUTH_TOPIC})')
    parser.add_argument('--summary', action='store_true',
                        help='the overall figures only, no line per frame')
    parser.add_argument('--explain', action='store_true',
                        help='then say what the bag holds and how to read it')
    return parser


def score_bag(labels_bag: Path, truth_bag: Path, labels_topic: str = scoring.LABELS_TOPIC,
              truth_topic: str = scoring.TRUTH_TOPIC) -> list[scoring.FrameScore]:
    """One :class:`~pearl_ros.scoring.FrameScore` per labels message, in recording order.

    Raises
    ------
    BagError
        A bag missing or unreadable, a topic missing, a malformed message.
    InputError
        Labels below -1.
    """
    truth_topics = reader.topics(truth_bag)
    if truth_topic not in truth_topics:
        hint = '; pass --truth BAG (the input bag)' if truth_bag == labels_bag else ''
        raise BagError(f'{truth_bag}: no ground truth topic {truth_topic}{hint}; topics: '
                       f'{", ".join(truth_topics) or "none"}')
    truth = scoring.GroundTruth.from_bag(truth_bag, truth_topic)
    frames = reader.read_ground_truth_frames(labels_bag, labels_topic)  # id and label fields
    if not frames:
        raise BagError(f'{labels_bag}: no message on {labels_topic}')
    return [scoring.score_frame(stamp, ids, labels, truth) for stamp, ids, labels in frames]


def report(scores: Sequence[scoring.FrameScore], per_frame: bool) -> list[str]:
    """The printout: a line per frame (unless not ``per_frame``), then the summary."""
    lines = []
    if per_frame:
        lines.append('frame  features  labelled  motions (true)  error  '
                     '(error: misclassification of the frame\'s features; n/a = nothing '
                     'labelled or no ground truth)')
        outliers = any(row.true_outliers for row in scores)
        for index, row in enumerate(scores):
            motions = f'{row.motions} ({row.true_motions})' if row.scored else f'{row.motions}'
            error = '   n/a' if row.labelled == 0 else scoring.percent(row.error)
            line = (f'{index:5d}  {row.features:8d}  {row.labelled:8d}  {motions:>14}  '
                    f'{error}')
            if outliers:
                line += f'  outliers labelled -1: {row.outliers_found}/{row.true_outliers}'
            lines.append(line)
    return lines + scoring.summary_lines(scoring.summarise(scores))


def explain(bag: Path, labels_topic: str) -> list[str]:
    """What the bag holds (topics, message counts) and how to look at it."""
    counts = reader.topic_counts(bag)
    lines = ['', f'{bag} is a ROS 2 bag; its topics (messages):']
    for topic, (msgtype, count) in counts.items():
        lines.append(f'  {topic} ({count}): {_CONTENTS.get(topic, msgtype)}')
    lines += [
        'To look at it:',
        f'  score it frame by frame:  {_command(sys.argv[0], "pearl_score")} {bag}',
        f'  read it in Python ({_command(sys.executable, "python")}; rosbags, no ROS needed):',
        *('    ' + line for line in SNIPPET.format(bag=bag, topic=labels_topic).splitlines()),
        f'  on a ROS 2 install:  ros2 bag info {bag};  ros2 bag play {bag}',
    ]
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``pearl_score``; 0 on success, 1 with one ``error:`` line otherwise."""
    parser = build_parser()
    try:
        try:
            args = parser.parse_args(argv)
        except SystemExit as done:  # --help
            return int(done.code or 0)
        truth = args.truth if args.truth is not None else args.labels_bag
        scores = score_bag(args.labels_bag, truth, args.labels_topic, args.truth_topic)
        lines = [f'{args.labels_bag}: {args.labels_topic} against {args.truth_topic} of {truth}']
        lines += report(scores, per_frame=not args.summary)
        if args.explain:
            lines += explain(args.labels_bag, args.labels_topic)
    except PearlError as err:
        print(f'error: {err}', file=sys.stderr)
        return 1
    print('\n'.join(lines))
    return 0


def _command(path: str, name: str) -> str:
    """``path`` as a user in this folder types it, if it is the command ``name``; else ``name``."""
    if not Path(path).name.startswith(name):
        return name
    relative = os.path.relpath(path)
    return relative if not relative.startswith('..') else path


if __name__ == '__main__':
    sys.exit(main())
