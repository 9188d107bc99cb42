"""The renderer's ground truth agrees with its own images; clips are reproducible."""

from __future__ import annotations

import numpy as np
import pytest

from pearl_ros.core.errors import InputError
from pearl_ros.tracking.render import render_scene


@pytest.fixture(scope='module')
def scene():
    return render_scene(7, frames=20)


def test_same_seed_same_clip_other_seed_other_clip():
    a, b, c = (render_scene(seed, frames=3, size=(60, 80)) for seed in (1, 1, 2))
    np.testing.assert_array_equal(a.frames, b.frames)
    np.testing.assert_array_equal(a.transforms, b.transforms)
    assert not np.array_equal(a.frames, c.frames)


def test_followed_pixels_keep_their_grey_level(scene):
    # Pixels of frame 0 carried by the ground truth to frame t show the same texture there
    # (up to noise and interpolation); the same pixels taken where they were in frame 0 do not,
    # since everything moves: the check can fail.
    rng = np.random.default_rng(0)
    height, width = scene.frames.shape[1:]
    uv = rng.uniform((20, 20), (width - 21, height - 21), (4000, 2)).round()
    surface = scene.surface_at(0, uv)
    start = scene.frames[0, uv[:, 1].astype(int), uv[:, 0].astype(int)].astype(float)
    for t in (1, 5, 19):
        moved, seen = scene.follow(0, uv, surface, t)
        inside = seen & np.all((moved >= 0) & (moved <= (width - 1, height - 1)), axis=1)
        cols, rows = np.rint(moved[inside]).T.astype(int)
        # nearest pixel: the texture is blurred, so a half-pixel step changes it a little
        followed = np.median(np.abs(scene.frames[t, rows, cols] - start[inside]))
        still = np.median(np.abs(scene.frames[t, uv[:, 1].astype(int), uv[:, 0].astype(int)]
                                 - start))
        assert inside.sum() > 1000
        assert followed < 8 and still > 3 * followed


def test_objects_move_on_their_own_and_one_enters_and_leaves(scene):
    counts = np.array([[np.count_nonzero(frame == s) for s in range(3)] for frame in scene.labels])
    assert np.all(counts[:, 1] > 0)  # the first object stays in view
    assert counts[0, 2] == 0 and counts[-1, 2] == 0 and counts[len(counts) // 2, 2] > 5000
    # Three different motions: the maps of the three surfaces from frame 0 to the last differ.
    moves = [scene.transforms[-1, s] @ np.linalg.inv(scene.transforms[0, s]) for s in range(3)]
    for i, j in ((0, 1), (0, 2), (1, 2)):
        assert np.abs(moves[i] - moves[j]).max() > 1.0


def test_occluded_points_are_reported_unseen(scene):
    # Background points under the first object in the last frame are not visible there.
    rows, cols = np.nonzero(scene.labels[-1] == 1)
    uv_last = np.column_stack([cols, rows]).astype(float)[::50]
    back = scene.transforms[0, 0] @ np.linalg.inv(scene.transforms[-1, 0])
    uv0 = (np.column_stack([uv_last, np.ones(len(uv_last))]) @ back.T)[:, :2]
    _, seen = scene.follow(0, uv0, np.zeros(len(uv0), int), len(scene.frames) - 1)
    assert len(seen) > 20 and not seen.any()


def test_bad_clip_settings_are_refused():
    with pytest.raises(InputError, match='crossing'):
        render_scene(0, objects=1, crossing=2)
