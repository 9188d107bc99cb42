"""Scene factories shared by the tests: synthetic motions with known ground truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

HOPKINS = Path(__file__).resolve().parents[1].parent / 'shared' / 'data' / 'hopkins155'


def _rotation(rng: np.random.Generator, angle: float) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def make_affine_scene(
    sizes: tuple[int, ...] = (120, 80),
    frames: int = 12,
    noise: float = 0.5,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Rigid bodies seen by an affine camera: tracks (F, N, 2) px and labels (N,).

    Body k is a cloud of 3-D points in its own image region; each frame it turns and shifts by
    its own random motion; an orthographic camera with a zoom projects it. Gaussian pixel noise.
    The regions stay apart, as opaque objects' do (no body's features show through another).
    """
    rng = np.random.default_rng(seed)
    tracks, labels = [], []
    for k, size in enumerate(sizes):
        centre = np.array([120.0 + 320.0 * k, 240.0 + 60.0 * (k % 2), 0.0])
        cloud = rng.uniform(-60, 60, (size, 3))
        rot, shift = np.eye(3), np.zeros(3)
        step_rot = _rotation(rng, 0.06)
        step_shift = rng.normal(0, 4.0, 3)
        body = []
        for _ in range(frames):
            world = cloud @ rot.T + centre + shift
            body.append(world[:, :2] * 1.0)
            rot, shift = step_rot @ rot, shift + step_shift
        tracks.append(np.stack(body))
        labels.append(np.full(size, k))
    tracks_arr = np.concatenate(tracks, axis=1) + rng.normal(0, noise, (frames, sum(sizes), 2))
    return tracks_arr, np.concatenate(labels)


def make_gap_scene(same_body: bool, frames: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Two 60-point clusters 300 px apart with nothing between; tracks (F, N, 2) and the
    cluster of each point. Both clusters are one rigid body (one motion of the pair), or each
    turns and shifts by its own motion, as the bodies of ``make_affine_scene`` do (0.06 rad a
    frame about a random axis). Orthographic views, noise 0.3 px."""
    rng = np.random.default_rng(7)
    centres = np.array([[0.0, 0.0, 0.0], [300.0, 0.0, 0.0]])
    clouds = [rng.uniform(-60, 60, (60, 3)) + centre for centre in centres]
    motions = []
    for _ in range(2):
        step = _rotation(rng, 0.06)
        motions.append((step, rng.normal(0, 4.0, 3)))
    if same_body:
        motions[1] = motions[0]
    tracks = []
    for f in range(frames):
        views = []
        for cloud, (step, shift) in zip(clouds, motions):
            rot = np.linalg.matrix_power(step, f)
            views.append((cloud - [150.0, 0, 0]) @ rot.T + f * shift)
        tracks.append(np.concatenate(views)[:, :2])
    tracks = np.stack(tracks) + rng.normal(0, 0.3, (frames, 120, 2))
    return tracks, np.repeat([0, 1], 60)


@pytest.fixture
def affine_scene():
    return make_affine_scene


@pytest.fixture
def gap_scene():
    return make_gap_scene


@pytest.fixture
def hopkins_root() -> Path:
    assert HOPKINS.is_dir(), f'Hopkins155 data not found at {HOPKINS}'
    return HOPKINS
