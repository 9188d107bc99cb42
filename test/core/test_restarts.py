"""Batch fits are fitted again from fresh draws and keep the lowest energy.

``SolverSettings.two_view_restarts``: a two-view search ends in different minima from seed to
seed, so a batch two-view fit runs that many independent fits, drawn one after the other from
its one random generator, and keeps the one of least energy. Where the least of a batch fit's
(two-view or affine) is one motion whose noise level has widened past every level a fresh
proposal is offered at, up to ``SolverSettings.one_motion_restarts`` more fits are drawn, until
the least is no longer such an answer. The online segmenter's fits run once.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from pearl_ros.core import pearl
from pearl_ros.core.config import PearlConfig, SolverSettings
from pearl_ros.core.metrics import misclassification
from pearl_ros.datasets import hopkins, kt3dmoseg


def _config(restarts: int, model: str = 'fundamental', more: int = 0) -> PearlConfig:
    return PearlConfig(model=model, solver=SolverSettings(two_view_restarts=restarts,
                                                          one_motion_restarts=more))


def _least(results: list[pearl.PearlResult]) -> pearl.PearlResult:
    return min(results, key=lambda result: result.energy)


@pytest.mark.parametrize('seed', range(4))
def test_a_two_view_fit_keeps_the_least_energy_of_its_independent_fits(affine_scene, seed):
    # Oracle: the single fits drawn in turn from one generator, their least energy.
    tracks, _ = affine_scene(sizes=(70, 50), noise=0.5, seed=seed)
    tracks = tracks[[0, -1]]
    generator = np.random.default_rng(seed)
    singles = [pearl.fit(tracks, _config(1), generator) for _ in range(3)]
    best = _least(singles)
    kept = pearl.fit(tracks, _config(3, more=2), seed)
    assert kept.energy == pytest.approx(best.energy)
    assert kept.labels.tolist() == best.labels.tolist()


@pytest.mark.parametrize('seed', range(2))
def test_restarts_with_mismatches_keep_the_least_energy_of_their_independent_fits(
        two_view_scene, seed):
    # With 40% mismatches the neighbourhood is drawn in both views' coordinates and models
    # must keep their fellows (SolverSettings.joint_neighbours, kept_fellows); the restarts
    # draw it once and share it, each single fit draws its own.
    tracks, _ = two_view_scene(seed, mismatches=0.4)
    generator = np.random.default_rng(seed)
    singles = [pearl.fit(tracks, _config(1), generator) for _ in range(3)]
    best = _least(singles)
    kept = pearl.fit(tracks, _config(3), seed)
    assert kept.energy == best.energy
    assert kept.labels.tolist() == best.labels.tolist()


def test_a_restart_given_the_drawn_neighbourhood_sets_up_as_the_first_fit(two_view_scene):
    # The restarts take the first fit's neighbourhood as given: the same ties, and with
    # mismatches the same test of the models' fellows, as a setting that draws its own.
    tracks, _ = two_view_scene(3, mismatches=0.4)
    config = _config(3)
    first = pearl._setting(tracks, config, np.random.default_rng(0))
    again = pearl._setting(tracks, config, np.random.default_rng(0), graph=first.drawn)
    assert first.views is not None and again.views is not None
    assert np.array_equal(first.edges, again.edges)
    assert np.array_equal(first.weights, again.weights)
    assert np.array_equal(first.outlier_cost, again.outlier_cost)


def _widened_one(result: pearl.PearlResult) -> bool:
    # One motion whose noise level is past the widest level a fresh proposal is offered at.
    widest = max(SolverSettings().proposal_levels)
    return result.num_models == 1 and result.sigmas[0] > widest * result.scale


def _drawn(tracks: np.ndarray, config: PearlConfig, seed: int, first: int
           ) -> list[pearl.PearlResult]:
    # Oracle: the single fits drawn in turn from one generator; past the ``first``, drawn on
    # while the least energy so far is a widened one-motion answer, at most two more.
    generator = np.random.default_rng(seed)
    singles: list[pearl.PearlResult] = []
    for restart in range(first + 2):
        if restart >= first and not _widened_one(_least(singles)):
            break
        singles.append(pearl.fit(tracks, config, generator))
    return singles


def _one_motion_fits(tracks: np.ndarray, seed: int, model: str = 'fundamental',
                     **settings: float) -> tuple[bool, bool]:
    """Whether the fit kept the oracle's answer, and whether the oracle's answer differs from
    the least of the first fits a batch fit runs anyway (three two-view fits, one affine fit):
    the test can tell the rule from no rule."""
    first = 3 if model == 'fundamental' else 1
    label_cost = settings.pop('label_cost', PearlConfig().label_cost)
    single = PearlConfig(model=model, label_cost=label_cost,
                         solver=SolverSettings(two_view_restarts=1, one_motion_restarts=0,
                                               **settings))
    restarted = dataclasses.replace(single, solver=dataclasses.replace(
        single.solver, two_view_restarts=3, one_motion_restarts=2))
    singles = _drawn(tracks, single, seed, first)
    kept = pearl.fit(tracks, restarted, seed)
    same = (kept.energy == pytest.approx(_least(singles).energy)
            and kept.labels.tolist() == _least(singles).labels.tolist())
    return same, _least(singles).energy != _least(singles[:first]).energy


@pytest.mark.parametrize('model, seeds, settings', [
    # Two views: two bodies, a label cost above what the second saves and no noise ceiling:
    # every fit ends at one model for both, its noise level 5-16 noise scales, and five fits
    # are drawn.
    ('fundamental', range(4, 8), {'label_cost': 3000.0, 'local_ceiling': 0.0}),
    # Over all frames an affine fit runs once, and again where it ends at one motion past the
    # proposal levels: one affine subspace for both bodies at 6.5-9 noise scales on seeds
    # 0-2, 4 and 5, at 2 on seed 3.
    ('affine', range(6), {'label_cost': 4000.0}),
])
def test_a_widened_one_motion_answer_is_fitted_again(affine_scene, model, seeds, settings):
    differs = []
    for seed in seeds:
        tracks, _ = affine_scene(sizes=(60, 40), noise=0.5, seed=seed)
        view = tracks[[0, -1]] if model == 'fundamental' else tracks
        same, changed = _one_motion_fits(view, seed, model, **settings)
        assert same
        differs.append(changed)
    assert any(differs)


def test_a_one_motion_answer_within_the_proposal_levels_is_kept(affine_scene):
    # One rigid body: every fit ends at one motion at about one noise scale, so no fit is drawn
    # past the first three, though a fourth or fifth would have found a lower energy.
    differs = []
    for seed in range(4):
        tracks, _ = affine_scene(sizes=(90,), noise=0.5, seed=seed)
        same, _ = _one_motion_fits(tracks[[0, -1]], seed)
        assert same
        generator = np.random.default_rng(seed)
        config = _config(1)
        energies = [pearl.fit(tracks[[0, -1]], config, generator).energy for _ in range(5)]
        differs.append(min(energies) < min(energies[:3]) - 1e-9)
    assert any(differs)


def _with_and_without(tracks: np.ndarray, truth: np.ndarray, config: PearlConfig
                      ) -> tuple[dict[int, int], dict[int, float]]:
    """Over seeds 0-11, with ``one_motion_restarts`` 0 and 2: the seeds that end at one motion,
    and the mean error."""
    one, error = {0: 0, 2: 0}, {0: 0.0, 2: 0.0}
    for more in (0, 2):
        solver = dataclasses.replace(config.solver, one_motion_restarts=more)
        for seed in range(12):
            result = pearl.fit(tracks, dataclasses.replace(config, solver=solver), seed)
            one[more] += result.num_models == 1
            error[more] += misclassification(result.labels, truth) / 12
    return one, error


def test_the_one_motion_restarts_free_kt3dmoseg_seq013_from_one_motion(
        kt3dmoseg_root: Path) -> None:
    # Real data with ground truth: Seq013_Clip01's first and last frames (a car and the
    # driving background). Over seeds 0-11 the three fits all ended at one motion (its noise
    # level 9.3 noise scales), 43% of the points wrong, on seeds 4, 9 and 11 when measured;
    # drawing more fits while the least is such an answer leaves fewer such seeds, with lower
    # error.
    clip = kt3dmoseg.load_clip(kt3dmoseg_root / 'Seq013_Clip01_Tracks.mat')
    tracks, truth = clip.two_frames()
    one, error = _with_and_without(tracks, truth, _config(3))
    assert one[0] >= 2
    assert one[2] < one[0]
    assert error[2] < error[0] - 0.02


def test_the_one_motion_restarts_free_hopkins155_people1_from_one_motion(
        hopkins_root: Path) -> None:
    # Real data with ground truth: people1, all frames (a walking person and the background).
    # Over seeds 0-11 one fit ended at one motion on nine seeds, 6.3% of the points wrong,
    # against 0.4% for two, when measured; the fits drawn again leave fewer such seeds.
    sequence = hopkins.load_sequence(hopkins_root, 'people1')
    one, error = _with_and_without(sequence.tracks, sequence.labels, PearlConfig())
    assert one[0] >= 4
    assert one[2] < one[0]
    assert error[2] < error[0] - 0.01


@pytest.mark.parametrize('seed', range(3))
def test_affine_and_online_fits_run_once(affine_scene, seed):
    # The restarts are the batch two-view fits' alone: an affine fit that ends at two motions,
    # and a two-view fit of the online segmenter (batch=False), come out as with one fit.
    tracks, _ = affine_scene(sizes=(70, 50), noise=0.5, seed=seed)
    for model, view, batch in (('affine', tracks, True), ('fundamental', tracks[[0, -1]], False)):
        once = pearl.fit(view, _config(1, model), seed, batch=batch)
        again = pearl.fit(view, _config(3, model, more=2), seed, batch=batch)
        assert again.energy == once.energy and again.labels.tolist() == once.labels.tolist()


def test_the_restarts_lower_the_energy_and_error_of_hopkins155_two_frames(
        hopkins_root: Path) -> None:
    # Real data with ground truth: every fifth Hopkins155 sequence, its first and last frames,
    # two seeds. No fit's energy is above its single fit's (the first of the three), and the
    # mean error falls (5.39 -> 4.75% when measured).
    energies, errors = {1: [], 3: []}, {1: [], 3: []}
    for index, name in enumerate(hopkins.sequence_names(hopkins_root)[::5]):
        sequence = hopkins.load_sequence(hopkins_root, name)
        tracks = sequence.tracks[[0, -1]]
        for seed in range(2):
            for restarts in (1, 3):
                result = pearl.fit(tracks, _config(restarts), index + 100 * seed)
                energies[restarts].append(result.energy)
                errors[restarts].append(misclassification(result.labels, sequence.labels))
    assert all(b <= a + 1e-9 for a, b in zip(energies[1], energies[3], strict=True))
    assert sum(b < a - 1e-9 for a, b in zip(energies[1], energies[3], strict=True)) >= 5
    assert np.mean(errors[3]) < np.mean(errors[1]) - 0.003
