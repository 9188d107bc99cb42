"""How many frames the online fits span: long where tracks last, shorter where they churn."""

from __future__ import annotations

import numpy as np
import pytest

from pearl_ros.online.config import OnlineConfig
from pearl_ros.online.segmenter import OnlineSegmenter, _fit_span


def brute_span(age: np.ndarray, online: OnlineConfig) -> int:
    """The rule read literally: the most frames s that min_coverage of the tracks span, if
    s <= long_span, or that long_coverage of them span, whatever s."""
    best = 0
    for s in range(1, int(age.max()) + 1):
        share = np.count_nonzero(age >= s) / age.size
        if (s <= online.long_span and share >= online.min_coverage) or (
                share >= online.long_coverage):
            best = s
    return best


@pytest.mark.parametrize('seed', range(40))
def test_the_fitted_span_follows_the_rule_on_random_track_ages(seed):
    rng = np.random.default_rng(seed)
    online = OnlineConfig(window=int(rng.integers(3, 20)), long_span=int(rng.integers(2, 15)),
                          min_coverage=float(rng.uniform(0.1, 0.9)),
                          long_coverage=float(rng.uniform(0.1, 1.0)))
    age = rng.integers(1, online.window + 1, size=int(rng.integers(1, 60)))
    assert _fit_span(age, online) == brute_span(age, online)


def stream(lasting: float, frames: int = 20, tracks: int = 100, seed: int = 0):
    """Frames of ``tracks`` points under one translation, each pixel still; a share
    ``lasting`` of the tracks lasts from the first frame, the others are replaced (new ids) every
    5 frames, each at its own offset."""
    rng = np.random.default_rng(seed)
    points = rng.uniform(0, 500, size=(tracks, 2))
    churn = np.arange(tracks) >= round(lasting * tracks)
    for t in range(frames):
        generation = (t + np.arange(tracks)) // 5
        ids = np.where(churn, 1000 + np.arange(tracks) * 100 + generation, np.arange(tracks))
        yield 1_000_000_000 + t * 33_333_333, ids, points + [2.0 * t, 0.5 * t]


def spans(lasting: float) -> list[int]:
    segmenter = OnlineSegmenter(online=OnlineConfig(budget_ms=0.0))
    return [segmenter.process(stamp, ids, uv).frames for stamp, ids, uv in stream(lasting)]


def test_tracks_that_last_are_fitted_over_the_whole_window():
    online = OnlineConfig()
    assert online.window > online.long_span
    assert spans(1.0)[-1] == online.window


def test_where_tracks_churn_the_fit_stops_at_long_span():
    # 70% of the tracks last, under long_coverage (0.8) and over min_coverage (0.5).
    online = OnlineConfig()
    assert online.min_coverage < 0.7 < online.long_coverage
    assert spans(0.7)[-1] == online.long_span
