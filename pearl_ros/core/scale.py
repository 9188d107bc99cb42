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
    trim: int = 0,
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
    trim : int, >= 0
        Points of each neighbourhood left out as outliers (``SolverSettings.scale_trim``): a
        least-trimmed-squares fit keeps the ``k + 1 - trim`` points its own refit fits best
        (never fewer than the model's minimal sample and two more)
        (two concentration steps, Rousseeuw & Van Driessen 2006), and the level is measured
        from the kept points as usual (n - p), with no further correction: on affine scenes
        with 0.3 px noise, trim 2 reads 7% below least squares when there is no outlier, and
        holds within 5% of that with 20% random-walk outlier tracks, where least squares
        reads 4-5x too high. 0 keeps every point (least squares).

    Returns
    -------
    float, pixels; 0.0 when no neighbourhood could be fitted.
    """
    n, k = neighbours.shape
    m = model.min_samples
    if k + 1 <= m:
        return 0.0
    # At least two points beyond the model's own minimal sample stay to measure the level by.
    keep = max(k + 1 - trim, min(m + 2, k + 1))
    dof = model.residual_dof(data)
    seeds = rng.choice(n, size=min(num_seeds, n), replace=False)
    hoods = np.concatenate([seeds[:, None], neighbours[seeds]], axis=1)  # (S, k + 1)
    params, ok = model.fit_groups(data, hoods)
    if not np.any(ok):
        return 0.0
    hoods, params = hoods[ok], params[ok]
    residuals = np.take_along_axis(model.residuals(data, params), hoods, axis=1)
    if keep < k + 1:
        for _ in range(2):  # concentration steps: refit to the best-fitted points of each hood
            kept = np.take_along_axis(hoods, np.argsort(residuals, axis=1)[:, :keep], axis=1)
            params, ok = model.fit_groups(data, kept)
            if not np.any(ok):
                return 0.0
            hoods, params = hoods[ok], params[ok]
            residuals = np.take_along_axis(model.residuals(data, params), hoods, axis=1)
        residuals = np.sort(residuals, axis=1)[:, :keep]
    # n - p as in an unbiased variance: the fit absorbs about m points' worth of residual.
    levels = np.sqrt(np.sum(np.square(residuals), axis=1) / (dof * (keep - m)))
    return float(np.median(levels))

