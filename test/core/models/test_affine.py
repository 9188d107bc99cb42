"""Affine trajectory subspaces: exact fits, residuals against an independent projection."""

from __future__ import annotations

import numpy as np
import pytest

from pearl_ros.core.config import SolverSettings
from pearl_ros.core.errors import InputError
from pearl_ros.core.models.affine import AffineSubspace


def test_minimal_fit_passes_through_its_samples_and_the_whole_noise_free_body(affine_scene):
    tracks, labels = affine_scene(sizes=(60,), noise=0.0)
    model = AffineSubspace()
    data = model.data(tracks)
    params, ok = model.fit_minimal(data, np.array([[0, 7, 21, 40]]))
    assert ok.all()
    assert model.residuals(data, params).max() < 1e-4  # px; cancellation in the expanded form


def test_residual_is_rms_pixel_distance_to_the_subspace(affine_scene):
    tracks, _ = affine_scene(sizes=(50,), noise=1.0, seed=3)
    model = AffineSubspace()
    data = model.data(tracks)
    params = model.refit(data, np.arange(50), None)
    mean, basis = params[:, 0], params[:, 1:]
    # Independent route: explicit orthogonal projector on the raw (unscaled) trajectories.
    raw = np.transpose(tracks, (1, 0, 2)).reshape(50, -1)
    scale = np.sqrt(tracks.shape[0])
    proj = np.eye(raw.shape[1]) - basis @ basis.T
    dist = np.linalg.norm((raw - mean * scale) @ proj, axis=1)
    expected = dist / scale
    assert np.allclose(model.residuals(data, params)[0], expected, atol=1e-8)


def test_refit_minimises_squared_residuals_better_than_any_minimal_fit(affine_scene):
    tracks, _ = affine_scene(sizes=(80,), noise=1.0, seed=5)
    model = AffineSubspace()
    data = model.data(tracks)
    best = model.refit(data, np.arange(80), None)
    cost = np.square(model.residuals(data, best)).sum()
    rng = np.random.default_rng(0)
    params, ok = model.fit_minimal(data, rng.integers(0, 80, (50, 4)))
    others = np.square(model.residuals(data, params[ok])).sum(axis=1)
    assert cost <= others.min()


def test_degenerate_samples_are_flagged_not_raised(affine_scene):
    tracks, _ = affine_scene(sizes=(20,), noise=0.0)
    model = AffineSubspace()
    data = model.data(tracks)
    params, ok = model.fit_minimal(data, np.array([[0, 0, 1, 2], [0, 1, 2, 3]]))
    assert not ok[0] and ok[1]
    assert model.refit(data, np.array([0, 1, 2]), None) is None


def test_residual_dof_matches_the_mean_squared_residual_of_pure_noise():
    rng = np.random.default_rng(1)
    frames, n, sigma = 10, 4000, 0.7
    tracks = np.zeros((frames, n, 2)) + rng.normal(0, sigma, (frames, n, 2))
    model = AffineSubspace()
    data = model.data(tracks)
    # The true subspace (through 0, any 3 directions) leaves 2F - 3 noise directions.
    basis = np.linalg.qr(rng.normal(size=(2 * frames, 3)))[0]
    params = np.concatenate([np.zeros((2 * frames, 1)), basis], axis=1)[None]
    mean_sq = np.square(model.residuals(data, params)).mean()
    assert mean_sq / sigma**2 == pytest.approx(model.residual_dof(data), rel=0.03)


@pytest.mark.parametrize('bad', [np.zeros((5, 10)), np.zeros((1, 10, 2)),
                                 np.full((3, 10, 2), np.nan)])
def test_bad_tracks_raise_input_error_naming_the_argument(bad):
    with pytest.raises(InputError, match='tracks'):
        AffineSubspace().data(bad)


@pytest.mark.parametrize('frames, ceiling, weight', [
    (15, 1.0, 0.5), (30, 1.0, 1.0), (60, 1.0, 1.0), (100, 1.5, 1.5), (60, 0.0, 2.0),
    (100, 0.0, 100 / 30)])
def test_the_label_cost_grows_with_the_frames_up_to_its_ceiling(frames, ceiling, weight):
    # F / 30 (affine_reference_frames), never above affine_cost_ceiling; 0 is no ceiling.
    model = AffineSubspace(SolverSettings(affine_cost_ceiling=ceiling))
    data = model.data(np.zeros((frames, 5, 2)))
    assert model.label_cost_weight(data) == pytest.approx(weight, rel=1e-12)
