"""Synthetic two-view scenes with known cameras, for the fundamental and homography models.

Ground truth is built here from the cameras (``P = K [R | t]``), never by the code under test:
``F = K^-T [t]_x R K^-1`` (H&Z eq. 9.6 with P1 = K [I | 0]) and, for points on the plane
``n^T X = d``, ``H = K (R + t n^T / d) K^-1`` (H&Z result 13.1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

# A 640 x 480 camera with a 500 px focal length.
CAMERA = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class Scene:
    """N correspondences between two views, noisy and noise-free, with the true motion."""

    P1: np.ndarray  # (3, 4) camera of the first view
    P2: np.ndarray  # (3, 4) camera of the second view
    points: np.ndarray  # (N, 3) scene points
    clean: np.ndarray  # (N, 4) [x1, y1, x2, y2] pixels, exact projections
    data: np.ndarray  # (N, 4) the same with seeded Gaussian noise
    F: np.ndarray  # (3, 3) true fundamental matrix, unit Frobenius norm
    H: np.ndarray | None  # (3, 3) true homography (plane or pure rotation), else None

    @property
    def tracks(self) -> np.ndarray:
        """(2, N, 2) tracks of the noisy data."""
        return np.stack([self.data[:, :2], self.data[:, 2:]])


def project(P: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) of ``points`` (N, 3) seen by camera ``P`` (3, 4)."""
    x = points @ P[:, :3].T + P[:, 3]
    return x[:, :2] / x[:, 2:]


def skew(t: np.ndarray) -> np.ndarray:
    """[t]_x, with [t]_x v = t x v."""
    return np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])


def unit(matrix: np.ndarray) -> np.ndarray:
    return matrix / np.linalg.norm(matrix)


def make_scene(n: int = 100, noise: float = 0.0, seed: int = 0, kind: str = 'general',
               rotvec: tuple[float, float, float] = (0.05, -0.1, 0.03),
               t: tuple[float, float, float] = (1.0, 0.2, 0.1)) -> Scene:
    """A seeded two-view scene.

    ``kind`` is ``'general'`` (points in a box 4..8 m deep), ``'planar'`` (points on a tilted
    plane 6 m away) or ``'rotation'`` (general points, camera only rotates: t = 0).
    Every point projects inside 640 x 480 in both views.
    """
    rng = np.random.default_rng(seed)
    R = Rotation.from_rotvec(rotvec).as_matrix()
    t_vec = np.zeros(3) if kind == 'rotation' else np.asarray(t, dtype=float)
    # Rays through most of the first image, then a depth along each ray.
    rays = np.column_stack([rng.uniform(-0.5, 0.5, n), rng.uniform(-0.38, 0.38, n), np.ones(n)])
    normal, depth = unit(np.array([0.1, -0.2, 1.0])), 6.0
    if kind == 'planar':
        z = depth / (rays @ normal)  # n^T (z ray) = d
    else:
        z = rng.uniform(4.0, 8.0, n)
    points = rays * z[:, None]
    P1 = CAMERA @ np.column_stack([np.eye(3), np.zeros(3)])
    P2 = CAMERA @ np.column_stack([R, t_vec])
    clean = np.column_stack([project(P1, points), project(P2, points)])
    data = clean + rng.normal(0.0, noise, clean.shape) if noise > 0 else clean.copy()
    K_inv = np.linalg.inv(CAMERA)
    F = unit(K_inv.T @ skew(t_vec) @ R @ K_inv) if kind != 'rotation' else np.zeros((3, 3))
    H = None
    if kind == 'planar':
        H = unit(CAMERA @ (R + np.outer(t_vec, normal) / depth) @ K_inv)
    elif kind == 'rotation':
        H = unit(CAMERA @ R @ K_inv)
    return Scene(P1, P2, points, clean, data, F, H)


@pytest.fixture
def scene():
    """The factory :func:`make_scene`."""
    return make_scene


def aligned(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """``estimate`` scaled to unit norm with the sign that best matches ``truth``."""
    estimate = unit(estimate)
    return estimate if np.sum(estimate * truth) >= 0 else -estimate


@pytest.fixture
def align():
    """The helper :func:`aligned`: compare matrices defined up to scale and sign."""
    return aligned
