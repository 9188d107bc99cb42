"""The robot stream is a tracker's view of a perspective camera driving among moving objects.

Oracles are independent of the generator: epipolar geometry built from the scene's poses (a
Sampson distance written here), a homography fitted here by least squares, depths triangulated
here from two views, and counts over the frames.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import Delaunay

from pearl_ros.core.errors import InputError
from pearl_ros.datasets.robot import (
    HEIGHT_PX,
    INTRINSICS,
    WIDTH_PX,
    RobotScene,
    robot_scene,
    robot_stream,
)
from pearl_ros.datasets.synthetic import FRAME_NS

SEEDS = (0, 1, 2)
KINDS = ('car', 'person', 'car')


@pytest.fixture(scope='module')
def streams() -> dict[int, list]:
    """The default stream (300 frames, 300 features, 0.5 px noise, 10% outliers) per seed."""
    return {seed: list(robot_stream(seed=seed)) for seed in SEEDS}


@pytest.fixture(scope='module')
def clean() -> tuple[RobotScene, list]:
    """A noise-free stream without outlier tracks, and its scene."""
    args = dict(frames=80, seed=3)
    return robot_scene(**args), list(robot_stream(noise=0.0, outlier_share=0.0, **args))


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def _fundamental(scene: RobotScene, a: int, b: int, body: int) -> np.ndarray:
    """F with x_b^T F x_a = 0 for points of ``body`` (0 = static world) seen in frames a, b."""
    # Body coordinates X: world = B X + p (identity for the static world); camera = C^T (w - c).
    def pose(t: int) -> tuple[np.ndarray, np.ndarray]:
        if body == 0:
            return np.eye(3), np.zeros(3)
        return scene.object_rotation[t, body - 1], scene.object_position[t, body - 1]

    (ba, pa), (bb, pb) = pose(a), pose(b)
    ca, cb = scene.camera_rotation[a], scene.camera_rotation[b]
    # camera_b = R camera_a + s
    rotation = cb.T @ bb @ ba.T @ ca
    shift = cb.T @ (bb @ ba.T @ (scene.camera_position[a] - pa) + pb - scene.camera_position[b])
    k_inv = np.linalg.inv(INTRINSICS)
    return k_inv.T @ _skew(shift) @ rotation @ k_inv


def _sampson(f: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
    """Sampson distances (px) of correspondences (N, 2) to fundamental matrix f."""
    ha, hb = np.column_stack([xa, np.ones(len(xa))]), np.column_stack([xb, np.ones(len(xb))])
    fa, fb = ha @ f.T, hb @ f
    error = np.sum(hb * fa, axis=1)
    return np.abs(error) / np.sqrt(fa[:, 0]**2 + fa[:, 1]**2 + fb[:, 0]**2 + fb[:, 1]**2)


def _homography_residual(xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
    """Transfer errors (px) of the least-squares (normalised DLT) homography from xa to xb."""
    def normalise(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        centre, scale = x.mean(axis=0), np.sqrt(2) / np.mean(np.linalg.norm(x - x.mean(0), axis=1))
        t = np.array([[scale, 0, -scale * centre[0]], [0, scale, -scale * centre[1]], [0, 0, 1]])
        return np.column_stack([x, np.ones(len(x))]) @ t.T, t

    (ha, ta), (hb, tb) = normalise(xa), normalise(xb)
    zero = np.zeros((len(xa), 3))
    rows = np.concatenate([
        np.column_stack([zero, -ha, hb[:, 1:2] * ha]),
        np.column_stack([ha, zero, -hb[:, 0:1] * ha])])
    h = np.linalg.svd(rows)[2][-1].reshape(3, 3)
    h = np.linalg.inv(tb) @ h @ ta
    mapped = np.column_stack([xa, np.ones(len(xa))]) @ h.T
    return np.linalg.norm(mapped[:, :2] / mapped[:, 2:] - xb, axis=1)


def _matched(frames: list, a: int, b: int, body: int | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
    """Pixels in frames a and b of the tracks seen in every frame from a to b (with truth
    ``body`` in a and b); an id missing from a frame between may have been reused."""
    fa, fb = frames[a], frames[b]
    ids = fa.ids
    for frame in frames[a + 1:b + 1]:
        ids = np.intersect1d(ids, frame.ids)
    _, ia, ib = np.intersect1d(fa.ids, fb.ids, return_indices=True)
    keep = np.isin(fa.ids[ia], ids)
    ia, ib = ia[keep], ib[keep]
    if body is not None:
        same = (fa.truth[ia] == body) & (fb.truth[ib] == body)
        ia, ib = ia[same], ib[same]
    return fa.uv[ia], fb.uv[ib]


def test_ids_are_unique_and_every_feature_is_inside_the_image(streams):
    for frames in streams.values():
        for frame in frames:
            assert np.unique(frame.ids).size == frame.ids.size
            assert np.all((frame.uv >= 0) & (frame.uv <= [WIDTH_PX - 1, HEIGHT_PX - 1]))
            assert set(np.unique(frame.truth)) <= {-1, 0, 1, 2, 3}


def test_each_frame_holds_about_num_features_at_30_hz(streams):
    for frames in streams.values():
        counts = np.array([frame.ids.size for frame in frames])
        assert counts.min() >= 285 and counts.max() <= 315
        assert np.all(np.diff([frame.stamp_ns for frame in frames]) == FRAME_NS)


def test_the_same_seed_gives_the_same_stream_and_another_seed_another():
    first, again, other = (list(robot_stream(seed=seed, frames=40)) for seed in (1, 1, 2))
    for one, two in zip(first, again, strict=True):
        assert one.stamp_ns == two.stamp_ns
        for name in ('ids', 'uv', 'truth'):
            np.testing.assert_array_equal(getattr(one, name), getattr(two, name))
    assert not np.allclose(first[39].uv[:50], other[39].uv[:50])
    assert not np.allclose(robot_scene(40, 1).camera_position, robot_scene(40, 2).camera_position)


def test_outlier_tracks_make_up_the_requested_share_and_walk_3_px_steps(streams):
    shares = [np.mean(frame.truth == -1) for frames in streams.values() for frame in frames]
    assert np.mean(shares) == pytest.approx(0.1, abs=0.01)
    steps = np.concatenate([
        np.diff(np.stack(_matched(frames, t, t + 1, body=-1)), axis=0)[0]
        for frames in streams.values() for t in range(0, 299, 10)])
    assert np.std(steps) == pytest.approx(3.0, rel=0.1)
    shares = [np.mean(frame.truth == -1) for frame in robot_stream(frames=20, outlier_share=0.3)]
    assert np.mean(shares) == pytest.approx(0.3, abs=0.02)
    assert all(-1 not in frame.truth for frame in robot_stream(frames=20, outlier_share=0.0))


def test_ids_come_back_only_after_three_frames_away(streams):
    reused = 0
    for frames in streams.values():
        seen: dict[int, list[int]] = {}
        for t, frame in enumerate(frames):
            for i in frame.ids.tolist():
                seen.setdefault(i, []).append(t)
        for times in seen.values():
            gaps = np.diff(times)
            assert np.all((gaps == 1) | (gaps >= 4))  # absent from 3 frames at least
            reused += int(np.sum(gaps >= 4))
    assert reused > 100


def _long_runs(present: np.ndarray, length: int = 10) -> list[bool]:
    """The values of the runs of ``present`` that last ``length`` frames or more, in order,
    equal neighbours merged (short flickers ignored)."""
    values: list[bool] = []
    start = 0
    for t in range(1, present.size + 1):
        if t == present.size or present[t] != present[start]:
            if t - start >= length and (not values or values[-1] != bool(present[start])):
                values.append(bool(present[start]))
            start = t
    return values


def test_objects_leave_the_view_and_come_back_and_one_is_in_the_last_frame(streams):
    for frames in streams.values():
        present = np.array([[np.sum(frame.truth == k) > 0 for k in (1, 2, 3)]
                            for frame in frames])
        assert np.all(present.mean(axis=0) >= 0.25)
        assert present[-1].any()
        # Some object is in view for 10 frames or more, out of it as long, and back.
        patterns = [''.join('1' if v else '0' for v in _long_runs(column))
                    for column in present.T]
        assert any('101' in pattern for pattern in patterns), patterns


def test_objects_hold_a_fair_share_of_the_features_while_in_view(streams):
    for frames in streams.values():
        for k in (1, 2, 3):
            counts = np.array([np.sum(frame.truth == k) for frame in frames])
            assert np.median(counts[counts > 0]) >= 6
        moving = np.mean([np.mean(frame.truth > 0) for frame in frames])
        assert 0.05 < moving < 0.4


def test_the_background_fits_the_true_camera_motion_and_shows_parallax(clean):
    scene, frames = clean
    for a, b in ((0, 1), (10, 20), (40, 79)):
        xa, xb = _matched(frames, a, b, body=0)
        assert len(xa) > 30
        assert np.max(_sampson(_fundamental(scene, a, b, 0), xa, xb)) < 1e-6
        if b - a >= 10:
            # No plane explains it: one homography leaves pixels of error.
            assert np.median(_homography_residual(xa, xb)) > 1.0


def test_each_object_moves_rigidly_and_not_with_the_background(clean):
    scene, frames = clean
    checked = 0
    for t in range(0, 79, 3):
        for k in (1, 2, 3):
            xa, xb = _matched(frames, t, t + 1, body=k)
            if len(xa) < 8:
                continue
            checked += 1
            assert np.max(_sampson(_fundamental(scene, t, t + 1, k), xa, xb)) < 1e-6
            assert np.median(_sampson(_fundamental(scene, t, t + 1, 0), xa, xb)) > 1e-3
    assert checked >= 10


def _triangulate(scene: RobotScene, a: int, b: int, xa: np.ndarray, xb: np.ndarray
                 ) -> np.ndarray:
    """World points (N, 3) from pixels in frames a and b (linear triangulation)."""
    def projection(t: int) -> np.ndarray:
        rotation = scene.camera_rotation[t]
        return INTRINSICS @ np.column_stack([rotation.T, -rotation.T @ scene.camera_position[t]])

    pa, pb = projection(a), projection(b)
    points = []
    for (ua, va), (ub, vb) in zip(xa, xb, strict=True):
        rows = np.array([ua * pa[2] - pa[0], va * pa[2] - pa[1], ub * pb[2] - pb[0],
                         vb * pb[2] - pb[1]])
        h = np.linalg.svd(rows)[2][-1]
        points.append(h[:3] / h[3])
    return np.array(points)


def test_no_feature_shows_through_a_nearer_object(clean):
    # A box is convex: every ray through its silhouette meets it, so a background feature there
    # must be in front of it, nearer than its farthest corner (if occlusion were ignored, the
    # static world behind each object would show through). Depths of background features come
    # from triangulation over 10 frames.
    scene, frames = clean
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    silhouettes = 0
    for t in range(10, 80, 5):
        xa, xb = _matched(frames, t - 10, t, body=0)
        world = _triangulate(scene, t - 10, t, xa, xb)
        _, depth = scene.project(t, world)
        for k in range(3):
            corners = (signs * scene.object_half_extents[k]) @ scene.object_rotation[t, k].T \
                + scene.object_position[t, k]
            uv, corner_depth = scene.project(t, corners)
            if np.any(corner_depth <= 0):
                continue
            covered = Delaunay(uv).find_simplex(xb) >= 0
            silhouettes += int(np.any(np.all((uv >= 0) & (uv <= [WIDTH_PX, HEIGHT_PX]), axis=1)))
            assert np.all(depth[covered] < corner_depth.max())
    assert silhouettes >= 10


def test_bad_arguments_raise_one_line_errors():
    for kwargs in (dict(outlier_share=1.0), dict(objects=('bus',)), dict(frames=0),
                   dict(noise=-1.0), dict(num_features=0)):
        with pytest.raises(InputError) as info:
            robot_stream(**kwargs)  # at the call, before any frame is asked for
        assert '\n' not in str(info.value)
