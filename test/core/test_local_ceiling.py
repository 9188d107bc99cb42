"""A two-view model's noise level capped by its members' local noise
(``SolverSettings.local_ceiling``): one fundamental matrix may not take two structures, or a
structure and the mismatches around it, by widening until it holds them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pearl_ros.core import pearl
from pearl_ros.core.config import PearlConfig, SolverSettings
from pearl_ros.core.metrics import misclassification
from pearl_ros.datasets import adelaide, kt3dmoseg

CAPPED = PearlConfig(model='fundamental')
FREE = PearlConfig(model='fundamental', solver=SolverSettings(local_ceiling=0.0))


@pytest.mark.parametrize('seed', range(3))
def test_every_model_of_a_two_view_fit_keeps_within_its_members_local_noise(two_view_scene, seed):
    # One search, so that the setting drawn here from the same seed is the fit's own (each
    # restart draws its own noise scale, and with it the reference).
    single = PearlConfig(model='fundamental',
                         solver=SolverSettings(two_view_restarts=1, one_motion_restarts=0))
    tracks, _ = two_view_scene(seed)
    result = pearl.fit(tracks, single, rng=seed)
    setting = pearl._setting(tracks, single, np.random.default_rng(seed))
    assert setting.local is not None and setting.reference >= setting.scale
    for k, sigma in enumerate(result.sigmas):
        members = np.flatnonzero(result.labels == k)
        # The members' median nearest miss, or the reference, times local_ceiling (4).
        local = max(float(np.median(setting.local[members])), setting.reference)
        assert sigma <= 4.0 * local * (1 + 1e-9)
    # Batch only: the online segmenter's fits (batch=False) and multi-frame fits are uncapped.
    assert pearl._setting(tracks, CAPPED, np.random.default_rng(seed), batch=False).local is None
    assert pearl._setting(tracks, FREE, np.random.default_rng(seed)).local is None


def _kt3dmoseg_two_frames(root: Path, config: PearlConfig) -> float:
    errors = []
    for index, path in enumerate(kt3dmoseg.clip_paths(root)):
        tracks, truth = kt3dmoseg.load_clip(path).two_frames()
        errors.append(misclassification(pearl.fit(tracks, config, rng=index).labels, truth))
    return float(np.mean(errors))


def test_the_ceiling_lowers_the_error_of_kt3dmoseg_two_frames(kt3dmoseg_root: Path) -> None:
    # Real data with ground truth: the 11 development clips, first and last frame.
    assert _kt3dmoseg_two_frames(kt3dmoseg_root, CAPPED) < (
        _kt3dmoseg_two_frames(kt3dmoseg_root, FREE) - 0.01)


def test_the_ceiling_lowers_the_error_of_adelaidermf_pairs(adelaidermf_root: Path) -> None:
    # Real data with ground truth: the 10 development pairs, mismatches a group of their own,
    # over three seeds (a pair's error moves by several points between seeds), each pair
    # drawn from the seed alone as `pearl_bench suite --seeds 0 1 2` draws it.
    errors: dict[bool, list[float]] = {True: [], False: []}
    for seed in range(3):
        for path in adelaide.pair_paths(adelaidermf_root):
            pair = adelaide.load_pair(path)
            for capped, config in ((True, CAPPED), (False, FREE)):
                labels = pearl.fit(pair.tracks, config, rng=seed).labels
                errors[capped].append(misclassification(labels, pair.labels))
    assert np.mean(errors[True]) < np.mean(errors[False]) - 0.005
