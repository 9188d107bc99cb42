"""Alpha-expansion with Potts smoothness and label costs.

After Delong, Osokin, Isack & Boykov, IJCV 2012.

One move lets every point either keep its label or switch to ``alpha``; the optimal move is a
minimum s-t cut. Side convention, used throughout: a node on the SINK side has x = 1, "switch to
alpha"; so the source capacity of a node is its cost of switching and the sink capacity its cost
of keeping (a cut pays the s-link of a sink-side node and the t-link of a source-side node).
"""

from __future__ import annotations

import maxflow
import numpy as np

from pearl_ros.core.energy import Problem, pair_costs


def expansion_move(problem: Problem, labels: np.ndarray, alpha: int) -> np.ndarray:
    """The labelling of least energy among those one alpha-expansion away from ``labels``.

    With a negative Potts weight (a reward for cutting the pair) some pair terms of the move are
    not submodular and no graph cut represents them. They are truncated (Rother, Kumar,
    Kolmogorov & Blake, "Digital tapestry", CVPR 2005): the move is then optimal for an upper
    bound of the energy that is exact at ``labels``, so it is never worse than keeping
    ``labels``. Several moves from one labelling: :class:`Expansions`.
    """
    return Expansions(problem, labels).move(alpha)


class Expansions:
    """Alpha-expansion moves of ``problem`` from one labelling ``labels`` (N,).

    What a move needs of the labelling alone (each point's cost as it is, each edge's pair term
    as it is, the members of each label that pays a cost) is worked out once: a sweep tries
    every label from one labelling, and most of its moves fail and leave it as it was.
    """

    def __init__(self, problem: Problem, labels: np.ndarray) -> None:
        self.problem, self.labels = problem, labels
        n = labels.size
        self._keep_cost = problem.unary[labels, np.arange(n)]
        p, q = problem.edges[:, 0], problem.edges[:, 1]
        self._ends = labels[p], labels[q]
        self._e00 = pair_costs(problem, *self._ends)
        costs = problem.label_costs
        used = np.unique(labels)
        self._paid = used[costs[used] > 0]
        order = np.argsort(labels, kind='stable')
        starts = np.searchsorted(labels[order], self._paid)
        ends = np.searchsorted(labels[order], self._paid, side='right')
        self._members = [order[s:e] for s, e in zip(starts, ends, strict=True)]
        self.used = np.zeros(costs.size, dtype=bool)  # (L,) the labels the labelling uses
        self.used[used] = True

    def move(self, alpha: int) -> np.ndarray:
        """The labelling of least energy one ``alpha``-expansion away (:func:`expansion_move`)."""
        problem, labels = self.problem, self.labels
        n = labels.size
        cost_keep = self._keep_cost
        cost_switch = problem.unary[alpha].astype(np.float64, copy=True)
        src = cost_switch  # paid when x_p = 1
        snk = cost_keep.copy()  # paid when x_p = 0

        # Pairwise Potts terms
        #   E(x_p, x_q) = A + (C - A) x_p + (D - C) x_q + (B + C - A - D)(1 - x_p) x_q
        # with A = E00, B = E01, C = E10, D = E11 (Kolmogorov & Zabih 2004). D is 0 under Potts;
        # a pair of outliers that move apart earns its reward (Problem.outlier_apart), so D is
        # not 0 when alpha is the outlier label.
        p, q = problem.edges[:, 0], problem.edges[:, 1]
        # A negative weight, or a pair cut with the outlier label paying less than half its
        # weight (Problem.outlier_tie), can make the term non-submodular (pair < 0 below). Such
        # an edge is truncated: its pair term is left out, which overstates the cost of "p
        # keeps, q switches" by -pair and leaves the three other cases exact. So that the case
        # kept exact is the likelier one, p is made the end that gains more by switching.
        # Both keep (E00), only the second end switches (E01), only the first (E10), both (E11).
        to_alpha = np.int64(alpha)
        e00 = self._e00
        e01 = pair_costs(problem, self._ends[0], to_alpha)
        e10 = pair_costs(problem, to_alpha, self._ends[1])
        e11 = pair_costs(problem, to_alpha, to_alpha)
        risky = e01 + e10 - e00 - e11 < 0
        gain = cost_keep - cost_switch
        flip = risky & (gain[q] > gain[p])
        p, q = np.where(flip, q, p), np.where(flip, p, q)
        e01, e10 = np.where(flip, e10, e01), np.where(flip, e01, e10)  # V is symmetric
        _add_unary(src, snk, p, e10 - e00)
        _add_unary(src, snk, q, e11 - e10)
        pair = e01 + e10 - e00 - e11  # >= 0 but on truncated edges: the move is submodular

        # Label costs. A used label l != alpha is paid unless all its points switch: an
        # auxiliary node y_l that can sit on the sink side ("l is gone", no cost) only if every
        # point of l does. An unused alpha is paid once any point switches: an auxiliary z on
        # the sink side ("alpha is used") that every switching point drags along.
        costs = problem.label_costs
        others = self._paid != alpha
        paid = self._paid[others]
        members = [m for m, other in zip(self._members, others, strict=True) if other]
        new_alpha = costs[alpha] > 0 and not self.used[alpha]
        num_aux = paid.size + int(new_alpha)
        # Stands for infinity: more than all finite capacities of the graph together (not every
        # proposal's data costs, whose sum took a tenth of a move's time).
        big = float(src.sum() + snk.sum() + np.abs(pair).sum() + costs[paid].sum()
                    + costs[alpha] + 1.0)
        num_edges = p.size + sum(m.size for m in members) + (n if new_alpha else 0)

        graph = maxflow.Graph[float](n + num_aux, num_edges)
        nodes = graph.add_nodes(n + num_aux)
        keep = pair > 0
        graph.add_edges(nodes[p[keep]], nodes[q[keep]], pair[keep], np.zeros(int(keep.sum())))
        aux_src = np.zeros(num_aux)
        aux_snk = np.zeros(num_aux)
        for k, (label, pts) in enumerate(zip(paid, members, strict=True)):
            aux_snk[k] = costs[label]
            # x_p = 0 (source side) with y_l = 1 (sink side) would cut p -> y_l: forbidden.
            graph.add_edges(pts, np.full(pts.size, n + k), np.full(pts.size, big),
                            np.zeros(pts.size))
        if new_alpha:
            z = n + num_aux - 1
            aux_src[-1] = costs[alpha]
            # z = 0 (source side) with x_p = 1 (sink side) would cut z -> p: forbidden.
            graph.add_edges(np.full(n, z), nodes[:n], np.full(n, big), np.zeros(n))
        graph.add_grid_tedges(nodes, np.concatenate([src, aux_src]),
                              np.concatenate([snk, aux_snk]))
        graph.maxflow()
        switch = graph.get_grid_segments(nodes[:n])
        return np.where(switch, alpha, labels)


def _add_unary(src: np.ndarray, snk: np.ndarray, nodes: np.ndarray, coef: np.ndarray) -> None:
    """Add ``coef * x`` for each node: positive to the switch cost, negative to the keep cost.

    ``u x = u`` paid at x = 1 when u >= 0; for u < 0, ``u x = u + |u| (1 - x)``, and the constant
    ``u`` shifts every labelling alike, so it is dropped.
    """
    n = src.size
    src += np.bincount(nodes, weights=np.maximum(coef, 0.0), minlength=n)
    snk += np.bincount(nodes, weights=np.maximum(-coef, 0.0), minlength=n)
