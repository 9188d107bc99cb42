"""``pearl_video``: a video file through the tracker and the node's segmenter, into a bag.

No ROS graph: every frame of a file OpenCV reads is tracked (:class:`FeatureTracker`, as
``pearl_tracker``), its VINS-Mono ``PointCloud`` built and then segmented by the per-message
pipeline ``pearl_node`` runs (:class:`~pearl_ros.pipeline.messages.MessagePipeline`), so the
labels are those the live chain ``pearl_tracker`` -> ``pearl_node`` would publish. Example::

    pearl_video clip.mp4 --output-bag build/clip_labels --annotated build/clip_labels.mp4

The output bag holds, one message each per video frame in frame order, stamped ``i / fps``:

- ``/feature_tracker/feature``: ``sensor_msgs/msg/PointCloud`` in the VINS-Mono layout; with no
  intrinsics known the points are pixels ``(u, v, 1)``; channels ``id_of_point``, ``u_of_point``,
  ``v_of_point``, ``velocity_x_of_point``, ``velocity_y_of_point`` (px/s);
- ``/motion_labels``: ``sensor_msgs/msg/PointCloud2``, fields ``id``, ``u``, ``v``, ``label``
  as the node publishes them (empty for a frame without features);
- with ``--image-topic TOPIC``, the frames themselves (``sensor_msgs/msg/Image``, bgr8), which
  ``pearl_render`` then draws the labels on.

Parameters are ``pearl_node``'s (``--params FILE.yaml``, then ``--set NAME=VALUE``).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from pearl_ros.bagio import encode
from pearl_ros.bagio.reader import POINTCLOUD, POINTCLOUD2, TYPESTORE, FeatureFrame
from pearl_ros.bagio.writer import open_output_bag, stamped_header, vins_pointcloud
from pearl_ros.cli.progress import ProgressBar
from pearl_ros.core.errors import InputError, PearlError, UsageParser, one_line
from pearl_ros.pipeline import settings as pipeline_settings
from pearl_ros.pipeline.messages import Labelled, MessagePipeline
from pearl_ros.pipeline.threads import limit_blas_threads
from pearl_ros.tracking import image as image_io
from pearl_ros.tracking.draw import Overlay
from pearl_ros.tracking.tracker import FeatureTracker, Tracks

FEATURE_TOPIC = '/feature_tracker/feature'
LABELS_TOPIC = '/motion_labels'
DEFAULT_FPS = 30.0
FRAME_ID = 'camera'
# PointCloud ids are float32: exact only up to 2**24, so ids are written modulo it (as
# pearl_tracker publishes them); an id comes back only after 2**24 newer tracks.
ID_MODULUS = 2**24
IMAGE = 'sensor_msgs/msg/Image'
MESSAGE_TYPES = encode.MessageTypes.from_typestore(TYPESTORE)
_Image: Any = TYPESTORE.types[IMAGE]


def build_parser() -> argparse.ArgumentParser:
    parser = UsageParser(
        prog='pearl_video',
        description='Track the features of a video file, segment them with the online segmenter '
        '(the code pearl_node runs) and write features and motion labels to a ROS 2 bag, and '
        'optionally the video with the labels drawn on it.',
    )
    parser.add_argument('video', type=Path, metavar='VIDEO', help='any file OpenCV reads')
    parser.add_argument('--output-bag', '-o', type=Path, required=True, metavar='OUT_BAG',
                        help='ROS 2 bag folder to create (not named *.bag)')
    parser.add_argument('--annotated', type=Path, metavar='OUT.mp4',
                        help='also write the video with the labels drawn on it (mp4v)')
    parser.add_argument('--image-topic', metavar='TOPIC',
                        help='also write every frame to the bag on TOPIC (sensor_msgs/Image, '
                        'bgr8), for pearl_render to draw on; off by default (large bags)')
    parser.add_argument('--params', type=Path, metavar='YAML',
                        help="parameter file: pearl_node's ROS parameter file or name: value")
    parser.add_argument('--set', dest='assignments', action='extend', nargs='+', default=[],
                        metavar='NAME=VALUE', help='set a parameter (after --params)')
    parser.add_argument('--fps', type=float, default=None,
                        help=f"frame rate for the stamps (default: the file's, else "
                        f'{DEFAULT_FPS:g})')
    parser.add_argument('--force', action='store_true',
                        help='replace OUT_BAG (if it is a bag) and OUT.mp4 if they exist')
    parser.add_argument('--progress', choices=('auto', 'on', 'off'), default='auto',
                        help='progress bar on stderr (auto: when stderr is a terminal)')
    return parser


@dataclass
class VideoStats:
    """What a run did: frames, features per frame, motions per frame, wall time."""

    output: str
    features: list[int] = field(default_factory=list)
    motions: list[int] = field(default_factory=list)
    wall_s: float = 0.0

    def line(self) -> str:
        frames = len(self.features)
        mean = float(np.mean(self.features)) if frames else 0.0
        last = self.motions[-1] if self.motions else 0
        rate = frames / self.wall_s if self.wall_s > 0 else 0.0
        return (f'wrote {self.output}: {frames} frames, {mean:.1f} features per frame, '
                f'{last} motions in the last frame, {rate:.1f} frames/s')


class VideoSource:
    """The frames of a video file (BGR uint8) and their stamps, from its frame rate.

    Raises
    ------
    InputError
        The file is missing or OpenCV cannot read a first frame from it.
    """

    def __init__(self, path: Path, fps: float | None = None) -> None:
        if not path.is_file():
            raise InputError(f'video not found: {path}')
        self._capture = cv2.VideoCapture(str(path))
        ok, first = self._capture.read() if self._capture.isOpened() else (False, None)
        if not ok or first is None:
            self._capture.release()
            raise InputError(f'cannot read video {path}: OpenCV decodes no frame from it')
        self._first: np.ndarray | None = first
        if fps is not None and not (np.isfinite(fps) and fps > 0):
            raise InputError(f'--fps must be a positive number, got {fps}')
        found = float(self._capture.get(cv2.CAP_PROP_FPS) or 0.0)
        self.fps = fps or (found if np.isfinite(found) and 0 < found < 1000 else DEFAULT_FPS)
        self.count = max(int(self._capture.get(cv2.CAP_PROP_FRAME_COUNT) or 0), 0)
        self.size = (int(first.shape[1]), int(first.shape[0]))  # width, height

    def __iter__(self) -> Iterator[tuple[int, np.ndarray]]:
        """``(stamp_ns, frame)`` in file order; frame ``i`` is stamped ``i / fps``."""
        index = 0
        frame = self._first
        self._first = None
        while frame is not None:
            yield round(index * 1e9 / self.fps), frame
            index += 1
            ok, frame = self._capture.read()
            frame = frame if ok else None

    def close(self) -> None:
        self._capture.release()


def features_message(stamp_ns: int, tracks: Tracks, previous: FeatureFrame | None
                     ) -> tuple[Any, FeatureFrame]:
    """The VINS-Mono PointCloud of one frame's tracks (points in pixels), and its frame (the
    ``previous`` of the next call: velocities are differences of it, px/s)."""
    frame = FeatureFrame(stamp_ns, tracks.ids % ID_MODULUS, tracks.uv)
    return vins_pointcloud(frame, frame.uv, previous, stamped_header(stamp_ns, FRAME_ID)), frame


def labels_of(msg: Any, pipeline: MessagePipeline) -> tuple[Any, np.ndarray, int]:
    """``motion_labels``, labels ``(N,)`` and motion count of one feature message.

    A frame without features (which the node would skip) gets an empty ``motion_labels``, so
    that every video frame has one.
    """
    outcome = pipeline.process(msg)
    if isinstance(outcome, Labelled):
        return outcome.labels_msg, outcome.labels, int(outcome.result.motions)
    if len(msg.points):
        raise InputError(f'frame at {msg.header.stamp.sec} s: {outcome.reason}')
    empty = np.zeros(0, np.int64)
    labels_msg = encode.motion_labels(msg.header, empty, np.zeros((0, 2)), empty, MESSAGE_TYPES)
    return labels_msg, empty, 0


def image_message(header: Any, image: np.ndarray) -> Any:
    """A bgr8 ``sensor_msgs/msg/Image`` of ``image`` (H, W, 3) uint8 with ``header``."""
    fields = image_io.array_to_image_fields(image, 'bgr8')
    fields['data'] = np.frombuffer(fields['data'], np.uint8)  # rosbags stores uint8 arrays
    return _Image(header=header, **fields)


def check_outputs(args: argparse.Namespace) -> None:
    """Fail before any work when an output exists (without ``--force``) or cannot be written."""
    outputs = [args.output_bag] + ([args.annotated] if args.annotated is not None else [])
    for path in outputs:
        if (path.exists() or path.is_symlink()) and not args.force:
            raise InputError(f'{path} exists; pass --force to replace it')
        if not path.parent.is_dir():
            raise InputError(f'output folder does not exist: {path.parent}')
    if args.image_topic is not None and args.image_topic in ('', FEATURE_TOPIC, LABELS_TOPIC):
        raise InputError(f'--image-topic must be a new topic name, got {args.image_topic!r}')
    if args.annotated is not None:
        if args.annotated.is_dir():
            raise InputError(f'--annotated {args.annotated} is a folder')
        if args.annotated.resolve() == args.output_bag.resolve():
            raise InputError('--annotated and --output-bag are the same path')


@contextmanager
def video_writer(path: Path | None, fps: float, size: tuple[int, int]
                 ) -> Iterator[cv2.VideoWriter | None]:
    """An mp4v writer of ``size`` (width, height) frames whose file appears at ``path`` only
    when the block completes (written beside it under a hidden name first); None if no path."""
    if path is None:
        yield None
        return
    handle, name = tempfile.mkstemp(prefix=f'.{path.stem}.', suffix=path.suffix or '.mp4',
                                    dir=path.parent)
    os.close(handle)
    writer = cv2.VideoWriter(name, cv2.VideoWriter.fourcc(*'mp4v'), fps, size)
    try:
        if not writer.isOpened():
            raise InputError(f'cannot write video {path}: OpenCV has no mp4v writer for it')
        yield writer
        writer.release()
        os.replace(name, path)
    finally:
        writer.release()
        Path(name).unlink(missing_ok=True)


def run(args: argparse.Namespace, progress: ProgressBar | None = None) -> VideoStats:
    """Track, segment and write every frame of ``args.video`` (module docstring)."""
    settings = pipeline_settings.from_sources(
        [args.params] if args.params is not None else [], args.assignments)
    check_outputs(args)
    source = VideoSource(args.video, args.fps)
    start = time.perf_counter()
    stats = VideoStats(str(args.output_bag))
    tracker, pipeline, overlay = FeatureTracker(), MessagePipeline(settings), Overlay()
    previous: FeatureFrame | None = None
    try:
        with open_output_bag(args.output_bag, replace=args.force) as out, \
                video_writer(args.annotated, source.fps, source.size) as video:
            out.add_topic(FEATURE_TOPIC, POINTCLOUD)
            out.add_topic(LABELS_TOPIC, POINTCLOUD2)
            if args.image_topic:
                out.add_topic(args.image_topic, IMAGE)
            for stamp, image in source:
                tracks = tracker.track(image, stamp)
                msg, previous = features_message(stamp, tracks, previous)
                labels_msg, labels, motions = labels_of(msg, pipeline)
                out.write(FEATURE_TOPIC, stamp, msg)
                out.write(LABELS_TOPIC, stamp, labels_msg)
                if args.image_topic:
                    out.write(args.image_topic, stamp, image_message(msg.header, image))
                if video is not None:
                    video.write(overlay.draw(image, previous.ids, previous.uv, labels))
                stats.features.append(len(tracks))
                stats.motions.append(motions)
                if progress is not None:
                    progress(len(stats.features), source.count)
    finally:
        source.close()
    stats.wall_s = time.perf_counter() - start
    return stats


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``pearl_video``; 0 on success, 1 with one ``error:`` line otherwise."""
    bar: ProgressBar | None = None
    try:
        try:
            args = build_parser().parse_args(argv)
        except SystemExit as done:  # --help
            return int(done.code or 0)
        show = args.progress == 'on' or (args.progress == 'auto' and sys.stderr.isatty())
        limit_blas_threads()  # as pearl_node runs: the segmenter's second thread needs the core
        bar = ProgressBar(sys.stderr, 'frames') if show else None
        stats = run(args, bar)
    except (PearlError, OSError, cv2.error) as err:
        print(f'error: {one_line(err, 400)}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print('error: interrupted; no output written', file=sys.stderr)
        return 1
    finally:
        if bar is not None:
            bar.close()
    line = stats.line()
    if args.annotated is not None:
        line += f'; annotated video {args.annotated}'
    print(line)
    return 0


if __name__ == '__main__':
    sys.exit(main())
