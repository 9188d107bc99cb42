"""One task per benchmark item (a pair, a clip, a sequence, a stream), scored the same way.

Every task runs the code a user runs: batch and two-frame items call
:func:`pearl_ros.core.pearl.fit`, streams go frame by frame through
:class:`pearl_ros.online.segmenter.OnlineSegmenter`, the node's online code. Misclassification
treats outliers as a group of their own where the data labels them (a point labelled ``-1`` is
right only where the truth says outlier), as the AdelaideRMF protocol does (Wong et al., ICCV
2011). Tasks are top-level functions of picklable arguments, so worker processes can run them.
"""

from __future__ import annotations

import math
import time
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pearl_ros.core.config import PearlConfig
from pearl_ros.core.errors import PearlError
from pearl_ros.core.labels import OUTLIER, num_motions
from pearl_ros.core.metrics import LabelIdentity, misclassification
from pearl_ros.online.config import OnlineConfig

FRAME_NS = 33_333_333  # 30 Hz stamps for streamed items
MODES = ('all', 'two', 'stream')


@dataclass(frozen=True)
class Score:
    """The outcome on one item.

    Attributes
    ----------
    dataset, name : str
    error_pct : float, misclassification in percent (final frame for streams)
    motions_true, motions_found : int
    points : int, scored points
    seconds : float, wall time of the fit (for streams: mean per frame)
    outlier_recall_pct : float, percent of true outliers labelled -1 (NaN without outliers)
    rejected_pct : float, percent of true motion points labelled -1
    half_pct : float, for a stream, the mean misclassification over the second half of its
        frames in percent (the final frame alone swings with one frame's split or merge); NaN
        for a batch or two-frame item
    switches, frames : int, for a stream, the identity switches of its true motions
        (:class:`~pearl_ros.core.metrics.LabelIdentity`) over its frames; 0 and 0 otherwise
    """

    dataset: str
    name: str
    error_pct: float
    motions_true: int
    motions_found: int
    points: int
    seconds: float
    outlier_recall_pct: float = math.nan
    rejected_pct: float = math.nan
    half_pct: float = math.nan
    switches: int = 0
    frames: int = 0


@dataclass(frozen=True)
class Task:
    """One item: ``kind`` names the task function, ``source`` a file or a seed."""

    kind: str
    source: str
    mode: str
    config: PearlConfig
    online: OnlineConfig
    seed: int = 0
    outliers: float = 0.0
    lens: float = 0.0  # robot streams: radial distortion k1 of the camera's lens (0: none)
    undistort: bool = False  # and whether the segmenter gets the pixels undistorted
    dataset: str = ''  # robot streams: the set scored, where not the mode's own row


def score(dataset: str, name: str, pred: np.ndarray, truth: np.ndarray, seconds: float,
          motions_found: int, outliers_apart: bool = False, half_pct: float = math.nan,
          identity: LabelIdentity | None = None
          ) -> Score:
    """A :class:`Score` of ``pred`` against ``truth`` (``-1`` = outlier in both).

    With ``outliers_apart`` the error counts the true motion points only (a true point
    labelled -1 is wrong) and the outliers are judged by recall alone, as when outlier tracks
    were added to a clean set. ``half_pct`` is passed on (:attr:`Score.half_pct`), and a
    stream's ``identity`` gives :attr:`Score.switches` and :attr:`Score.frames`.
    """
    pred, truth = np.asarray(pred), np.asarray(truth)
    true = truth != OUTLIER
    if outliers_apart:
        error = misclassification(pred[true], truth[true])
    else:
        error = misclassification(pred, truth)
    recall = 100.0 * float(np.mean(pred[~true] == OUTLIER)) if np.any(~true) else math.nan
    rejected = 100.0 * float(np.mean(pred[true] == OUTLIER)) if np.any(true) else math.nan
    switches, frames = (identity.switches, identity.frames) if identity is not None else (0, 0)
    return Score(dataset, name, 100.0 * error, num_motions(truth),
                 int(motions_found), int(truth.size), seconds, recall, rejected, half_pct,
                 switches, frames)


def run_task(task: Task) -> Score:
    """Run one task; top level so that worker processes can import it."""
    runner = _RUNNERS[task.kind]
    try:
        return runner(task)
    except PearlError as err:
        raise type(err)(f'{Path(task.source).name}: {err}') from err


def _fit(tracks: np.ndarray, config: PearlConfig, seed: int) -> tuple[np.ndarray, int, float]:
    from pearl_ros.core.pearl import fit

    start = time.perf_counter()
    result = fit(tracks, config, rng=np.random.default_rng(seed))
    return result.labels, result.num_models, time.perf_counter() - start


def _stream(frames: list[tuple[np.ndarray, np.ndarray, np.ndarray]], config: PearlConfig,
            online: OnlineConfig, cameras: list[np.ndarray] | None = None
            ) -> tuple[np.ndarray, np.ndarray, int, float, float, LabelIdentity]:
    """Feed (ids, uv, truth) frames to an online segmenter (with each frame's projection
    matrix, if ``cameras``): the final frame's labels and truth, its motion count, the mean
    seconds per frame, the mean misclassification (percent) over the second half of the
    frames (outliers a group of their own, as in :func:`score`), and the identity switches
    over every frame."""
    from pearl_ros.online.segmenter import OnlineSegmenter

    segmenter = OnlineSegmenter(config, online)
    seconds, half, identity = 0.0, [], LabelIdentity()
    for t, (ids, uv, truth) in enumerate(frames):
        start = time.perf_counter()
        result = segmenter.process(1_000_000_000 + t * FRAME_NS, ids, uv,
                                   None if cameras is None else cameras[t])
        seconds += time.perf_counter() - start
        identity.add(result.labels, truth)
        if t >= len(frames) // 2:
            half.append(misclassification(result.labels, truth))
    return (result.labels, frames[-1][2], result.motions, seconds / max(len(frames), 1),
            100.0 * float(np.mean(half)), identity)


def _through_lens(frames: list[tuple[np.ndarray, np.ndarray, np.ndarray]], k1: float,
                  undistort: bool) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Robot-stream frames as a lens of radial distortion ``k1`` (plumb_bob) shows them, or,
    with ``undistort``, those pixels undistorted again as ``camera_info_topic`` does
    (:meth:`CameraModel.undistort`)."""
    from pearl_ros.datasets.robot import INTRINSICS
    from pearl_ros.tracking.tracker import CameraModel

    lens = CameraModel(INTRINSICS, np.array([k1, 0.0, 0.0, 0.0, 0.0]), 'plumb_bob')
    out = []
    for ids, uv, truth in frames:
        xy = (uv - INTRINSICS[:2, 2]) / INTRINSICS[0, 0]
        bent = xy * (1.0 + k1 * np.sum(np.square(xy), axis=1, keepdims=True))
        seen = bent * INTRINSICS[0, 0] + INTRINSICS[:2, 2]
        out.append((ids, lens.undistort(seen) if undistort else seen, truth))
    return out


def _adelaide(task: Task) -> Score:
    """An AdelaideRMF pair, one fundamental-matrix fit; mismatches are the outlier group."""
    import dataclasses

    from pearl_ros.datasets.adelaide import load_pair

    pair = load_pair(task.source)
    config = dataclasses.replace(task.config, model='fundamental')
    labels, found, seconds = _fit(pair.tracks, config, task.seed)
    return score('adelaidermf_f', pair.name, labels, pair.labels, seconds, found)


def _kt3dmoseg(task: Task) -> Score:
    """A KT3DMoSeg clip: ``all`` fits the points seen in every frame, ``two`` the first and
    last frame (fundamental), ``stream`` feeds every frame and scores the final one."""
    import dataclasses

    from pearl_ros.datasets.kt3dmoseg import load_clip

    clip = load_clip(task.source)
    dataset = f'kt3dmoseg_{task.mode}'
    if task.mode == 'stream':
        online = dataclasses.replace(task.online, seed=task.seed)
        labels, truth, found, seconds, half, identity = _stream(list(clip.frames()),
                                                                task.config, online)
        return score(dataset, clip.name, labels, truth, seconds, found, half_pct=half,
                     identity=identity)
    if task.mode == 'two':
        tracks, truth = clip.two_frames()
        config = dataclasses.replace(task.config, model='fundamental')
    else:
        (tracks, truth), config = clip.complete(), task.config
    labels, found, seconds = _fit(tracks, config, task.seed)
    return score(dataset, clip.name, labels, truth, seconds, found)


def _hopkins_outliers(task: Task) -> Score:
    """A Hopkins155 sequence with random-walk outlier tracks added (``task.outliers`` of all
    tracks; mode ``all``), true points scored on their own and outliers by recall; or its first
    and last frames with gross mismatches added (mode ``two``: ``task.outliers`` of all
    points, a fundamental matrix fit), scored with the mismatches as a group of their own, as
    AdelaideRMF's pairs are."""
    import dataclasses

    from pearl_ros.datasets.hopkins import load_mat
    from pearl_ros.datasets.outliers import add_mismatches, add_outlier_tracks

    seq = load_mat(task.source)
    # The outliers depend on the sequence and --seed only, never on the worker.
    rng = np.random.default_rng(np.random.SeedSequence([task.seed, zlib.crc32(seq.name.encode())]))
    if task.mode == 'two':
        tracks, truth = add_mismatches(seq.tracks[[0, -1]], seq.labels, task.outliers, rng)
        labels, found, seconds = _fit(tracks, dataclasses.replace(task.config,
                                                                  model='fundamental'), task.seed)
        return score('hopkins155_mismatches', seq.name, labels, truth, seconds, found)
    tracks, truth = add_outlier_tracks(seq.tracks, seq.labels, task.outliers, rng)
    labels, found, seconds = _fit(tracks, task.config, task.seed)
    return score('hopkins155_outliers', seq.name, labels, truth, seconds, found,
                 outliers_apart=True)


def robot_dataset(task: Task) -> str:
    """The set a robot stream is scored on: ``task.dataset``, else its mode's own line."""
    return task.dataset or ('robot_synthetic_cameras' if task.mode == 'cameras'
                            else 'robot_synthetic')


def _robot(task: Task) -> Score:
    """A robot-like synthetic stream (:mod:`pearl_ros.datasets.robot`) of seed ``source``,
    final frame scored, its outlier tracks a group of their own; mode ``cameras`` gives the
    segmenter each frame's true camera, as odometry would."""
    import dataclasses

    from pearl_ros.datasets.robot import robot_scene, robot_stream

    seed = int(task.source)
    frames = [(f.ids, f.uv, f.truth) for f in robot_stream(seed=seed)]
    if task.lens:
        frames = _through_lens(frames, task.lens, task.undistort)
    online = dataclasses.replace(task.online, seed=task.seed)
    cameras = None
    if task.mode == 'cameras':
        scene = robot_scene(len(frames), seed)
        cameras = [scene.camera(t) for t in range(len(frames))]
    labels, truth, found, seconds, half, identity = _stream(frames, task.config, online, cameras)
    return score(robot_dataset(task), f'seed{seed}', labels, truth, seconds, found, half_pct=half,
                 identity=identity)


_RUNNERS = {
    'adelaide': _adelaide,
    'kt3dmoseg': _kt3dmoseg,
    'hopkins_outliers': _hopkins_outliers,
    'robot': _robot,
}
KINDS = tuple(_RUNNERS)


@dataclass(frozen=True)
class Summary:
    """One data set's line of the suite table."""

    dataset: str
    items: int
    mean_pct: float
    median_pct: float
    motions_right_pct: float
    outlier_recall_pct: float
    rejected_pct: float
    seconds: float  # median per item (per frame for streams)
    half_pct: float = math.nan  # mean of the streams' Score.half_pct (NaN for other sets)
    switches_per_100: float = math.nan  # streams: identity switches per 100 frames, all items


def summarise(scores: list[Score]) -> list[Summary]:
    """One :class:`Summary` per data set, in the order they first appear."""
    out = []
    for dataset in dict.fromkeys(s.dataset for s in scores):
        mine = [s for s in scores if s.dataset == dataset]
        errors = np.array([s.error_pct for s in mine])
        recall = [s.outlier_recall_pct for s in mine if not math.isnan(s.outlier_recall_pct)]
        rejected = [s.rejected_pct for s in mine if not math.isnan(s.rejected_pct)]
        half = [s.half_pct for s in mine if not math.isnan(s.half_pct)]
        frames = sum(s.frames for s in mine)
        out.append(Summary(
            dataset, len(mine), float(errors.mean()), float(np.median(errors)),
            100.0 * float(np.mean([s.motions_found == s.motions_true for s in mine])),
            float(np.mean(recall)) if recall else math.nan,
            float(np.mean(rejected)) if rejected else math.nan,
            float(np.median([s.seconds for s in mine])),
            float(np.mean(half)) if half else math.nan,
            100.0 * sum(s.switches for s in mine) / frames if frames else math.nan))
    return out


def format_seed_means(per_seed: dict[int, list[Summary]]) -> str:
    """One line per data set over several runs of the suite, one run a seed: each seed's mean
    misclassification, their mean, and for streams the mean of their ``2nd half %``. A change
    is judged on the means: one seed's flips move a set by more than most changes do."""
    seeds = list(per_seed)
    head = (f'{"set":<22}{"items":>6}' + ''.join(f'{"seed " + str(s):>10}' for s in seeds)
            + f'{"mean %":>9}{"2nd half %":>12}')
    lines = [head]
    for dataset in dict.fromkeys(s.dataset for rows in per_seed.values() for s in rows):
        rows = [next((s for s in per_seed[seed] if s.dataset == dataset), None)
                for seed in seeds]
        found = [s for s in rows if s is not None]
        errors = ''.join(f'{"-" if s is None else format(s.mean_pct, ".2f"):>10}' for s in rows)
        half = [s.half_pct for s in found if not math.isnan(s.half_pct)]
        half_text = format(float(np.mean(half)), '.2f') if half else '-'
        lines.append(f'{dataset:<22}{found[0].items:>6}{errors}'
                     f'{float(np.mean([s.mean_pct for s in found])):>9.2f}{half_text:>12}')
    return '\n'.join(lines)


def format_summaries(summaries: list[Summary]) -> str:
    """The suite table: one line per data set. ``2nd half %``: for streams, the mean over
    their items of the misclassification averaged over the second half of the frames;
    ``switches/100``: their true motions' identity switches per 100 frames."""
    head = (f'{"set":<22}{"items":>6}{"mean %":>9}{"median %":>10}{"motions ok %":>14}'
            f'{"outl. -1 %":>12}{"true -1 %":>11}{"s/item":>9}{"2nd half %":>12}'
            f'{"switches/100":>14}')
    lines = [head]
    for s in summaries:
        def num(value: float, spec: str = '.2f') -> str:
            return '-' if math.isnan(value) else format(value, spec)
        lines.append(f'{s.dataset:<22}{s.items:>6}{s.mean_pct:>9.2f}{s.median_pct:>10.2f}'
                     f'{s.motions_right_pct:>14.1f}{num(s.outlier_recall_pct, ".1f"):>12}'
                     f'{num(s.rejected_pct):>11}{s.seconds:>9.3f}{num(s.half_pct):>12}'
                     f'{num(s.switches_per_100):>14}')
    return '\n'.join(lines)
