"""``pearl_bench``: PEaRL on the Hopkins155 motion segmentation benchmark (Tron & Vidal, 2007).

Runs :func:`pearl_ros.core.pearl.fit` on every sequence and prints misclassification statistics
in the layout of Table 2.2 of the PEaRL thesis (Isack & Boykov, IJCV 2012): rows checkerboard /
traffic / articulated / all, column groups 2 motions / 3 motions / all, cells mean and median.
PEaRL finds the number of motions itself, so the share of sequences where it found the true number
is reported too.

Examples
--------
::

    pearl_bench hopkins155 ../shared/data/hopkins155 --frames all --jobs 4 --csv hopkins.csv
    pearl_bench hopkins155 ../shared/data/hopkins155 --frames two --only 1R2RC cars1

``--set NAME=VALUE`` overrides a field of :class:`PearlConfig` for experiments; reported numbers
use the defaults.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import dataclasses
import math
import multiprocessing
import os
import statistics
import sys
import time
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from pearl_ros.core.config import PearlConfig
from pearl_ros.core.errors import InputError, PearlError, UsageParser
from pearl_ros.pipeline.threads import THREAD_VARIABLES, limit_blas_threads

CATEGORIES = ('checkerboard', 'traffic', 'articulated')
MOTION_GROUPS = (2, 3)  # columns always shown, as in Table 2.2; other counts only under 'all'
CSV_COLUMNS = (
    'name',
    'category',
    'motions_true',
    'motions_found',
    'points',
    'frames',
    'error_pct',
    'seconds',
    'iterations',
    'energy',
    'truth_energy',
    'crossover_pct',
)


@dataclass(frozen=True)
class Row:
    """The outcome of PEaRL on one sequence (one CSV row).

    Attributes
    ----------
    name, category : str
    motions_true, motions_found : int
        Ground-truth number of motions; number of models PEaRL kept.
    points, frames : int
        Tracked points; frames given to ``fit`` (2 with ``--frames two``).
    error_pct : float
        Misclassification, percent of points.
    seconds : float
        Wall time of ``fit``, seconds.
    iterations : int
    energy : float
        Final energy (NaN when ``fit`` reports no history).
    truth_energy : float
        With ``--oracle``: energy of the ground-truth segmentation, models refitted to it, in
        the same setting; NaN otherwise.
    crossover_pct : float
        With ``--oracle``: percent of points closer to another true motion's model than to
        their own; NaN otherwise.
    """

    name: str
    category: str
    motions_true: int
    motions_found: int
    points: int
    frames: int
    error_pct: float
    seconds: float
    iterations: int
    energy: float
    truth_energy: float = math.nan
    crossover_pct: float = math.nan

    def csv_fields(self) -> list[str]:
        return [
            self.name,
            self.category,
            str(self.motions_true),
            str(self.motions_found),
            str(self.points),
            str(self.frames),
            f'{self.error_pct:.4f}',
            f'{self.seconds:.4f}',
            str(self.iterations),
            f'{self.energy:.10g}',
            f'{self.truth_energy:.10g}',
            f'{self.crossover_pct:.4f}',
        ]


# ----------------------------------------------------------------------------- summary


def _cell_stats(values: list[float]) -> dict[str, float | int | None]:
    if not values:
        return {'count': 0, 'mean': None, 'median': None}
    return {
        'count': len(values),
        'mean': statistics.fmean(values),
        'median': float(statistics.median(values)),
    }


def summarise(rows: Iterable[Row], wall_seconds: float | None = None) -> dict[str, Any]:
    """Benchmark statistics in the layout of Table 2.2, from per-sequence rows.

    Parameters
    ----------
    rows : iterable of Row
    wall_seconds : float, optional
        Wall time of the whole run, seconds; carried into the summary for :func:`format_table`.

    Returns
    -------
    dict
        ``'groups'``: column keys, ``'2'``, ``'3'`` (plus any other true motion count present)
        and ``'all'``. ``'error'[category][group]``: ``{'count', 'mean', 'median'}``
        misclassification in percent, ``None`` for an empty cell; categories are
        checkerboard, traffic, articulated and ``'all'``. ``'motions_correct'[category][group]``:
        ``{'count', 'correct', 'share'}`` with share in percent of sequences where the number of
        models found equals the true number of motions (``None`` if empty). ``'seconds'``:
        ``{'mean', 'median', 'max', 'total'}`` over sequences (``None`` values if no rows).
        ``'by_count'``: for ``'more'``, ``'fewer'`` and ``'equal'`` (motions found against
        true), ``{'count', 'points'}``: the sequences of that kind and their share of the mean
        error over all rows, in percentage points (the three add up to the mean).
        ``'count'``: number of rows. ``'wall_seconds'``: as given.
    """
    rows = list(rows)
    counts = sorted(set(MOTION_GROUPS) | {r.motions_true for r in rows})
    groups = [str(k) for k in counts] + ['all']
    categories = [*CATEGORIES, *sorted({r.category for r in rows} - set(CATEGORIES)), 'all']

    def select(category: str, group: str) -> list[Row]:
        return [
            r
            for r in rows
            if category in ('all', r.category) and group in ('all', str(r.motions_true))
        ]

    error: dict[str, dict[str, Any]] = {}
    correct: dict[str, dict[str, Any]] = {}
    for category in categories:
        error[category] = {}
        correct[category] = {}
        for group in groups:
            cell = select(category, group)
            error[category][group] = _cell_stats([r.error_pct for r in cell])
            hits = sum(r.motions_found == r.motions_true for r in cell)
            correct[category][group] = {
                'count': len(cell),
                'correct': hits,
                'share': 100.0 * hits / len(cell) if cell else None,
            }
    seconds = [r.seconds for r in rows]
    kinds = {'more': lambda r: r.motions_found > r.motions_true,
             'fewer': lambda r: r.motions_found < r.motions_true,
             'equal': lambda r: r.motions_found == r.motions_true}
    by_count = {
        kind: {'count': sum(1 for r in rows if test(r)),
               'points': math.fsum(r.error_pct for r in rows if test(r)) / max(len(rows), 1)}
        for kind, test in kinds.items()}
    return {
        'groups': groups,
        'categories': categories,
        'error': error,
        'motions_correct': correct,
        'seconds': {
            'mean': statistics.fmean(seconds) if seconds else None,
            'median': float(statistics.median(seconds)) if seconds else None,
            'max': max(seconds) if seconds else None,
            'total': math.fsum(seconds),
        },
        'by_count': by_count,
        'count': len(rows),
        'wall_seconds': wall_seconds,
    }


def _num(value: float | None, spec: str = '.2f') -> str:
    return '-' if value is None else format(value, spec)


def format_table(summary: dict[str, Any], title: str | None = None) -> str:
    """Text tables of a :func:`summarise` result: errors as in Table 2.2, then counts and times.

    Empty cells print as ``-``. Every error cell is ``mean median`` in percent, with the number
    of sequences ``n`` in the cell.
    """
    groups = summary['groups']
    categories = summary['categories']
    label_width = max(12, *(len(c) for c in categories))
    cell_width = 22  # '  n   mean  median' plus gaps
    heads = [f'{g} motions' if g != 'all' else 'all' for g in groups]
    lines: list[str] = []
    if title:
        lines += [title, '']
    lines.append('Misclassification (%)')
    lines.append(' ' * label_width + ''.join(h.rjust(cell_width) for h in heads))
    sub = f'{"n":>4} {"mean":>7} {"median":>7}'
    lines.append(' ' * label_width + ''.join(sub.rjust(cell_width) for _ in groups))
    for category in categories:
        cells = []
        for group in groups:
            stats = summary['error'][category][group]
            text = f'{stats["count"]:>4} {_num(stats["mean"]):>7} {_num(stats["median"]):>7}'
            cells.append(text.rjust(cell_width))
        lines.append(category.ljust(label_width) + ''.join(cells))
    lines.append('')
    lines.append('Number of motions found correctly (% of sequences)')
    lines.append(' ' * label_width + ''.join(h.rjust(cell_width) for h in heads))
    for category in categories:
        cells = []
        for group in groups:
            stats = summary['motions_correct'][category][group]
            frac = f'({stats["correct"]}/{stats["count"]})'
            text = f'{_num(stats["share"], ".1f"):>6} {frac:>9}'
            cells.append(text.rjust(cell_width))
        lines.append(category.ljust(label_width) + ''.join(cells))
    by_count = summary.get('by_count')
    if by_count and summary['count']:
        parts = [f'{words} {by_count[kind]["points"]:.2f} (n = {by_count[kind]["count"]})'
                 for kind, words in (('more', 'more motions than true'),
                                     ('fewer', 'fewer'), ('equal', 'as many'))]
        lines.append('Points of the mean error, by motions found: ' + ', '.join(parts))
    lines.append('')
    secs = summary['seconds']
    lines.append(
        f'Seconds per sequence: mean {_num(secs["mean"])}, median {_num(secs["median"])}, '
        f'max {_num(secs["max"])} ({summary["count"]} sequences)'
    )
    if summary.get('wall_seconds') is not None:
        lines.append(f'Total wall time: {summary["wall_seconds"]:.1f} s')
    return '\n'.join(lines)


# ----------------------------------------------------------------------------- running


def parse_overrides(items: Sequence[str]) -> dict[str, Any]:
    """``NAME=VALUE`` strings to PearlConfig values (the batch fit's), typed.

    Raises
    ------
    InputError
        On a malformed item, an unknown name (with the closest known one), a name of the
        streaming or node parameters, or a value of the wrong type.
    """
    from pearl_ros.pipeline import settings

    return settings.parse_assignments(items, refused=_not_batch())


def _not_batch() -> tuple[str, ...]:
    """Parameters the batch fit has no use for: the streaming layer's and the node's."""
    from pearl_ros.core.config import parameter_specs
    from pearl_ros.online.config import OnlineConfig
    from pearl_ros.pipeline.settings import NODE_NAMES

    return tuple(item.name for item in parameter_specs(OnlineConfig)) + NODE_NAMES


def _online_configs(items: Sequence[str]) -> tuple[dict[str, Any], Any, Any]:
    """``--set`` values of the streaming commands and their (PearlConfig, OnlineConfig)."""
    from pearl_ros.pipeline import settings

    overrides = settings.parse_assignments(items, refused=settings.NODE_NAMES)
    built = settings.build(overrides, refused=settings.NODE_NAMES)
    return overrides, built.config, built.online


@dataclass(frozen=True)
class _Task:
    root: str
    name: str
    index: int  # position in the full sorted list of the folder: fixes the seed of the sequence
    seed: int
    frames: str
    config: PearlConfig
    oracle: bool = False


def _run_one(task: _Task) -> Row:
    """Fit one sequence; top level so that worker processes can import it."""
    import numpy as np

    from pearl_ros.core.metrics import misclassification
    from pearl_ros.core.pearl import evaluate_segmentation, fit
    from pearl_ros.datasets.hopkins import load_sequence

    try:
        seq = load_sequence(task.root, task.name)
        tracks = seq.tracks[[0, -1]] if task.frames == 'two' else seq.tracks
        # The seed of a sequence depends on --seed and its index only, never on the worker.
        seed = np.random.SeedSequence([task.seed, task.index])
        start = time.perf_counter()
        result = fit(tracks, config=task.config, rng=np.random.default_rng(seed))
        seconds = time.perf_counter() - start
        error = misclassification(result.labels, seq.labels)
        truth_energy = crossover = math.nan
        if task.oracle:
            # The same seed gives the same setting (noise scale) as the fit above.
            truth_energy, residuals = evaluate_segmentation(
                tracks, seq.labels, task.config, np.random.default_rng(seed))
            own = residuals[seq.labels, np.arange(seq.labels.size)]
            crossover = 100.0 * float(np.mean(np.nanmin(residuals, axis=0) < own))
    except PearlError as err:
        raise type(err)(f'{task.name}: {err}') from err
    history = list(result.energy_history)
    return Row(
        name=seq.name,
        category=seq.category,
        motions_true=seq.num_motions,
        motions_found=int(result.num_models),
        points=int(seq.tracks.shape[1]),
        frames=int(tracks.shape[0]),
        error_pct=100.0 * error,
        seconds=seconds,
        iterations=int(result.iterations),
        energy=float(history[-1]) if history else math.nan,
        truth_energy=float(truth_energy),
        crossover_pct=crossover,
    )


@contextlib.contextmanager
def _single_threaded_children() -> Iterator[None]:
    """Make processes started inside the block load BLAS / OpenMP with one thread.

    Worker processes are *spawned* (fresh interpreters), so they import numpy after these
    variables are set; forked workers would inherit the parent's already loaded thread pools.
    """
    saved = {name: os.environ.get(name) for name in THREAD_VARIABLES}
    os.environ.update({name: '1' for name in THREAD_VARIABLES})
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def run(tasks: Sequence[_Task], jobs: int) -> Iterator[Row]:
    """Rows of ``tasks`` in order, from ``jobs`` worker processes (none if ``jobs`` is 1)."""
    return _parallel(_run_one, tasks, jobs)


class _Progress:
    """``[#####.....] 37/155 name`` on a terminal, one short line per sequence otherwise."""

    def __init__(self, total: int, stream: TextIO, width: int = 30) -> None:
        self.total = total
        self.stream = stream
        self.width = width
        self.tty = stream.isatty()

    def update(self, done: int, row: Row) -> None:
        if self.tty:
            filled = self.width * done // max(self.total, 1)
            bar = '#' * filled + '.' * (self.width - filled)
            self.stream.write(f'\r[{bar}] {done}/{self.total} {row.name[:30]:<30}')
            if done == self.total:
                self.stream.write('\n')
        else:
            self.stream.write(
                f'[{done:>{len(str(self.total))}}/{self.total}] {row.name} '
                f'{row.error_pct:.2f}% {row.seconds:.2f}s\n'
            )
        self.stream.flush()


def _build_parser() -> argparse.ArgumentParser:
    parser = UsageParser(
        prog='pearl_bench', description='Benchmark PEaRL motion segmentation on a dataset.'
    )
    commands = parser.add_subparsers(dest='dataset', metavar='DATASET', required=True)
    hop = commands.add_parser(
        'hopkins155',
        help='Hopkins155: 155 sequences of tracked points with ground-truth motions',
        description='Run PEaRL on every Hopkins155 sequence (dancing left out) and print '
        'misclassification statistics as in Table 2.2 of the PEaRL thesis.',
    )
    hop.add_argument('path', metavar='PATH', help='folder with one sub-folder per sequence')
    hop.add_argument(
        '--frames',
        choices=('all', 'two'),
        default='all',
        help='all frames with the affine model (default), or the first and last frame with '
        'the fundamental model',
    )
    hop.add_argument('--jobs', type=int, default=1, metavar='N', help='worker processes')
    hop.add_argument('--csv', metavar='FILE', help='write one row per sequence to FILE')
    hop.add_argument('--seed', type=int, default=0, help='base random seed (default 0)')
    hop.add_argument(
        '--oracle',
        action='store_true',
        help='also measure the ground-truth segmentation in the same energy: counts search '
        'failures (result energy above the truth\'s) and energy failures',
    )
    hop.add_argument('--only', nargs='+', metavar='NAME', help='run these sequences only')
    hop.add_argument('--outliers', type=float, default=None, metavar='SHARE',
                     help='add random-walk outlier tracks making up SHARE of all tracks (3 px '
                     'steps); true points scored on their own, outliers by recall')
    hop.add_argument('--mismatches', type=float, default=None, metavar='SHARE',
                     help='with --frames two: add gross mismatches (random point pairs) making '
                     'up SHARE of all points; scored with them as a group of their own, as '
                     'AdelaideRMF is')
    hop.add_argument('--every', type=int, default=1, metavar='N',
                     help='every Nth sequence only (with --outliers the robot-data benchmark '
                     'uses 5)')
    hop.add_argument('--items', action='store_true',
                     help='with --outliers or --mismatches: also print one line per sequence '
                     '(without them, --csv writes them)')
    hop.add_argument(
        '--set',
        action='append',
        default=[],
        metavar='NAME=VALUE',
        help='override a PearlConfig field, for experiments (repeatable)',
    )
    stream = commands.add_parser(
        'stream',
        help='stream Hopkins155 frame by frame through the online segmenter',
        description='Feed every Hopkins155 sequence frame by frame through the online segmenter '
        '(as the node does), warm-started and cold, and report accuracy, label changes and '
        'per-frame latency.',
    )
    stream.add_argument('dataset_name', choices=('hopkins155',), metavar='hopkins155')
    stream.add_argument('path', metavar='PATH', help='folder with one sub-folder per sequence')
    stream.add_argument('--jobs', type=int, default=1, metavar='N', help='worker processes')
    stream.add_argument('--only', nargs='+', metavar='NAME', help='stream these sequences only')
    stream.add_argument('--no-cold', action='store_true', help='skip the cold-start run')
    stream.add_argument('--set', action='append', default=[], metavar='NAME=VALUE',
                        help='override a PearlConfig or OnlineConfig field (repeatable)')
    _add_latency_parser(commands)
    from pearl_ros.cli import bench_sets

    bench_sets.add_commands(commands)
    return parser


def _add_latency_parser(commands: Any) -> None:
    """The ``latency`` subcommand's arguments."""
    latency = commands.add_parser(
        'latency',
        help='per-frame latency of the online segmenter at a frame rate, by size',
        description='Streams of 300 / 500 / 1000 / 2000 features (ground truth known) arrive '
        'at --rate Hz on a simulated clock and go through the online segmenter, one frame at a '
        'time: a frame waits while an earlier one is processed, and that wait is part of its '
        'latency. Per size: p50 / p95 / p99 / max latency, the share of frames over the frame '
        'period, frames dropped by the queue policy, the misclassification, and a floor row '
        '(the sliding window alone) for the same frames.',
    )
    latency.add_argument('--frames', type=int, default=300,
                         help='frames per stream (default 300, as make bench-node)')
    latency.add_argument('--features', nargs='+', default=None, metavar='N[@HZ]',
                         help='features per frame, one run each; N@HZ runs that size at HZ '
                         'instead of --rate (2000@10: 2000 features at 10 Hz); default '
                         '300 500 1000 2000, 500 with --profile')
    latency.add_argument('--windows', type=int, nargs='+', metavar='W',
                         help='window sizes, frames (default: the window parameter, 15 '
                         'unless --set)')
    latency.add_argument('--rate', type=float, default=30.0, metavar='HZ',
                         help='frame rate, Hz: frames arrive every 1/HZ s (default 30)')
    latency.add_argument('--queue', choices=('all', 'newest'), default='newest',
                         help='frames that arrive while one is processed: newest: only the '
                         'newest is processed, the rest dropped (default, as pearl_node\'s '
                         'queue_policy); all: each waits its turn')
    latency.add_argument('--stream', choices=('robot', 'synthetic'), default='robot',
                         help='robot: moving camera, parallax, cars and a person, 10%% outlier '
                         'tracks (default); synthetic: rigid 2-D motions with births and deaths')
    latency.add_argument('--scene-seeds', type=int, nargs='+', default=[0], metavar='SEED',
                         help='seeds of the streams: one stream per seed, size and '
                         'window (default 0)')
    latency.add_argument('--cameras', action='store_true',
                         help="give the segmenter each frame's true camera, as a robot's "
                         'odometry would (pose_topic; robot streams only)')
    latency.add_argument('--wall-clock', action='store_true',
                         help='sleep until each frame arrives, so that the machine idles '
                         'between frames as behind a live camera (slower than the default '
                         'simulated clock, which runs the frames back to back)')
    latency.add_argument('--memory', action='store_true',
                         help='also measure the peak MiB the segmenter allocates (one more '
                         'unpaced run per stream, under tracemalloc)')
    latency.add_argument('--profile', action='store_true',
                         help='profile one size (one --features, one --windows) with cProfile '
                         'over the frames after the window fills, instead of timing: top 25 '
                         'functions by cumulative and by own time (of the calling thread: '
                         'what the neighbourhood hands to its second thread shows as waits)')
    latency.add_argument('--set', action='append', default=[], metavar='NAME=VALUE',
                         help='override a PearlConfig or OnlineConfig field (repeatable)')


def _stream(args: argparse.Namespace) -> int:
    from pearl_ros.cli.bench_stream import StreamTask, format_stream, stream_one
    from pearl_ros.datasets.hopkins import sequence_names

    if args.jobs < 1:
        raise InputError(f'--jobs must be >= 1, got {args.jobs}')
    overrides, config, online = _online_configs(args.set)
    root = Path(args.path)
    names = list(dict.fromkeys(args.only)) if args.only else sequence_names(root)
    if not names:
        raise InputError(f'no Hopkins155 sequences (*/*_truth.mat) in {root}')
    runs = [('warm start', online)]
    if not args.no_cold:
        runs.append(('cold start', dataclasses.replace(online, warm_start=False)))
    for label, settings in runs:
        tasks = [StreamTask(str(root), name, config, settings) for name in names]
        rows = []
        for done, row in enumerate(_parallel(stream_one, tasks, args.jobs), start=1):
            rows.append(row)
            sys.stderr.write(f'\r{label}: {done}/{len(tasks)} {row.name[:30]:<30}')
        sys.stderr.write('\n')
        title = (f'Online PEaRL on Hopkins155 ({root}), {label}, window {settings.window}, '
                 f'budget {settings.budget_ms:g} ms')
        if overrides:
            title += ', ' + ', '.join(f'{k}={v}' for k, v in overrides.items())
        print(format_stream(rows, title))
        print()
    return 0


def _latency(args: argparse.Namespace) -> int:
    from pearl_ros.cli import bench_stream
    from pearl_ros.evaluation import latency

    overrides, config, online = _online_configs(args.set)
    if min(args.scene_seeds) < 0:
        raise InputError(f'--scene-seeds must be >= 0, got {min(args.scene_seeds)}')
    if not 0 < args.rate < math.inf:
        raise InputError(f'--rate must be > 0 Hz, got {args.rate:g}')
    tokens = args.features or (['500'] if args.profile else ['300', '500', '1000', '2000'])
    sizes = [latency.parse_size(token, args.rate) for token in tokens]
    if args.cameras and args.stream != 'robot':
        raise InputError('--cameras needs --stream robot (its cameras are known)')
    windows = args.windows or [online.window]
    if min(windows) < 2 or args.frames <= max(windows):
        raise InputError('need windows >= 2 and frames > window')
    if args.profile:
        if len(sizes) > 1 or len(windows) > 1:
            raise InputError('--profile runs one size: give one --features and one --windows')
        print(bench_stream.profile_one(sizes[0][0], windows[0], args.frames, config,
                                       online, args.scene_seeds[0], stream=args.stream,
                                       cameras=args.cameras))
        return 0
    rows = []
    for features, rate in sizes:
        for window in windows:
            for scene in args.scene_seeds:
                sys.stderr.write(f'\rlatency: {features} features at {rate:g} Hz, W={window}, '
                                 f'scene {scene}   ')
                rows += bench_stream.latency_rows(
                    features, window, args.frames, config, online, scene, rate_hz=rate,
                    queue=args.queue, stream=args.stream, memory=args.memory,
                    cameras=args.cameras, wall_clock=args.wall_clock)
    sys.stderr.write('\n')
    title = (f'Online PEaRL latency, {args.stream} streams of {args.frames} frames paced at '
             f'their rate, queue {args.queue}, budget {online.budget_ms:g} ms'
             + (', true cameras given' if args.cameras else '')
             + (', in real time' if args.wall_clock else ''))
    if overrides:
        title += ', ' + ', '.join(f'{k}={v}' for k, v in overrides.items())
    print(bench_stream.format_latency(rows, title))
    return 0


def _parallel(function: Any, tasks: Sequence[Any], jobs: int) -> Iterator[Any]:
    """``function`` over ``tasks`` in order, in ``jobs`` spawned single-threaded workers."""
    if jobs <= 1 or len(tasks) <= 1:
        for task in tasks:
            yield function(task)
        return
    context = multiprocessing.get_context('spawn')
    with _single_threaded_children():
        pool = context.Pool(processes=min(jobs, len(tasks)))
    with pool:
        yield from pool.imap(function, tasks, chunksize=1)


def hopkins_tasks(root: Path, names: Sequence[str], seed: int, frames: str, config: PearlConfig,
                  oracle: bool = False, everything: Sequence[str] | None = None) -> list[_Task]:
    """One fit task per sequence. A sequence's seed comes from ``seed`` and its position among
    all the folder's sequences (``everything``, read from ``root`` when not given), so it is
    the same whichever sequences are run and in whichever worker."""
    if everything is None:
        from pearl_ros.datasets.hopkins import sequence_names

        everything = sequence_names(root, include_dancing=True)
    index = {name: i for i, name in enumerate(everything)}
    return [_Task(str(root), name, index[name], seed, frames, config, oracle) for name in names]


def _hopkins155(args: argparse.Namespace) -> int:
    from pearl_ros.datasets.hopkins import sequence_names

    if args.jobs < 1:
        raise InputError(f'--jobs must be >= 1, got {args.jobs}')
    if args.outliers is not None and not 0.0 <= args.outliers < 1.0:
        raise InputError(f'--outliers must be in [0, 1), got {args.outliers}')
    if args.mismatches is not None and not 0.0 <= args.mismatches < 1.0:
        raise InputError(f'--mismatches must be in [0, 1), got {args.mismatches}')
    if args.outliers is not None and args.mismatches is not None:
        raise InputError('--outliers (tracks over all frames) and --mismatches (two frames) '
                         'are two benchmarks: give one')
    if args.mismatches is not None and args.frames != 'two':
        raise InputError('--mismatches goes with --frames two')
    if args.outliers is not None or args.mismatches is not None:
        # These benchmarks score through the data sets' tasks: options they would not honour
        # are refused rather than ignored.
        flag = '--outliers' if args.outliers is not None else '--mismatches'
        given = [name for name, used in (('--csv', args.csv), ('--oracle', args.oracle),
                                         ('--frames two', args.outliers is not None
                                          and args.frames == 'two')) if used]
        if given:
            raise InputError(f'{flag} prints per sequence with --items; it does not take '
                             f'{", ".join(given)}')
    elif args.items:
        raise InputError('--items goes with --outliers or --mismatches (without them, --csv '
                         'writes one row per sequence)')
    from pearl_ros.online.config import OnlineConfig
    from pearl_ros.pipeline import settings

    overrides = parse_overrides(args.set)
    model = 'affine' if args.frames == 'all' else 'fundamental'
    base = settings.Settings((PearlConfig(model=model), OnlineConfig()))
    config = settings.build(overrides, base, refused=_not_batch()).config

    root = Path(args.path)
    everything = sequence_names(root, include_dancing=True)
    index = {name: i for i, name in enumerate(everything)}
    if args.only:
        unknown = [name for name in args.only if name not in index]
        if unknown:
            raise InputError(f'unknown sequence(s) in {root}: {", ".join(unknown)}')
        names = list(dict.fromkeys(args.only))
    else:
        names = sequence_names(root)
    if args.every < 1:
        raise InputError(f'--every must be >= 1, got {args.every}')
    names = names[::args.every]
    if not names:
        raise InputError(f'no Hopkins155 sequences (*/*_truth.mat) in {root}')
    if args.outliers is not None or args.mismatches is not None:
        from pearl_ros.cli.bench_sets import hopkins_outliers

        return hopkins_outliers(args, root, names)
    tasks = hopkins_tasks(root, names, args.seed, args.frames, config, args.oracle, everything)

    csv_file = None
    if args.csv:
        try:
            csv_file = open(args.csv, 'w', newline='', encoding='utf-8')  # noqa: SIM115
        except OSError as err:
            raise InputError(f'cannot write {args.csv}: {err.strerror}') from err
    try:
        writer = csv.writer(csv_file) if csv_file else None
        if writer:
            writer.writerow(CSV_COLUMNS)
        progress = _Progress(len(tasks), sys.stderr)
        rows: list[Row] = []
        start = time.perf_counter()
        for row in run(tasks, args.jobs):
            rows.append(row)
            if writer and csv_file:
                writer.writerow(row.csv_fields())
                csv_file.flush()
            progress.update(len(rows), row)
        wall = time.perf_counter() - start
    finally:
        if csv_file:
            csv_file.close()

    title = (
        f'PEaRL on Hopkins155 ({root}): {args.frames} frames, model {config.model}, '
        f'seed {args.seed}'
    )
    if overrides:
        title += ', ' + ', '.join(f'{k}={v}' for k, v in overrides.items())
    print(format_table(summarise(rows, wall_seconds=wall), title=title))
    if args.oracle:
        print()
        print(format_oracle(rows))
    return 0


def format_oracle(rows: Sequence[Row], failed_pct: float = 2.0) -> str:
    """Search and energy failures among the sequences with error >= ``failed_pct``."""
    failed = [r for r in rows if r.error_pct >= failed_pct]
    search = sum(r.energy > r.truth_energy for r in failed)
    points = sum(r.points for r in rows)
    crossover = sum(r.crossover_pct * r.points for r in rows) / points if points else math.nan
    return '\n'.join([
        'Oracle: the ground-truth segmentation, models refitted to it, in the same energy',
        f'  sequences with error < {failed_pct:g}%: {len(rows) - len(failed)}',
        f'  search failures (result energy above the truth\'s): {search}',
        f'  energy failures (the truth\'s energy not lower): {len(failed) - search}',
        f'  points closer to another true motion\'s model than to their own: {crossover:.2f}%',
    ])


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``pearl_bench``; returns the exit code."""
    try:
        args = _build_parser().parse_args(argv)
        limit_blas_threads()  # as pearl_node runs (spawned workers: THREAD_VARIABLES)
        from pearl_ros.cli import bench_sets

        commands = {'hopkins155': _hopkins155, 'stream': _stream, 'latency': _latency,
                    'adelaide': bench_sets.adelaide, 'kt3dmoseg': bench_sets.kt3dmoseg,
                    'synthetic': bench_sets.synthetic, 'suite': bench_sets.suite}
        return commands[args.dataset](args)
    except PearlError as err:
        print(f'error: {err}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print('error: interrupted', file=sys.stderr)
        return 1
    except BrokenPipeError:  # output piped into e.g. head: stop quietly, as other tools do
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 1


if __name__ == '__main__':
    sys.exit(main())
