"""Streaming benchmarks behind ``pearl_bench stream`` and ``pearl_bench latency``.

``stream`` feeds every Hopkins155 sequence (Tron & Vidal, CVPR 2007) frame by frame, at 30 Hz
stamps, through :class:`~pearl_ros.online.segmenter.OnlineSegmenter`, exactly as the node does,
and measures the labels of every frame against the ground truth. ``latency`` times synthetic
streams with births and deaths at several sizes.
"""

from __future__ import annotations

import dataclasses
import math
import statistics
import time
import tracemalloc
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from pearl_ros.core.config import PearlConfig
from pearl_ros.core.errors import PearlError
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


@dataclass(frozen=True)
class StreamTask:
    root: str
    name: str
    config: PearlConfig
    online: OnlineConfig


def stream_one(task: StreamTask) -> StreamRow:
    """Stream one Hopkins sequence; top level so that worker processes can import it."""
    from pearl_ros.core.metrics import misclassification
    from pearl_ros.datasets.hopkins import load_sequence
    from pearl_ros.online.segmenter import OnlineSegmenter

    try:
        seq = load_sequence(task.root, task.name)
    except PearlError as err:
        raise type(err)(f'{task.name}: {err}') from err
    segmenter = OnlineSegmenter(task.config, task.online)
    ids = np.arange(seq.tracks.shape[1])
    errors, latencies, changes = [], [], []
    previous = None
    result = None
    for f, uv in enumerate(seq.tracks):
        result = segmenter.process(1_000_000_000 + f * FRAME_NS, ids, uv)
        latencies.append(1e3 * result.latency_s)
        errors.append(misclassification(result.labels, seq.labels))
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
        latencies_ms=tuple(latencies))


def percentiles(values: Sequence[float]) -> dict[str, float]:
    if not values:
        return {'p50': math.nan, 'p95': math.nan, 'p99': math.nan, 'max': math.nan}
    array = np.asarray(values)
    p50, p95, p99 = np.percentile(array, [50, 95, 99])
    return {'p50': float(p50), 'p95': float(p95), 'p99': float(p99), 'max': float(array.max())}


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


@dataclass(frozen=True)
class LatencyRow:
    features: int
    window: int
    frames: int
    scene: int  # seed of the synthetic scene (generator)
    latency_ms: dict[str, float]
    peak_mib: float
    final_pct: float
    mean_pct: float  # misclassification over the frames after the window first fills


def latency_one(features: int, window: int, frames: int, config: PearlConfig,
                online: OnlineConfig, seed: int = 0) -> LatencyRow:
    """Time a synthetic stream (an object that starts mid-stream, one that stops, births and
    deaths; ``seed`` draws the scene) and measure the peak memory the segmenter allocates while
    it runs."""
    from pearl_ros.core.metrics import misclassification
    from pearl_ros.datasets.synthetic import BodySpec, synthetic_stream
    from pearl_ros.online.segmenter import OnlineSegmenter

    objects = (BodySpec(0.2), BodySpec(0.15, start=frames // 3), BodySpec(0.15, stop=frames // 2))
    stream = list(synthetic_stream(features, frames, objects, seed=seed))
    segmenter = OnlineSegmenter(config, dataclasses.replace(online, window=window))
    tracemalloc.start()
    try:
        for _ in _timed(segmenter, stream):
            pass
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    # Timing again without tracemalloc, whose hooks slow allocation-heavy code down.
    segmenter = OnlineSegmenter(config, dataclasses.replace(online, window=window))
    latencies, errors = [], []
    for (ms, result), frame in zip(_timed(segmenter, stream), stream, strict=True):
        latencies.append(ms)
        errors.append(misclassification(result.labels, frame.truth))
    return LatencyRow(features, window, frames, seed, percentiles(latencies[window:]),
                      peak / 2**20, 100.0 * errors[-1],
                      100.0 * statistics.fmean(errors[window:] or errors))


def _timed(segmenter: Any, stream: Sequence[Any]) -> Iterator[tuple[float, Any]]:
    """``(latency ms, FrameResult)`` of each frame of ``stream`` through ``segmenter``."""
    for frame in stream:
        start = time.perf_counter()
        result = segmenter.process(frame.stamp_ns, frame.ids, frame.uv)
        yield 1e3 * (time.perf_counter() - start), result


def format_latency(rows: Sequence[LatencyRow], title: str) -> str:
    lines = [title, '', f'{"features":>8} {"W":>3} {"frames":>6} {"scene":>5} {"p50 ms":>7} '
             f'{"p95 ms":>7} {"p99 ms":>7} {"max ms":>7} {"peak MiB":>8} {"final err %":>11} '
             f'{"mean err %":>10}']
    for r in rows:
        lat: dict[str, Any] = r.latency_ms
        lines.append(f'{r.features:>8} {r.window:>3} {r.frames:>6} {r.scene:>5} {lat["p50"]:7.1f} '
                     f'{lat["p95"]:7.1f} {lat["p99"]:7.1f} {lat["max"]:7.1f} {r.peak_mib:8.1f} '
                     f'{r.final_pct:11.2f} {r.mean_pct:10.2f}')
    lines.append('(latency and mean error over the frames after the window first fills)')
    return '\n'.join(lines)
