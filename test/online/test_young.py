"""Young tracks labelled by the nearest motion subspace, against a one-motion-at-a-time SVD."""

from __future__ import annotations

import numpy as np
import pytest

from pearl_ros.online.segmenter import _nearest_subspace


def _brute_force(coords, age, fitted, fitted_labels, young):
    out = []
    for y in young:
        a = age[y]
        point = coords[-a:, y].reshape(-1)
        best, label = np.inf, -1
        for motion in np.unique(fitted_labels[fitted_labels >= 0]):
            members = fitted[fitted_labels == motion]
            if members.size < 5:
                continue
            rows = np.stack([coords[-a:, m].reshape(-1) for m in members])
            mean = rows.mean(axis=0)
            _, _, vt = np.linalg.svd(rows - mean, full_matrices=False)
            basis = vt[: min(3, 2 * a - 1)].T
            offset = point - mean
            distance = np.linalg.norm(offset - basis @ (basis.T @ offset))
            if distance < best:
                best, label = distance, motion
        out.append(label)
    return np.array(out, dtype=np.int64)


@pytest.mark.parametrize('seed', range(8))
def test_nearest_subspace_matches_a_per_track_svd(seed):
    rng = np.random.default_rng(seed)
    frames, n = 8, 60
    coords = rng.normal(0, 50, (frames, n, 2))
    age = rng.integers(2, frames + 1, n)
    age[:20] = frames  # enough fitted tracks for three motions
    for i, a in enumerate(age):
        coords[: frames - a, i] = np.nan  # born a frames before the end
    fitted = np.flatnonzero(age == frames)
    young = np.flatnonzero(age < frames)
    labels = rng.integers(-1, 3, fitted.size)
    labels[:15] = np.repeat([0, 1, 2], 5)  # every motion has enough members
    np.testing.assert_array_equal(_nearest_subspace(coords, age, fitted, labels, young),
                                  _brute_force(coords, age, fitted, labels, young))


def test_a_motion_with_too_few_members_is_not_offered():
    rng = np.random.default_rng(0)
    coords = rng.normal(0, 10, (4, 12, 2))
    age = np.array([4] * 10 + [3, 2])
    coords[:1, 10] = np.nan
    coords[:2, 11] = np.nan
    fitted = np.arange(10)
    labels = np.array([7] * 4 + [-1] * 6)  # motion 7 has 4 members: fewer than 5
    out = _nearest_subspace(coords, age, fitted, labels, np.array([10, 11]))
    np.testing.assert_array_equal(out, [-1, -1])
