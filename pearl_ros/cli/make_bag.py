"""``pearl_make_bag``: write a bag of tracked features with ground truth.

Two sources:

- a Hopkins-format ``*_truth.mat`` file: one message per frame at ``--rate`` Hz, stamps from a
  fixed epoch (output is deterministic), feature ids ``0..P-1`` in the column order of the file,
  pixels from ``y``, normalised coordinates from ``x`` (or ``K^-1 y``), and one ground-truth
  message per frame with labels ``0..k-1`` (the file's groups ``s`` renumbered in increasing
  order). ``--frames 0,-1`` keeps only some frames (a two-view pair), with their stamps;
- the word ``synthetic``: :func:`pearl_ros.datasets.synthetic.synthetic_stream` (rigid bodies
  under an affine camera, features dying and being born, ids reused), at 30 Hz from the same
  epoch, with each frame's own ground truth (an object that has not started, or has stopped,
  moving is labelled background, 0).

An output path ending in ``.bag`` is written as a ROS 1 bag file (Noetic message definitions);
any other path is a ROS 2 bag folder.

Examples::

    pearl_make_bag ../shared/data/hopkins155/cars2/cars2_truth.mat bags/cars2
    pearl_make_bag synthetic bags/synthetic --num-features 300 --num-frames 90 \\
        --object 0.2:30 --object 0.15:0:60
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.io

from pearl_ros.bagio.reader import FeatureFrame
from pearl_ros.bagio.writer import (
    FORMATS,
    STORAGES,
    is_bag,
    staged,
    write_feature_bag,
    write_ros1_bag,
)
from pearl_ros.core.errors import InputError, PearlError, UsageParser, one_line
from pearl_ros.datasets.hopkins import load_mat
from pearl_ros.datasets.synthetic import BodySpec, synthetic_stream

EPOCH_NS = 1_700_000_000 * 1_000_000_000  # stamp of the first frame, int ns (2023-11-14)
SYNTHETIC = 'synthetic'

# Normalised coordinates of synthetic streams: a nominal pinhole camera for a 640 x 480 image.
SYNTHETIC_FOCAL = 500.0  # px
SYNTHETIC_CENTRE = (320.0, 240.0)  # px


@dataclass(frozen=True)
class Output:
    """How the bag is written, whatever its source.

    Attributes
    ----------
    msg_format : {'pointcloud', 'pointcloud2'}
        Message layout of the features (:data:`pearl_ros.bagio.writer.FORMATS`).
    storage : {'mcap', 'sqlite3'}
        rosbag2 storage of a bag folder (a ``*.bag`` path is a ROS 1 file).
    topic, truth_topic : str
        Topics of the features and of the ground truth.
    force : bool
        Replace an existing bag at the output path.
    """

    msg_format: str = 'pointcloud'
    storage: str = 'mcap'
    topic: str = '/feature_tracker/feature'
    truth_topic: str = '/ground_truth/labels'
    force: bool = False

    def check(self, out_bag: Path) -> None:
        """InputError unless ``out_bag`` can be written: new, or a bag and ``force``."""
        exists = out_bag.exists() or out_bag.is_symlink()
        if exists and not self.force:
            raise InputError(f'{out_bag} exists; pass --force to replace it')
        if exists and not _is_bag(out_bag):
            raise InputError(f'refusing to replace {out_bag}: it is not a bag (no metadata.yaml)')
        if not out_bag.parent.is_dir():
            raise InputError(f'output folder does not exist: {out_bag.parent}')

    def write(self, out_bag: Path, frames: Iterable[FeatureFrame],
              truth: Iterable[tuple[int, np.ndarray, np.ndarray]],
              normalized: Callable[[np.ndarray], np.ndarray] | None, *, what: str,
              truth_note: str = '') -> str:
        """Write the bag, all or nothing (:func:`~pearl_ros.bagio.writer.staged`); the summary
        line, saying ``what`` was written."""
        with staged(out_bag) as target:
            ros2 = target.with_name('ros2') if out_bag.suffix == '.bag' else target
            write_feature_bag(ros2, frames, truth, topic=self.topic,
                              truth_topic=self.truth_topic, msg_format=self.msg_format,
                              storage=self.storage, normalized=normalized)
            if ros2 != target:
                write_ros1_bag(ros2, target)
        container = 'ROS 1 bag' if out_bag.suffix == '.bag' else self.storage
        return (f'wrote {out_bag}: {what}, {FORMATS[self.msg_format]} on {self.topic}, '
                f'labels on {self.truth_topic}{truth_note}, {container}')


def build_parser() -> argparse.ArgumentParser:
    parser = UsageParser(
        prog='pearl_make_bag',
        description='Write a bag of tracked features with ground-truth labels, from a '
        'Hopkins-format *_truth.mat file or a synthetic stream.',
    )
    parser.add_argument('source', metavar='SOURCE', help='Hopkins-format <name>_truth.mat file, '
                        f'or {SYNTHETIC!r} for a synthetic stream')
    parser.add_argument('out_bag', type=Path, help='ROS 2 bag folder to create (name it without '
                        '.bag); a path ending in .bag is written as a ROS 1 bag file')
    parser.add_argument('--rate', type=float, default=30.0,
                        help='frame rate of a .mat file, Hz (default 30)')
    parser.add_argument('--frames', dest='frame_list', default=None, metavar='I,J,...',
                        help='.mat file: keep only these frames (0-based, negative from the end, '
                        'e.g. 0,-1 for a two-view pair); their stamps are kept')
    synthetic = parser.add_argument_group('synthetic stream')
    synthetic.add_argument('--num-features', type=int, default=300,
                           help='features per frame (default 300)')
    synthetic.add_argument('--num-frames', type=int, default=90, help='frames (default 90)')
    synthetic.add_argument('--object', dest='objects', action='append', default=None,
                           metavar='SHARE[:START[:STOP]]',
                           help='a moving object: share of the features, first frame it moves '
                           'on its own and frame it stops (repeat for more objects; default '
                           '0.2:30 and 0.15:0:60, one that starts and one that stops)')
    synthetic.add_argument('--death-rate', type=float, default=0.02,
                           help='probability that a feature is lost in a frame (default 0.02)')
    synthetic.add_argument('--noise', type=float, default=0.5,
                           help='px, Gaussian tracking noise (default 0.5)')
    synthetic.add_argument('--seed', type=int, default=0, help='random seed (default 0)')
    parser.add_argument(
        '--format',
        dest='msg_format',
        choices=tuple(FORMATS),
        default='pointcloud',
        help='pointcloud: VINS-Mono sensor_msgs/PointCloud (default); '
        'pointcloud2: sensor_msgs/PointCloud2 with id, u, v, x, y',
    )
    parser.add_argument(
        '--storage', choices=tuple(STORAGES), default='mcap', help='rosbag2 storage (default mcap)'
    )
    parser.add_argument(
        '--topic',
        default='/feature_tracker/feature',
        help='feature topic (default /feature_tracker/feature)',
    )
    parser.add_argument(
        '--truth-topic',
        default='/ground_truth/labels',
        help='ground-truth topic (default /ground_truth/labels)',
    )
    parser.add_argument(
        '--force',
        action='store_true',
        help='replace OUT_BAG if it exists (only a bag folder is replaced)',
    )
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command; 0 on success, 1 with ``error: ...`` on stderr for a user error."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except InputError as err:
        parser.print_usage(sys.stderr)
        print(f'error: {err}', file=sys.stderr)
        return 1
    except SystemExit as done:  # --help
        return int(done.code or 0)
    try:
        output = Output(args.msg_format, args.storage, args.topic, args.truth_topic, args.force)
        if args.source == SYNTHETIC:
            summary = make_synthetic_bag(
                args.out_bag,
                num_features=args.num_features,
                num_frames=args.num_frames,
                objects=parse_objects(args.objects or ['0.2:30', '0.15:0:60']),
                death_rate=args.death_rate,
                noise=args.noise,
                seed=args.seed,
                output=output,
            )
        else:
            summary = make_bag(
                args.source,
                args.out_bag,
                rate=args.rate,
                frames=parse_frames(args.frame_list) if args.frame_list is not None else None,
                output=output,
            )
    except (PearlError, OSError) as err:
        print(f'error: {one_line(err, None)}', file=sys.stderr)
        return 1
    print(summary)
    return 0


def make_bag(
    mat_file: str | Path,
    out_bag: str | Path,
    *,
    rate: float = 30.0,
    frames: Sequence[int] | None = None,
    output: Output = Output(),
) -> str:
    """Write the bag of a Hopkins-format file; returns a one-line summary.

    ``frames`` (0-based, negative from the end) keeps only those frames, with the stamps they
    have in the whole sequence. Raises InputError / BagError on bad input.
    """
    if not (math.isfinite(rate) and rate > 0):
        raise InputError(f'rate must be a finite frequency > 0 Hz, got {rate}')
    mat_file, out_bag = Path(mat_file), Path(out_bag)
    if not mat_file.is_file():
        raise InputError(f'no such .mat file: {mat_file}')
    output.check(out_bag)
    sequence = load_mat(mat_file)
    normalized = normaliser(scipy.io.loadmat(str(mat_file)), mat_file)
    num_frames, num_points, _ = sequence.tracks.shape
    kept = select_frames(frames, num_frames) if frames is not None else list(range(num_frames))
    stamps = [EPOCH_NS + round(index * 1e9 / rate) for index in kept]
    ids = np.arange(num_points, dtype=np.int64)

    def feature_frames() -> Iterator[FeatureFrame]:
        for stamp, index in zip(stamps, kept, strict=True):
            yield FeatureFrame(stamp, ids, sequence.tracks[index])

    truth = ((stamp, ids, sequence.labels) for stamp in stamps)
    which = '' if frames is None else f' (frames {",".join(map(str, kept))} of {num_frames})'
    return output.write(out_bag, feature_frames(), truth, normalized, what=(
        f'{len(kept)} frames{which} x {num_points} points, {sequence.num_motions} motions'))


def make_synthetic_bag(
    out_bag: str | Path,
    *,
    num_features: int = 300,
    num_frames: int = 90,
    objects: Sequence[BodySpec] = (BodySpec(0.2, start=30), BodySpec(0.15, stop=60)),
    death_rate: float = 0.02,
    noise: float = 0.5,
    seed: int = 0,
    output: Output = Output(),
) -> str:
    """Write a bag of :func:`~pearl_ros.datasets.synthetic.synthetic_stream`; a summary line.

    Frames are 30 Hz apart from :data:`EPOCH_NS`. Ground truth is published per frame with
    that frame's stamp: labels change over time (an object not moving on its own is background,
    0) and ids are reused. Normalised coordinates come from a nominal camera
    (:data:`SYNTHETIC_FOCAL`, :data:`SYNTHETIC_CENTRE`).
    """
    out_bag = Path(out_bag)
    for name, value, low in (('num_features', num_features, 1), ('num_frames', num_frames, 1)):
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise InputError(f'{name} must be an integer >= {low}, got {value!r}')
    if not (math.isfinite(death_rate) and 0 <= death_rate < 1):
        raise InputError(f'death_rate must be in [0, 1), got {death_rate}')
    if not (math.isfinite(noise) and noise >= 0):
        raise InputError(f'noise must be a finite number of pixels >= 0, got {noise}')
    if sum(o.share for o in objects) >= 1:
        raise InputError('objects must leave a positive share of features to the background')
    output.check(out_bag)
    stream = list(synthetic_stream(num_features, num_frames, tuple(objects), death_rate, noise,
                                   seed, start_ns=EPOCH_NS))
    frames = [FeatureFrame(f.stamp_ns, f.ids, f.uv) for f in stream]
    truth = [(f.stamp_ns, f.ids, f.truth) for f in stream]
    centre = np.asarray(SYNTHETIC_CENTRE)

    def normalized(uv: np.ndarray) -> np.ndarray:
        """(N, 2) pixels -> (N, 2) normalised coordinates of the nominal camera."""
        xy: np.ndarray = (uv - centre) / SYNTHETIC_FOCAL
        return xy

    ids = set().union(*(f.ids.tolist() for f in stream))
    return output.write(out_bag, frames, truth, normalized, truth_note=' per frame', what=(
        f'synthetic, {num_frames} frames x {num_features} features ({len(ids)} ids), '
        f'{len(objects)} objects'))


def parse_frames(text: str) -> list[int]:
    """``'0,-1'`` -> ``[0, -1]``."""
    try:
        return [int(item) for item in text.split(',')]
    except ValueError as err:
        raise InputError(f'--frames must be integers separated by commas, got {text!r}') from err


def select_frames(frames: Sequence[int], num_frames: int) -> list[int]:
    """Frame indices (negative from the end) resolved, checked in range and increasing."""
    kept = []
    for index in frames:
        resolved = index + num_frames if index < 0 else index
        if not 0 <= resolved < num_frames:
            raise InputError(f'frame {index} is outside the {num_frames} frames of the sequence')
        kept.append(resolved)
    if not kept or any(b <= a for a, b in itertools.pairwise(kept)):
        raise InputError(f'frames must be increasing and distinct, got {list(frames)}')
    return kept


def parse_objects(items: Sequence[str]) -> list[BodySpec]:
    """``'SHARE[:START[:STOP]]'`` strings -> BodySpec (``'0.15:0:60'``; ``'0.2:30'``)."""
    specs = []
    for item in items:
        parts = item.split(':')
        try:
            if not 1 <= len(parts) <= 3:
                raise ValueError(item)
            share = float(parts[0])
            start = int(parts[1]) if len(parts) > 1 and parts[1] else 0
            stop = int(parts[2]) if len(parts) > 2 and parts[2] else None
        except ValueError as err:
            raise InputError(f'--object must be SHARE[:START[:STOP]], got {item!r}') from err
        if not (math.isfinite(share) and 0 < share < 1) or start < 0 or (
                stop is not None and stop <= start):
            raise InputError(f'--object {item!r}: need 0 < share < 1, start >= 0, stop > start')
        specs.append(BodySpec(share, start, stop))
    return specs


def normaliser(
    mat: dict[str, np.ndarray], source: str | Path = '.mat file'
) -> Callable[[np.ndarray], np.ndarray] | None:
    """Pixels -> normalised coordinates as the .mat file defines them.

    From the fields ``y`` (pixels) and ``x`` (normalised) when both exist: the affine map
    ``x = A [u, v, 1]^T`` fitted by least squares must reproduce ``x`` exactly (a few sequences,
    e.g. ``three-cars``, carry a ``K`` that does not match ``x``). Else from ``K`` (``K^-1``).
    None when the file has neither: pixels stand in for normalised coordinates.
    """
    if 'x' in mat:
        y = np.asarray(mat['y'], dtype=np.float64)
        x = np.asarray(mat['x'], dtype=np.float64)
        if x.shape != y.shape:
            raise InputError(f'{source}: fields x {x.shape} and y {y.shape} differ in shape')
        pixels = (y[:2] / y[2:3]).reshape(2, -1).T
        normal = (x[:2] / x[2:3]).reshape(2, -1).T
        design = np.column_stack((pixels, np.ones(len(pixels))))
        affine, *_ = np.linalg.lstsq(design, normal, rcond=None)  # (3, 2)
        error = np.abs(design @ affine - normal).max()
        if not error <= 1e-6 * max(1.0, np.abs(normal).max()):
            raise InputError(f'{source}: field x is not an affine image of y (error {error:.3g})')
    elif 'K' in mat:
        intrinsics = np.asarray(mat['K'], dtype=np.float64)
        if intrinsics.shape != (3, 3) or not np.allclose(intrinsics[2], (0, 0, 1)):
            raise InputError(f'{source}: field K must be 3 x 3 with last row 0 0 1')
        try:
            affine = np.linalg.inv(intrinsics)[:2].T  # (3, 2)
        except np.linalg.LinAlgError as err:
            raise InputError(f'{source}: field K is singular') from err
    else:
        return None

    def normalized(uv: np.ndarray) -> np.ndarray:
        """(N, 2) pixels -> (N, 2) normalised coordinates."""
        xy: np.ndarray = uv @ affine[:2] + affine[2]
        return xy

    return normalized


def _is_bag(path: Path) -> bool:
    """A rosbag2 folder, a storage file or a ROS 1 bag file: what --force may delete."""
    return is_bag(path) or (path.is_file() and path.suffix == '.bag')


if __name__ == '__main__':
    sys.exit(main())
