"""A second thread for the per-frame work that numpy and scipy run without the GIL.

A frame's neighbourhood (:func:`pearl_ros.core.neighbourhood.neighbourhood`) is a Delaunay
triangulation (qhull), a k-d tree query and a batch of small eigendecompositions (LAPACK): all
three release the GIL while they compute, and the triangulation does not depend on the other
two. Where a core is idle, the work goes to one worker thread, shared by the process, in pieces
whose results are the same bit for bit as when they run in turn: only who computes them
changes. Where every core is busy (other nodes, or ``pearl_bench --jobs``), handing a piece
over only adds the wait for a core: the pieces then run in turn.
"""

from __future__ import annotations

import ctypes
import math
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import TypeVar

import numpy as np

_T = TypeVar('_T')

# Below this many points a frame's pieces are done in turn: handing one to the worker and
# waiting for it costs some 50-100 microseconds, what the pieces of 150 points cost.
PARALLEL_MIN_POINTS = 200

# Seconds between two readings of how busy the machine is.
IDLE_EVERY_S = 1.0
# The second thread is used where at least this many cores' worth of time went idle since the
# last reading (this process's own work counts as busy).
IDLE_MARGIN = 0.5

_lock = threading.Lock()
_pool: ThreadPoolExecutor | None = None
_worker_id: int | None = None  # the worker thread's native id
_allowed: set[int] = set()  # the cores the worker could run on when it started
_steered: set[int] = set()  # the cores it was last allowed
# When the machine was last read (monotonic s), its idle and total CPU time then (jiffies,
# /proc/stat) and whether a core was idle over the interval before.
_idle: tuple[float, int, int, bool] = (-math.inf, 0, 0, False)


def _find_getcpu() -> Callable[[], int] | None:
    """libc's ``sched_getcpu`` (the core the calling thread runs on), or None."""
    if not hasattr(os, 'sched_setaffinity'):
        return None
    try:
        getcpu = ctypes.CDLL(None).sched_getcpu
    except (OSError, AttributeError):
        return None
    getcpu.restype = ctypes.c_int
    getcpu.argtypes = []
    return lambda: int(getcpu())


_getcpu = _find_getcpu()


def worthwhile(num_points: int) -> bool:
    """Whether the work of ``num_points`` points is worth a second thread: enough points, and
    a core idle (:func:`idle_core`)."""
    return num_points >= PARALLEL_MIN_POINTS and idle_core()


def idle_core() -> bool:
    """Whether this machine has a core to spare: ``IDLE_MARGIN`` cores' worth of its time idle
    since the last reading (``/proc/stat``), read at most every ``IDLE_EVERY_S`` seconds. On
    the first reading, or without ``/proc/stat``, the 1-minute load average below the cores
    by ``IDLE_MARGIN`` (without either, any second core counts as idle)."""
    global _idle
    now = time.monotonic()
    read_at, idle_then, total_then, idle = _idle
    if now - read_at < IDLE_EVERY_S:
        return idle
    cores = os.cpu_count() or 1
    times = _cpu_times()
    if times is not None and total_then and times[1] > total_then:
        spare = cores * (times[0] - idle_then) / (times[1] - total_then)
    else:
        try:
            spare = cores - os.getloadavg()[0]
        except (AttributeError, OSError):
            spare = cores - 1.0
    idle = cores >= 2 and spare > IDLE_MARGIN
    _idle = (now, *(times or (0, 0)), idle)
    return idle


def _cpu_times() -> tuple[int, int] | None:
    """The machine's idle and total CPU time so far (jiffies, every core), or None."""
    try:
        with open('/proc/stat', 'rb') as stat:
            fields = stat.readline().split()
    except OSError:
        return None
    if len(fields) < 5 or fields[0] != b'cpu':
        return None
    values = [int(value) for value in fields[1:]]
    return values[3] + (values[4] if len(values) > 4 else 0), sum(values[:8])


def in_background(func: Callable[..., _T], *args: object) -> Future[_T]:
    """``func(*args)`` on the worker thread; the caller reads ``.result()`` when it needs it."""
    pool = _worker()
    _steer()
    return pool.submit(func, *args)


def _steer() -> None:
    """Keep the worker off the caller's core. A thread woken by another is placed on the
    waker's core where the scheduler expects their caches to be shared; after a frame's idle
    gap the worker then shares the caller's core and nothing runs in parallel (the caller's
    neighbourhood at 2,000 features took as long as in turn). Its affinity is set to the
    cores it was allowed when it started less the one the caller runs on, where that leaves
    any (Linux)."""
    global _steered
    worker = _worker_id
    if worker is None or _getcpu is None:
        return
    try:
        cores = _allowed - {_getcpu()}
        if cores and cores != _steered:
            os.sched_setaffinity(worker, cores)
            _steered = cores
    except OSError:
        pass


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
    global _pool, _worker_id, _allowed
    with _lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix='pearl_parallel')
            _worker_id = _pool.submit(threading.get_native_id).result()
            if _getcpu is not None:
                try:
                    _allowed = os.sched_getaffinity(_worker_id)
                except OSError:
                    _allowed = set()
        return _pool


def _forget_worker() -> None:
    """A forked child has no worker thread, only the parent's executor object: it makes its
    own (``pearl_bench --jobs`` forks its workers)."""
    global _pool, _lock, _worker_id, _allowed, _steered
    _pool, _lock, _worker_id, _allowed, _steered = None, threading.Lock(), None, set(), set()


os.register_at_fork(after_in_child=_forget_worker)
