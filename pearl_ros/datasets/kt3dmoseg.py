"""KT3DMoSeg clips (Xu, Cheong & Li, CVPR 2018): KITTI driving, partial tracks, ``*_Tracks.mat``.

Each clip is a forward-moving car camera with other cars moving; tracks start and end within the
clip. The labelled ("sparse") tracks are the scored points; ``GtLabel`` 1 is mostly the
background. The usual two-frame protocol takes the first and the last frame and the points
visible in both.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.io
from scipy.io.matlab import MatReadError

from pearl_ros.core.errors import InputError, one_line
from pearl_ros.datasets._files import data_files


@dataclass(frozen=True)
class Clip:
    """One KT3DMoSeg clip's labelled tracks.

    Attributes
    ----------
    name : str
    tracks : (F, P, 2) float64, pixels; NaN where the point is not tracked
    visible : (F, P) bool
    labels : (P,) int64, ground-truth motion 0..k-1 (0 is mostly the background)
    """

    name: str
    tracks: np.ndarray
    visible: np.ndarray
    labels: np.ndarray

    @property
    def num_motions(self) -> int:
        return int(np.unique(self.labels).size)

    def two_frames(self) -> tuple[np.ndarray, np.ndarray]:
        """Tracks ``(2, M, 2)`` of the first and last frame for the M points seen in both, and
        their labels ``(M,)``."""
        both = self.visible[0] & self.visible[-1]
        return self.tracks[[0, -1]][:, both], self.labels[both]

    def complete(self) -> tuple[np.ndarray, np.ndarray]:
        """Tracks ``(F, M, 2)`` of the M points seen in every frame, and their labels."""
        every = self.visible.all(axis=0)
        return self.tracks[:, every], self.labels[every]

    def frames(self) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Per frame, as a tracker publishes it: ids ``(n,)`` (the point index), pixels
        ``(n, 2)`` and the true motion ``(n,)`` of the points tracked in that frame."""
        for t in range(self.tracks.shape[0]):
            ids = np.flatnonzero(self.visible[t])
            yield ids.astype(np.int64), self.tracks[t, ids], self.labels[ids]


def load_clip(path: str | Path) -> Clip:
    """Read one ``SeqNNN_ClipMM_Tracks.mat`` file (struct ``Data``: ``ySparse`` (3, P, F),
    ``visibleSparse`` (P, F), ``GtLabel`` (P,))."""
    path = Path(path)
    try:
        data = scipy.io.loadmat(str(path), squeeze_me=True, struct_as_record=False)['Data']
        y = np.asarray(data.ySparse, dtype=np.float64)
        visible = np.asarray(data.visibleSparse).astype(bool).T
        groups = np.asarray(data.GtLabel).ravel().astype(np.int64)
    except (OSError, ValueError, KeyError, AttributeError, MatReadError) as err:
        raise InputError(f'cannot read KT3DMoSeg clip {path}: {one_line(err)}') from err
    if y.ndim != 3 or y.shape[0] != 3 or visible.shape != (y.shape[2], y.shape[1]):
        raise InputError(f'{path}: ySparse must be 3 x P x F and visibleSparse P x F, got '
                         f'{y.shape} and {visible.T.shape}')
    with np.errstate(divide='ignore', invalid='ignore'):
        tracks = np.transpose(y[:2] / y[2:3], (2, 1, 0))
    tracks[~visible] = np.nan
    _, labels = np.unique(groups, return_inverse=True)
    return Clip(path.name.removesuffix('_Tracks.mat'), tracks, visible, labels.astype(np.int64))


def clip_paths(root: str | Path) -> list[Path]:
    """The clip files under ``root``, sorted by name; InputError if there are none."""
    return data_files(root, '*_Tracks.mat', 'KT3DMoSeg', 'clips')
