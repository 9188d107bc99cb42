"""The protocol every motion model follows (after scikit-image's ``measure.fit`` models).

A model works on per-point *data* rows built from tracks by :meth:`MotionModel.data`, so that the
rest of PEaRL never needs to know what a model measures. Parameters of K hypotheses travel as one
array ``params`` of shape ``(K, ...)``, which keeps proposal fitting and residuals batched.

Residuals are geometric distances in pixels, so one noise scale serves every model.
"""

from __future__ import annotations

from typing import ClassVar, Protocol

import numpy as np

from pearl_ros.core.errors import InputError


class MotionModel(Protocol):
    """A family of rigid-motion models fitted to point data.

    Attributes
    ----------
    name : str
        Registry name (``'affine'``, ``'fundamental'``, ``'homography'``).
    min_samples : int
        Points in a minimal sample.
    refit_from_start : bool
        Whether :meth:`refit` depends on its starting ``params`` (an iterative refinement) or
        only on the inliers (a closed form): a closed-form refit of the same inliers is the
        model it was, and the optimiser skips it.
    """

    name: ClassVar[str]
    min_samples: int
    refit_from_start: ClassVar[bool]

    def data(self, tracks: np.ndarray) -> np.ndarray:
        """Per-point rows ``(N, D)`` from ``tracks`` ``(F, N, 2)`` in pixels."""
        ...

    def fit_minimal(
        self, data: np.ndarray, samples: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Fit one hypothesis per row of ``samples`` ``(K, min_samples)`` int.

        Returns ``params`` ``(K, ...)`` and ``ok`` ``(K,)`` bool; rows with ``ok`` False are
        degenerate samples (their params are unspecified) and are skipped by the caller.
        """
        ...

    def fit_groups(self, data: np.ndarray, groups: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Linear least-squares fit of one hypothesis per row of ``groups`` ``(K, m)`` int,
        m >= min_samples, all at once (no iterative refinement): cheap approximate fits of many
        small point sets, to measure their residual level. Returns ``params`` ``(K, ...)`` and
        ``ok`` ``(K,)`` as :meth:`fit_minimal` does; a model may leave out constraints that
        would inflate the residuals of such small sets (the fundamental matrix's rank).
        """
        ...

    def refit(self, data: np.ndarray, inliers: np.ndarray,
              params: np.ndarray) -> np.ndarray | None:
        """Re-estimate one hypothesis from its ``inliers`` (int indices), starting at ``params``.

        Returns the new params (shape of one hypothesis) or None when the inliers are degenerate.
        """
        ...

    def residuals(self, data: np.ndarray, params: np.ndarray) -> np.ndarray:
        """Distances ``(K, N)`` in pixels of every point to each of ``params`` ``(K, ...)``."""
        ...

    def label_cost_weight(self, data: np.ndarray) -> float:
        """The factor on the configured label cost for models fitted to ``data``."""
        ...

    def residual_dof(self, data: np.ndarray) -> float:
        """E[r^2] / sigma^2 for an inlier under isotropic pixel noise sigma per coordinate.

        It turns residuals into a likelihood with an unknown noise level per model.
        """
        ...


def check_tracks(tracks: np.ndarray, min_frames: int = 1) -> np.ndarray:
    """Validate ``tracks`` (F, N, 2) pixels; returns it as float64."""
    tracks = np.asarray(tracks, dtype=np.float64)
    if tracks.ndim != 3 or tracks.shape[2] != 2:
        raise InputError(f'tracks must have shape (F, N, 2), got {tracks.shape}')
    if tracks.shape[0] < min_frames:
        raise InputError(f'tracks must have at least {min_frames} frames, got {tracks.shape[0]}')
    if not np.all(np.isfinite(tracks)):
        raise InputError('tracks must be finite (no NaN or inf coordinates)')
    return tracks


def check_groups(groups: np.ndarray, min_samples: int) -> np.ndarray:
    """Validate the shape of ``groups`` ``(K, m)``, m >= ``min_samples``, for ``fit_groups``."""
    groups = np.asarray(groups)
    if groups.ndim != 2 or groups.shape[1] < min_samples:
        raise InputError(f'groups must have shape (K, m) with m >= {min_samples}, '
                         f'got {groups.shape}')
    return groups
