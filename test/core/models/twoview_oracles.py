"""Independent two-view helpers the model tests compare against (not the package's code)."""

from __future__ import annotations

import numpy as np


def similarity(points: np.ndarray) -> np.ndarray:
    """Hartley's normalising similarity (3, 3) of ``points`` (N, 2)."""
    c = points.mean(axis=0)
    s = np.sqrt(2) / np.mean(np.linalg.norm(points - c, axis=1))
    return np.array([[s, 0, -s * c[0]], [0, s, -s * c[1]], [0, 0, 1]])


def normalised_pairs(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Homogeneous normalised points of both views of ``rows`` (N, 4), with their similarities."""
    T1, T2 = similarity(rows[:, :2]), similarity(rows[:, 2:])
    x1 = np.column_stack([rows[:, :2], np.ones(len(rows))]) @ T1.T
    x2 = np.column_stack([rows[:, 2:], np.ones(len(rows))]) @ T2.T
    return x1, x2, T1, T2


def assert_batch_equals_singles(model, data: np.ndarray, samples: np.ndarray,
                                probes: tuple[int, ...]) -> None:
    """``fit_minimal`` on a batch equals one sample at a time; ``residuals`` likewise at
    the hypotheses ``probes``."""
    params, ok = model.fit_minimal(data, samples)
    for k in range(samples.shape[0]):
        one, one_ok = model.fit_minimal(data, samples[k:k + 1])
        assert one_ok[0] == ok[k]
        np.testing.assert_allclose(one[0], params[k], atol=1e-12)
    residuals = model.residuals(data, params)
    for k in probes:
        np.testing.assert_allclose(model.residuals(data, params[k:k + 1])[0], residuals[k])
