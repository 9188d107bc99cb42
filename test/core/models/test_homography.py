"""The homography model against planar and pure-rotation scenes with known cameras."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from pearl_ros.core.errors import InputError
from pearl_ros.core.models import get_model
from pearl_ros.core.models._twoview import FAR
from pearl_ros.core.models.homography import Homography

from twoview_oracles import assert_batch_equals_singles, normalised_pairs, similarity


@pytest.fixture
def model() -> Homography:
    return Homography()


def transfer(H: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) of ``H`` applied to ``points`` (N, 2)."""
    x = np.column_stack([points, np.ones(len(points))]) @ H.T
    return x[:, :2] / x[:, 2:]


def algebraic_error(H: np.ndarray, z: np.ndarray) -> np.ndarray:
    """First two rows of x2 x (H x1) for one row z = [x1, y1, x2, y2] (H&Z eq. 4.1)."""
    return np.cross(np.r_[z[2:], 1.0], H @ np.r_[z[:2], 1.0])[:2]


def sampson_sq_by_differences(H: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """e^T (J J^T)^-1 e with J by central differences (exact: e is affine in each coordinate)."""
    out = np.empty(len(rows))
    for n, z in enumerate(rows):
        jac = np.empty((2, 4))
        for i in range(4):
            dz = np.zeros(4)
            dz[i] = 1.0
            jac[:, i] = (algebraic_error(H, z + dz) - algebraic_error(H, z - dz)) / 2.0
        e = algebraic_error(H, z)
        out[n] = e @ np.linalg.solve(jac @ jac.T, e)
    return out


def reprojection_distance(H: np.ndarray, row: np.ndarray) -> float:
    """Gold-standard distance (H&Z sec. 4.2.5): min over u of |x1 - u|^2 + |x2 - H u|^2."""

    def residual(u: np.ndarray) -> np.ndarray:
        return np.r_[row[:2] - u, row[2:] - transfer(H, u[None])[0]]

    fit = least_squares(residual, row[:2], xtol=1e-15, ftol=1e-15, gtol=1e-15)
    return float(np.linalg.norm(fit.fun))


def dlt(rows: np.ndarray) -> np.ndarray:
    """A plain normalised DLT (H&Z alg. 4.2), written here as the baseline for refit."""
    x1, x2, T1, T2 = normalised_pairs(rows)
    A = []
    for a, (u, v, w) in zip(x1, x2, strict=True):
        A.append(np.r_[np.zeros(3), -w * a, v * a])
        A.append(np.r_[w * a, np.zeros(3), -u * a])
    Hn = np.linalg.svd(np.array(A))[2][-1].reshape(3, 3)
    return np.linalg.inv(T2) @ Hn @ T1


def sum_sq(model: Homography, data: np.ndarray, H: np.ndarray) -> float:
    return float(np.sum(model.residuals(data, H[None]) ** 2))


def rms(model: Homography, data: np.ndarray, H: np.ndarray) -> float:
    return float(np.sqrt(np.mean(model.residuals(data, H[None]) ** 2)))


# data and fit_minimal --------------------------------------------------------------------


def test_registry_builds_the_homography_model():
    model = get_model('homography')
    assert isinstance(model, Homography)
    assert (model.name, model.min_samples) == ('homography', 4)


def test_data_pairs_the_first_and_the_last_frame_and_rejects_nan(model):
    tracks = np.arange(4 * 3 * 2, dtype=float).reshape(4, 3, 2)
    np.testing.assert_array_equal(model.data(tracks), np.hstack([tracks[0], tracks[3]]))
    tracks[2, 1, 0] = np.nan
    with pytest.raises(InputError, match='tracks'):
        model.data(tracks)


@pytest.mark.parametrize('kind', ['planar', 'rotation'])
def test_fit_minimal_recovers_the_true_homography_from_four_exact_points(model, scene, align,
                                                                         kind):
    truth = scene(n=40, kind=kind, seed=1)
    params, ok = model.fit_minimal(truth.data, np.arange(40).reshape(10, 4))
    assert params.shape == (10, 3, 3) and ok.all()
    for H in params:
        np.testing.assert_allclose(align(H, truth.H), truth.H, atol=1e-8)
    assert model.residuals(truth.data, params).max() < 1e-6


def test_fit_minimal_batch_equals_one_sample_at_a_time(model, scene):
    truth = scene(n=300, kind='planar', noise=0.5, seed=2)
    samples = np.random.default_rng(2).integers(0, 300, (50, 4))
    assert_batch_equals_singles(model, truth.data, samples, (0, 23, 49))


def test_fit_minimal_flags_degenerate_samples_without_raising(model, scene):
    truth = scene(n=8, kind='planar', seed=3)
    line = np.column_stack([np.linspace(50, 600, 4), np.linspace(400, 60, 4)])
    general = truth.data[:4].copy()
    three_on_a_line = general.copy()
    three_on_a_line[:3, :2] = line[:3]  # collinear in the first image only
    collinear = np.hstack([line, transfer(truth.H, line)])  # collinear in both images
    data = np.vstack([general, three_on_a_line, collinear])
    samples = np.array([[0, 1, 2, 2], [0, 0, 0, 0], [4, 5, 6, 7], [8, 9, 10, 11], [0, 1, 2, 3]])
    with np.errstate(all='raise'):
        params, ok = model.fit_minimal(data, samples)
    assert ok.tolist() == [False, False, False, False, True]
    assert np.all(np.isfinite(params))
    np.testing.assert_array_equal(model.residuals(data, params[:1]), FAR)


def test_fit_minimal_flags_a_sample_collinear_in_the_second_image_only(model, scene):
    truth = scene(n=4, kind='planar', seed=4)
    data = truth.data.copy()
    data[[0, 2, 3], 2:] = [[10.0, 20.0], [110.0, 70.0], [310.0, 170.0]]
    _, ok = model.fit_minimal(data, np.arange(4)[None])
    assert not ok[0]


def test_fit_minimal_flags_a_sample_collinear_to_a_hundredth_of_a_pixel(model, scene):
    # Exactly collinear samples also fail the rank tests; a point 0.01 px off the line does not,
    # yet the H it gives is determined by noise alone.
    truth = scene(n=4, kind='planar', seed=5)
    line = np.column_stack([np.linspace(50, 600, 3), np.linspace(400, 60, 3)])
    normal = np.array([340.0, 550.0]) / np.hypot(340.0, 550.0)
    data = truth.data.copy()
    data[:3, :2] = line + np.outer([0.0, 0.01, 0.0], normal)
    data[:3, 2:] = transfer(truth.H, data[:3, :2])
    _, ok = model.fit_minimal(data, np.arange(4)[None])
    assert not ok[0]
    far_off = data.copy()
    far_off[1, :2] += 20.0 * normal  # 20 px off the line: a fine sample
    far_off[1, 2:] = transfer(truth.H, far_off[1:2, :2])[0]
    assert model.fit_minimal(far_off, np.arange(4)[None])[1][0]


@pytest.mark.parametrize('samples', [np.arange(3)[None], np.arange(4.0)[None],
                                     np.array([[0, 1, 2, 9]])])
def test_fit_minimal_rejects_malformed_samples_naming_them(model, scene, samples):
    with pytest.raises(InputError, match='samples'):
        model.fit_minimal(scene(n=9, kind='planar').data, samples)


# residuals -------------------------------------------------------------------------------


def test_residuals_are_the_exact_distance_for_an_affine_homography(model):
    # For x2 = A x1 + b the model is a 2-D plane in R^4 and the Sampson distance is exact:
    # the least-squares distance min_u |x1 - u|^2 + |x2 - A u - b|^2.
    rng = np.random.default_rng(5)
    A, b = np.array([[1.1, 0.2], [-0.1, 0.9]]), np.array([12.0, -7.0])
    H = np.block([[A, b[:, None]], [np.zeros((1, 2)), np.ones((1, 1))]])
    rows = rng.uniform(0, 640, (50, 4))
    expected = []
    for z in rows:
        design = np.vstack([np.eye(2), A])
        target = np.r_[z[:2], z[2:] - b]
        u = np.linalg.lstsq(design, target, rcond=None)[0]
        expected.append(np.linalg.norm(design @ u - target))
    np.testing.assert_allclose(model.residuals(rows, H[None])[0], expected, rtol=1e-9)


def test_residuals_equal_sampson_from_a_finite_difference_jacobian(model, scene):
    rng = np.random.default_rng(6)
    truth = scene(n=30, kind='planar', noise=3.0, seed=6)
    rows = np.vstack([truth.data, rng.uniform(0, 640, (30, 4))])
    projective = np.eye(3) + rng.normal(0, [[0.1, 0.1, 20], [0.1, 0.1, 20], [1e-4, 1e-4, 0.1]])
    for H in (truth.H, projective):
        expected = sampson_sq_by_differences(H, rows)
        np.testing.assert_allclose(model.residuals(rows, H[None])[0] ** 2, expected, rtol=1e-8)


def test_residuals_approximate_the_reprojection_distance_for_small_errors(model, scene):
    truth = scene(n=20, kind='planar', seed=7)
    offsets = np.random.default_rng(7).normal(0.0, 0.5, truth.clean.shape)
    rows = truth.clean + offsets
    sampson = model.residuals(rows, truth.H[None])[0]
    for n in range(20):
        gold = reprojection_distance(truth.H, rows[n])
        assert gold <= np.linalg.norm(offsets[n]) + 1e-9
        assert sampson[n] == pytest.approx(gold, rel=1e-2, abs=1e-4)


def test_median_residual_of_the_true_homography_matches_the_noise(model, scene):
    # Two constraints, noise sigma in all 4 coordinates: the squared Sampson distance is
    # ~ sigma^2 chi^2_2 to first order, whose median distance is sigma sqrt(2 ln 2).
    sigma = 0.5
    truth = scene(n=4000, kind='rotation', noise=sigma, seed=8)
    median = np.median(model.residuals(truth.data, truth.H[None]))
    assert median == pytest.approx(np.sqrt(2 * np.log(2)) * sigma, rel=0.06)


def test_residuals_are_finite_where_the_homography_sends_points_to_infinity(model):
    H = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])  # x1 = 0 -> infinity
    rows = np.array([[0.0, 5.0, 3.0, 4.0], [2.0, 5.0, 1.0, 2.5], [1.0, 1.0, 1.0, 1.0]])
    with np.errstate(all='raise'):
        residuals = model.residuals(rows, np.stack([H, np.zeros((3, 3))]))
    assert np.all(np.isfinite(residuals)) and np.all(residuals <= FAR)
    assert residuals[0, 1] < 1e-12  # (2, 5) -> (1, 2.5) exactly
    assert residuals[1].tolist() == [FAR, FAR, FAR]


# refit -----------------------------------------------------------------------------------


@pytest.mark.parametrize('kind', ['planar', 'rotation'])
def test_refit_cost_is_no_higher_than_the_linear_dlt(model, scene, kind):
    for seed in range(5):
        truth = scene(n=200, kind=kind, noise=1.0, seed=10 + seed)
        linear = dlt(truth.data)
        refitted = model.refit(truth.data, np.arange(200), linear)
        assert refitted is not None
        cost, linear_cost = sum_sq(model, truth.data, refitted), sum_sq(model, truth.data, linear)
        assert cost <= linear_cost * (1 + 1e-9)


def test_refit_ends_at_a_local_minimum_of_the_sampson_cost(model, scene):
    # No small perturbation may lower the cost: at a minimum it changes by O(step^2) >= 0, while
    # at a non-stationary point (the algebraic DLT fit) some directions lower it.
    truth = scene(n=200, kind='planar', noise=1.0, seed=15)
    rng = np.random.default_rng(15)
    T1, T2 = similarity(truth.data[:, :2]), similarity(truth.data[:, 2:])
    T1_inv, T2_inv = np.linalg.inv(T1), np.linalg.inv(T2)

    def directions_that_lower_the_cost(H: np.ndarray) -> int:
        cost, lowered = sum_sq(model, truth.data, H), 0
        Hn = T2 @ H @ T1_inv  # perturbed in normalised coordinates, where entries are balanced
        for _ in range(40):
            perturbed = T2_inv @ (Hn + 1e-5 * np.linalg.norm(Hn) * rng.normal(size=(3, 3))) @ T1
            lowered += sum_sq(model, truth.data, perturbed) < cost * (1 - 1e-9)
        return lowered

    linear = dlt(truth.data)
    assert directions_that_lower_the_cost(linear) > 0  # the probe can tell
    assert directions_that_lower_the_cost(model.refit(truth.data, np.arange(200), linear)) == 0


def test_refit_recovers_the_truth_when_outliers_are_excluded(model, scene):
    rng = np.random.default_rng(20)
    truth = scene(n=260, kind='planar', noise=1.0, seed=20)
    data = truth.data.copy()
    outliers = np.arange(200, 260)
    data[outliers, 2:] = rng.uniform([0, 0], [640, 480], (60, 2))
    start = dlt(data[190:230])  # fitted through outliers: refit must not be tied to it
    refitted = model.refit(data, np.arange(200), start)
    assert refitted is not None
    assert rms(model, truth.clean, refitted) < 0.3
    assert np.median(model.residuals(data, refitted[None])[0, outliers]) > 10.0
    assert rms(model, truth.clean, model.refit(data, np.arange(260), start)) > 1.0


def test_refit_of_exact_points_returns_the_true_homography(model, scene, align):
    truth = scene(n=30, kind='rotation', seed=21)
    for inliers in (np.arange(4), np.arange(30)):
        refitted = model.refit(truth.data, inliers, np.zeros((3, 3)))
        np.testing.assert_allclose(align(refitted, truth.H), truth.H, atol=1e-8)
        assert np.linalg.norm(refitted) == pytest.approx(1.0)


def test_refit_returns_none_for_too_few_or_collinear_inliers(model, scene):
    truth = scene(n=20, kind='planar', seed=22)
    assert model.refit(truth.data, np.arange(3), truth.H) is None
    line = np.column_stack([np.linspace(50, 600, 20), np.linspace(400, 60, 20)])
    collinear = np.hstack([line, transfer(truth.H, line)])
    with np.errstate(all='raise'):
        assert model.refit(collinear, np.arange(20), truth.H) is None


def test_refit_rejects_malformed_params_naming_them(model, scene):
    with pytest.raises(InputError, match='params'):
        model.refit(scene(n=20, kind='planar').data, np.arange(20), np.eye(3)[None])
