"""Batch fits merge interchangeable models once the search settles.

``SolverSettings.interchangeable``: two models each of which holds the other's points within
that many of its own noise levels (the median point) are one motion, whatever the pair term
says. The oracle of each test is measured here, with the model's own residuals.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pearl_ros.core import pearl
from pearl_ros.core.config import PearlConfig, SolverSettings
from pearl_ros.core.metrics import misclassification
from pearl_ros.core.models import get_model
from pearl_ros.datasets import kt3dmoseg


def _config(interchangeable: float, model: str = 'fundamental') -> PearlConfig:
    return PearlConfig(model=model, solver=SolverSettings(interchangeable=interchangeable))


def _held(tracks: np.ndarray, config: PearlConfig, result: pearl.PearlResult) -> np.ndarray:
    """``held[i, j]``: the median residual of segment j's points to model i, in model i's
    noise levels, from the result's own models."""
    model = get_model(config.model, config.solver)
    residuals = model.residuals(model.data(tracks), result.params)
    k = result.num_models
    return np.array([[np.median(residuals[i, result.labels == j]) / result.sigmas[i]
                      for j in range(k)] for i in range(k)])


def _settled(tracks: np.ndarray, config: PearlConfig, segments: np.ndarray) -> pearl._Search:
    """The search of ``segments`` (each refitted to its points), after the settling step."""
    setting = pearl._setting(tracks, config, np.random.default_rng(0))
    search = pearl._start(setting, segments, 0.0)
    pearl._run(pearl._settle(search, [], {'refit': 0.0}))
    return search


def test_the_two_halves_of_one_rigid_body_are_one_motion(affine_scene):
    # One body seen in two views, cut in two by image position: each half's fundamental matrix
    # holds the other half at the noise, so the settled search has one model for all.
    tracks, _ = affine_scene(sizes=(160,), noise=0.5, seed=3)
    tracks = tracks[[0, -1]]
    halves = (tracks[-1, :, 0] > np.median(tracks[-1, :, 0])).astype(np.int64)
    search = _settled(tracks, _config(4.0), halves)
    assert np.unique(search.labels).tolist() == [1]
    assert search.params.shape[0] == 1
    # Off, the halves stay two.
    assert np.unique(_settled(tracks, _config(0.0), halves).labels).tolist() == [1, 2]


def test_two_bodies_that_move_differently_stay_apart(affine_scene):
    tracks, truth = affine_scene(sizes=(120, 100), noise=0.5, seed=5)
    tracks = tracks[[0, -1]]
    search = _settled(tracks, _config(4.0), truth)
    assert np.unique(search.labels).tolist() == [1, 2]
    assert misclassification(search.labels - 1, truth) == 0.0


@pytest.mark.parametrize('seed', range(3))
def test_online_fits_are_not_settled(affine_scene, seed):
    # The online segmenter's fits (batch=False) come out as with the merge off.
    tracks, _ = affine_scene(sizes=(80, 60), noise=0.5, seed=seed)
    for model, view in (('affine', tracks), ('fundamental', tracks[[0, -1]])):
        on = pearl.fit(view, _config(4.0, model), seed, batch=False)
        off = pearl.fit(view, _config(0.0, model), seed, batch=False)
        assert on.energy == off.energy and on.labels.tolist() == off.labels.tolist()


def test_kt3dmoseg_two_frames_no_result_holds_two_interchangeable_models(
        kt3dmoseg_root: Path) -> None:
    # Real data with ground truth, every development clip's first and last frames, seed 0.
    # Whatever the clip, no two models of the result hold each other's points within the
    # limit. On Seq009_Clip03 the energy cuts the static world in two along the near road
    # (11.8% misclassified with the merge off, when measured); merged, it is one motion.
    config = _config(4.0)
    for path in kt3dmoseg.clip_paths(kt3dmoseg_root):
        clip = kt3dmoseg.load_clip(path)
        tracks, truth = clip.two_frames()
        result = pearl.fit(tracks, config, 0)
        held = _held(tracks, config, result)
        apart = np.maximum(held, held.T)
        np.fill_diagonal(apart, np.inf)
        assert apart.size == 0 or apart.min() >= 4.0, clip.name
        if clip.name == 'Seq009_Clip03':
            assert misclassification(result.labels, truth) < 0.02
            cut = pearl.fit(tracks, _config(0.0), 0)
            assert misclassification(cut.labels, truth) > 0.08
            assert cut.energy < result.energy  # the energy itself prefers the cut
            history = result.energy_history
            assert result.energy == pytest.approx(history[-1]) and history[-1] > history[-2]
