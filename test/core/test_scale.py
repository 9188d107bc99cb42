"""The automatic noise scale against scenes of known pixel noise; batched neighbourhood fits."""

from __future__ import annotations

import numpy as np
import pytest

from pearl_ros.core.config import SolverSettings
from pearl_ros.core.errors import InputError
from pearl_ros.core.models import get_model
from pearl_ros.core.neighbourhood import nearest_neighbours
from pearl_ros.core.scale import local_scale


def _scale(model_name: str, tracks: np.ndarray, seed: int = 0) -> float:
    model = get_model(model_name)
    data = model.data(tracks)
    return local_scale(model, data, nearest_neighbours(tracks[-1], 10),
                       np.random.default_rng(seed), SolverSettings().scale_seeds)


def _plane_pair(noise: float, seed: int = 8, n: int = 400) -> np.ndarray:
    """Two views of a plane (a homography, and degenerately any F through it), pixel noise."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 600, (n, 2))
    H = np.array([[1.02, 0.03, 5.0], [-0.02, 0.99, -3.0], [1e-5, -2e-5, 1.0]])
    moved = np.c_[xy, np.ones(n)] @ H.T
    return np.stack([xy, moved[:, :2] / moved[:, 2:]]) + rng.normal(0, noise, (2, n, 2))


@pytest.mark.parametrize('noise', [0.3, 1.0])
def test_affine_scale_recovers_the_pixel_noise_of_one_body(affine_scene, noise):
    tracks, _ = affine_scene(sizes=(300,), frames=10, noise=noise, seed=4)
    assert _scale('affine', tracks) == pytest.approx(noise, rel=0.25)


def test_batched_affine_fits_are_the_refits(affine_scene):
    tracks, _ = affine_scene(sizes=(150, 100), noise=0.7, seed=6)
    model = get_model('affine')
    data = model.data(tracks)
    groups = np.random.default_rng(1).integers(0, 250, (20, 11))
    params, ok = model.fit_groups(data, groups)
    assert ok.all()
    for group, batched in zip(groups, params, strict=True):
        one = model.refit(data, group, None)
        np.testing.assert_allclose(model.residuals(data, batched[None]),
                                   model.residuals(data, one[None]), atol=1e-8)


@pytest.mark.parametrize('noise', [0.5, 1.5])
def test_homography_scale_is_the_pixel_noise(noise):
    # The Sampson distance of a point with isotropic noise sigma per coordinate to the true
    # model is about sigma; the shift between the views is several pixels, far above it.
    assert _scale('homography', _plane_pair(noise)) == pytest.approx(noise, rel=0.35)


def test_unconstrained_fundamental_group_fits_beat_rank_two_linear_ones():
    # Why fit_groups skips the rank-2 projection: on small groups it inflates the residuals.
    model = get_model('fundamental')
    data = model.data(_plane_pair(1.0) + np.random.default_rng(3).normal(0, 0.01, (2, 400, 2)))
    groups = np.random.default_rng(2).integers(0, 400, (30, 11))
    loose, ok = model.fit_groups(data, groups)
    rank_two, _ = model._linear(data[groups], minimal=False)
    rows = np.arange(groups.shape[0])[:, None]
    ss_loose = np.sum(model.residuals(data, loose)[rows, groups] ** 2, axis=1)
    ss_rank_two = np.sum(model.residuals(data, rank_two)[rows, groups] ** 2, axis=1)
    assert np.median(ss_loose[ok] / ss_rank_two[ok]) < 0.9


@pytest.mark.parametrize('name', ['affine', 'fundamental', 'homography'])
def test_fit_groups_rejects_groups_smaller_than_a_minimal_sample(name, affine_scene):
    model = get_model(name)
    tracks, _ = affine_scene(sizes=(40,), noise=0.5)
    data = model.data(tracks)
    with pytest.raises(InputError, match='groups'):
        model.fit_groups(data, np.zeros((3, model.min_samples - 1), dtype=int))


def test_a_trimmed_scale_holds_where_outlier_tracks_inflate_least_squares(affine_scene) -> None:
    from pearl_ros.core.config import PearlConfig, SolverSettings
    from pearl_ros.core.pearl import noise_scale
    from pearl_ros.datasets.outliers import add_outlier_tracks

    tracks, labels = affine_scene(sizes=(80, 60), frames=10, noise=0.3, seed=1)
    dirty, _ = add_outlier_tracks(tracks, labels, 0.2, rng=1, step=3.0)
    trimmed = PearlConfig(solver=SolverSettings(scale_trim=2))
    # The scenes' noise is 0.3 px per coordinate: least squares over neighbourhoods that hold
    # outlier tracks reads far above it, the trimmed fit stays near it, with or without them.
    assert noise_scale(dirty, rng=0) > 0.9
    for data in (tracks, dirty):
        assert 0.24 < noise_scale(data, trimmed, rng=0) < 0.36
