"""Streaming benchmarks behind ``pearl_bench stream`` and ``pearl_bench latency``.

``stream`` feeds every Hopkins155 sequence (Tron & Vidal, CVPR 2007) frame by frame, at 30 Hz
stamps, through :class:`~pearl_ros.online.segmenter.OnlineSegmenter`, exactly as the node does,
and measures the labels of every frame against the ground truth. ``latency`` times synthetic
streams at several sizes, paced at a frame rate on a simulated clock (:func:`paced`), and
profiles one (:func:`profile_one`).
"""

from __future__ import annotations

import dataclasses
import math
import statistics
import time
import tracemalloc
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from pearl_ros.core.config import PearlConfig
from pearl_ros.core.errors import InputError, PearlError
from pearl_ros.evaluation.latency import (
    LatencyStats,
    accuracy,
    latency_stats,
    make_stream,
    percentiles,
)
from pearl_ros.online.config import OnlineConfig

FRAME_NS = 33_333_333
_COLD_FRAMES = 3  # frames 0-2 of a stream: nothing to fit, then the cold two-view and affine fits


@dataclass(frozen=True)
class StreamRow:
    """One sequence streamed through the online segmenter.

    Attributes
    ----------
    name, category : str
    motions_true, motions_found : int, the latter in the final frame
    points, frames : int
    final_pct : float, misclassification of the final frame, percent
    second_half_pct : float, mean misclassification over the frames of the second half, percent
    changes_pct : float, percent of features whose label changes between consecutive labelled
        frames (the true motion of a Hopkins point never changes)
    latencies_ms : tuple of float, per frame
    switches : int, identity switches of the true motions over the frames
        (:class:`~pearl_ros.core.metrics.LabelIdentity`)
    """

    name: str
    category: str
    motions_true: int
    motions_found: int
    points: int
    frames: int
    final_pct: float
    second_half_pct: float
    changes_pct: float
    latencies_ms: tuple[float, ...]
    switches: int = 0


@dataclass(frozen=True)
class StreamTask:
    root: str
    name: str
    config: PearlConfig
    online: OnlineConfig


def stream_one(task: StreamTask) -> StreamRow:
    """Stream one Hopkins sequence; top level so that worker processes can import it."""
    from pearl_ros.core.metrics import LabelIdentity, misclassification
    from pearl_ros.datasets.hopkins import load_sequence
    from pearl_ros.online.segmenter import OnlineSegmenter

    try:
        seq = load_sequence(task.root, task.name)
    except PearlError as err:
        raise type(err)(f'{task.name}: {err}') from err
    segmenter = OnlineSegmenter(task.config, task.online)
    ids = np.arange(seq.tracks.shape[1])
    errors, latencies, changes = [], [], []
    identity = LabelIdentity()
    previous = None
    result = None
    for f, uv in enumerate(seq.tracks):
        result = segmenter.process(1_000_000_000 + f * FRAME_NS, ids, uv)
        latencies.append(1e3 * result.latency_s)
        errors.append(misclassification(result.labels, seq.labels))
        identity.add(result.labels, seq.labels)
        if previous is not None and result.frames and previous.frames:
            changes.append(float(np.mean(result.labels != previous.labels)))
        previous = result
    assert result is not None
    half = errors[len(errors) // 2:]
    return StreamRow(
        name=seq.name, category=seq.category, motions_true=seq.num_motions,
        motions_found=result.motions, points=int(ids.size), frames=len(errors),
        final_pct=100.0 * errors[-1], second_half_pct=100.0 * statistics.fmean(half),
        changes_pct=100.0 * statistics.fmean(changes) if changes else 0.0,
        latencies_ms=tuple(latencies), switches=identity.switches)


def _mean_median(values: list[float]) -> str:
    if not values:
        return f'{"-":>7} {"-":>7}'
    return f'{statistics.fmean(values):7.2f} {statistics.median(values):7.2f}'


def format_stream(rows: Sequence[StreamRow], title: str) -> str:
    """Final-frame and second-half misclassification by motion count, label changes, latency."""
    lines = [title, '', f'{"":<28}{"n":>4} {"mean":>7} {"median":>7}']
    groups = [('2 motions', 2), ('3 motions', 3), ('all', None)]
    for what, attr in (('final frame', 'final_pct'), ('second half', 'second_half_pct')):
        for label, count in groups:
            cell = [getattr(r, attr) for r in rows if count in (None, r.motions_true)]
            lines.append(f'{what + ", " + label:<28}{len(cell):>4} {_mean_median(cell)}')
    right = sum(r.motions_found == r.motions_true for r in rows)
    lines.append('')
    lines.append(f'Motions right in the final frame: {100.0 * right / max(len(rows), 1):.1f}% '
                 f'({right}/{len(rows)})')
    frames = sum(r.frames - 1 for r in rows)
    changes = sum(r.changes_pct * (r.frames - 1) for r in rows) / max(frames, 1)
    lines.append(f'Label changes between consecutive frames: {changes:.2f}% of features')
    switches, streamed = sum(r.switches for r in rows), sum(r.frames for r in rows)
    lines.append(f'Identity switches (a true motion matched to another number than before): '
                 f'{switches}, {100.0 * switches / max(streamed, 1):.2f} per 100 frames')
    lat = percentiles([x for r in rows for x in r.latencies_ms])
    lines.append(f'Latency per frame (ms): p50 {lat["p50"]:.1f}, p95 {lat["p95"]:.1f}, '
                 f'p99 {lat["p99"]:.1f}, max {lat["max"]:.1f} '
                 f'({sum(len(r.latencies_ms) for r in rows)} frames)')
    # Frames 1 and 2 of a stream are its cold start: the two-view fit of the first two frames
    # and the first affine fit, each with a noise scale to estimate.
    steady = [x for r in rows for x in r.latencies_ms[_COLD_FRAMES:]]
    lat = percentiles(steady)
    lines.append(f'  from frame {_COLD_FRAMES} on: p50 {lat["p50"]:.1f}, p95 {lat["p95"]:.1f}, '
                 f'p99 {lat["p99"]:.1f}, max {lat["max"]:.1f} ({len(steady)} frames)')
    return '\n'.join(lines)


# ----------------------------------------------------------------------------- latency

QUEUES = ('all', 'newest')
KINDS = ('floor', 'pearl')  # pearl_bench latency rows: the window alone, the segmenter


@dataclass(frozen=True)
class Schedule:
    """When each frame of a paced run was processed.

    Attributes
    ----------
    processed : tuple of int, frame indices in the order processed
    start_s, finish_s : tuple of float, s, per processed frame, on the arrivals' clock
    latency_s : tuple of float, s, finish minus arrival, per processed frame
    dropped : tuple of int, frames never processed (``queue='newest'``)
    """

    processed: tuple[int, ...]
    start_s: tuple[float, ...]
    finish_s: tuple[float, ...]
    latency_s: tuple[float, ...]
    dropped: tuple[int, ...]


def paced(arrivals_s: Sequence[float], work: Callable[[int], float], queue: str = 'all',
          wall_clock: bool = False) -> Schedule:
    """Run frames that arrive at ``arrivals_s`` through one worker, on a simulated clock.

    Frame ``i`` is processed by ``work(i)``, which returns how long it took (s); the worker
    starts it at the later of its arrival and the end of the previous frame, so a frame's
    latency (finish minus arrival) includes the time it waited behind slower ones, as on a
    robot. Nothing sleeps: the clock advances by the durations ``work`` reports. With
    ``wall_clock`` the worker sleeps until each frame's start comes in real time too, so that
    the machine idles between frames as it does behind a live camera (cold caches, sleeping
    cores); the latencies are still the simulated clock's, from the durations ``work`` reports.

    Parameters
    ----------
    arrivals_s : sequence of float, s, non-decreasing
    work : callable, frame index -> seconds it took; called once per processed frame, in order
    queue : 'all' (every frame, in order) or 'newest' (when the worker frees up, it takes the
        newest frame that has arrived and drops the older ones waiting)
    """
    if queue not in QUEUES:
        raise InputError(f'queue must be one of {", ".join(QUEUES)}, got {queue!r}')
    processed: list[int] = []
    start: list[float] = []
    finish: list[float] = []
    dropped: list[int] = []
    free = -math.inf  # when the worker is next free
    i, count = 0, len(arrivals_s)
    origin = time.perf_counter() - (arrivals_s[0] if count else 0.0)
    while i < count:
        begin = max(arrivals_s[i], free)
        take = i
        if queue == 'newest':
            while take + 1 < count and arrivals_s[take + 1] <= begin:
                take += 1
            dropped.extend(range(i, take))
        if wall_clock:
            while (ahead := origin + begin - time.perf_counter()) > 0:
                time.sleep(ahead)
        free = begin + work(take)
        processed.append(take)
        start.append(begin)
        finish.append(free)
        i = take + 1
    latency = tuple(f - arrivals_s[p] for p, f in zip(processed, finish, strict=True))
    return Schedule(tuple(processed), tuple(start), tuple(finish), latency, tuple(dropped))


@dataclass(frozen=True)
class LatencyRow:
    """One ``pearl_bench latency`` row: a size run paced through the floor or the segmenter.

    ``kind`` is ``'floor'`` (the sliding window alone: ``push`` and ``history``, what every
    frame costs before any segmentation) or ``'pearl'`` (:class:`OnlineSegmenter`).
    ``peak_mib`` is NaN unless measured (``memory``); ``mean_pct`` and ``final_pct`` as
    :func:`accuracy` (NaN for the floor, which labels nothing).
    """

    kind: str
    features: int
    window: int
    frames: int
    scene: int  # seed of the stream
    rate_hz: float
    stats: LatencyStats
    dropped: int
    peak_mib: float
    mean_pct: float
    final_pct: float


def latency_rows(features: int, window: int, frames: int, config: PearlConfig,
                 online: OnlineConfig, seed: int = 0, *, rate_hz: float = 30.0,
                 queue: str = 'all', stream: str = 'robot', memory: bool = False,
                 cameras: bool = False, wall_clock: bool = False) -> list[LatencyRow]:
    """The floor and segmenter rows of one stream, paced at ``rate_hz`` (:func:`paced`, in
    real time too with ``wall_clock``); with ``cameras`` (robot streams) each frame comes with
    its true camera, as odometry gives it.

    With ``memory``, the segmenter runs once more, unpaced, under ``tracemalloc`` for its peak
    allocation (not while timing: its hooks slow allocation down).
    """
    from pearl_ros.online.segmenter import OnlineSegmenter
    from pearl_ros.online.window import SlidingWindow

    frames_ = make_stream(stream, features, frames, seed)
    known = stream_cameras(stream, len(frames_), seed) if cameras else [None] * len(frames_)
    arrivals = [i / rate_hz for i in range(len(frames_))]
    online = dataclasses.replace(online, window=window)
    slider = SlidingWindow(window)

    def floor(i: int) -> float:
        frame = frames_[i]
        begin = time.perf_counter()
        slider.history(slider.push(frame.stamp_ns, frame.ids, frame.uv))
        return time.perf_counter() - begin

    segmenter = OnlineSegmenter(config, online)
    labels: dict[int, np.ndarray] = {}

    def segment(i: int) -> float:
        frame = frames_[i]
        begin = time.perf_counter()
        labels[i] = segmenter.process(frame.stamp_ns, frame.ids, frame.uv, known[i]).labels
        return time.perf_counter() - begin

    peak = math.nan
    if memory:
        peak = _peak_mib(OnlineSegmenter(config, online), frames_, known)
    rows = []
    for kind, work in (('floor', floor), ('pearl', segment)):
        run = paced(arrivals, work, queue, wall_clock)
        stats = latency_stats([1e3 * s for s in run.latency_s], len(frames_), 1e3 / rate_hz)
        mean, final = (accuracy(labels, [f.truth for f in frames_]) if kind == 'pearl'
                       else (math.nan, math.nan))
        rows.append(LatencyRow(kind, features, window, len(frames_), seed, rate_hz, stats,
                               len(run.dropped), peak if kind == 'pearl' else math.nan,
                               mean, final))
    return rows


def stream_cameras(stream: str, frames: int, seed: int) -> list[Any]:
    """The true camera (3, 4) of each frame of a ``'robot'`` stream of seed ``seed``."""
    if stream != 'robot':
        raise InputError(f'cameras are known for robot streams only, not {stream!r}')
    from pearl_ros.datasets.robot import robot_scene

    scene = robot_scene(frames, seed)
    return [scene.camera(t) for t in range(frames)]


def _peak_mib(segmenter: Any, frames: Sequence[Any], cameras: Sequence[Any]) -> float:
    """Peak MiB ``tracemalloc`` sees while ``segmenter`` processes ``frames``."""
    tracemalloc.start()
    try:
        for frame, camera in zip(frames, cameras, strict=True):
            segmenter.process(frame.stamp_ns, frame.ids, frame.uv, camera)
        return tracemalloc.get_traced_memory()[1] / 2**20
    finally:
        tracemalloc.stop()


def _cell(value: float, spec: str, width: int) -> str:
    return f'{"-":>{width}}' if math.isnan(value) else f'{value:{width}{spec}}'


def format_latency(rows: Sequence[LatencyRow], title: str) -> str:
    """The ``pearl_bench latency`` table: one line per row, a legend below."""
    lines = [title, '', f'{"kind":<5} {"features":>8} {"Hz":>4} {"W":>3} {"scene":>5} '
             f'{"answered":>9} {"p50 ms":>7} {"p95 ms":>7} {"p99 ms":>7} {"max ms":>7} '
             f'{"over %":>6} {"p99/p50":>7} {"peak MiB":>8} {"mean err %":>10} '
             f'{"final err %":>11}']
    for r in rows:
        s = r.stats
        lines.append(
            f'{r.kind:<5} {r.features:>8} {r.rate_hz:>4g} {r.window:>3} {r.scene:>5} '
            f'{f"{s.answered}/{s.sent}":>9} {_cell(s.p50, ".1f", 7)} {_cell(s.p95, ".1f", 7)} '
            f'{_cell(s.p99, ".1f", 7)} {_cell(s.max, ".1f", 7)} {_cell(s.over_pct, ".1f", 6)} '
            f'{_cell(s.ratio, ".2f", 7)} {_cell(r.peak_mib, ".1f", 8)} '
            f'{_cell(r.mean_pct, ".2f", 10)} {_cell(r.final_pct, ".2f", 11)}')
    lines += [
        'kind: floor = the sliding window alone (push + history), pearl = OnlineSegmenter.',
        'Frames arrive every 1/Hz s (simulated clock); latency = finish - arrival, waiting',
        'included; answered = frames processed, the rest dropped by the queue policy.',
        'over %: answered frames whose latency exceeds the frame period. mean err %:',
        'misclassification over the last three quarters of the frames; final: last answered.',
    ]
    return '\n'.join(lines)


# ----------------------------------------------------------------------------- profile


def profile_one(features: int, window: int, frames: int, config: PearlConfig,
                online: OnlineConfig, seed: int = 0, *, stream: str = 'robot',
                top: int = 25, cameras: bool = False) -> str:
    """pstats of the segmenter on one stream, restricted to the frames after the window fills:
    the ``top`` functions by cumulative time, then by own time (``cameras``: as
    :func:`latency_rows`)."""
    import cProfile
    import io
    import pstats

    from pearl_ros.online.segmenter import OnlineSegmenter

    frames_ = make_stream(stream, features, frames, seed)
    known = stream_cameras(stream, len(frames_), seed) if cameras else [None] * len(frames_)
    segmenter = OnlineSegmenter(config, dataclasses.replace(online, window=window))
    for frame, camera in zip(frames_[:window], known, strict=False):
        segmenter.process(frame.stamp_ns, frame.ids, frame.uv, camera)
    profiler = cProfile.Profile()
    profiler.enable()
    for frame, camera in zip(frames_[window:], known[window:], strict=True):
        segmenter.process(frame.stamp_ns, frame.ids, frame.uv, camera)
    profiler.disable()
    out = io.StringIO()
    stats = pstats.Stats(profiler, stream=out)
    for order, what in (('cumulative', 'cumulative time'), ('tottime', 'own time')):
        out.write(f'Top {top} functions by {what}, frames {window}-{len(frames_) - 1} '
                  f'({len(frames_) - window} frames after the window fills)\n')
        stats.sort_stats(order).print_stats(top)
    return _short_paths(out.getvalue())


def _short_paths(text: str) -> str:
    """File names from their package on (``pearl_ros/core/pearl.py``, ``numpy/...``)."""
    import os

    import pearl_ros

    for package in (pearl_ros, np):
        root = os.path.dirname(os.path.dirname(os.path.abspath(str(package.__file__))))
        text = text.replace(root + os.sep, '')
    return text
