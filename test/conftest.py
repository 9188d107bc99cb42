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


@pytest.fixture
def affine_scene():
    return make_affine_scene


@pytest.fixture
def hopkins_root() -> Path:
    assert HOPKINS.is_dir(), f'Hopkins155 data not found at {HOPKINS}'
    return HOPKINS
