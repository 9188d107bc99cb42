"""Segmentation quality against ground truth: the misclassification rate of Hopkins155.

The misclassification rate (Tron & Vidal, CVPR 2007) is the share of points whose label is wrong
after predicted labels are matched one-to-one to true groups so as to agree on the most points.
A method that finds the number of motions itself, as PEaRL does (Isack & Boykov, IJCV 2012), may
return more or fewer groups than there are: predicted groups left without a partner are wrong,
and so are points it calls outliers (label ``-1``), unless the ground truth says outlier too.
The best matching is a linear assignment on the contingency table (Hungarian method).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from scipy.optimize import linear_sum_assignment

from pearl_ros.core.errors import InputError
from pearl_ros.core.labels import OUTLIER


def _as_labels(values: object, name: str) -> np.ndarray:
    """``values`` as a 1-D int64 array of labels >= -1, or InputError naming ``name``."""
    array = np.asarray(values)
    if array.ndim != 1:
        raise InputError(f'{name} must be a 1-D array of labels, got shape {array.shape}')
    if array.size and not (
        np.issubdtype(array.dtype, np.integer) or np.issubdtype(array.dtype, np.bool_)
    ):
        raise InputError(f'{name} must hold integer labels, got dtype {array.dtype}')
    array = array.astype(np.int64)
    if array.size and array.min() < OUTLIER:
        raise InputError(f'{name} labels must be >= {OUTLIER}, got {int(array.min())}')
    return array


def _check_pair(pred: object, truth: object) -> tuple[np.ndarray, np.ndarray]:
    pred_a = _as_labels(pred, 'pred')
    truth_a = _as_labels(truth, 'truth')
    if pred_a.shape != truth_a.shape:
        raise InputError(
            f'pred and truth must label the same points, '
            f'got {pred_a.size} and {truth_a.size} labels'
        )
    return pred_a, truth_a


def contingency(pred: object, truth: object) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Count the points shared by each predicted group and each true group.

    Outliers (label ``-1``) on either side have no row or column.

    Parameters
    ----------
    pred : (N,) int
        Predicted labels, ``-1`` for outliers.
    truth : (N,) int
        True group labels, ``-1`` for true outliers.

    Returns
    -------
    table : (Kp, Kt) int64
        ``table[i, j]`` = number of points with ``pred == pred_labels[i]`` and
        ``truth == true_labels[j]``.
    pred_labels : (Kp,) int64
        The distinct predicted labels other than ``-1``, sorted.
    true_labels : (Kt,) int64
        The distinct true labels other than ``-1``, sorted.

    Raises
    ------
    InputError
        If the inputs are not 1-D integer arrays of the same length with labels >= -1.
    """
    pred_a, truth_a = _check_pair(pred, truth)
    pred_labels, pred_idx = np.unique(pred_a, return_inverse=True)
    true_labels, true_idx = np.unique(truth_a, return_inverse=True)
    table = np.zeros((pred_labels.size, true_labels.size), dtype=np.int64)
    np.add.at(table, (pred_idx.ravel(), true_idx.ravel()), 1)
    keep_rows = pred_labels != OUTLIER
    keep_cols = true_labels != OUTLIER
    return table[keep_rows][:, keep_cols], pred_labels[keep_rows], true_labels[keep_cols]


def _matching(pred: object, truth: object) -> list[tuple[int, int, int]]:
    """The one-to-one matching of predicted to true labels that agrees on the most points (the
    Hungarian method on :func:`contingency`): ``(predicted label, true label, points they
    share)`` per matched pair. The solver pairs every label it can, so a pair may share none."""
    table, pred_labels, true_labels = contingency(pred, truth)
    if table.size == 0:
        return []
    rows, cols = linear_sum_assignment(table, maximize=True)
    return [(int(pred_labels[r]), int(true_labels[c]), int(table[r, c]))
            for r, c in zip(rows, cols, strict=True)]


def match_labels(pred: object, truth: object) -> dict[int, int]:
    """The one-to-one matching of predicted to true labels that agrees on the most points.

    Returns
    -------
    dict
        Predicted label -> true label, for the matched predicted labels only (at most as many as
        there are true groups). Ties are broken by the assignment solver, deterministically.
    """
    return {label: motion for label, motion, _ in _matching(pred, truth)}


def relabel_to_truth(pred: object, truth: object) -> np.ndarray:
    """Predicted labels renamed to their matched true labels, for side-by-side display.

    Unmatched predicted groups get fresh labels above the largest true label, in order of their
    original label; outliers stay ``-1``.

    Returns
    -------
    (N,) int64
    """
    pred_a, truth_a = _check_pair(pred, truth)
    mapping = match_labels(pred_a, truth_a)
    fresh = int(max(truth_a.max(initial=OUTLIER), max(mapping.values(), default=OUTLIER))) + 1
    for label in np.unique(pred_a):
        if label != OUTLIER and int(label) not in mapping:
            mapping[int(label)] = fresh
            fresh += 1
    mapping[OUTLIER] = OUTLIER
    out = np.empty_like(pred_a)
    for source, target in mapping.items():
        out[pred_a == source] = target
    return out


def misclassification(pred: object, truth: object) -> float:
    """The share of points labelled wrongly under the best one-to-one matching of labels.

    A point is right when its predicted group is matched to its true group, or when both labels
    are ``-1``. Predicted outliers of true groups, and points of predicted groups that found no
    partner (there are more predicted groups than true ones), are wrong.

    Parameters
    ----------
    pred : (N,) int
        Predicted labels, ``-1`` for outliers, any non-negative values otherwise.
    truth : (N,) int
        True group labels, ``-1`` for true outliers.

    Returns
    -------
    float
        Misclassification rate in [0, 1] (multiply by 100 for the percentages of Hopkins155).

    Raises
    ------
    InputError
        If the inputs are not 1-D integer arrays of the same non-zero length with labels >= -1.
    """
    pred_a, truth_a = _check_pair(pred, truth)
    if pred_a.size == 0:
        raise InputError('pred and truth must label at least one point')
    matched = sum(shared for _, _, shared in _matching(pred_a, truth_a))
    matched += int(np.count_nonzero((pred_a == OUTLIER) & (truth_a == OUTLIER)))
    return 1.0 - matched / pred_a.size


def identities(pred: object, truth: object) -> dict[int, int]:
    """True motion -> the predicted label matched to it one-to-one, as :func:`misclassification`
    matches them; a pair that shares no point is left out (the matching pairs every label it
    can, and a true motion whose points are all ``-1`` has no label of its own)."""
    return {motion: label for label, motion, shared in _matching(pred, truth) if shared}


class LabelIdentity:
    """How steadily a stream's motion numbers follow the true motions, frame after frame.

    A user of an online segmenter reads a motion's number as its identity (the car ahead is
    motion 3 while it is in view), so a number that changes while the motion goes on is an error
    that the per-frame misclassification does not see: it matches labels anew on every frame.
    Each frame (:meth:`add`), numbers are matched one-to-one to true motions as
    :func:`misclassification` matches them; a true motion's *switch* is a frame where it is
    matched to another number than the last one it was matched to, however many frames ago
    (:func:`identities`; the identity switches of the CLEAR MOT metrics, Bernardin &
    Stiefelhagen 2008). A motion merged into another is unmatched while merged, not switched:
    if it comes out of the merge under its old number, nothing is counted, under a new one, one
    switch. True outliers (``-1``) carry no identity.

    Attributes
    ----------
    frames : int, frames added
    matched : int, true motions matched to a number, summed over the frames
    switches : int
    """

    def __init__(self) -> None:
        self.frames = 0
        self.matched = 0
        self.switches = 0
        self._last: dict[int, int] = {}  # true motion -> the number it was last matched to

    def add(self, pred: object, truth: object) -> None:
        """Count one frame's labels ``pred`` against its true labels ``truth`` (both (N,))."""
        self.count(identities(pred, truth))

    def count(self, matched: Mapping[int, int]) -> None:
        """Count one frame from its :func:`identities` (true motion -> number)."""
        for motion, number in matched.items():
            last = self._last.get(motion)
            self.switches += last is not None and last != number
            self._last[motion] = number
            self.matched += 1
        self.frames += 1

    @property
    def switches_per_100(self) -> float:
        """Switches per 100 frames (NaN before the first frame)."""
        return 100.0 * self.switches / self.frames if self.frames else float('nan')
