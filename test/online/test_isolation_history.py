"""Isolation judged over time (pearl_ros.online.isolation): each track's isolation ratios over
its last fits, the tracks far above the scene's median, and what the segmenter hands fit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pearl_ros.core import pearl
from pearl_ros.core.config import PearlConfig, SolverSettings
from pearl_ros.core.errors import InputError
from pearl_ros.core.metrics import misclassification
from pearl_ros.core.neighbourhood import neighbourhood
from pearl_ros.datasets.robot import robot_stream
from pearl_ros.online.config import OnlineConfig
from pearl_ros.online.isolation import LEAST_JUDGED, IsolationHistory, persistent_suspects
from pearl_ros.online.segmenter import OnlineSegmenter

SETTINGS = SolverSettings()


def test_a_track_keeps_its_last_ratios_and_forgets_them_once_it_is_gone():
    # Oracle: a dict of per-key lists, cut to the last `frames` values; a key missing from a
    # frame starts over when it comes back.
    rng = np.random.default_rng(0)
    frames = 4
    history, oracle = IsolationHistory(frames), {}
    for _ in range(30):
        keys = rng.permutation(np.flatnonzero(rng.random(12) < 0.7))
        ratios = rng.uniform(0.5, 50.0, keys.size)
        ratios[rng.random(keys.size) < 0.1] = np.inf  # no neighbour: not recorded
        rows = history.update(keys, ratios)
        oracle = {int(k): (oracle.get(int(k), []) + [r])[-frames:]
                  for k, r in zip(keys, ratios, strict=True)}
        for key, row in zip(keys, rows, strict=True):
            want = [np.log(r) if np.isfinite(r) else np.nan for r in oracle[int(key)]]
            want = [np.nan] * (frames - len(want)) + want
            np.testing.assert_array_equal(row, want)


def test_a_ratio_of_zero_counts_as_the_least_ratio_seen():
    logs = np.log(np.full((LEAST_JUDGED, 5), 2.0))
    logs[0] = -np.inf  # a point its neighbour fits exactly
    logs[1, 2] = -np.inf
    logs[-1] = np.log(100.0)
    suspect = persistent_suspects(logs, SETTINGS)
    assert np.flatnonzero(suspect).tolist() == [LEAST_JUDGED - 1]


def _oracle(logs, settings, rough=None):
    """The rule, one track at a time."""
    judged = [i for i, row in enumerate(logs) if np.count_nonzero(~np.isnan(row)) >=
              settings.persist_frames]
    means = {i: float(np.nanmean(logs[i])) for i in judged}
    values = np.array(list(means.values()))
    median = float(np.median(values))
    spread = 1.4826 * float(np.median(np.abs(values - median)))

    def threshold(i):
        deviations = settings.persist_deviations
        if rough is not None and rough[i]:
            deviations = settings.persist_rough_deviations
        return max(median + deviations * spread, np.log(settings.persist_least))

    return sorted(i for i in judged if means[i] > threshold(i))


@pytest.mark.parametrize('seed', range(5))
def test_tracks_far_above_the_median_track_are_suspected(seed):
    rng = np.random.default_rng(seed)
    n, frames = 60, 10
    logs = rng.normal(0.3, 0.3, (n, frames))
    logs[rng.random((n, frames)) < 0.3] = np.nan  # tracks born late, frames not fitted
    wanderers = rng.choice(n, 6, replace=False)
    logs[wanderers] += rng.uniform(1.0, 4.0, (6, 1))
    got = np.flatnonzero(persistent_suspects(logs, SETTINGS)).tolist()
    assert got == _oracle(logs, SETTINGS)
    assert set(got) <= set(wanderers.tolist())


@pytest.mark.parametrize('seed', range(5))
def test_rough_tracks_are_suspected_on_less_isolation(seed):
    # Four tracks set 6.5 robust deviations above the median track: past the rough tracks'
    # threshold (5), short of the others' (8); two of them rough. Only those two are
    # suspected.
    rng = np.random.default_rng(seed)
    n, frames = 60, 10
    logs = rng.normal(0.5, 0.6, (n, frames))  # 6.5 deviations: past persist_least (3)
    rough = rng.random(n) < 0.2
    between = rng.choice(n, 4, replace=False)
    rough[between] = [True, True, False, False]

    def scene():
        means = logs.mean(axis=1)
        median = float(np.median(means))
        return means, median, 1.4826 * float(np.median(np.abs(means - median)))

    for _ in range(50):  # moving them moves the median and the spread: to a fixed point
        means, median, spread = scene()
        logs[between] += (median + 6.5 * spread - means[between])[:, None]
    means, median, spread = scene()
    np.testing.assert_allclose((means[between] - median) / spread, 6.5, atol=0.01)
    assert (means[between] > np.log(SETTINGS.persist_least)).all()
    got = np.flatnonzero(persistent_suspects(logs, SETTINGS, rough)).tolist()
    assert got == _oracle(logs, SETTINGS, rough)
    assert set(got) & set(between.tolist()) == set(between[:2].tolist())
    plain = np.flatnonzero(persistent_suspects(logs, SETTINGS)).tolist()
    assert plain == _oracle(logs, SETTINGS) and not set(plain) & set(between.tolist())
    off = dataclasses.replace(SETTINGS, persist_rough_deviations=0.0)
    assert np.flatnonzero(persistent_suspects(logs, off, rough)).tolist() == plain


def test_none_is_suspected_where_every_track_moves_alike_or_too_few_are_judged():
    alike = np.zeros((40, 10))  # every ratio 1: no spread at all
    alike[0] = np.log(2.5)  # above the median, but under persist_least (3)
    assert not persistent_suspects(alike, SETTINGS).any()
    alike[0] = np.log(4.0)
    assert persistent_suspects(alike, SETTINGS).tolist() == [True] + [False] * 39
    few = alike[: LEAST_JUDGED - 1]
    assert not persistent_suspects(few, SETTINGS).any()
    young = alike.copy()
    young[:, : 10 - SETTINGS.persist_frames + 1] = np.nan  # one frame short everywhere
    assert not persistent_suspects(young, SETTINGS).any()
    off = dataclasses.replace(SETTINGS, persist_deviations=0.0)
    assert not persistent_suspects(alike, off).any()


def test_suspects_leave_the_noise_scale_as_if_they_were_not_there(affine_scene):
    # Oracle: the scale of the other points alone. On this clean scene the isolation test
    # itself suspects no point, so the given suspects are all that is left out.
    tracks, _ = affine_scene(frames=8, seed=3)
    graph = neighbourhood(tracks)
    assert not (pearl.isolation_ratios(graph.nearest_miss()) > SETTINGS.isolation).any()
    suspects = np.zeros(tracks.shape[1], dtype=bool)
    suspects[::7] = True
    config = PearlConfig()
    with_them = pearl.noise_scale(tracks, config, 5, graph, suspects)
    assert with_them == pearl.noise_scale(tracks[:, ~suspects], config, 5)
    assert with_them != pearl.noise_scale(tracks, config, 5, graph)


def test_fit_refuses_suspects_of_the_wrong_shape(affine_scene):
    tracks, _ = affine_scene(frames=5, seed=1)
    with pytest.raises(InputError, match='suspects must be'):
        pearl.fit(tracks, suspects=np.zeros(3, dtype=bool))
    with pytest.raises(InputError, match='suspects must be'):
        pearl.fit(tracks, suspects=np.zeros(tracks.shape[1]))


def _fit_calls(monkeypatch):
    """The ``(last frame's pixels, suspects)`` of every call of fit from now on, recorded by a
    spy that calls the real fit."""
    from pearl_ros.online import segmenter as module
    given = []

    def spy(tracks, config, *args, **kwargs):
        given.append((tracks[-1], kwargs.get('suspects')))
        return real(tracks, config, *args, **kwargs)

    real = module.fit
    monkeypatch.setattr(module, 'fit', spy)
    return given


def test_the_segmenter_hands_fit_the_wandering_tracks_of_a_robot_stream(monkeypatch):
    # A robot-like stream (moving perspective camera, 10% outlier tracks wandering 3 px a frame):
    # no such track passes the one-window isolation test (40 times the core), but over its
    # frames it stays far above the median track. The truth of each fitted point is found by
    # its pixels in the frame.
    given = _fit_calls(monkeypatch)
    segmenter = OnlineSegmenter(online=OnlineConfig(budget_ms=0.0))
    hits = total = walks = 0
    for t, frame in enumerate(robot_stream(frames=80, seed=0)):
        given.clear()
        segmenter.process(1_000_000_000 + t * 33_333_333, frame.ids, frame.uv)
        if t < 40 or not given or given[-1][1] is None:
            continue
        last, suspects = given[-1]
        truth = {tuple(p): k for p, k in zip(frame.uv.tolist(), frame.truth.tolist(), strict=True)}
        outlier = np.array([truth[tuple(p)] == -1 for p in last.tolist()])
        hits += np.count_nonzero(suspects & outlier)
        total += np.count_nonzero(suspects)
        walks += np.count_nonzero(outlier)
    assert total > 0
    assert hits / total >= 0.9  # what is suspected is nearly all outlier tracks
    assert hits / walks >= 0.3  # and a good share of the outlier tracks fitted


def test_tracks_after_a_reset_start_without_a_past(monkeypatch):
    # After a reset (an older stamp: a bag played again) every track is a new one, even where
    # the tracker's ids are the same, so no fit is handed a suspect until persist_frames fits
    # of three frames or more have run again.
    given = _fit_calls(monkeypatch)

    def suspected(calls):
        return sum(0 if s is None else int(np.count_nonzero(s)) for _, s in calls)

    frames = list(robot_stream(frames=60, seed=0))
    segmenter = OnlineSegmenter(online=OnlineConfig(budget_ms=0.0))
    for t, frame in enumerate(frames):
        segmenter.process(2_000_000_000 + t * 33_333_333, frame.ids, frame.uv)
    assert suspected(given[-10:]) > 0
    given.clear()
    for t, frame in enumerate(frames[:6]):
        segmenter.process(1_000_000_000 + t * 33_333_333, frame.ids, frame.uv)
    # Fits over 2 and 3 .. 6 frames: at most 4 of three frames or more, fewer than 5.
    assert given and suspected(given) == 0


EVERY = PearlConfig(solver=SolverSettings(persist_roughness=0.0))  # every suspect held out


def test_suspects_handed_to_fit_are_outliers_whatever_model_would_hold_them(affine_scene):
    # Points of two clean rigid bodies, some handed over as suspects, every suspect held out
    # (persist_roughness 0): each fits its body's model within the noise, yet comes out -1
    # (its outlier cost 0, no tie to its neighbours but the rewards of pairs that move
    # apart), and the rest keep their bodies. With persist_outliers off, the suspects go with
    # their bodies.
    tracks, truth = affine_scene(frames=8, seed=2)
    suspects = np.zeros(truth.size, dtype=bool)
    suspects[np.random.default_rng(0).choice(truth.size, 12, replace=False)] = True
    held = pearl.fit(tracks, EVERY, rng=0, suspects=suspects)
    assert (held.labels[suspects] == -1).all()
    others = held.labels[~suspects]
    assert (others != -1).all() and misclassification(others, truth[~suspects]) < 0.02
    setting = pearl._setting(tracks, EVERY, np.random.default_rng(0), also=suspects,
                             batch=True)
    assert (setting.outlier_cost[suspects] == 0.0).all()
    loose = suspects[setting.edges[:, 0]] | suspects[setting.edges[:, 1]]
    assert loose.any() and (setting.weights[loose] <= 0.0).all()
    off = PearlConfig(solver=SolverSettings(persist_outliers=False))
    kept = pearl.fit(tracks, off, rng=0, suspects=suspects)
    assert misclassification(kept.labels, truth) < 0.02


def test_only_rough_suspects_are_held_out(affine_scene):
    # Oracle: the RMS second difference of each track, against twice the median track's.
    # Suspects whose tracks wander (a random walk of 3 px steps added) are held out; suspects
    # as smooth as their bodies are not, by default.
    tracks, truth = affine_scene(frames=8, seed=2)
    rng = np.random.default_rng(1)
    suspects = np.zeros(truth.size, dtype=bool)
    suspects[rng.choice(truth.size, 12, replace=False)] = True
    wander = np.flatnonzero(suspects)[:6]
    tracks = tracks.copy()
    tracks[:, wander] += np.cumsum(rng.normal(0.0, 3.0, (tracks.shape[0], wander.size, 2)),
                                   axis=0)
    accel = tracks[2:] - 2 * tracks[1:-1] + tracks[:-2]
    rough = np.sqrt((accel**2).sum(axis=2).mean(axis=0))
    expected = suspects & (rough > 2.0 * np.median(rough))
    assert set(np.flatnonzero(expected)) == set(wander)
    setting = pearl._setting(tracks, PearlConfig(), np.random.default_rng(0), also=suspects,
                             batch=True)
    np.testing.assert_array_equal(setting.outlier_cost == 0.0, expected)
    result = pearl.fit(tracks, rng=0, suspects=suspects)
    assert (result.labels[wander] == -1).all()
    smooth = suspects & ~expected
    assert misclassification(result.labels[smooth], truth[smooth]) == 0.0


def _labelled_out(solver, scene):
    """The shares of a robot-like stream's walks and of its bodies' points labelled -1 on
    frames 40-79, segmented with ``solver``."""
    segmenter = OnlineSegmenter(PearlConfig(solver=solver), OnlineConfig(budget_ms=0.0))
    walks_out = walks = body_out = body = 0
    for t, frame in enumerate(robot_stream(frames=80, seed=scene)):
        labels = segmenter.process(1_000_000_000 + t * 33_333_333, frame.ids, frame.uv).labels
        if t >= 40:
            walk = frame.truth == -1
            walks_out += np.count_nonzero(labels[walk] == -1)
            walks += np.count_nonzero(walk)
            body_out += np.count_nonzero(labels[~walk] == -1)
            body += np.count_nonzero(~walk)
    return walks_out / walks, body_out / body


def test_the_wandering_tracks_a_robot_stream_suspects_come_out_as_outliers():
    # Scene 0 of the robot-like streams (10% outlier tracks wandering 3 px a frame), frames
    # 40-79: with persist_outliers off a wide model holds every walk; by default a good share
    # of the walks is labelled -1 and next to no point of a body is.
    walks_held, body_held = _labelled_out(SolverSettings(), scene=0)
    walks_kept, _ = _labelled_out(SolverSettings(persist_outliers=False), scene=0)
    assert walks_held >= 0.3 and walks_kept < 0.1
    assert body_held < 0.02


def test_rough_tracks_of_a_robot_stream_come_out_on_less_isolation():
    # Scene 1, frames 40-79: its walks stay apart from their neighbours by less than other
    # scenes' (their mean isolation 3-8 robust deviations above the median track). Suspected
    # from 5 deviations when rough, more of them are -1 than with the smooth tracks' 8, and
    # still next to no point of a body.
    walks_rough, body_rough = _labelled_out(SolverSettings(), scene=1)
    walks_plain, _ = _labelled_out(SolverSettings(persist_rough_deviations=0.0), scene=1)
    assert walks_rough >= walks_plain + 0.15
    assert body_rough < 0.02


def test_true_tracks_that_perspective_keeps_apart_are_not_held_out():
    # A camera driving forward over a static world with a crossing box and no outlier track
    # at all: perspective keeps a few true tracks apart from their neighbours' subspaces
    # frame after frame, and they are suspected. They are as smooth as the rest, and none is
    # labelled -1; held out whatever their roughness, they would be.
    from static_scene import static_scene

    tracks, truth, _ = static_scene(frames=20, static=60, moving=100, seed=0)
    ids = np.arange(truth.size)
    out = {}
    for factor in (2.0, 0.0):
        config = PearlConfig(solver=SolverSettings(persist_roughness=factor))
        segmenter = OnlineSegmenter(config, OnlineConfig(budget_ms=0.0))
        for t in range(tracks.shape[0]):
            labels = segmenter.process(1_000_000_000 + t * 33_333_333, ids, tracks[t]).labels
        out[factor] = np.count_nonzero(labels == -1)
    assert out[2.0] == 0 and out[0.0] >= 2
