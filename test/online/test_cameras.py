"""The online segmenter with each frame's camera: the window keeps them, bad ones are refused,
and a stream with cameras finds the static world and the box, young tracks included."""

from __future__ import annotations

import numpy as np
import pytest
from static_scene import static_scene

from pearl_ros.core.config import PearlConfig
from pearl_ros.core.errors import InputError
from pearl_ros.core.metrics import misclassification
from pearl_ros.online.config import OnlineConfig
from pearl_ros.online.segmenter import OnlineSegmenter
from pearl_ros.online.window import SlidingWindow

STEP_NS = 33_333_333


def test_window_gives_the_newest_cameras_with_nan_for_frames_without_one():
    window = SlidingWindow(4)
    cameras = [np.full((3, 4), float(t + 1)) for t in range(5)]
    ids, uv = np.arange(3), np.zeros((3, 2))
    window.push(0, ids, uv, cameras[0])
    window.push(10, ids, uv)  # a frame without its camera
    window.push(20, ids, uv, cameras[2])
    assert window.cameras(2) is None  # one of two known: no static point is fixed by one view
    got = window.cameras(3)
    assert got is None  # two of three known: fewer than CAMERA_FRAMES
    window.push(30, ids, uv, cameras[3])
    got = window.cameras(4)
    assert got is not None
    assert np.array_equal(got[[0, 2, 3], 0, 0], [1.0, 3.0, 4.0]) and np.isnan(got[1]).all()
    assert window.cameras(5) is None  # more frames than the window holds


def test_a_late_camera_goes_to_the_frame_nearest_its_stamp_within_the_tolerance():
    window = SlidingWindow(3)
    ids, uv = np.arange(3), np.zeros((3, 2))
    for stamp in (0, 100, 200):
        window.push(stamp, ids, uv, None if stamp == 100 else np.zeros((3, 4)))
    late = np.full((3, 4), 7.0)
    assert not window.set_camera(140, late, tolerance_ns=30)  # 40 ns from the nearest frame
    assert not window.set_camera(190, late, tolerance_ns=30)  # nearest has its camera
    assert window.set_camera(120, late, tolerance_ns=30)
    got = window.cameras(3)
    assert got is not None and np.all(got[1] == 7.0)
    assert not window.set_camera(100, late, tolerance_ns=30)  # taken already


@pytest.mark.parametrize('camera, message', [
    (np.zeros((3, 3)), 'finite \\(3, 4\\)'),
    (np.full((3, 4), np.nan), 'finite \\(3, 4\\)'),
    (np.zeros((3, 4)), 'finite camera'),
])
def test_a_bad_camera_is_refused_and_the_state_kept(camera, message):
    tracks, _, cameras = static_scene(frames=3)
    segmenter = OnlineSegmenter(PearlConfig(), OnlineConfig(budget_ms=0))
    ids = np.arange(tracks.shape[1])
    segmenter.process(0, ids, tracks[0], cameras[0])
    with pytest.raises(InputError, match=message):
        segmenter.process(STEP_NS, ids, tracks[1], camera)
    assert segmenter.frames_in_window == 1
    segmenter.process(STEP_NS, ids, tracks[1], cameras[1])  # the same stamp is still free
    assert segmenter.frames_in_window == 2


def _stream(tracks, cameras, born, with_cameras):
    """Feed the scene frame by frame; feature i is tracked from frame ``born[i]`` on."""
    segmenter = OnlineSegmenter(PearlConfig(), OnlineConfig(budget_ms=0, seed=0))
    for t in range(tracks.shape[0]):
        seen = np.flatnonzero(born <= t)
        result = segmenter.process(t * STEP_NS, seen, tracks[t, seen],
                                   cameras[t] if with_cameras else None)
    return result.labels, seen


def test_a_stream_with_cameras_separates_the_box_young_tracks_included():
    tracks, truth, cameras = static_scene(frames=24, static=150, moving=40, seed=4)
    # A fifth of the static points and of the box's are born in the last four frames: young
    # tracks, labelled outside the fit.
    born = np.zeros(truth.size, dtype=int)
    born[::5] = tracks.shape[0] - 4
    labels, seen = _stream(tracks, cameras, born, with_cameras=True)
    assert seen.size == truth.size
    assert misclassification(labels, truth) < 0.05
    young = born > 0
    world = labels[(truth == 0) & ~young]
    static_motion = np.bincount(world[world >= 0]).argmax()
    # Young static tracks take the static world's motion.
    assert np.mean(labels[young & (truth == 0)] == static_motion) > 0.9
    assert np.mean(labels[young & (truth == 1)] == static_motion) < 0.1


def test_cameras_that_come_after_their_frames_serve_as_well():
    tracks, truth, cameras = static_scene(frames=16, seed=5)
    segmenter = OnlineSegmenter(PearlConfig(), OnlineConfig(budget_ms=0, seed=0))
    ids = np.arange(truth.size)
    for t in range(tracks.shape[0]):
        # Each frame's pose comes just after its features: the frame is segmented with the
        # poses of the frames before it.
        result = segmenter.process(t * STEP_NS, ids, tracks[t])
        assert segmenter.set_camera(t * STEP_NS + 1_000, cameras[t], tolerance_ns=5_000)
    assert misclassification(result.labels, truth) < 0.05
    for bad in (np.zeros((3, 3)), None):
        with pytest.raises(InputError, match='finite'):
            segmenter.set_camera(0, bad)
