"""The online segmenter on synthetic streams with known motions, births, deaths and reused ids."""

from __future__ import annotations

import dataclasses
import functools
import math
import time

import numpy as np
import pytest

from pearl_ros.core.config import PearlConfig
from pearl_ros.core.errors import InputError
from pearl_ros.core.labels import OUTLIER
from pearl_ros.core.metrics import match_labels, misclassification
from pearl_ros.datasets.synthetic import BodySpec, synthetic_stream
from pearl_ros.online.config import OnlineConfig
from pearl_ros.online.segmenter import OnlineSegmenter

WINDOW = OnlineConfig().window


# No time budget: labels must not depend on the machine's load, or runs that should agree
# exactly (feature order, a refused bad frame) would differ whenever the budget bites.
UNTIMED = OnlineConfig(budget_ms=0.0)


def run(frames, segmenter=None):
    segmenter = segmenter or OnlineSegmenter(online=UNTIMED)
    return segmenter, [segmenter.process(f.stamp_ns, f.ids, f.uv) for f in frames]


def number_of(result, frame, motion):
    """The label number most features of true ``motion`` carry in this frame."""
    values = result.labels[(frame.truth == motion) & (result.labels >= 0)]
    return int(np.bincount(values).argmax()) if values.size else -1


def test_two_motions_are_found_and_keep_their_numbers_through_births_deaths_and_shuffles():
    frames = list(synthetic_stream(200, 40, (BodySpec(0.4),), death_rate=0.03, seed=0))
    _, results = run(frames)
    settled = range(2 * WINDOW, len(frames))
    for t in settled:
        assert results[t].motions == 2
        assert misclassification(results[t].labels, frames[t].truth) < 0.15
    background = {number_of(results[t], frames[t], 0) for t in settled}
    car = {number_of(results[t], frames[t], 1) for t in settled}
    assert len(background) == 1 and len(car) == 1 and background != car


def test_a_motion_starting_mid_stream_gets_a_fresh_number_and_the_background_keeps_its_own():
    # A known limit: a motion that starts under a settled single model is not always split off
    # (seed 1 of this scene stays one model; docs/experiments.md, "Synthetic streams": objects
    # found late or missed); seed 5 shows the identity rules.
    # The object holds 40% of the features: the background, the larger part of the old
    # segment, is the one that keeps its number.
    start = 15
    frames = list(synthetic_stream(200, 45, (BodySpec(0.4, start=start),), seed=5))
    _, results = run(frames)
    before = results[start - 1]
    assert before.motions == 1
    old = number_of(before, frames[start - 1], 0)
    after = range(start + WINDOW + 5, len(frames))
    for t in after:
        assert results[t].motions == 2
        assert number_of(results[t], frames[t], 0) == old
        assert number_of(results[t], frames[t], 1) not in (old, -1)
        assert misclassification(results[t].labels, frames[t].truth) < 0.15


def test_with_rare_proposals_a_rise_in_energy_still_calls_them_when_a_motion_starts():
    # propose_every=1000: no scheduled proposals after the first warm frame, so the new motion
    # can only be found because its start raises the energy per feature (the scene above with
    # an object of half the features).
    start = 15
    frames = list(synthetic_stream(200, 45, (BodySpec(0.5, start=start),), seed=5))
    _, results = run(frames, OnlineSegmenter(online=dataclasses.replace(UNTIMED,
                                                                        propose_every=1000)))
    assert results[start - 1].motions == 1
    for t in range(start + WINDOW + 5, len(frames)):
        assert results[t].motions == 2
        assert misclassification(results[t].labels, frames[t].truth) < 0.15


def test_an_object_that_stops_retires_its_number_for_good():
    stop = 15
    frames = list(synthetic_stream(200, 45, (BodySpec(0.4, stop=stop),), seed=2))
    _, results = run(frames)
    moving = results[stop - 1]
    background = number_of(moving, frames[stop - 1], 0)
    car = number_of(moving, frames[stop - 1], 1)
    assert moving.motions == 2 and car != background
    for t in range(stop + WINDOW + 5, len(frames)):
        assert results[t].motions == 1
        assert car not in results[t].labels
        assert np.mean(results[t].labels == background) > 0.9


@pytest.mark.parametrize('seed', [0, 2])
def test_an_object_that_pauses_takes_its_number_back_when_it_moves_again(seed):
    # The object moves with the background over frames 15-29: its segment merges into the
    # background's and its number is retired; its tracks still remember it (1% of them die a
    # frame), so when it moves on its own again the segment split off takes it back.
    frames = list(synthetic_stream(200, 60, (BodySpec(0.4, pause=(15, 30)),), death_rate=0.01,
                                   seed=seed))
    _, results = run(frames)
    background = number_of(results[14], frames[14], 0)
    car = number_of(results[14], frames[14], 1)
    assert results[14].motions == 2 and car not in (background, -1)
    assert results[29].motions == 1 and car not in results[29].labels
    for t in range(30 + WINDOW + 5, len(frames)):
        assert results[t].motions == 2
        assert number_of(results[t], frames[t], 0) == background
        assert number_of(results[t], frames[t], 1) == car


def test_after_a_reset_no_track_takes_back_a_number_from_before_it():
    # The paused object's stream twice over: after the reset its features are new tracks (the
    # window's keys keep increasing) that remember nothing, and the numbering goes on, so the
    # second pass gives out fresh numbers only, and still takes its own back after the pause.
    frames = list(synthetic_stream(200, 60, (BodySpec(0.4, pause=(15, 30)),), death_rate=0.01,
                                   seed=0))
    seg, first = run(frames)
    before = {int(k) for r in first for k in r.labels if k >= 0}
    seg.reset()
    second = [seg.process(f.stamp_ns, f.ids, f.uv) for f in frames]
    after = {int(k) for r in second for k in r.labels if k >= 0}
    assert after and not after & before
    car = number_of(second[14], frames[14], 1)
    assert number_of(second[-1], frames[-1], 1) == car  # the number still comes back


@pytest.mark.parametrize('seed', [0, 1])
def test_a_static_world_seen_driving_forward_is_one_motion_on_every_frame(seed):
    # Perspective spreads a driving camera's static world over more than one affine subspace
    # (near points stream outwards, far ones barely move): a segmenter that cuts it in two
    # tells a visual-inertial estimator that half of the static world moves.
    rng = np.random.default_rng(seed)
    world = np.column_stack([rng.uniform(-15, 15, 250), rng.uniform(-3, 1.5, 250),
                             rng.uniform(3, 60, 250)])
    segmenter = OnlineSegmenter(online=dataclasses.replace(UNTIMED, seed=seed))
    labelled = 0
    for t in range(40):
        yaw = 0.005 * t  # 8 m/s at 30 Hz, turning 0.15 rad/s
        turn = np.array([[math.cos(yaw), 0.0, math.sin(yaw)], [0.0, 1.0, 0.0],
                         [-math.sin(yaw), 0.0, math.cos(yaw)]])
        seen = (world - [0.0, 0.0, 8.0 * t / 30]) @ turn
        uv = 500.0 * seen[:, :2] / seen[:, 2:] + [320.0, 240.0]
        ids = np.flatnonzero((seen[:, 2] > 1.0) & np.all((uv > 0) & (uv < [640, 480]), axis=1))
        result = segmenter.process(1_000_000_000 + t * 33_333_333, ids,
                                   uv[ids] + rng.normal(0.0, 0.5, (ids.size, 2)))
        motions = np.unique(result.labels[result.labels >= 0])
        assert motions.size <= 1, f'frame {t}: {motions.size} motions'
        assert np.mean(result.labels == OUTLIER) < 0.02 or t < 2
        labelled += motions.size
    assert labelled >= 35  # every frame once the first motion is fitted


def test_feature_order_does_not_change_the_labels_of_a_feature():
    frames = list(synthetic_stream(150, 25, (BodySpec(0.4),), seed=3))
    rng = np.random.default_rng(0)
    shuffled = []
    for f in frames:
        order = rng.permutation(f.ids.size)
        shuffled.append(dataclasses.replace(f, ids=f.ids[order], uv=f.uv[order],
                                            truth=f.truth[order]))
    _, plain = run(frames)
    _, other = run(shuffled)
    for f, g, a, b in zip(frames, shuffled, plain, other, strict=True):
        by_id = dict(zip(f.ids.tolist(), a.labels.tolist(), strict=True))
        assert [by_id[i] for i in g.ids.tolist()] == b.labels.tolist()


def test_an_id_that_comes_back_is_a_new_track():
    seg = OnlineSegmenter()
    uv = np.random.default_rng(0).uniform(0, 500, (30, 2))
    ids = np.arange(30)
    seg.process(1, ids, uv)
    seg.process(2, ids[1:], uv[1:])
    seg.process(3, ids, uv)
    coords, age = seg._window.history(seg._window._frames[-1].keys)
    # Id 0 returned after a gap: its track has one frame, everyone else's three.
    assert sorted(age.tolist()) == [1] + [3] * 29


def _ages(frames, t):
    """Frames each feature of frame ``t`` has been tracked for, counting frame ``t`` (capped)."""
    held = np.ones(frames[t].ids.size, dtype=np.int64)
    alive = np.ones(frames[t].ids.size, dtype=bool)
    for k in range(1, WINDOW):
        alive &= np.isin(frames[t].ids, frames[t - k].ids)
        held += alive
    return held


@pytest.mark.parametrize('seed', [0, 2, 3])
def test_young_tracks_take_the_motion_whose_subspace_is_nearest(seed):
    # Tracks of 2 to 8 frames are too young for the window's fit; their own short trajectories
    # still tell their motion. Judged where the fitted tracks are segmented right, with the
    # labels matched to the truth on those tracks only.
    frames = list(synthetic_stream(200, 40, (BodySpec(0.4),), death_rate=0.05, seed=seed))
    _, results = run(frames)
    hits = total = 0
    for t in range(2 * WINDOW, len(frames)):
        frame, result, age = frames[t], results[t], _ages(frames, t)
        old, young = age >= WINDOW, (age >= 2) & (age < WINDOW - 1)
        if misclassification(result.labels[old], frame.truth[old]) > 0.05:
            continue
        mapping = match_labels(result.labels[old], frame.truth[old])
        predicted = np.array([mapping.get(int(v), -2) for v in result.labels[young]])
        hits += int(np.sum(predicted == frame.truth[young]))
        total += int(young.sum())
    # Every young track labelled background would score about 0.6 here (the object holds 40%
    # of the features); the neighbour vote scored 0.52-0.70 on tracks of 2 frames.
    assert total >= 500
    assert hits / total >= 0.9


def test_newborn_features_are_labelled_from_their_neighbours():
    # One frame gives no motion to judge by: a newborn feature takes the vote of its image
    # neighbours (test_vote.py checks the vote itself), never -1 while labelled ones exist.
    frames = list(synthetic_stream(200, 30, (BodySpec(0.4),), death_rate=0.05, seed=0))
    _, results = run(frames)
    for t in range(2 * WINDOW, len(frames)):
        newborn = _ages(frames, t) == 1
        if np.any(results[t].labels[~newborn] >= 0):
            assert np.all(results[t].labels[newborn] >= 0)


def test_non_finite_features_get_the_outlier_label_and_the_rest_are_labelled():
    frames = list(synthetic_stream(150, 20, (BodySpec(0.4),), seed=5))
    seg, _ = run(frames[:-1])
    last = frames[-1]
    uv = last.uv.copy()
    uv[[0, 7]] = [np.nan, np.inf]
    result = seg.process(last.stamp_ns, last.ids, uv)
    assert OUTLIER == -1 and (result.labels[[0, 7]] == OUTLIER).all()
    assert np.mean(result.labels >= 0) > 0.9


def test_too_few_features_give_the_outlier_label_without_error():
    seg = OnlineSegmenter()
    for t in range(3):
        result = seg.process(t + 1, np.arange(3), np.zeros((3, 2)) + t)
        assert (result.labels == OUTLIER).all() and result.motions == 0
    result = seg.process(10, np.array([], dtype=np.int64), np.empty((0, 2)))
    assert result.labels.shape == (0,)


@pytest.mark.parametrize('ids,uv,match', [
    (np.array([1, 2, 2]), np.zeros((3, 2)), 'duplicate ids'),
    (np.array([1, 2]), np.zeros((3, 2)), 'uv must have shape'),
    (np.array([1.5, 2.0]), np.zeros((2, 2)), 'integers'),
])
def test_bad_frames_raise_and_leave_the_state_untouched(ids, uv, match):
    frames = list(synthetic_stream(150, 14, (BodySpec(0.4),), seed=6))
    reference, expected = run(frames)
    seg, _ = run(frames[:-1])
    with pytest.raises(InputError, match=match):
        seg.process(frames[-1].stamp_ns - 1, ids, uv)
    assert seg.process(frames[-1].stamp_ns, frames[-1].ids, frames[-1].uv).labels.tolist() \
        == expected[-1].labels.tolist()


def test_a_repeated_stamp_is_refused_and_an_older_one_resets_the_window():
    frames = list(synthetic_stream(100, 6, (BodySpec(0.4),), seed=7))
    seg, _ = run(frames)
    with pytest.raises(InputError, match='repeats'):
        seg.process(frames[-1].stamp_ns, frames[-1].ids, frames[-1].uv)
    assert seg.frames_in_window == 6
    result = seg.process(frames[0].stamp_ns, frames[0].ids, frames[0].uv)
    assert result.reset and seg.frames_in_window == 1


def test_state_stays_bounded_on_a_long_stream():
    frames = synthetic_stream(100, 120, (BodySpec(0.4),), death_rate=0.1, seed=8)
    seg = OnlineSegmenter(online=OnlineConfig(window=5))
    for f in frames:
        seg.process(f.stamp_ns, f.ids, f.uv)
        assert seg.frames_in_window <= 5
        assert seg._labelled_keys.size <= f.ids.size
        assert seg._before_keys.size <= f.ids.size


def test_warm_and_cold_agree_with_the_truth_on_a_clear_scene():
    frames = list(synthetic_stream(200, 25, (BodySpec(0.4),), seed=9))
    for warm in (True, False):
        _, results = run(frames, OnlineSegmenter(online=dataclasses.replace(UNTIMED,
                                                                             warm_start=warm)))
        assert misclassification(results[-1].labels, frames[-1].truth) < 0.1
        assert results[-1].warm == warm


def _fit_calls(monkeypatch, online, read):
    """Run a one-object synthetic stream through a segmenter with ``online``; ``(warm, read(
    config, kwargs))`` for each call of fit, recorded by a spy that calls the real fit."""
    from pearl_ros.online import segmenter as module
    given = []

    def spy(tracks, config, *args, **kwargs):
        given.append((kwargs.get('init') is not None, read(config, kwargs)))
        return real(tracks, config, *args, **kwargs)

    real = module.fit
    monkeypatch.setattr(module, 'fit', spy)
    run(list(synthetic_stream(120, 6, (BodySpec(0.4),), seed=13)),
        OnlineSegmenter(online=online))
    return given


def test_warm_frames_measure_pairs_in_their_own_unit(monkeypatch):
    # The segmenter hands fit a configuration: the cold start keeps unit_quantile, every fit
    # of a warm frame takes warm_unit_quantile (a fit without init there is the check of a
    # warm fit that ends with few motions, solver.restart_motions).
    online = dataclasses.replace(UNTIMED, warm_unit_quantile=0.3)
    given = _fit_calls(monkeypatch, online, lambda config, kwargs: config.unit_quantile)
    assert given[0] == (False, PearlConfig().unit_quantile)
    assert len(given) > 1 and {quantile for _, quantile in given[1:]} == {0.3}
    assert any(warm for warm, _ in given[1:])


def test_warm_frames_let_the_last_frame_s_motions_go_on_at_their_share_of_the_label_cost(
        monkeypatch):
    # Every warm fit gets continued_label_cost as the share its init models pay; a cold fit
    # has no init for it to apply to.
    online = dataclasses.replace(UNTIMED, continued_label_cost=0.25)
    given = _fit_calls(monkeypatch, online, lambda config, kwargs: kwargs['init_label_share'])
    assert {share for warm, share in given if warm} == {0.25}
    assert any(not warm for warm, _ in given)


def test_same_seed_same_frames_same_labels():
    frames = list(synthetic_stream(150, 15, (BodySpec(0.4),), seed=10))
    online = OnlineConfig(budget_ms=0.0)
    _, a = run(frames, OnlineSegmenter(online=online))
    _, b = run(frames, OnlineSegmenter(online=online))
    assert all(x.labels.tolist() == y.labels.tolist() for x, y in zip(a, b, strict=True))


@pytest.mark.parametrize('model', ['fundamental', 'homography'])
def test_two_frame_windows_use_the_two_view_model(model):
    frames = list(synthetic_stream(100, 2, (BodySpec(0.4),), seed=11))
    seg = OnlineSegmenter(online=OnlineConfig(two_view_model=model, budget_ms=0.0))
    results = [seg.process(f.stamp_ns, f.ids, f.uv) for f in frames]
    assert results[0].model == '' and results[1].model == model and results[1].frames == 2


def test_reconfigure_applies_a_smaller_window_from_the_next_frame():
    frames = list(synthetic_stream(100, 12, (BodySpec(0.4),), seed=12))
    seg, _ = run(frames[:-1])
    seg.reconfigure(online=OnlineConfig(window=4))
    assert seg.frames_in_window == 4
    result = seg.process(frames[-1].stamp_ns, frames[-1].ids, frames[-1].uv)
    assert result.frames <= 4


def test_a_budget_smaller_than_any_frame_still_converges_one_slice_a_frame():
    # With a budget no frame can meet, every frame does the least work: one expansion, one
    # split trial, a slice of the cold start's proposals. Spread over frames, that work still
    # finds both objects; the unbudgeted run is the reference.
    frames = list(synthetic_stream(300, 40, (BodySpec(0.2), BodySpec(0.15)), seed=0))
    starved = OnlineSegmenter(online=dataclasses.replace(UNTIMED, budget_ms=1e-6))
    _, starved_results = run(frames, starved)
    _, free_results = run(frames)
    for results in (starved_results, free_results):
        assert results[-1].motions == 3
        assert misclassification(results[-1].labels, frames[-1].truth) < 0.02


def test_a_budgeted_cold_start_draws_what_the_unbudgeted_one_draws(monkeypatch):
    # Budgeted or not, the cold fit draws num_proposals in each of its rounds (budgeted, over
    # the frames it takes), and the frames after it propose at the warm cadence.
    from pearl_ros.online import segmenter as module

    drawn = []
    real, real_sliced = module.fit, module.SlicedFit

    def spy(tracks, config, rng, **kwargs):
        drawn.append((config.num_proposals, config.rounds, kwargs['propose']))
        return real(tracks, config, rng, **kwargs)

    def sliced_spy(tracks, config, rng, graph, deadline, **kwargs):
        drawn.append((config.num_proposals, config.rounds, True))
        return real_sliced(tracks, config, rng, graph, deadline, **kwargs)

    monkeypatch.setattr(module, 'fit', spy)
    monkeypatch.setattr(module, 'SlicedFit', sliced_spy)
    frames = list(synthetic_stream(150, 40, (BodySpec(0.3),), seed=2))
    cold = PearlConfig()
    for budget in (0.0, 1e-6):
        drawn.clear()
        run(frames, OnlineSegmenter(online=dataclasses.replace(UNTIMED, budget_ms=budget)))
        assert drawn[0] == (cold.num_proposals, cold.rounds, True)
        assert len(drawn) > 1
        assert all(n == UNTIMED.warm_proposals and r == UNTIMED.warm_rounds
                   for n, r, _ in drawn[1:])


def test_a_cold_start_in_slices_ends_with_the_labels_of_the_unbudgeted_one(monkeypatch,
                                                                             same_partition):
    # With no cap on the budgets it may take, the budgeted cold start (a cold fit of the
    # window of COLD_START_FRAMES frames, a millisecond's worth a frame) finds what the
    # unbudgeted segmenter's first fit finds: however its steps fall into frames, when it is
    # done the features still seen carry the partition the unbudgeted segmenter gave them on
    # its first fit (up to the numbers).
    from pearl_ros.online import segmenter as module

    monkeypatch.setattr(module, 'COLD_BUDGETS', 1e15)
    # Every 8th frame, so that the first fit, two frames apart, finds the three motions.
    frames = list(synthetic_stream(150, 8 * 120, (BodySpec(0.3), BodySpec(0.25)),
                                   death_rate=0.0, seed=4))[::8]
    _, sliced = run(frames, OnlineSegmenter(online=dataclasses.replace(UNTIMED,
                                                                       budget_ms=1.0)))
    _, free = run(frames[:2])
    done = next(t for t, r in enumerate(sliced) if r.warm) - 1
    assert done > 1 and free[1].motions == 3
    # Tracks seen on every frame since (one lost and found again is a new track).
    kept = functools.reduce(np.intersect1d, [f.ids for f in frames[:done + 1]])
    assert kept.size > 100
    here = np.flatnonzero(np.isin(frames[done].ids, kept))
    here = here[np.argsort(frames[done].ids[here])]
    there = np.flatnonzero(np.isin(frames[1].ids, kept))
    there = there[np.argsort(frames[1].ids[there])]
    assert same_partition(sliced[done].labels[here], free[1].labels[there])


def test_a_budgeted_cold_start_answers_its_labels_so_far_until_its_fit_is_done(monkeypatch):
    # A budget far below any step, no cap on the budgets: the cold fit runs one step a frame.
    # It begins once the window holds COLD_START_FRAMES frames, in the affine family; before
    # its first move every feature is -1; from then on the tracks it fits carry its labelling
    # so far, and from the frame after it is done the frames start warm.
    from pearl_ros.online import segmenter as module

    monkeypatch.setattr(module, 'COLD_BUDGETS', 1e15)
    frames = list(synthetic_stream(150, 120, (BodySpec(0.4),), seed=3))
    _, results = run(frames, OnlineSegmenter(online=dataclasses.replace(UNTIMED,
                                                                        budget_ms=1e-6)))
    first = next(t for t, r in enumerate(results) if r.motions)
    done = next(t for t, r in enumerate(results) if r.warm) - 1
    begun = module.COLD_START_FRAMES - 1  # the frame it begins on
    assert begun < first < done  # the first fit took several frames
    for r in results[:first]:
        assert np.all(r.labels == OUTLIER) and r.model == '' and r.frames == 0 and not r.warm
    for r, frame in zip(results[first:done + 1], frames[first:done + 1], strict=True):
        assert r.model == 'affine' and r.frames == module.COLD_START_FRAMES and not r.warm
        # Tracks born since the frame it began on wait for the warm frames; the fit's tracks
        # have motions.
        born = ~np.isin(frame.ids, frames[begun].ids)
        assert r.motions >= 1 and np.all(r.labels[born] == OUTLIER)
    assert all(r.warm for r in results[done + 1:])
    assert results[-1].motions == 2
    assert misclassification(results[-1].labels, frames[-1].truth) < 0.05


@pytest.mark.parametrize('window', [2, 3])
def test_a_window_shorter_than_the_cold_start_s_begins_it_once_full(window):
    # A budgeted cold start waits for COLD_START_FRAMES frames, or for a full window where the
    # window holds fewer: it begins on the first frame whose window is full, over that window.
    from pearl_ros.online import segmenter as module

    assert window < module.COLD_START_FRAMES
    frames = list(synthetic_stream(150, 30, (BodySpec(0.4),), seed=3))
    _, results = run(frames, OnlineSegmenter(online=dataclasses.replace(
        UNTIMED, window=window, budget_ms=1e-6)))
    first = next(t for t, r in enumerate(results) if r.motions)
    assert first >= window - 1 and results[first].frames == window
    assert results[-1].motions == 2
    assert misclassification(results[-1].labels, frames[-1].truth) < 0.05


def _spy_on_deadlines(monkeypatch, late_first=0.0):
    """The segmenter's warm fits, spied on: the list of the seconds each had left until its
    deadline when it began; the first one ends ``late_first`` s past its deadline."""
    from pearl_ros.online import segmenter as module

    real_fit, room = module.fit, []

    def timed_fit(tracks, config, rng, **kwargs):
        deadline = kwargs['deadline']
        room.append(deadline - time.perf_counter())
        result = real_fit(tracks, config, rng, **kwargs)
        if late_first and len(room) == 1:
            time.sleep(max(deadline + late_first - time.perf_counter(), 0.0))
        return result

    monkeypatch.setattr(module, 'fit', timed_fit)
    return room


BUDGETED = dataclasses.replace(UNTIMED, budget_ms=50.0, warm_start=True)


def test_the_work_after_the_fit_comes_out_of_the_frames_budget(monkeypatch):
    # The budget bounds the frame, its answer included: where labelling the young tracks
    # takes 30 ms, a 50 ms budget leaves the fit at most 20 ms from when it starts.
    from pearl_ros.online import segmenter as module

    real_young = module._nearest_subspace

    def slow_young(*args, **kwargs):
        time.sleep(0.030)
        return real_young(*args, **kwargs)

    room = _spy_on_deadlines(monkeypatch)
    monkeypatch.setattr(module, '_nearest_subspace', slow_young)
    run(list(synthetic_stream(150, 12, (BodySpec(0.3),), seed=1)), OnlineSegmenter(
        online=BUDGETED))
    # Warm fits after one with young tracks labelled: the 30 ms are set aside.
    assert len(room) > 4
    assert max(room[2:]) <= 0.020


def test_the_budget_counts_from_when_the_frame_arrived(monkeypatch):
    # A frame that waited 30 ms for the worker (a node's callback took it then) leaves the fit
    # at most 20 ms of a 50 ms budget.
    room = _spy_on_deadlines(monkeypatch)
    seg = OnlineSegmenter(online=dataclasses.replace(UNTIMED, budget_ms=50.0))
    for frame in synthetic_stream(150, 12, (BodySpec(0.3),), seed=1):
        seg.process(frame.stamp_ns, frame.ids, frame.uv, arrived=time.perf_counter() - 0.030)
    assert len(room) > 4
    assert max(room) <= 0.020


def test_the_time_an_answer_took_to_go_out_comes_out_of_the_next_frames_budget(monkeypatch):
    # A node that takes 30 ms to publish each answer, and says so (delivered), leaves the
    # fits of the frames after at most 20 ms of a 50 ms budget.
    room = _spy_on_deadlines(monkeypatch)
    seg = OnlineSegmenter(online=BUDGETED)
    for frame in synthetic_stream(150, 12, (BodySpec(0.3),), seed=1):
        seg.process(frame.stamp_ns, frame.ids, frame.uv)
        time.sleep(0.030)
        seg.delivered()
    assert len(room) > 4
    assert max(room) <= 0.020


def test_a_fit_that_ran_past_its_deadline_leaves_the_next_fits_that_much_earlier(monkeypatch):
    # The first warm fit's last step runs 15 ms past its deadline: the fits after it stop
    # 15 ms earlier, 35 ms into a 50 ms budget at most.
    room = _spy_on_deadlines(monkeypatch, late_first=0.015)
    run(list(synthetic_stream(150, 12, (BodySpec(0.3),), seed=1)), OnlineSegmenter(
        online=BUDGETED))
    assert len(room) > 4
    assert room[0] > 0.035 and max(room[1:]) <= 0.035


@pytest.mark.parametrize('at', [math.nan, -math.inf, 'later'])
def test_a_delivery_time_that_is_no_time_is_refused(at):
    frames = list(synthetic_stream(150, 3, (BodySpec(0.3),), seed=1))
    seg = OnlineSegmenter(online=UNTIMED)
    run(frames, seg)
    with pytest.raises(InputError, match='at must be a finite'):
        seg.delivered(at)


@pytest.mark.parametrize('arrived', [math.nan, math.inf, 'now'])
def test_an_arrival_time_that_is_no_time_is_refused(arrived):
    frame = next(iter(synthetic_stream(50, 1, (BodySpec(0.3),), seed=1)))
    seg = OnlineSegmenter(online=UNTIMED)
    with pytest.raises(InputError, match='arrived must be a finite'):
        seg.process(frame.stamp_ns, frame.ids, frame.uv, arrived=arrived)
    assert seg.frames_in_window == 0


def test_a_reset_drops_a_cold_start_under_way():
    frames = list(synthetic_stream(150, 12, (BodySpec(0.4),), seed=3))
    seg = OnlineSegmenter(online=dataclasses.replace(UNTIMED, budget_ms=1e-6))
    run(frames[:3], seg)  # the cold start is under way
    seg.reset()
    # Frames from the start again: the cold start begins anew on the new window's first fit,
    # as on a fresh segmenter.
    _, again = run(frames, seg)
    _, fresh = run(frames, OnlineSegmenter(online=dataclasses.replace(UNTIMED,
                                                                      budget_ms=1e-6)))
    assert [r.motions for r in again] == [r.motions for r in fresh]


def test_chosen_tracks_stay_chosen_as_tracks_that_hash_higher_come_and_go():
    from pearl_ros.online.segmenter import _chosen
    keys = np.arange(100, 400, dtype=np.int64)
    first = set(keys[_chosen(keys, 50)].tolist())
    assert len(first) == 50 and _chosen(keys, 0) is None and _chosen(keys, 300) is None
    # New tracks arrive (keys 400-499) and old ones not chosen die: a chosen track is dropped
    # only for a newcomer that hashes lower, never for another old one.
    later_keys = np.concatenate([keys[np.isin(keys, list(first)) | (keys % 3 == 0)],
                                 np.arange(400, 500)])
    later = set(later_keys[_chosen(later_keys, 50)].tolist())
    kept = first & later
    newcomers = later - set(keys.tolist())
    assert len(kept) + len(newcomers) == 50
    assert not (later - kept - newcomers)


def test_with_a_cap_every_spanning_feature_is_labelled_by_the_fit_s_models():
    # 240 features, the optimiser sees 100: the others go to the models by their data cost
    # and come out as right as those the optimiser labelled (ground truth as the oracle).
    frames = list(synthetic_stream(240, 25, (BodySpec(0.4),), seed=9))
    capped = dataclasses.replace(UNTIMED, max_fitted=100)
    _, results = run(frames, OnlineSegmenter(online=capped))
    for t in range(2 * WINDOW, len(frames)):
        assert results[t].motions == 2
        assert misclassification(results[t].labels, frames[t].truth) < 0.1
        assert np.mean(results[t].labels == OUTLIER) < 0.05
    _, again = run(frames, OnlineSegmenter(online=capped))
    assert all(x.labels.tolist() == y.labels.tolist() for x, y in zip(results, again, strict=True))
