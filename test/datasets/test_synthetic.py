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


def test_a_paused_object_moves_with_the_background_and_its_truth_says_so():
    # Frames 5-9: the object moves as the background does, and the truth calls it background.
    frames = list(synthetic_stream(200, 15, (BodySpec(0.4, pause=(5, 10)),), death_rate=0.0,
                                   noise=0.0, seed=1))

    def object_ids(frame):
        return set(frame.ids[frame.truth == 1].tolist())

    assert object_ids(frames[4]) and object_ids(frames[10])
    assert not any(object_ids(frames[t]) for t in range(5, 10))

    def residual(a, b, ids):
        """RMS residual of one least-squares 2-D affine map from frame a to frame b."""
        pa = dict(zip(a.ids.tolist(), a.uv.tolist(), strict=True))
        pb = dict(zip(b.ids.tolist(), b.uv.tolist(), strict=True))
        both = [i for i in ids if i in pa and i in pb]
        src = np.array([pa[i] + [1.0] for i in both])
        dst = np.array([pb[i] for i in both])
        fit = np.linalg.lstsq(src, dst, rcond=None)[0]
        return float(np.sqrt(np.mean(np.square(src @ fit - dst))))

    everyone = set(frames[4].ids.tolist())
    background = set(frames[4].ids[frames[4].truth == 0].tolist())
    # While paused, the object's features fit the background's own frame-to-frame map as well
    # as the background does (0.9 times its residual on this seed); moving, they do not (3.9).
    paused = residual(frames[6], frames[7], everyone) / residual(frames[6], frames[7], background)
    moving = residual(frames[2], frames[3], everyone) / residual(frames[2], frames[3], background)
    assert paused < 1.5 < moving
