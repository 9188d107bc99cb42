"""``pearl_bench latency``: the paced schedule against hand-computed ones, sizes, accuracy,
the paced table and ``--profile``. No assertion on a measured time."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from pearl_ros.cli.bench import main
from pearl_ros.cli.bench_stream import paced
from pearl_ros.core.errors import InputError
from pearl_ros.evaluation.latency import accuracy, latency_stats, parse_size

# Frames arrive at 8 Hz; every time below is a multiple of 1/32 s, exact in binary floating
# point, so the schedules can be compared with ==.
ARRIVALS = [i / 8 for i in range(6)]


def durations(*seconds: float):
    """A stand-in for the segmenter's clock only: frame i 'takes' seconds[i]; records calls."""
    calls: list[int] = []

    def work(i: int) -> float:
        calls.append(i)
        return seconds[i]

    return work, calls


def test_queue_all_makes_each_frame_wait_for_the_one_before_it() -> None:
    work, calls = durations(10 / 32, 2 / 32, 2 / 32, 2 / 32, 1 / 32, 12 / 32)
    run = paced(ARRIVALS, work, 'all')
    # Worked by hand: frame 0 runs 0 -> 10/32; 1 (due 4/32) waits until 10/32, ends 12/32;
    # 2 (due 8/32) 12 -> 14; 3 (due 12/32) 14 -> 16; 4 (due 16/32) starts on arrival, ends
    # 17/32; 5 (due 20/32) 20 -> 32/32.
    assert calls == [0, 1, 2, 3, 4, 5]
    assert run.processed == (0, 1, 2, 3, 4, 5) and run.dropped == ()
    assert run.start_s == tuple(x / 32 for x in (0, 10, 12, 14, 16, 20))
    assert run.finish_s == tuple(x / 32 for x in (10, 12, 14, 16, 17, 32))
    assert run.latency_s == tuple(x / 32 for x in (10, 8, 6, 4, 1, 12))


def test_queue_newest_takes_the_newest_arrived_frame_and_drops_the_older_ones() -> None:
    work, calls = durations(10 / 32, 2 / 32, 2 / 32, 2 / 32, 1 / 32, 12 / 32)
    run = paced(ARRIVALS, work, 'newest')
    # At 10/32, frames 1 (4/32) and 2 (8/32) have arrived: 2 runs, 1 is dropped; 2 ends at
    # 12/32, when 3 arrives: it runs at once. 4 and 5 find the worker free.
    assert calls == [0, 2, 3, 4, 5]
    assert run.processed == (0, 2, 3, 4, 5) and run.dropped == (1,)
    assert run.start_s == tuple(x / 32 for x in (0, 10, 12, 16, 20))
    assert run.latency_s == tuple(x / 32 for x in (10, 4, 2, 1, 12))


def test_a_long_frame_under_queue_newest_drops_everything_that_arrived_meanwhile() -> None:
    work, calls = durations(18 / 32, 9, 9, 9, 1 / 32, 12 / 32)
    run = paced(ARRIVALS, work, 'newest')
    # Frame 0 ends at 18/32: 1, 2, 3 and 4 (16/32) have arrived, 4 runs until 19/32; 5 comes
    # at 20/32.
    assert calls == [0, 4, 5]
    assert run.dropped == (1, 2, 3)
    assert run.latency_s == tuple(x / 32 for x in (18, 3, 12))
    # The same durations with every frame kept: the backlog of 9 s frames delays frame 5.
    work, calls = durations(18 / 32, 9, 9, 9, 1 / 32, 12 / 32)
    assert paced(ARRIVALS, work, 'all').finish_s[-1] == 18 / 32 + 27 + 13 / 32


def test_on_the_wall_clock_the_schedule_is_the_same_and_frames_wait_for_their_time() -> None:
    # The same hand-worked schedule as on the simulated clock; each frame starts no earlier, in
    # real time, than its start there (arrivals at 8 Hz: the run lasts 20/32 s or more).
    began: list[float] = []
    work, calls = durations(1 / 32, 1 / 32, 1 / 32, 1 / 32, 1 / 32, 1 / 32)

    def timed(i: int) -> float:
        began.append(time.perf_counter())
        return work(i)

    origin = time.perf_counter()
    run = paced(ARRIVALS, timed, 'all', wall_clock=True)
    assert run.latency_s == tuple(1 / 32 for _ in ARRIVALS)
    assert run.start_s == tuple(ARRIVALS)
    assert all(at - origin >= start - 1e-3 for at, start in zip(began, run.start_s, strict=True))
    assert began[-1] - origin >= ARRIVALS[-1] - 1e-3


def test_an_unknown_queue_policy_is_refused() -> None:
    with pytest.raises(InputError, match='queue must be one of all, newest'):
        paced(ARRIVALS, lambda i: 0.0, 'oldest')


def test_latency_stats_count_frames_over_the_period_and_the_unanswered() -> None:
    stats = latency_stats([10.0, 20.0, 40.0, 50.0], sent=5, period_ms=33.3)
    assert (stats.sent, stats.answered) == (5, 4)
    assert stats.over_pct == 50.0 and stats.max == 50.0
    assert stats.ratio == pytest.approx(stats.p99 / stats.p50)
    empty = latency_stats([], sent=3, period_ms=33.3)
    assert empty.answered == 0 and math.isnan(empty.p50) and math.isnan(empty.over_pct)


def test_accuracy_averages_answered_frames_of_the_last_three_quarters() -> None:
    truth = [np.array([0, 0, 1, 1])] * 8
    right, wrong = np.array([1, 1, 0, 0]), np.array([-1, -1, -1, -1])
    # Frames 0 and 1 (the first quarter) are left out whatever they say; 3 is unanswered.
    labels = {0: wrong, 1: wrong, 2: right, 4: right, 5: wrong, 6: right, 7: wrong}
    mean, final = accuracy(labels, truth)
    assert mean == pytest.approx(100 * 2 / 5) and final == 100.0
    assert all(math.isnan(x) for x in accuracy({}, truth))


@pytest.mark.parametrize(('token', 'size'), [('500', (500, 30.0)), ('2000@10', (2000, 10.0)),
                                             ('300@7.5', (300, 7.5))])
def test_a_size_is_features_with_an_optional_rate(token: str, size: tuple[int, float]) -> None:
    assert parse_size(token, 30.0) == size


@pytest.mark.parametrize('token', ['x', '500@', '500@fast', '5', '500@0', '500@-3'])
def test_a_bad_size_is_refused(token: str) -> None:
    with pytest.raises(InputError):
        parse_size(token, 30.0)


def _rows(out: str) -> list[list[str]]:
    return [line.split() for line in out.splitlines() if line.split()[:1] in (['floor'],
                                                                              ['pearl'])]


def test_paced_table_has_a_floor_and_a_segmenter_row_per_size(capsys) -> None:
    assert main(['latency', '--frames', '12', '--features', '60', '80@10', '--windows', '5',
                 '--queue', 'all']) == 0
    rows = _rows(capsys.readouterr().out)
    assert [(r[0], r[1], r[2], r[3]) for r in rows] == [
        ('floor', '60', '30', '5'), ('pearl', '60', '30', '5'),
        ('floor', '80', '10', '5'), ('pearl', '80', '10', '5')]
    for kind, _, _, _, _, answered, p50, p95, p99, top, over, _, peak, mean, final in rows:
        assert answered == '12/12'  # queue all: every frame processed
        assert float(p50) <= float(p95) <= float(p99) <= float(top)
        assert 0.0 <= float(over) <= 100.0 and peak == '-'
        if kind == 'pearl':
            assert 0.0 <= float(mean) <= 100.0 and 0.0 <= float(final) <= 100.0
        else:
            assert mean == final == '-'


def test_queue_newest_answers_the_first_and_the_last_frame_when_all_arrive_at_once(capsys
                                                                                  ) -> None:
    # 10**9 Hz: the twelve frames arrive within 11 ns, before the first one is done; the next
    # the worker takes is the newest, frame 11, and the ten in between are dropped.
    assert main(['latency', '--frames', '12', '--features', '60', '--windows', '5',
                 '--rate', '1e9', '--queue', 'newest', '--memory']) == 0
    rows = _rows(capsys.readouterr().out)
    assert [r[5] for r in rows] == ['2/12', '2/12']
    assert rows[1][12] != '-' and float(rows[1][12]) > 0  # peak MiB with --memory


def test_profile_names_the_segmenter_by_cumulative_and_own_time(capsys) -> None:
    assert main(['latency', '--profile', '--features', '60', '--windows', '3',
                 '--frames', '8']) == 0
    out = capsys.readouterr().out
    assert 'by cumulative time, frames 3-7' in out and 'by own time, frames 3-7' in out
    assert 'pearl_ros/online/segmenter.py' in out and '(process)' in out


@pytest.mark.parametrize(('argv', 'message'), [
    (['--profile', '--features', '60', '80'], '--profile runs one size'),
    (['--features', '60@x'], 'FEATURES@HZ'),
    (['--rate', '0'], '--rate must be > 0'),
    (['--features', '60', '--windows', '1'], 'windows >= 2'),
])
def test_bad_latency_arguments_get_one_line(argv: list[str], message: str, capsys) -> None:
    assert main(['latency', '--frames', '20', *argv]) == 1  # more frames than the window
    err = capsys.readouterr().err
    assert message in err and 'Traceback' not in err and err.count('\n') == 1
