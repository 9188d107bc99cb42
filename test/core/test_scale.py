"""The automatic noise scale against scenes of known pixel noise, refined and batched."""

from __future__ import annotations

import numpy as np
import pytest

from pearl_ros.core.errors import InputError
from pearl_ros.core.models import get_model
from pearl_ros.core.neighbourhood import nearest_neighbours
from pearl_ros.core.scale import local_scale


def _scale(model_name: str, tracks: np.ndarray, refine: bool, seed: int = 0) -> float:
    model = get_model(model_name)
    data = model.data(tracks)
    return local_scale(model, data, nearest_neighbours(tracks[-1], 10),
                       np.random.default_rng(seed), refine=refine)


@pytest.mark.parametrize('noise', [0.3, 1.0])
@pytest.mark.parametrize('refine', [True, False])
def test_affine_scale_recovers_the_pixel_noise_of_one_body(affine_scene, noise, refine):
    tracks, _ = affine_scene(sizes=(300,), frames=10, noise=noise, seed=4)
    assert _scale('affine', tracks, refine) == pytest.approx(noise, rel=0.25)


def test_batched_affine_fits_are_the_refits(affine_scene):
    # Principal subspaces either way: the batched route must give the refined scale exactly.
    tracks, _ = affine_scene(sizes=(150, 100), noise=0.7, seed=6)
    assert _scale('affine', tracks, False) == pytest.approx(_scale('affine', tracks, True),
                                                            rel=1e-9)


@pytest.mark.parametrize('name', ['fundamental', 'homography'])
def test_two_view_scale_is_of_the_pixel_noise_refined_or_not(name):
    # A plane seen by two cameras fits both a homography and (degenerately) a fundamental
    # matrix; the linear fit overfits less well than LM, so it can only come out larger.
    rng = np.random.default_rng(8)
    xy = rng.uniform(0, 600, (400, 2))
    H = np.array([[1.02, 0.03, 5.0], [-0.02, 0.99, -3.0], [1e-5, -2e-5, 1.0]])
    moved = np.c_[xy, np.ones(400)] @ H.T
    tracks = np.stack([xy, moved[:, :2] / moved[:, 2:]]) + rng.normal(0, 0.5, (2, 400, 2))
    refined, linear = _scale(name, tracks, True), _scale(name, tracks, False)
    assert 0.1 < refined <= linear * 1.05
    assert linear < 2.0  # px: the noise, not the motion (shifts of several px)


@pytest.mark.parametrize('name', ['affine', 'fundamental', 'homography'])
def test_fit_groups_rejects_groups_smaller_than_a_minimal_sample(name, affine_scene):
    model = get_model(name)
    tracks, _ = affine_scene(sizes=(40,), noise=0.5)
    data = model.data(tracks)
    with pytest.raises(InputError, match='groups'):
        model.fit_groups(data, np.zeros((3, model.min_samples - 1), dtype=int))
