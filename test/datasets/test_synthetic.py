"""The synthetic stream shows what a tracker sees: no background feature through an object."""

from __future__ import annotations

import numpy as np
from scipy.spatial import Delaunay

from pearl_ros.datasets.synthetic import BodySpec, synthetic_stream


def test_no_background_feature_shows_inside_an_object():
    # Objects move on their own from the start, so the truth names every feature's body. The
    # hull of an object's own features lies inside its silhouette: no background feature there.
    objects = (BodySpec(0.3), BodySpec(0.2))
    covered = 0
    for frame in synthetic_stream(300, 30, objects, seed=4):
        background = frame.uv[frame.truth == 0]
        for body in (1, 2):
            hull = Delaunay(frame.uv[frame.truth == body])
            covered += int(np.sum(hull.find_simplex(background) >= 0))
    assert covered == 0


def test_covered_features_are_replaced_so_every_frame_keeps_its_feature_count():
    frames = list(synthetic_stream(300, 30, (BodySpec(0.3),), death_rate=0.0, seed=4))
    assert all(f.ids.size == 300 for f in frames)
    # With no random deaths, features are still lost (and replaced) as the object moves over
    # the background.
    assert len(set().union(*(set(f.ids.tolist()) for f in frames))) > 300
