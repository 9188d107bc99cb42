"""The fundamental matrix between the first and the last frame: a rigid motion seen in 3-D.

Corresponding points ``x1 <-> x2`` (homogeneous pixels) of one rigid body satisfy the epipolar
constraint ``x2^T F x1 = 0`` for a rank-2 matrix F (H&Z sec. 9.2). Hypotheses come from the
Hartley-normalised 8-point algorithm, rank 2 enforced by zeroing the smallest singular value
(Hartley 1997; H&Z alg. 11.1). Residuals are Sampson distances in pixels (H&Z eq. 11.9), the
first-order approximation of the distance in R^4 from ``(x1, y1, x2, y2)`` to the nearest
correspondence that satisfies F exactly. Refits run Levenberg-Marquardt on that error over the
rank-2 matrices in the orthonormal representation of Bartoli & Sturm (2004).

References
----------
R. I. Hartley, "In defense of the eight-point algorithm", IEEE TPAMI 19(6):580-593, 1997.
R. Hartley and A. Zisserman, *Multiple View Geometry in Computer Vision*, 2nd ed., Cambridge
University Press, 2003: sec. 4.2.6 (Sampson error), ch. 11 (computation of F).
A. Bartoli and P. Sturm, "Nonlinear estimation of the fundamental matrix with minimal
parameters", IEEE TPAMI 26(3):426-432, 2004.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import ClassVar

import numpy as np

from pearl_ros.core.config import SolverSettings, default_solver
from pearl_ros.core.models._twoview import (
    RANK_TOL,
    Similarities,
    TwoViewModel,
    clip_far,
    homogeneous,
    normalise,
    null_vectors,
    unit_frobenius,
)


class Fundamental(TwoViewModel):
    """Fundamental matrices ``F`` (K, 3, 3) with ``x2^T F x1 = 0``; unit Frobenius norm, rank 2.

    ``x1`` is a point in the first frame of the tracks and ``x2`` the same point in the last.
    """

    name: ClassVar[str] = 'fundamental'
    min_samples: int = 8

    def __init__(self, settings: SolverSettings | None = None) -> None:
        settings = settings or default_solver()
        super().__init__(settings)
        # Sampson-reweighted linear fits after the first in fit_groups (one is enough: more
        # change the Hopkins155 scales by < 3%).
        self.reweight_steps = settings.fundamental_reweight_steps

    def _cost_weight(self, settings: SolverSettings) -> float:
        """``fundamental_cost_weight``, 0.75: one epipolar constraint per point is weaker
        evidence than a long subspace.

        The Sampson residual measures one constraint per point (``residual_dof`` 1, against
        about 2 for a 30-frame affine subspace), so a second motion gains less data cost for
        the same misfit, and at the full label cost two-view fits merged motions. On
        Hopkins155 (first and last frames, seeds 0-2) 0.75 takes the mean from 6.65% to 6.25%
        and the 3-motion checkerboards from 13.85% to 11.68%; 0.5, 0.67 and 0.83 do worse
        (BENCHMARKS.md).
        """
        return settings.fundamental_cost_weight

    def fit_groups(self, data: np.ndarray, groups: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Linear fits of F to each group, all groups at once, for measuring noise levels.

        The 8-point fit *without* the rank-2 projection, then ``reweight_steps`` fits with each
        point's equation divided by its Sampson gradient norm at the previous estimate
        (iteratively reweighted least squares on the Sampson error). Projecting an 8-point fit
        of 11 points to rank 2 inflates their residuals 1.7-3x (Hopkins155 first and last
        frames); the unconstrained fit leaves them at 0.7-0.9x those of the rank-2 LM refit
        (which absorbs one parameter less), and the noise scale it gives serves PEaRL better
        (BENCHMARKS.md). The matrices are rank 3 in general: not hypotheses for PEaRL.
        """
        rows = self._group_rows(data, groups)
        matrices, ok = self._linear(rows, minimal=False, rank_two=False)
        for _ in range(self.reweight_steps):
            x1, x2 = homogeneous(rows[:, :, :2]), homogeneous(rows[:, :, 2:])
            lines2 = np.einsum('kij,kmj->kmi', matrices, x1)  # F x1
            lines1 = np.einsum('kji,kmj->kmi', matrices, x2)  # F^T x2
            grad_sq = (lines2[..., 0] ** 2 + lines2[..., 1] ** 2
                       + lines1[..., 0] ** 2 + lines1[..., 1] ** 2)
            typical = np.median(grad_sq, axis=1, keepdims=True)
            good = ok & np.all(np.isfinite(grad_sq), axis=1) & (typical[:, 0] > 0)
            safe = np.where(good[:, None], typical, 1.0)
            weights = safe / np.maximum(np.where(good[:, None], grad_sq, 1.0), 1e-6 * safe)
            again, ok_again = self._linear(rows, minimal=False, weights=weights,
                                           rank_two=False)
            update = good & ok_again
            matrices = np.where(update[:, None, None], again, matrices)
        return matrices, ok

    def _linear(self, rows: np.ndarray, minimal: bool, weights: np.ndarray | None = None,
                rank_two: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Normalised 8-point algorithm on each of ``rows`` (K, m, 4), m >= 8, pixels; each
        point's equation scaled by the square root of its ``weights`` (K, m) if given.

        Each sample is normalised on its own points, not on the whole data set: PEaRL draws many
        samples from small neighbourhoods (NAPSAC), which a data-set-wide normalisation would
        leave clustered in a corner, with a badly conditioned design matrix (Hartley 1997).
        """
        num, m, _ = rows.shape
        p1, T1, _, ok1 = normalise(rows[:, :, :2])
        p2, T2, _, ok2 = normalise(rows[:, :, 2:])
        x1, x2 = homogeneous(p1), homogeneous(p2)
        # Row-major f = vec(F): entry F[i, j] multiplies x2_i * x1_j in x2^T F x1 (H&Z eq. 11.3).
        design = (x2[:, :, :, None] * x1[:, :, None, :]).reshape(num, m, 9)
        if weights is not None:
            design = design * np.sqrt(weights)[:, :, None]
        f, ok = null_vectors(design)
        u, s, vt = np.linalg.svd(f.reshape(num, 3, 3))
        # Closest rank-2 matrix in Frobenius norm: drop the smallest singular value (H&Z 11.1.1).
        # A rank-1 result (second singular value ~0) is no fundamental matrix.
        ok &= s[:, 1] > RANK_TOL * s[:, 0]
        rank2 = (u[:, :, :2] * s[:, None, :2]) @ vt[:, :2, :] if rank_two else f.reshape(num, 3, 3)
        # x2n^T Fn x1n = x2^T (T2^T Fn T1) x1: undo the normalisation.
        matrices, ok_norm = unit_frobenius(np.swapaxes(T2, 1, 2) @ rank2 @ T1)
        ok &= ok1 & ok2 & ok_norm
        return np.where(ok[:, None, None], matrices, 0.0), ok

    def _terms(self, matrices: np.ndarray, data: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Epipolar residual ``x2^T F x1`` and its squared gradient norm in pixels, (K, N) each."""
        x1, x2 = homogeneous(data[:, :2]), homogeneous(data[:, 2:])
        lines2 = x1 @ np.swapaxes(matrices, 1, 2)  # (K, N, 3): epipolar lines F x1 in image 2
        lines1 = x2 @ matrices  # (K, N, 3): epipolar lines F^T x2 in image 1
        eps = np.einsum('knj,nj->kn', lines2, x2)
        # d eps / d(x1, y1, x2, y2) = ((F^T x2)_1, (F^T x2)_2, (F x1)_1, (F x1)_2) (H&Z eq. 11.9)
        grad_sq = (lines2[..., 0] ** 2 + lines2[..., 1] ** 2
                   + lines1[..., 0] ** 2 + lines1[..., 1] ** 2)
        return eps, grad_sq

    def _distances(self, matrices: np.ndarray, data: np.ndarray) -> np.ndarray:
        eps, grad_sq = self._terms(matrices, data)
        # A point at both epipoles has a zero gradient: not measurable, reported FAR.
        with np.errstate(divide='ignore', invalid='ignore'):
            return clip_far(np.abs(eps) / np.sqrt(grad_sq))

    def _whitened(self, matrices: np.ndarray, data: np.ndarray) -> np.ndarray:
        eps, grad_sq = self._terms(matrices, data)
        with np.errstate(divide='ignore', invalid='ignore'):
            return clip_far(eps / np.sqrt(grad_sq))

    def _chart(self, matrix: np.ndarray, sims: Similarities
               ) -> tuple[np.ndarray, Callable[[np.ndarray], np.ndarray]]:
        """Orthonormal representation ``Fn = U diag(1, sigma, 0) V^T`` (Bartoli & Sturm 2004).

        Seven parameters, as many as F has degrees of freedom: rotation vectors ``w_u``,
        ``w_v`` acting on the first two columns of U and V, and ``sigma``, the ratio of the two
        singular values. Every value gives rank <= 2, so no constraint is needed in LM. The
        chart lives in normalised coordinates, where the entries of Fn are balanced; the
        matrices it returns are in pixels.
        """
        normalised = sims.T2_inv.T @ matrix @ sims.T1_inv
        u, s, vt = np.linalg.svd(normalised)
        u2, v2 = u[:, :2], vt[:2].T
        start = np.zeros(7)
        start[6] = s[1] / s[0]

        def matrices_of(p: np.ndarray) -> np.ndarray:
            turns = _rotations(np.concatenate([p[:, 0:3], p[:, 3:6]]))  # both, in one call
            left = turns[:p.shape[0]] @ u2  # (B, 3, 2)
            right = turns[p.shape[0]:] @ v2
            singular = np.stack([np.ones(p.shape[0]), p[:, 6]], axis=1)  # (B, 2)
            fn = (left * singular[:, None, :]) @ np.swapaxes(right, 1, 2)
            pixels: np.ndarray = sims.T2.T @ fn @ sims.T1
            return pixels

        return start, matrices_of

    def _admissible(self, matrix: np.ndarray, sims: Similarities) -> bool:
        s = np.linalg.svd(sims.T2_inv.T @ matrix @ sims.T1_inv, compute_uv=False)
        return bool(s[1] > RANK_TOL * s[0])


def _rotations(w: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(B, 3, 3)`` of rotation vectors ``w`` ``(B, 3)`` (Rodrigues)."""
    theta_sq = np.einsum('bi,bi->b', w, w)
    theta = np.sqrt(theta_sq)
    small = theta < 1e-4
    safe = np.where(small, 1.0, theta)
    # sin(t)/t and (1 - cos(t))/t^2 by their Taylor series near 0, where the ratios lose digits.
    a = np.where(small, 1.0 - theta_sq / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta_sq / 24.0, (1.0 - np.cos(safe)) / safe**2)
    skew = np.zeros((w.shape[0], 3, 3))
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    skew -= np.swapaxes(skew, 1, 2)
    rotations: np.ndarray = np.eye(3) + a[:, None, None] * skew + b[:, None, None] * (skew @ skew)
    return rotations
