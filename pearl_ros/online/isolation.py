"""Isolation judged over time: tracks that move unlike every neighbour frame after frame.

The isolation test of one fit (``SolverSettings.isolation``) suspects a point whose most alike
neighbour misses it by tens of times what the most alike neighbours usually miss by. An outlier
track that wanders a few pixels a frame in a scene whose bodies are themselves loose fits
(a perspective camera driving forward) never passes that test in one window, but it stays
apart from its neighbours window after window, which a point of a body rarely does. Each
track's isolation ratio, averaged in log over its last frames, is compared with the other
tracks': one far above the median, by robust deviations of that scene's own spread, is
suspected isolated. Where tracks' ratios spread widely (perspective bodies, KT3DMoSeg's
driving clips), the threshold moves up with them.
"""

from __future__ import annotations

import numpy as np

from pearl_ros.core.config import SolverSettings
from pearl_ros.online.window import find

_MAD_TO_SIGMA = 1.4826  # a Gaussian's standard deviation per median absolute deviation
# Fits over fewer frames (two views) measure isolation on another footing: not recorded.
LEAST_SPAN = 3
# Tracks with enough history that their median and spread are read at all (fewer: none is
# suspected on its past).
LEAST_JUDGED = 20


class IsolationHistory:
    """The isolation ratios of each track over its last ``frames`` fits.

    Parameters
    ----------
    frames : int, most frames a track's mean is taken over, >= 1
    """

    def __init__(self, frames: int) -> None:
        self.frames = frames
        self._keys = np.empty(0, dtype=np.int64)  # sorted
        self._logs = np.empty((0, frames))  # log ratios, oldest column first, NaN where none

    def clear(self) -> None:
        self._keys = np.empty(0, dtype=np.int64)
        self._logs = np.empty((0, self.frames))

    def update(self, keys: np.ndarray, ratios: np.ndarray) -> np.ndarray:
        """Add one fit's ratios ``(N,)`` (:func:`pearl_ros.core.pearl.isolation_ratios`) of the
        tracks ``keys`` ``(N,)``; returns their log ratios over their last frames ``(N,
        frames)``, oldest first, NaN where a track was not fitted. Tracks not among ``keys``
        are forgotten: a track that comes back is a new one (:mod:`pearl_ros.online.window`).
        """
        keys = np.asarray(keys, dtype=np.int64)
        rows = np.full((keys.size, self.frames), np.nan)
        pos, found = find(self._keys, keys)
        rows[found, :-1] = self._logs[pos[found], 1:]
        with np.errstate(divide='ignore'):
            rows[:, -1] = np.where(np.isfinite(ratios), np.log(np.maximum(ratios, 0.0)), np.nan)
        order = np.argsort(keys, kind='stable')
        self._keys, self._logs = keys[order], rows[order]
        return rows


def persistent_suspects(logs: np.ndarray, settings: SolverSettings,
                        rough: np.ndarray | None = None) -> np.ndarray:
    """Tracks ``(N,)`` bool isolated over their past frames, from their log isolation ratios
    ``(N, frames)`` (:meth:`IsolationHistory.update`; NaN where none).

    A track with at least ``settings.persist_frames`` ratios is suspected where its mean log
    ratio exceeds the median of such tracks' means by ``settings.persist_deviations`` robust
    deviations (1.4826 median absolute deviations), and ``log(settings.persist_least)``. A log
    ratio of -inf (a point that its neighbour fits exactly) counts as the least finite one.
    Tracks ``rough`` ``(N,)`` bool (:func:`pearl_ros.core.pearl.rough_tracks`) need
    ``settings.persist_rough_deviations`` deviations instead, where that is set.
    None is suspected while fewer than :data:`LEAST_JUDGED` tracks have enough ratios.
    """
    n = logs.shape[0]
    suspect = np.zeros(n, dtype=bool)
    if not settings.persist_deviations or n == 0:
        return suspect
    seen = ~np.isnan(logs)
    counts = seen.sum(axis=1)
    judged = np.flatnonzero(counts >= settings.persist_frames)
    if judged.size < LEAST_JUDGED:
        return suspect
    rows = logs[judged]
    finite = rows[np.isfinite(rows)]
    least = finite.min() if finite.size else 0.0
    rows = np.where(seen[judged], np.maximum(rows, least), 0.0)
    means = rows.sum(axis=1) / counts[judged]
    median = float(np.median(means))
    spread = _MAD_TO_SIGMA * float(np.median(np.abs(means - median)))
    deviations = np.full(judged.size, settings.persist_deviations)
    if rough is not None and settings.persist_rough_deviations:
        deviations[rough[judged]] = settings.persist_rough_deviations
    threshold = np.maximum(median + deviations * spread, float(np.log(settings.persist_least)))
    suspect[judged] = means > threshold
    return suspect
