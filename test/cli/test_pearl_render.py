"""pearl_render on labels bags written here with rosbags: with an image topic, and without one.

Oracles: the stamps written (which labels have an image), the positions and labels of the points
(a motion's dot is coloured, an outlier's grey, on a grey image), the canvas size rule.
(pearl_render of pearl_video's own output is tested in test_video.py.)
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from pearl_ros.bagio import encode
from pearl_ros.bagio.reader import POINTCLOUD2, TYPESTORE
from pearl_ros.bagio.writer import open_output_bag
from pearl_ros.cli.render import main
from pearl_ros.tracking.image import array_to_image_fields

TYPES = encode.MessageTypes.from_typestore(TYPESTORE)
Header: Any = TYPESTORE.types['std_msgs/msg/Header']
Time: Any = TYPESTORE.types['builtin_interfaces/msg/Time']
Image: Any = TYPESTORE.types['sensor_msgs/msg/Image']
STEP = 100_000_000  # ns: 10 Hz
HEIGHT, WIDTH = 240, 320
# (id, u, v, label): two motions and an outlier, far apart.
POINTS = np.array([(1, 60.0, 60.0, 0), (2, 250.0, 60.0, 1), (3, 160.0, 180.0, -1)])


def header(stamp: int) -> Any:
    sec, nanosec = divmod(stamp, 1_000_000_000)
    return Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id='camera')


def write_bag(path: Path, image_stamps: list[int], label_stamps: list[int],
              encoding: str = 'mono8', points: np.ndarray = POINTS) -> None:
    grey = np.full((HEIGHT, WIDTH), 128, np.uint8)
    pixels = grey if encoding == 'mono8' else np.dstack([grey] * 3)
    events = [(s, 'image') for s in image_stamps] + [(s, 'labels') for s in label_stamps]
    with open_output_bag(path) as out:
        out.add_topic('/camera/image_raw', 'sensor_msgs/msg/Image')
        out.add_topic('/motion_labels', POINTCLOUD2)
        for stamp, kind in sorted(events):
            if kind == 'image':
                fields = array_to_image_fields(pixels, encoding)
                fields['data'] = np.frombuffer(fields['data'], np.uint8)  # rosbags: uint8 array
                msg = Image(header=header(stamp), **fields)
                out.write('/camera/image_raw', stamp, msg)
            else:
                msg = encode.motion_labels(header(stamp), points[:, 0].astype(np.int64),
                                           points[:, 1:3], points[:, 3].astype(np.int64), TYPES)
                out.write('/motion_labels', stamp, msg)


def frames_of(path: Path) -> list[np.ndarray]:
    capture = cv2.VideoCapture(str(path))
    frames = []
    ok, frame = capture.read()
    while ok:
        frames.append(frame)
        ok, frame = capture.read()
    capture.release()
    return frames


def spread(frame: np.ndarray, u: float, v: float) -> int:
    """How far from grey the pixel at (u, v) is: its channels' range."""
    pixel = frame[int(v), int(u)].astype(int)
    return int(pixel.max() - pixel.min())


@pytest.mark.parametrize('encoding', ['mono8', 'rgb8'])
def test_labels_are_drawn_on_the_images_of_their_stamps(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], encoding: str) -> None:
    bag, out = tmp_path / 'bag', tmp_path / 'out.mp4'
    # Images at 0..4; labels at 1, 2, 3 and at 7 (no image: not drawn).
    write_bag(bag, [i * STEP for i in range(5)], [i * STEP for i in (1, 2, 3, 7)], encoding)
    assert main([str(bag), '--output', str(out)]) == 0
    assert 'the images of /camera/image_raw' in capsys.readouterr().out
    frames = frames_of(out)
    assert len(frames) == 3
    assert frames[0].shape == (HEIGHT, WIDTH, 3)
    for frame in frames:
        assert spread(frame, 60, 60) > 60 and spread(frame, 250, 60) > 60
        assert spread(frame, 160, 180) < 30  # outlier: grey
        assert abs(int(frame[120, 60].mean()) - 128) < 15  # the image itself, undrawn
    # Two motions, two colours.
    first = frames[0].astype(int)
    assert np.abs(first[60, 60] - first[60, 250]).max() > 60


def test_without_images_the_canvas_is_the_labels_extent(tmp_path: Path) -> None:
    bag, out = tmp_path / 'bag', tmp_path / 'out.mp4'
    write_bag(bag, [], [i * STEP for i in range(4)])
    assert main([str(bag), '--output', str(out)]) == 0
    frames = frames_of(out)
    assert len(frames) == 4
    assert frames[0].shape == (182, 252, 3)  # max v 180, max u 250: + 1, rounded up to even
    assert spread(frames[0], 60, 60) > 60


def test_without_images_or_points_the_canvas_is_640_by_480(tmp_path: Path) -> None:
    bag, out = tmp_path / 'bag', tmp_path / 'out.mp4'
    write_bag(bag, [], [0, STEP], points=np.zeros((0, 4)))
    assert main([str(bag), '--output', str(out)]) == 0
    frames = frames_of(out)
    assert len(frames) == 2 and frames[0].shape == (480, 640, 3)


def _error(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err
    assert err.startswith('error: ') and err.count('\n') == 1, err
    return err


def test_errors_are_one_line_and_write_nothing(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    bag, out = tmp_path / 'bag', tmp_path / 'out.mp4'
    assert main([str(tmp_path / 'missing'), '--output', str(out)]) == 1
    assert 'not found' in _error(capsys)
    write_bag(bag, [0], [STEP])
    assert main([str(bag), '--output', str(out), '--labels-topic', '/nope']) == 1
    assert '/nope' in _error(capsys)
    assert main([str(bag), '--output', str(out), '--image-topic', '/nope']) == 1
    assert '/nope' in _error(capsys)
    # An image, but none at a labels stamp.
    assert main([str(bag), '--output', str(out)]) == 1
    assert 'stamp' in _error(capsys)
    assert not out.exists()
    out.write_text('mine')
    assert main([str(bag), '--output', str(out), '--image-topic', '/camera/image_raw']) == 1
    assert '--force' in _error(capsys)
    assert out.read_text() == 'mine'


def test_help_exits_0(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(['--help']) == 0
    assert capsys.readouterr().out.startswith('usage: pearl_render')
