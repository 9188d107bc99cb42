"""Automatic noise scale: how far points stray from models fitted to their image neighbours.

Points of one rigid body cluster in the image, so a model fitted by least squares to a point's
image neighbourhood mostly describes one motion, and its residuals measure the tracking noise at
the sequence's own level. The median over many neighbourhoods is robust to the few that straddle
two motions. It needs no segmentation and no per-sequence parameter.
"""

from __future__ import annotations

import numpy as np

from pearl_ros.core.models.base import MotionModel


def local_scale(
    model: MotionModel,
    data: np.ndarray,
    neighbours: np.ndarray,
    rng: np.random.Generator,
    num_seeds: int,
) -> float:
    """Median noise level (pixels) of models fitted to image neighbourhoods.

    All neighbourhoods are fitted at once by :meth:`MotionModel.fit_groups`, linear least
    squares: for affine subspaces these are the refits themselves; for two-view models they are
    not Levenberg-Marquardt fits, but on Hopkins155 they serve PEaRL better (BENCHMARKS.md) at a
    hundredth of the time.

    Parameters
    ----------
    model : MotionModel
    data : (N, D) model data rows
    neighbours : (N, k) int, image neighbours of every point (k > min_samples)
    rng : numpy Generator
    num_seeds : int, neighbourhoods examined (``SolverSettings.scale_seeds``)

    Returns
    -------
    float, pixels; 0.0 when no neighbourhood could be fitted.
    """
    n, k = neighbours.shape
    m = model.min_samples
    if k + 1 <= m:
        return 0.0
    dof = model.residual_dof(data)
    seeds = rng.choice(n, size=min(num_seeds, n), replace=False)
    hoods = np.concatenate([seeds[:, None], neighbours[seeds]], axis=1)  # (S, k + 1)
    params, ok = model.fit_groups(data, hoods)
    if not np.any(ok):
        return 0.0
    hoods, params = hoods[ok], params[ok]
    residuals = np.take_along_axis(model.residuals(data, params), hoods, axis=1)
    # n - p as in an unbiased variance: the fit absorbs about m points' worth of residual.
    levels = np.sqrt(np.sum(np.square(residuals), axis=1) / (dof * (hoods.shape[1] - m)))
    return float(np.median(levels))
