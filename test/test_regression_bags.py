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


# (bag, largest misclassification allowed). cars2 and 1R2RCR are known weak cases of the
# current defaults, whose bounds record today's level so that a regression shows, not a target:
# in cars2 a car and a handheld camera move nearly dependently; in 1R2RCR one object's pairs
# with the background miss each other by 3-25 units, where pairs tie, and with the unit of the
# misses at their 60th percentile one or both objects are merged into the background on every
# seed tried (seeds 0-4: 21.8 or 32.2%, BENCHMARKS.md, "Bundled bags"; the bound allows that and
# no worse). The median as unit kept them apart (0.8%) but cost Hopkins155 more
# (docs/experiments.md, "The unit of the misses").
@pytest.mark.parametrize('name,bound', [('1R2RCR', 0.33), ('1R2RCR_g12', 0.02), ('cars2', 0.45)])
def test_bundled_bag_segmentation_stays_accurate(name, bound):
    labels, truth = segment(BAGS / name)
    assert misclassification(labels, truth) <= bound
    if bound <= 0.02:
        assert np.unique(labels[labels >= 0]).size == np.unique(truth).size
