"""A sliding window over the last W frames of tracked features.

Trackers give every feature an id that persists while it is tracked. Here a *track* is one
unbroken run of an id: an id that is missing from a frame and comes back later starts a new
track (trackers reuse ids, and a feature lost and re-detected is not known to be the same point).
Tracks get keys from one increasing counter, so a track's frames are always the newest ones of
the window and the window never holds more than W frames, however long the stream runs.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, replace

import numpy as np

# Frames of a window that must have their cameras for them to be used: fewer constrain a
# static point too little (two frames leave one residual direction per track).
CAMERA_FRAMES = 3


@dataclass(frozen=True)
class WindowFrame:
    """One frame as the window holds it: track keys sorted, with their pixel coordinates."""

    stamp_ns: int
    keys: np.ndarray  # (N,) int64, sorted
    uv: np.ndarray  # (N, 2) float64, pixels, rows in the order of keys
    camera: np.ndarray | None = None  # (3, 4) float64, projection matrix, where known


class SlidingWindow:
    """The last ``size`` frames, features keyed by track.

    Parameters
    ----------
    size : int, frames kept (the newest included), >= 2
    """

    def __init__(self, size: int) -> None:
        self.size = size
        self._frames: deque[WindowFrame] = deque(maxlen=size)
        # The ids of the newest frame, sorted, and their track keys.
        self._ids = np.empty(0, dtype=np.int64)
        self._id_keys = np.empty(0, dtype=np.int64)
        self._next_key = 0

    def __len__(self) -> int:
        return len(self._frames)

    @property
    def last_stamp(self) -> int | None:
        return self._frames[-1].stamp_ns if self._frames else None

    def resize(self, size: int) -> None:
        """Hold ``size`` frames from now on, keeping the newest ones that fit."""
        self.size = size
        self._frames = deque(self._frames, maxlen=size)

    def clear(self) -> None:
        """Forget every frame and track (keys keep increasing: a new track is never an old one)."""
        self._frames.clear()
        self._ids = self._id_keys = np.empty(0, dtype=np.int64)

    def push(self, stamp_ns: int, ids: np.ndarray, uv: np.ndarray,
             camera: np.ndarray | None = None) -> np.ndarray:
        """Append a frame; returns the track key of each feature, in input order.

        Parameters
        ----------
        stamp_ns : int, nanoseconds
        ids : (N,) int64, unique tracker ids
        uv : (N, 2) float64, pixels, finite
        camera : (3, 4) float64, optional, the frame's projection matrix (pixels from world)
        """
        ids = np.asarray(ids, dtype=np.int64)
        keys = lookup(self._ids, self._id_keys, ids, -1)
        new = keys < 0  # ids not in the previous frame: new tracks, keyed in input order
        keys[new] = self._next_key + np.arange(np.count_nonzero(new))
        self._next_key += int(np.count_nonzero(new))
        by_id = np.argsort(ids, kind='stable')
        self._ids, self._id_keys = ids[by_id], keys[by_id]
        order = np.argsort(keys, kind='stable')
        self._frames.append(WindowFrame(stamp_ns, keys[order], uv[order], camera))
        return keys

    def cameras(self, frames: int) -> np.ndarray | None:
        """The projection matrices ``(frames, 3, 4)`` of the newest ``frames`` frames, oldest
        first, NaN for a frame that came without one; None unless at least
        ``CAMERA_FRAMES`` of them (and two at the least) came with theirs."""
        newest = list(self._frames)[-frames:]
        known = [frame.camera is not None for frame in newest]
        if len(newest) < frames or sum(known) < min(CAMERA_FRAMES, frames) or sum(known) < 2:
            return None
        return np.stack([np.full((3, 4), np.nan) if frame.camera is None else frame.camera
                         for frame in newest])

    def set_camera(self, stamp_ns: int, camera: np.ndarray, tolerance_ns: int = 0) -> bool:
        """Give the frame nearest ``stamp_ns`` (within ``tolerance_ns``) that has no camera
        yet its ``camera`` (3, 4): a pose that came after its frame. Whether one took it."""
        if not self._frames:
            return False
        gaps = [abs(frame.stamp_ns - stamp_ns) for frame in self._frames]
        at = int(np.argmin(gaps))
        frame = self._frames[at]
        if gaps[at] > tolerance_ns or frame.camera is not None:
            return False
        self._frames[at] = replace(frame, camera=camera)
        return True

    def history(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The window's coordinates of tracks ``keys`` (all present in the newest frame).

        Returns
        -------
        coords : (F, N, 2) float64, pixels, oldest frame first, NaN where a track was not yet born
        age : (N,) int64, frames in the window holding the track (it holds the newest ``age``)
        """
        coords = np.full((len(self._frames), keys.size, 2), np.nan)
        age = np.zeros(keys.size, dtype=np.int64)
        for f, frame in enumerate(self._frames):
            pos, found = find(frame.keys, keys)
            coords[f, found] = frame.uv[pos[found]]
            age += found
        return coords, age


def find(sorted_keys: np.ndarray, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where each of ``queries`` is in ``sorted_keys`` (unique, ascending): positions ``(Q,)``
    int, meaningful where ``found`` ``(Q,)`` bool is true."""
    if sorted_keys.size == 0:
        return np.zeros(queries.size, dtype=np.int64), np.zeros(queries.size, dtype=bool)
    pos = np.minimum(np.searchsorted(sorted_keys, queries), sorted_keys.size - 1)
    found: np.ndarray = sorted_keys[pos] == queries
    return pos, found


def lookup(sorted_keys: np.ndarray, values: np.ndarray, queries: np.ndarray,
           missing: int) -> np.ndarray:
    """``values`` at the positions of ``queries`` in ``sorted_keys`` (unique, ascending),
    ``missing`` for a query not among them, ``(Q,)`` int64."""
    out = np.full(queries.size, missing, dtype=np.int64)
    pos, found = find(sorted_keys, queries)
    out[found] = values[pos[found]]
    return out
