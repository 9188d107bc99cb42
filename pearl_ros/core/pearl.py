"""PEaRL: Propose, Expand and Re-estimate Labels (Isack & Boykov, IJCV 2012).

``fit`` composes the pure steps: :mod:`proposals` draws minimal samples, each becomes a model
hypothesis (a label); :func:`sweep` runs alpha-expansions (:mod:`expansion`) over them; refit
re-estimates every model in use from its points; both repeat while the energy
(:mod:`energy`) goes down. Rounds then mix the surviving models with a fresh batch of samples,
the thesis' remedy for too few samples (Isack, sec. 2.3.3). Label 0 inside the optimiser is the
outlier label, with a constant cost and no label cost; the result reports it as -1.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from pearl_ros.core.config import PearlConfig
from pearl_ros.core.energy import Problem, energy
from pearl_ros.core.expansion import expansion_move
from pearl_ros.core.models import MotionModel, get_model
from pearl_ros.core.neighbourhood import delaunay_edges, nearest_neighbours
from pearl_ros.core.proposals import mixed_samples
from pearl_ros.core.errors import InputError

OUTLIER = 0
_NEIGHBOURS = 10  # image neighbours a local sample is drawn from
_MAX_PASSES = 5  # expansion passes over the labels within one sweep


@dataclass(frozen=True)
class PearlResult:
    """What :func:`fit` found.

    Attributes
    ----------
    labels : (N,) int64, model index 0..K-1 of each point, -1 for outliers
    params : (K, ...) float64, parameters of model k (layout set by the model)
    energy : float, final energy
    energy_history : tuple of float, energy after every expand / re-estimate iteration
    iterations : int, expand / re-estimate iterations run
    timings : dict of str to float, seconds per step
    """

    labels: np.ndarray
    params: np.ndarray
    energy: float
    energy_history: tuple[float, ...]
    iterations: int
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def num_models(self) -> int:
        return int(self.params.shape[0])


def data_costs(residuals: np.ndarray, config: PearlConfig) -> np.ndarray:
    """D_p(l) = (r / noise)^2: the negative log-likelihood of Gaussian residuals, up to a constant."""
    return np.square(residuals / config.noise)


def sweep(problem: Problem, labels: np.ndarray) -> np.ndarray:
    """Alpha-expansions until no move lowers the energy; labels are tried best-first.

    Every label in use is expanded each pass. An unused label is expanded only while its data
    gain alone, sum_p max(0, D_p(f_p) - D_p(alpha)), exceeds its label cost: a cheap bound that
    skips the many proposals that cannot pay for themselves, so a sweep costs a few moves,
    not one per proposal.
    """
    unary, costs = problem.unary, problem.label_costs
    idx = np.arange(labels.size)
    current = energy(problem, labels)
    for _ in range(_MAX_PASSES):
        changed = False
        tried = np.zeros(unary.shape[0], dtype=bool)
        while True:
            used = np.zeros(unary.shape[0], dtype=bool)
            used[labels] = True
            gain = np.maximum(unary[labels, idx][None, :] - unary, 0.0).sum(axis=1)
            gain = np.where(used, np.inf, gain - costs)
            gain[tried] = -np.inf
            alpha = int(np.argmax(gain))
            if not gain[alpha] > 0:
                break
            tried[alpha] = True
            moved = expansion_move(problem, labels, alpha)
            moved_energy = energy(problem, moved)
            if moved_energy < current - 1e-9:
                labels, current, changed = moved, moved_energy, True
        if not changed:
            break
    return labels


def fit(
    tracks: np.ndarray,
    config: PearlConfig | None = None,
    rng: np.random.Generator | int | None = None,
) -> PearlResult:
    """Segment tracked points into rigid motions; the number of motions is found, not given.

    Parameters
    ----------
    tracks : (F, N, 2) float64, pixel coordinates of N points tracked over F frames
        (two-view models use the first and the last frame).
    config : PearlConfig, optional
    rng : numpy Generator, seed or None

    Returns
    -------
    PearlResult
    """
    config = config or PearlConfig()
    rng = np.random.default_rng(rng)
    model = get_model(config.model)
    timings = {'propose': 0.0, 'expand': 0.0, 'refit': 0.0}
    data = model.data(tracks)
    n = data.shape[0]
    if n < model.min_samples:
        raise InputError(f'tracks must hold at least {model.min_samples} points for '
                         f'model {config.model!r}, got {n}')
    anchor = np.asarray(tracks, dtype=np.float64)[-1]
    edges = delaunay_edges(anchor)
    weights = np.full(edges.shape[0], config.smoothness)
    neighbours = nearest_neighbours(anchor, _NEIGHBOURS)
    outlier_cost = (config.outlier_threshold / config.noise) ** 2

    params = np.empty((0,) + _param_shape(model, data))
    labels = np.full(n, OUTLIER, dtype=np.int64)
    history: list[float] = []
    iterations = 0
    for _ in range(config.rounds):
        start = time.perf_counter()
        samples = mixed_samples(n, neighbours, config.num_proposals, model.min_samples,
                                config.local_sampling, rng)
        fresh, ok = model.fit_minimal(data, samples)
        params = np.concatenate([params, fresh[ok]], axis=0)
        unary = np.vstack([np.full((1, n), outlier_cost),
                           data_costs(model.residuals(data, params), config)])
        costs = np.full(unary.shape[0], config.label_cost)
        costs[OUTLIER] = 0.0
        timings['propose'] += time.perf_counter() - start

        current = energy(Problem(unary, edges, weights, costs), labels)
        for _ in range(config.max_iterations):
            iterations += 1
            start = time.perf_counter()
            labels = sweep(Problem(unary, edges, weights, costs), labels)
            timings['expand'] += time.perf_counter() - start
            start = time.perf_counter()
            _refit(model, data, labels, params, unary, config)
            timings['refit'] += time.perf_counter() - start
            new = energy(Problem(unary, edges, weights, costs), labels)
            history.append(new)
            if not new < current - 1e-9:
                break
            current = new
        # Only the models in use survive into the next round (and into the result).
        labels, params = _compress(labels, params)

    final = energy_of(labels, params, model, data, edges, weights, config)
    out = np.where(labels == OUTLIER, -1, labels - 1)
    return PearlResult(out, params, final, tuple(history), iterations, timings)


def energy_of(labels, params, model, data, edges, weights, config) -> float:
    """The energy of a compressed labelling (outlier = 0, model k = k + 1)."""
    n = data.shape[0]
    unary = np.vstack([np.full((1, n), (config.outlier_threshold / config.noise) ** 2),
                       data_costs(model.residuals(data, params), config)])
    costs = np.full(unary.shape[0], config.label_cost)
    costs[OUTLIER] = 0.0
    return energy(Problem(unary, edges, weights, costs), labels)


def _param_shape(model: MotionModel, data: np.ndarray) -> tuple[int, ...]:
    sample = np.arange(model.min_samples)[None, :]
    return model.fit_minimal(data, sample)[0].shape[1:]


def _refit(model: MotionModel, data: np.ndarray, labels: np.ndarray, params: np.ndarray,
           unary: np.ndarray, config: PearlConfig) -> None:
    """Re-estimate every model in use from its points; keep a refit only if it lowers their cost.

    ``params`` and ``unary`` are updated in place, so the energy never goes up.
    """
    for label in np.unique(labels):
        if label == OUTLIER:
            continue
        members = np.flatnonzero(labels == label)
        new = model.refit(data, members, params[label - 1])
        if new is None:
            continue
        row = data_costs(model.residuals(data, new[None])[0], config)
        if row[members].sum() < unary[label, members].sum():
            params[label - 1] = new
            unary[label] = row


def _compress(labels: np.ndarray, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Keep the models in use, renumbered by decreasing support; outliers stay 0."""
    used = np.unique(labels[labels != OUTLIER])
    support = np.array([np.count_nonzero(labels == u) for u in used])
    used = used[np.argsort(-support, kind='stable')]
    mapping = np.zeros(params.shape[0] + 1, dtype=np.int64)
    mapping[used] = np.arange(1, used.size + 1)
    return mapping[labels], params[used - 1]
