"""``pearl_render``: the motion labels of a bag drawn as a video.

Any labels bag will do: ``pearl_replay``'s or ``pearl_video``'s output, or a recording of
``pearl_node``'s ``motion_labels`` (``sensor_msgs/msg/PointCloud2`` with fields ``id``, ``u``,
``v``, ``label``). When the bag has an image topic (``sensor_msgs/msg/Image``) the labels are
drawn on the image of the same header stamp, one video frame per matched image, in the images'
order; otherwise on a black canvas of the labels' extent (640 x 480 when there are no points),
one video frame per labels message. Example::

    pearl_render build/demo_labels --output build/demo_labels.mp4
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from pearl_ros.bagio import decode
from pearl_ros.bagio.reader import POINTCLOUD2, bag_messages, open_bag
from pearl_ros.cli.video import video_writer
from pearl_ros.core.errors import BagError, InputError, PearlError, UsageParser, one_line
from pearl_ros.tracking.draw import Overlay, to_bgr
from pearl_ros.tracking.image import image_to_array

LABELS_TOPIC = '/motion_labels'
IMAGE = 'sensor_msgs/msg/Image'
CANVAS = (640, 480)  # width, height of the blank canvas when the labels have no points
DEFAULT_FPS = 30.0


def build_parser() -> argparse.ArgumentParser:
    parser = UsageParser(
        prog='pearl_render',
        description='Draw the motion labels of a bag (pearl_replay, pearl_video or a recording '
        "of pearl_node's motion_labels) on the bag's images, or on a blank canvas when it has "
        'none, and write them as a video (mp4v).',
    )
    parser.add_argument('labels_bag', type=Path, metavar='LABELS_BAG',
                        help='ROS 2 bag folder, .mcap/.db3 file, or ROS 1 .bag')
    parser.add_argument('--output', '-o', type=Path, required=True, metavar='OUT.mp4',
                        help='video file to write')
    parser.add_argument('--labels-topic', default=None,
                        help=f'labels topic (default {LABELS_TOPIC}, else the one PointCloud2 '
                        'topic)')
    parser.add_argument('--image-topic', default=None,
                        help="image topic (default: the bag's image topic with messages, the "
                        'first by name if several; none: a blank canvas)')
    parser.add_argument('--fps', type=float, default=None,
                        help='frame rate of the video (default: from the stamps, else 30)')
    parser.add_argument('--force', action='store_true', help='replace OUT.mp4 if it exists')
    return parser


@dataclass(frozen=True)
class LabelFrame:
    """One labels message: stamp (int ns), ids (N,), uv (N, 2) px, labels (N,)."""

    stamp_ns: int
    ids: np.ndarray
    uv: np.ndarray
    labels: np.ndarray


def pick_topics(path: Path, labels_topic: str | None, image_topic: str | None
                ) -> tuple[str, str | None]:
    """The labels topic and the image topic (None: no images) of the bag ``path``."""
    with open_bag(path) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        counts = {c.topic: 0 for c in reader.connections}
        for connection in reader.connections:
            counts[connection.topic] += connection.msgcount
    clouds = sorted(t for t, kind in types.items() if kind == POINTCLOUD2)
    if labels_topic is None:
        if LABELS_TOPIC in clouds or len(clouds) != 1:
            labels_topic = LABELS_TOPIC
        else:
            labels_topic = clouds[0]
    if types.get(labels_topic) != POINTCLOUD2:
        listing = ', '.join(f'{t} ({k})' for t, k in sorted(types.items())) or 'none'
        raise BagError(f'{path}: no PointCloud2 topic {labels_topic}; topics: {listing}')
    images = sorted(t for t, kind in types.items() if kind == IMAGE and counts[t])
    if image_topic is not None and types.get(image_topic) != IMAGE:
        raise BagError(f'{path}: no sensor_msgs/msg/Image topic {image_topic}; image topics '
                       'with messages: '
                       f'{", ".join(images) or "none"}')
    return labels_topic, image_topic or (images[0] if images else None)


def read_labels(path: Path, topic: str) -> list[LabelFrame]:
    """Every labels message of ``topic``, in recording order."""
    frames = []
    with open_bag(path) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        for index, (_, msg) in enumerate(bag_messages(reader, path, connections)):
            try:
                columns = decode.decode_fields(msg, ('id', 'u', 'v', 'label'))
                ids = decode.integer_ids(columns['id'], 'label ids')
                labels = decode.integer_ids(columns['label'], 'labels')
            except InputError as err:
                raise BagError(f'{path}: message {index} on {topic}: {err}') from err
            uv = np.column_stack([columns['u'], columns['v']]).astype(np.float64)
            frames.append(LabelFrame(decode.stamp_ns(msg.header), ids, uv, labels))
    if not frames:
        raise BagError(f'{path}: no messages on {topic}')
    return frames


def frame_rate(frames: Sequence[LabelFrame]) -> float:
    """Frames per second from the median stamp step (30 with fewer than two frames)."""
    steps = np.diff([frame.stamp_ns for frame in frames])
    steps = steps[steps > 0]
    if steps.size == 0:
        return DEFAULT_FPS
    return float(np.clip(1e9 / np.median(steps), 1.0, 240.0))


def canvas_size(frames: Sequence[LabelFrame]) -> tuple[int, int]:
    """(width, height): the labels' extent (even, at least 16 px), 640 x 480 without points."""
    points = [frame.uv for frame in frames if len(frame.uv)]
    if not points:
        return CANVAS
    top = np.max(np.concatenate(points), axis=0)
    width, height = (max(16, 2 * math.ceil((float(value) + 1) / 2)) for value in top)
    return int(min(width, 8192)), int(min(height, 8192))


def images(path: Path, topic: str, wanted: set[int]) -> Iterator[tuple[int, np.ndarray]]:
    """``(stamp_ns, bgr image)`` of the images on ``topic`` whose stamp is in ``wanted``."""
    with open_bag(path) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        for _, msg in bag_messages(reader, path, connections):
            stamp = decode.stamp_ns(msg.header)
            if stamp in wanted:
                yield stamp, to_bgr(image_to_array(msg), str(msg.encoding))


def render(args: argparse.Namespace) -> tuple[int, int, str]:
    """Write the video; (frames written, labels messages, what they were drawn on)."""
    if (args.output.exists() or args.output.is_symlink()) and not args.force:
        raise InputError(f'{args.output} exists; pass --force to replace it')
    if not args.output.parent.is_dir():
        raise InputError(f'output folder does not exist: {args.output.parent}')
    labels_topic, image_topic = pick_topics(args.labels_bag, args.labels_topic, args.image_topic)
    frames = read_labels(args.labels_bag, labels_topic)
    fps = args.fps if args.fps is not None else frame_rate(frames)
    if not (np.isfinite(fps) and fps > 0):
        raise InputError(f'--fps must be a positive number, got {fps}')
    overlay = Overlay()
    if image_topic is None:
        size = canvas_size(frames)
        with video_writer(args.output, fps, size) as video:
            assert video is not None
            for frame in frames:
                blank = np.zeros((size[1], size[0], 3), np.uint8)
                video.write(overlay.draw(blank, frame.ids, frame.uv, frame.labels))
        return len(frames), len(frames), 'a blank canvas'
    by_stamp = {frame.stamp_ns: frame for frame in frames}
    pictures = images(args.labels_bag, image_topic, set(by_stamp))
    first = next(pictures, None)
    if first is None:
        raise BagError(f'{args.labels_bag}: no image on {image_topic} has the stamp of a '
                       f'labels message on {labels_topic}')
    size = (int(first[1].shape[1]), int(first[1].shape[0]))
    written = 0
    with video_writer(args.output, fps, size) as video:
        assert video is not None
        for stamp, picture in itertools.chain([first], pictures):
            if (picture.shape[1], picture.shape[0]) != size:
                picture = cv2.resize(picture, size)
            frame = by_stamp[stamp]
            video.write(overlay.draw(picture, frame.ids, frame.uv, frame.labels))
            written += 1
    return written, len(frames), f'the images of {image_topic}'


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``pearl_render``; 0 on success, 1 with one ``error:`` line otherwise."""
    try:
        try:
            args = build_parser().parse_args(argv)
        except SystemExit as done:  # --help
            return int(done.code or 0)
        written, total, ground = render(args)
    except (PearlError, OSError, cv2.error) as err:
        print(f'error: {one_line(err, 400)}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print('error: interrupted; no output written', file=sys.stderr)
        return 1
    print(f'wrote {args.output}: {written} frames ({total} labels messages) drawn on {ground}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
