"""Young features' labels by neighbour vote, against a brute-force count."""

from __future__ import annotations

import numpy as np
import pytest

from pearl_ros.online.segmenter import _vote


def _brute_force(uv, fitted, fitted_labels, young, k):
    labelled = [(int(p), int(lab)) for p, lab in zip(fitted, fitted_labels, strict=True)
                if lab != -1]
    out = []
    for y in young:
        if not labelled:
            out.append(-1)
            continue
        ranked = sorted(labelled, key=lambda item: np.linalg.norm(uv[item[0]] - uv[y]))
        near = [lab for _, lab in ranked[:k]]
        best = max(near.count(lab) for lab in near)
        out.append(next(lab for lab in near if near.count(lab) == best))  # nearest on a tie
    return np.array(out, dtype=np.int64)


@pytest.mark.parametrize('seed', range(20))
def test_vote_takes_the_most_common_neighbour_label_nearest_first_on_ties(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(3, 40))
    uv = rng.uniform(0, 100, (n, 2))  # distinct distances almost surely
    order = rng.permutation(n)
    cut = int(rng.integers(1, n))
    fitted, young = np.sort(order[:cut]), np.sort(order[cut:])
    labels = rng.integers(-1, 3, fitted.size)  # few labels: ties are common
    k = int(rng.integers(1, 7))
    np.testing.assert_array_equal(_vote(uv, fitted, labels, young, k),
                                  _brute_force(uv, fitted, labels, young, k))


def test_vote_without_labelled_neighbours_leaves_features_unlabelled():
    uv = np.arange(10.0).reshape(5, 2)
    out = _vote(uv, np.array([0, 1]), np.array([-1, -1]), np.array([2, 3, 4]), 3)
    np.testing.assert_array_equal(out, [-1, -1, -1])
