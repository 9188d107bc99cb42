"""Hopkins155 sequences (Tron & Vidal, CVPR 2007): ``<name>/<name>_truth.mat`` files."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.io
from scipy.io.matlab import MatReadError

from pearl_ros.core.errors import InputError, one_line
from pearl_ros.datasets._files import data_files

# Articulated / non-rigid sequences, by the grouping of the Hopkins155 README.
_ARTICULATED = ('arm', 'articulated', 'people', 'kanatani3', 'head', 'two_cranes', 'dancing')
_TRAFFIC = ('cars', 'truck', 'kanatani1', 'kanatani2')


@dataclass(frozen=True)
class Sequence:
    """One Hopkins-format sequence.

    Attributes
    ----------
    name : str
    tracks : (F, P, 2) float64, pixels
    labels : (P,) int64, ground-truth group 0..k-1
    width, height : int, pixels
    """

    name: str
    tracks: np.ndarray
    labels: np.ndarray
    width: int
    height: int

    @property
    def num_motions(self) -> int:
        return int(self.labels.max()) + 1

    @property
    def category(self) -> str:
        """``'checkerboard'``, ``'traffic'`` or ``'articulated'`` (Hopkins155 README)."""
        return category(self.name)


def category(name: str) -> str:
    """The Hopkins155 category of a sequence name."""
    base = name.lower()
    if base.startswith(_ARTICULATED):
        return 'articulated'
    if base.startswith(_TRAFFIC):
        return 'traffic'
    return 'checkerboard'


def load_mat(path: str | Path, name: str | None = None) -> Sequence:
    """Read one ``*_truth.mat`` file (fields ``y`` (3, P, F), ``s`` (P, 1), ``width``,
    ``height``)."""
    path = Path(path)
    try:
        mat = scipy.io.loadmat(str(path))
    except (OSError, ValueError, MatReadError) as err:
        raise InputError(f'cannot read Hopkins .mat file {path}: {one_line(err)}') from err
    missing = [key for key in ('y', 's') if key not in mat]
    if missing:
        raise InputError(f'{path} is not a Hopkins truth file: missing field(s) {missing}')
    y = np.asarray(mat['y'], dtype=np.float64)
    if y.ndim != 3 or y.shape[0] != 3:
        raise InputError(f'{path}: field y must be 3 x P x F, got {y.shape}')
    tracks = np.transpose(y[:2] / y[2:3], (2, 1, 0))  # (F, P, 2)
    groups = np.asarray(mat['s']).ravel().astype(np.int64)
    _, labels = np.unique(groups, return_inverse=True)
    width = int(np.asarray(mat.get('width', [[0]])).ravel()[0])
    height = int(np.asarray(mat.get('height', [[0]])).ravel()[0])
    if name is None:
        name = path.name.removesuffix('_truth.mat')
    return Sequence(name, tracks, labels.astype(np.int64), width, height)


def load_sequence(root: str | Path, name: str) -> Sequence:
    """Read sequence ``name`` from the Hopkins155 folder ``root``."""
    return load_mat(Path(root) / name / f'{name}_truth.mat', name)


def sequence_names(root: str | Path, include_dancing: bool = False) -> list[str]:
    """Names of the sequences under ``root``, sorted; ``dancing`` is left out by convention."""
    files = data_files(root, '*/*_truth.mat', 'Hopkins155', 'sequences')
    names = sorted(path.parent.name for path in files)
    if not include_dancing:
        names = [n for n in names if n != 'dancing']
    return names
