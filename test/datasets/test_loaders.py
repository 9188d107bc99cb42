"""KT3DMoSeg and AdelaideRMF readers, on files written here and on the real data sets, and the
outlier-track generator."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.io

from pearl_ros.core.errors import InputError
from pearl_ros.datasets import adelaide, kt3dmoseg
from pearl_ros.datasets.outliers import add_mismatches, add_outlier_tracks


def _write_clip(path: Path, points: np.ndarray, visible: np.ndarray, groups: np.ndarray) -> None:
    """A KT3DMoSeg-shaped file: ``points`` (F, P, 2) pixels, homogeneous with w = 2."""
    y = np.concatenate([2.0 * points, np.full(points.shape[:2] + (1,), 2.0)], axis=2)
    y = np.transpose(y, (2, 1, 0)) * visible.T[None]  # 0 where not tracked, as in the data
    scipy.io.savemat(str(path), {'Data': {'ySparse': y, 'visibleSparse': visible.T.astype(float),
                                          'GtLabel': groups.astype(float)}})


def test_a_clip_reads_back_its_points_visibility_and_labels(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    points = rng.uniform(0, 600, (5, 7, 2))
    visible = rng.random((5, 7)) < 0.7
    visible[[0, -1], :3] = True
    groups = np.array([1, 1, 3, 3, 1, 3, 1])
    _write_clip(tmp_path / 'Seq001_Clip01_Tracks.mat', points, visible, groups)
    clip = kt3dmoseg.load_clip(tmp_path / 'Seq001_Clip01_Tracks.mat')
    assert clip.name == 'Seq001_Clip01'
    np.testing.assert_array_equal(clip.visible, visible)
    np.testing.assert_allclose(clip.tracks[visible], points[visible])
    assert np.isnan(clip.tracks[~visible]).all()
    np.testing.assert_array_equal(clip.labels, [0, 0, 1, 1, 0, 1, 0])
    both = visible[0] & visible[-1]
    pair, labels = clip.two_frames()
    np.testing.assert_allclose(pair, points[[0, -1]][:, both])
    np.testing.assert_array_equal(labels, clip.labels[both])
    frames = list(clip.frames())
    assert len(frames) == 5
    for t, (ids, uv, truth) in enumerate(frames):
        np.testing.assert_array_equal(ids, np.flatnonzero(visible[t]))
        np.testing.assert_allclose(uv, points[t, ids])
        np.testing.assert_array_equal(truth, clip.labels[ids])


def test_a_pair_maps_mismatches_to_the_outlier_label(tmp_path: Path) -> None:
    x1 = np.array([[10.0, 20.0], [30.0, 40.0], [50.0, 60.0], [70.0, 80.0]])
    x2 = x1 + 5.0
    data = np.vstack([x1.T, np.ones(4), x2.T, np.ones(4)])
    scipy.io.savemat(str(tmp_path / 'toy.mat'), {'data': data, 'label': [[0, 2, 1, 2]]})
    pair = adelaide.load_pair(tmp_path / 'toy.mat')
    np.testing.assert_allclose(pair.tracks, np.stack([x1, x2]))
    np.testing.assert_array_equal(pair.labels, [-1, 1, 0, 1])
    assert pair.num_motions == 2
    assert pair.outlier_share == 0.25


def test_unreadable_files_are_one_line_errors(tmp_path: Path) -> None:
    bad = tmp_path / 'bad.mat'
    bad.write_bytes(b'not a mat file')
    for load in (kt3dmoseg.load_clip, adelaide.load_pair):
        with pytest.raises(InputError, match='bad.mat'):
            load(bad)
    with pytest.raises(InputError, match='not found'):
        kt3dmoseg.clip_paths(tmp_path / 'nowhere')


def test_outlier_tracks_make_up_the_share_asked_and_move_as_random_walks() -> None:
    rng = np.random.default_rng(1)
    tracks = rng.uniform(0, 500, (30, 80, 2))
    labels = rng.integers(0, 2, 80)
    out, out_labels = add_outlier_tracks(tracks, labels, 0.2, rng=3, step=3.0)
    np.testing.assert_array_equal(out[:, :80], tracks)
    np.testing.assert_array_equal(out_labels[:80], labels)
    assert out.shape[1] == 100 and np.all(out_labels[80:] == -1)  # 20 of 100
    steps = np.diff(out[:, 80:], axis=0)
    assert abs(steps.std() - 3.0) < 0.2  # 29 x 20 x 2 Gaussian steps of 3 px
    assert abs(steps.mean()) < 0.3
    with pytest.raises(InputError, match='share'):
        add_outlier_tracks(tracks, labels, 1.0)


def test_mismatches_are_random_pairs_added_after_the_clean_points() -> None:
    rng = np.random.default_rng(2)
    first = rng.uniform([10, 20], [610, 420], (120, 2))
    views = np.stack([first, 1.2 * first + [300.0, -50.0]])  # the second view zoomed and moved
    labels = rng.integers(0, 3, 120)
    out, out_labels = add_mismatches(views, labels, 0.6, rng=5)
    np.testing.assert_array_equal(out[:, :120], views)
    np.testing.assert_array_equal(out_labels[:120], labels)
    assert out.shape == (2, 300, 2) and np.all(out_labels[120:] == -1)  # 180 of 300
    for view, added in zip(views, out[:, 120:], strict=True):
        # Each view's mismatches fill that view's box of clean points, uniformly.
        low, high = view.min(axis=0), view.max(axis=0)
        assert np.all((added >= low) & (added <= high))
        assert np.all(np.abs(added.mean(axis=0) - (low + high) / 2) < 0.1 * (high - low))
    # The two ends of a mismatch are drawn apart: no motion relates them.
    moved = out[1, 120:] - (1.2 * out[0, 120:] + [300.0, -50.0])
    assert np.median(np.linalg.norm(moved, axis=1)) > 100.0
    assert np.array_equal(add_mismatches(views, labels, 0.6, rng=5)[0], out)
    assert add_mismatches(views, labels, 0.0)[0].shape == (2, 120, 2)
    with pytest.raises(InputError, match='share'):
        add_mismatches(views, labels, 1.0)
    with pytest.raises(InputError, match=r'\(2, N, 2\)'):
        add_mismatches(np.concatenate([views, views]), labels, 0.5)


def test_every_kt3dmoseg_clip_reads_with_a_background_and_moving_objects(
        kt3dmoseg_root: Path) -> None:
    for path in kt3dmoseg.clip_paths(kt3dmoseg_root):
        clip = kt3dmoseg.load_clip(path)
        assert clip.num_motions >= 2
        assert np.all(np.isfinite(clip.tracks[clip.visible]))
        assert clip.two_frames()[0].shape[1] > 8


def test_every_adelaide_pair_reads_with_mismatches_labelled(adelaidermf_root: Path) -> None:
    for path in adelaide.pair_paths(adelaidermf_root):
        pair = adelaide.load_pair(path)
        assert 0.2 < pair.outlier_share < 0.8  # "roughly 30-70% mismatches"
        assert pair.num_motions >= 1
        assert pair.tracks.shape[0] == 2 and np.all(np.isfinite(pair.tracks))
