"""Random minimal samples: the "propose" step of PEaRL.

Uniform samples draw any ``m`` distinct points; local samples (NAPSAC, Nasuto & Craddock 2002;
Myatt et al. 2002) draw a seed point and ``m - 1`` of its image neighbours, since points of one
rigid body cluster in the image and a local sample is far more often pure.
"""

from __future__ import annotations

import numpy as np


def uniform_samples(pool: np.ndarray, num: int, m: int, rng: np.random.Generator) -> np.ndarray:
    """``(num, m)`` rows of ``m`` distinct entries of ``pool`` (int indices), uniformly."""
    pool = np.asarray(pool)
    if pool.size < m or num <= 0:
        return np.empty((0, m), dtype=np.int64)
    keys = rng.random((num, pool.size))
    return pool[np.argpartition(keys, m - 1, axis=1)[:, :m]].astype(np.int64)


def local_samples(
    neighbours: np.ndarray, num: int, m: int, rng: np.random.Generator
) -> np.ndarray:
    """``(num, m)`` rows: a random seed point and ``m - 1`` distinct of its ``neighbours``
    ``(N, k)``."""
    n, k = neighbours.shape
    if k < m - 1 or num <= 0:
        return np.empty((0, m), dtype=np.int64)
    seeds = rng.integers(0, n, num)
    picks = np.argpartition(rng.random((num, k)), m - 2, axis=1)[:, : m - 1] if m > 1 else None
    if picks is None:
        return seeds[:, None].astype(np.int64)
    return np.concatenate([seeds[:, None], neighbours[seeds[:, None], picks]], axis=1)


def mixed_samples(
    num_points: int,
    neighbours: np.ndarray,
    num: int,
    m: int,
    local_share: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """``num`` minimal samples, a ``local_share`` of them local, the rest uniform."""
    num_local = int(round(num * local_share))
    local = local_samples(neighbours, num_local, m, rng)
    rest = uniform_samples(np.arange(num_points), num - local.shape[0], m, rng)
    return np.concatenate([local, rest], axis=0)
