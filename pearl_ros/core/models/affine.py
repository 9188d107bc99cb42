"""Affine motion subspaces over N frames.

Under an affine camera the trajectories of the points of one rigid body, stacked as vectors of
R^(2F), lie in a 4-D linear subspace that contains the common translation; equivalently, in a 3-D
*affine* subspace (Tomasi & Kanade 1992; Tron & Vidal 2007). A hypothesis here is that 3-D affine
subspace: a point ``m`` and an orthonormal basis ``B`` (2F x 3), fitted from 4 trajectories.

The PEaRL thesis (Isack, sec. 2.3.3) projects trajectories to R^5 and fits 4-D hyperplanes there.
Measuring the distance in the full R^(2F) keeps every frame's evidence, and scaling it by
1/sqrt(F) turns it into a per-frame RMS image distance in pixels, the unit every model shares.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from pearl_ros.core.config import SolverSettings, default_solver
from pearl_ros.core.models.base import check_groups, check_tracks

# A sample whose 3 difference vectors have a singular value below this share of the largest
# spans less than 3 dimensions: its subspace is not determined.
_RANK_TOL = 1e-6


class AffineSubspace:
    """3-D affine subspaces of trajectory space; params ``(K, 2F, 4)``: mean, then basis.

    Parameters
    ----------
    settings : SolverSettings, optional
        ``affine_reference_frames`` and ``affine_cost_ceiling`` set the label cost weight.
    """

    name: ClassVar[str] = 'affine'
    min_samples = 4
    refit_from_start: ClassVar[bool] = False  # principal components of the inliers
    dim = 3

    def __init__(self, settings: SolverSettings | None = None) -> None:
        settings = settings or default_solver()
        self.reference_frames = settings.affine_reference_frames
        self.cost_ceiling = settings.affine_cost_ceiling

    def data(self, tracks: np.ndarray) -> np.ndarray:
        """Trajectories ``(N, 2F)`` scaled by 1/sqrt(F), so distances are RMS pixels per frame."""
        tracks = check_tracks(tracks, min_frames=2)
        num_frames, num_points, _ = tracks.shape
        rows = np.transpose(tracks, (1, 0, 2)).reshape(num_points, 2 * num_frames)
        scaled: np.ndarray = rows / np.sqrt(num_frames)
        return scaled

    def fit_minimal(self, data: np.ndarray, samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pts = data[samples]  # (K, 4, D)
        origin = pts[:, 0, :]
        diffs = np.transpose(pts[:, 1:, :] - origin[:, None, :], (0, 2, 1))  # (K, D, 3)
        basis, r = np.linalg.qr(diffs)
        diag = np.abs(np.diagonal(r, axis1=1, axis2=2))
        ok = diag.min(axis=1) > _RANK_TOL * np.maximum(diag.max(axis=1), 1e-12)
        # The origin of the minimal subspace is the sample mean: its residuals are symmetric.
        return np.concatenate([pts.mean(axis=1)[:, :, None], basis], axis=2), ok

    def fit_groups(self, data: np.ndarray, groups: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Principal subspace of each row of ``groups`` ``(K, m)``, m >= 4, batched: what
        :meth:`refit` finds for each group."""
        pts = data[check_groups(groups, self.min_samples)]  # (K, m, D)
        mean = pts.mean(axis=1)
        _, s, vt = np.linalg.svd(pts - mean[:, None, :], full_matrices=False)
        ok = s[:, self.dim - 1] > _RANK_TOL * np.maximum(s[:, 0], 1e-12)
        basis = np.transpose(vt[:, : self.dim, :], (0, 2, 1))
        return np.concatenate([mean[:, :, None], basis], axis=2), ok

    def refit(self, data: np.ndarray, inliers: np.ndarray,
              params: np.ndarray) -> np.ndarray | None:
        """Least-squares subspace of the inliers (principal components): optimal for sum r^2."""
        pts = data[inliers]
        if pts.shape[0] < self.min_samples:
            return None
        mean = pts.mean(axis=0)
        centred = pts - mean
        # Principal directions from the D x D scatter matrix: with D = 2F small and many
        # inliers, its eigendecomposition costs far less than an SVD of the inliers.
        values, vectors = np.linalg.eigh(centred.T @ centred)
        values = np.maximum(values[::-1], 0.0)
        if values.size < self.dim or values[self.dim - 1] <= _RANK_TOL**2 * max(values[0], 1e-24):
            return None
        return np.concatenate([mean[:, None], vectors[:, ::-1][:, : self.dim]], axis=1)

    def label_cost_weight(self, data: np.ndarray) -> float:
        """F / R over F frames, at most C: the configured label cost is that of an R-frame
        subspace (R = ``SolverSettings.affine_reference_frames``, 30) and of any longer one
        (C = ``SolverSettings.affine_cost_ceiling``, 1; 0 = no ceiling).

        Residuals are per-frame RMS distances, so a model's data gain does not grow with F by
        itself, but the motions of different bodies drift apart over time and a short window
        holds less of that evidence. On Hopkins155 a cost proportional to F leaves the all-frame
        error unchanged (19.3% -> 19.7% mean) and cuts the error on the last 10 frames from 23.5%
        to 18.8% (BENCHMARKS.md). Past R frames the drift no longer adds in proportion: without
        the ceiling a 61- or 100-frame sequence paid two or three label costs per motion, more
        than its second motion's data gain and rewards together (Hopkins155 ``cars9_g12``,
        ``kanatani3``: one motion found for two).
        """
        frames: int = data.shape[1] // 2
        weight = frames / self.reference_frames
        return min(weight, self.cost_ceiling) if self.cost_ceiling else weight

    def residual_dof(self, data: np.ndarray) -> float:
        """(2F - 3) / F: the residual lives in the 2F - 3 directions normal to the subspace and
        r^2 is its squared length divided by F."""
        dims: int = data.shape[1]
        return (dims - self.dim) / (dims / 2)

    def residuals(self, data: np.ndarray, params: np.ndarray) -> np.ndarray:
        params = np.asarray(params)
        if params.ndim == 2:
            params = params[None]
        mean, basis = params[:, :, 0], params[:, :, 1:]
        num, dims = mean.shape
        if num == 0:
            return np.empty((0, data.shape[0]))
        # ||x - m||^2 - ||B^T (x - m)||^2, expanded so that no (K, N, D) array is formed and the
        # heavy products are matrix products (BLAS).
        x_sq = np.einsum('nd,nd->n', data, data)
        dist_sq = (x_sq[None, :] - 2.0 * (mean @ data.T)
                   + np.einsum('kd,kd->k', mean, mean)[:, None])
        flat = np.transpose(basis, (1, 0, 2)).reshape(dims, num * self.dim)  # (D, K*3)
        proj = (data @ flat).reshape(-1, num, self.dim)  # (N, K, 3)
        proj -= np.einsum('kdj,kd->kj', basis, mean)[None, :, :]
        dist_sq -= np.einsum('nkj,nkj->kn', proj, proj)
        distance: np.ndarray = np.sqrt(np.maximum(dist_sq, 0.0))
        return distance
