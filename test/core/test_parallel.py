"""The neighbourhood's pieces on a second thread give the same results, bit for bit, as in turn."""

from __future__ import annotations

import multiprocessing
import os
import time

import numpy as np
import pytest

from pearl_ros.core import parallel
from pearl_ros.core.neighbourhood import neighbourhood


def _tracks(num_points: int, seed: int) -> np.ndarray:
    """Two rigid planar motions over 8 frames, with tracking noise: (F, N, 2) pixels."""
    rng = np.random.default_rng(seed)
    start = rng.uniform(0, 640, (num_points, 2))
    side = start[:, 0] > 320
    frames = []
    for t in range(8):
        angle = 0.01 * t * np.where(side, 1.0, -1.0)
        shift = np.stack([2.0 * t * np.where(side, 1.0, -0.5), 0.5 * t * np.ones(num_points)], 1)
        c, s = np.cos(angle), np.sin(angle)
        moved = np.stack([c * start[:, 0] - s * start[:, 1], s * start[:, 0] + c * start[:, 1]],
                         axis=1) + shift
        frames.append(moved + rng.normal(0.0, 0.3, moved.shape))
    return np.stack(frames)


@pytest.mark.parametrize('count', [1, 2, 7, 300, 501])
def test_eigh_split_over_two_threads_equals_one_call(count: int) -> None:
    # Oracle: numpy's own eigh of the whole stack in one call.
    rng = np.random.default_rng(count)
    half = rng.normal(size=(count, 8, 8))
    matrices = half @ np.transpose(half, (0, 2, 1))
    values, vectors = parallel.eigh_batch(matrices, split=True)
    want_values, want_vectors = np.linalg.eigh(matrices)
    assert np.array_equal(values, want_values)
    assert np.array_equal(vectors, want_vectors)


@pytest.mark.parametrize('seed', range(3))
def test_a_neighbourhood_built_on_two_threads_equals_one_built_in_turn(
        seed: int, monkeypatch: pytest.MonkeyPatch) -> None:
    tracks = _tracks(400, seed)
    monkeypatch.setattr(parallel, 'PARALLEL_MIN_POINTS', 10**9)
    alone = neighbourhood(tracks)
    monkeypatch.setattr(parallel, 'PARALLEL_MIN_POINTS', 1)
    monkeypatch.setattr(parallel, 'idle_core', lambda: True)
    assert parallel.worthwhile(400)
    shared = neighbourhood(tracks)
    assert np.array_equal(alone.edges, shared.edges)
    assert np.array_equal(alone.neighbours, shared.neighbours)
    assert np.array_equal(alone.misses, shared.misses)
    assert np.array_equal(alone.subspaces.basis, shared.subspaces.basis)


def _child_misses(queue: multiprocessing.Queue) -> None:  # type: ignore[type-arg]
    queue.put(neighbourhood(_tracks(400, 0)).misses)


def test_the_second_thread_is_used_only_where_a_core_is_idle() -> None:
    # Oracle: /proc/stat's idle time over the cores, read around the segmenter's own reading.
    before = parallel._cpu_times()
    if before is None:
        pytest.skip('no /proc/stat on this platform')
    parallel.idle_core()  # a first reading, to measure from
    first = parallel._idle
    spin_until = time.monotonic() + parallel.IDLE_EVERY_S + 0.2
    while time.monotonic() < spin_until:  # keep one core busy meanwhile
        pass
    idle = parallel.idle_core()
    after = parallel._cpu_times()
    assert after is not None and after[1] > first[2]
    cores = os.cpu_count() or 1
    spare = cores * (after[0] - first[1]) / (after[1] - first[2])
    # Its interval ended just before ours: the spare time of both is within a few jiffies.
    assert idle == (cores >= 2 and spare > parallel.IDLE_MARGIN) or abs(
        spare - parallel.IDLE_MARGIN) < 0.1
    # Few points are never worth it.
    assert not parallel.worthwhile(parallel.PARALLEL_MIN_POINTS - 1)


def test_the_worker_is_kept_off_the_callers_core() -> None:
    # Oracle: the kernel's own affinity mask of the worker thread, after a hand-over from a
    # caller pinned to one core.
    if not hasattr(os, 'sched_setaffinity') or len(os.sched_getaffinity(0)) < 2:
        pytest.skip('needs a second core and thread affinities (Linux)')
    parallel.in_background(int).result()  # the worker exists
    mine = os.sched_getaffinity(0)
    for core in sorted(mine)[:2]:
        os.sched_setaffinity(0, {core})
        try:
            assert parallel.in_background(int).result() == 0
            worker = os.sched_getaffinity(parallel._worker_id)
        finally:
            os.sched_setaffinity(0, mine)
        assert core not in worker and worker


def test_a_machine_with_one_core_never_hands_work_over(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(os, 'cpu_count', lambda: 1)
    monkeypatch.setattr(parallel, '_idle', (-float('inf'), 0, 0, True))
    assert not parallel.idle_core()


def test_a_forked_child_gets_a_worker_of_its_own(monkeypatch: pytest.MonkeyPatch) -> None:
    # The parent's worker thread does not exist in a forked child (pearl_bench --jobs forks):
    # the child's neighbourhood must still be built, and be the parent's.
    if 'fork' not in multiprocessing.get_all_start_methods():
        pytest.skip('no fork on this platform')
    monkeypatch.setattr(parallel, 'idle_core', lambda: True)  # the child inherits it
    want = neighbourhood(_tracks(400, 0)).misses  # the parent's worker now exists
    context = multiprocessing.get_context('fork')
    queue = context.Queue()
    child = context.Process(target=_child_misses, args=(queue,))
    child.start()
    got = queue.get(timeout=60)
    child.join(timeout=60)
    assert child.exitcode == 0
    assert np.array_equal(got, want)
