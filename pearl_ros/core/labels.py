"""The label values every layer shares: one name and one value for the outlier label."""

from __future__ import annotations

import numpy as np

# The label of a point that belongs to no motion: an outlier of every model, and, in the online
# layer and the bags it writes, a feature without finite coordinates or not labelled yet.
# Motions are numbered 0, 1, ... Inside the optimiser the outlier is a row of the cost table,
# pearl.OUTLIER_ROW; no other value is ever called the outlier label.
OUTLIER = -1


def num_motions(labels: np.ndarray) -> int:
    """How many motions ``labels`` (N,) use: the distinct labels other than ``OUTLIER``."""
    labels = np.asarray(labels)
    return int(np.unique(labels[labels != OUTLIER]).size)
