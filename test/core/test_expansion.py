"""Every alpha-expansion move is the optimal move: checked against brute force."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from pearl_ros.core.energy import Problem, energy
from pearl_ros.core.expansion import Expansions, expansion_move


def random_problem(rng: np.random.Generator, n: int, num_labels: int) -> Problem:
    pairs = np.array([(i, j) for i in range(n) for j in range(i + 1, n)])
    keep = rng.random(len(pairs)) < 0.5
    edges = pairs[keep].reshape(-1, 2)
    # Some labels free, some expensive: label costs must decide some moves.
    costs = rng.uniform(0, 15, num_labels) * (rng.random(num_labels) < 0.8)
    return Problem(rng.uniform(0, 10, (num_labels, n)), edges,
                   rng.uniform(0, 5, len(edges)), costs)


def best_move_energy(problem: Problem, labels: np.ndarray, alpha: int) -> float:
    n = labels.size
    return min(energy(problem, np.where(np.array(switch, dtype=bool), alpha, labels))
               for switch in itertools.product([False, True], repeat=n))


@pytest.mark.parametrize('seed', range(20))
def test_expansion_move_is_optimal_against_brute_force(seed):
    rng = np.random.default_rng(seed)
    for _ in range(10):
        n = int(rng.integers(2, 9))
        problem = random_problem(rng, n, int(rng.integers(2, 6)))
        labels = rng.integers(0, problem.unary.shape[0], n)
        alpha = int(rng.integers(0, problem.unary.shape[0]))
        moved = expansion_move(problem, labels, alpha)
        assert set(np.flatnonzero(moved != labels)) <= set(np.flatnonzero(moved == alpha))
        assert energy(problem, moved) == pytest.approx(best_move_energy(problem, labels, alpha),
                                                       abs=1e-9)


@pytest.mark.parametrize('seed', range(10))
def test_moves_from_one_labelling_are_each_optimal(seed):
    # A sweep tries every label from one labelling with one Expansions: no move may disturb
    # what the next one starts from.
    rng = np.random.default_rng(100 + seed)
    for _ in range(5):
        n = int(rng.integers(2, 8))
        problem = random_problem(rng, n, int(rng.integers(2, 6)))
        problem = dataclasses.replace(problem, weights=problem.weights - 1.0, outlier_row=0,
                                      outlier_tie=0.3, outlier_apart=True)
        labels = rng.integers(0, problem.unary.shape[0], n)
        moves = Expansions(problem, labels)
        before = labels.copy()
        for alpha in rng.permutation(problem.unary.shape[0]):
            moved = moves.move(int(alpha))
            assert energy(problem, moved) <= energy(problem, labels) + 1e-9
            assert np.array_equal(moved, expansion_move(problem, labels, int(alpha)))
        assert np.array_equal(labels, before)


def test_expansion_to_an_unused_label_pays_its_label_cost():
    # Two points both cheaper under label 1 by 3 each; label 1 costs 10 to open: no move.
    unary = np.array([[5.0, 5.0], [2.0, 2.0]])
    problem = Problem(unary, np.empty((0, 2), dtype=np.int64), np.empty(0), np.array([0.0, 10.0]))
    labels = np.zeros(2, dtype=np.int64)
    assert np.array_equal(expansion_move(problem, labels, 1), labels)
    # Cheaper to open than the gain of 6: both switch.
    cheap = Problem(unary, problem.edges, problem.weights, np.array([0.0, 5.0]))
    assert np.array_equal(expansion_move(cheap, labels, 1), [1, 1])


def test_expansion_removes_a_label_whose_cost_outweighs_its_data_gain():
    # Point 1 is slightly better under label 2, but label 2 costs 4: expanding label 1 takes it.
    unary = np.array([[9.0, 9.0], [1.0, 2.0], [9.0, 1.0]])
    problem = Problem(unary, np.empty((0, 2), dtype=np.int64), np.empty(0),
                      np.array([0.0, 4.0, 4.0]))
    moved = expansion_move(problem, np.array([1, 2]), 1)
    assert np.array_equal(moved, [1, 1])


def test_smoothness_pulls_a_lone_point_to_its_neighbours_label():
    unary = np.array([[0.0, 0.0, 1.0], [1.0, 1.0, 0.0]])
    edges = np.array([[0, 2], [1, 2]])
    problem = Problem(unary, edges, np.array([2.0, 2.0]), np.zeros(2))
    moved = expansion_move(problem, np.array([1, 1, 1]), 0)
    assert np.array_equal(moved, [0, 0, 0])


def signed_move(rng: np.random.Generator, may_reward) -> tuple[Problem, np.ndarray, int]:
    """A random problem, labelling (point 0 labelled alpha) and alpha, where about half of the
    edges that ``may_reward(touches)`` allows get a negative weight; ``touches`` marks the
    edges with an end labelled alpha."""
    n = int(rng.integers(3, 9))
    base = random_problem(rng, n, int(rng.integers(2, 6)))
    labels = rng.integers(0, base.unary.shape[0], n)
    alpha = int(rng.integers(0, base.unary.shape[0]))
    labels[0] = alpha
    touches = (labels[base.edges[:, 0]] == alpha) | (labels[base.edges[:, 1]] == alpha)
    reward = may_reward(touches) & (rng.random(touches.size) < 0.5)
    return (Problem(base.unary, base.edges, np.where(reward, -base.weights, base.weights),
                    base.label_costs), labels, alpha)


@pytest.mark.parametrize('seed', range(20))
def test_with_rewards_for_cut_pairs_a_move_never_raises_the_energy(seed):
    # Negative weights reward cutting a pair; some of those terms cannot be cut exactly and are
    # truncated, so the move is no longer always optimal, but it never does worse than standing.
    rng = np.random.default_rng(100 + seed)
    for _ in range(10):
        problem, labels, alpha = signed_move(rng, lambda touches: np.ones(touches.size, bool))
        moved = expansion_move(problem, labels, alpha)
        assert set(np.flatnonzero(moved != labels)) <= set(np.flatnonzero(moved == alpha))
        assert energy(problem, moved) <= energy(problem, labels) + 1e-9


@pytest.mark.parametrize('seed', range(10))
def test_with_rewards_on_pairs_that_touch_alpha_the_move_is_still_optimal(seed):
    # A rewarded pair with an end already labelled alpha is exactly representable (modular):
    # the move must then match brute force.
    rng = np.random.default_rng(200 + seed)
    for _ in range(10):
        problem, labels, alpha = signed_move(rng, lambda touches: touches)
        moved = expansion_move(problem, labels, alpha)
        assert energy(problem, moved) == pytest.approx(best_move_energy(problem, labels, alpha),
                                                       abs=1e-9)


def test_a_reward_for_cutting_a_pair_lets_one_end_switch_alone():
    # Both points slightly prefer to stay; alpha is free. Without a reward neither moves; a
    # reward of 3 for cutting the pair pays for point 1 (the one that loses least) to switch.
    unary = np.array([[1.0, 1.0], [2.0, 1.5]])
    edges = np.array([[0, 1]])
    costs = np.zeros(2)
    labels = np.zeros(2, dtype=np.int64)
    assert np.array_equal(expansion_move(Problem(unary, edges, np.array([0.0]), costs),
                                         labels, 1), [0, 0])
    assert np.array_equal(expansion_move(Problem(unary, edges, np.array([-3.0]), costs),
                                         labels, 1), [0, 1])


@pytest.mark.parametrize('tie', [0.5, 0.8])
@pytest.mark.parametrize('seed', range(8))
def test_a_softer_outlier_tie_that_stays_metric_keeps_moves_optimal(seed, tie):
    # V(a, out) = tie w with tie >= 1/2 is a metric: every expansion move is a submodular cut.
    rng = np.random.default_rng(100 + seed)
    for _ in range(10):
        n = int(rng.integers(2, 9))
        base = random_problem(rng, n, int(rng.integers(2, 6)))
        problem = dataclasses.replace(base, outlier_row=0, outlier_tie=tie)
        labels = rng.integers(0, problem.unary.shape[0], n)
        alpha = int(rng.integers(0, problem.unary.shape[0]))
        moved = expansion_move(problem, labels, alpha)
        assert energy(problem, moved) == pytest.approx(best_move_energy(problem, labels, alpha),
                                                       abs=1e-9)


def falls_short(problem: Problem, labels: np.ndarray, alpha: int) -> bool:
    """Run one move with truncated pair terms: it must only switch points to ``alpha``, never
    raise the energy and never beat brute force. Whether it fell short of the best move."""
    moved = expansion_move(problem, labels, alpha)
    assert set(np.flatnonzero(moved != labels)) <= set(np.flatnonzero(moved == alpha))
    assert energy(problem, moved) <= energy(problem, labels) + 1e-9
    best = best_move_energy(problem, labels, alpha)
    assert energy(problem, moved) >= best - 1e-9
    return bool(energy(problem, moved) > best + 1e-9)


@pytest.mark.parametrize('seed', range(10))
def test_a_free_outlier_tie_never_makes_a_move_worse(seed):
    # Below 1/2 the outlier label's expansions break pairs of two motions at a saving the cut
    # cannot hold; those pairs are truncated, and the move is still never worse than staying.
    rng = np.random.default_rng(200 + seed)
    worse_than_best = 0
    for _ in range(10):
        n = int(rng.integers(2, 9))
        problem = dataclasses.replace(random_problem(rng, n, int(rng.integers(2, 6))),
                                      outlier_row=0, outlier_tie=float(rng.uniform(0, 0.5)))
        labels = rng.integers(0, problem.unary.shape[0], n)
        alpha = int(rng.integers(0, problem.unary.shape[0]))
        worse_than_best += falls_short(problem, labels, alpha)
    # Expansions of a motion label stay exact: only some outlier expansions fall short.
    assert worse_than_best <= 5


def test_a_pair_cut_next_to_an_outlier_pays_its_share_of_the_weight():
    unary = np.zeros((3, 3))
    edges = np.array([[0, 1], [1, 2]])
    problem = Problem(unary, edges, np.array([4.0, 6.0]), np.zeros(3), outlier_row=0,
                      outlier_tie=0.25)
    assert energy(problem, np.array([0, 1, 2])) == pytest.approx(0.25 * 4.0 + 6.0)
    assert energy(problem, np.array([1, 1, 0])) == pytest.approx(0.25 * 6.0)
    assert energy(problem, np.array([0, 0, 0])) == 0.0


def apart_problem(rng: np.random.Generator, n: int, num_labels: int,
                  rewards: bool) -> Problem:
    """A random problem whose row 0 is a free outlier label with ``outlier_apart``; with
    ``rewards``, about half of the weights are negative."""
    base = random_problem(rng, n, num_labels)
    weights = base.weights
    if rewards:
        weights = np.where(rng.random(weights.size) < 0.5, -weights, weights)
    costs = base.label_costs.copy()
    costs[0] = 0.0
    return dataclasses.replace(base, weights=weights, label_costs=costs, outlier_row=0,
                               outlier_apart=True)


@pytest.mark.parametrize('seed', range(10))
def test_with_outliers_apart_a_move_never_raises_the_energy_nor_beats_brute_force(seed):
    # Two outliers that move apart earn a reward when both switch to the outlier label (E11 is
    # not 0): the move must account for it. Truncated terms may leave it short of the best move,
    # never below it and never above standing still.
    rng = np.random.default_rng(300 + seed)
    short = 0
    for _ in range(10):
        n = int(rng.integers(3, 8))
        problem = apart_problem(rng, n, int(rng.integers(2, 5)), rewards=True)
        labels = rng.integers(0, problem.unary.shape[0], n)
        alpha = int(rng.integers(0, problem.unary.shape[0]))
        short += falls_short(problem, labels, alpha)
    assert short < 10


def test_with_only_alike_pairs_outliers_apart_changes_nothing():
    # The option only touches pairs with a negative weight: with none, moves are exact Potts.
    rng = np.random.default_rng(5)
    for _ in range(20):
        n = int(rng.integers(2, 7))
        problem = apart_problem(rng, n, 3, rewards=False)
        labels = rng.integers(0, 3, n)
        alpha = int(rng.integers(0, 3))
        moved = expansion_move(problem, labels, alpha)
        assert energy(problem, moved) == pytest.approx(best_move_energy(problem, labels, alpha),
                                                       abs=1e-9)


@pytest.mark.parametrize('seed', range(10))
def test_a_sweep_ends_where_no_expansion_of_a_label_in_use_lowers_the_energy(seed):
    # (An unused label is screened by a bound on its gain that leaves out the label costs its
    # move could free, so it may be left untried where its move would pay.)
    from pearl_ros.core.config import SolverSettings
    from pearl_ros.core.pearl import sweep

    rng = np.random.default_rng(seed)
    patient = SolverSettings(max_passes=1000, max_failed=10**6)
    for _ in range(5):
        n = int(rng.integers(3, 9))
        problem = random_problem(rng, n, int(rng.integers(2, 6)))
        start = rng.integers(0, problem.unary.shape[0], n)
        labels = sweep(problem, start, patient)
        assert energy(problem, labels) <= energy(problem, start) + 1e-9
        for alpha in np.unique(labels):
            assert best_move_energy(problem, labels, alpha) >= energy(problem, labels) - 1e-9


@pytest.mark.parametrize('seed', range(10))
def test_a_sweep_never_runs_one_move_twice_on_the_same_labelling(seed, monkeypatch):
    # A failed expansion fails again on the same labelling: a later pass must not rerun it.
    from pearl_ros.core import pearl

    runs: list[tuple[bytes, int]] = []
    real = Expansions.move

    def counted(self, alpha):
        runs.append((np.asarray(self.labels).tobytes(), alpha))
        return real(self, alpha)

    monkeypatch.setattr(Expansions, 'move', counted)
    rng = np.random.default_rng(seed)
    for _ in range(5):
        n = int(rng.integers(3, 9))
        problem = random_problem(rng, n, int(rng.integers(2, 6)))
        runs.clear()
        pearl.sweep(problem, rng.integers(0, problem.unary.shape[0], n))
        assert len(runs) == len(set(runs)) and runs
