"""``pearl_segment_bag``: segment the feature tracks recorded in bags and score them.

For each bag folder: read the feature frames and the ground-truth labels, keep the features seen
in every frame, run PEaRL (Isack & Boykov, IJCV 2012) on all frames with the default
configuration (affine model), and print the number of motions found, the misclassification rate
and the label of every point.

Example
-------
::

    pearl_segment_bag bags/*/
"""

from __future__ import annotations

import os
import sys
import typing
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from pearl_ros import scoring
from pearl_ros.core.errors import InputError, PearlError, UsageParser
from pearl_ros.pipeline.threads import limit_blas_threads

_TRUTH_TOPIC = '/ground_truth/labels'  # read_ground_truth's default topic


def stack_tracks(frames: Sequence[typing.Any]) -> tuple[np.ndarray, np.ndarray]:
    """Tracks of the features present in every frame.

    Parameters
    ----------
    frames : sequence of FeatureFrame
        Each with ``ids`` ``(N_f,)`` int feature ids (unique within a frame) and ``uv``
        ``(N_f, 2)`` float pixels.

    Returns
    -------
    ids : (N,) int64
        Ids seen in every frame, sorted.
    tracks : (F, N, 2) float64, pixels
        ``tracks[f, i]`` = position of feature ``ids[i]`` in frame ``f``.

    Raises
    ------
    InputError
        If there are no frames, a frame is malformed or repeats an id.
    """
    if len(frames) == 0:
        raise InputError('no feature frames')
    id_sets = []
    for k, frame in enumerate(frames):
        ids = np.asarray(frame.ids).astype(np.int64, copy=False)
        uv = np.asarray(frame.uv, dtype=np.float64)
        if ids.ndim != 1 or uv.shape != (ids.size, 2):
            raise InputError(f'frame {k}: ids {ids.shape} and uv {uv.shape} do not match')
        if np.unique(ids).size != ids.size:
            raise InputError(f'frame {k}: repeated feature ids')
        id_sets.append(ids)
    common = id_sets[0]
    for ids in id_sets[1:]:
        common = np.intersect1d(common, ids, assume_unique=True)
    common = np.sort(common)
    tracks = np.empty((len(frames), common.size, 2), dtype=np.float64)
    for k, (frame, ids) in enumerate(zip(frames, id_sets, strict=True)):
        order = np.argsort(ids, kind='stable')
        pos = order[np.searchsorted(ids[order], common)]
        tracks[k] = np.asarray(frame.uv, dtype=np.float64)[pos]
    return common, tracks


def label_string(labels: np.ndarray, width: int = 80) -> str:
    """Labels ``(N,)`` one character each, as :func:`pearl_ros.scoring.label_string` writes
    them (``-`` for outliers), wrapped at ``width``."""
    text = scoring.label_string(labels)
    # Plain slices: textwrap would break lines after the '-' of an outlier.
    return '\n'.join(text[k : k + width] for k in range(0, len(text), width))


def segment_bag(path: Path, seed: int) -> str:
    """Segment the bag at ``path`` with ``fit(..., rng=seed)``; the report, ready to print."""
    from pearl_ros.bagio.reader import read_feature_frames, read_ground_truth, topics
    from pearl_ros.core.config import PearlConfig
    from pearl_ros.core.metrics import misclassification, relabel_to_truth
    from pearl_ros.core.pearl import fit

    frames = list(read_feature_frames(path))
    if len(frames) < 2:
        raise InputError(f'{path}: need at least 2 feature frames, found {len(frames)}')
    ids, tracks = stack_tracks(frames)
    if ids.size == 0:
        raise InputError(f'{path}: no feature is tracked through all {len(frames)} frames')
    truth_map = read_ground_truth(path, _TRUTH_TOPIC) if _TRUTH_TOPIC in topics(path) else {}
    result = fit(tracks, config=PearlConfig(model='affine'), rng=seed)
    labels = np.asarray(result.labels, dtype=np.int64)

    lines = [f'{path.name or path}: {len(frames)} frames, {ids.size} points tracked in all frames']
    known = np.array([int(i) in truth_map for i in ids.tolist()], dtype=bool)
    if not known.any():
        lines.append(f'  motions found {result.num_models} (no ground truth in the bag)')
        lines.append('  labels by feature id ("-" = outlier):')
        lines += ['    ' + line for line in label_string(labels, 76).splitlines()]
        return '\n'.join(lines)

    truth = np.array([truth_map.get(int(i), -1) for i in ids.tolist()], dtype=np.int64)
    motions_true = int(np.unique(truth[known & (truth >= 0)]).size)
    error = misclassification(labels[known], truth[known])
    shown = labels.copy()
    shown[known] = relabel_to_truth(labels[known], truth[known])
    lines.append(
        f'  motions found {result.num_models} (true {motions_true}), '
        f'misclassification {100.0 * error:.2f}% of {int(known.sum())} labelled points'
    )
    # Points grouped by true motion (then id), so that a right answer reads as blocks.
    order = np.lexsort((ids, np.where(truth < 0, np.iinfo(np.int64).max, truth)))
    lines.append('  truth, points by true motion then feature id ("-" = outlier or unknown):')
    lines += ['    ' + line for line in label_string(truth[order], 76).splitlines()]
    lines.append('  found, same order, renamed to the matching true motion ("-" = outlier):')
    lines += ['    ' + line for line in label_string(shown[order], 76).splitlines()]
    return '\n'.join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``pearl_segment_bag``; returns the exit code."""
    parser = UsageParser(
        prog='pearl_segment_bag',
        description='Segment the feature tracks of recorded bags with PEaRL (affine model, '
        'all frames, default configuration) and compare with their ground truth.',
    )
    parser.add_argument('bags', nargs='+', metavar='BAG', help='bag folder(s)')
    parser.add_argument('--seed', type=int, default=0, help='random seed (default 0)')
    try:
        args = parser.parse_args(argv)
        limit_blas_threads()  # as pearl_node runs: the segmenter's second thread needs the core
        for k, bag in enumerate(args.bags):
            if k:
                print()
            print(segment_bag(Path(bag), args.seed), flush=True)
    except PearlError as err:
        print(f'error: {err}', file=sys.stderr)
        return 1
    except BrokenPipeError:  # output piped into e.g. head: stop quietly, as other tools do
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
