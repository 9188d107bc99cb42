"""``pearl_bench`` on data shaped like a robot's, and ``pearl_bench suite``: every set at once.

AdelaideRMF two-view pairs with mismatches (Wong et al., ICCV 2011), KT3DMoSeg driving clips
(Xu, Cheong & Li, CVPR 2018), Hopkins155 (Tron & Vidal, CVPR 2007) with gross outlier tracks,
and robot-like synthetic streams (:mod:`pearl_ros.datasets.robot`) run through the code paths
of the node: batch :func:`~pearl_ros.core.pearl.fit`, two-frame fits, and the online segmenter
frame by frame (:mod:`pearl_ros.evaluation.sets`). ``suite`` runs them all, with Hopkins155 all
frames, two frames and streamed, and prints one line per set, so that a change that helps one
set and hurts another shows in one run.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pearl_ros.core.errors import InputError
from pearl_ros.evaluation.sets import (
    Score,
    Task,
    format_seed_means,
    format_summaries,
    robot_dataset,
    run_task,
    summarise,
)

# Where suite looks for each set, below --data.
SET_FOLDERS = {'hopkins155': 'hopkins155', 'kt3dmoseg': 'kt3dmoseg_dev',
               'adelaide': 'adelaidermf_f_dev'}
SUITE_OUTLIERS = 0.2  # share of outlier tracks added to every fifth Hopkins155 sequence
SUITE_EVERY = 5
# Share of gross mismatches added to the first and last frames of every fifth Hopkins155
# sequence (AdelaideRMF's pairs hold 27-73%): a second real set of two views with mismatches
# beside AdelaideRMF's ten pairs.
SUITE_MISMATCHES = 0.5
SUITE_ROBOT_SEEDS = (0, 1, 2)
# More robot-like scenes, scored apart from the first three (their own row), so that a change
# tuned on those three shows whether it holds on others.
SUITE_ROBOT_MORE = tuple(range(3, 21))
ROBOT_MORE = 'robot_synthetic_3_20'


def add_commands(commands: Any) -> None:
    """The set subcommands and ``suite``, on ``pearl_bench``'s subparsers."""
    def common(sub: argparse.ArgumentParser) -> None:
        sub.add_argument('--jobs', type=int, default=1, metavar='N', help='worker processes')
        sub.add_argument('--seed', type=int, default=0, help='base random seed (default 0)')
        sub.add_argument('--items', action='store_true', help='also print one line per item')
        sub.add_argument('--set', action='append', default=[], metavar='NAME=VALUE',
                         help='override a parameter or solver.NAME setting (repeatable)')

    ade = commands.add_parser(
        'adelaide', help='AdelaideRMF F: two-view pairs with 30-70%% mismatches',
        description='Fit fundamental matrices to every AdelaideRMF pair; mismatches are scored '
        'as a group of their own (a point labelled -1 is right only where the truth says 0).')
    ade.add_argument('path', metavar='PATH', help='folder of pair .mat files')
    common(ade)
    kt = commands.add_parser(
        'kt3dmoseg', help='KT3DMoSeg: KITTI driving clips with partial tracks',
        description='Segment every KT3DMoSeg clip: all = the points seen in every frame, two = '
        'first and last frame (fundamental), stream = frame by frame through the online '
        'segmenter, final frame scored.')
    kt.add_argument('path', metavar='PATH', help='folder of *_Tracks.mat clips')
    kt.add_argument('--frames', choices=('all', 'two', 'stream'), default='stream')
    common(kt)
    syn = commands.add_parser(
        'synthetic', help='robot-like synthetic streams (perspective camera, cars, people, '
        'outlier tracks)',
        description='Stream robot-like synthetic scenes through the online segmenter and score '
        'the final frame, outlier tracks as a group of their own.')
    syn.add_argument('--scenes', type=int, nargs='+', default=list(SUITE_ROBOT_SEEDS),
                     metavar='SEED', help='scene seeds (default 0 1 2)')
    syn.add_argument('--oracle', action='store_true',
                     help='also read each final window with the true camera poses: which '
                     'points a static point explains, and how far each group lies from the '
                     "static world's 3-D and 4-D affine subspaces")
    syn.add_argument('--lens', type=float, default=0.0, metavar='K1',
                     help='see the streams through a lens of radial distortion K1 (plumb_bob, '
                     'e.g. -0.2: barrel, 50 px at the corners); default 0: none')
    syn.add_argument('--undistort', action='store_true',
                     help="with --lens, undistort the pixels before segmenting, as "
                     'camera_info_topic does')
    syn.add_argument('--cameras', action='store_true',
                     help="give the segmenter each frame's true camera (as a robot's odometry "
                     'would): the static world becomes a motion of known parameters')
    common(syn)
    suite = commands.add_parser(
        'suite', help='every data set in one table',
        description='Hopkins155 (all frames, two frames, stream; every fifth sequence with 20%% '
        'outlier tracks), KT3DMoSeg (all, two, stream), AdelaideRMF F and robot-like synthetic '
        'streams (scenes 0-2, with and without their cameras; scenes 3-20 on a line of their '
        'own), with the same parameters: one line per set.')
    suite.add_argument('--data', metavar='DIR', default=None,
                       help='folder holding hopkins155/, kt3dmoseg_dev/, adelaidermf_f_dev/ '
                       '(default: $PEARL_DATA, else ../shared/data)')
    suite.add_argument('--only', nargs='+', metavar='SET', help='run these sets only (names '
                       'as in the table, e.g. adelaidermf_f kt3dmoseg_two)')
    suite.add_argument('--seeds', nargs='+', type=int, metavar='SEED',
                       help='run the suite once per seed (in place of --seed): each seed\'s '
                       'table, then one line per set with each seed\'s mean and their mean')
    common(suite)


def _check(args: argparse.Namespace) -> None:
    if args.jobs < 1:
        raise InputError(f'--jobs must be >= 1, got {args.jobs}')
    if args.seed < 0:
        raise InputError(f'--seed must be >= 0, got {args.seed}')


def _configs(args: argparse.Namespace) -> tuple[dict[str, Any], Any, Any]:
    from pearl_ros.cli.bench import _online_configs

    return _online_configs(args.set)


def _report(scores: list[Score], title: str, items: bool) -> None:
    if items:
        for s in scores:
            extra = ('' if math.isnan(s.outlier_recall_pct)
                     else f' outliers -1 {s.outlier_recall_pct:.1f}%')
            if not math.isnan(s.half_pct):
                extra += f'  2nd half {s.half_pct:.2f}%  switches {s.switches}'
            print(f'{s.dataset:<22}{s.name:<24}{s.error_pct:7.2f}%  motions '
                  f'{s.motions_found}/{s.motions_true}{extra}  {s.seconds:.3f}s')
        print()
    print(title)
    print(format_summaries(summarise(scores)))


def _run(function: Any, tasks: Sequence[Any], jobs: int) -> list[Any]:
    from pearl_ros.cli.bench import _parallel

    out = []
    for done, result in enumerate(_parallel(function, tasks, jobs), start=1):
        out.append(result)
        sys.stderr.write(f'\r{done}/{len(tasks)} ')
    sys.stderr.write('\n')
    return out


def _title(what: str, overrides: dict[str, Any], online: Any) -> str:
    title = f'{what} (streams: window {online.window}, budget {online.budget_ms:g} ms)'
    if overrides:
        title += ', ' + ', '.join(f'{k}={v}' for k, v in overrides.items())
    return title


def adelaide(args: argparse.Namespace) -> int:
    from pearl_ros.datasets.adelaide import pair_paths

    _check(args)
    overrides, config, online = _configs(args)
    tasks = [Task('adelaide', str(p), 'two', config, online, args.seed)
             for p in pair_paths(args.path)]
    _report(_run(run_task, tasks, args.jobs), _title('PEaRL on AdelaideRMF F', overrides,
                                                     online), args.items)
    return 0


def kt3dmoseg(args: argparse.Namespace) -> int:
    from pearl_ros.datasets.kt3dmoseg import clip_paths

    _check(args)
    overrides, config, online = _configs(args)
    tasks = [Task('kt3dmoseg', str(p), args.frames, config, online, args.seed)
             for p in clip_paths(args.path)]
    _report(_run(run_task, tasks, args.jobs),
            _title(f'PEaRL on KT3DMoSeg, frames {args.frames}', overrides, online), args.items)
    return 0


def synthetic(args: argparse.Namespace) -> int:
    _check(args)
    if min(args.scenes) < 0:
        raise InputError(f'--scenes must be >= 0, got {min(args.scenes)}')
    overrides, config, online = _configs(args)
    if not -1.0 < args.lens < 1.0:
        raise InputError(f'--lens must be in (-1, 1), got {args.lens:g}')
    if args.undistort and not args.lens:
        raise InputError('--undistort needs --lens')
    mode = 'cameras' if args.cameras else 'stream'
    tasks = [Task('robot', str(s), mode, config, online, args.seed, lens=args.lens,
                  undistort=args.undistort) for s in args.scenes]
    title = 'Online PEaRL on robot-like synthetic streams' + (
        ', true cameras given' if args.cameras else '') + (
        f', lens k1 {args.lens:g}' + (' undone' if args.undistort else '') if args.lens else '')
    _report(_run(run_task, tasks, args.jobs), _title(title, overrides, online),
            args.items)
    if args.oracle:
        from pearl_ros.evaluation.robot_oracle import final_window, format_readings

        print(format_readings([r for s in args.scenes for r in final_window(s, online.window)]))
    return 0


def hopkins_outliers(args: argparse.Namespace, root: Path, names: list[str]) -> int:
    """``pearl_bench hopkins155 PATH --outliers SHARE``: outlier tracks added; or ``--frames
    two --mismatches SHARE``: gross mismatches added to the first and last frames."""
    overrides, config, online = _configs(args)
    mode, share = (('two', args.mismatches) if args.mismatches is not None
                   else ('all', args.outliers))
    tasks = [Task('hopkins_outliers', str(root / n / f'{n}_truth.mat'), mode, config, online,
                  args.seed, share) for n in names]
    title = (f'PEaRL on Hopkins155, first and last frames with {100 * share:g}% mismatches'
             if mode == 'two' else f'PEaRL on Hopkins155 with {100 * share:g}% outlier tracks')
    _report(_run(run_task, tasks, args.jobs), _title(title, overrides, online),
            getattr(args, 'items', False))
    return 0


def _suite_item(item: tuple[str, Any]) -> Score:
    """One suite item in a worker: a Hopkins batch or stream task, or a set task."""
    kind, task = item
    if kind == 'set':
        return run_task(task)
    if kind == 'hopkins':
        from pearl_ros.cli.bench import _run_one

        row = _run_one(task)
        return Score(f'hopkins155_{task.frames}', row.name, row.error_pct, row.motions_true,
                     row.motions_found, row.points, row.seconds)
    from pearl_ros.cli.bench_stream import stream_one

    srow = stream_one(task)
    seconds = sum(srow.latencies_ms) / 1000.0 / max(len(srow.latencies_ms), 1)
    return Score('hopkins155_stream', srow.name, srow.final_pct, srow.motions_true,
                 srow.motions_found, srow.points, seconds, half_pct=srow.second_half_pct,
                 switches=srow.switches, frames=srow.frames)


def _suite_items(data: Path, args: argparse.Namespace) -> list[tuple[str, Any]]:
    import dataclasses

    from pearl_ros.cli.bench import hopkins_tasks
    from pearl_ros.cli.bench_stream import StreamTask
    from pearl_ros.datasets.adelaide import pair_paths
    from pearl_ros.datasets.hopkins import sequence_names
    from pearl_ros.datasets.kt3dmoseg import clip_paths

    _, config, online = _configs(args)
    hop = data / SET_FOLDERS['hopkins155']
    names = sequence_names(hop)
    two = dataclasses.replace(config, model='fundamental')
    items: list[tuple[str, Any]] = []
    for frames, cfg in (('all', config), ('two', two)):
        items += [('hopkins', task) for task in hopkins_tasks(hop, names, args.seed, frames, cfg)]
    # Every stream of the suite is seeded by --seed, as its batch fits are.
    seeded = dataclasses.replace(online, seed=args.seed)
    items += [('stream', StreamTask(str(hop), n, config, seeded)) for n in names]
    # Every fifth sequence with outlier tracks (all frames), then with mismatches (two).
    for mode, share in (('all', SUITE_OUTLIERS), ('two', SUITE_MISMATCHES)):
        items += [('set', Task('hopkins_outliers', str(hop / n / f'{n}_truth.mat'), mode,
                               config, online, args.seed, share))
                  for n in names[::SUITE_EVERY]]
    for mode in ('all', 'two', 'stream'):
        items += [('set', Task('kt3dmoseg', str(p), mode, config, online, args.seed))
                  for p in clip_paths(data / SET_FOLDERS['kt3dmoseg'])]
    items += [('set', Task('adelaide', str(p), 'two', config, online, args.seed))
              for p in pair_paths(data / SET_FOLDERS['adelaide'])]
    for mode in ('stream', 'cameras'):
        items += [('set', Task('robot', str(s), mode, config, online, args.seed))
                  for s in SUITE_ROBOT_SEEDS]
    items += [('set', Task('robot', str(s), 'stream', config, online, args.seed,
                           dataset=ROBOT_MORE)) for s in SUITE_ROBOT_MORE]
    return items


def _dataset_of(item: tuple[str, Any]) -> str:
    kind, task = item
    if kind == 'hopkins':
        return f'hopkins155_{task.frames}'
    if kind == 'stream':
        return 'hopkins155_stream'
    if task.kind == 'robot':
        return robot_dataset(task)
    if task.kind == 'hopkins_outliers':
        return 'hopkins155_mismatches' if task.mode == 'two' else 'hopkins155_outliers'
    return {'kt3dmoseg': f'kt3dmoseg_{task.mode}',
            'adelaide': 'adelaidermf_f'}[task.kind]


def suite(args: argparse.Namespace) -> int:
    import os

    _check(args)
    data = Path(args.data or os.environ.get('PEARL_DATA') or
                Path(__file__).resolve().parents[2].parent / 'shared' / 'data')
    if not data.is_dir():
        raise InputError(f'data folder not found: {data} (give --data or set PEARL_DATA)')
    seeds = args.seeds or [args.seed]
    if min(seeds) < 0 or len(set(seeds)) < len(seeds):
        raise InputError(f'--seeds must be distinct and >= 0, got {" ".join(map(str, seeds))}')
    items: list[tuple[str, Any]] = []
    owner: list[int] = []  # the seed of each item
    for seed in seeds:
        mine = _suite_items(data, argparse.Namespace(**{**vars(args), 'seed': seed}))
        if args.only:
            known = sorted({_dataset_of(i) for i in mine})
            unknown = sorted(set(args.only) - set(known))
            if unknown:
                raise InputError(f'unknown set {unknown[0]!r} (known: {", ".join(known)})')
            mine = [i for i in mine if _dataset_of(i) in args.only]
        items += mine
        owner += [seed] * len(mine)
    # The slowest items first, so that the workers finish together.
    order = sorted(range(len(items)), key=lambda i: items[i][0] != 'set')
    start = time.time()
    done = _run(_suite_item, [items[i] for i in order], args.jobs)
    scores = [s for _, s in sorted(zip(order, done, strict=True))]
    overrides, _, online = _configs(args)
    title = _title(f'PEaRL suite ({data})', overrides, online)
    wall = f', {time.time() - start:.0f} s wall'
    if len(seeds) == 1:
        _report(scores, title + wall, args.items)
        return 0
    per_seed = {}
    for seed in seeds:
        mine_scores = [s for s, o in zip(scores, owner, strict=True) if o == seed]
        _report(mine_scores, f'{title}, seed {seed}', args.items)
        print()
        per_seed[seed] = summarise(mine_scores)
    print(f'{title}, seeds {" ".join(map(str, seeds))}{wall}')
    print(format_seed_means(per_seed))
    return 0
