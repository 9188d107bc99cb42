"""``pearl_make_bag``: turn a Hopkins-format ``*_truth.mat`` file into a ROS 2 bag of features.

One message per frame at ``--rate`` Hz, stamps from a fixed epoch (output is deterministic),
feature ids ``0..P-1`` in the column order of the file, pixels from ``y``, normalised coordinates
from ``x`` (or ``K^-1 y``), and one ground-truth message per frame with labels ``0..k-1`` (the
file's groups ``s`` renumbered in increasing order).

Example::

    pearl_make_bag ../shared/data/hopkins155/cars2/cars2_truth.mat bags/cars2
"""

from __future__ import annotations

import argparse
import math
import shutil
import sys
import tempfile
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import numpy as np
import scipy.io

from pearl_ros.bagio.reader import FeatureFrame
from pearl_ros.bagio.writer import FORMATS, STORAGES, write_feature_bag
from pearl_ros.core.errors import InputError, PearlError
from pearl_ros.datasets.hopkins import load_mat

EPOCH_NS = 1_700_000_000 * 1_000_000_000  # stamp of the first frame, int ns (2023-11-14)


class _UsageError(Exception):
    """argparse found a bad command line."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # type: ignore[override]
        raise _UsageError(message)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog='pearl_make_bag',
        description='Convert a Hopkins-format *_truth.mat file into a ROS 2 bag of tracked '
        'features with ground-truth labels.',
    )
    parser.add_argument('mat_file', type=Path, help='Hopkins-format <name>_truth.mat file')
    parser.add_argument('out_bag', type=Path, help='bag folder to create (name it without .bag)')
    parser.add_argument('--rate', type=float, default=30.0, help='frame rate, Hz (default 30)')
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
    except _UsageError as err:
        parser.print_usage(sys.stderr)
        print(f'error: {err}', file=sys.stderr)
        return 1
    except SystemExit as done:  # --help
        return int(done.code or 0)
    try:
        summary = make_bag(
            args.mat_file,
            args.out_bag,
            rate=args.rate,
            msg_format=args.msg_format,
            storage=args.storage,
            topic=args.topic,
            truth_topic=args.truth_topic,
            force=args.force,
        )
    except (PearlError, OSError) as err:
        print(f'error: {" ".join(str(err).split())}', file=sys.stderr)
        return 1
    print(summary)
    return 0


def make_bag(
    mat_file: str | Path,
    out_bag: str | Path,
    *,
    rate: float = 30.0,
    msg_format: str = 'pointcloud',
    storage: str = 'mcap',
    topic: str = '/feature_tracker/feature',
    truth_topic: str = '/ground_truth/labels',
    force: bool = False,
) -> str:
    """Write the bag; returns a one-line summary. Raises InputError / BagError on bad input."""
    if not (math.isfinite(rate) and rate > 0):
        raise InputError(f'rate must be a finite frequency > 0 Hz, got {rate}')
    mat_file, out_bag = Path(mat_file), Path(out_bag)
    if not mat_file.is_file():
        raise InputError(f'no such .mat file: {mat_file}')
    replace = out_bag.exists() or out_bag.is_symlink()
    if replace and not force:
        raise InputError(f'{out_bag} exists; pass --force to replace it')
    if replace and not _is_bag(out_bag):
        raise InputError(f'refusing to replace {out_bag}: it is not a bag (no metadata.yaml)')

    sequence = load_mat(mat_file)
    normalized = normaliser(scipy.io.loadmat(str(mat_file)), mat_file)
    num_frames, num_points, _ = sequence.tracks.shape
    stamps = [EPOCH_NS + round(index * 1e9 / rate) for index in range(num_frames)]
    ids = np.arange(num_points, dtype=np.int64)

    def frames() -> Iterator[FeatureFrame]:
        for stamp, uv in zip(stamps, sequence.tracks, strict=True):
            yield FeatureFrame(stamp, ids, uv)

    truth = ((stamp, ids, sequence.labels) for stamp in stamps)

    def write(target: Path) -> None:
        write_feature_bag(
            target,
            frames(),
            truth,
            topic=topic,
            truth_topic=truth_topic,
            msg_format=msg_format,
            storage=storage,
            normalized=normalized,
        )

    if not replace:
        write(out_bag)
    else:
        # Write the new bag aside first: a failure leaves the old one in place.
        staging = Path(tempfile.mkdtemp(prefix=f'.{out_bag.name}.', dir=out_bag.parent))
        try:
            write(staging / out_bag.name)
            if out_bag.is_dir() and not out_bag.is_symlink():
                shutil.rmtree(out_bag)
            else:
                out_bag.unlink()
            (staging / out_bag.name).rename(out_bag)
        finally:
            shutil.rmtree(staging, ignore_errors=True)
    return (
        f'wrote {out_bag}: {num_frames} frames x {num_points} points, '
        f'{sequence.num_motions} motions, {FORMATS[msg_format]} on {topic}, '
        f'labels on {truth_topic}, {storage}'
    )


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
    """A rosbag2 folder, or a single storage file: what --force may delete."""
    if path.is_dir():
        return (path / 'metadata.yaml').is_file()
    return path.suffix in ('.mcap', '.db3')


if __name__ == '__main__':
    sys.exit(main())
