"""AdelaideRMF two-view pairs (Wong, Chin, Yu & Suter, ICCV 2011): keypoint matches between two
shots of several objects moved between them, hand-labelled; label 0 marks a gross mismatch.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.io
from scipy.io.matlab import MatReadError

from pearl_ros.core.errors import InputError, one_line
from pearl_ros.core.labels import OUTLIER, num_motions
from pearl_ros.datasets._files import data_files


@dataclass(frozen=True)
class Pair:
    """One AdelaideRMF pair.

    Attributes
    ----------
    name : str
    tracks : (2, N, 2) float64, pixels of each match in the first and second image
    labels : (N,) int64, motion 0..k-1, or ``OUTLIER`` (-1) for a mismatch
    """

    name: str
    tracks: np.ndarray
    labels: np.ndarray

    @property
    def num_motions(self) -> int:
        return num_motions(self.labels)

    @property
    def outlier_share(self) -> float:
        return float(np.mean(self.labels == OUTLIER))


def load_pair(path: str | Path) -> Pair:
    """Read one pair file (``data`` (6, N) = x1, y1, 1, x2, y2, 1; ``label`` (1, N))."""
    path = Path(path)
    try:
        mat = scipy.io.loadmat(str(path), variable_names=('data', 'label'))
        data = np.asarray(mat['data'], dtype=np.float64)
        label = np.asarray(mat['label']).ravel().astype(np.int64)
    except (OSError, ValueError, KeyError, MatReadError) as err:
        raise InputError(f'cannot read AdelaideRMF pair {path}: {one_line(err)}') from err
    if data.ndim != 2 or data.shape[0] != 6 or label.size != data.shape[1]:
        raise InputError(f'{path}: data must be 6 x N with N labels, got {data.shape} and '
                         f'{label.size} labels')
    tracks = np.stack([data[0:2].T / data[2][:, None], data[3:5].T / data[5][:, None]])
    # Motions 1..k become 0..k-1 in order; 0 (a mismatch) becomes OUTLIER.
    motions = np.unique(label[label > 0])
    labels = np.full(label.size, OUTLIER, dtype=np.int64)
    labels[label > 0] = np.searchsorted(motions, label[label > 0])
    return Pair(path.stem, tracks, labels)


def pair_paths(root: str | Path) -> list[Path]:
    """The pair files under ``root``, sorted by name; InputError if there are none."""
    return data_files(root, '*.mat', 'AdelaideRMF', 'pairs')
