"""``pearl_replay``: segment a recorded bag with the node's pipeline, write its outputs to a bag.

The command line of :func:`pearl_ros.pipeline.replay.replay` (topics and outputs described
there). Example::

    pearl_replay bags/1R2RCR_g12 --output build/labels --stats build/labels.json

Parameters come from ``--params FILE.yaml`` (the node's ROS parameter file, or a flat mapping of
name: value), then ``--set NAME=VALUE``, then ``--layout`` / ``--camera-id``; all take the names
of ``pearl_node``'s parameters (:mod:`pearl_ros.pipeline.settings`).
"""

from __future__ import annotations

import argparse
import sys
import typing
from collections.abc import Sequence
from pathlib import Path

from pearl_ros.bagio import decode
from pearl_ros.bagio.writer import STORAGES
from pearl_ros.cli.progress import ProgressBar
from pearl_ros.core.errors import PearlError, UsageParser, one_line
from pearl_ros.pipeline import settings as pipeline_settings
from pearl_ros.pipeline.messages import Skipped, SkipWarnings
from pearl_ros.pipeline.replay import (
    INPUT_TOPIC,
    OUTPUT_TOPIC,
    STATIC_TOPIC,
    TRUTH_TOPIC,
    ReplaySettings,
    ReplayStats,
    check_stats_path,
    replay,
    write_stats,
)
from pearl_ros.pipeline.threads import limit_blas_threads


def build_parser() -> argparse.ArgumentParser:
    parser = UsageParser(
        prog='pearl_replay',
        description='Segment the tracked features of a recorded bag with the online segmenter '
        '(the code pearl_node runs) and write motion labels and static features to a new '
        'ROS 2 bag.',
    )
    parser.add_argument('in_bag', type=Path, metavar='IN_BAG',
                        help='ROS 2 bag folder (mcap or sqlite3), .mcap/.db3 file, or ROS 1 .bag')
    parser.add_argument('--output', '-o', type=Path, required=True, metavar='OUT_BAG',
                        help='ROS 2 bag folder to create (not named *.bag)')
    parser.add_argument('--input-topic', default=INPUT_TOPIC,
                        help=f'feature topic, PointCloud or PointCloud2 (default {INPUT_TOPIC})')
    parser.add_argument('--output-topic', default=OUTPUT_TOPIC,
                        help=f'labels topic (default {OUTPUT_TOPIC})')
    parser.add_argument('--static-topic', default=STATIC_TOPIC,
                        help=f'background features topic (default {STATIC_TOPIC})')
    parser.add_argument('--truth-topic', default=TRUTH_TOPIC,
                        help=f'topic copied through when present (default {TRUTH_TOPIC}); '
                        "'' to copy nothing")
    parser.add_argument('--layout', choices=decode.LAYOUTS, default=None,
                        help="PointCloud channel layout (default: the parameter file's, "
                        'else auto)')
    parser.add_argument('--camera-id', type=int, default=None,
                        help='camera kept from a VINS-Fusion cloud (default 0)')
    parser.add_argument('--storage', choices=tuple(STORAGES), default='mcap',
                        help='storage of the output bag (default mcap)')
    parser.add_argument('--params', type=Path, metavar='YAML',
                        help="parameter file: pearl_node's ROS parameter file or name: value")
    parser.add_argument('--set', dest='assignments', action='extend', nargs='+', default=[],
                        metavar='NAME=VALUE', help='set a parameter (after --params)')
    parser.add_argument('--stats', type=Path, metavar='FILE.json',
                        help='write per-frame latency, counts and a summary as JSON')
    parser.add_argument('--force', action='store_true',
                        help='replace OUT_BAG if it is an existing bag')
    parser.add_argument('--progress', choices=('auto', 'on', 'off'), default='auto',
                        help='progress bar on stderr (auto: when stderr is a terminal)')
    return parser


def settings_from_args(args: argparse.Namespace) -> ReplaySettings:
    """The replay's settings from parsed arguments (InputError on a bad parameter)."""
    settings = pipeline_settings.from_sources(
        [args.params] if args.params is not None else [], args.assignments,
        {'layout': args.layout, 'camera_id': args.camera_id})
    return ReplaySettings(input_topic=args.input_topic, output_topic=args.output_topic,
                          static_topic=args.static_topic, truth_topic=args.truth_topic,
                          storage=args.storage, settings=settings)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``pearl_replay``; 0 on success, 1 with one ``error:`` line otherwise."""
    bar: ProgressBar | None = None
    try:
        try:
            args = build_parser().parse_args(argv)
        except SystemExit as done:  # --help
            return int(done.code or 0)
        settings = settings_from_args(args)
        limit_blas_threads()  # as pearl_node runs: the segmenter's second thread needs the core
        if args.stats is not None:
            check_stats_path(args.stats, args.output)
        show = args.progress == 'on' or (args.progress == 'auto' and sys.stderr.isatty())
        bar = ProgressBar(sys.stderr, 'messages') if show else None
        warnings = _Warnings(sys.stderr, bar, args.input_topic)
        stats = replay(args.in_bag, args.output, settings, force=args.force, warn=warnings,
                       progress=bar)
        if bar is not None:
            bar.close()
        warnings.close()
        if args.stats is not None:
            write_stats(args.stats, stats)
    except (PearlError, OSError) as err:
        if bar is not None:
            bar.close()
        print(f'error: {one_line(err, 400)}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        if bar is not None:
            bar.close()
        print('error: interrupted; no output written', file=sys.stderr)
        return 1
    print(_report(stats))
    return 0


def _report(stats: ReplayStats) -> str:
    counts, summary = stats.counts(), stats.summary()
    fps = summary['frames_per_second']
    text = (
        f'wrote {stats.output}: {counts["frames"]} frames of {counts["messages"]} messages '
        f'on {stats.input_topic}, {counts["skipped"]} skipped'
    )
    if counts['copied']:
        text += ', copied ' + ', '.join(f'{t} ({n})' for t, n in counts['copied'].items())
    if fps is not None:
        text += f'; {fps:.1f} frames/s'
    return text


class _Warnings:
    """Skip warnings on stderr (:class:`SkipWarnings`), clearing the progress bar first."""

    def __init__(self, stream: typing.TextIO, bar: ProgressBar | None, topic: str) -> None:
        self._stream = stream
        self._bar = bar
        self._skips = SkipWarnings(topic)

    def __call__(self, index: int, skip: Skipped) -> None:
        line = self._skips.warn(index, skip)
        if line is None:
            return
        if self._bar is not None:
            self._bar.clear()
        print(line, file=self._stream)

    def close(self) -> None:
        """The count, when some warnings were not shown (the rows are in ``--stats``)."""
        line = self._skips.summary()
        if line is not None:
            print(line, file=self._stream)


if __name__ == '__main__':
    sys.exit(main())
