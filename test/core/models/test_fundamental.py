"""The fundamental-matrix model against synthetic scenes with known cameras."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from pearl_ros.core.errors import InputError
from pearl_ros.core.models import get_model
from pearl_ros.core.models._twoview import _FD_STEP, FAR, Similarities, normalise, refine_lm
from pearl_ros.core.models.fundamental import Fundamental, _rotations
from pearl_ros.core.neighbourhood import nearest_neighbours
from pearl_ros.core.scale import local_scale

from twoview_oracles import assert_batch_equals_singles, normalised_pairs, similarity


@pytest.fixture
def model() -> Fundamental:
    return Fundamental()


def epipolar_error(F: np.ndarray, z: np.ndarray) -> float:
    """x2^T F x1 for one row z = [x1, y1, x2, y2]."""
    return float(np.r_[z[2:], 1.0] @ F @ np.r_[z[:2], 1.0])


def sampson_sq_by_differences(F: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """eps^2 / (J J^T), J = d eps / d(x1, y1, x2, y2) by central differences, point by point.

    eps is affine in each coordinate separately, so the central difference is exact up to
    rounding: an independent route to H&Z eq. 11.9, with no formula shared with the model.
    """
    out = np.empty(len(rows))
    step = 1.0  # px; any step is exact for an affine function
    for n, z in enumerate(rows):
        jac = np.empty(4)
        for i in range(4):
            dz = np.zeros(4)
            dz[i] = step
            jac[i] = (epipolar_error(F, z + dz) - epipolar_error(F, z - dz)) / (2 * step)
        out[n] = epipolar_error(F, z) ** 2 / (jac @ jac)
    return out


def reprojection_distance(P1: np.ndarray, P2: np.ndarray, row: np.ndarray,
                          start: np.ndarray) -> float:
    """Gold-standard distance (H&Z sec. 12.3): min over 3-D X of the 4-D reprojection error."""

    def residual(X: np.ndarray) -> np.ndarray:
        x1, x2 = P1 @ np.r_[X, 1.0], P2 @ np.r_[X, 1.0]
        return np.r_[x1[:2] / x1[2], x2[:2] / x2[2]] - row

    fit = least_squares(residual, start, xtol=1e-15, ftol=1e-15, gtol=1e-15)
    return float(np.linalg.norm(fit.fun))


def eight_point(rows: np.ndarray) -> np.ndarray:
    """A plain normalised 8-point fit (Hartley 1997), written here as the baseline for refit."""
    x1, x2, T1, T2 = normalised_pairs(rows)
    A = np.array([np.kron(b, a) for a, b in zip(x1, x2, strict=True)])
    Fn = np.linalg.svd(A)[2][-1].reshape(3, 3)
    u, s, vt = np.linalg.svd(Fn)
    return T2.T @ (u @ np.diag([s[0], s[1], 0.0]) @ vt) @ T1


def sum_sq(model: Fundamental, data: np.ndarray, F: np.ndarray) -> float:
    return float(np.sum(model.residuals(data, F[None]) ** 2))


# data ------------------------------------------------------------------------------------


def test_registry_builds_the_fundamental_model():
    model = get_model('fundamental')
    assert isinstance(model, Fundamental)
    assert (model.name, model.min_samples) == ('fundamental', 8)


def test_data_pairs_the_first_and_the_last_frame(model):
    tracks = np.arange(3 * 5 * 2, dtype=float).reshape(3, 5, 2)
    rows = model.data(tracks)
    assert rows.shape == (5, 4) and rows.dtype == np.float64
    np.testing.assert_array_equal(rows[:, :2], tracks[0])
    np.testing.assert_array_equal(rows[:, 2:], tracks[2])


@pytest.mark.parametrize('tracks', [
    np.zeros((5, 2)),  # no frame axis
    np.zeros((2, 5, 3)),  # not 2-D points
    np.zeros((1, 5, 2)),  # one frame
    np.where(np.arange(20).reshape(2, 5, 2) == 7, np.nan, 0.0),
    np.where(np.arange(20).reshape(2, 5, 2) == 3, np.inf, 0.0),
])
def test_data_rejects_malformed_tracks_naming_them(model, tracks):
    with pytest.raises(InputError, match='tracks'):
        model.data(tracks)


# fit_minimal -----------------------------------------------------------------------------


def test_fit_minimal_recovers_the_true_matrix_from_eight_exact_points(model, scene, align):
    truth = scene(n=40, seed=1)
    samples = np.arange(40).reshape(5, 8)
    params, ok = model.fit_minimal(truth.data, samples)
    assert params.shape == (5, 3, 3) and ok.all()
    for F in params:
        np.testing.assert_allclose(align(F, truth.F), truth.F, atol=1e-7)


def test_fit_minimal_returns_rank_two_matrices_of_unit_norm(model, scene):
    truth = scene(n=400, noise=1.0, seed=2)
    samples = np.random.default_rng(2).integers(0, 400, (100, 8))
    params, ok = model.fit_minimal(truth.data, samples)
    s = np.linalg.svd(params[ok], compute_uv=False)
    assert ok.sum() > 90
    np.testing.assert_allclose(np.linalg.norm(params[ok], axis=(1, 2)), 1.0)
    assert np.all(s[:, 2] < 1e-12 * s[:, 0])
    assert np.all(np.abs(np.linalg.det(params[ok])) < 1e-12)


def test_fit_minimal_batch_equals_one_sample_at_a_time(model, scene):
    truth = scene(n=300, noise=0.5, seed=3)
    samples = np.random.default_rng(3).integers(0, 300, (50, 8))
    assert_batch_equals_singles(model, truth.data, samples, (0, 17, 49))


def test_fit_minimal_flags_repeated_points_without_raising(model, scene):
    truth = scene(n=20, noise=0.5, seed=4)
    samples = np.array([[0, 1, 2, 3, 4, 5, 6, 6], [0, 0, 0, 0, 0, 0, 0, 0],
                        [0, 1, 2, 3, 4, 5, 6, 7]])
    with np.errstate(all='raise'):
        params, ok = model.fit_minimal(truth.data, samples)
    assert ok.tolist() == [False, False, True]
    assert np.all(np.isfinite(params))


def test_fit_minimal_flags_eight_coplanar_scene_points(model, scene):
    # A plane seen from two views fixes F only up to a 3-parameter family (H&Z sec. 11.9).
    planar = scene(n=80, kind='planar', seed=5)
    samples = np.arange(80).reshape(10, 8)
    with np.errstate(all='raise'):
        params, ok = model.fit_minimal(planar.data, samples)
    assert not ok.any()
    assert np.all(np.isfinite(params))


def test_failed_samples_give_far_residuals_not_nan(model, scene):
    truth = scene(n=20, seed=6)
    params, ok = model.fit_minimal(truth.data, np.zeros((1, 8), dtype=int))
    assert not ok[0]
    np.testing.assert_array_equal(model.residuals(truth.data, params), FAR)


@pytest.mark.parametrize('samples', [
    np.arange(7)[None],  # too few points
    np.arange(8.0)[None],  # not integers
    np.array([[0, 1, 2, 3, 4, 5, 6, 20]]),  # out of range
    np.array([[-1, 1, 2, 3, 4, 5, 6, 7]]),
    np.arange(8),  # no batch axis
])
def test_fit_minimal_rejects_malformed_samples_naming_them(model, scene, samples):
    with pytest.raises(InputError, match='samples'):
        model.fit_minimal(scene(n=20).data, samples)


# residuals -------------------------------------------------------------------------------


def test_residuals_vanish_on_a_noise_free_scene(model, scene):
    truth = scene(n=500, seed=7)
    params, ok = model.fit_minimal(truth.data, np.arange(8)[None])
    residuals = model.residuals(truth.data, np.stack([truth.F, params[0]]))
    assert ok[0] and residuals.shape == (2, 500) and residuals.dtype == np.float64
    assert residuals.max() < 1e-6


def test_median_residual_of_the_true_matrix_matches_the_noise(model, scene):
    # With noise sigma in all 4 coordinates the Sampson distance is ~ |N(0, sigma^2)| to first
    # order, whose median is 0.6745 sigma.
    sigma = 0.5
    truth = scene(n=4000, noise=sigma, seed=8)
    median = np.median(model.residuals(truth.data, truth.F[None]))
    assert median == pytest.approx(0.6745 * sigma, rel=0.06)


def test_residuals_equal_sampson_from_a_finite_difference_jacobian(model, scene):
    rng = np.random.default_rng(9)
    truth = scene(n=30, noise=3.0, seed=9)
    rows = np.vstack([truth.data, rng.uniform(0, 640, (30, 4))])  # on and far off the model
    matrices = [truth.F, rng.normal(size=(3, 3))]  # the second is not even rank 2
    for F in matrices:
        expected = sampson_sq_by_differences(F, rows)
        np.testing.assert_allclose(model.residuals(rows, F[None])[0] ** 2, expected, rtol=1e-9)


def test_residuals_approximate_the_reprojection_distance_for_small_errors(model, scene):
    truth = scene(n=20, seed=10)
    offsets = np.random.default_rng(10).normal(0.0, 0.5, truth.clean.shape)
    rows = truth.clean + offsets
    sampson = model.residuals(rows, truth.F[None])[0]
    for n in range(20):
        gold = reprojection_distance(truth.P1, truth.P2, rows[n], truth.points[n])
        # The 4-D offset bounds the distance to the model from above.
        assert gold <= np.linalg.norm(offsets[n]) + 1e-9
        assert sampson[n] == pytest.approx(gold, rel=1e-2, abs=1e-4)


def test_residuals_ignore_the_scale_and_sign_of_the_matrix(model, scene):
    truth = scene(n=100, noise=1.0, seed=11)
    residuals = model.residuals(truth.data, np.stack([truth.F, -1e-4 * truth.F, 1e3 * truth.F]))
    np.testing.assert_allclose(residuals[1:], residuals[[0, 0]], rtol=1e-10)


def test_residuals_are_far_not_nan_where_the_gradient_vanishes(model):
    # Both epipoles of diag(1, 1, 0) are the origin: for x1 = x2 = (0, 0), F x1 = F^T x2 = 0.
    F = np.diag([1.0, 1.0, 0.0])
    rows = np.array([[0.0, 0.0, 0.0, 0.0], [1.0, 2.0, 3.0, 4.0]])
    with np.errstate(all='raise'):
        residuals = model.residuals(rows, np.stack([F, np.zeros((3, 3))]))
    assert np.all(np.isfinite(residuals))
    assert residuals[0, 0] == FAR and residuals[1].tolist() == [FAR, FAR]
    assert residuals[0, 1] < FAR


def test_residuals_handle_an_empty_batch(model, scene):
    assert model.residuals(scene(n=10).data, np.empty((0, 3, 3))).shape == (0, 10)


@pytest.mark.parametrize('params', [np.eye(3), np.zeros((2, 3, 4))])
def test_residuals_reject_malformed_params_naming_them(model, scene, params):
    with pytest.raises(InputError, match='params'):
        model.residuals(scene(n=10).data, params)


def test_refit_chart_rotations_match_scipy():
    w = np.random.default_rng(12).normal(0.0, 1.0, (20, 3)) * np.logspace(-9, 0, 20)[:, None]
    np.testing.assert_allclose(_rotations(w), Rotation.from_rotvec(w).as_matrix(), atol=1e-15)


# refit -----------------------------------------------------------------------------------


def test_refit_cost_is_no_higher_than_the_linear_eight_point_fit(model, scene):
    for seed in range(5):
        truth = scene(n=200, noise=1.0, seed=20 + seed)
        linear = eight_point(truth.data)
        refitted = model.refit(truth.data, np.arange(200), linear)
        assert refitted is not None
        # LM minimises the sum of squared Sampson distances; it must not end above its start.
        cost, linear_cost = sum_sq(model, truth.data, refitted), sum_sq(model, truth.data, linear)
        assert cost <= linear_cost * (1 + 1e-9)


def test_refit_ends_at_a_local_minimum_of_the_sampson_cost(model, scene):
    # No small rank-2 perturbation may lower the cost: at a minimum it changes by O(step^2) >= 0,
    # while at a non-stationary point (e.g. the linear fit) about half the directions lower it.
    # Perturbations are made in normalised coordinates, where the entries of F are balanced.
    truth = scene(n=200, noise=1.0, seed=25)
    rng = np.random.default_rng(25)
    T1, T2 = similarity(truth.data[:, :2]), similarity(truth.data[:, 2:])
    T1_inv, T2_inv = np.linalg.inv(T1), np.linalg.inv(T2)

    def directions_that_lower_the_cost(F: np.ndarray) -> int:
        cost, lowered = sum_sq(model, truth.data, F), 0
        Fn = T2_inv.T @ F @ T1_inv
        for _ in range(40):
            u, s, vt = np.linalg.svd(Fn + 1e-5 * np.linalg.norm(Fn) * rng.normal(size=(3, 3)))
            perturbed = T2.T @ u @ np.diag([s[0], s[1], 0.0]) @ vt @ T1
            lowered += sum_sq(model, truth.data, perturbed) < cost * (1 - 1e-9)
        return lowered

    linear = eight_point(truth.data)
    assert directions_that_lower_the_cost(linear) > 0  # the probe can tell
    assert directions_that_lower_the_cost(model.refit(truth.data, np.arange(200), linear)) == 0


@pytest.mark.parametrize('max_nfev', [3, 50])
def test_refine_lm_takes_the_steps_of_scipy_least_squares_lm(model, scene, max_nfev):
    # refine_lm calls MINPACK itself; scipy's least_squares(method='lm') is the reference it
    # must match to the bit, stopped by its tolerances (50) or by the evaluation cap (3).
    truth = scene(n=120, noise=1.0, seed=8)
    start = eight_point(truth.data[:40])
    _, T1, T1_inv, _ = normalise(truth.data[None, :, :2])
    _, T2, T2_inv, _ = normalise(truth.data[None, :, 2:])
    sims = Similarities(T1[0], T1_inv[0], T2[0], T2_inv[0])
    chart_start, matrices_of = model._chart(start, sims)

    def residuals_of(batch):
        return model._whitened(matrices_of(batch), truth.data)

    def jac(p):
        step = _FD_STEP * np.maximum(1.0, np.abs(p))
        r = residuals_of(np.vstack([p, p + np.diag(step)]))
        return ((r[1:] - r[0]) / step[:, None]).T

    p0 = chart_start + 0.3  # away from the linear fit, so that LM has steps to take
    expected = least_squares(lambda p: residuals_of(p[None])[0], p0, jac=jac, method='lm',
                             max_nfev=max_nfev).x
    found = refine_lm(residuals_of, p0, max_nfev)
    assert not np.array_equal(found, p0)
    np.testing.assert_array_equal(found, expected)


def test_refit_recovers_the_truth_when_outliers_are_excluded(model, scene):
    rng = np.random.default_rng(30)
    truth = scene(n=260, noise=1.0, seed=30)
    data = truth.data.copy()
    outliers = np.arange(200, 260)
    data[outliers, 2:] = rng.uniform([0, 0], [640, 480], (60, 2))
    inliers = np.arange(200)
    # Start from a hypothesis fitted to a contaminated sample: refit must not be tied to it.
    start = eight_point(data[190:230])
    refitted = model.refit(data, inliers, start)
    assert refitted is not None
    # Judged on the noise-free correspondences: the model is within a fraction of the noise.
    clean = model.residuals(truth.clean, refitted[None])[0]
    assert np.sqrt(np.mean(clean**2)) < 0.25
    assert np.median(model.residuals(data, refitted[None])[0, outliers]) > 10.0
    # Fitting through the outliers instead does visibly worse.
    polluted = model.refit(data, np.arange(260), start)
    assert np.sqrt(np.mean(model.residuals(truth.clean, polluted[None])[0] ** 2)) > 0.5


def test_refit_returns_a_rank_two_matrix_of_unit_norm(model, scene):
    truth = scene(n=500, noise=1.0, seed=31)
    refitted = model.refit(truth.data, np.arange(500), truth.F)
    s = np.linalg.svd(refitted, compute_uv=False)
    assert np.linalg.norm(refitted) == pytest.approx(1.0)
    assert s[2] < 1e-12 * s[0]
    assert abs(np.linalg.det(refitted)) < 1e-12


def test_refit_of_exact_points_returns_the_true_matrix(model, scene, align):
    truth = scene(n=30, seed=32)
    for inliers in (np.arange(8), np.arange(30)):
        refitted = model.refit(truth.data, inliers, np.eye(3))
        np.testing.assert_allclose(align(refitted, truth.F), truth.F, atol=1e-7)


def test_refit_accepts_a_zero_start_and_uses_the_linear_fit(model, scene):
    truth = scene(n=100, noise=0.5, seed=33)
    refitted = model.refit(truth.data, np.arange(100), np.zeros((3, 3)))
    assert refitted is not None
    assert np.sqrt(np.mean(model.residuals(truth.clean, refitted[None]) ** 2)) < 0.25


def test_refit_returns_none_for_fewer_than_eight_inliers(model, scene):
    assert model.refit(scene(n=20).data, np.arange(7), np.eye(3)) is None


def test_refit_returns_none_for_a_planar_scene(model, scene):
    planar = scene(n=50, kind='planar', seed=34)
    with np.errstate(all='raise'):
        assert model.refit(planar.data, np.arange(50), np.eye(3)) is None


@pytest.mark.parametrize('inliers', [np.arange(10.0), np.arange(10)[None], np.array([0, 99])])
def test_refit_rejects_malformed_inliers_naming_them(model, scene, inliers):
    with pytest.raises(InputError, match='inliers'):
        model.refit(scene(n=20).data, inliers, np.eye(3))


def test_fit_groups_recovers_the_true_matrix_from_groups_of_exact_points(model, scene, align):
    truth = scene(n=60, seed=4)
    params, ok = model.fit_groups(truth.data, np.arange(60).reshape(5, 12))
    assert ok.all()
    for F in params:
        np.testing.assert_allclose(align(F, truth.F), truth.F, atol=1e-7)


@pytest.mark.parametrize('noise', [0.5, 1.5])
def test_noise_scale_of_a_rigid_scene_is_its_pixel_noise(scene, noise):
    # fit_groups serves the automatic noise scale: on a general 3-D scene (a plane would leave
    # 11-point groups a family of F to overfit with) it must find the pixel noise it was given.
    truth = scene(n=400, noise=noise, seed=7)
    model = Fundamental()
    level = local_scale(model, truth.data, nearest_neighbours(truth.tracks[-1], 10),
                        np.random.default_rng(0), 60)
    assert level == pytest.approx(noise, rel=0.35)
