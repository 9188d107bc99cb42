"""``pearl_replay``: run the online segmenter over a recorded bag and write its outputs to a bag.

Reads the tracked features of a ROS 2 bag (mcap or sqlite3) or a ROS 1 ``.bag`` file, feeds them
frame by frame to :class:`~pearl_ros.online.segmenter.OnlineSegmenter` (the code the node runs),
and writes a ROS 2 bag with, for every input message it can read, the node's two outputs at the
input's log time and with the input's header:

- ``/motion_labels``: ``sensor_msgs/msg/PointCloud2``, fields ``id``, ``u``, ``v``, ``label``
  (:func:`pearl_ros.bagio.encode.motion_labels`), one point per input feature in input order;
- ``/static_features``: the input message cut down to the background motion's features
  (:func:`pearl_ros.bagio.encode.static_features`).

``/ground_truth/labels`` is copied through when the input has it, so the output bag can be
scored on its own. A malformed input message is skipped, reported on stderr and counted (never
dropped silently); the rest of the bag is processed.

Example::

    pearl_replay bags/1R2RCR_g12 --output /tmp/labels --stats /tmp/labels.json

Parameters come from ``--params FILE.yaml`` (the node's ROS parameter file, or a flat mapping of
name: value) and then ``--set NAME=VALUE``; both take the names of ``pearl_node``'s parameters.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import tempfile
import time
import typing
from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pearl_ros.bagio import decode, encode
from pearl_ros.bagio.reader import (
    POINTCLOUD2,
    TYPESTORE,
    CopiedMessage,
    FeatureMessage,
    open_feature_stream,
)
from pearl_ros.bagio.writer import STORAGES, is_bag, open_output_bag
from pearl_ros.core.config import PearlConfig
from pearl_ros.core.errors import BagError, InputError, PearlError
from pearl_ros.frontend import NODE_SPECS
from pearl_ros.online.config import OnlineConfig, build_configs, known_names, parse_assignments
from pearl_ros.online.segmenter import OnlineSegmenter

INPUT_TOPIC = '/feature_tracker/feature'
OUTPUT_TOPIC = '/motion_labels'
STATIC_TOPIC = '/static_features'
TRUTH_TOPIC = '/ground_truth/labels'

MESSAGE_TYPES = encode.MessageTypes.from_typestore(TYPESTORE)
_Header: Any = TYPESTORE.types['std_msgs/msg/Header']
_Time: Any = TYPESTORE.types['builtin_interfaces/msg/Time']

# pearl_node's own parameters (NODE_SPECS). A node parameter file may hold them: the ones that
# change what is computed apply here too, the ones about live transport (subscription type, QoS,
# timers) have no meaning in a replay.
NODE_APPLIED = ('layout', 'camera_id', 'max_features', 'background_motion')
NODE_IGNORED = ('msg_type', 'qos', 'qos_depth', 'diagnostics_period')
_NODE_DEFAULTS: dict[str, Any] = {
    item.name: item.default for item in NODE_SPECS if item.name in NODE_APPLIED}
_ROS_NODE_NAMES = ('pearl_node', '/pearl_node', '/**')

_MAX_WARNINGS = 20  # skipped messages reported one by one on stderr; the rest only counted


@dataclass
class ReplayStats:
    """What a replay did: per-frame rows, counts and a summary (``--stats`` writes it as JSON).

    Attributes
    ----------
    frames : list of dict
        One row per frame processed: ``index`` (position on the input topic), ``stamp_ns``,
        ``features``, ``segmented`` (fed to the segmenter: at most ``max_features``),
        ``labelled`` (label != -1), ``motions``, ``static`` (features on
        static_features), ``latency_ms`` (time in ``OnlineSegmenter.process``), ``reset``,
        ``warm``, ``model``, ``window_frames`` (frames the models were fitted over).
    skipped : list of dict
        One row per input message not processed: ``index``, ``log_time_ns``, ``reason``.
    """

    input: str
    output: str
    input_topic: str
    input_types: list[str]
    parameters: dict[str, Any]
    frames: list[dict[str, Any]] = field(default_factory=list)
    skipped: list[dict[str, Any]] = field(default_factory=list)
    copied: dict[str, int] = field(default_factory=dict)
    not_copied: int = 0
    messages: int = 0
    wall_s: float = 0.0

    def counts(self) -> dict[str, Any]:
        reasons = Counter(_reason_kind(row['reason']) for row in self.skipped)
        return {
            'messages': self.messages,
            'frames': len(self.frames),
            'features': int(sum(row['features'] for row in self.frames)),
            'labelled': int(sum(row['labelled'] for row in self.frames)),
            'skipped': len(self.skipped),
            'skip_reasons': dict(sorted(reasons.items())),
            'resets': int(sum(row['reset'] for row in self.frames)),
            'copied': dict(self.copied),
            'not_copied': self.not_copied,
        }

    def summary(self) -> dict[str, Any]:
        latency = np.array([row['latency_ms'] for row in self.frames], dtype=np.float64)
        frames = len(self.frames)
        busy = float(latency.sum()) / 1e3
        return {
            'wall_s': self.wall_s,
            # End to end: reading, decoding, segmenting, encoding and writing, per wall second.
            'frames_per_second': frames / self.wall_s if self.wall_s > 0 else None,
            # The segmenter alone: frames per second of time spent inside process().
            'segmenter_frames_per_second': frames / busy if busy > 0 else None,
            'latency_ms': _quantiles(latency),
        }

    def as_dict(self) -> dict[str, Any]:
        return {
            'input': self.input,
            'output': self.output,
            'input_topic': self.input_topic,
            'input_types': self.input_types,
            'parameters': self.parameters,
            'counts': self.counts(),
            'summary': self.summary(),
            'frames': self.frames,
            'skipped': self.skipped,
        }


@dataclass(frozen=True)
class ReplaySettings:
    """Everything a replay needs besides the two paths (defaults as the command line's)."""

    input_topic: str = INPUT_TOPIC
    output_topic: str = OUTPUT_TOPIC
    static_topic: str = STATIC_TOPIC
    truth_topic: str = TRUTH_TOPIC
    layout: str = 'auto'
    camera_id: int = 0
    max_features: int = 2000
    background_motion: int = -1
    storage: str = 'mcap'
    config: PearlConfig = field(default_factory=PearlConfig)
    online: OnlineConfig = field(default_factory=OnlineConfig)


def replay(
    in_bag: str | Path,
    out_bag: str | Path,
    settings: ReplaySettings | None = None,
    *,
    force: bool = False,
    warn: Callable[[str], None] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> ReplayStats:
    """Segment every frame of ``in_bag`` and write the labels to the new bag ``out_bag``.

    Parameters
    ----------
    in_bag : str or Path
        ROS 2 bag folder, ``.mcap`` / ``.db3`` file, or ROS 1 ``.bag`` file.
    out_bag : str or Path
        ROS 2 bag folder to create; appears only once complete (module docstring for topics).
    settings : ReplaySettings, optional
    force : bool
        Replace ``out_bag`` if it is an existing bag.
    warn : callable, optional
        Called with a one-line message for every skipped input message.
    progress : callable, optional
        Called as ``progress(done, total)`` with input messages handled so far.

    Returns
    -------
    ReplayStats

    Raises
    ------
    BagError
        Missing or corrupt input, unknown topic, wrong type, no readable message at all,
        existing output without ``force``, failure to write. Nothing is left at ``out_bag``
        then (an existing bag stays as it was).
    InputError
        Bad settings.
    """
    settings = settings or ReplaySettings()
    in_bag, out_bag = Path(in_bag), Path(out_bag)
    _check_paths(in_bag, out_bag, force)
    topics = {settings.output_topic, settings.static_topic, settings.truth_topic}
    if len(topics) < 3:
        raise InputError('output, static and ground-truth topics must all differ')
    if settings.input_topic in (settings.output_topic, settings.static_topic):
        raise InputError(f'input topic {settings.input_topic} is also an output topic')
    warn = warn or (lambda _: None)
    start = time.perf_counter()
    segmenter = OnlineSegmenter(settings.config, settings.online)
    copy_topics = (settings.truth_topic,) if settings.truth_topic else ()
    with open_feature_stream(
        in_bag, settings.input_topic, settings.layout, settings.camera_id, copy_topics
    ) as stream:
        stats = ReplayStats(
            input=str(in_bag),
            output=str(out_bag),
            input_topic=settings.input_topic,
            input_types=list(stream.msgtypes),
            parameters=_parameters(settings),
            messages=stream.count,
        )
        if len(stream.msgtypes) > 1:
            raise BagError(
                f'{in_bag}: topic {settings.input_topic} carries several types '
                f'{"|".join(stream.msgtypes)}; static_features needs one'
            )
        total = stream.count  # progress counts feature messages only
        with open_output_bag(out_bag, storage=settings.storage, replace=force) as out:
            out.add_topic(settings.output_topic, POINTCLOUD2)
            out.add_topic(settings.static_topic, stream.msgtypes[0])
            for topic, msgtype in stream.copied.items():
                out.add_topic(topic, msgtype)
            done = 0
            for item in stream:
                if isinstance(item, CopiedMessage):
                    if item.cdr is None:
                        stats.not_copied += 1
                        warn(f'{item.topic} message at {item.log_time_ns} ns not copied: '
                             f'{item.error}')
                        continue
                    out.write_cdr(item.topic, item.log_time_ns, item.cdr)
                    continue
                reason = _replay_one(item, segmenter, settings, out, stats)
                if reason is not None:
                    stats.skipped.append(
                        {'index': item.index, 'log_time_ns': item.log_time_ns, 'reason': reason}
                    )
                    warn(f'message {item.index} on {settings.input_topic} skipped: {reason}')
                done += 1
                if progress is not None:
                    progress(done, total)
            if stats.skipped and not stats.frames:
                # Nothing to show for the run: most likely the wrong topic or layout.
                first = stats.skipped[0]['reason']
                raise BagError(
                    f'none of the {len(stats.skipped)} messages on {settings.input_topic} could '
                    f'be read (first: {first})'
                )
            stats.copied = {topic: out.counts[topic] for topic in stream.copied}
    stats.wall_s = time.perf_counter() - start
    return stats


def _replay_one(
    item: FeatureMessage,
    segmenter: OnlineSegmenter,
    settings: ReplaySettings,
    out: Any,
    stats: ReplayStats,
) -> str | None:
    """Segment one input message and write its outputs; the reason if it was skipped."""
    if item.frame is None:
        return item.error or 'unreadable'
    frame = item.frame
    # As the node: above max_features, a subsample chosen by a hash of the ids is segmented.
    segmented = encode.subsample_mask(frame.ids, settings.max_features)
    try:
        result = segmenter.process(frame.stamp_ns, frame.ids[segmented], frame.uv[segmented])
    except InputError as err:  # e.g. a stamp equal to the previous one; state unchanged
        return ' '.join(str(err).split())
    labels = np.full(frame.ids.size, encode.UNLABELLED, dtype=np.int64)
    labels[segmented] = result.labels
    background = None if settings.background_motion < 0 else settings.background_motion
    keep = encode.static_mask(labels, background)
    header = _ros2_header(item.msg.header)
    labels_msg = encode.motion_labels(header, frame.ids, frame.uv, labels, MESSAGE_TYPES)
    static_msg = encode.static_features(
        item.msg, keep, MESSAGE_TYPES, settings.layout, settings.camera_id
    )
    static_msg.header = header
    out.write(settings.output_topic, item.log_time_ns, labels_msg)
    out.write(settings.static_topic, item.log_time_ns, static_msg)
    stats.frames.append({
        'index': item.index,
        'stamp_ns': frame.stamp_ns,
        'features': int(frame.ids.size),
        'segmented': int(segmented.sum()),
        'labelled': int(np.count_nonzero(labels != encode.UNLABELLED)),
        'motions': result.motions,
        'static': int(keep.sum()),
        'latency_ms': result.latency_s * 1e3,
        'reset': bool(result.reset),
        'warm': bool(result.warm),
        'model': result.model,
        'window_frames': result.frames,
    })
    return None


def replay_throughput(
    paths: Iterable[str | Path], settings: ReplaySettings | None = None
) -> list[dict[str, Any]]:
    """Replay each bag into a temporary folder and measure it: one row per bag.

    Rows: ``bag``, ``frames``, ``features`` (mean per frame), ``skipped``, ``wall_s``,
    ``fps`` (end to end, reading and writing included), ``segmenter_fps`` (time inside the
    segmenter only), ``latency_p50_ms``, ``latency_p99_ms``, ``latency_max_ms``.
    A benchmark, not a test: the figures depend on the machine and on ``budget_ms``.
    """
    rows = []
    for path in paths:
        path = Path(path)
        with tempfile.TemporaryDirectory(prefix='pearl_replay.') as scratch:
            stats = replay(path, Path(scratch) / 'out', settings)
        counts, summary = stats.counts(), stats.summary()
        latency = summary['latency_ms']
        rows.append({
            'bag': path.name or str(path),
            'frames': counts['frames'],
            'features': counts['features'] / max(counts['frames'], 1),
            'skipped': counts['skipped'],
            'wall_s': summary['wall_s'],
            'fps': summary['frames_per_second'],
            'segmenter_fps': summary['segmenter_frames_per_second'],
            'latency_p50_ms': latency['p50'],
            'latency_p99_ms': latency['p99'],
            'latency_max_ms': latency['max'],
        })
    return rows


def load_params(path: str | Path) -> dict[str, Any]:
    """Parameter name -> value from a YAML file.

    Accepts the node's ROS 2 parameter file (``pearl_node: {ros__parameters: {...}}``, or
    ``/**:`` for every node; nested namespaces joined with dots) or a flat ``name: value``
    mapping. Names are not checked here (:func:`settings_from` does).

    Raises
    ------
    InputError
        Unreadable file, not YAML, not a mapping, or a ROS file without a ``pearl_node`` entry.
    """
    from ruamel.yaml import YAML, YAMLError  # a dependency of rosbags

    path = Path(path)
    try:
        text = path.read_text()
    except OSError as err:
        raise InputError(f'cannot read parameter file {path}: {err.strerror or err}') from err
    try:
        data = YAML(typ='safe', pure=True).load(text)
    except (YAMLError, ValueError) as err:
        detail = ' '.join(str(err).split())
        raise InputError(f'parameter file {path} is not valid YAML: {detail[:200]}') from err
    if data is None:
        return {}
    if not isinstance(data, Mapping):
        raise InputError(f'parameter file {path} must hold a mapping, got {type(data).__name__}')
    nodes = {name: entry for name, entry in data.items()
             if isinstance(entry, Mapping) and 'ros__parameters' in entry}
    if nodes:
        chosen = [nodes[name] for name in _ROS_NODE_NAMES if name in nodes]
        if not chosen and len(nodes) == 1:
            chosen = list(nodes.values())
        if not chosen:
            raise InputError(
                f'parameter file {path} has ros__parameters for {sorted(nodes)}, none for '
                'pearl_node'
            )
        params = chosen[0]['ros__parameters'] or {}
        if not isinstance(params, Mapping):
            raise InputError(f'parameter file {path}: ros__parameters must be a mapping')
        return _flatten(params)
    return _flatten(data)


def settings_from(
    params: Mapping[str, Any],
    assignments: Sequence[str] = (),
    **overrides: Any,
) -> ReplaySettings:
    """A :class:`ReplaySettings` from file parameters, ``NAME=VALUE`` strings and keywords.

    ``assignments`` win over ``params``; keyword ``overrides`` (command-line options such as
    ``layout``) win over both, a None keyword is not given.

    Raises
    ------
    InputError
        An unknown parameter name or a bad value (one line, naming it).
    """
    values = dict(params)
    values.update(_parse_assignments(assignments))
    known = set(known_names())
    unknown = sorted(set(values) - known - set(NODE_APPLIED) - set(NODE_IGNORED))
    if unknown:
        raise _unknown(unknown[0])
    config, online = build_configs({k: v for k, v in values.items() if k in known})
    node = {**_NODE_DEFAULTS, **{k: values[k] for k in NODE_APPLIED if k in values}}
    node.update({k: v for k, v in overrides.items() if v is not None and k in node})
    node['layout'] = decode.check_layout(_typed(node['layout'], str, 'layout'))
    node['camera_id'] = decode.check_camera_id(_typed(node['camera_id'], int, 'camera_id'))
    background = _typed(node['background_motion'], int, 'background_motion')
    if background < -1:
        raise InputError(f'background_motion must be >= -1, got {background}')
    max_features = _typed(node['max_features'], int, 'max_features')
    if max_features < 1:
        raise InputError(f'max_features must be >= 1, got {max_features}')
    rest = {k: v for k, v in overrides.items() if v is not None and k not in node}
    return ReplaySettings(config=config, online=online, layout=node['layout'],
                          camera_id=node['camera_id'], max_features=max_features,
                          background_motion=background, **rest)


class _Parser(argparse.ArgumentParser):
    """Usage errors raise InputError, so that main prints one ``error:`` line and returns 1."""

    def error(self, message: str) -> typing.NoReturn:
        raise InputError(message)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
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
                        help='PointCloud channel layout (default: the parameter file\'s, '
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


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``pearl_replay``; 0 on success, 1 with one ``error:`` line otherwise."""
    parser = build_parser()
    bar: _ProgressBar | None = None
    try:
        try:
            args = parser.parse_args(argv)
        except SystemExit as done:  # --help
            return int(done.code or 0)
        params = load_params(args.params) if args.params is not None else {}
        settings = settings_from(
            params, args.assignments, layout=args.layout, camera_id=args.camera_id,
            input_topic=args.input_topic, output_topic=args.output_topic,
            static_topic=args.static_topic, truth_topic=args.truth_topic, storage=args.storage,
        )
        if args.stats is not None:
            _check_stats_path(args.stats, args.output)
        show = args.progress == 'on' or (args.progress == 'auto' and sys.stderr.isatty())
        bar = _ProgressBar(sys.stderr) if show else None
        warnings = _Warnings(sys.stderr, bar)
        stats = replay(args.in_bag, args.output, settings, force=args.force, warn=warnings,
                       progress=bar)
        if bar is not None:
            bar.close()
        warnings.close()
        if args.stats is not None:
            _write_json(args.stats, stats.as_dict())
    except (PearlError, OSError) as err:
        if bar is not None:
            bar.close()
        print(f'error: {_one_line(err)}', file=sys.stderr)
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


class _ProgressBar:
    """``[#####-----] done/total`` on one terminal line, redrawn at most 10 times a second."""

    def __init__(self, stream: typing.TextIO, width: int = 30) -> None:
        self._stream = stream
        self._width = width
        self._last = 0.0
        self._start = time.perf_counter()
        self._shown = False

    def __call__(self, done: int, total: int) -> None:
        now = time.perf_counter()
        if done < total and now - self._last < 0.1:
            return
        self._last = now
        filled = self._width * done // total if total else self._width
        rate = done / (now - self._start) if now > self._start else 0.0
        self._stream.write(f'\r[{"#" * filled}{"-" * (self._width - filled)}] '
                           f'{done}/{total} messages {rate:6.1f}/s')
        self._stream.flush()
        self._shown = True

    def clear(self) -> None:
        """End the bar's line so that a message can be printed below it."""
        if self._shown:
            self._stream.write('\n')
            self._stream.flush()
            self._shown = False

    def close(self) -> None:
        self.clear()


class _Warnings:
    """Skipped-message warnings on stderr: the first ones in full, then only counted."""

    def __init__(self, stream: typing.TextIO, bar: _ProgressBar | None) -> None:
        self._stream = stream
        self._bar = bar
        self.count = 0

    def __call__(self, message: str) -> None:
        self.count += 1
        if self.count > _MAX_WARNINGS:
            return
        if self._bar is not None:
            self._bar.clear()
        print(f'warning: {message}', file=self._stream)
        if self.count == _MAX_WARNINGS:
            print('warning: further skips are counted, not shown (see --stats)',
                  file=self._stream)

    def close(self) -> None:
        if self.count > _MAX_WARNINGS:
            print(f'warning: {self.count} messages skipped in all', file=self._stream)


def _check_paths(in_bag: Path, out_bag: Path, force: bool) -> None:
    if not (in_bag.exists() or in_bag.is_symlink()):
        raise BagError(f'bag not found: {in_bag}')
    if out_bag.exists() or out_bag.is_symlink():
        if not force:
            raise BagError(f'{out_bag} exists; pass --force to replace it')
        if not is_bag(out_bag):
            raise BagError(f'refusing to replace {out_bag}: it is not a bag (no metadata.yaml)')
        if out_bag.resolve() == in_bag.resolve():
            raise BagError(f'output {out_bag} is the input bag')


def _check_stats_path(stats: Path, out_bag: Path) -> None:
    """Fail before the replay, not after it, when the stats file cannot be written."""
    if not stats.parent.is_dir():
        raise InputError(f'--stats folder does not exist: {stats.parent}')
    if stats.is_dir():
        raise InputError(f'--stats {stats} is a folder')
    if stats.resolve() == out_bag.resolve():
        raise InputError('--stats and --output are the same path')


def _write_json(path: Path, data: dict[str, Any]) -> None:
    """Write ``data`` to ``path`` through a temporary file in the same folder, then rename."""
    handle, name = tempfile.mkstemp(prefix=f'.{path.name}.', suffix='.partial', dir=path.parent)
    try:
        with os.fdopen(handle, 'w') as out:
            json.dump(data, out, indent=1, allow_nan=False)
            out.write('\n')
        # mkstemp makes the file private (0600); give it the mode a plain open() would.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(name, 0o666 & ~umask)
        os.replace(name, path)
    except BaseException:
        Path(name).unlink(missing_ok=True)
        raise


def _ros2_header(header: Any) -> Any:
    """A ROS 2 ``std_msgs/msg/Header`` with ``header``'s stamp and frame (drops ROS 1 ``seq``)."""
    return _Header(
        stamp=_Time(sec=int(header.stamp.sec), nanosec=int(header.stamp.nanosec)),
        frame_id=str(header.frame_id),
    )


def _parameters(settings: ReplaySettings) -> dict[str, Any]:
    values = {**dataclasses.asdict(settings.config), **dataclasses.asdict(settings.online)}
    values.update(layout=settings.layout, camera_id=settings.camera_id,
                  max_features=settings.max_features,
                  background_motion=settings.background_motion)
    return values


def _parse_assignments(items: Sequence[str]) -> dict[str, Any]:
    """``NAME=VALUE`` strings; the node-only names typed here, the rest by parse_assignments."""
    node_items, config_items = [], []
    for item in items:
        name = item.partition('=')[0].strip()
        if name in NODE_APPLIED + NODE_IGNORED:
            node_items.append(item)
        elif '=' in item and name and name not in known_names():
            raise _unknown(name)
        else:
            config_items.append(item)
    values = parse_assignments(config_items)
    for item in node_items:
        name, _, text = item.partition('=')
        name, text = name.strip(), text.strip()
        default = _NODE_DEFAULTS.get(name)
        if isinstance(default, int):
            try:
                values[name] = int(text)
            except ValueError as err:
                raise InputError(f'invalid value for {name}: {text!r} is not int') from err
        else:
            values[name] = text
    return values


def _unknown(name: str) -> InputError:
    names = ', '.join(known_names() + NODE_APPLIED)
    return InputError(f'unknown parameter {name!r} (known: {names})')


def _typed(value: Any, kind: type, name: str) -> Any:
    if isinstance(value, bool) or not isinstance(value, kind):
        raise InputError(f'{name} must be of type {kind.__name__}, got {value!r}')
    return value


def _flatten(params: Mapping[str, Any], prefix: str = '') -> dict[str, Any]:
    """Nested ROS parameter namespaces as dotted names."""
    out: dict[str, Any] = {}
    for name, value in params.items():
        key = f'{prefix}{name}'
        if isinstance(value, Mapping):
            out.update(_flatten(value, key + '.'))
        else:
            out[key] = value
    return out


def _quantiles(values: np.ndarray) -> dict[str, float | None]:
    if values.size == 0:
        return {'mean': None, 'p50': None, 'p99': None, 'max': None}
    return {
        'mean': float(values.mean()),
        'p50': float(np.percentile(values, 50)),
        'p99': float(np.percentile(values, 99)),
        'max': float(values.max()),
    }


def _reason_kind(reason: str) -> str:
    """A short class of a skip reason, for the counts (the full text stays in ``skipped``)."""
    lowered = reason.lower()
    for kind, words in (
        ('deserialise', ('cannot deserialise',)),
        ('empty', ('empty cloud',)),
        ('stamp', ('stamp',)),
        ('duplicate_ids', ('repeats feature id', 'duplicate ids')),
        ('non_finite', ('non-finite',)),
        ('ids', ('ids above', 'must be integers')),
        ('layout', ('channel', 'field', 'layout', 'row_step', 'data has', 'datatype')),
    ):
        if any(word in lowered for word in words):
            return kind
    return 'other'


def _one_line(err: BaseException) -> str:
    text = ' '.join(str(err).split()) or type(err).__name__
    return text if len(text) <= 400 else text[:397] + '...'


if __name__ == '__main__':
    sys.exit(main())
