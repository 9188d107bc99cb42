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


@pytest.mark.parametrize('model,seed', [('affine', 3), ('affine', 4), ('fundamental', 0),
                                        ('fundamental', 1), ('homography', 2)])
def test_a_fit_is_the_same_in_any_pixel_unit_and_origin(affine_scene, two_view_scene,
                                                        same_partition, model, seed):
    if model == 'affine':
        tracks, _ = affine_scene(sizes=(200, 150, 120), noise=0.5, seed=seed)
    else:  # a quarter of the points mismatched for fundamental matrices, none for homographies
        tracks, _ = two_view_scene(seed, mismatches=0.25 if model == 'fundamental' else 0.0)
    config = PearlConfig(model=model)
    plain = fit(tracks, config, rng=0)
    zoomed = fit(tracks * ZOOM + SHIFT, config, rng=0)
    assert plain.scale > 3 * config.min_noise
    assert same_partition(plain.labels, zoomed.labels)
    assert zoomed.scale == pytest.approx(ZOOM * plain.scale, rel=1e-6)
    assert np.allclose(np.sort(zoomed.sigmas), ZOOM * np.sort(plain.sigmas), rtol=1e-6)
    assert zoomed.energy == pytest.approx(plain.energy, rel=1e-6)


def test_the_partition_oracle_tells_labellings_apart(same_partition):
    labels = np.array([0, 0, 1, 1, OUTLIER])
    assert same_partition(labels, np.array([5, 5, 2, 2, OUTLIER]))
    assert not same_partition(labels, np.array([0, 1, 1, 1, OUTLIER]))
    assert not same_partition(labels, np.array([0, 0, 1, 1, 1]))
    assert not same_partition(labels, np.array([0, 0, 0, 0, OUTLIER]))
