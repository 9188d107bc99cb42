"""PEaRL: Propose, Expand and Re-estimate Labels (Isack & Boykov, IJCV 2012).

``fit`` is a short loop over named steps, each a function of the search state (``_Search``:
the labelling and its models) that says what it changed. Per round: :func:`_propose` draws
minimal samples (:mod:`proposals`), each a model hypothesis (a label); then, while the energy
(:mod:`energy`) goes down, :func:`sweep` runs alpha-expansions (:mod:`expansion`) over them,
:func:`_refit` re-estimates every model in use from its points and :func:`_split` tries
expansions judged after refitting the models they take points from; :func:`_merge` then joins
neighbouring segments that one model explains. Rounds mix the surviving models with a fresh
batch of samples, the thesis' remedy for too few samples (Isack, sec. 2.3.3).

Inside the optimiser, row ``OUTLIER_ROW`` (0) of the cost table stands for the outlier label,
with a constant cost and no label cost, and model k is label k + 1; the result reports outliers
as :data:`~pearl_ros.core.labels.OUTLIER` (-1) and models as 0..K-1.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Generator, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np

from pearl_ros.core.config import PearlConfig, SolverSettings, default_solver
from pearl_ros.core.contrast import edge_weights, long_edge_stretch, pair_unit
from pearl_ros.core.energy import Problem, energy
from pearl_ros.core.errors import InputError
from pearl_ros.core.expansion import Expansions, expansion_move
from pearl_ros.core.labels import OUTLIER
from pearl_ros.core.models import MotionModel, get_model
from pearl_ros.core.models.ego import WithStaticWorld, static_ties
from pearl_ros.core.neighbourhood import (
    Neighbourhood,
    kept_neighbours,
    lost_neighbours,
    nearest_neighbours,
    neighbourhood,
)
from pearl_ros.core.proposals import mixed_samples, uniform_samples
from pearl_ros.core.scale import local_scale

_T = TypeVar('_T')

OUTLIER_ROW = 0  # the row of the cost table (the optimiser's label) of the outlier label
# Fewest frames whose isolated points are bridged (SolverSettings.bridge_isolated). Over two
# frames a local subspace is one constraint in R^4: the points of a sparse moving body are
# often isolated there, and bridges drawn across them tie the bodies around it together
# (Hopkins155 two frames 5.94 -> 6.42%, docs/experiments.md). Two views with mismatches
# (SolverSettings.joint_neighbours) are bridged: their isolation test reads patches drawn on
# both views' coordinates, where the mismatches stand apart.
BRIDGE_FRAMES = 3
# Model families between two views, which SolverSettings.local_ceiling caps.
TWO_VIEW = ('fundamental', 'homography')
# The quantile of the points' least pair misses that isolation is measured in: low, so that it
# is a true point's even where most points are mismatches (AdelaideRMF's `game`, 73%, where the
# lower quartile was a mismatch's). The misses themselves need true neighbours: on synthetic
# two-view scenes with mismatches spread uniformly, isolation holds to 50% and fails from 60%.
CORE_QUANTILE = 0.1
# Minimal samples fitted, measured and offered to the search at a time (a step of a
# SlicedFit): at 2000 points 200 samples in one batch took 80 ms.
PROPOSE_CHUNK = 64
# The nearest fellow points (of the same model) whose keeping from one view to the other tells
# a rigid motion from a model of mismatches (SolverSettings.kept_fellows): by chance a point
# keeps FELLOWS / (M - 1) of them among M. Five, not the patches' ten, so that small models
# can keep more than chance: among 14 points ten neighbours are most of them.
FELLOWS = 5
# Refits a setting keeps (_Setting.refits) before it forgets them all, each two rows of N
# floats: a batch two-view search of AdelaideRMF's pairs computes 21 distinct ones at the
# median and at most 60 (a third of those it asks for), Hopkins155's searches under 30.
REFITS_KEPT = 256

# A model refitted by _refit_one: params, noise level (px), residual row (px), data cost row.
_Refit = tuple[np.ndarray, float, np.ndarray, np.ndarray]


@dataclass(frozen=True)
class PearlResult:
    """What :func:`fit` found.

    Attributes
    ----------
    labels : (N,) int64, model index 0..K-1 of each point, -1 for outliers
    params : (K, ...) float64, parameters of model k (layout set by the model)
    sigmas : (K,) float64, pixels, noise level of model k
    energy : float, final energy
    energy_history : tuple of float, energy after every expand / re-estimate iteration and
        after the merges that end a round
    iterations : int, expand / re-estimate iterations run
    timings : dict of str to float, seconds per step (of every fit a restarted fit ran)
    scale : float, pixels, the residual scale the data costs were measured in
    """

    labels: np.ndarray
    params: np.ndarray
    sigmas: np.ndarray
    energy: float
    energy_history: tuple[float, ...]
    iterations: int
    timings: dict[str, float] = field(default_factory=dict)
    scale: float = 1.0

    @property
    def num_models(self) -> int:
        return int(self.params.shape[0])


def data_costs(residuals: np.ndarray, sigmas: np.ndarray, dof: float, floor: float) -> np.ndarray:
    """D_p(l) = r^2 / sigma_l^2 + 2 dof log(sigma_l / floor), rows ``(K, N)``.

    Twice the negative log-likelihood of Gaussian residuals with a noise level sigma_l of each
    model's own, per unit of dof, up to a constant: a model of a motion tracked less precisely
    (a small, far or non-rigid object, stronger perspective) is not forced into the noise level of
    the background. Every sigma_l >= floor, so every cost is >= 0, as graph capacities must be.
    """
    sigmas = np.asarray(sigmas, dtype=np.float64)[:, None]
    costs: np.ndarray = (np.square(residuals) / np.square(sigmas)
                         + 2.0 * dof * np.log(sigmas / floor))
    return costs


def noise_level(residuals: np.ndarray, dof: float, floor: float, min_samples: int,
                ceiling: float = math.inf) -> float | None:
    """Noise level sigma of a model fitted to its members' ``residuals``, at least ``floor``.

    The fit itself absorbs about ``min_samples`` points' worth of residual, so the sum of squares
    is shared among the others only (the n - p of an unbiased variance): a model fitted to its
    own minimal sample claims no precision at all, and None is returned.
    """
    spare = residuals.size - min_samples
    if spare <= 0:
        return None
    return float(min(max(np.sqrt(np.sum(np.square(residuals)) / (dof * spare)), floor), ceiling))


def sweep(problem: Problem, labels: np.ndarray, settings: SolverSettings | None = None,
          deadline: float | None = None) -> np.ndarray:
    """Alpha-expansions until no move lowers the energy; labels are tried best-first.

    Every label in use is expanded each pass. An unused label is expanded only while its gain
    bound exceeds its label cost: its data gain, sum_p max(0, D_p(f_p) - D_p(alpha)), plus the
    rewards (negative Potts weights) of the pairs it would split (:func:`_gain_bound`). A cheap
    screen that skips the many proposals that cannot pay for themselves, so a sweep costs a few
    moves, not one per proposal. At most ``settings.max_passes`` passes; a pass ends after
    ``settings.max_failed`` unused labels in a row fail to lower the energy. Past the
    ``deadline`` (a ``time.perf_counter()`` value) the sweep only relabels with the labels in
    use when it started, once each (the first pass's first moves), unless every point is
    still an outlier.
    """
    return _run(_sweep_moves(problem, labels, settings or default_solver(), deadline))


def _sweep_moves(problem: Problem, labels: np.ndarray, settings: SolverSettings,
                 deadline: float | None) -> Generator[None, None, np.ndarray]:
    """:func:`sweep`, yielding after each computation of the gain bounds and before each
    expansion move; returns the labels."""
    unary, costs = problem.unary, problem.label_costs
    current = energy(problem, labels)
    in_use = np.zeros(unary.shape[0], dtype=bool)
    in_use[labels] = True
    # Labels whose expansion failed on the labelling as it is now: the same move on the same
    # labelling fails again, so a later pass counts it as failed without running it (the
    # labels come out exactly as if it ran). Any accepted move makes every label worth a try.
    stale = np.zeros(unary.shape[0], dtype=bool)
    for sweep_pass in range(settings.max_passes):
        changed = False
        tried = np.zeros(unary.shape[0], dtype=bool)
        failed = 0  # unused labels rejected in a row
        gain = None  # the bounds change only when a move is accepted
        while True:
            if gain is None:
                moves = Expansions(problem, labels)
                used = moves.used
                gain = np.where(used, np.inf, _gain_bound(problem, labels) - costs)
                yield  # the bounds cost as much as a move on large problems
            gain[tried] = -np.inf
            alpha = int(np.argmax(gain))
            if not gain[alpha] > 0 or (failed >= settings.max_failed and not used[alpha]):
                break
            if (_past(deadline) and (sweep_pass or not in_use[alpha])
                    and np.any(labels != problem.outlier_row)):
                return labels
            tried[alpha] = True
            if stale[alpha]:
                failed += int(not used[alpha])
                continue
            yield
            moved = moves.move(alpha)
            moved_energy = energy(problem, moved)
            if moved_energy < current - 1e-9:
                labels, current, changed, gain = moved, moved_energy, True, None
                failed = 0
                stale[:] = False
            else:
                stale[alpha] = True
                if not used[alpha]:
                    failed += 1
        if not changed:
            break
    return labels


def _gain_bound(problem: Problem, labels: np.ndarray) -> np.ndarray:
    """What expanding each label could gain, before its label cost, ``(L,)``.

    The data gain sum_p max(0, D_p(f_p) - D_p(l)), plus the reward of every pair with a negative
    weight that shares a label now and that l would split: one end fits l better, the other
    does not. Without the rewards a tight model of one of two dependent motions, which one
    loose model fits about as well, would never be tried, though splitting them pays.
    """
    unary = problem.unary
    current = unary[labels, np.arange(labels.size)]
    gain: np.ndarray = np.maximum(current[None, :] - unary, 0.0).sum(axis=1)
    p, q = problem.edges[:, 0], problem.edges[:, 1]
    paying = (problem.weights < 0) & (labels[p] == labels[q])
    if np.any(paying):
        p, q = p[paying], q[paying]
        better = unary < current[None, :]
        gain += (better[:, p] != better[:, q]) @ -problem.weights[paying]
    return gain


@dataclass(frozen=True)
class _Setting:
    """What stays fixed while PEaRL runs on one set of tracks."""

    model: MotionModel
    solver: SolverSettings
    data: np.ndarray  # (N, D) model data rows
    edges: np.ndarray  # (E, 2) Delaunay neighbours in the last frame
    weights: np.ndarray  # (E,) signed Potts weights (contrast.edge_weights)
    neighbours: np.ndarray  # (N, k) image neighbours, for local samples
    scale: float  # px, noise level of a fresh proposal (estimated or given)
    floor: float  # px, least noise level a model may claim
    ceiling: float  # px, most noise level a model may claim (inf: none)
    dof: float  # E[r^2] / sigma^2 of the model's residuals
    outlier_cost: np.ndarray  # (N,) the outlier label's data cost of each point
    label_cost: float
    # Batch two-view fits: each point's local noise (its nearest miss, px) and the least
    # reference of a model's ceiling (noise scale or pair unit), SolverSettings.local_ceiling.
    local: np.ndarray | None = None
    reference: float = 0.0
    batch: bool = True  # fit(..., batch=): False for the online segmenter's fits
    # Two views with mismatches (SolverSettings.joint_neighbours): their points (2, N, 2), on
    # which a model's points must keep their fellows (SolverSettings.kept_fellows).
    views: np.ndarray | None = None
    # The neighbourhood as the setting was given or drew it (before any redraw): it depends on
    # the tracks and settings alone, and a batch fit's later restarts take it as given.
    drawn: Neighbourhood | None = field(default=None, repr=False, compare=False)
    # Every refit of this setting, by its members and start (_refit_one): a search tries the
    # same refit again and again (a merge candidate round after round, a split's losers).
    refits: dict[tuple[bytes, bytes], _Refit | None] = field(
        default_factory=dict, repr=False, compare=False)

    def cap(self, members: np.ndarray) -> float:
        """The most noise level a model of ``members`` may claim, px."""
        if self.local is None or members.size == 0:
            return self.ceiling
        local = max(float(np.median(self.local[members])), self.reference)
        return min(self.ceiling, self.solver.local_ceiling * local)

    def unary(self, residuals: np.ndarray, sigmas: np.ndarray) -> np.ndarray:
        """Data costs ``(1 + K, N)`` from model residuals ``(K, N)`` and noise levels ``(K,)``:
        the outlier row, then one row per model."""
        n = self.data.shape[0]
        rows = data_costs(residuals, sigmas, self.dof, self.floor)
        return np.vstack([np.broadcast_to(self.outlier_cost, (1, n)), rows])

    def problem(self, unary: np.ndarray, continued: np.ndarray | None = None,
                share: float = 1.0) -> Problem:
        """The optimiser's problem over ``unary``: each model pays the label cost, and the
        models ``continued`` ``(K,)`` bool pay ``share`` of it."""
        costs = np.full(unary.shape[0], self.label_cost)
        costs[OUTLIER_ROW] = 0.0
        if continued is not None and share != 1.0:
            costs[1:][continued] *= share
        return Problem(unary, self.edges, self.weights, costs, OUTLIER_ROW,
                       self.solver.outlier_tie, self.solver.outlier_apart)


@dataclass(eq=False)
class _Search:
    """What PEaRL's steps change: the labelling and the models its labels stand for.

    Labels are the optimiser's: ``OUTLIER_ROW``, or k + 1 for model k. ``unary`` holds the
    outlier row and then each model's data costs plus its fixed row of the init term,
    ``bias`` (:func:`_init_bias`); ``problem`` holds ``unary`` itself, so a model refitted in
    place (:meth:`adopt`) changes the energy every later step sees. Every method leaves the
    tables consistent with the models.

    Attributes
    ----------
    setting : _Setting
    labels : (N,) int64, optimiser labels
    params : (K, ...) float64, models
    sigmas : (K,) float64, px, their noise levels
    residuals : (K, N) float64, px, every point's residual to each model
    origin : (K,) int64, the init segment each model stands for, OUTLIER for none
    prior : (N,) int64, each point's init segment, OUTLIER for none
    init_cost : float, cost units of the init term
    init_share : float, the share of the label cost a model standing for an init segment pays
    fitted_to : list of (M,) int64 arrays or None, per model: the points it was last fitted
        to (None for a proposal fitted to its minimal sample)
    """

    setting: _Setting
    labels: np.ndarray
    params: np.ndarray
    sigmas: np.ndarray
    residuals: np.ndarray
    origin: np.ndarray
    prior: np.ndarray
    init_cost: float
    fitted_to: list[np.ndarray | None]
    init_share: float = 1.0
    unary: np.ndarray = field(init=False)  # (1 + K, N)
    bias: np.ndarray = field(init=False)  # (1 + K, N), read-only zeros without an init cost
    problem: Problem = field(init=False)

    def __post_init__(self) -> None:
        self._tables()

    def _tables(self) -> None:
        """The cost tables of the current models, measured afresh."""
        self.bias = _init_bias(self.prior, self.origin, self.init_cost)
        self.unary = self.setting.unary(self.residuals, self.sigmas)
        if self.init_cost:
            self.unary += self.bias
        self.problem = self._problem()

    def _problem(self) -> Problem:
        return self.setting.problem(self.unary, self.origin != OUTLIER, self.init_share)

    def energy(self) -> float:
        return energy(self.problem, self.labels)

    def add(self, params: np.ndarray, sigmas: np.ndarray, residuals: np.ndarray) -> None:
        """Offer new models (labels after the current ones), standing for no init segment."""
        origin = np.full(params.shape[0], OUTLIER, dtype=np.int64)
        self.params = np.concatenate([self.params, params])
        self.sigmas = np.concatenate([self.sigmas, sigmas])
        self.residuals = np.concatenate([self.residuals, residuals])
        self.origin = np.concatenate([self.origin, origin])
        self.fitted_to += [None] * params.shape[0]
        # Only the new models' rows are measured: the others' are unchanged.
        setting = self.setting
        rows = data_costs(residuals, sigmas, setting.dof, setting.floor)
        if self.init_cost:
            bias = _init_bias(self.prior, origin, self.init_cost)[1:]
            rows += bias
            self.bias = np.concatenate([self.bias, bias])
        else:
            self.bias = _init_bias(self.prior, self.origin, 0.0)
        self.unary = np.concatenate([self.unary, rows])
        self.problem = self._problem()

    def adopt(self, label: int, fitted: _Refit, members: np.ndarray) -> None:
        """Model ``label`` becomes a refit of :func:`_refit_one` (params, noise level, residual
        row, data cost row) to ``members``."""
        self.params[label - 1], self.sigmas[label - 1], self.residuals[label - 1] = fitted[:3]
        self.unary[label] = fitted[3] + self.bias[label]
        self.fitted_to[label - 1] = members

    def refitted_already(self, label: int, members: np.ndarray) -> bool:
        """Whether a refit of model ``label`` to ``members`` would give the model it is: it
        was last fitted to these very points, and its family refits in closed form or (batch
        fits) its refit was a Levenberg-Marquardt descent, which from its own end stays there."""
        last = self.fitted_to[label - 1]
        return ((self.setting.batch or not self.setting.model.refit_from_start)
                and last is not None and np.array_equal(last, members))

    def compress(self) -> None:
        """Keep only the models in use, renumbered by decreasing support (:func:`_compress`).
        The kept models' rows of the cost tables are kept as they are."""
        self.labels, kept = _compress(self.labels)
        self.params, self.sigmas = self.params[kept], self.sigmas[kept]
        self.residuals, self.origin = self.residuals[kept], self.origin[kept]
        self.fitted_to = [self.fitted_to[k] for k in kept.tolist()]
        rows = np.concatenate([[OUTLIER_ROW], kept + 1])
        self.unary = self.unary[rows]
        self.bias = _init_bias(self.prior, self.origin, self.init_cost)
        self.problem = self._problem()


def _start(setting: _Setting, init: np.ndarray | None, init_cost: float,
           init_share: float = 1.0) -> _Search:
    """The search before the first round: the models of the ``init`` segments, each refitted to
    its points, and their labelling; without ``init``, no model and every point an outlier."""
    n = setting.data.shape[0]
    if init is None:
        return _Search(setting, labels=np.full(n, OUTLIER_ROW, dtype=np.int64),
                       params=np.empty((0,) + _param_shape(setting.model, setting.data)),
                       sigmas=np.empty(0), residuals=np.empty((0, n)),
                       origin=np.empty(0, dtype=np.int64),
                       prior=np.full(n, OUTLIER, dtype=np.int64), init_cost=init_cost,
                       fitted_to=[])
    prior = _check_labels(init, n)
    params, sigmas, residuals, labels = _segment_models(setting, prior)
    fitted_to: list[np.ndarray | None] = [np.flatnonzero(labels == k + 1)
                                          for k in range(params.shape[0])]
    return _Search(setting, labels, params, sigmas, residuals,
                   _origins(labels, prior, params.shape[0]), prior, init_cost, fitted_to,
                   init_share)


def fit(
    tracks: np.ndarray,
    config: PearlConfig | None = None,
    rng: np.random.Generator | int | None = None,
    init: np.ndarray | None = None,
    deadline: float | None = None,
    init_cost: float = 0.0,
    propose: bool = True,
    graph: Neighbourhood | None = None,
    suspects: np.ndarray | None = None,
    init_label_share: float = 1.0,
    cameras: np.ndarray | None = None,
    batch: bool = True,
) -> PearlResult:
    """Segment tracked points into rigid motions; the number of motions is found, not given.

    Parameters
    ----------
    tracks : (F, N, 2) float64, pixel coordinates of N points tracked over F frames
        (two-view models use the first and the last frame).
    config : PearlConfig, optional
    rng : numpy Generator, seed or None
    init : (N,) int, optional
        A warm start: a segmentation (0..K-1, -1 for outlier or unknown) whose segments become the
        first models, each refitted to its points, and the first labelling. The thesis' "mix the
        optimal models with a new batch of samples" across calls (Isack, sec. 2.3.3).
    deadline : float, optional
        ``time.perf_counter()`` value after which no further alpha-expansion, split or merge
        trial, expand / re-estimate iteration or proposal round starts; the labels in use are
        still expanded once each (more moves run only while every point is an outlier), one
        split trial runs and each model in use is re-estimated once. The result is then no
        longer a function of the seed alone.
    init_cost : float, cost units, >= 0
        With ``init``: a term ``init_cost * [f_p != init model of p]`` added to the energy for
        every point with an init segment, which keeps labels from flickering between calls
        (a temporal Potts term). The model of a segment stays "its" model through refits.
    propose : bool
        With ``init``, False skips the fresh proposals: the init models are only relabelled and
        re-estimated (a cheap warm step between proposal batches). Ignored without ``init``.
    graph : Neighbourhood, optional
        The neighbour systems of ``tracks`` (:func:`pearl_ros.core.neighbourhood.neighbourhood`),
        when the caller already has them; built from ``tracks`` otherwise (once for all of a
        batch fit's restarts). One drawn with ``joint`` makes a batch two-view fit test its
        models' fellows (``SolverSettings.kept_fellows``), as one the fit draws jointly does.
    suspects : (N,) bool, optional
        Points the caller suspects isolated, besides those the isolation test finds
        (``SolverSettings.isolation``; the online segmenter judges tracks over their past
        frames). With ``SolverSettings.persist_outliers`` those whose tracks are rough
        (``persist_roughness``) are outliers: isolated whatever their nearest miss, their
        outlier cost 0 and their ties dropped (a pair's reward stays). Ignored when the test
        is off.
    init_label_share : float in [0, 1]
        With ``init``: the share of the label cost that a model standing for an init segment
        pays (a motion that goes on), where a fresh proposal pays all of it. Below 1, a motion
        is harder to start than to keep: a label-level counterpart of ``init_cost``.
    cameras : (F, 3, 4) float64, optional
        The projection matrices (pixels from world) of the frames of ``tracks``, where the
        caller knows them (odometry): the static world then joins the label set as a model
        whose parameters are known (:mod:`pearl_ros.core.models.ego`), and neighbours that it
        explains unequally are tied less (``SolverSettings.static_contrast``). The static
        world comes out as one of the models; a result's params are all NaN for it.
    batch : bool
        False for the online segmenter's fits: every point's patch stays as ``graph`` drew it,
        isolated points among them (``SolverSettings.redraw_isolated``: a stream's isolated
        points change from frame to frame, and its patches with them would), two-view
        models claim any noise level (``SolverSettings.local_ceiling``), and a two-view model
        is refitted again to the points it was last refitted to (a batch fit leaves it: its
        Levenberg-Marquardt refit would end where it is).

    Returns
    -------
    PearlResult
    """
    config = config or PearlConfig()
    generator = np.random.default_rng(rng)
    # A batch two-view fit is fitted again from fresh draws (the noise scale's too) and the
    # lowest energy kept: its searches end in different minima from seed to seed. Any batch
    # fit whose lowest is one widened model for everything (_widened_one) is fitted again, up
    # to one_motion_restarts more times.
    restarts, more = 1, 0
    if batch and init is None:
        more = config.solver.one_motion_restarts
        if config.model in TWO_VIEW:
            restarts = config.solver.two_view_restarts
    if restarts == 1 and more == 0:
        return _run(_steps(tracks, config, generator, init, deadline, init_cost, propose,
                           graph, suspects, init_label_share, cameras, batch))
    # The restarts' searches are compared where they end; the lowest is then settled.
    best: tuple[_Search | None, PearlResult] | None = None
    spent: dict[str, float] = {}  # every fit's seconds per step
    for restart in range(restarts + more):
        if restart and _past(deadline):
            break
        if restart >= restarts and best is not None and not _widened_one(best[1], config.solver):
            break
        search, result = _run_search(_steps(tracks, config, generator, init, deadline,
                                            init_cost, propose, graph, suspects,
                                            init_label_share, cameras, batch, settle=False))
        assert search is not None  # _steps yields its search first
        graph = search.setting.drawn  # the same for every restart: drawn once
        for step, seconds in result.timings.items():
            spent[step] = spent.get(step, 0.0) + seconds
        if best is None or result.energy < best[1].energy:
            best = search, result
    assert best is not None
    search, result = best
    assert search is not None  # _steps yields its search first
    history = list(result.energy_history)
    _run(_settle(search, history, spent))
    return _result(search, history, result.iterations, spent)


def _widened_one(result: PearlResult, solver: SolverSettings) -> bool:
    """Whether ``result`` is one motion for everything whose model has widened past every
    noise level a fresh proposal is offered at (``solver.proposal_levels``): the minimum a
    batch search falls into most (``SolverSettings.one_motion_restarts``)."""
    widest = max(solver.proposal_levels) * result.scale
    return result.num_models == 1 and bool(result.sigmas[0] > widest)


def _run(steps: Generator[object, None, _T]) -> _T:
    """Run the steps of a generator to its end; its return value."""
    return _run_search(steps)[1]


def _run_search(steps: Generator[object, None, _T]) -> tuple[_Search | None, _T]:
    """Run the steps of :func:`_steps` (or any generator) to its end: the search it yielded
    first (None if none) and its return value."""
    search: _Search | None = None
    while True:
        try:
            step = next(steps)
        except StopIteration as done:
            result: _T = done.value
            return search, result
        if search is None and isinstance(step, _Search):
            search = step


def _timed_steps(timings: dict[str, float], step: str, steps: Generator[None, None, _T]
                 ) -> Generator[None, None, _T]:
    """``yield from steps``, adding the seconds spent in them (not between) to
    ``timings[step]``."""
    while True:
        start = time.perf_counter()
        try:
            next(steps)
        except StopIteration as done:
            timings[step] += time.perf_counter() - start
            result: _T = done.value
            return result
        timings[step] += time.perf_counter() - start
        yield


class SlicedFit:
    """A :func:`fit` run a slice at a time: the same steps in the same order, so the same result
    for the same seed, however it is sliced.

    Each :meth:`advance` runs whole steps (the setup; :data:`PROPOSE_CHUNK` of a round's
    proposals; a sweep's gain bounds; one expansion move; one model's refit; one split trial;
    one merge candidate)
    until the ``deadline`` it is given has passed,
    at least one step, and returns the result once the last step has run. The online segmenter
    runs a budgeted cold start this way, over as many frames as it takes, instead of letting one
    frame take it all, and answers the frames before it is done with :attr:`labels`. The
    arguments are those of a cold :func:`fit` (no ``init``); its ``deadline``, if given, ends
    the whole fit early as it ends :func:`fit`. It runs one search: a batch fit's restarts
    (``SolverSettings.two_view_restarts``, ``one_motion_restarts``) are :func:`fit`'s alone.
    """

    def __init__(self, tracks: np.ndarray, config: PearlConfig | None = None,
                 rng: np.random.Generator | int | None = None,
                 graph: Neighbourhood | None = None, deadline: float | None = None,
                 cameras: np.ndarray | None = None, batch: bool = True) -> None:
        self._steps = _steps(tracks, config or PearlConfig(), np.random.default_rng(rng), None,
                             deadline, 0.0, True, graph, cameras=cameras, batch=batch)
        self.result: PearlResult | None = None
        self.steps_run = 0
        self._search: _Search | None = None

    @property
    def labels(self) -> np.ndarray | None:
        """The labelling so far, 0..K-1 per track (the models in use), -1 outliers: the
        result's once done; None before the setup has run."""
        if self.result is not None:
            return self.result.labels
        if self._search is None:
            return None
        labels = self._search.labels
        _, segments = np.unique(labels, return_inverse=True)
        segments = segments.reshape(-1) - int(np.any(labels == OUTLIER_ROW))
        return np.where(labels == OUTLIER_ROW, OUTLIER, segments)

    def advance(self, deadline: float) -> PearlResult | None:
        """Run steps until ``deadline`` (a ``time.perf_counter()`` value) has passed, at least
        one; the result when the fit is done (then and on later calls), else None."""
        while self.result is None:
            try:
                search = next(self._steps)
            except StopIteration as done:
                self.result = done.value
            else:
                if search is not None:  # the first step's: the search, once set up
                    self._search = search
            self.steps_run += 1
            if _past(deadline):
                break
        return self.result


def _steps(tracks: np.ndarray, config: PearlConfig, rng: np.random.Generator,
           init: np.ndarray | None, deadline: float | None, init_cost: float, propose: bool,
           graph: Neighbourhood | None, suspects: np.ndarray | None = None,
           init_share: float = 1.0, cameras: np.ndarray | None = None, batch: bool = True,
           settle: bool = True) -> Generator[_Search | None, None, PearlResult]:
    """:func:`fit`'s steps: yields the search once set up, then None before each step
    (:class:`SlicedFit`); returns the result. Without ``settle``, the last step
    (:func:`_settle`) is left to the caller."""
    timings = {'setup': 0.0, 'propose': 0.0, 'expand': 0.0, 'refit': 0.0}
    with _timed(timings, 'setup'):
        setting = _setting(tracks, config, rng, graph, suspects, cameras, batch)
    if not init_cost >= 0:
        raise InputError(f'init_cost must be >= 0, got {init_cost!r}')
    if not 0.0 <= init_share <= 1.0:
        raise InputError(f'init_label_share must be in [0, 1], got {init_share!r}')
    search = _start(setting, init, init_cost, init_share)
    yield search
    history: list[float] = []  # the energy after every iteration and every round's merges
    iterations = 0
    for _ in range(config.rounds):
        if iterations and _past(deadline):
            break
        if propose or init is None:
            yield None
            yield from _timed_steps(timings, 'propose', _propose(search, config, rng))
        energies = yield from _descend(search, config.max_iterations, deadline, timings)
        history += energies
        iterations += len(energies)
        # Segments of one motion that no expansion joins are merged once the round settles.
        merged = yield from _timed_steps(timings, 'refit', _merge(search, deadline))
        if merged + _drop_scattered(search):
            history.append(search.energy())
        search.compress()  # only the models in use go on (into the next round, the result)
    if settle:
        yield from _settle(search, history, timings)
    return _result(search, history, iterations, timings)


def _settle(search: _Search, history: list[float], timings: dict[str, float]
            ) -> Generator[None, None, None]:
    """The search's last step: interchangeable models merged (:func:`_merge_interchangeable`),
    the energy after it added to ``history``."""
    if (yield from _timed_steps(timings, 'refit', _merge_interchangeable(search))):
        history.append(search.energy())
        search.compress()


def _result(search: _Search, history: list[float], iterations: int,
            timings: dict[str, float]) -> PearlResult:
    return PearlResult(np.where(search.labels == OUTLIER_ROW, OUTLIER, search.labels - 1),
                       search.params, search.sigmas, search.energy(), tuple(history),
                       iterations, timings, search.setting.scale)


def _descend(search: _Search, max_iterations: int, deadline: float | None,
             timings: dict[str, float]) -> Generator[None, None, list[float]]:
    """Expand and re-estimate while the energy goes down: the inner loop of a round.

    Each iteration sweeps alpha-expansions over every label (:func:`sweep`), re-estimates the
    models in use (:func:`_refit`) and tries split moves (:func:`_split`). Past the
    ``deadline``, the sweep and the split moves stop between moves, and no iteration starts
    after the first. Yields before each expansion move, model refit and split trial;
    returns the energy after each iteration run.
    """
    energies: list[float] = []
    current = search.energy()
    for step in range(max_iterations):
        if step and _past(deadline):
            break
        search.labels = yield from _timed_steps(
            timings, 'expand',
            _sweep_moves(search.problem, search.labels, search.setting.solver, deadline))
        yield from _timed_steps(timings, 'refit', _refit(search))
        yield from _timed_steps(timings, 'refit', _split(search, deadline))
        energies.append(search.energy())
        if not energies[-1] < current - 1e-9:
            break
        current = energies[-1]
    return energies


@contextmanager
def _timed(timings: dict[str, float], step: str) -> Iterator[None]:
    """Add the seconds the ``with`` block takes to ``timings[step]``."""
    start = time.perf_counter()
    try:
        yield
    finally:
        timings[step] += time.perf_counter() - start


def assign(tracks: np.ndarray, result: PearlResult, config: PearlConfig | None = None,
           cameras: np.ndarray | None = None) -> np.ndarray:
    """Labels of further points by the models of a :func:`fit`: 0..K-1, or -1 (outlier).

    Each point of ``tracks`` (F, M, 2; the frames ``result`` was fitted over) goes to the model
    of least data cost at that model's noise level, or to the outlier label where its cost is
    less: the data term of the fit's energy alone, with no pair or label cost. ``config`` is
    the fit's (its model, noise floor and outlier threshold); the noise scale is
    ``result.scale``. Isolation is not judged here (it needs the points' neighbours), so every
    point pays the outlier cost of a point that is not isolated. ``cameras``: the fit's.
    """
    config = config or PearlConfig()
    model = get_model(config.model, config.solver)
    if cameras is not None:
        model = WithStaticWorld(model, cameras)
    data = model.data(tracks)  # validates tracks
    out = np.full(data.shape[0], OUTLIER, dtype=np.int64)
    if result.params.shape[0] == 0 or data.shape[0] == 0:
        return out
    dof = model.residual_dof(data)
    floor = config.solver.sigma_floor * result.scale
    costs = data_costs(model.residuals(data, result.params), result.sigmas, dof, floor)
    outlier_cost = _outlier_cost(config.outlier_threshold, result.scale, dof, floor)
    best = np.argmin(costs, axis=0)
    inlier = costs[best, np.arange(data.shape[0])] < outlier_cost
    out[inlier] = best[inlier]
    return out


def evaluate_segmentation(
    tracks: np.ndarray,
    labels: np.ndarray,
    config: PearlConfig | None = None,
    rng: np.random.Generator | int | None = None,
) -> tuple[float, np.ndarray]:
    """The energy of a given segmentation, each segment with a model refitted to it.

    With the same ``config`` and seed as a :func:`fit`, the energy is measured in the same
    setting (same noise scale), so comparing it with ``fit(...).energy`` tells a search failure
    (the optimiser stopped above this energy) from an energy failure (the energy prefers the
    answer found). A segment too small or too degenerate for a model counts as outliers.

    Parameters
    ----------
    tracks : (F, N, 2) float64, pixels
    labels : (N,) int, segment 0..K-1 of each point, -1 for outliers
    config : PearlConfig, optional
    rng : numpy Generator, seed or None

    Returns
    -------
    energy : float
    residuals : (K, N) float64, pixels, of every point to each segment's model (NaN rows for
        segments that got no model)
    """
    config = config or PearlConfig()
    setting = _setting(tracks, config, np.random.default_rng(rng))
    n = setting.data.shape[0]
    labels = _check_labels(labels, n)
    params, sigmas, rows, inner = _segment_models(setting, labels)
    num = int(labels.max()) + 1 if labels.size else 0
    residuals = np.full((num, n), np.nan)
    # Segment k got model inner[p] - 1 for any of its members p, if it got one.
    for k in range(num):
        members = np.flatnonzero(labels == k)
        if members.size and inner[members[0]] != OUTLIER_ROW:
            residuals[k] = rows[inner[members[0]] - 1]
    unary = setting.unary(rows, sigmas)
    return energy(setting.problem(unary), inner), residuals


def _check_labels(labels: np.ndarray, n: int) -> np.ndarray:
    labels = np.asarray(labels)
    if labels.shape != (n,) or not np.issubdtype(labels.dtype, np.integer):
        raise InputError(f'labels must be integers of shape ({n},), got {labels.dtype} '
                         f'{labels.shape}')
    return labels.astype(np.int64)


def _segment_models(setting: _Setting, labels: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One model per segment of ``labels`` (0..K-1, -1 outlier), refitted to its members.

    A segment too small or too degenerate for a model becomes outliers. Returns the models'
    params, noise levels and residual rows, and the labelling in the optimiser's numbering
    (``OUTLIER_ROW``, model k is label k + 1).
    """
    model, data = setting.model, setting.data
    m = model.min_samples
    num = int(labels.max()) + 1 if labels.size else 0
    inner = np.full(data.shape[0], OUTLIER_ROW, dtype=np.int64)
    params, sigmas, rows = [], [], []
    for k in range(num):
        members = np.flatnonzero(labels == k)
        if members.size <= m:
            continue
        start, ok = model.fit_minimal(data, members[None, :m])
        new = model.refit(data, members, start[0])
        if new is None:
            continue
        row = model.residuals(data, new[None])[0]
        sigma = noise_level(row[members], setting.dof, setting.floor, m, setting.cap(members))
        if sigma is None:
            continue
        params.append(new)
        sigmas.append(sigma)
        rows.append(row)
        inner[members] = len(params)
    shape = (0,) + _param_shape(model, data)
    return (np.asarray(params, dtype=np.float64).reshape((len(params),) + shape[1:]),
            np.asarray(sigmas, dtype=np.float64), np.asarray(rows).reshape(-1, data.shape[0]),
            inner)


def _origins(labels: np.ndarray, prior: np.ndarray, num_models: int) -> np.ndarray:
    """The init segment each of the ``num_models`` models of :func:`_segment_models` was fitted
    to (its members' ``prior``)."""
    origin = np.full(num_models, OUTLIER, dtype=np.int64)
    inlier = labels != OUTLIER_ROW
    origin[labels[inlier] - 1] = prior[inlier]
    return origin


def _init_bias(prior: np.ndarray, origin: np.ndarray, cost: float) -> np.ndarray:
    """Rows ``(1 + K, N)`` of the init term: ``cost`` where a point with an init segment takes
    any label but that segment's model (the outlier label and new models included)."""
    rows = np.concatenate([[OUTLIER], origin])  # the outlier row is no segment's model
    if not cost:  # a read-only view of one zero: nothing allocated on the usual path
        return np.broadcast_to(np.zeros(1), (rows.size, prior.size))
    bias: np.ndarray = cost * ((prior[None, :] >= 0) & (rows[:, None] != prior[None, :]))
    return bias


def _past(deadline: float | None) -> bool:
    return deadline is not None and time.perf_counter() > deadline


def _outlier_cost(threshold: float, scale: float, dof: float, floor: float) -> float:
    """The outlier label's data cost: a point is an outlier when its residual to a model at the
    fresh noise level ``scale`` exceeds ``threshold`` of those levels."""
    return float(data_costs(np.array([[threshold * scale]]), np.array([scale]), dof, floor)[0, 0])


def _setting(tracks: np.ndarray, config: PearlConfig, rng: np.random.Generator,
             graph: Neighbourhood | None = None, also: np.ndarray | None = None,
             cameras: np.ndarray | None = None, batch: bool = True) -> _Setting:
    solver = config.solver
    model = get_model(config.model, solver)
    if cameras is not None:
        model = WithStaticWorld(model, cameras)
    data = model.data(tracks)  # validates tracks
    n = data.shape[0]
    if n < model.min_samples + 1:
        raise InputError(f'tracks must hold at least {model.min_samples + 1} points for '
                         f'model {config.model!r}, got {n}')
    # Neighbours are compared over every frame given, whatever the model family.
    if graph is None:
        # Two views with mismatches: neighbours in both views' coordinates together.
        joint = (batch and tracks.shape[0] == 2 and solver.joint_neighbours > 0
                 and lost_neighbours(tracks, solver.image_neighbours)
                 >= solver.joint_neighbours)
        graph = neighbourhood(tracks, settings=solver,
                              core_patches=batch and solver.core_patches, joint=joint)
    else:
        graph.check(n)
    drawn = graph
    # A batch two-view neighbourhood drawn jointly (its isolation misses apart) is that of two
    # views with mismatches: its models must keep their fellows, and its isolated points,
    # told apart on both views' coordinates, are bridged.
    joint = batch and tracks.shape[0] == 2 and graph.isolation_misses is not None
    views = tracks if joint and solver.kept_fellows > 0 else None
    edges, neighbours = graph.edges, graph.neighbours
    nearest = graph.nearest_miss()
    suspect = _suspects(nearest, solver.isolation, also)
    scale = config.noise or _estimate_scale(model, data, neighbours, config, rng, suspect,
                                            tracks[-1])
    dof = model.residual_dof(data)
    floor = solver.sigma_floor * scale
    ceiling = solver.sigma_ceiling * scale if solver.sigma_ceiling else math.inf
    outlier_cost = _outlier_cost(config.outlier_threshold, scale, dof, floor)
    costs = np.full(n, outlier_cost)
    counted = None
    misses, measured = graph.misses, edges.shape[0]
    held = None  # the caller's suspects, taken as outliers (SolverSettings.persist_outliers)
    if suspect is not None:
        isolated = suspect & (nearest > solver.isolation_floor * scale)
        if also is not None and solver.persist_outliers and tracks.shape[0] >= 3:
            held = _check_suspects(also, n) & rough_tracks(tracks, solver.persist_roughness)
            isolated |= held
        if (batch and solver.redraw_isolated and tracks.shape[0] >= BRIDGE_FRAMES
                and isolated.any() and np.count_nonzero(~isolated) > neighbours.shape[1]):
            graph, isolated = _redrawn(graph, tracks, isolated, solver,
                                       solver.isolation_floor * scale, also, held)
            neighbours, misses = graph.neighbours, graph.misses
        # Per coordinate: a reduction over the long axis of an (M, 2) array is 20 times slower.
        span = float(max(np.ptp(tracks[..., 0]), np.ptp(tracks[..., 1])))
        uniform = dof * (2.0 * math.log(max(span, floor) / floor) - math.log(2.0 * math.pi))
        costs[isolated] = min(outlier_cost, max(uniform, 0.0))
        if held is not None:
            costs[held] = 0.0
        kept = ~(isolated[edges[:, 0]] | isolated[edges[:, 1]])
        if solver.bridge_isolated and (tracks.shape[0] >= BRIDGE_FRAMES or joint) \
                and isolated.any():
            bridges, bridge_misses = graph.bridges(tracks, isolated, solver)
            edges = np.concatenate([edges, bridges])
            misses = np.concatenate([misses, bridge_misses])
            # The unit stays that of the triangulation's own edges: bridges are longer.
            kept = np.concatenate([kept, np.zeros(bridges.shape[0], dtype=bool)])
        if np.any(kept):
            counted = kept
    stretch = long_edge_stretch(tracks, edges, neighbours, config.long_edge_growth, solver,
                                measured)
    weights = edge_weights(misses, scale, config.smoothness, config.separation,
                           config.contrast, config.unit_quantile, stretch, counted)
    if held is not None:
        # A track held apart keeps no tie to its neighbours, only the rewards of the pairs
        # that move apart, which the outlier label collects whatever its neighbours' labels
        # (outlier_apart): no labelling pays less for it than the outlier label.
        loose = held[edges[:, 0]] | held[edges[:, 1]]
        weights[loose] = np.minimum(weights[loose], 0.0)
    local, reference = None, 0.0
    if batch and solver.local_ceiling and model.name in TWO_VIEW:
        local = nearest
        reference = pair_unit(misses, scale, config.unit_quantile, counted)
    if cameras is not None:
        weights = static_ties(weights, edges, data[:, -1], scale, solver.static_contrast)
    return _Setting(
        model=model, solver=solver, data=data, edges=edges,
        weights=weights,
        neighbours=neighbours, scale=scale, floor=floor, ceiling=ceiling, dof=dof,
        outlier_cost=costs,
        label_cost=config.label_cost * model.label_cost_weight(data),
        local=local, reference=reference, batch=batch, views=views, drawn=drawn)


def noise_scale(tracks: np.ndarray, config: PearlConfig | None = None,
                rng: np.random.Generator | int | None = None,
                graph: Neighbourhood | None = None,
                suspects: np.ndarray | None = None) -> float:
    """The noise scale (px) :func:`fit` estimates when ``config.noise`` is 0.

    Callers that fit similar data again and again (the online segmenter) estimate it once and
    pass it on as ``config.noise``, saving the setup cost of every fit. With the ``graph`` of
    ``tracks`` that :func:`fit` is given, the points it finds isolated
    (``SolverSettings.isolation``, and the ``suspects`` it is given) are left out as they are
    in :func:`fit`.
    """
    config = config or PearlConfig()
    model = get_model(config.model, config.solver)
    data = model.data(tracks)
    anchor = np.asarray(tracks, dtype=np.float64)[-1]
    neighbours, suspect = nearest_neighbours(anchor, config.solver.image_neighbours), None
    if graph is not None:
        graph.check(data.shape[0])
        suspect = _suspects(graph.nearest_miss(), config.solver.isolation, suspects)
    return _estimate_scale(model, data, neighbours, config, np.random.default_rng(rng),
                           suspect, anchor)


def isolation_ratios(nearest: np.ndarray) -> np.ndarray | None:
    """Each point's least miss ``nearest`` (:meth:`Neighbourhood.nearest_miss`) over the
    ``CORE_QUANTILE`` quantile of those misses ``(N,)`` (inf for a point with no neighbour, or
    where the quantile is 0); None when no point has a neighbour."""
    finite = nearest[np.isfinite(nearest)]
    if not finite.size:
        return None
    core = float(np.quantile(finite, CORE_QUANTILE))
    with np.errstate(divide='ignore', invalid='ignore'):
        ratios: np.ndarray = np.where(nearest > 0, nearest / core, 0.0)
    return ratios


def _suspects(nearest: np.ndarray, isolation: float, also: np.ndarray | None = None
              ) -> np.ndarray | None:
    """Points ``(N,)`` bool whose most alike neighbour misses them by more than ``isolation``
    times the ``CORE_QUANTILE`` quantile of such misses (:func:`isolation_ratios`), or that
    ``also`` marks (a caller's suspects, judged over earlier frames); None when ``isolation`` is
    0 or no point has a neighbour."""
    ratios = isolation_ratios(nearest) if isolation else None
    if ratios is None:
        return None
    suspect: np.ndarray = ratios > isolation
    if also is not None:
        suspect |= _check_suspects(also, nearest.size)
    return suspect


def rough_tracks(tracks: np.ndarray, factor: float) -> np.ndarray:
    """Tracks ``(N,)`` bool of ``tracks`` (F, N, 2), F >= 3, whose RMS second difference
    (a pixel's acceleration from frame to frame) is more than ``factor`` times the median
    track's. A random walk's steps are independent, so its second differences are those of
    its steps; a rigid body's track accelerates smoothly, and its second differences are
    about its tracking noise, as its neighbours' are."""
    accel = tracks[2:] - 2.0 * tracks[1:-1] + tracks[:-2]
    rough = np.sqrt(np.mean(np.sum(np.square(accel), axis=2), axis=0))
    out: np.ndarray = rough > factor * float(np.median(rough))
    return out


def _redrawn(graph: Neighbourhood, tracks: np.ndarray, isolated: np.ndarray,
             solver: SolverSettings, floor: float, also: np.ndarray | None,
             held: np.ndarray | None = None) -> tuple[Neighbourhood, np.ndarray]:
    """``graph`` with every patch drawn again among the points not ``isolated`` (N,) bool
    (:meth:`Neighbourhood.without`), and the points still isolated on those patches: their
    nearest miss still above ``floor`` px and the isolation test's threshold.

    The first test reads the patches as drawn, outlier tracks among them. A true point whose
    patch held several is then as far from its neighbours' subspaces as an outlier, and its
    neighbours, joined across it by bridges that run far across the body, are cut apart for
    the rewards of those bridges (Hopkins155 with outlier tracks: a background split in two).
    Drawn among its own body's points, its patch takes it back. The patches are drawn once
    more, without the points that stay isolated. Points ``held`` (N,) bool, the caller's taken
    as outliers whatever their misses, stay isolated.
    """
    redrawn = graph.without(tracks, isolated, solver)
    nearest = redrawn.nearest_miss()
    suspect = _suspects(nearest, solver.isolation, also)
    if suspect is None:
        return redrawn, isolated
    still = isolated & suspect & (nearest > floor)
    if held is not None:
        still |= held
    if np.count_nonzero(still) == np.count_nonzero(isolated):
        return redrawn, isolated
    return graph.without(tracks, still, solver), still


def _check_suspects(suspects: np.ndarray, n: int) -> np.ndarray:
    suspects = np.asarray(suspects)
    if suspects.shape != (n,) or suspects.dtype != bool:
        raise InputError(f'suspects must be a ({n},) bool array, got {suspects.dtype} '
                         f'{suspects.shape}')
    return suspects


def _estimate_scale(model: MotionModel, data: np.ndarray, neighbours: np.ndarray,
                    config: PearlConfig, rng: np.random.Generator,
                    suspect: np.ndarray | None = None, anchor: np.ndarray | None = None) -> float:
    """The noise scale of :func:`local_scale`; with ``suspect`` points (N,) and every point's
    image position ``anchor`` (N, 2), from the neighbourhoods of the other points among
    themselves, so that points that move unlike all their neighbours do not inflate it."""
    if (suspect is not None and anchor is not None
            and np.count_nonzero(~suspect) > neighbours.shape[1] + 1):
        kept = np.flatnonzero(~suspect)
        neighbours = nearest_neighbours(anchor[kept], neighbours.shape[1])
        data = data[kept]
    return max(local_scale(model, data, neighbours, rng, config.solver.scale_seeds,
                           config.solver.scale_trim), config.min_noise)


def _propose(search: _Search, config: PearlConfig, rng: np.random.Generator
             ) -> Generator[None, None, None]:
    """Offer fresh hypotheses to the search: a batch of minimal samples, plus, once models
    exist, samples drawn inside each segment. (A motion split between two labels is joined by
    the merge moves that end each round, :func:`_merge`.) All samples are drawn first; their
    models are fitted, measured and offered :data:`PROPOSE_CHUNK` samples at a time, yielding
    between chunks: the same labels, in the same order, as in one batch."""
    setting = search.setting
    model, data = setting.model, setting.data
    m = model.min_samples
    samples = [mixed_samples(data.shape[0], setting.neighbours, config.num_proposals, m,
                             config.local_sampling, rng)]
    for k in range(1, search.params.shape[0] + 1):
        samples.append(uniform_samples(np.flatnonzero(search.labels == k),
                                       setting.solver.segment_samples, m, rng))
    drawn = np.concatenate(samples)
    # A fresh hypothesis does not know its noise level yet: it is offered at several, and
    # re-estimation tightens the one that is taken.
    levels = setting.scale * np.asarray(setting.solver.proposal_levels)
    for start in range(0, drawn.shape[0], PROPOSE_CHUNK):
        if start:
            yield None
        fresh, ok = model.fit_minimal(data, drawn[start:start + PROPOSE_CHUNK])
        fresh = fresh[ok]
        search.add(np.repeat(fresh, levels.size, axis=0), np.tile(levels, fresh.shape[0]),
                   np.repeat(model.residuals(data, fresh), levels.size, axis=0))
    fixed = getattr(model, 'fixed_hypotheses', None)
    if fixed is not None:
        yield None
        known = fixed(data)
        search.add(np.repeat(known, levels.size, axis=0), np.tile(levels, known.shape[0]),
                   np.repeat(model.residuals(data, known), levels.size, axis=0))


def _param_shape(model: MotionModel, data: np.ndarray) -> tuple[int, ...]:
    sample = np.arange(model.min_samples)[None, :]
    return model.fit_minimal(data, sample)[0].shape[1:]


def _refit_one(setting: _Setting, members: np.ndarray, start: np.ndarray) -> _Refit | None:
    """A model re-estimated from ``members``: params, noise level, residual row and data cost
    row (read-only); None when the members are too few or degenerate. A refit depends on
    nothing else, and is computed once per setting (:attr:`_Setting.refits`)."""
    key = (np.asarray(members, dtype=np.int64).tobytes(),
           np.asarray(start, dtype=np.float64).tobytes())
    if key in setting.refits:
        return setting.refits[key]
    fitted = _computed_refit(setting, members, start)
    if len(setting.refits) >= REFITS_KEPT:
        setting.refits.clear()
    if REFITS_KEPT:
        setting.refits[key] = fitted
    return fitted


def _computed_refit(setting: _Setting, members: np.ndarray, start: np.ndarray
                    ) -> _Refit | None:
    """:func:`_refit_one`, computed."""
    model = setting.model
    new = model.refit(setting.data, members, start)
    if new is None:
        return None
    residuals = model.residuals(setting.data, new[None])
    sigma = noise_level(residuals[0, members], setting.dof, setting.floor, model.min_samples,
                        setting.cap(members))
    if sigma is None:
        return None
    row = data_costs(residuals, np.array([sigma]), setting.dof, setting.floor)[0]
    for array in (new, residuals, row):
        array.setflags(write=False)
    return new, sigma, residuals[0], row


def _refit(search: _Search) -> Generator[None, None, int]:
    """Re-estimate every model in use, and its noise level, from its points; keep a refit only
    if it lowers their cost, so the energy never goes up. A model already fitted to the same
    points in closed form is left as it is (its refit would be itself). Yields before each
    model's refit; returns the models refitted."""
    labels, unary, bias = search.labels, search.unary, search.bias
    refitted = 0
    for label in np.unique(labels):
        if label == OUTLIER_ROW:
            continue
        members = np.flatnonzero(labels == label)
        if search.refitted_already(label, members):
            continue
        yield
        fitted = _refit_one(search.setting, members, search.params[label - 1])
        if fitted is not None and (fitted[3][members].sum()
                                   < unary[label, members].sum() - bias[label, members].sum()):
            search.adopt(label, fitted, members)
            refitted += 1
    return refitted


def _split(search: _Search, deadline: float | None = None) -> Generator[None, None, int]:
    """Split moves: expansions judged after the models that lose points are refitted to what is
    left. Returns the moves kept.

    A plain expansion of a tight model for one motion out of a loose model that covers two is
    rejected: the loose model keeps its noise level until it is refitted, so the points left to
    it still pay for it. Here the few most promising unused labels (:func:`_split_candidates`)
    are expanded, the losing models refitted, and the move kept only if the whole energy drops.
    Past the ``deadline`` no trial starts but the first: the one that lets a budgeted stream
    split a motion over its frames, one trial a frame. Yields before each trial.
    """
    kept = 0
    current = search.energy()
    for tried, alpha in enumerate(_split_candidates(search)):
        if tried and _past(deadline):
            break
        yield
        trial = _split_trial(search, alpha)
        if trial is not None and trial[2] < current - 1e-9:
            search.labels, refits, current = trial
            for label, fitted in refits.items():
                search.adopt(label, fitted, np.flatnonzero(search.labels == label))
            kept += 1
    return kept


def _split_candidates(search: _Search) -> list[int]:
    """The unused labels worth a split move, best gain bound first (at most ``split_tries`` of
    the ``split_screen`` best)."""
    solver, labels, unary = search.setting.solver, search.labels, search.unary
    used = np.zeros(unary.shape[0], dtype=bool)
    used[labels] = True
    # Without the label cost: the refit of the losers may pay for it.
    gain = _gain_bound(search.problem, labels)
    gain[used] = -np.inf
    # A useful split takes part of a segment, not all of it: a near copy of the segment's own
    # model has a large gain but leaves nothing to refit. Candidates are screened by the share
    # of their best-supported segment that they fit better.
    size = np.bincount(labels, minlength=unary.shape[0])
    current_costs = unary[labels, np.arange(labels.size)]
    candidates: list[int] = []
    for alpha in np.argsort(-gain, kind='stable')[:solver.split_screen]:
        if not gain[alpha] > 0 or len(candidates) == solver.split_tries:
            break
        taken = labels[(unary[alpha] < current_costs) & (labels != OUTLIER_ROW)]
        if taken.size == 0:
            continue
        counts = np.bincount(taken, minlength=unary.shape[0])
        share = counts / np.maximum(size, 1)
        if np.any((share >= solver.split_share_min) & (share <= solver.split_share_max)):
            candidates.append(int(alpha))
    return candidates


def _split_trial(search: _Search, alpha: int
                 ) -> tuple[np.ndarray, dict[int, _Refit], float] | None:
    """The split move of ``alpha``: the labelling, the refits of the losers and of ``alpha``
    (label -> :func:`_refit_one` result) and the energy with them; None if no model loses."""
    labels, unary, problem = search.labels, search.unary, search.problem
    # Expanded as if alpha were free: its label cost is paid, if at all, by the refits.
    free = problem.label_costs.copy()
    free[alpha] = 0.0
    moved = expansion_move(dataclasses.replace(problem, label_costs=free), labels, alpha)
    losers = np.unique(labels[moved != labels])
    losers = losers[losers != OUTLIER_ROW]
    if losers.size == 0:
        return None
    trial = unary.copy()
    refits: dict[int, _Refit] = {}
    # The new model is refitted to what it took too, like the losers to what they kept.
    for label in (*losers, alpha):
        members = np.flatnonzero(moved == label)
        fitted = (_refit_one(search.setting, members, search.params[label - 1])
                  if members.size else None)
        if fitted is not None:
            refits[label] = fitted
            trial[label] = fitted[3] + search.bias[label]
    moved_energy = energy(dataclasses.replace(problem, unary=trial), moved)
    return moved, refits, moved_energy


def _merge(search: _Search, deadline: float | None = None) -> Generator[None, None, int]:
    """Merge moves: two neighbouring segments become one, its model refitted to both. Returns
    the merges made.

    An expansion cannot merge two segments of one motion when neither model fits the other's
    points, and the model of their union is not among the proposals: one motion stays cut in
    two though one model of both lowers the energy. Each pair of segments that share a
    neighbour edge is tried, the larger keeping its label; the best merge that lowers the energy
    is made (:func:`_best_merge`), and the pairs are tried again, until the ``deadline``.
    Yields before each pair's trial.
    """
    merges = 0
    while not _past(deadline):
        best = yield from _best_merge(search, deadline)
        if best is None:
            break
        keep, drop, fitted = best
        search.labels = np.where(search.labels == drop, keep, search.labels)
        search.adopt(keep, fitted, np.flatnonzero(search.labels == keep))
        merges += 1
    return merges


def _drop_scattered(search: _Search) -> int:
    """Free the points of the models that do not keep their points' fellows; returns how
    many models were dropped.

    A rigid motion keeps the image neighbours of its points from one view to the other; a
    mismatch lands anywhere in the second view. Where the views hold many mismatches
    (``_Setting.views``), a model with a wide enough noise level holds a set of them at a data
    cost below the outlier label's (AdelaideRMF's ``game``: 54 mismatches at 29 px, beside its
    structure at 2.8 px). Of its points' :data:`FELLOWS` nearest fellow points (of the same
    model) in the first view, a share ``s`` is among their nearest in the second, where
    chance alone keeps ``c = FELLOWS / (M - 1)`` among M points; ``(s - c) / (1 - c)`` is
    the share kept beyond chance: 0.08-0.14 for the models of mismatches of AdelaideRMF's
    pairs, 0.55 or more for their structures and 0.35 or more for clouds of points seen
    through (synthetic bodies turned by 38 degrees). A model that keeps less than
    ``SolverSettings.kept_fellows`` beyond chance is no motion: its points become outliers (a
    test of the hypothesis, as the interchangeable merge is, not a move of the energy; the
    next round offers its points to the other models). A model of FELLOWS + 1 points or fewer
    is not tested: every point is every other's neighbour.
    """
    views = search.setting.views
    if views is None:
        return 0
    least = search.setting.solver.kept_fellows
    dropped = 0
    for label in np.unique(search.labels[search.labels != OUTLIER_ROW]).tolist():
        members = np.flatnonzero(search.labels == label)
        if members.size <= FELLOWS + 1:
            continue
        kept, k = kept_neighbours(views[:, members], FELLOWS)
        chance = k / (members.size - 1)
        if (float(np.mean(kept)) / k - chance) / (1.0 - chance) < least:
            search.labels = np.where(search.labels == label, OUTLIER_ROW, search.labels)
            dropped += 1
    return dropped


def _merge_interchangeable(search: _Search) -> Generator[None, None, int]:
    """Merge the models that are one motion by their residuals alone, once the rounds end;
    returns the merges made.

    Two models are interchangeable where each holds the other's points about as it holds its
    own: the median of the other segment's residuals to it is within
    ``SolverSettings.interchangeable`` of its noise levels (``interchangeable_online`` in a
    stream's fits). The pair term can keep such a pair
    apart: neighbours on one body that move apart in the image (a depth discontinuity under
    perspective, where the local subspaces of the contrast term extrapolate badly) earn a
    reward for being cut, and a second model along that line collects it. The merge ignores
    the energy, which it may raise: it is a test of the hypotheses, as multi-model fitting
    merges duplicate instances, not a move. The most interchangeable pair goes first, the
    larger segment keeping its label and its model refitted to both; then the pairs are
    measured again. Yields before each refit.
    """
    solver = search.setting.solver
    limit = solver.interchangeable if search.setting.batch else solver.interchangeable_online
    merges = 0
    while limit > 0:
        used = np.unique(search.labels[search.labels != OUTLIER_ROW])
        if used.size < 2:
            break
        members = [search.labels == label for label in used]
        # held[i, j]: the median residual of segment j's points to model i, in its noise levels
        held = np.array([[np.median(search.residuals[a - 1, members[j]]) / search.sigmas[a - 1]
                          for j in range(used.size)] for a in used])
        apart = np.maximum(held, held.T)
        np.fill_diagonal(apart, np.inf)
        i, j = np.unravel_index(np.argmin(apart), apart.shape)
        if not apart[i, j] < limit:
            break
        keep, drop = ((used[i], used[j]) if np.count_nonzero(members[i])
                      >= np.count_nonzero(members[j]) else (used[j], used[i]))
        both = np.flatnonzero(members[i] | members[j])
        yield
        fitted = _refit_one(search.setting, both, search.params[keep - 1])
        if fitted is None:
            break
        search.labels = np.where(search.labels == drop, keep, search.labels)
        search.adopt(keep, fitted, both)
        merges += 1
    return merges


def _best_merge(search: _Search, deadline: float | None = None
                ) -> Generator[None, None, tuple[int, int, _Refit] | None]:
    """The merge that lowers the energy most: the label kept, the label dropped and the kept
    model's refit to both segments; None if no merge lowers it. Past the ``deadline``, the
    best of the pairs tried so far."""
    labels, unary, problem = search.labels, search.unary, search.problem
    p, q = problem.edges[:, 0], problem.edges[:, 1]
    a, b = labels[p], labels[q]
    touch = (a != b) & (a != OUTLIER_ROW) & (b != OUTLIER_ROW)
    if not np.any(touch):
        return None
    pairs, where = np.unique(np.sort(np.stack([a[touch], b[touch]], axis=1), axis=1),
                             axis=0, return_inverse=True)
    # The weights of the edges each merge would no longer cut.
    uncut = np.bincount(where.reshape(-1), weights=problem.weights[touch],
                        minlength=pairs.shape[0])
    size = np.bincount(labels, minlength=unary.shape[0])
    current_costs = unary[labels, np.arange(labels.size)]
    best: tuple[int, int, _Refit] | None = None
    best_delta = -1e-9
    for (x, y), freed in zip(pairs, uncut, strict=True):
        if _past(deadline):
            break
        yield
        keep, drop = (x, y) if size[x] >= size[y] else (y, x)
        members = np.flatnonzero((labels == keep) | (labels == drop))
        fitted = _refit_one(search.setting, members, search.params[keep - 1])
        if fitted is None:
            continue
        delta = (fitted[3][members].sum() + search.bias[keep, members].sum()
                 - current_costs[members].sum() - freed - problem.label_costs[drop])
        if delta < best_delta:
            best, best_delta = (keep, drop, fitted), delta
    return best


def _compress(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Renumber the models in use by decreasing support (outliers stay in ``OUTLIER_ROW``);
    also returns the indices of the kept models among the old ones."""
    used = np.unique(labels[labels != OUTLIER_ROW])
    support = np.array([np.count_nonzero(labels == u) for u in used], dtype=np.int64)
    used = used[np.argsort(-support, kind='stable')]
    mapping = np.full(int(labels.max()) + 1, OUTLIER_ROW, dtype=np.int64)
    mapping[used] = np.arange(1, used.size + 1)
    return mapping[labels], used - 1

