"""Gross outlier tracks added to a clean sequence: what a tracker that drifts or jumps adds."""

from __future__ import annotations

import numpy as np

from pearl_ros.core.errors import InputError
from pearl_ros.core.labels import OUTLIER


def add_outlier_tracks(
    tracks: np.ndarray,
    labels: np.ndarray,
    share: float,
    rng: np.random.Generator | int | None = None,
    step: float = 3.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Append random-walk tracks so that they make up ``share`` of all tracks.

    Each outlier track starts anywhere in the bounding box of the clean tracks' first frame and
    moves by an isotropic Gaussian step of ``step`` px (per axis) every frame, independently
    of every other track: no rigid motion explains it.

    Parameters
    ----------
    tracks : (F, N, 2) float64, pixels
    labels : (N,) int, true motion of each track
    share : float in [0, 1), outlier tracks / all tracks afterwards
    rng : numpy Generator, seed or None
    step : float, px, standard deviation of a frame's step along each axis

    Returns
    -------
    tracks : (F, N + M, 2) float64, the clean tracks first
    labels : (N + M,) int64, ``OUTLIER`` (-1) for the M added tracks
    """
    tracks = np.asarray(tracks, dtype=np.float64)
    labels = np.asarray(labels, dtype=np.int64)
    if tracks.ndim != 3 or tracks.shape[2] != 2 or labels.shape != (tracks.shape[1],):
        raise InputError(f'tracks must be (F, N, 2) with N labels, got {tracks.shape} and '
                         f'{labels.shape}')
    rng = np.random.default_rng(rng)
    frames, n = tracks.shape[:2]
    count = _added(share, n)
    low, high = tracks[0].min(axis=0), tracks[0].max(axis=0)
    start = rng.uniform(low, high, (count, 2))
    steps = rng.normal(0.0, step, (frames - 1, count, 2))
    walks = start[None] + np.concatenate([np.zeros((1, count, 2)), np.cumsum(steps, axis=0)])
    return (np.concatenate([tracks, walks], axis=1),
            np.concatenate([labels, np.full(count, OUTLIER, dtype=np.int64)]))


def add_mismatches(
    tracks: np.ndarray,
    labels: np.ndarray,
    share: float,
    rng: np.random.Generator | int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Append gross mismatches to two views so that they make up ``share`` of all points.

    A mismatch is what a descriptor matcher adds between wide-baseline views (AdelaideRMF's
    pairs hold 27-73% of them): a point anywhere in the first view's bounding box of the clean
    points, matched to a point anywhere in the second view's, the two drawn independently, so
    that no motion relates them.

    Parameters
    ----------
    tracks : (2, N, 2) float64, pixels: the two views
    labels : (N,) int, true motion of each point
    share : float in [0, 1), mismatches / all points afterwards
    rng : numpy Generator, seed or None

    Returns
    -------
    tracks : (2, N + M, 2) float64, the clean points first
    labels : (N + M,) int64, ``OUTLIER`` (-1) for the M added mismatches
    """
    tracks = np.asarray(tracks, dtype=np.float64)
    labels = np.asarray(labels, dtype=np.int64)
    if tracks.shape[0] != 2 or tracks.ndim != 3 or tracks.shape[2] != 2 \
            or labels.shape != (tracks.shape[1],):
        raise InputError(f'tracks must be (2, N, 2) with N labels, got {tracks.shape} and '
                         f'{labels.shape}')
    rng = np.random.default_rng(rng)
    count = _added(share, tracks.shape[1])
    views = [rng.uniform(view.min(axis=0), view.max(axis=0), (count, 2)) for view in tracks]
    return (np.concatenate([tracks, np.stack(views)], axis=1),
            np.concatenate([labels, np.full(count, OUTLIER, dtype=np.int64)]))


def _added(share: float, clean: int) -> int:
    """How many points to add to ``clean`` ones so that the added make up ``share`` of all."""
    if not 0.0 <= share < 1.0:
        raise InputError(f'share must be in [0, 1), got {share!r}')
    return int(round(share * clean / (1.0 - share)))
