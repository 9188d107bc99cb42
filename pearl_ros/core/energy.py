"""The PEaRL energy, kept apart from its optimiser so that "it never goes up" can be tested.

    E(f) = sum_p D_p(f_p) + sum_{(p,q) in N} w_pq [f_p != f_q] + sum_{l in f} h_l

(Isack & Boykov, IJCV 2012, eq. 1; label costs h after Delong et al., IJCV 2012). Labels are
rows of the unary table ``unary`` (L, N); the weights ``w`` already hold the smoothness factor
lambda.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Problem:
    """A labelling problem.

    Attributes
    ----------
    unary : (L, N) float64, cost of giving point p label l (>= 0)
    edges : (E, 2) int, neighbour pairs
    weights : (E,) float64, Potts weight of each pair, lambda included; a negative weight
        rewards cutting the pair (:func:`pearl_ros.core.expansion.expansion_move` truncates it)
    label_costs : (L,) float64, cost of each label in use (>= 0)
    outlier_row : int, the row of the outlier label, or -1 for none
    outlier_tie : float in [0, 1], the share of its weight a pair pays when it is cut with one
        end on the outlier row (1: plain Potts). Below 1/2 the term is no longer a metric, and
        expansions of the outlier label truncate the pairs it breaks.
    outlier_apart : bool, an outlier earns the reward of a pair with a negative weight whatever
        its neighbour's label, another outlier's included: outliers are not one motion whose
        members should stay together, and the reward of a point that moves unlike its
        neighbours should not need a model of its own to collect.
    """

    unary: np.ndarray
    edges: np.ndarray
    weights: np.ndarray
    label_costs: np.ndarray
    outlier_row: int = -1
    outlier_tie: float = 1.0
    outlier_apart: bool = False

    @property
    def num_points(self) -> int:
        return int(self.unary.shape[1])


def pair_costs(problem: Problem, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The pair term of every edge, ``(E,)``, when its two ends hold labels ``a`` and ``b``."""
    cost: np.ndarray = problem.weights * (a != b)
    if problem.outlier_tie == 1.0 and not problem.outlier_apart:
        return cost
    touches = (a == problem.outlier_row) | (b == problem.outlier_row)
    cost = np.where(touches, problem.outlier_tie * cost, cost)
    if problem.outlier_apart:
        cost = np.where(touches & (problem.weights < 0), problem.weights, cost)
    return cost


def energy(problem: Problem, labels: np.ndarray) -> float:
    """E(f) of ``labels`` (N,) int, indices into the rows of ``problem.unary``."""
    data = problem.unary[labels, np.arange(labels.size)].sum()
    p, q = problem.edges[:, 0], problem.edges[:, 1]
    if problem.outlier_tie == 1.0 and not problem.outlier_apart:  # plain Potts: cut edges
        smooth = problem.weights[labels[p] != labels[q]].sum()
    else:
        smooth = pair_costs(problem, labels[p], labels[q]).sum()
    # The labels in use, in increasing order as np.unique gives them (a tenth of the cost).
    in_use = np.bincount(labels, minlength=problem.label_costs.size) > 0
    return float(data + smooth + problem.label_costs[in_use].sum())
