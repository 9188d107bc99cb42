"""A second thread for the per-frame work that numpy and scipy run without the GIL.

A frame's neighbourhood (:func:`pearl_ros.core.neighbourhood.neighbourhood`) is a Delaunay
triangulation (qhull), a k-d tree query and a batch of small eigendecompositions (LAPACK): all
three release the GIL while they compute, and the triangulation does not depend on the other
two. On a robot's computer the segmenter otherwise keeps one core busy while the others wait
for the next frame. The work goes to one worker thread, shared by the process, in pieces whose
results are the same bit for bit as when they run in turn: only who computes them changes.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import TypeVar

import numpy as np

_T = TypeVar('_T')

# Below this many points a frame's pieces are done in turn: handing one to the worker and
# waiting for it costs some 50-100 microseconds, what the pieces of 150 points cost.
PARALLEL_MIN_POINTS = 200

_lock = threading.Lock()
_pool: ThreadPoolExecutor | None = None


def worthwhile(num_points: int) -> bool:
    """Whether the work of ``num_points`` points is worth a second thread."""
    return num_points >= PARALLEL_MIN_POINTS


def in_background(func: Callable[..., _T], *args: object) -> Future[_T]:
    """``func(*args)`` on the worker thread; the caller reads ``.result()`` when it needs it."""
    return _worker().submit(func, *args)


def eigh_batch(matrices: np.ndarray, split: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """``numpy.linalg.eigh`` of a stack ``(M, k, k)`` of symmetric matrices, its first half on
    the worker thread where ``split`` (each matrix is decomposed on its own either way, so
    the results are those of one call)."""
    if not split or matrices.shape[0] < 2:
        values, vectors = np.linalg.eigh(matrices)
        return values, vectors
    half = matrices.shape[0] // 2
    first = in_background(np.linalg.eigh, matrices[:half])
    rest = np.linalg.eigh(matrices[half:])
    head = first.result()
    return (np.concatenate([head[0], rest[0]]), np.concatenate([head[1], rest[1]]))


def _worker() -> ThreadPoolExecutor:
    global _pool
    with _lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix='pearl_parallel')
        return _pool


def _forget_worker() -> None:
    """A forked child has no worker thread, only the parent's executor object: it makes its
    own (``pearl_bench --jobs`` forks its workers)."""
    global _pool, _lock
    _pool, _lock = None, threading.Lock()


os.register_at_fork(after_in_child=_forget_worker)
