"""What the latency benchmarks share, free of ROS: their streams with ground truth, the sizes
they are asked for, and the statistics of a run (``pearl_bench latency`` and
``pearl_node_bench``)."""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from pearl_ros.core.errors import InputError


def percentiles(values: Sequence[float]) -> dict[str, float]:
    if not values:
        return {'p50': math.nan, 'p95': math.nan, 'p99': math.nan, 'max': math.nan}
    array = np.asarray(values)
    p50, p95, p99 = np.percentile(array, [50, 95, 99])
    return {'p50': float(p50), 'p95': float(p95), 'p99': float(p99), 'max': float(array.max())}


STREAMS = ('robot', 'synthetic')


def parse_size(token: str, rate_hz: float) -> tuple[int, float]:
    """``'500'`` -> (500, ``rate_hz``); ``'2000@10'`` -> (2000, 10.0): features per frame and
    the frame rate (Hz) of one benchmark size. InputError on anything else."""
    features, at, rate = token.partition('@')
    try:
        size = (int(features), float(rate) if at else float(rate_hz))
    except ValueError:
        raise InputError(f'a size is FEATURES or FEATURES@HZ (such as 2000@10), got '
                         f'{token!r}') from None
    if size[0] < 10 or not 0 < size[1] < math.inf:
        raise InputError(f'a size needs >= 10 features and a rate > 0 Hz, got {token!r}')
    return size


def make_stream(kind: str, features: int, frames: int, seed: int) -> list[Any]:
    """The frames of a benchmark stream with ground truth (``StreamFrame`` each), 30 Hz stamps.

    ``'robot'``: :func:`pearl_ros.datasets.robot.robot_stream` (a moving camera, parallax, two
    cars and a person, 10 % outlier tracks, births and deaths). ``'synthetic'``:
    :func:`pearl_ros.datasets.synthetic.synthetic_stream` with an object that starts a third of
    the way in and one that stops half way.
    """
    if kind == 'robot':
        from pearl_ros.datasets.robot import robot_stream

        return list(robot_stream(features, frames, seed=seed))
    from pearl_ros.datasets.synthetic import BodySpec, synthetic_stream

    objects = (BodySpec(0.2), BodySpec(0.15, start=frames // 3), BodySpec(0.15, stop=frames // 2))
    return list(synthetic_stream(features, frames, objects, seed=seed))


@dataclass(frozen=True)
class LatencyStats:
    """Latency of the answered frames of a run, and how many were not answered.

    Attributes
    ----------
    sent, answered : int, frames
    p50, p95, p99, max : float, ms, over the answered frames (NaN when none was)
    over_pct : float, percent of the answered frames whose latency exceeds ``period_ms``
    period_ms : float, ms, the frame period
    """

    sent: int
    answered: int
    p50: float
    p95: float
    p99: float
    max: float
    over_pct: float
    period_ms: float

    @property
    def ratio(self) -> float:
        """p99 / p50, how much worse the worst frames are than the typical one."""
        return self.p99 / self.p50 if self.p50 > 0 else math.nan


def latency_stats(latencies_ms: Sequence[float], sent: int, period_ms: float) -> LatencyStats:
    """:class:`LatencyStats` of ``latencies_ms`` (one per answered frame) out of ``sent``."""
    values = np.asarray(latencies_ms, dtype=np.float64)
    cut = percentiles(values.tolist())
    over = 100.0 * float(np.mean(values > period_ms)) if values.size else math.nan
    return LatencyStats(sent, int(values.size), cut['p50'], cut['p95'], cut['p99'], cut['max'],
                        over, period_ms)


def accuracy(labels: dict[int, np.ndarray], truth: Sequence[np.ndarray]) -> tuple[float, float]:
    """Misclassification in percent: ``(mean, final)``.

    ``labels`` maps a frame's index to its labels (answered frames only); ``truth`` holds every
    frame's. The mean is over the answered frames among the last three quarters of the stream
    (the first quarter is the warm-up), the final one that of the last answered frame. NaN
    when no frame qualifies.
    """
    from pearl_ros.core.metrics import misclassification

    if not labels:
        return math.nan, math.nan
    settled = [misclassification(labels[i], truth[i]) for i in sorted(labels)
               if i >= len(truth) // 4]
    final = misclassification(labels[max(labels)], truth[max(labels)])
    return (100.0 * statistics.fmean(settled) if settled else math.nan), 100.0 * final
