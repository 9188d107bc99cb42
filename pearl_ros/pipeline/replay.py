"""The replay engine: a recorded bag through :class:`~pearl_ros.pipeline.messages.MessagePipeline`
(the code ``pearl_node`` runs) into a new bag.

Reads the tracked features of a ROS 2 bag (mcap or sqlite3) or a ROS 1 ``.bag`` file and writes
a ROS 2 bag with, for every input message the pipeline labels, the node's two outputs at the
input's log time and with the input's header:

- ``/motion_labels``: ``sensor_msgs/msg/PointCloud2``, fields ``id``, ``u``, ``v``, ``label``
  (:func:`pearl_ros.bagio.encode.motion_labels`), one point per input feature in input order;
- ``/static_features``: the input message cut down to the background motion's features
  (:func:`pearl_ros.bagio.encode.static_features`).

``/ground_truth/labels`` is copied through when the input has it, so the output bag can be
scored on its own. A message the pipeline skips is counted and reported (never dropped
silently); the rest of the bag is processed. ``pearl_replay`` (:mod:`pearl_ros.cli.replay`) is
its command line.
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pearl_ros.bagio import cdr, encode
from pearl_ros.bagio.reader import (
    POINTCLOUD2,
    TYPESTORE,
    CopiedMessage,
    FeatureStream,
    open_feature_stream,
)
from pearl_ros.bagio.writer import is_bag, open_output_bag
from pearl_ros.core.errors import BagError, InputError
from pearl_ros.online.config import setting_values
from pearl_ros.pipeline.messages import Labelled, MessagePipeline, Skipped
from pearl_ros.pipeline.poses import CAMERA_INFO, POSE_TYPES
from pearl_ros.pipeline.settings import PIPELINE_NAMES, Settings
from pearl_ros.pipeline.threads import limit_blas_threads

INPUT_TOPIC = '/feature_tracker/feature'
OUTPUT_TOPIC = '/motion_labels'
STATIC_TOPIC = '/static_features'
TRUTH_TOPIC = '/ground_truth/labels'

# Outputs are built as pearl_ros.bagio.cdr messages and written as their CDR bytes.
MESSAGE_TYPES = cdr.TYPES

# (input index, skip) -> None: told of every skipped input message, and of copies that failed.
WarnCallback = Callable[[int, Skipped], None]


@dataclass(frozen=True)
class ReplaySettings:
    """Everything a replay needs besides the two paths (defaults as the command line's).

    ``settings`` are the pipeline's; of the node's own parameters the replay applies
    :data:`~pearl_ros.pipeline.settings.PIPELINE_NAMES` (layout, camera, caps, background).
    """

    input_topic: str = INPUT_TOPIC
    output_topic: str = OUTPUT_TOPIC
    static_topic: str = STATIC_TOPIC
    truth_topic: str = TRUTH_TOPIC
    storage: str = 'mcap'
    settings: Settings = field(default_factory=Settings)


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
        One row per input message not processed: ``index``, ``log_time_ns``, ``kind``,
        ``reason``.
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
    poses: int = 0  # camera poses taken from pose_topic
    bad_poses: int = 0  # camera poses that could not be read or used
    frames_with_camera: int = 0  # feature frames that got a camera pose
    camera_infos: int = 0  # camera_info messages taken from camera_info_topic
    bad_camera_infos: int = 0  # camera_info messages that could not be read or used
    messages: int = 0
    wall_s: float = 0.0

    def counts(self) -> dict[str, Any]:
        reasons = Counter(row['kind'] for row in self.skipped)
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
            'poses': self.poses,
            'bad_poses': self.bad_poses,
            'frames_with_camera': self.frames_with_camera,
            'camera_infos': self.camera_infos,
            'bad_camera_infos': self.bad_camera_infos,
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


def replay(
    in_bag: str | Path,
    out_bag: str | Path,
    settings: ReplaySettings | None = None,
    *,
    force: bool = False,
    warn: WarnCallback | None = None,
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
        ``warn(index, skip)`` for every skipped input message (``index`` on the input topic)
        and every message of a copied topic that could not be converted (``index`` -1).
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
    check_paths(in_bag, out_bag, force)
    _check_topics(settings)
    warn = warn or (lambda index, skip: None)
    start = time.perf_counter()
    pipeline = MessagePipeline(settings.settings, MESSAGE_TYPES)
    copy_topics: tuple[str, ...] = (settings.truth_topic,) if settings.truth_topic else ()
    pose_topic = settings.settings.node.pose_topic
    info_topic = settings.settings.node.camera_info_topic
    if pose_topic:  # read for the pipeline, and copied as the truth is
        copy_topics += (pose_topic,)
    if info_topic and info_topic not in copy_topics:
        copy_topics += (info_topic,)
    with open_feature_stream(in_bag, settings.input_topic, copy_topics) as stream:
        stats = ReplayStats(
            input=str(in_bag), output=str(out_bag), input_topic=settings.input_topic,
            input_types=list(stream.msgtypes), parameters=_parameters(settings.settings),
            messages=stream.count,
        )
        if len(stream.msgtypes) > 1:
            raise BagError(
                f'{in_bag}: topic {settings.input_topic} carries several types '
                f'{"|".join(stream.msgtypes)}; static_features needs one'
            )
        with open_output_bag(out_bag, storage=settings.storage, replace=force) as out:
            out.add_topic(settings.output_topic, POINTCLOUD2)
            out.add_topic(settings.static_topic, stream.msgtypes[0])
            for topic, msgtype in stream.copied.items():
                out.add_topic(topic, msgtype)
            _run(stream, pipeline, settings, out, stats, warn, progress)
            stats.frames_with_camera = pipeline.frames_with_camera
            if info_topic and not stats.camera_infos:
                without = 'the poses and the lens' if pose_topic else 'the lens'
                warn(-1, Skipped('camera_info_missing', f'no valid {CAMERA_INFO} on '
                                 f'{info_topic}: segmented without {without}', False))
            elif stats.poses and not stats.frames_with_camera:
                warn(-1, Skipped('pose_unmatched', f'none of the {stats.poses} poses on '
                                 f'{pose_topic} is within pose_tolerance_ms of a feature '
                                 'frame (clocks that differ?): segmented without them', False))
            if stats.skipped and not stats.frames:
                # Nothing to show for the run: most likely the wrong topic or layout.
                raise BagError(
                    f'none of the {len(stats.skipped)} messages on {settings.input_topic} could '
                    f'be read (first: {stats.skipped[0]["reason"]})'
                )
            stats.copied = {topic: out.counts[topic] for topic in stream.copied}
    stats.wall_s = time.perf_counter() - start
    return stats


def _run(stream: FeatureStream, pipeline: MessagePipeline, settings: ReplaySettings, out: Any,
         stats: ReplayStats, warn: WarnCallback,
         progress: Callable[[int, int], None] | None) -> None:
    """Every message of ``stream`` through ``pipeline`` into ``out``, in recording order."""
    done = 0
    node = settings.settings.node
    for item in stream:
        if isinstance(item, CopiedMessage):
            if item.topic in (node.pose_topic, node.camera_info_topic):
                _take_recorded(item, pipeline, stats, warn)
            _copy(item, out, stats, warn)
            continue
        if item.msg is None:
            outcome: Labelled | Skipped = Skipped.because(item.error or 'unreadable')
        else:
            outcome = pipeline.process(item.msg, _ros2_header(item.msg.header))
        _record(item.index, item.log_time_ns, outcome, settings, out, stats, warn)
        done += 1
        if progress is not None:
            progress(done, stream.count)  # counts feature messages only


def _take_recorded(item: CopiedMessage, pipeline: MessagePipeline, stats: ReplayStats,
                   warn: WarnCallback) -> None:
    """Hand a recorded camera pose (``pose_topic``) or camera_info (``camera_info_topic``) to
    the pipeline; count it, or warn about it."""
    node = pipeline.settings.node
    if item.topic == node.pose_topic:
        msg = _recorded(item, POSE_TYPES[node.pose_type], 'pose',
                        f' (pose_type {node.pose_type})')
        take, good, bad = pipeline.add_pose, 'poses', 'bad_poses'
    else:
        msg = _recorded(item, CAMERA_INFO, 'camera_info')
        take, good, bad = pipeline.add_camera_info, 'camera_infos', 'bad_camera_infos'
    skip = msg if isinstance(msg, Skipped) else take(msg)
    counter = good if skip is None else bad
    setattr(stats, counter, getattr(stats, counter) + 1)
    if skip is not None:
        warn(-1, skip)


def _recorded(item: CopiedMessage, expected: str, kind: str, hint: str = '') -> Any:
    """The message of a recorded ``item`` of type ``expected``, or the :class:`Skipped`
    (``kind``) of one that is unreadable or of another type (``hint`` ends that line)."""
    if item.cdr is None:
        return Skipped(kind, f'{kind}: {item.error}', True)
    if item.msgtype != expected:
        return Skipped(kind, f'{kind}: {item.topic} carries {item.msgtype}, not '
                       f'{expected}{hint}', True)
    try:
        return TYPESTORE.deserialize_cdr(item.cdr, item.msgtype)
    except Exception as err:  # rosbags raises several kinds on damaged bytes
        return Skipped(kind, f'{kind}: {cdr.unreadable(item.msgtype, err)}', True)


def _check_topics(settings: ReplaySettings) -> None:
    topics = {settings.output_topic, settings.static_topic, settings.truth_topic}
    if len(topics) < 3:
        raise InputError('output, static and ground-truth topics must all differ')
    if settings.input_topic in (settings.output_topic, settings.static_topic):
        raise InputError(f'input topic {settings.input_topic} is also an output topic')


def _copy(item: CopiedMessage, out: Any, stats: ReplayStats, warn: WarnCallback) -> None:
    if item.cdr is None:
        stats.not_copied += 1
        reason = f'{item.topic} message at {item.log_time_ns} ns not copied: {item.error}'
        warn(-1, Skipped('not_copied', reason, True))
        return
    out.write_cdr(item.topic, item.log_time_ns, item.cdr)


def _record(index: int, log_time_ns: int, outcome: Labelled | Skipped,
            settings: ReplaySettings, out: Any, stats: ReplayStats, warn: WarnCallback) -> None:
    """Write a labelled message's outputs and its row, or count and report a skipped one."""
    if isinstance(outcome, Skipped):
        stats.skipped.append({'index': index, 'log_time_ns': log_time_ns,
                              'kind': outcome.kind, 'reason': outcome.reason})
        warn(index, outcome)
        return
    out.write_cdr(settings.output_topic, log_time_ns, cdr.serialize(outcome.labels_msg))
    out.write_cdr(settings.static_topic, log_time_ns, cdr.serialize(outcome.static_msg))
    result = outcome.result
    stats.frames.append({
        'index': index,
        'stamp_ns': outcome.stamp_ns,
        'features': int(outcome.ids.size),
        'segmented': int(outcome.segmented.sum()),
        'labelled': int(np.count_nonzero(outcome.labels != encode.UNLABELLED)),
        'motions': result.motions,
        'static': int(outcome.static.sum()),
        'latency_ms': result.latency_s * 1e3,
        'reset': bool(result.reset),
        'warm': bool(result.warm),
        'model': result.model,
        'window_frames': result.frames,
    })


def replay_throughput(
    paths: Iterable[str | Path], settings: ReplaySettings | None = None
) -> list[dict[str, Any]]:
    """Replay each bag into a temporary folder and measure it: one row per bag.

    Rows: ``bag``, ``frames``, ``features`` (mean per frame), ``skipped``, ``wall_s``,
    ``fps`` (end to end, reading and writing included), ``segmenter_fps`` (time inside the
    segmenter only), ``latency_p50_ms``, ``latency_p99_ms``, ``latency_max_ms``.
    A benchmark, not a test: the figures depend on the machine and on ``budget_ms``. It sets
    BLAS to one thread, as ``pearl_replay`` runs (:func:`limit_blas_threads`).
    """
    limit_blas_threads()
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


def check_paths(in_bag: Path, out_bag: Path, force: bool) -> None:
    """Raise BagError unless ``in_bag`` exists and ``out_bag`` may be written."""
    if not (in_bag.exists() or in_bag.is_symlink()):
        raise BagError(f'bag not found: {in_bag}')
    if out_bag.exists() or out_bag.is_symlink():
        if not force:
            raise BagError(f'{out_bag} exists; pass --force to replace it')
        if not is_bag(out_bag):
            raise BagError(f'refusing to replace {out_bag}: it is not a bag (no metadata.yaml)')
        if out_bag.resolve() == in_bag.resolve():
            raise BagError(f'output {out_bag} is the input bag')


def check_stats_path(stats: Path, out_bag: Path) -> None:
    """Fail before the replay, not after it, when the stats file cannot be written."""
    if not stats.parent.is_dir():
        raise InputError(f'--stats folder does not exist: {stats.parent}')
    if stats.is_dir():
        raise InputError(f'--stats {stats} is a folder')
    if stats.resolve() == out_bag.resolve():
        raise InputError('--stats and --output are the same path')


def write_stats(path: Path, stats: ReplayStats) -> None:
    """``stats`` as JSON at ``path``, through a temporary file in the same folder, renamed."""
    handle, name = tempfile.mkstemp(prefix=f'.{path.name}.', suffix='.partial', dir=path.parent)
    try:
        with os.fdopen(handle, 'w') as out:
            json.dump(stats.as_dict(), out, indent=1, allow_nan=False)
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
    return cdr.Header(cdr.Time(int(header.stamp.sec), int(header.stamp.nanosec)),
                      str(header.frame_id))


def _parameters(settings: Settings) -> dict[str, Any]:
    """What shaped the replay: every setting of the segmenter (``solver.NAME`` included) and the
    pipeline's node parameters."""
    values = setting_values(*settings.configs)
    values.update(settings.values(PIPELINE_NAMES))
    return values


def _quantiles(values: np.ndarray) -> dict[str, float | None]:
    if values.size == 0:
        return {'mean': None, 'p50': None, 'p99': None, 'max': None}
    return {
        'mean': float(values.mean()),
        'p50': float(np.percentile(values, 50)),
        'p99': float(np.percentile(values, 99)),
        'max': float(values.max()),
    }
