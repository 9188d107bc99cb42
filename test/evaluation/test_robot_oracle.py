"""The robot-stream oracle: triangulation with known cameras (the static world's residual,
:func:`pearl_ros.core.models.ego.static_residuals`), and its readings of a stream."""

from __future__ import annotations

import numpy as np
import pytest

from pearl_ros.core.errors import InputError
from pearl_ros.core.models.ego import static_residuals as triangulate
from pearl_ros.evaluation.robot_oracle import final_window, format_readings


def _cameras(frames: int) -> np.ndarray:
    """Projection matrices of a camera (focal 500 px) moving along x and forward, turning."""
    k = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
    cameras = []
    for t in range(frames):
        angle = 0.02 * t
        c, s = np.cos(angle), np.sin(angle)
        rotation = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])  # world from camera
        centre = np.array([0.1 * t, 0.0, 0.3 * t])
        cameras.append(k @ np.hstack([rotation.T, -rotation.T @ centre[:, None]]))
    return np.stack(cameras)


def _project(cameras: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(F, N, 2) pixels of world points (F, N, 3) (one position per frame)."""
    homogeneous = np.concatenate([points, np.ones(points.shape[:2] + (1,))], axis=2)
    projected = np.einsum('fij,fnj->fni', cameras, homogeneous)
    return projected[..., :2] / projected[..., 2:]


def test_static_points_reproject_exactly_and_moving_ones_do_not() -> None:
    rng = np.random.default_rng(0)
    frames = 8
    cameras = _cameras(frames)
    world = np.column_stack([rng.uniform(-5, 5, 30), rng.uniform(-2, 2, 30),
                             rng.uniform(10, 30, 30)])
    static = np.repeat(world[None], frames, axis=0)
    # Ten points move sideways at 0.4 m per frame, across the camera's line of travel.
    moving = static.copy()
    moving[:, :10, 0] += 0.4 * np.arange(frames)[:, None]
    residual, in_front = triangulate(cameras, _project(cameras, static))
    assert np.all(residual < 1e-6) and np.all(in_front)
    residual, _ = triangulate(cameras, _project(cameras, moving))
    assert np.all(residual[:10] > 1.0) and np.all(residual[10:] < 1e-6)


def test_a_point_behind_the_cameras_is_not_in_front() -> None:
    cameras = _cameras(5)
    behind = np.repeat(np.array([[[0.5, 0.2, -8.0]]]), 5, axis=0)
    residual, in_front = triangulate(cameras, _project(cameras, behind))
    # A point behind projects consistently (the same rays, reversed), but no point in front
    # explains it: the best one, at infinity, leaves its parallax.
    assert not in_front[0] or residual[0] > 1.0


def test_triangulate_rejects_mismatched_shapes() -> None:
    with pytest.raises(InputError, match='cameras'):
        triangulate(np.zeros((3, 3, 4)), np.zeros((4, 5, 2)))


def test_the_static_world_is_explained_and_outlier_tracks_are_not() -> None:
    readings = final_window(0, window=10, frames=60)
    by_group = {r.group: r for r in readings}
    # The generator's truth: the static world is static, outlier tracks are random walks.
    assert by_group[0].points > 20 and by_group[0].static_share >= 0.95
    assert by_group[0].static_px < 1.0  # 0.5 px tracking noise per axis
    assert by_group[-1].static_share <= 0.05
    # Against the static world's own spread: a hundredth of its tracks lie beyond its 99%
    # quantile by definition, and no random walk lies within it.
    assert 0.97 <= by_group[0].within_share <= 1.0
    assert by_group[-1].within_share == 0.0
    assert all(r.within_share <= r.static_share + 1e-12 or r.group == 0 for r in readings)
    # Perspective: the static world fits a 4-D affine subspace closer than a 3-D one.
    assert by_group[0].affine4_px < by_group[0].affine3_px
    assert 'static point would' in format_readings(readings)


def test_pearl_bench_synthetic_oracle_prints_the_readings(capsys: pytest.CaptureFixture[str]
                                                          ) -> None:
    from pearl_ros.cli.bench import main

    assert main(['synthetic', '--scenes', '1', '--oracle']) == 0
    out = capsys.readouterr().out
    rows = [line.split('|') for line in out.splitlines() if line.startswith('| 1 |')]
    static = next(r for r in rows if r[2].strip() == 'static world')
    assert float(static[5]) >= 0.95  # the static world is explained by static points
    assert float(static[6]) >= 0.97  # ... within its own 99% quantile, but a hundredth
    assert 'seed 1: ' in out and 'robot_synthetic' in out
