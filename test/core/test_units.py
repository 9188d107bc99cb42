"""A fit does not depend on the pixel unit or the image origin where the noise floor does not bind.

Every cost of the energy is measured in noise levels, and the noise scale is estimated from the
tracks: zooming the tracks by a factor (another image resolution) and moving their origin
changes no label, and every noise level and the scale by the same factor. The one quantity in
pixels is the floor of the scale, ``PearlConfig.min_noise``; the scenes here are noisier than
it by three times or more, zoomed or not.
"""

from __future__ import annotations

import numpy as np
import pytest

from pearl_ros.core.config import PearlConfig
from pearl_ros.core.labels import OUTLIER
from pearl_ros.core.pearl import fit

ZOOM, SHIFT = 2.5, np.array([1500.0, -700.0])


def _same_partition(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether labellings ``a`` and ``b`` put the same points together and the same ones out."""
    if not np.array_equal(a == OUTLIER, b == OUTLIER):
        return False
    pairs = {(int(x), int(y)) for x, y in zip(a, b, strict=True)}
    return len(pairs) == len({x for x, _ in pairs}) == len({y for _, y in pairs})


def _two_view_with_mismatches(affine_scene, seed: int) -> np.ndarray:
    tracks, _ = affine_scene(sizes=(120, 90), noise=0.3, seed=seed)
    tracks = tracks[[0, -1]].copy()
    rng = np.random.default_rng(seed)
    bad = rng.random(tracks.shape[1]) < 0.25
    low, high = tracks.reshape(-1, 2).min(axis=0), tracks.reshape(-1, 2).max(axis=0)
    tracks[1, bad] = rng.uniform(low, high, (int(bad.sum()), 2))
    return tracks


@pytest.mark.parametrize('model,seed', [('affine', 3), ('affine', 4), ('fundamental', 0),
                                        ('fundamental', 1), ('homography', 2)])
def test_a_fit_is_the_same_in_any_pixel_unit_and_origin(affine_scene, model, seed):
    if model == 'affine':
        tracks, _ = affine_scene(sizes=(200, 150, 120), noise=0.5, seed=seed)
    elif model == 'fundamental':
        tracks = _two_view_with_mismatches(affine_scene, seed)
    else:
        tracks = affine_scene(sizes=(120, 90), noise=0.3, seed=seed)[0][[0, -1]]
    config = PearlConfig(model=model)
    plain = fit(tracks, config, rng=0)
    zoomed = fit(tracks * ZOOM + SHIFT, config, rng=0)
    assert plain.scale > 3 * config.min_noise
    assert _same_partition(plain.labels, zoomed.labels)
    assert zoomed.scale == pytest.approx(ZOOM * plain.scale, rel=1e-6)
    assert np.allclose(np.sort(zoomed.sigmas), ZOOM * np.sort(plain.sigmas), rtol=1e-6)
    assert zoomed.energy == pytest.approx(plain.energy, rel=1e-6)


def test_the_partition_oracle_tells_labellings_apart():
    labels = np.array([0, 0, 1, 1, OUTLIER])
    assert _same_partition(labels, np.array([5, 5, 2, 2, OUTLIER]))
    assert not _same_partition(labels, np.array([0, 1, 1, 1, OUTLIER]))
    assert not _same_partition(labels, np.array([0, 0, 1, 1, 1]))
    assert not _same_partition(labels, np.array([0, 0, 0, 0, OUTLIER]))
