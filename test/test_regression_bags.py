"""Regression: segment the bundled bags with default parameters and check the accuracy."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pearl_ros.bagio.reader import read_feature_frames, read_ground_truth
from pearl_ros.core.metrics import misclassification
from pearl_ros.core.pearl import fit

BAGS = Path(__file__).resolve().parents[1] / 'bags'


def segment(bag: Path) -> tuple[np.ndarray, np.ndarray]:
    frames = list(read_feature_frames(bag))
    truth = read_ground_truth(bag)
    ids = frames[0].ids  # Hopkins bags: every feature in every frame, same order
    tracks = np.stack([f.uv for f in frames])
    return fit(tracks, rng=0).labels, np.array([truth[int(i)] for i in ids])


# (bag, largest misclassification allowed). cars2 is a known weak case of the current defaults
# (a car and a handheld camera whose motions are nearly dependent; BENCHMARKS.md): the bound
# records today's level so that a regression shows, not a target.
@pytest.mark.parametrize('name,bound', [('1R2RCR', 0.02), ('1R2RCR_g12', 0.02), ('cars2', 0.45)])
def test_bundled_bag_segmentation_stays_accurate(name, bound):
    labels, truth = segment(BAGS / name)
    assert misclassification(labels, truth) <= bound
    if bound <= 0.02:
        assert np.unique(labels[labels >= 0]).size == np.unique(truth).size
