"""PEaRL on scenes with known motions: accuracy, monotone energy, label-cost flips, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from pearl_ros.core import pearl
from pearl_ros.core.config import PearlConfig, SolverSettings
from pearl_ros.core.errors import InputError
from pearl_ros.core.expansion import Expansions
from pearl_ros.core.labels import OUTLIER
from pearl_ros.core.metrics import misclassification
from pearl_ros.core.models import get_model
from pearl_ros.core.neighbourhood import neighbourhood
from pearl_ros.core.pearl import evaluate_segmentation, fit
from pearl_ros.datasets import hopkins


# Motions of 120+ points: with the default label cost, a motion of under ~100 points behind a
# looser model straddling it cannot always pay its own label (the energy prefers the merge:
# BENCHMARKS.md, "What limits accuracy now"; docs/experiments.md, "The label cost").
@pytest.mark.parametrize('sizes,seed', [((200, 150), 2), ((200, 150, 120), 3),
                                        ((200, 150, 120), 4)])
def test_fit_finds_the_number_of_motions_and_segments_them(affine_scene, sizes, seed):
    tracks, truth = affine_scene(sizes=sizes, noise=0.5, seed=seed)
    result = fit(tracks, rng=0)
    assert result.num_models == len(sizes)
    assert misclassification(result.labels, truth) < 0.02


def test_energy_never_increases_across_iterations(affine_scene):
    tracks, _ = affine_scene(sizes=(100, 70, 60), noise=1.0, seed=11)
    result = fit(tracks, rng=1)
    history = np.array(result.energy_history)
    assert history.size >= 2
    assert np.all(np.diff(history) <= 1e-6)
    assert result.energy == pytest.approx(history[-1])


def test_a_higher_label_cost_leaves_fewer_models(affine_scene):
    tracks, _ = affine_scene(sizes=(100, 70, 60), noise=0.5, seed=4)
    cheap = fit(tracks, PearlConfig(label_cost=100.0), rng=0)
    dear = fit(tracks, PearlConfig(label_cost=1e6), rng=0)
    assert cheap.num_models == 3
    assert dear.num_models < cheap.num_models


def translating_pair(seed: int, frames: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Two flat objects 40 px apart, each translating on its own straight path: dependent
    motions (each trajectory set is a 2-D affine subspace, both with the same directions, so
    their union fits one 3-D subspace as well as two do). Closer, the local subspaces of the
    points along the gap mix the two objects and the pairs across it look alike."""
    rng = np.random.default_rng(seed)
    left = rng.uniform([0, 0], [200, 240], (150, 2))
    right = rng.uniform([240, 0], [440, 240], (120, 2))
    steps = np.arange(frames)[:, None, None]
    tracks = np.concatenate([left + steps * [2.0, 0.5], right + steps * [-0.5, 1.5]], axis=1)
    tracks = tracks + rng.normal(0, 0.3, tracks.shape)
    return tracks, np.repeat([0, 1], [150, 120])


@pytest.mark.parametrize('core_patches', [False, True])
@pytest.mark.parametrize('seed', [0, 1, 2])
def test_neighbours_that_move_apart_keep_dependent_motions_apart(seed, core_patches):
    tracks, truth = translating_pair(seed)
    found = fit(tracks, PearlConfig(solver=SolverSettings(core_patches=core_patches)), rng=0)
    assert found.num_models == 2
    assert misclassification(found.labels, truth) < 0.02
    # With every neighbour pair weighted alike and no reward for cutting one, the energy
    # prefers one subspace for both.
    plain = fit(tracks, PearlConfig(separation=0.0, contrast=1e6), rng=0)
    assert plain.num_models == 1


def test_fit_is_deterministic_for_a_seed(affine_scene):
    tracks, _ = affine_scene(sizes=(80, 60), noise=1.0, seed=2)
    first, again = fit(tracks, rng=7), fit(tracks, rng=7)
    assert np.array_equal(first.labels, again.labels)
    assert first.energy == again.energy


@pytest.mark.parametrize('model', ['affine', 'fundamental'])
def test_a_fit_in_slices_is_the_fit_however_it_is_sliced(affine_scene, model):
    # One step per slice (a deadline already past) and one slice for all (no deadline in
    # sight) give the labels, models and energy of fit itself, for the same seed (one search:
    # a batch two-view fit's restarts are fit's alone).
    tracks, _ = affine_scene(sizes=(80, 60), noise=1.0, seed=2)
    if model == 'fundamental':
        tracks = tracks[[0, -1]]
    config = PearlConfig(model=model, rounds=2, solver=SolverSettings(two_view_restarts=1))
    whole = fit(tracks, config, rng=7)
    stepwise = pearl.SlicedFit(tracks, config, rng=7)
    results = [stepwise.advance(0.0) for _ in range(200)]
    done = next(i for i, r in enumerate(results) if r is not None)
    # Setup, then per round its proposals, and per iteration at least one expansion move.
    assert done + 1 == stepwise.steps_run >= 1 + config.rounds + whole.iterations
    assert all(r is None for r in results[:done]) and all(r is results[done]
                                                         for r in results[done:])
    at_once = pearl.SlicedFit(tracks, config, rng=7).advance(float('inf'))
    for sliced in (results[done], at_once):
        assert sliced is not None
        assert np.array_equal(sliced.labels, whole.labels)
        assert np.array_equal(sliced.params, whole.params)
        assert sliced.energy == whole.energy and sliced.iterations == whole.iterations


@pytest.mark.parametrize('model', ['affine', 'fundamental'])
def test_proposals_offered_in_chunks_are_the_proposals_offered_at_once(affine_scene, model,
                                                                      monkeypatch):
    # The chunks only split the fitting and measuring of samples drawn beforehand: any chunk
    # size gives the fit of one batch.
    tracks, _ = affine_scene(sizes=(80, 60), noise=1.0, seed=3)
    if model == 'fundamental':
        tracks = tracks[[0, -1]]
    config = PearlConfig(model=model, rounds=2)
    results = []
    for chunk in (10**9, 7):
        monkeypatch.setattr(pearl, 'PROPOSE_CHUNK', chunk)
        results.append(fit(tracks, config, rng=5))
    batch, chunked = results
    assert np.array_equal(batch.labels, chunked.labels)
    assert np.array_equal(batch.params, chunked.params)
    assert batch.energy == chunked.energy and batch.energy_history == chunked.energy_history


def test_a_given_neighbourhood_is_the_one_fit_builds(affine_scene):
    tracks, _ = affine_scene(sizes=(80, 60), noise=1.0, seed=2)
    given = fit(tracks, rng=7, graph=neighbourhood(tracks))
    built = fit(tracks, rng=7)
    assert np.array_equal(given.labels, built.labels)
    assert given.energy == built.energy
    # A neighbourhood of other points is refused, naming it.
    with pytest.raises(InputError, match='neighbourhood'):
        fit(tracks[:, :-1], rng=7, graph=neighbourhood(tracks))


def test_gross_outliers_get_the_outlier_label_minus_one(affine_scene):
    tracks, truth = affine_scene(sizes=(120, 90), noise=0.5, seed=8)
    rng = np.random.default_rng(0)
    bad = rng.choice(tracks.shape[1], 8, replace=False)
    tracks[:, bad] += rng.uniform(-80, 80, (tracks.shape[0], bad.size, 2))
    result = fit(tracks, rng=0)
    # One outlier label, -1, in results; the models are 0..K-1 (the optimiser's own outlier
    # row, 0, never shows).
    assert OUTLIER == -1
    assert np.mean(result.labels[bad] == OUTLIER) >= 0.75
    assert set(np.unique(result.labels)) == {OUTLIER, *range(result.num_models)}
    good = np.setdiff1d(np.arange(truth.size), bad)
    assert misclassification(result.labels[good], truth[good]) < 0.02


def test_assign_gives_held_out_points_their_true_motion_and_gross_outliers_minus_one(
        affine_scene):
    # The scene's truth is the oracle: a fit on every other point, the rest assigned by its
    # models alone; points moved by tens of pixels per frame fit no model.
    tracks, truth = affine_scene(sizes=(120, 90), noise=0.5, seed=8)
    rng = np.random.default_rng(1)
    bad = rng.choice(tracks.shape[1], 10, replace=False)
    tracks[:, bad] += rng.uniform(-80, 80, (tracks.shape[0], bad.size, 2))
    held = np.zeros(truth.size, dtype=bool)
    held[1::2] = True
    result = fit(tracks[:, ~held], rng=0)
    labels = pearl.assign(tracks[:, held], result)
    good = ~np.isin(np.flatnonzero(held), bad)
    assert np.all(labels[~good] == OUTLIER)
    assert misclassification(labels[good], truth[held][good]) < 0.02
    assert np.mean(labels[good] == OUTLIER) < 0.02
    # Points the fit saw get the model whose data cost is least, as the fit's own labels do
    # wherever the pair term does not decide (it rarely does on this clear scene).
    own = pearl.assign(tracks[:, ~held], result)
    assert np.mean(own == result.labels) > 0.97


def test_assign_without_models_labels_every_point_an_outlier(affine_scene):
    tracks, _ = affine_scene(sizes=(60,), noise=0.5, seed=2)
    empty = pearl.PearlResult(np.full(60, OUTLIER), np.empty((0, 2 * tracks.shape[0], 4)),
                              np.empty(0), 0.0, (), 0, scale=0.5)
    assert np.all(pearl.assign(tracks, empty) == OUTLIER)


@pytest.mark.parametrize('model', ['fundamental', 'homography'])
def test_two_view_models_run_through_the_same_optimiser(affine_scene, model):
    tracks, truth = affine_scene(sizes=(120, 90), noise=0.3, seed=6)
    result = fit(tracks[[0, -1]], PearlConfig(model=model), rng=0)
    assert result.num_models >= 1
    assert result.labels.shape == truth.shape


def test_too_few_points_raise_a_clear_error():
    with pytest.raises(InputError, match='at least'):
        fit(np.zeros((5, 3, 2)))


def test_non_finite_tracks_raise_input_error(affine_scene):
    tracks, _ = affine_scene(sizes=(30,))
    tracks[2, 4, 0] = np.inf
    with pytest.raises(InputError, match='finite'):
        fit(tracks)


@pytest.mark.parametrize('field,value', [('noise', -1.0), ('label_cost', -2.0),
                                         ('model', 'sphere'), ('local_sampling', 1.5),
                                         ('rounds', 0), ('long_edge_growth', 0.5)])
def test_config_rejects_out_of_range_values_naming_the_field(field, value):
    with pytest.raises(InputError, match=field):
        PearlConfig(**{field: value})


def test_evaluate_segmentation_gives_fit_its_own_energy_and_ranks_the_truth_first(affine_scene):
    tracks, truth = affine_scene(sizes=(200, 150), noise=0.5, seed=2)
    result = fit(tracks, rng=5)
    own, _ = evaluate_segmentation(tracks, result.labels, rng=5)
    assert own == pytest.approx(result.energy, rel=1e-9)
    true_energy, residuals = evaluate_segmentation(tracks, truth, rng=5)
    merged, _ = evaluate_segmentation(tracks, np.zeros_like(truth), rng=5)
    assert true_energy < merged
    # Independent check of the residual rows: each true motion fits its own points best.
    assert np.mean(residuals.argmin(axis=0) == truth) > 0.99


def test_evaluate_segmentation_rejects_labels_of_the_wrong_length(affine_scene):
    from pearl_ros.core.pearl import evaluate_segmentation

    tracks, truth = affine_scene(sizes=(40,))
    with pytest.raises(InputError, match='labels'):
        evaluate_segmentation(tracks, truth[:-1])


# The init term (temporal Potts in the online segmenter) -----------------------------------


def _corrupted_init(truth: np.ndarray, moved: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The true segmentation with ``moved`` points of motion 0 put in motion 1."""
    init = truth.copy()
    wrong = np.random.default_rng(seed).choice(np.flatnonzero(truth == 0), moved, replace=False)
    init[wrong] = 1
    return init, wrong


def test_without_init_cost_a_warm_start_corrects_wrong_init_labels(affine_scene):
    tracks, truth = affine_scene(sizes=(200, 150), noise=0.5, seed=2)
    init, wrong = _corrupted_init(truth, 12, seed=0)
    result = fit(tracks, PearlConfig(rounds=1), rng=0, init=init)
    assert misclassification(result.labels, truth) < 0.01


def test_a_dear_init_cost_keeps_the_init_labels_a_cheap_one_does_not(affine_scene):
    # Behaviour flip: at 1e4 cost units a point pays far more to leave its init segment than
    # any residual (the outlier cost is about 100 units), so the wrong labels stay put.
    tracks, truth = affine_scene(sizes=(200, 150), noise=0.5, seed=2)
    init, wrong = _corrupted_init(truth, 12, seed=0)
    kept = fit(tracks, PearlConfig(rounds=1), rng=0, init=init, init_cost=1e4)
    assert misclassification(kept.labels, init) == 0.0
    cheap = fit(tracks, PearlConfig(rounds=1), rng=0, init=init, init_cost=0.5)
    assert misclassification(cheap.labels, truth) < 0.01


def test_energy_with_an_init_cost_never_increases(affine_scene):
    tracks, truth = affine_scene(sizes=(120, 90, 70), noise=1.0, seed=5)
    init, _ = _corrupted_init(truth, 10, seed=1)
    history = np.array(fit(tracks, rng=3, init=init, init_cost=2.0).energy_history)
    assert history.size >= 2
    assert np.all(np.diff(history) <= 1e-6)


def test_the_init_term_costs_nothing_when_every_point_keeps_its_segment(affine_scene):
    # Started from the truth, both fits keep it; the term then adds exactly zero, so the
    # energies agree (the outlier label and new models would each have cost 5 units a point).
    tracks, truth = affine_scene(sizes=(200, 150), noise=0.5, seed=2)
    plain = fit(tracks, PearlConfig(rounds=1), rng=0, init=truth)
    with_term = fit(tracks, PearlConfig(rounds=1), rng=0, init=truth, init_cost=5.0)
    assert misclassification(plain.labels, truth) == 0.0
    assert misclassification(with_term.labels, truth) == 0.0
    assert with_term.energy == pytest.approx(plain.energy, rel=1e-9)


def test_models_that_go_on_pay_their_share_of_the_label_cost(affine_scene):
    # Oracle: evaluate_segmentation charges every segment the whole label cost (label_cost
    # times the family's weight). Started from
    # the truth without fresh proposals, each model of the result stands for an init segment,
    # so at a share s the fit's energy is that less (1 - s) label costs per model.
    tracks, truth = affine_scene(sizes=(200, 150, 120), noise=0.5, seed=4)
    config = PearlConfig(rounds=1)
    for share in (1.0, 0.5, 0.0):
        result = fit(tracks, config, rng=0, init=truth, propose=False, init_label_share=share)
        assert misclassification(result.labels, truth) == 0.0
        whole, _ = evaluate_segmentation(tracks, result.labels, config, rng=0)
        model = get_model(config.model)
        per_model = config.label_cost * model.label_cost_weight(model.data(tracks))
        saved = (1.0 - share) * per_model * result.num_models
        assert result.energy == pytest.approx(whole - saved, rel=1e-9)


def test_a_motion_is_kept_at_a_share_of_the_label_cost_that_would_not_start_it(affine_scene):
    # Behaviour flip: a small body (12 points) whose data gain is below the label cost but
    # above a tenth of it. Cold, with every proposal paying the whole cost, it is merged; a
    # warm start from the truth keeps it when its model pays a tenth, and merges it at the whole.
    tracks, truth = affine_scene(sizes=(200, 12), noise=0.5, seed=6)
    config = PearlConfig(rounds=1, label_cost=5e3)
    assert fit(tracks, config, rng=0).num_models == 1
    kept = fit(tracks, config, rng=0, init=truth, init_label_share=0.1)
    assert misclassification(kept.labels, truth) == 0.0
    whole = fit(tracks, config, rng=0, init=truth, init_label_share=1.0)
    assert whole.num_models == 1


def test_an_init_label_share_outside_0_1_is_rejected(affine_scene):
    tracks, truth = affine_scene(sizes=(60, 50), noise=0.5)
    with pytest.raises(InputError, match='init_label_share'):
        fit(tracks, rng=0, init=truth, init_label_share=1.5)


def test_a_negative_init_cost_is_rejected(affine_scene):
    tracks, truth = affine_scene(sizes=(60, 50), noise=0.5)
    with pytest.raises(InputError, match='init_cost'):
        fit(tracks, rng=0, init=truth, init_cost=-1.0)


def test_a_passed_deadline_stops_after_the_first_iteration(affine_scene):
    # Past the deadline, one iteration runs: expansions until some point has a model, one
    # split trial, no merges; the result still labels every point.
    tracks, truth = affine_scene(sizes=(120, 90), noise=0.5, seed=8)
    late = fit(tracks, rng=0, deadline=0.0)
    free = fit(tracks, rng=0)
    assert late.iterations == 1 and len(late.energy_history) == 1
    assert free.iterations > 1
    assert late.labels.shape == truth.shape
    assert np.any(late.labels != OUTLIER)
    assert late.energy >= free.energy - 1e-6


def test_a_passed_deadline_bounds_a_warm_fit_to_a_relabelling_and_one_split_trial(
        affine_scene, monkeypatch):
    # The bound that keeps a budgeted frame short: started warm, a fit past its deadline
    # expands each label in use once (a relabelling with the current models) and runs one
    # split trial, however many proposals it holds.
    tracks, truth = affine_scene(sizes=(120, 90, 80), noise=0.5, seed=3)
    moves = []
    real = Expansions.move

    def counted(self, alpha):
        moves.append(alpha)
        return real(self, alpha)

    monkeypatch.setattr(Expansions, 'move', counted)
    fit(tracks, rng=0, init=truth)
    unbounded = len(moves)
    moves.clear()
    late = fit(tracks, rng=0, init=truth, deadline=0.0)
    relabel, split = moves[:-1], moves[-1]
    in_use = {pearl.OUTLIER_ROW, 1, 2, 3}  # the optimiser's labels of the three segments
    assert len(relabel) == len(set(relabel)) and set(relabel) <= in_use
    assert split not in in_use
    assert len(moves) < unbounded
    assert late.labels.shape == truth.shape


def test_without_proposals_a_warm_start_keeps_its_models(affine_scene):
    # Behaviour flip: started from one segment covering both motions, only fresh proposals can
    # split it; with propose=False the models are only relabelled and refitted.
    tracks, truth = affine_scene(sizes=(200, 150), noise=0.5, seed=2)
    merged = np.zeros_like(truth)
    kept = fit(tracks, rng=0, init=merged, propose=False)
    split = fit(tracks, rng=0, init=merged)
    assert kept.num_models == 1
    assert split.num_models == 2 and misclassification(split.labels, truth) < 0.02


def gapped_perspective_body(seed: int, frames: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """One rigid body close to a pinhole camera, turning: its trajectories miss any one 3-D
    affine subspace by perspective. It has no features in a vertical band across its middle,
    so its two halves are joined only by long neighbour edges, as on the Hopkins155 sequences
    whose extra motions were pieces of one body cut off along such edges. Returns the tracks
    and the half (0, 1) each point is on."""
    rng = np.random.default_rng(seed)
    cloud = rng.uniform([-3, -2, -1.5], [3, 2, 1.5], (960, 3))
    cloud = cloud[np.abs(cloud[:, 0]) > 1.2][:240]
    tracks = []
    for t in range(frames):
        angle = 0.06 * t
        turn = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0],
                         [-np.sin(angle), 0, np.cos(angle)]])
        world = cloud @ turn.T + [0.1 * t, 0.0, 8.0]
        tracks.append(400 * world[:, :2] / world[:, 2:] + [320, 240])
    tracks = np.stack(tracks) + rng.normal(0, 0.3, (frames, cloud.shape[0], 2))
    return tracks, (cloud[:, 0] > 0).astype(np.int64)


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_merge_moves_join_two_halves_of_one_body(seed, monkeypatch):
    tracks, halves = gapped_perspective_body(seed)
    one = np.zeros_like(halves)
    # The energy prefers one model for the body ...
    assert evaluate_segmentation(tracks, one, rng=0)[0] < evaluate_segmentation(tracks, halves,
                                                                                rng=0)[0]
    # ... which the merge move finds from the two halves, without fresh proposals ...
    merged = fit(tracks, rng=0, init=halves, propose=False)
    assert merged.num_models == 1 and np.all(merged.labels == 0)
    # The merge's bookkeeping (in-place refits, freed pairs and label cost) agrees with the
    # energy recomputed from scratch, and the energy went down.
    history = np.array(merged.energy_history)
    assert np.all(np.diff(history) <= 1e-6)
    assert merged.energy == pytest.approx(history[-1], rel=1e-9)
    assert merged.energy == pytest.approx(evaluate_segmentation(tracks, one, rng=0)[0], rel=1e-9)
    # ... and expansions alone do not: neither half's model fits the other half.
    def no_merges(search, deadline=None):
        yield from ()
        return 0

    monkeypatch.setattr(pearl, '_merge', no_merges)
    assert fit(tracks, rng=0, init=halves, propose=False).num_models == 2


def test_merge_moves_leave_different_motions_apart(affine_scene):
    tracks, truth = affine_scene(sizes=(200, 150, 120), noise=0.5, seed=3)
    kept = fit(tracks, rng=0, init=truth, propose=False)
    assert kept.num_models == 3 and misclassification(kept.labels, truth) < 0.02


def test_long_edge_growth_loosens_the_long_edges_within_one_body(gap_scene):
    # One rigid body in two clusters 300 px apart: the edges across the gap are long.
    tracks, cluster = gap_scene(same_body=True)
    plain = pearl._setting(tracks, PearlConfig(long_edge_growth=1.0), np.random.default_rng(0))
    grown = pearl._setting(tracks, PearlConfig(), np.random.default_rng(0))
    across = cluster[plain.edges[:, 0]] != cluster[plain.edges[:, 1]]
    assert np.any(across) and np.array_equal(grown.edges, plain.edges)
    assert np.array_equal(grown.weights[~across], plain.weights[~across])
    # A larger unit reads the same miss as more alike: a higher weight on every such edge.
    assert np.all(grown.weights[across] > plain.weights[across])


def test_a_sigma_ceiling_bounds_every_model_noise_level(affine_scene) -> None:
    from pearl_ros.core.config import SolverSettings
    from pearl_ros.datasets.outliers import add_outlier_tracks

    tracks, labels = affine_scene(sizes=(80, 60), frames=10, noise=0.3, seed=0)
    tracks, labels = add_outlier_tracks(tracks, labels, 0.2, rng=1, step=3.0)
    free = fit(tracks, PearlConfig(), rng=0)
    assert free.sigmas.max() > 4.0 * free.scale  # outliers widen some model without a ceiling
    capped = fit(tracks, PearlConfig(solver=SolverSettings(sigma_ceiling=4.0)), rng=0)
    assert capped.scale == free.scale
    assert capped.sigmas.max() <= 4.0 * capped.scale * (1 + 1e-12)


def _count_refits(monkeypatch):
    """A list that gets the member count of every model refit from now on."""
    calls = []
    real = pearl._refit_one

    def counted(setting, members, start):
        calls.append(members.size)
        return real(setting, members, start)

    monkeypatch.setattr(pearl, '_refit_one', counted)
    return calls


def test_closed_form_models_already_fitted_to_their_points_are_not_refitted(affine_scene,
                                                                          monkeypatch):
    # Oracle: the same fit with the shortcut disabled. An affine refit depends on its points
    # only, so skipping one whose points did not change must leave every result bit for bit.
    tracks, truth = affine_scene(sizes=(120, 90, 80), noise=0.5, seed=5)
    calls = _count_refits(monkeypatch)
    fast = fit(tracks, rng=0, init=truth, init_cost=2.0)
    skipped_calls = len(calls)
    calls.clear()
    monkeypatch.setattr(pearl._Search, 'refitted_already', lambda self, label, members: False)
    slow = fit(tracks, rng=0, init=truth, init_cost=2.0)
    assert skipped_calls < len(calls)
    assert np.array_equal(fast.labels, slow.labels)
    assert np.array_equal(fast.params, slow.params)
    assert fast.energy == slow.energy


@pytest.mark.parametrize('model', ['fundamental', 'homography'])
def test_batch_two_view_models_refitted_to_the_same_points_are_not_refitted_again(
        affine_scene, model, monkeypatch):
    # Oracle: the same fit refitting every model every iteration. A Levenberg-Marquardt refit
    # of a model to the points it was last refitted to starts where it ended: the labels and
    # the models' noise levels come out the same, the energy within what a further LM step
    # gains. The online segmenter's fits (batch=False) keep refitting.
    tracks, _ = affine_scene(sizes=(120, 90), noise=0.5, seed=4)
    tracks = tracks[[0, -1]]
    config = PearlConfig(model=model)
    calls = _count_refits(monkeypatch)
    results, counts = {}, {}
    for batch in (True, False):
        calls.clear()
        results[batch] = fit(tracks, config, rng=3, batch=batch)
        counts[batch] = len(calls)
    monkeypatch.setattr(pearl._Search, 'refitted_already', lambda self, label, members: False)
    for batch in (True, False):
        calls.clear()
        every = fit(tracks, config, rng=3, batch=batch)
        assert np.array_equal(results[batch].labels, every.labels)
        np.testing.assert_allclose(results[batch].sigmas, every.sigmas, rtol=1e-6)
        assert results[batch].energy == pytest.approx(every.energy, rel=1e-6)
        if batch:
            assert counts[batch] < len(calls)
        else:
            assert counts[batch] == len(calls)


@pytest.mark.parametrize('name', ['cars9_g12', 'kanatani3'])
def test_a_long_sequence_pays_no_more_than_the_label_cost_per_motion(hopkins_root, name):
    # Real data with ground truth: two Hopkins155 sequences of 61 and 100 frames, two motions
    # each. With the label cost grown in proportion to the frames (no ceiling: two and three
    # label costs per motion) the energy prefers one motion for both; at most one label cost
    # per motion (affine_cost_ceiling 1), both motions are found.
    sequence = hopkins.load_sequence(hopkins_root, name)
    assert sequence.tracks.shape[0] > 60
    found = fit(sequence.tracks, rng=0)
    assert found.num_models == 2
    assert misclassification(found.labels, sequence.labels) < 0.02
    grown = fit(sequence.tracks, PearlConfig(solver=SolverSettings(affine_cost_ceiling=0.0)),
                rng=0)
    assert grown.num_models == 1


def test_patches_drawn_around_their_cores_keep_two_dependent_bodies_apart(hopkins_root):
    # Real data with ground truth: Hopkins155 `2RT3RTCRT_g23`, two bodies whose neighbours
    # across the boundary move almost alike. Patches of the closest-moving neighbours take
    # points of both bodies, the pairs across the boundary read alike, and the energy prefers
    # one motion; patches drawn around their cores (SolverSettings.core_patches, the default)
    # find both.
    sequence = hopkins.load_sequence(hopkins_root, '2RT3RTCRT_g23')
    found = fit(sequence.tracks, rng=0)
    assert found.num_models == 2
    assert misclassification(found.labels, sequence.labels) < 0.02
    closest = fit(sequence.tracks, PearlConfig(solver=SolverSettings(core_patches=False)), rng=0)
    assert closest.num_models == 1
