"""The KLT tracker on rendered clips of known motion, and its checks one by one."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from pearl_ros.core.errors import InputError
from pearl_ros.tracking.render import render_scene, texture
from pearl_ros.tracking.tracker import CameraModel, FeatureTracker, TrackerConfig

# Around a track's first point: a corner on an object's outline belongs to either surface.
_NEAR = np.array([(dx, dy) for dx in (-1.5, 0.0, 1.5) for dy in (-1.5, 0.0, 1.5)])


def _run(scene, tracker):
    """Every frame's Tracks, and each id's history [(frame, uv)]."""
    out, history = [], {}
    for t, frame in enumerate(scene.frames):
        tracks = tracker.track(frame)
        out.append(tracks)
        for i, uv in zip(tracks.ids, tracks.uv, strict=True):
            history.setdefault(int(i), []).append((t, uv))
    return out, history


def _off_surface(scene, history):
    """Track-frames after the first, and how many of them are more than 1 px from where the
    render puts the track's first point (on the surface that explains the track best among
    those within 1.5 px of that point) or where that point is hidden."""
    total = bad = 0
    for steps in history.values():
        t0, uv0 = steps[0]
        best = None
        for surface in set(scene.surface_at(t0, uv0 + _NEAR)) - {-1}:
            wrong = 0
            for t, uv in steps[1:]:
                truth, _ = scene.follow(t0, uv0, np.array([surface]), t)
                seen = np.any(scene.surface_at(t, truth + _NEAR) == surface)
                wrong += int(np.linalg.norm(truth[0] - uv) > 1.0 or not seen)
            best = wrong if best is None else min(best, wrong)
        total += len(steps) - 1
        bad += best
    return total, bad


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_tracks_stay_on_the_surface_they_started_on(seed):
    # Panning, rolling and zooming camera, one object moving on its own, one crossing the view.
    scene = render_scene(seed)
    _, history = _run(scene, FeatureTracker())
    total, bad = _off_surface(scene, history)
    assert total > 8000
    assert bad <= 0.01 * total, f'{bad} of {total} track-frames off their surface'


def test_without_the_appearance_checks_tracks_leave_their_surface():
    # The oracle can fail: the same tracker without its forward-backward, residual and template
    # checks lets occluded background features ride on the crossing object.
    scene = render_scene(0)
    loose = FeatureTracker(TrackerConfig(fb_threshold=0.0, max_residual=0.0,
                                         min_template_ncc=0.0))
    total, bad = _off_surface(scene, _run(scene, loose)[1])
    assert bad > 0.02 * total


@pytest.fixture(scope='module')
def clip():
    scene = render_scene(4, frames=25)
    config = TrackerConfig(max_features=250, min_distance=15.0)
    return scene, config, _run(scene, FeatureTracker(config))[0]


def test_ids_are_unique_and_never_reused(clip):
    _, _, frames = clip
    seen, ended = -1, set()
    alive: set[int] = set()
    for tracks in frames:
        ids = set(tracks.ids.tolist())
        assert len(ids) == len(tracks)
        assert not ids & ended
        new = ids - alive
        assert all(i > seen for i in new)  # new ids count up
        assert all(tracks.age[tracks.ids == i][0] == 1 for i in new)
        seen = max(seen, *ids)
        ended |= alive - ids
        alive = ids


def test_feature_count_stays_near_the_target(clip):
    _, config, frames = clip
    counts = np.array([len(tracks) for tracks in frames])
    assert counts.max() <= config.max_features
    assert counts.min() >= 0.9 * config.max_features


def test_corners_are_detected_only_to_top_up(clip):
    _, config, frames = clip
    topped = 0
    for tracks in frames[1:]:
        survivors, new = np.count_nonzero(tracks.age > 1), np.count_nonzero(tracks.age == 1)
        if survivors >= config.top_up_share * config.max_features:
            assert new == 0
        else:
            assert new > 0 and len(tracks) <= config.max_features
            topped += 1
    assert 0 < topped < len(frames) - 1


def test_new_corners_keep_the_minimum_distance(clip):
    _, config, frames = clip
    checked = 0
    for tracks in frames[1:]:
        new, old = tracks.uv[tracks.age == 1], tracks.uv[tracks.age > 1]
        if len(new) and len(old):
            gaps = np.linalg.norm(new[:, None] - old[None], axis=2)
            assert gaps.min() >= config.min_distance
            checked += len(new)
        pairs = np.linalg.norm(new[:, None] - new[None], axis=2) + 1e9 * np.eye(len(new))
        assert len(new) < 2 or pairs.min() >= config.min_distance
    assert checked > 20


def test_velocities_are_the_frame_to_frame_motion_per_frame_or_per_second(clip):
    scene, config, frames = clip
    tracker = FeatureTracker(config)
    for t in range(3):
        tracks = tracker.track(scene.frames[t], stamp=t * 100_000_000)
    previous = dict(zip(frames[1].ids.tolist(), frames[1].uv, strict=True))
    old = tracks.age > 1
    assert tracks.per_second and old.sum() > 100 and np.all(tracks.velocity[~old] == 0)
    expected = np.array([tracks.uv[k] - previous[i] for k, i in enumerate(tracks.ids) if old[k]])
    np.testing.assert_allclose(tracks.velocity[old], 10.0 * expected, atol=1e-6)
    np.testing.assert_allclose(frames[2].velocity[frames[2].age > 1] * 10.0,
                               tracks.velocity[old], atol=1e-6)


def _textured(seed: int, size=(240, 320)) -> np.ndarray:
    return np.clip(texture(np.random.default_rng(seed), *size), 0, 255).astype(np.uint8)


def test_forward_backward_check_drops_a_feature_whose_patch_is_replaced():
    image = _textured(1)
    # Only the forward-backward check on: no residual or template check.
    config = TrackerConfig(max_features=200, min_distance=10.0, max_residual=0.0,
                           min_template_ncc=0.0)
    tracker = FeatureTracker(config)
    first = tracker.track(image)
    # The next frame: the camera is still, but a 60 px square is replaced by texture from
    # elsewhere (an occluder): what was there has no place to go.
    nxt = image.copy()
    nxt[90:150, 130:190] = _textured(2)[0:60, 0:60]
    inside = np.all((first.uv >= (135, 95)) & (first.uv <= (185, 145)), axis=1)
    assert inside.sum() >= 5
    second = tracker.track(nxt)
    kept = np.isin(first.ids, second.ids)
    assert not kept[inside].any()
    assert kept[~inside].mean() > 0.9
    # Without it, some of them are kept, misplaced.
    loose = FeatureTracker(replace(config, fb_threshold=0.0))
    loose.track(image)
    assert np.isin(first.ids[inside], loose.track(nxt).ids).any()


def test_template_check_drops_a_feature_whose_window_changes_slowly():
    # A region cross-fades to other texture over 12 still frames: each frame-to-frame change is
    # small (the forward-backward and residual checks pass it), the change since birth is not.
    image, other = _textured(4).astype(float), _textured(5).astype(float)
    inside_box = (slice(80, 160), slice(100, 200))
    frames = []
    for step in range(13):
        frame = image.copy()
        frame[inside_box] = (1 - step / 12) * image[inside_box] + step / 12 * other[inside_box]
        frames.append(np.rint(frame).astype(np.uint8))

    def survivors(ncc: float) -> tuple[np.ndarray, np.ndarray]:
        tracker = FeatureTracker(TrackerConfig(min_distance=10.0, min_template_ncc=ncc))
        first = tracker.track(frames[0])
        for frame in frames[1:]:
            last = tracker.track(frame)
        inside = np.all((first.uv >= (108, 88)) & (first.uv <= (192, 152)), axis=1)
        return first.ids[inside], np.isin(first.ids[inside], last.ids)

    ids, kept = survivors(0.8)
    assert len(ids) >= 5 and not kept.any()
    assert survivors(0.0)[1].mean() > 0.5


def test_mask_excludes_regions():
    scene = render_scene(5, frames=12)
    height, width = scene.frames.shape[1:]
    mask = np.ones((height, width), np.uint8)
    mask[:, : width // 2] = 0
    mask[300:, :] = 0
    tracker = FeatureTracker(mask=mask)
    counted = 0
    for frame in scene.frames:
        tracks = tracker.track(frame)
        cols, rows = np.rint(tracks.uv).astype(int).T
        assert np.all(mask[rows, cols] == 1)
        counted += len(tracks)
    assert counted > 500


K = np.array([[420.0, 0.0, 330.5], [0.0, 410.0, 242.25], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize('model, coefficients', [
    ('plumb_bob', (-0.28, 0.09, 0.0012, -0.0008, -0.012)),
    ('rational_polynomial', (0.1, -0.05, 0.001, 0.002, 0.01, 0.12, -0.04, 0.008)),
    ('equidistant', (-0.02, 0.004, -0.003, 0.0005)),
])
def test_undistortion_inverts_the_opencv_projection(model, coefficients):
    # Known normalised points projected through the lens by OpenCV's forward model; the camera
    # model must give them back.
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.6, 0.6, (200, 2))
    rays = np.column_stack([xy, np.ones(len(xy))]).reshape(-1, 1, 3)
    dist = np.array(coefficients)
    zero = np.zeros(3)
    if model == 'equidistant':
        uv, _ = cv2.fisheye.projectPoints(rays, zero, zero, K, dist)
    else:
        uv, _ = cv2.projectPoints(rays, zero, zero, K, dist)
    camera = CameraModel(K, dist, model)
    np.testing.assert_allclose(camera.normalise(uv.reshape(-1, 2)), xy, atol=1e-5)
    # The columns of a wider array (a cloud's x, y of x, y, z) are not contiguous rows.
    cloud = np.column_stack([uv.reshape(-1, 2), np.ones(len(xy))])
    np.testing.assert_allclose(camera.normalise(cloud[:, :2]), xy, atol=1e-5)


def test_undistorted_camera_gives_inverse_intrinsics_and_the_tracker_reports_them():
    info = type('Info', (), {'k': K.ravel().tolist(), 'd': [], 'distortion_model': ''})()
    camera = CameraModel.from_camera_info(info)
    tracker = FeatureTracker(camera=camera)
    tracks = tracker.track(_textured(3, (480, 640)))
    expected = np.linalg.solve(K, np.column_stack([tracks.uv, np.ones(len(tracks))]).T).T
    assert len(tracks) > 100 and tracks.xy is not None
    np.testing.assert_allclose(tracks.xy, expected[:, :2], atol=1e-12)
    assert FeatureTracker().track(_textured(3)).xy is None


def test_a_new_image_size_ends_every_track_and_ids_count_on():
    tracker = FeatureTracker(TrackerConfig(max_features=50))
    first = tracker.track(_textured(6))
    second = tracker.track(_textured(6, (200, 300)))
    assert len(first) == len(second) == 50
    assert second.ids.min() > first.ids.max() and np.all(second.age == 1)


def test_camera_info_fields_give_the_camera_model():
    info = type('Info', (), {'k': K.ravel().tolist(), 'd': [0.1, -0.02, 0.001, 0.0, 0.003],
                             'distortion_model': 'plumb_bob'})()
    camera = CameraModel.from_camera_info(info)
    assert camera.model == 'plumb_bob'
    np.testing.assert_array_equal(camera.K, K)
    np.testing.assert_array_equal(camera.distortion, info.d)
    uncalibrated = type('Info', (), {'k': [0.0] * 9, 'd': [], 'distortion_model': ''})
    with pytest.raises(InputError, match='uncalibrated'):
        CameraModel.from_camera_info(uncalibrated)


@pytest.mark.parametrize('settings, name', [
    ({'max_features': 0}, 'max_features'), ({'min_distance': -1.0}, 'min_distance'),
    ({'quality_level': 2.0}, 'quality_level'), ({'window_size': 20}, 'window_size'),
    ({'pyramid_levels': 1.5}, 'pyramid_levels'), ({'fb_threshold': -0.5}, 'fb_threshold'),
    ({'max_residual': 300.0}, 'max_residual'), ({'border': -2}, 'border'),
    ({'top_up_share': 0.0}, 'top_up_share'), ({'min_template_ncc': 1.5}, 'min_template_ncc'),
])
def test_bad_settings_are_one_line_errors_naming_the_field(settings, name):
    with pytest.raises(InputError) as info:
        TrackerConfig(**settings)
    assert str(info.value).startswith(name) and '\n' not in str(info.value)


@pytest.mark.parametrize('build, word', [
    (lambda: CameraModel(np.zeros((3, 3))), 'uncalibrated'),
    (lambda: CameraModel(K, np.zeros(3), 'plumb_bob'), 'plumb_bob'),
    (lambda: CameraModel(K, np.zeros(4), 'kannala'), 'kannala'),
    (lambda: FeatureTracker().track(np.zeros((4, 4), np.float32)), 'uint8'),
    (lambda: FeatureTracker(mask=np.ones((5, 5))).track(np.zeros((6, 6), np.uint8)), 'mask'),
])
def test_bad_camera_and_image_inputs_are_one_line_errors(build, word):
    with pytest.raises(InputError) as info:
        build()
    assert word in str(info.value) and '\n' not in str(info.value)
