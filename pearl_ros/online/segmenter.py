"""Online motion segmentation: PEaRL over a sliding window, warm-started frame to frame.

Each frame, the features whose tracks span the fitting frames of the window are segmented by
:func:`pearl_ros.core.pearl.fit`. Warm-started (the default), that fit starts from the previous
frame's segmentation of the same tracks (its models refitted to the current window) and adds a
small batch of fresh proposals: the thesis' "mix the optimal models with a new batch of samples"
(Isack, sec. 2.3.3), spread over frames. Tracks too young for the fit go to the motion whose
subspace over their own frames is nearest (affine models, 2 frames or more); a feature seen in
one frame only takes the label of most of its labelled image neighbours. With
``OnlineConfig.max_fitted`` set, the fit sees at most that many tracks (chosen by a hash of their
keys) and the other spanning tracks go to its models by their data cost alone
(:func:`pearl_ros.core.pearl.assign`).

Label identity: motions carry numbers that persist. After each fit, its segments are matched
one-to-one to the numbers their tracks had in the previous frame (the assignment that agrees on
most tracks). A segment keeps the number it shares most tracks with; a number matched to no
segment is retired. A segment made mostly of tracks that had no number, or that lost the
matching, takes back the retired number most of its tracks carried before their current one (a
motion that merged into another for a few frames and split off again), or else a fresh one.
Numbers are given out again only that way.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from pearl_ros.core.config import PearlConfig, SolverSettings, default_solver
from pearl_ros.core.errors import InputError
from pearl_ros.core.labels import OUTLIER, num_motions
from pearl_ros.core.models import get_model
from pearl_ros.core.models.ego import is_static, static_residuals
from pearl_ros.core.neighbourhood import Neighbourhood, neighbourhood
from pearl_ros.core.pearl import (
    PearlResult,
    SlicedFit,
    assign,
    fit,
    isolation_ratios,
    noise_scale,
    rough_tracks,
)
from pearl_ros.online.config import OnlineConfig
from pearl_ros.online.isolation import LEAST_SPAN, IsolationHistory, persistent_suspects
from pearl_ros.online.window import CAMERA_FRAMES, SlidingWindow, lookup

_TWO_VIEW = ('fundamental', 'homography')
# A budgeted cold start is the unbudgeted one (every round of num_proposals) run a budget's
# worth a frame (SlicedFit), and starts no expand / re-estimate iteration after this many
# budgets from its start: its final labels come a few frames late, and no frame waits for all
# of it. (One round in 4 budgets cost the streams 0.4-2 points: docs/experiments.md.)
COLD_BUDGETS = 8
# A budgeted cold start of a multi-frame model family begins once the window holds this many
# frames, in that family, rather than as a fundamental matrix between the first two frames:
# the frames before are answered -1 (a window of fewer frames: once it is full). Its labels
# come about as early, as a fit of the stream's own family they carry over into the warm frames
# (Hopkins155 stream at the budget, seeds 0-2, final / second half 5.44 / 5.88% against 5.64 /
# 6.12% from two frames; docs/experiments.md).
COLD_START_FRAMES = 4
# With cameras: a young track whose static residual is within this many times the static
# world's noise level is given the static world's motion (3: a track of it under Gaussian
# noise lies within in all but a few cases).
STATIC_YOUNG = 3.0
# Unexplained young tracks are a cluster (founding_span) where each has at least
# FOUNDING_CLUSTER others of them among its FOUNDING_NEIGHBOURS nearest features in the image.
FOUNDING_NEIGHBOURS = 5
FOUNDING_CLUSTER = 2
# A motion a fit cut short merged away is given back (held_numbers) only with at least this
# many tracks: twice an affine subspace's minimal sample.
HELD_TRACKS = 8
# The work of a frame after its fit (numbering the motions, labelling the young tracks) comes
# out of the frame's budget: the fit stops that much earlier, the most this work took over the
# last this many frames.
TAIL_FRAMES = 10
# A fit's last step ends past its deadline (by up to a move or a refit): the fits stop that
# much earlier, the most it was over the last this many frames (a second at 30 Hz).
OVERRUN_FRAMES = 30
# Within a budget, the cold fit that checks a warm fit of few motions (SolverSettings.
# restart_motions) starts only where the time left holds this many times the warm fit's own
# (check_room).
RESTART_ROOM = 2.0


@dataclass(frozen=True)
class FrameResult:
    """Labels of one frame and what it took to get them.

    Attributes
    ----------
    stamp_ns : int
    labels : (N,) int64, motion number of each input feature, in input order; -1 for an outlier,
        a feature without finite coordinates or one that cannot be labelled yet
    motions : int, motions in use in this frame
    frames : int, frames the models were fitted over (0 when nothing could be fitted)
    fitted : int, features whose tracks span those frames (the ones the optimiser saw)
    model : str, the model family used for this frame ('' when nothing could be fitted)
    reset : bool, the window was emptied before this frame because its stamp went back in time
    warm : bool, the fit was warm-started
    latency_s : float, seconds spent in :meth:`OnlineSegmenter.process`
    static_motion : int or None, the motion number of the static world, where the frame's
        fit had the cameras (``process``'s ``camera``) and found it; None otherwise
    """

    stamp_ns: int
    labels: np.ndarray
    motions: int
    frames: int
    fitted: int
    model: str
    reset: bool
    warm: bool
    latency_s: float
    static_motion: int | None = None


class OnlineSegmenter:
    """Feed frames one at a time with :meth:`process`; labels keep their numbers over time.

    Parameters
    ----------
    config : PearlConfig, optional
        The energy and the cold-start optimiser; its ``solver`` settings also tune the
        segmenter (``rescale_every``, ``young_min_age``, ``subspace_dim``,
        ``subspace_members``, ``founding_scales``, ``founding_tracks``, ``hold_motions``,
        ``energy_rise``).
    online : OnlineConfig, optional
        Window, warm start and per-frame budget.
    """

    def __init__(self, config: PearlConfig | None = None,
                 online: OnlineConfig | None = None) -> None:
        self.config = config or PearlConfig()
        self.online = online or OnlineConfig()
        self._rng = np.random.default_rng(self.online.seed)
        self._window = SlidingWindow(self.online.window)
        # Track keys (sorted) labelled in the last frame, and their motion numbers.
        self._labelled_keys = np.empty(0, dtype=np.int64)
        self._labelled_motions = np.empty(0, dtype=np.int64)
        # Track keys (sorted) that carried another number before their current one (or before
        # -1), and that number: what a motion split off again is known by.
        self._before_keys = np.empty(0, dtype=np.int64)
        self._before_motions = np.empty(0, dtype=np.int64)
        self._next_label = 0
        self._scales: dict[str, tuple[float, int]] = {}  # model -> (px, fitted frames since)
        self._quiet = 0  # warm fits since the last one with fresh proposals
        # A one-motion check the budget had no room for, put off to the next frame: the time
        # the check is expected to take there (seconds; None: none put off).
        self._check_due: float | None = None
        self._configs: tuple[tuple[str, float, str] | None, PearlConfig] = (None, self.config)
        self._energy_ref = 0.0  # energy per feature of that fit
        self._graph: tuple[str, Neighbourhood] | None = None  # model, last fit's neighbourhood
        self._cold: _ColdStart | None = None  # a budgeted cold start under way
        # The most frames the next fit spans, while young tracks found a motion (None: any).
        self._span_limit: int | None = None
        # Each track's isolation over its last window of fits (online/isolation.py).
        self._isolation = IsolationHistory(self.online.window)
        # Seconds from the end of each of the last TAIL_FRAMES fits to its frame's answer, and
        # how far each ran past its deadline (its last step's overrun; 0 for none).
        self._tails: deque[float] = deque(maxlen=TAIL_FRAMES)
        self._overruns: deque[float] = deque(maxlen=OVERRUN_FRAMES)
        self._budget_from = 0.0  # perf_counter seconds: when this frame's budget began
        self._fitted_at: float | None = None  # when the last frame's fit ended, if it had one

    @property
    def frames_in_window(self) -> int:
        return len(self._window)

    def reset(self) -> None:
        """Empty the window. Motion numbers already used are never given out again."""
        self._window.clear()
        self._labelled_keys = self._labelled_motions = np.empty(0, dtype=np.int64)
        self._before_keys = self._before_motions = np.empty(0, dtype=np.int64)
        self._scales = {}
        self._quiet = 0
        self._check_due = None
        self._graph = None
        self._cold = None
        self._span_limit = None
        self._isolation.clear()

    def delivered(self, at: float | None = None) -> None:
        """The last frame's answer went out at ``at`` (a :func:`time.perf_counter` value,
        default now), after :meth:`process` returned it: a node calls this once it has
        published. The time from the frame's fit to then comes out of the next frames' budget,
        as the work after the fit within :meth:`process` does. Without a fit on the last frame,
        or called again for it, it does nothing."""
        at = time.perf_counter() if at is None else _check_time(at, 'at')
        if self._fitted_at is None:  # else the frame's tail is the last one kept
            return
        self._tails[-1] = max(self._tails[-1], at - self._fitted_at)
        self._fitted_at = None

    def reconfigure(self, config: PearlConfig | None = None,
                    online: OnlineConfig | None = None) -> None:
        """Apply new parameters from the next frame on; a new window size keeps the newest
        frames that fit."""
        if config is not None:
            self.config = config
        self._configs = (None, self.config)
        self._cold = None  # a cold start under way is begun again with the new parameters
        if online is not None:
            self._window.resize(online.window)
            if online.window != self._isolation.frames:
                self._isolation = IsolationHistory(online.window)
            if online.seed != self.online.seed:
                self._rng = np.random.default_rng(online.seed)
            self.online = online

    def set_camera(self, stamp_ns: int, camera: np.ndarray, tolerance_ns: int = 0) -> bool:
        """Give a frame of the window that came without its camera the ``camera`` (3, 4) of
        stamp ``stamp_ns`` (a robot's pose often comes after its image's features): the
        frame nearest it, within ``tolerance_ns``. Whether a frame took it.

        Raises
        ------
        InputError
            On a camera that is not a finite (3, 4) projection matrix.
        """
        checked = _check_camera(camera)
        if checked is None:
            raise InputError('camera must be a finite (3, 4) projection matrix, got None')
        return self._window.set_camera(int(stamp_ns), checked, int(tolerance_ns))

    def process(self, stamp_ns: int, ids: np.ndarray, uv: np.ndarray,
                camera: np.ndarray | None = None, arrived: float | None = None) -> FrameResult:
        """Label one frame.

        Parameters
        ----------
        stamp_ns : int, nanoseconds, later than the previous frame's; an earlier one (a bag
            played in a loop) empties the window first
        ids : (N,) int, tracker ids, unique within the frame
        uv : (N, 2) float, pixels; features with a NaN or inf coordinate are labelled -1 and
            treated as not seen in this frame
        camera : (3, 4) float, optional
            The frame's projection matrix (pixels from world: intrinsics times the world-to-
            camera pose), where the robot knows it (or later, :meth:`set_camera`). Over windows
            where ``CAMERA_FRAMES`` frames or more have theirs, the multi-frame fits take the
            static world as a motion of known parameters (:func:`pearl_ros.core.pearl.fit`'s
            ``cameras``); two-view fits do not use them.
        arrived : float, optional
            When the frame arrived (a :func:`time.perf_counter` value, such as a node's
            subscription callback takes): the budget counts from then, so that a frame that
            waited for the one before it leaves the optimiser less. Default: the call.

        Raises
        ------
        InputError
            On mismatched shapes, non-integer or duplicate ids, a stamp equal to the previous
            one, or an ``arrived`` that is not finite. The segmenter's state is then unchanged.
        """
        start = time.perf_counter()
        self._budget_from = start if arrived is None else min(_check_time(arrived), start)
        stamp_ns, ids, uv = _check_frame(stamp_ns, ids, uv)
        camera = _check_camera(camera)
        last = self._window.last_stamp
        reset = last is not None and stamp_ns < last
        if last is not None and stamp_ns == last:
            raise InputError(f'stamp {stamp_ns} ns repeats the previous frame\'s')
        if reset:
            self.reset()

        finite = np.all(np.isfinite(uv), axis=1)
        seen = np.flatnonzero(finite)
        # Features in id order: the proposals sample by position, so that labels must not depend
        # on the order a tracker lists its features in.
        seen = seen[np.argsort(ids[seen], kind='stable')]
        keys = self._window.push(stamp_ns, ids[seen], uv[seen], camera)
        coords, age = self._window.history(keys)

        span = _fit_span(age, self.online)
        held = min(span, self.online.long_span)  # what a span cut short is checked over
        if self._span_limit is not None:
            span = min(span, self._span_limit)
        model_name = self._model_name(span)
        fitted = np.flatnonzero(age >= span) if span >= 2 else np.empty(0, dtype=np.int64)
        warm = False
        motion_labels = np.full(keys.size, OUTLIER, dtype=np.int64)
        if fitted.size > get_model(model_name).min_samples:
            tracks = coords[-span:, fitted]
            cameras = None
            if model_name in _TWO_VIEW:
                tracks = tracks[[0, -1]]
            else:
                cameras = self._window.cameras(span)
            fitted_keys = keys[fitted]
            prior = lookup(self._labelled_keys, self._labelled_motions, fitted_keys, OUTLIER)
            chosen = _chosen(fitted_keys, self.online.max_fitted)
            # Every spanning track, as a view (no copy), unless max_fitted chose some.
            pick = slice(None) if chosen is None else chosen
            warm = self.online.warm_start and bool(np.any(prior[pick] != OUTLIER))
            sliced = not warm and self.online.warm_start and self.online.budget_ms > 0
            if (sliced and self._cold is None and self.config.model not in _TWO_VIEW
                    and len(self._window) < min(COLD_START_FRAMES, self.online.window)):
                return self._answer(keys, motion_labels, seen, ids.size, stamp_ns, 0, 0, '',
                                    reset, False, start)
            if self._cold is not None or sliced:
                return self._cold_slice(tracks[:, pick], fitted_keys[pick], model_name, keys,
                                        seen, ids.size, stamp_ns, reset, start, cameras)
            result, config = self._fit(tracks[:, pick], fitted_keys[pick], model_name,
                                       prior[pick], warm, cameras)
            fitted_at = time.perf_counter()
            segments = result.labels
            if chosen is not None:
                rest = np.ones(fitted.size, dtype=bool)
                rest[chosen] = False
                segments = np.empty(fitted.size, dtype=np.int64)
                segments[chosen] = result.labels
                segments[rest] = assign(tracks[:, rest], result, config, cameras)
            numbers = self._identify(segments, prior, fitted_keys)
            if (self.config.solver.hold_motions and warm and span < held and chosen is None
                    and cameras is None and model_name not in _TWO_VIEW):
                numbers = self._hold(coords[-held:], age, fitted, keys, numbers, prior,
                                     model_name)
            motion_labels[fitted] = numbers
            static = _static_model(result) if cameras is not None else None
            members = np.flatnonzero(segments == static) if static is not None else fitted[:0]
            static_motion = int(motion_labels[fitted[members[0]]]) if members.size else None
            young = np.flatnonzero(age < span)  # the tracks not fitted, in order
            solver = self.config.solver
            grown = age[young] >= solver.young_min_age if model_name not in _TWO_VIEW \
                else np.zeros(young.size, dtype=bool)
            tracked, newborn = young[grown], young[~grown]
            known = None
            if (cameras is not None and static is not None and static_motion is not None
                    and chosen is None):
                known = (static_motion, _static_young(coords, age, tracked, cameras,
                                                      float(result.sigmas[static])))
            distances = np.full(tracked.size, np.inf)
            motion_labels[tracked] = _nearest_subspace(coords, age, fitted,
                                                       motion_labels[fitted], tracked, solver,
                                                       known, distances)
            self._found(coords, age, tracked, distances, model_name)
            motion_labels[newborn] = _vote(uv[seen], fitted, motion_labels[fitted], newborn,
                                           self.online.neighbours)
        else:
            span, model_name, static_motion, fitted_at = 0, '', None, None
        return self._answer(keys, motion_labels, seen, ids.size, stamp_ns, span,
                            int(fitted.size) if span else 0, model_name, reset, warm, start,
                            static_motion, fitted_at)

    def _answer(self, keys: np.ndarray, motion_labels: np.ndarray, seen: np.ndarray, n: int,
                stamp_ns: int, span: int, fitted: int, model_name: str, reset: bool,
                warm: bool, start: float, static_motion: int | None = None,
                fitted_at: float | None = None) -> FrameResult:
        """The frame's result from the motion numbers of its tracks ``keys`` (the features
        ``seen`` of ``n``), which the next frame starts from; ``fitted_at``: when the frame's
        fit ended (perf_counter seconds), if it had one."""
        labels = np.full(n, OUTLIER, dtype=np.int64)
        labels[seen] = motion_labels
        labelled = np.flatnonzero(motion_labels != OUTLIER)
        by_key = labelled[np.argsort(keys[labelled], kind='stable')]
        last = lookup(self._labelled_keys, self._labelled_motions, keys, OUTLIER)
        before = np.where((last != OUTLIER) & (last != motion_labels), last,
                          lookup(self._before_keys, self._before_motions, keys, OUTLIER))
        remembered = np.flatnonzero(before != OUTLIER)
        remembered = remembered[np.argsort(keys[remembered], kind='stable')]
        self._before_keys, self._before_motions = keys[remembered], before[remembered]
        self._labelled_keys, self._labelled_motions = keys[by_key], motion_labels[by_key]
        now = time.perf_counter()
        self._fitted_at = fitted_at
        if fitted_at is not None:
            self._tails.append(now - fitted_at)
        return FrameResult(stamp_ns, labels, num_motions(motion_labels), span, fitted,
                           model_name, reset, warm, now - start, static_motion)

    def _deadline(self, budgets: float = 1.0) -> float | None:
        """When a fit begun with this frame stops: ``budgets`` budgets after the frame arrived
        (:meth:`process`'s ``arrived``), less the time the frame's answer took after the fit on
        the last frames (their most, until :meth:`delivered` where called) and the most a fit
        ran past its deadline on the last ``OVERRUN_FRAMES``; None without a budget."""
        budget = self.online.budget_ms / 1e3
        if budget <= 0:
            return None
        return (self._budget_from + budgets * budget - max(self._tails, default=0.0)
                - max(self._overruns, default=0.0))

    def _overran(self, deadline: float | None, began: float, fitted_at: float) -> None:
        """Keep how far a fit begun at ``began`` ran past its ``deadline``; none for a fit
        that began past it (it runs its least work, whatever the margin)."""
        if deadline is not None:
            self._overruns.append(max(fitted_at - deadline, 0.0) if began < deadline else 0.0)

    def _cold_slice(self, tracks: np.ndarray, fitted_keys: np.ndarray, model_name: str,
                    keys: np.ndarray, seen: np.ndarray, n: int, stamp_ns: int, reset: bool,
                    start: float, cameras: np.ndarray | None = None) -> FrameResult:
        """A frame of a budgeted cold start: the fit of the frame it began on (``tracks`` of
        ``fitted_keys``, when none is under way) goes on for a budget's worth. The tracks it
        fits get the motions of its labelling so far (every feature -1 before its first move);
        once it is done, the next frame starts warm from its labels."""
        if self._cold is None:
            graph, noise, _ = self._neighbourhood(tracks, fitted_keys, model_name, None)
            config = self._config(model_name, noise, 'cold')
            order = np.argsort(fitted_keys, kind='stable')
            last = self._deadline(COLD_BUDGETS)
            assert last is not None  # a cold start is sliced only under a budget
            self._cold = _ColdStart(SlicedFit(tracks, config, self._rng, graph, last,
                                              cameras=cameras, batch=False),
                                    fitted_keys[order], order, model_name, tracks.shape[0])
        cold = self._cold
        deadline = self._deadline()
        assert deadline is not None
        began = time.perf_counter()
        result = cold.fit.advance(deadline)
        fitted_at = time.perf_counter()
        self._overran(deadline, began, fitted_at)
        segments = cold.fit.labels
        if segments is None or not np.any(segments != OUTLIER):
            return self._answer(keys, np.full(keys.size, OUTLIER, dtype=np.int64), seen, n,
                                stamp_ns, 0, 0, '', reset, False, start)
        if result is not None:
            self._cold = None
            self._quiet, self._energy_ref = 0, result.energy / max(cold.keys.size, 1)
        # The labels so far (the result's once done), numbered as the last frame answered.
        prior = lookup(self._labelled_keys, self._labelled_motions, cold.keys, OUTLIER)
        numbers = self._identify(segments[cold.order], prior, cold.keys)
        motion_labels = lookup(cold.keys, numbers, keys, OUTLIER)
        return self._answer(keys, motion_labels, seen, n, stamp_ns, cold.frames,
                            int(cold.keys.size), cold.model, reset, False, start,
                            fitted_at=fitted_at)

    def _model_name(self, span: int) -> str:
        if self.config.model in _TWO_VIEW:
            return self.config.model
        return self.online.two_view_model if span == 2 else self.config.model

    def _fit(self, tracks: np.ndarray, keys: np.ndarray, model_name: str, prior: np.ndarray,
             warm: bool, cameras: np.ndarray | None = None
             ) -> tuple[PearlResult, PearlConfig]:
        """Segment ``tracks`` (of the tracks ``keys``; their frames' ``cameras`` where known);
        returns the fit (labels 0..K-1 per track, -1 outliers) and the configuration it ran
        with."""
        # Fresh proposals on a cold fit and on every propose_every-th warm one; the warm frames
        # between only relabel and refit the motions already there, unless the energy per
        # feature rose since the last proposals (a motion starting, say): then the next frame
        # proposes.
        propose = not warm or self._quiet + 1 >= self.online.propose_every
        # The frames between proposals reuse the last frame's neighbour edges when the same
        # features are fitted (Delaunay and k-d tree: 2 ms of a 480-feature frame); a frame
        # with proposals builds them anew.
        previous = None
        if not propose and self._graph is not None and self._graph[0] == model_name:
            previous = self._graph[1]
        graph, noise, suspects = self._neighbourhood(tracks, keys, model_name, previous)
        init = None
        deadline = self._deadline()
        if warm:
            config = self._config(model_name, noise, 'warm')
            init = _start_segments(prior)
        elif deadline is not None:
            # Without a warm start every frame is a cold fit within the frame's budget: one
            # round of num_proposals, the round the budget leaves time for.
            config = self._config(model_name, noise, 'slice')
        else:
            config = self._config(model_name, noise, 'cold')
        began = time.perf_counter()
        result = fit(tracks, config, self._rng, init=init, deadline=deadline,
                     init_cost=self.online.temporal_cost if warm else 0.0, propose=propose,
                     graph=graph, suspects=suspects,
                     init_label_share=self.online.continued_label_cost, cameras=cameras,
                     batch=False)
        # A warm start refits the last frame's motions first: one wide motion that took a new
        # object in too leaves no expansion a gain, where a cold fit of the same tracks finds
        # the object. Such a frame's fit is checked against a cold one, where the budget has
        # room for it; where it has none, on the next frame (most often one without fresh
        # proposals, whose warm fit is the lighter) if the room is there.
        fitted_at = time.perf_counter()
        if init is not None and result.num_models <= config.solver.restart_motions:
            run, self._check_due = check_room(propose, self._check_due, fitted_at - began,
                                              fitted_at, deadline)
            if run:
                cold = fit(tracks, config, self._rng, init=None, deadline=deadline,
                           init_cost=0.0, propose=True, graph=graph, suspects=suspects,
                           init_label_share=self.online.continued_label_cost,
                           cameras=cameras, batch=False)
                moved = temporal_cost(cold.labels, init, self.online.temporal_cost)
                if cold.energy + moved < result.energy:
                    result = cold
        else:
            self._check_due = None
        self._overran(deadline, began, time.perf_counter())
        per_feature = result.energy / max(tracks.shape[1], 1)
        if propose:
            self._quiet, self._energy_ref = 0, per_feature
        elif per_feature > (1.0 + config.solver.energy_rise) * self._energy_ref:
            self._quiet = self.online.propose_every
        else:
            self._quiet += 1
        return result, config

    def _hold(self, coords: np.ndarray, age: np.ndarray, fitted: np.ndarray, keys: np.ndarray,
              numbers: np.ndarray, prior: np.ndarray, model_name: str) -> np.ndarray:
        """``numbers`` of the ``fitted`` tracks, checked over the frames of ``coords`` where a
        fit cut short by young tracks lost a motion of the last frame (their ``prior``) or
        split a new one off (:func:`held_numbers`).

        Young tracks that found a motion cut the span (:func:`founding_span`), and over a few
        frames a motion that moves nearly as another does (a car driving ahead of the camera,
        as the road does near it) joins it, while over ten frames the same tracks tell them
        apart (KT3DMoSeg ``Seq059_Clip01``; docs/experiments.md). The tracks that span every
        frame of ``coords`` are fitted again over them, from the cut fit's numbers and the
        lost motions' tracks from their last frame's (no fresh proposals), at the noise scale
        of those tracks over those frames, estimated afresh (it reads otherwise over a longer
        span, and few frames call for the check).
        """
        frames = coords.shape[0]
        old = np.flatnonzero(age[fitted] >= frames)  # positions within ``fitted``
        held_prior, current = prior[old], numbers[old]
        lost = np.setdiff1d(held_prior[held_prior != OUTLIER], numbers)
        new = np.setdiff1d(current[current != OUTLIER], prior)
        deadline = self._deadline()
        if ((lost.size == 0 and new.size == 0) or old.size <= HELD_TRACKS
                or (deadline is not None and time.perf_counter() >= deadline)):
            return numbers
        tracks = coords[:, fitted[old]]
        graph = neighbourhood(tracks, keys[fitted[old]], None, self.config.solver,
                              core_patches=False)
        scale = noise_scale(tracks, dataclasses.replace(self.config, model=model_name),
                            self._rng, graph)
        config = self._config(model_name, scale, 'warm', keep=False)
        start = np.where(np.isin(held_prior, lost), held_prior, current)
        result = fit(tracks, config, self._rng, init=_start_segments(start), deadline=deadline,
                     init_cost=self.online.temporal_cost, propose=False, graph=graph,
                     init_label_share=self.online.continued_label_cost, batch=False)
        out: np.ndarray = numbers.copy()
        out[old] = held_numbers(current, start, result.labels, lost, new)
        return out

    def _neighbourhood(self, tracks: np.ndarray, keys: np.ndarray, model_name: str,
                       previous: Neighbourhood | None
                       ) -> tuple[Neighbourhood, float, np.ndarray | None]:
        """The neighbourhood of ``tracks`` (of the tracks ``keys``; kept for the next frame),
        the noise scale of ``model_name`` on them (given, or estimated) and the tracks
        suspected isolated over their past fits (None: none can be yet)."""
        solver = self.config.solver
        # Closest-moving patches: over the online windows, patches drawn around their cores
        # measured worse (docs/experiments.md).
        graph = neighbourhood(tracks, keys, previous, solver, core_patches=False)
        self._graph = (model_name, graph)
        suspects = None
        if solver.isolation and solver.persist_deviations and tracks.shape[0] >= LEAST_SPAN:
            ratios = isolation_ratios(graph.nearest_miss())
            if ratios is not None:
                rough = None
                if solver.persist_outliers and solver.persist_rough_deviations:
                    rough = rough_tracks(tracks, solver.persist_roughness)
                suspects = persistent_suspects(self._isolation.update(keys, ratios), solver,
                                               rough)
        noise = self.config.noise or self._scale(tracks, model_name, graph, suspects)
        return graph, noise, suspects

    def _config(self, model_name: str, noise: float, kind: str, keep: bool = True
                ) -> PearlConfig:
        """The fit's configuration: ``self.config`` with ``model_name`` and ``noise``, and for a
        ``kind`` of fit ``'warm'`` the warm-start settings, ``'slice'`` a budgeted cold fit's
        one round of proposals, ``'cold'`` none. Kept (``keep``) until the next change:
        building and checking one costs 0.5 ms, a frame's worth of warm fit; a fit of its own
        scale that the next frame does not repeat (:meth:`_hold`'s) leaves the frames' one
        in place."""
        key = (model_name, noise, kind)
        if self._configs[0] == key:
            return self._configs[1]
        config = dataclasses.replace(self.config, model=model_name, noise=noise)
        online = self.online
        if kind == 'warm':
            config = dataclasses.replace(config, num_proposals=online.warm_proposals,
                                         rounds=online.warm_rounds,
                                         unit_quantile=online.warm_unit_quantile)
        elif kind == 'slice':
            config = dataclasses.replace(config, rounds=1)
        if keep:
            self._configs = (key, config)
        return config

    def _scale(self, tracks: np.ndarray, model_name: str, graph: Neighbourhood,
               suspects: np.ndarray | None) -> float:
        """The noise scale of ``model_name``, estimated again every ``rescale_every`` frames
        (solver settings): it changes slowly, and estimating it costs more than a warm-started
        fit."""
        every = self.config.solver.rescale_every
        scale, age = self._scales.get(model_name, (0.0, every))
        if age >= every:
            config = dataclasses.replace(self.config, model=model_name)
            scale, age = noise_scale(tracks, config, self._rng, graph, suspects), 0
        self._scales[model_name] = (scale, age + 1)
        return scale

    def _found(self, coords: np.ndarray, age: np.ndarray, tracked: np.ndarray,
               distances: np.ndarray, model_name: str) -> None:
        """Set the span limit of the next fits: it grows by a frame a frame (the tracks that
        set it age with the window) until the window holds no more, and is cut to the span of
        young tracks that found a motion (:func:`founding_span`)."""
        limit = self._span_limit
        if limit is not None:
            limit = None if limit >= self.online.window else limit + 1
        scale = self._scales.get(model_name, (0.0, 0))[0]
        if scale > 0:
            found = founding_span(coords, age, tracked, distances, scale, self.config.solver)
            if found is not None:
                limit = found if limit is None else min(limit, found)
        self._span_limit = limit

    def _identify(self, segments: np.ndarray, prior: np.ndarray, keys: np.ndarray
                  ) -> np.ndarray:
        """Motion numbers for ``segments`` (0..K-1, -1) of the tracks ``keys``, matched to the
        ``prior`` numbers those tracks carried in the last frame (module docstring)."""
        out = np.full(segments.size, OUTLIER, dtype=np.int64)
        num = int(segments.max()) + 1 if segments.size else 0
        if num == 0:
            return out
        known = prior != OUTLIER
        olds, old_idx = np.unique(prior[known], return_inverse=True)
        table = np.zeros((num, olds.size), dtype=np.int64)
        ok = known & (segments != OUTLIER)
        np.add.at(table, (segments[ok], old_idx.reshape(-1)[ok[known]]), 1)
        number = np.full(num, OUTLIER, dtype=np.int64)  # until the segment gets its number
        if olds.size:
            rows, cols = linear_sum_assignment(table, maximize=True)
            for r, c in zip(rows, cols, strict=True):
                # Keep a number only for a segment made mostly of tracks that carried it.
                if 2 * table[r, c] > np.count_nonzero(segments == r):
                    number[r] = olds[c]
        self._take_back(number, segments, keys)
        for r in range(num):
            if number[r] == OUTLIER:
                number[r] = self._next_label
                self._next_label += 1
        inlier = segments != OUTLIER
        out[inlier] = number[segments[inlier]]
        return out

    def _take_back(self, number: np.ndarray, segments: np.ndarray, keys: np.ndarray) -> None:
        """Give the segments still without a number (``number`` -1) the retired number that
        most of their tracks carried before their current one, where one does; in place. The
        segments with the most such tracks choose first."""
        open_ = np.flatnonzero(number == OUTLIER)
        if open_.size == 0 or self._before_keys.size == 0:
            return
        before = lookup(self._before_keys, self._before_motions, keys, OUTLIER)
        claims = []
        for r in open_.tolist():
            members = segments == r
            value, count = _majority(before[members])
            if 2 * count > np.count_nonzero(members):
                claims.append((-count, r, value))
        taken = set(number[number != OUTLIER].tolist())
        for _, r, value in sorted(claims):
            if value not in taken:
                number[r] = value
                taken.add(value)


@dataclass
class _ColdStart:
    """A budgeted cold start under way: its fit, the keys of the tracks it fits (sorted) and
    their order in its tracks, its model family and the frames it fits over."""

    fit: SlicedFit
    keys: np.ndarray
    order: np.ndarray
    model: str
    frames: int


def _check_time(value: object, name: str = 'arrived') -> float:
    """``value`` (the argument ``name``) as a float, or InputError unless it is a finite
    time."""
    try:
        seconds = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        seconds = math.nan
    if not math.isfinite(seconds):
        raise InputError(f'{name} must be a finite time.perf_counter() value, got {value!r}')
    return seconds


def _check_frame(stamp_ns: int, ids: np.ndarray, uv: np.ndarray
                 ) -> tuple[int, np.ndarray, np.ndarray]:
    try:
        stamp = int(stamp_ns)
    except (TypeError, ValueError) as err:
        raise InputError(f'stamp_ns must be an integer, got {stamp_ns!r}') from err
    ids = np.asarray(ids)
    uv = np.asarray(uv, dtype=np.float64)
    if ids.ndim != 1:
        raise InputError(f'ids must have shape (N,), got {ids.shape}')
    if uv.shape != (ids.size, 2):
        raise InputError(f'uv must have shape ({ids.size}, 2) to match ids, got {uv.shape}')
    if ids.size and not np.issubdtype(ids.dtype, np.integer):
        as_float = ids.astype(np.float64)
        if not np.all(np.isfinite(as_float)) or np.any(as_float != np.round(as_float)):
            raise InputError('ids must be integers')
        ids = as_float.astype(np.int64)
    ids = ids.astype(np.int64)
    unique, counts = np.unique(ids, return_counts=True)
    if np.any(counts > 1):
        raise InputError(f'duplicate ids in one frame: {unique[counts > 1][:5].tolist()}')
    return stamp, ids, uv


def _check_camera(camera: np.ndarray | None) -> np.ndarray | None:
    if camera is None:
        return None
    camera = np.asarray(camera, dtype=np.float64)
    if camera.shape != (3, 4) or not np.all(np.isfinite(camera)):
        raise InputError(f'camera must be a finite (3, 4) projection matrix, got shape '
                         f'{camera.shape}')
    if not abs(np.linalg.det(camera[:, :3])) > 1e-12 * float(np.abs(camera).max()) ** 3:
        raise InputError('camera must be a projection matrix of a finite camera (its left '
                         '3 x 3 block invertible)')
    return camera


def _static_model(result: PearlResult) -> int | None:
    """The index of the static world among the models of a fit with cameras, or None."""
    return next((k for k in range(result.num_models) if is_static(result.params[k])), None)


def _static_young(coords: np.ndarray, age: np.ndarray, young: np.ndarray,
                  cameras: np.ndarray, sigma: float) -> np.ndarray:
    """The squared distance of each of the ``young`` tracks to the static world, as
    :func:`_nearest_subspace` takes a known motion's: the sum over the track's own frames of
    its squared reprojection error as a static point (the units of a subspace distance);
    infinite where the static world does not explain it (a point behind the cameras, or beyond
    ``STATIC_YOUNG`` times the static world's noise level ``sigma``)."""
    if young.size == 0:
        return np.empty(0)
    # All young tracks at once, each over its own frames (NaN before its birth is left out).
    points = coords[-cameras.shape[0]:, young]
    known = ~np.isnan(cameras).all(axis=(1, 2))
    used = np.count_nonzero(known[:, None] & ~np.isnan(points[..., 0]), axis=0)
    residual, in_front = static_residuals(cameras, points)
    explained = in_front & (residual <= STATIC_YOUNG * sigma) & (
        used >= np.minimum(CAMERA_FRAMES, age[young]))
    distance_sq: np.ndarray = np.where(explained, used * np.square(residual), np.inf)
    return distance_sq


def held_numbers(current: np.ndarray, start: np.ndarray, segments: np.ndarray,
                 lost: np.ndarray, new: np.ndarray) -> np.ndarray:
    """The motion numbers of tracks after a fit cut short (``current``), checked by a fit of
    the same tracks over a longer span that started from ``start`` (``current``, but the
    tracks of the ``lost`` motions on their last frame's numbers) and ended at ``segments``
    (0..K-1, -1).

    A lost motion is given back to its tracks in a segment of which they are most and at
    least ``HELD_TRACKS``. A ``new`` motion (split off in the cut fit) whose tracks mostly
    fall in a segment that most started as another motion, neither new nor lost, takes that
    motion's number. Every other track keeps its ``current`` number.
    """
    out: np.ndarray = current.copy()
    for segment in range(int(segments.max()) + 1 if segments.size else 0):
        members = segments == segment
        number, count = _majority(start[members])
        if number == OUTLIER or 2 * count <= np.count_nonzero(members):
            continue
        if number in lost:
            if count >= HELD_TRACKS:
                out[members & (start == number)] = number
        elif number not in new:
            for split in new.tolist():
                tracks = start == split
                if 2 * np.count_nonzero(members & tracks) > np.count_nonzero(tracks):
                    out[tracks] = number
    return out


def _start_segments(numbers: np.ndarray) -> np.ndarray:
    """A warm start's segments (0..K-1, -1) from the motion ``numbers`` (-1 outlier) the
    tracks carry."""
    _, segments = np.unique(numbers, return_inverse=True)
    out: np.ndarray = segments.reshape(-1) - int(np.any(numbers == OUTLIER))
    return out


def _majority(values: np.ndarray) -> tuple[int, int]:
    """The most common of ``values`` other than -1, and how many times it occurs ((-1, 0) for
    none)."""
    values = values[values != OUTLIER]
    if values.size == 0:
        return OUTLIER, 0
    numbers, counts = np.unique(values, return_counts=True)
    best = int(np.argmax(counts))
    return int(numbers[best]), int(counts[best])


def _chosen(keys: np.ndarray, most: int) -> np.ndarray | None:
    """Indices (sorted) of the tracks ``keys`` the optimiser segments: None for all of them, or
    the ``most`` whose keys hash lowest (``most`` > 0). A hash rather than the image keeps the
    chosen tracks spread over the image as all tracks are, and a track once chosen stays chosen
    while fewer tracks hash lower: the warm start finds the same tracks frame after frame."""
    if most == 0 or keys.size <= most:
        return None
    # Fibonacci hashing: the key times 2^64 / golden ratio, modulo 2^64.
    hashed = keys.astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)
    return np.sort(np.argsort(hashed, kind='stable')[:most])


def founding_span(coords: np.ndarray, age: np.ndarray, young: np.ndarray,
                  distances: np.ndarray, scale: float, settings: SolverSettings) -> int | None:
    """The span of the next fit (frames) that lets ``young`` tracks no motion explains found
    one of their own, or None where they do not call for one.

    A motion is fitted only from the tracks that span the fitted frames, and a young track
    goes to the nearest motion found (:func:`_nearest_subspace`): an object that enters, or
    whose tracks are lost and found again as it moves (occlusion, its own outline), has too few
    spanning tracks to be proposed from and is labelled with its surroundings. The young tracks
    farther than ``settings.founding_scales`` noise scales (RMS per frame, ``distances`` being
    each one's squared distance to its nearest motion's subspace) from every motion are
    unexplained; those with at least ``FOUNDING_CLUSTER`` others of them among their
    ``FOUNDING_NEIGHBOURS`` nearest features in the newest frame are a cluster (outlier tracks
    start anywhere; a new object's points come together). Where ``settings.founding_tracks``
    of the cluster are at least its median age (3 at the least) old, the next fit spans that
    age plus one (the frame they will have aged by).
    """
    if settings.founding_scales <= 0 or young.size < settings.founding_tracks:
        return None
    with np.errstate(invalid='ignore'):  # a distance rounded below 0 reads as explained
        far = np.sqrt(distances / age[young]) / scale > settings.founding_scales
    lost = young[far]
    if lost.size < settings.founding_tracks:
        return None
    now = coords[-1]
    k = min(FOUNDING_NEIGHBOURS + 1, now.shape[0])
    _, near = cKDTree(now).query(now[lost], k=k)
    cluster = lost[np.isin(near[:, 1:], lost).sum(axis=1) >= FOUNDING_CLUSTER]
    if cluster.size < settings.founding_tracks:
        return None
    frames = max(3, int(np.median(age[cluster])))
    if np.count_nonzero(age[cluster] >= frames) < settings.founding_tracks:
        return None
    return frames + 1


def _fit_span(age: np.ndarray, online: OnlineConfig) -> int:
    """Frames the models are fitted over: the most frames back that ``online.min_coverage`` of
    the features span, up to ``online.long_span``, and beyond it as far as
    ``online.long_coverage`` of them span."""
    span = min(_span(age, online.min_coverage), online.long_span)
    return max(span, _span(age, online.long_coverage))


def _span(age: np.ndarray, coverage: float) -> int:
    """The most frames back that at least ``coverage`` of the features span (0 if none)."""
    if age.size == 0:
        return 0
    # The k-th oldest age, k = ceil(coverage * N): that many features reach back this far.
    need = max(int(np.ceil(coverage * age.size)), 1)
    return int(np.sort(age)[::-1][need - 1])


def _nearest_subspace(coords: np.ndarray, age: np.ndarray, fitted: np.ndarray,
                      fitted_labels: np.ndarray, young: np.ndarray,
                      settings: SolverSettings | None = None,
                      known: tuple[int, np.ndarray] | None = None,
                      distances: np.ndarray | None = None) -> np.ndarray:
    """Labels of ``young`` tracks (each ``age`` < the fitted span): the motion whose members'
    trajectories over the young track's own frames span the affine subspace nearest to it.

    A rigid motion's trajectories over any frames lie in a 3-D affine subspace (Tomasi & Kanade
    1992), so each motion's subspace over a young track's last ``age`` frames is refitted from
    the motion's fitted members (principal components) and the track goes to the nearest. The
    motion itself, not its image neighbourhood, decides: a vote of image neighbours errs along
    every outline, where neighbours belong to another motion. A motion with fewer than
    ``settings.subspace_members`` members is not offered; -1 if none is. Subspaces are
    ``settings.subspace_dim``-dimensional (3), fewer where the young track's frames allow fewer.

    Parameters
    ----------
    coords : (F, N, 2) float64, pixels, the window (NaN before a track's birth)
    age : (N,) int, frames each track holds (its newest ``age``)
    fitted, fitted_labels : (M,) int, the fitted tracks and their motion numbers (-1 outlier)
    young : (Y,) int, tracks to label, each with an ``age`` of at least 2
    settings : SolverSettings, optional
    known : (motion, (Y,) float), optional
        A motion whose model is known (the static world seen by known cameras), with each
        young track's squared distance to it (infinite where it does not explain the track):
        the known model stands in for the motion's subspace.
    distances : (Y,) float64, optional, filled with each young track's squared distance to
        its nearest subspace (left as it was where no motion is offered)
    """
    settings = settings or default_solver()
    out = np.full(young.size, OUTLIER, dtype=np.int64)
    motions = np.unique(fitted_labels[fitted_labels != OUTLIER])
    groups = [fitted[fitted_labels == motion] for motion in motions]
    offered = np.array([g.size >= settings.subspace_members for g in groups], dtype=bool)
    if young.size == 0 or not offered.any():
        return out
    motions = motions[offered]
    # Each motion's mean and scatter over the fitted span, once: those over a young track's
    # last frames are their trailing entries and bottom-right block (centring is per coordinate).
    span = int(age[fitted].min())
    means, scatters = [], []
    for members in (g for g, ok in zip(groups, offered, strict=True) if ok):
        trajectories = _rows(coords[-span:, members])
        mean = trajectories.mean(axis=0)
        means.append(mean)
        scatters.append((trajectories - mean).T @ (trajectories - mean))
    means_all, scatters_all = np.stack(means), np.stack(scatters)  # (K, D), (K, D, D)
    for frames in np.unique(age[young]):
        rows = np.flatnonzero(age[young] == frames)
        points = _rows(coords[-frames:, young[rows]])  # (n, d), d = 2 * frames
        d = points.shape[1]
        dim = min(settings.subspace_dim, d - 1)
        # One batched eigendecomposition for all motions; columns by increasing eigenvalue.
        _, vectors = np.linalg.eigh(scatters_all[:, -d:, -d:])
        basis = vectors[:, :, ::-1][:, :, :dim]  # (K, d, dim)
        offset = points[None, :, :] - means_all[:, None, -d:]  # (K, n, d)
        inside = np.einsum('knd,kde->kne', offset, basis)
        distance_sq = np.einsum('knd,knd->kn', offset, offset) - np.einsum('kne,kne->kn',
                                                                           inside, inside)
        if known is not None and np.any(motions == known[0]):
            distance_sq[np.flatnonzero(motions == known[0])[0]] = known[1][rows]
        nearest = np.argmin(distance_sq, axis=0)
        least = distance_sq[nearest, np.arange(rows.size)]
        if distances is not None:
            distances[rows] = least
        out[rows] = np.where(np.isfinite(least), motions[nearest], OUTLIER)
    return out


def check_room(propose: bool, due: float | None, fit_seconds: float, now: float,
               deadline: float | None) -> tuple[bool, float | None]:
    """Whether a warm fit that ended with few motions (``restart_motions``) at ``now`` (a
    :func:`time.perf_counter` value, the fit having taken ``fit_seconds``) is checked against a
    cold fit now, and the time to keep free for a check put off to the next frame (None: none
    put off).

    A frame with fresh proposals (``propose``) is checked where the time left before its
    ``deadline`` (None: no budget) holds ``RESTART_ROOM`` times its own fit's (a cold fit takes
    1.3-1.8 times a warm one with proposals, the 10-90% range on Hopkins155's streams); where
    it does not, the check is put off to the next frame, which runs it if its own warm fit
    still ended with as few and the time left holds the room the first frame asked for
    (``due``). Most next frames have no fresh proposals, whose warm fits are the lighter.
    """
    if propose:
        room = RESTART_ROOM * fit_seconds
    elif due is None:
        return False, None
    else:
        room = due
    if deadline is None or now + room < deadline:
        return True, None
    return False, room if propose else None


def temporal_cost(labels: np.ndarray, prior: np.ndarray, cost: float) -> float:
    """The temporal term a warm fit from the segments ``prior`` (N,) (0..K-1, -1 none) would
    charge the segmentation ``labels`` (N,) (0..L-1, -1 outliers): ``cost`` for each point with
    a prior segment that its label does not continue, each label continuing at most one prior
    segment, matched to keep the most points (a warm fit's models stay their segments' own
    through refits; a fresh fit's are matched after the fact)."""
    has = prior >= 0
    if not has.any():
        return 0.0
    kept = 0.0
    both = has & (labels >= 0)
    if both.any():
        table = np.zeros((int(labels.max()) + 1, int(prior.max()) + 1))
        np.add.at(table, (labels[both], prior[both]), 1)
        rows, cols = linear_sum_assignment(table, maximize=True)
        kept = float(table[rows, cols].sum())
    return float(cost * (np.count_nonzero(has) - kept))


def _rows(tracks: np.ndarray) -> np.ndarray:
    """(F, N, 2) -> (N, 2F) trajectory rows."""
    return np.transpose(tracks, (1, 0, 2)).reshape(tracks.shape[1], -1)


def _vote(uv: np.ndarray, fitted: np.ndarray, fitted_labels: np.ndarray, young: np.ndarray,
          k: int) -> np.ndarray:
    """Labels of the ``young`` features: the most common label among their ``k`` nearest
    labelled ``fitted`` features in the image (ties to the nearer); -1 if none is labelled."""
    out = np.full(young.size, OUTLIER, dtype=np.int64)
    labelled = fitted[fitted_labels != OUTLIER]
    if young.size == 0 or labelled.size == 0:
        return out
    votes = fitted_labels[fitted_labels != OUTLIER]
    k = min(k, labelled.size)
    _, idx = cKDTree(uv[labelled]).query(uv[young], k=k)
    idx = np.asarray(idx).reshape(young.size, k)
    near = votes[idx]  # (Y, k), nearest first
    # How often each neighbour's label occurs in its row; the first position with the highest
    # count holds the most common label, the nearer one on a tie.
    counts = np.count_nonzero(near[:, :, None] == near[:, None, :], axis=2)
    voted: np.ndarray = near[np.arange(young.size), np.argmax(counts, axis=1)]
    return voted
