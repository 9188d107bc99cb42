"""pearl_video on a rendered clip of known motion, read back with rosbags and OpenCV.

Oracles: the clip's ground truth (:func:`render_scene`: the surface under every pixel of every
frame), the frame count and rate the clip was written with, and the bag's two topics checked
against each other (ids and pixels of ``motion_labels`` against the feature message's).
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from pearl_ros.bagio.decode import decode_fields, decode_pointcloud, stamp_ns
from pearl_ros.bagio.reader import bag_messages, open_bag
from pearl_ros.cli.render import main as render_main
from pearl_ros.cli.video import main
from pearl_ros.core.metrics import misclassification
from pearl_ros.tracking.render import Scene, render_scene

FEATURES = '/feature_tracker/feature'
LABELS = '/motion_labels'
FRAMES = 60
FPS = 30.0
# Mean misclassification of the labels from the 10th frame on, against the rendered ground truth.
# Measured with budget_ms=0 (labels independent of the machine's load) on 60-frame 480 x 640
# clips written with mp4v: seed 0 2.10%, seed 1 1.23%, seed 2 2.29%. The bound is the issue's
# target; labelling every feature one motion scores ~15-30% on these clips (checked below).
MEAN_BOUND = 0.03


@dataclass(frozen=True)
class Run:
    scene: Scene
    clip: Path
    bag: Path
    annotated: Path
    stdout: str


def write_clip(scene: Scene, folder: Path) -> Path:
    """The scene's frames as a BGR video (mp4v, or MJPG .avi where mp4v cannot be written)."""
    height, width = scene.frames.shape[1:]
    for name, codec in (('clip.mp4', 'mp4v'), ('clip.avi', 'MJPG')):
        path = folder / name
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*codec), FPS, (width, height))
        if writer.isOpened():
            for frame in scene.frames:
                writer.write(cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR))
            writer.release()
            return path
    raise AssertionError('OpenCV writes neither mp4v nor MJPG here')


@pytest.fixture(scope='module')
def run(tmp_path_factory: pytest.TempPathFactory) -> Run:
    folder = tmp_path_factory.mktemp('video')
    scene = render_scene(0, frames=FRAMES, size=(480, 640))
    clip = write_clip(scene, folder)
    bag, annotated = folder / 'labels', folder / 'annotated.mp4'
    out = folder / 'stdout.txt'
    with out.open('w') as stream, contextlib.redirect_stdout(stream):
        status = main([str(clip), '--output-bag', str(bag), '--annotated', str(annotated),
                       '--set', 'budget_ms=0'])
    assert status == 0
    return Run(scene, clip, bag, annotated, out.read_text())


def read_topic(bag: Path, topic: str) -> list[Any]:
    with open_bag(bag) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        return [msg for _, msg in bag_messages(reader, bag, connections)]


def labels_of(msg: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    columns = decode_fields(msg, ('id', 'u', 'v', 'label'))
    uv = np.column_stack([columns['u'], columns['v']])
    return columns['id'].astype(np.int64), uv, columns['label'].astype(np.int64)


def video_frames(path: Path) -> list[np.ndarray]:
    capture = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, frame = capture.read()
        if not ok:
            break
        frames.append(frame)
    capture.release()
    return frames


def test_bag_holds_one_feature_and_one_labels_message_per_frame_in_order(run: Run) -> None:
    expected = [round(i * 1e9 / FPS) for i in range(FRAMES)]
    for topic in (FEATURES, LABELS):
        stamps = [stamp_ns(msg.header) for msg in read_topic(run.bag, topic)]
        assert stamps == expected, topic


def test_labels_carry_the_ids_and_pixels_of_the_feature_messages(run: Run) -> None:
    features, labels = read_topic(run.bag, FEATURES), read_topic(run.bag, LABELS)
    for feature_msg, labels_msg in zip(features, labels, strict=True):
        ids, uv = decode_pointcloud(feature_msg, 'vins_mono')
        label_ids, label_uv, _ = labels_of(labels_msg)
        assert ids.size > 100
        np.testing.assert_array_equal(label_ids, ids)
        np.testing.assert_array_equal(label_uv, uv.astype(np.float32))


def test_feature_points_are_pixels_and_velocities_px_per_second(run: Run) -> None:
    features = read_topic(run.bag, FEATURES)
    for before, after in zip(features[:-1], features[1:], strict=True):
        points = np.array([(p.x, p.y, p.z) for p in after.points])
        names = [c.name for c in after.channels]
        assert names == ['id_of_point', 'u_of_point', 'v_of_point', 'velocity_x_of_point',
                         'velocity_y_of_point']
        ids, u, v, vx, vy = (np.asarray(c.values, np.float64)
                             for c in after.channels)
        np.testing.assert_array_equal(points, np.column_stack([u, v, np.ones_like(u)]))
        old_ids, old_u, old_v = (np.asarray(c.values, np.float64) for c in before.channels[:3])
        old = {int(i): (a, b) for i, a, b in zip(old_ids, old_u, old_v, strict=True)}
        kept = [k for k, i in enumerate(ids) if int(i) in old]
        assert len(kept) > 100
        moved = np.array([np.subtract((u[k], v[k]), old[int(ids[k])]) for k in kept]) * FPS
        np.testing.assert_allclose(np.column_stack([vx, vy])[kept], moved, atol=1e-2)


def test_labels_are_outliers_or_motion_numbers_and_find_the_objects(run: Run) -> None:
    motions = []
    for msg in read_topic(run.bag, LABELS):
        _, _, labels = labels_of(msg)
        assert labels.min() >= -1
        motions.append(np.unique(labels[labels >= 0]).size)
    # Three surfaces (background, an object in view, one crossing it) are in view mid-clip.
    assert max(motions) >= 3
    assert f'wrote {run.bag}: {FRAMES} frames' in run.stdout


def test_labels_match_the_rendered_ground_truth(run: Run) -> None:
    rates, one_motion = [], []
    for frame, msg in enumerate(read_topic(run.bag, LABELS)):
        if frame < 9:  # from the 10th frame on: the window has filled
            continue
        _, uv, labels = labels_of(msg)
        truth = run.scene.surface_at(frame, uv)
        rates.append(misclassification(labels, truth))
        one_motion.append(misclassification(np.zeros_like(labels), truth))
    assert np.mean(one_motion) > 0.1  # the clip is not trivial
    assert np.mean(rates) <= MEAN_BOUND, f'mean misclassification {np.mean(rates):.2%}'


def test_annotated_video_has_every_frame_with_coloured_dots(run: Run) -> None:
    frames = video_frames(run.annotated)
    assert len(frames) == FRAMES
    assert frames[0].shape == (480, 640, 3)
    # The clip is grey: only the overlay gives pixels whose channels differ widely.
    late = frames[-1].astype(int)
    colourful = np.ptp(late, axis=2) > 80
    assert colourful.sum() > 500


def test_pearl_render_draws_pearl_videos_bag(run: Run, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / 'render.mp4'
    assert render_main([str(run.bag), '--output', str(out)]) == 0
    assert 'blank canvas' in capsys.readouterr().out
    frames = video_frames(out)
    assert len(frames) == FRAMES
    height, width = frames[0].shape[:2]
    assert 600 <= width <= 640 and 440 <= height <= 480  # the features' extent


def test_frames_go_to_the_image_topic_and_pearl_render_draws_on_them(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scene = render_scene(1, frames=8, size=(120, 160), objects=1, crossing=0)
    clip = write_clip(scene, tmp_path)
    bag, out = tmp_path / 'bag', tmp_path / 'render.mp4'
    assert main([str(clip), '--output-bag', str(bag), '--image-topic', '/camera/image']) == 0
    images = read_topic(bag, '/camera/image')
    decoded = video_frames(clip)
    assert len(images) == len(decoded) == 8
    for msg, frame in zip(images, decoded, strict=True):
        assert (msg.encoding, msg.height, msg.width) == ('bgr8', 120, 160)
        np.testing.assert_array_equal(np.asarray(msg.data).reshape(120, 160, 3), frame)
    assert render_main([str(bag), '--output', str(out)]) == 0
    assert 'the images of /camera/image' in capsys.readouterr().out
    rendered = video_frames(out)
    assert len(rendered) == 8
    # The clip's texture under the dots, not a black canvas.
    assert rendered[-1].shape == (120, 160, 3) and rendered[-1].mean() > 40


def _error(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err
    assert err.startswith('error: ') and err.count('\n') == 1, err
    return err


def test_an_unreadable_video_is_one_error_line(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    bogus = tmp_path / 'not_a_video.mp4'
    bogus.write_text('hello\n')
    assert main([str(bogus), '--output-bag', str(tmp_path / 'out')]) == 1
    assert 'cannot read video' in _error(capsys)
    assert main([str(tmp_path / 'missing.mp4'), '--output-bag', str(tmp_path / 'out')]) == 1
    assert 'not found' in _error(capsys)
    assert not (tmp_path / 'out').exists()


def test_an_existing_output_needs_force(run: Run, tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    bag = tmp_path / 'out'
    bag.mkdir()
    (bag / 'keep.txt').write_text('mine')
    assert main([str(run.clip), '--output-bag', str(bag)]) == 1
    assert '--force' in _error(capsys)
    assert (bag / 'keep.txt').read_text() == 'mine'
    video = tmp_path / 'a.mp4'
    video.write_text('mine')
    assert main([str(run.clip), '--output-bag', str(tmp_path / 'new'), '--annotated',
                 str(video)]) == 1
    assert '--force' in _error(capsys)
    assert video.read_text() == 'mine' and not (tmp_path / 'new').exists()
    # --force replaces a bag, never a folder that is not one.
    assert main([str(run.clip), '--output-bag', str(bag), '--force']) == 1
    assert 'not a bag' in _error(capsys)


def test_a_bad_setting_is_one_error_line(run: Run, tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / 'out'
    assert main([str(run.clip), '--output-bag', str(out), '--set', 'label_cots=3']) == 1
    assert 'label_cots' in _error(capsys)
    assert main([str(run.clip), '--output-bag', str(out), '--set', 'label_cost']) == 1
    _error(capsys)
    assert main([str(run.clip), '--output-bag', str(out), '--fps', '0']) == 1
    _error(capsys)
    assert not out.exists()


def test_help_exits_0(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(['--help']) == 0
    assert capsys.readouterr().out.startswith('usage: pearl_video')
