"""Shared machinery of the two-view models: the fundamental matrix and the homography.

Both models see a track only through its first and its last frame, and both fit a 3 x 3 matrix
by a Hartley-normalised direct linear transform (DLT), then polish it by Levenberg-Marquardt on
the Sampson error. What the two have in common lives here once: the data rows, argument checks,
the normalising similarity, the DLT null vector with its rank test, and the batched LM driver.

References
----------
R. I. Hartley, "In defense of the eight-point algorithm", IEEE TPAMI 19(6):580-593, 1997.
R. Hartley and A. Zisserman, *Multiple View Geometry in Computer Vision*, 2nd ed., Cambridge
University Press, 2003: sec. 4.1 (DLT), 4.2.6 (Sampson error), 4.4 (normalisation), 11.1-11.4
(fundamental matrix).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import ClassVar, NamedTuple

import numpy as np
from scipy.optimize import leastsq

from pearl_ros.core.config import SolverSettings, default_solver
from pearl_ros.core.errors import InputError
from pearl_ros.core.models.base import check_groups, check_tracks

# px; the residual reported where a model cannot measure a point (zero gradient of the
# constraint, a point mapped to infinity). Large enough to lose to the outlier label, finite so
# that squared costs never become inf or NaN.
FAR = 1e6

# A design matrix is rank-deficient (its null space, hence the fitted matrix, is not unique) when
# its second-smallest singular value of nine is below this share of the largest one. Exactly
# degenerate samples reach ~1e-15 in float64; a well-spread normalised sample sits at 1e-3..1e-1.
RANK_TOL = 1e-8

# Relative step of the forward-difference Jacobian. Parameters live in Hartley-normalised units
# (order 1), where sqrt(machine epsilon) ~ 1.5e-8 balances truncation and rounding error.
_FD_STEP = 1.5e-8
_LM_TOL = 1e-8  # least_squares' default ftol, xtol and gtol


def two_view_data(tracks: np.ndarray) -> np.ndarray:
    """Rows ``[x1, y1, x2, y2]`` ``(N, 4)`` from the first and last frame of ``tracks``.

    Parameters
    ----------
    tracks : (F, N, 2) array_like, pixels, F >= 2, finite

    Returns
    -------
    (N, 4) float64, pixels
    """
    tracks = check_tracks(tracks, min_frames=2)
    return np.concatenate([tracks[0], tracks[-1]], axis=1)


def check_data(data: np.ndarray) -> np.ndarray:
    """Validate ``data`` rows ``(N, 4)`` as built by :func:`two_view_data`; returns float64."""
    data = np.asarray(data, dtype=np.float64)
    if data.ndim != 2 or data.shape[1] != 4:
        raise InputError(f'data must have shape (N, 4) [x1, y1, x2, y2], got {data.shape}')
    if not np.all(np.isfinite(data)):
        raise InputError('data must be finite (no NaN or inf coordinates)')
    return data


def check_samples(samples: np.ndarray, num_points: int, min_samples: int) -> np.ndarray:
    """Validate ``samples`` ``(K, min_samples)`` integer indices into ``num_points`` rows."""
    samples = np.asarray(samples)
    if samples.ndim != 2 or samples.shape[1] != min_samples:
        raise InputError(f'samples must have shape (K, {min_samples}), got {samples.shape}')
    return _check_index_values('samples', samples, num_points)


def check_inliers(inliers: np.ndarray, num_points: int) -> np.ndarray:
    """Validate ``inliers`` ``(M,)`` integer indices into ``num_points`` rows."""
    inliers = np.asarray(inliers)
    if inliers.ndim != 1:
        raise InputError(f'inliers must be a 1-D array of indices, got shape {inliers.shape}')
    return _check_index_values('inliers', inliers, num_points)


def _check_index_values(name: str, indices: np.ndarray, num_points: int) -> np.ndarray:
    """Integer dtype and values in [0, num_points) for the index array called ``name``."""
    if indices.size and not np.issubdtype(indices.dtype, np.integer):
        raise InputError(f'{name} must be integer indices, got dtype {indices.dtype}')
    if indices.size and (indices.min() < 0 or indices.max() >= num_points):
        raise InputError(f'{name} must index rows in [0, {num_points}), got values in '
                         f'[{indices.min()}, {indices.max()}]')
    return indices.astype(np.intp, copy=False)


def check_matrices(params: np.ndarray, *, batched: bool) -> np.ndarray:
    """Validate ``params`` ``(K, 3, 3)`` (``batched``) or ``(3, 3)``; returns float64."""
    params = np.asarray(params, dtype=np.float64)
    shape = (*params.shape[:1], 3, 3) if batched else (3, 3)
    if params.shape != shape:
        want = '(K, 3, 3)' if batched else '(3, 3)'
        raise InputError(f'params must have shape {want}, got {params.shape}')
    return params


def homogeneous(points: np.ndarray) -> np.ndarray:
    """``(..., 2)`` -> ``(..., 3)`` with a trailing 1."""
    return np.concatenate([points, np.ones((*points.shape[:-1], 1))], axis=-1)


def normalise(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Hartley's normalisation of each point set (Hartley 1997, sec. 5; H&Z sec. 4.4.4).

    The centroid moves to the origin and the mean distance from it becomes sqrt(2), so that the
    entries of the DLT design matrix have comparable magnitudes.

    Parameters
    ----------
    points : (K, m, 2) float64, pixels

    Returns
    -------
    normalised : (K, m, 2) float64, normalised units
    T : (K, 3, 3) float64, similarity with ``x_normalised ~ T @ x``
    T_inv : (K, 3, 3) float64, its inverse
    ok : (K,) bool, False where the points coincide (no scale can be defined)
    """
    centroid = points.mean(axis=1)  # (K, 2)
    centred = points - centroid[:, None, :]
    spread = np.linalg.norm(centred, axis=-1).mean(axis=1)  # (K,)
    # Relative to the centroid's magnitude: coincident points leave only rounding error here.
    ok = spread > 1e-9 * (1.0 + np.abs(centroid).max(axis=1))
    scale = np.sqrt(2.0) / np.where(ok, spread, 1.0)
    num = points.shape[0]
    T = np.zeros((num, 3, 3))
    T[:, 0, 0] = T[:, 1, 1] = scale
    T[:, :2, 2] = -scale[:, None] * centroid
    T[:, 2, 2] = 1.0
    T_inv = np.zeros((num, 3, 3))
    T_inv[:, 0, 0] = T_inv[:, 1, 1] = 1.0 / scale
    T_inv[:, :2, 2] = centroid
    T_inv[:, 2, 2] = 1.0
    return centred * scale[:, None, None], T, T_inv, ok


def null_vectors(design: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit right null vector of each DLT design matrix, and whether it is unique.

    Parameters
    ----------
    design : (K, r, 9) float64, r >= 8

    Returns
    -------
    vectors : (K, 9) float64, right singular vector of the smallest singular value
    ok : (K,) bool, False where the design matrix has rank < 8 (a 2-D or larger null space)
    """
    # Only with fewer than 9 rows are the full V^T needed to reach the null vector; with many rows
    # (refit) the thin SVD avoids forming an r x r U.
    _, s, vt = np.linalg.svd(design, full_matrices=design.shape[1] < 9)
    ok = s[:, 7] > RANK_TOL * s[:, 0]
    return vt[:, -1, :], ok


def unit_frobenius(matrices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Scale each ``(K, 3, 3)`` matrix to unit Frobenius norm; ok False for zero or non-finite."""
    norm = np.sqrt(np.einsum('kij,kij->k', matrices, matrices))
    ok = np.isfinite(norm) & (norm > 0.0)
    return matrices / np.where(ok, norm, 1.0)[:, None, None], ok


def clip_far(values: np.ndarray) -> np.ndarray:
    """Replace NaN and values beyond +-FAR by +-FAR (NaN -> FAR)."""
    return np.where(np.abs(values) < FAR, values, np.where(values < 0, -FAR, FAR))


def refine_lm(residuals_of: Callable[[np.ndarray], np.ndarray], start: np.ndarray,
              max_nfev: int) -> np.ndarray:
    """Levenberg-Marquardt (MINPACK, via scipy) from ``start``; returns the final parameters.

    Parameters
    ----------
    residuals_of : callable, (B, P) float64 -> (B, R) float64
        Residual vectors of B parameter vectors at once; R >= P. Batching lets the
        forward-difference Jacobian cost one call instead of P.
    start : (P,) float64
    max_nfev : int
        Cap on residual evaluations (Jacobians are not counted): bounds the time of one refit.

    Returns
    -------
    (P,) float64
    """

    def fun(p: np.ndarray) -> np.ndarray:
        row: np.ndarray = residuals_of(p[None])[0]
        return row

    def jac(p: np.ndarray) -> np.ndarray:
        step = _FD_STEP * np.maximum(1.0, np.abs(p))
        batch = np.vstack([p, p + np.diag(step)])
        r = residuals_of(batch)
        jacobian: np.ndarray = ((r[1:] - r[0]) / step[:, None]).T
        return jacobian

    # MINPACK's lmder as least_squares(method='lm') calls it (full output, tolerances 1e-8,
    # step bound factor 100, scaling from the Jacobian), without that wrapper's per-call
    # overhead (a tenth of a two-view fit) and its Jacobian after the end: the same steps, to
    # the bit. Reaching max_nfev is no failure here: the cap bounds a refit's time.
    found: np.ndarray = leastsq(fun, start, Dfun=jac, full_output=True, ftol=_LM_TOL,
                                xtol=_LM_TOL, gtol=_LM_TOL, maxfev=max_nfev)[0]
    return found


class Similarities(NamedTuple):
    """Hartley normalisations of one set of correspondences, ``(3, 3)`` each."""

    T1: np.ndarray  # image 1: x1_normalised ~ T1 @ x1
    T1_inv: np.ndarray
    T2: np.ndarray  # image 2: x2_normalised ~ T2 @ x2
    T2_inv: np.ndarray


class TwoViewModel:
    """What the fundamental matrix and the homography share: data, checks, residuals, refit.

    A subclass supplies the maths through five hooks: ``_linear`` (batched normalised DLT),
    ``_distances`` (Sampson distances in pixels), ``_whitened`` (signed residual vectors whose
    squares sum to the squared Sampson distances, for LM), ``_chart`` (a local parameterisation
    of the admissible matrices around a start) and ``_admissible`` (rank test of a result).
    Parameters are ``(K, 3, 3)`` float64 matrices of unit Frobenius norm, defined up to sign.

    Parameters
    ----------
    settings : SolverSettings, optional
        ``lm_max_nfev`` caps each refit; a subclass reads its label cost weight from it.
    """

    min_samples: int
    refit_from_start: ClassVar[bool] = True  # Levenberg-Marquardt from the given params

    def __init__(self, settings: SolverSettings | None = None) -> None:
        settings = settings or default_solver()
        # Residual evaluations per LM refit: a few ms for 500 inliers, and a refit runs for
        # every model in every PEaRL iteration. LM from the linear estimate converges in a
        # handful of steps.
        self.max_nfev = settings.lm_max_nfev
        self.cost_weight = self._cost_weight(settings)

    def data(self, tracks: np.ndarray) -> np.ndarray:
        """Rows ``[x1, y1, x2, y2]`` ``(N, 4)`` float64 pixels: first and last frame of ``tracks``.

        Parameters
        ----------
        tracks : (F, N, 2) array_like, pixels, F >= 2, finite

        Raises
        ------
        InputError
            If ``tracks`` has the wrong shape, fewer than 2 frames or non-finite values.
        """
        return two_view_data(tracks)

    def fit_minimal(self, data: np.ndarray, samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One hypothesis per minimal sample, by the normalised DLT.

        Parameters
        ----------
        data : (N, 4) float64, pixels, rows of :meth:`data`
        samples : (K, min_samples) int, row indices

        Returns
        -------
        params : (K, 3, 3) float64, unit Frobenius norm; zero matrices where ``ok`` is False
            (their residuals are FAR for every point, so a caller that forgets the mask loses
            nothing but time)
        ok : (K,) bool, False for degenerate samples; never raises on degenerate data
        """
        data = check_data(data)
        samples = check_samples(samples, data.shape[0], self.min_samples)
        return self._linear(data[samples], minimal=True)

    def fit_groups(self, data: np.ndarray, groups: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The normalised DLT of each row of ``groups`` ``(K, m)``, m >= min_samples, batched:
        the linear start of :meth:`refit` without its Levenberg-Marquardt refinement."""
        rows = self._group_rows(data, groups)
        return self._linear(rows, minimal=rows.shape[1] == self.min_samples)

    def _group_rows(self, data: np.ndarray, groups: np.ndarray) -> np.ndarray:
        """The data rows ``(K, m, 4)`` of validated ``groups`` ``(K, m)``."""
        data = check_data(data)
        groups = check_groups(groups, self.min_samples)
        check_inliers(groups.reshape(-1), data.shape[0])
        rows: np.ndarray = data[groups]
        return rows

    def label_cost_weight(self, data: np.ndarray) -> float:
        """The subclass's weight from the settings: two views are one fixed amount of evidence,
        whatever the data."""
        return self.cost_weight

    def residual_dof(self, data: np.ndarray) -> float:
        """1: the Sampson distance is a first-order distance to a codimension-1 variety."""
        return 1.0

    def residuals(self, data: np.ndarray, params: np.ndarray) -> np.ndarray:
        """Sampson distances ``(K, N)`` float64 in pixels, finite (at most FAR).

        Parameters
        ----------
        data : (N, 4) float64, pixels, rows of :meth:`data`
        params : (K, 3, 3) float64, any scale and sign
        """
        return self._distances(check_matrices(params, batched=True), check_data(data))

    def refit(self, data: np.ndarray, inliers: np.ndarray,
              params: np.ndarray) -> np.ndarray | None:
        """Re-estimate one hypothesis from its inliers: linear fit, then LM on the Sampson error.

        LM starts from whichever of the normalised linear fit on ``inliers`` and ``params`` has
        the lower Sampson cost (``params`` may be far off when the inliers changed a lot), and
        its result is kept only if it does not raise that cost. The sum of squared Sampson
        distances is what PEaRL's data term ``(r / noise)^2`` sums over the inliers (Isack &
        Boykov 2012), so a refit lowers the energy whenever the labels stay put.

        Parameters
        ----------
        data : (N, 4) float64, pixels, rows of :meth:`data`
        inliers : (M,) int, row indices
        params : (3, 3) float64, the current hypothesis

        Returns
        -------
        (3, 3) float64 with unit Frobenius norm, or None when fewer than ``min_samples``
        inliers are given or they are degenerate.
        """
        data = check_data(data)
        inliers = check_inliers(inliers, data.shape[0])
        params = check_matrices(params, batched=False)
        if inliers.size < self.min_samples:
            return None
        rows = data[inliers]
        linear, ok = self._linear(rows[None], minimal=False)
        if not ok[0]:
            return None
        _, T1, T1_inv, _ = normalise(rows[None, :, :2])
        _, T2, T2_inv, _ = normalise(rows[None, :, 2:])
        sims = Similarities(T1[0], T1_inv[0], T2[0], T2_inv[0])

        candidates = [linear[0]]
        given, ok_given = unit_frobenius(params[None])
        if ok_given[0]:
            candidates.append(given[0])
        charts = [self._chart(matrix, sims) for matrix in candidates]
        costs = [float(np.sum(self._whitened(chart(p0[None]), rows) ** 2)) for p0, chart in charts]
        best = int(np.argmin(costs))
        (p0, matrices_of), cost = charts[best], costs[best]

        p = refine_lm(lambda batch: self._whitened(matrices_of(batch), rows), p0, self.max_nfev)
        result = matrices_of(p[None])
        if not float(np.sum(self._whitened(result, rows) ** 2)) <= cost:
            result = matrices_of(p0[None])
        result, ok = unit_frobenius(result)
        if not (ok[0] and self._admissible(result[0], sims)):
            return None
        matrix: np.ndarray = result[0]
        return matrix

    # Hooks ----------------------------------------------------------------------------------

    def _cost_weight(self, settings: SolverSettings) -> float:
        """The factor on the configured label cost, from ``settings``."""
        raise NotImplementedError

    def _linear(self, rows: np.ndarray, minimal: bool) -> tuple[np.ndarray, np.ndarray]:
        """Normalised DLT per sample: rows ``(K, m, 4)`` -> ``(K, 3, 3)``, ok ``(K,)``."""
        raise NotImplementedError

    def _distances(self, matrices: np.ndarray, data: np.ndarray) -> np.ndarray:
        """Sampson distances ``(K, N)`` in pixels."""
        raise NotImplementedError

    def _whitened(self, matrices: np.ndarray, data: np.ndarray) -> np.ndarray:
        """Signed residuals ``(K, R)``; ``sum(r**2, axis=1)`` = sum of squared distances."""
        raise NotImplementedError

    def _chart(self, matrix: np.ndarray, sims: Similarities
               ) -> tuple[np.ndarray, Callable[[np.ndarray], np.ndarray]]:
        """Start ``p0`` ``(P,)`` and the map ``(B, P) -> (B, 3, 3)`` pixel matrices around it."""
        raise NotImplementedError

    def _admissible(self, matrix: np.ndarray, sims: Similarities) -> bool:
        """Whether a refitted ``(3, 3)`` matrix is a valid model (rank test)."""
        raise NotImplementedError
