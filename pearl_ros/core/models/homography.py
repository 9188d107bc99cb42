"""The homography between the first and the last frame: a plane, or a camera that only rotates.

Points of a 3-D plane, or any points seen by a camera rotating about its centre, map between two
views by a projective transformation ``x2 ~ H x1`` (H&Z sec. 13.1, 8.4.2). Hypotheses come from
the Hartley-normalised 4-point DLT (H&Z alg. 4.2). Residuals are Sampson distances in pixels
(H&Z sec. 4.2.6), as for the fundamental matrix: the first-order distance in R^4 from
``(x1, y1, x2, y2)`` to the nearest correspondence mapped exactly by H, with noise in both
images. One noise scale then means the same for every two-view model, and unlike the symmetric
transfer error it needs no inverse of H. For an affine H the constraint is linear in the point
and the Sampson distance is exact. Refits run Levenberg-Marquardt on that error.

References
----------
R. I. Hartley, "In defense of the eight-point algorithm", IEEE TPAMI 19(6):580-593, 1997.
R. Hartley and A. Zisserman, *Multiple View Geometry in Computer Vision*, 2nd ed., Cambridge
University Press, 2003: sec. 4.1 (DLT), 4.2.6 (Sampson error), 4.4 (normalisation).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import ClassVar

import numpy as np

from pearl_ros.core.config import SolverSettings
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

# Smallest triangle area, in Hartley-normalised units, of any 3 of the 4 points of a minimal
# sample in either image; below it the sample counts as collinear. A well-spread sample has
# areas ~1-2; 1e-3 is, for a sample spanning 640 px, a point 0.06 px off the line through two
# others: collinear far below pixel noise, and a DLT on it gives a (near-)singular H.
_COLLINEAR_TOL = 1e-3

# The 4 triangles of a 4-point sample.
_TRIPLES = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]])


class Homography(TwoViewModel):
    """Homographies ``H`` (K, 3, 3) with ``x2 ~ H x1``; unit Frobenius norm, non-singular.

    ``x1`` is a point in the first frame of the tracks and ``x2`` the same point in the last.
    """

    name: ClassVar[str] = 'homography'
    min_samples: int = 4

    def _cost_weight(self, settings: SolverSettings) -> float:
        """``homography_cost_weight`` (1)."""
        return settings.homography_cost_weight

    def _linear(self, rows: np.ndarray, minimal: bool) -> tuple[np.ndarray, np.ndarray]:
        """Normalised DLT on each of ``rows`` (K, m, 4), m >= 4, pixels (H&Z alg. 4.2).

        Each sample is normalised on its own points (see :class:`Fundamental` for why).
        """
        num, m, _ = rows.shape
        p1, T1, _, ok1 = normalise(rows[:, :, :2])
        p2, _, T2_inv, ok2 = normalise(rows[:, :, 2:])
        x1 = homogeneous(p1)  # (K, m, 3)
        u, v = p2[:, :, 0:1], p2[:, :, 1:2]
        zero = np.zeros_like(x1)
        # Two independent rows of x2 x (H x1) = 0 per point, h = row-major vec(H) (H&Z eq. 4.3).
        first = np.concatenate([zero, -x1, v * x1], axis=2)
        second = np.concatenate([x1, zero, -u * x1], axis=2)
        design = np.stack([first, second], axis=2).reshape(num, 2 * m, 9)
        h, ok = null_vectors(design)
        normalised = h.reshape(num, 3, 3)
        # A singular H maps the plane onto a line: no motion of a rigid plane.
        s = np.linalg.svd(normalised, compute_uv=False)
        ok &= s[:, 2] > RANK_TOL * s[:, 0]
        if minimal:
            # 3 collinear points of 4 leave the design matrix of full rank but H singular or
            # arbitrary; test them directly rather than trust a threshold on H.
            ok &= _smallest_triangle(p1) > _COLLINEAR_TOL
            ok &= _smallest_triangle(p2) > _COLLINEAR_TOL
        # x2n ~ Hn x1n  =>  x2 ~ (T2^-1 Hn T1) x1: undo the normalisation.
        matrices, ok_norm = unit_frobenius(T2_inv @ normalised @ T1)
        ok &= ok1 & ok2 & ok_norm
        return np.where(ok[:, None, None], matrices, 0.0), ok

    def _terms(self, matrices: np.ndarray, data: np.ndarray) -> tuple[np.ndarray, ...]:
        """Algebraic errors ``e1, e2`` and entries ``a, b, c`` of ``J J^T``, each (K, N).

        With ``x2 = (x', y', 1)`` and ``w = (H x1)_3``, the two independent rows of
        ``x2 x (H x1) = 0`` are ``e1 = y' w - (H x1)_2`` and ``e2 = (H x1)_1 - x' w``; J is their
        Jacobian with respect to ``(x1, y1, x', y')`` (H&Z sec. 4.2.6).
        """
        mapped = homogeneous(data[:, :2]) @ np.swapaxes(matrices, 1, 2)  # (K, N, 3): H x1
        xp, yp = data[None, :, 2], data[None, :, 3]
        w = mapped[..., 2]
        e1 = yp * w - mapped[..., 1]
        e2 = mapped[..., 0] - xp * w
        h = matrices[:, :, :, None]  # (K, 3, 3, 1) broadcasts against (K, N)
        # Rows of J: (de/dx1, de/dy1, de/dx', de/dy') = (j_x, j_y, 0, w) and (k_x, k_y, -w, 0).
        j_x, j_y = yp * h[:, 2, 0] - h[:, 1, 0], yp * h[:, 2, 1] - h[:, 1, 1]
        k_x, k_y = h[:, 0, 0] - xp * h[:, 2, 0], h[:, 0, 1] - xp * h[:, 2, 1]
        w_sq = w**2
        a = j_x**2 + j_y**2 + w_sq
        b = j_x * k_x + j_y * k_y
        c = k_x**2 + k_y**2 + w_sq
        return e1, e2, a, b, c

    def _distances(self, matrices: np.ndarray, data: np.ndarray) -> np.ndarray:
        e1, e2, a, b, c = self._terms(matrices, data)
        det = a * c - b**2
        # e^T (J J^T)^-1 e with the 2 x 2 inverse written out. A singular J J^T (e.g. a point
        # that H sends to infinity with degenerate derivatives) is not measurable: FAR.
        with np.errstate(divide='ignore', invalid='ignore'):
            dist_sq = np.maximum(c * e1**2 - 2.0 * b * e1 * e2 + a * e2**2, 0.0) / det
            return clip_far(np.sqrt(np.where(det > 0.0, dist_sq, np.inf)))

    def _whitened(self, matrices: np.ndarray, data: np.ndarray) -> np.ndarray:
        e1, e2, a, b, c = self._terms(matrices, data)
        det = a * c - b**2
        # L^-1 e with J J^T = L L^T (Cholesky): squared norm = e^T (J J^T)^-1 e.
        with np.errstate(divide='ignore', invalid='ignore'):
            r1 = e1 / np.sqrt(a)
            r2 = (a * e2 - b * e1) / np.sqrt(np.where(det > 0.0, a * det, 0.0))
        return clip_far(np.concatenate([r1, r2], axis=1))

    def _chart(self, matrix: np.ndarray, sims: Similarities
               ) -> tuple[np.ndarray, Callable[[np.ndarray], np.ndarray]]:
        """``hn + B p``: 8 steps orthogonal to the start in normalised coordinates.

        H has 8 degrees of freedom and the Sampson error ignores its scale, so the step along
        ``hn`` itself is dropped; B (8 x 9) is an orthonormal basis of its complement. Unlike
        fixing ``H[2, 2] = 1`` this has no singular start.
        """
        hn = (sims.T2 @ matrix @ sims.T1_inv).ravel()
        hn /= np.linalg.norm(hn)
        basis = np.linalg.svd(hn[None, :])[2][1:]  # (8, 9), rows orthogonal to hn

        def matrices_of(p: np.ndarray) -> np.ndarray:
            normalised = (hn + p @ basis).reshape(-1, 3, 3)
            pixels: np.ndarray = sims.T2_inv @ normalised @ sims.T1
            return pixels

        return np.zeros(8), matrices_of

    def _admissible(self, matrix: np.ndarray, sims: Similarities) -> bool:
        s = np.linalg.svd(sims.T2 @ matrix @ sims.T1_inv, compute_uv=False)
        return bool(s[2] > RANK_TOL * s[0])


def _smallest_triangle(points: np.ndarray) -> np.ndarray:
    """Smallest area ``(K,)`` of the 4 triangles of each 4-point set ``(K, 4, 2)``."""
    corners = points[:, _TRIPLES]  # (K, 4, 3, 2)
    d1 = corners[:, :, 1] - corners[:, :, 0]
    d2 = corners[:, :, 2] - corners[:, :, 0]
    area: np.ndarray = 0.5 * np.abs(d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0]).min(axis=1)
    return area
