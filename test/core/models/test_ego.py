"""The static world seen by known cameras: triangulation residuals, the wrapped family, the
pair ties it loosens, and a fit that finds it, against scenes of known geometry."""

from __future__ import annotations

import numpy as np
import pytest
from static_scene import INTRINSICS, static_scene

from pearl_ros.core.config import PearlConfig
from pearl_ros.core.errors import InputError
from pearl_ros.core.metrics import misclassification
from pearl_ros.core.models.affine import AffineSubspace
from pearl_ros.core.models.ego import (
    WithStaticWorld,
    is_static,
    static_residuals,
    static_ties,
)
from pearl_ros.core.pearl import fit


def test_a_static_point_reprojects_exactly_and_a_moving_one_does_not():
    tracks, truth, cameras = static_scene(noise=0.0)
    residual, in_front = static_residuals(cameras, tracks)
    assert residual[truth == 0].max() < 1e-6
    assert in_front[truth == 0].all()
    # The box crosses 3 m/s at 10 m: 30 cm over the window, about 15 px.
    assert np.median(residual[truth == 1]) > 2.0


def test_a_point_behind_the_cameras_is_no_static_point_in_front():
    _, _, cameras = static_scene()
    behind = np.array([1.0, 0.5, -8.0, 1.0])
    uv = np.stack([(c @ behind)[:2] / (c @ behind)[2] for c in cameras])[:, None, :]
    residual, in_front = static_residuals(cameras, uv)
    # Its projections are a static point's, but from behind every camera: the best point in
    # front is at infinity, which leaves the parallax of 8 m over 0.6 m driven (about 4 px
    # by the last frame).
    assert not in_front[0] or residual[0] > 1.0


def test_a_far_point_is_explained_at_infinity_in_front():
    _, _, cameras = static_scene()
    far = np.array([0.02, -0.01, 1.0, 0.0])  # a direction: the horizon ahead
    uv = np.stack([(c @ far)[:2] / (c @ far)[2] for c in cameras])[:, None, :]
    rng = np.random.default_rng(0)
    noisy = uv + rng.normal(0.0, 0.5, uv.shape)
    residual, in_front = static_residuals(cameras, noisy)
    assert in_front[0]
    assert residual[0] < 1.0  # the noise's, not a failure's


def test_residual_is_the_rms_reprojection_error_of_the_best_point_on_a_two_frame_pair():
    # Two frames, a pure sideways baseline: a track's disparity fixes the depth, and a
    # vertical offset between the frames is the whole residual (half of it in each frame).
    cameras = np.stack([INTRINSICS @ np.hstack([np.eye(3), [[0.0], [0.0], [0.0]]]),
                        INTRINSICS @ np.hstack([np.eye(3), [[-1.0], [0.0], [0.0]]])])
    uv = np.array([[[300.0, 200.0]], [[250.0, 204.0]]])
    residual, in_front = static_residuals(cameras, uv)
    assert residual[0] == pytest.approx(2.0, abs=0.05)  # 2 px off in each frame
    assert in_front[0]


def test_wrapped_family_residuals_refits_and_the_static_hypothesis():
    tracks, truth, cameras = static_scene(noise=0.3, seed=1)
    model = WithStaticWorld(AffineSubspace(), cameras)
    data = model.data(tracks)
    static_rows, in_front = static_residuals(cameras, tracks)
    # A track only a point behind the cameras explains is not the static world's.
    assert np.allclose(data[:, -1], np.where(in_front, static_rows, 1e4))
    assert np.allclose(data[:, :-1], AffineSubspace().data(tracks))
    world = np.flatnonzero(truth == 0)
    box = np.flatnonzero(truth == 1)
    # The static world explains its own points better than their affine fit (perspective over
    # a driving window): the refit keeps it, whatever it starts from.
    affine_start = model.fit_minimal(data, world[None, :4])[0][0]
    assert is_static(model.refit(data, world, affine_start))
    assert is_static(model.refit(data, world, model.static(data)))
    # A moving box is the family's: its refit is the affine refit of the same points.
    own = model.refit(data, box, model.static(data))
    assert not is_static(own)
    expected = AffineSubspace().refit(data[:, :-1], box, None)
    assert np.allclose(model.residuals(data, own), AffineSubspace().residuals(data[:, :-1],
                                                                              expected))
    # A batch of both kinds: the static row is the data's last column.
    batch = np.stack([own, model.static(data)])
    rows = model.residuals(data, batch)
    assert np.allclose(rows[1], data[:, -1]) and np.allclose(rows[0], model.residuals(data, own))


def test_a_few_points_of_another_motion_do_not_turn_the_static_world_into_a_fit():
    tracks, truth, cameras = static_scene(noise=0.3, seed=2)
    model = WithStaticWorld(AffineSubspace(), cameras)
    data = model.data(tracks)
    mixed = np.r_[np.flatnonzero(truth == 0), np.flatnonzero(truth == 1)[:10]]
    assert is_static(model.refit(data, mixed, model.static(data)))


def test_cameras_must_match_the_frames():
    tracks, _, cameras = static_scene()
    with pytest.raises(InputError, match='cameras must have shape'):
        static_residuals(cameras[:-1], tracks)
    bad = cameras.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(InputError, match='finite'):
        static_residuals(bad, tracks)


def test_static_ties_loosen_ties_by_the_gap_in_static_residual_only():
    edges = np.array([[0, 1], [1, 2], [2, 3], [0, 3]])
    weights = np.array([10.0, 10.0, -4.0, 0.0])
    static = np.array([0.5, 0.5, 6.5, 3.5])
    scale, contrast = 0.5, 3.0
    tied = static_ties(weights, edges, static, scale, contrast)
    # Independently: the gap 0 keeps all; 6 px / 0.5 px = 12 scales keeps exp(-16).
    assert tied[0] == pytest.approx(10.0)
    assert tied[1] == pytest.approx(10.0 * np.exp(-(12.0 / 3.0) ** 2))
    assert tied[2] == -4.0 and tied[3] == 0.0  # a reward and no weight stay
    assert static_ties(weights, edges, static, scale, 0.0) is weights


def test_fit_with_cameras_finds_the_static_world_and_the_moving_box():
    tracks, truth, cameras = static_scene(seed=3)
    result = fit(tracks, rng=0, cameras=cameras)
    assert misclassification(result.labels, truth) < 0.05
    static = [k for k in range(result.num_models) if is_static(result.params[k])]
    assert len(static) == 1
    held = np.mean(result.labels[truth == 0] == static[0])
    assert held > 0.95
    # The static world's noise level is the tracking noise's (0.5 px; the residual lives in
    # the 2F - 3 directions a point leaves free).
    assert 0.3 < result.sigmas[static[0]] < 0.8


def test_frames_without_their_camera_are_left_out():
    tracks, _, cameras = static_scene(noise=0.5, seed=6)
    partial = cameras.copy()
    partial[[2, 5]] = np.nan
    kept = np.setdiff1d(np.arange(tracks.shape[0]), [2, 5])
    got = static_residuals(partial, tracks)
    expected = static_residuals(cameras[kept], tracks[kept])
    assert np.allclose(got[0], expected[0]) and np.array_equal(got[1], expected[1])
    one = np.full_like(cameras, np.nan)
    one[0] = cameras[0]
    with pytest.raises(InputError, match='two frames'):
        static_residuals(one, tracks)


def test_cameras_go_with_the_affine_family_only():
    tracks, _, cameras = static_scene()
    with pytest.raises(InputError, match='affine model only'):
        fit(tracks, PearlConfig(model='fundamental'), rng=0, cameras=cameras)
