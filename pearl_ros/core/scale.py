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
    num_seeds: int = 60,
    refine: bool = True,
) -> float:
    """Median noise level (pixels) of models refitted to image neighbourhoods.

    With ``refine`` each neighbourhood's model is :meth:`MotionModel.refit` (for two-view models a
    Levenberg-Marquardt fit of the Sampson error, a few ms each); without, all neighbourhoods are
    fitted at once by :meth:`MotionModel.fit_groups`, linear least squares: about 50x faster for
    two-view models, identical for affine subspaces, but the linear fit of a fundamental matrix to
    11 points leaves residuals 1.5-3x larger than the refined one (Hopkins155 first and last
    frames), so the scale comes out larger.

    Parameters
    ----------
    model : MotionModel
    data : (N, D) model data rows
    neighbours : (N, k) int, image neighbours of every point (k > min_samples)
    rng : numpy Generator
    num_seeds : int, neighbourhoods examined
    refine : bool, refine each neighbourhood's fit (slow for two-view models)

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
    if refine:
        levels = _refined_levels(model, data, neighbours, seeds, dof)
        return float(np.median(levels)) if levels else 0.0
    hoods = np.concatenate([seeds[:, None], neighbours[seeds]], axis=1)  # (S, k + 1)
    params, ok = model.fit_groups(data, hoods)
    if not np.any(ok):
        return 0.0
    hoods, params = hoods[ok], params[ok]
    residuals = np.take_along_axis(model.residuals(data, params), hoods, axis=1)
    # n - p as in an unbiased variance: the fit absorbs about m points' worth of residual.
    levels = np.sqrt(np.sum(np.square(residuals), axis=1) / (dof * (hoods.shape[1] - m)))
    return float(np.median(levels))


def _refined_levels(model: MotionModel, data: np.ndarray, neighbours: np.ndarray,
                    seeds: np.ndarray, dof: float) -> list[float]:
    """Noise levels of :meth:`MotionModel.refit` models, one neighbourhood at a time."""
    m = model.min_samples
    levels = []
    start_samples = np.concatenate([seeds[:, None], neighbours[seeds, : m - 1]], axis=1)
    starts, ok = model.fit_minimal(data, start_samples)
    for seed, start, good in zip(seeds, starts, ok):
        if not good:
            continue
        hood = np.concatenate([[seed], neighbours[seed]])
        params = model.refit(data, hood, start)
        if params is None:
            continue
        residuals = model.residuals(data[hood], params[None])[0]
        levels.append(np.sqrt(np.sum(np.square(residuals)) / (dof * (hood.size - m))))
    return levels
