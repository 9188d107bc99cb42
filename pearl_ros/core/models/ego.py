"""The static world as a model whose parameters are known: the camera's own motion.

A robot usually knows where its camera was (odometry, visual-inertial state). A point of the
static world, triangulated from its track with those camera matrices, reprojects within the
tracking noise; a point of a moving object usually does not. :class:`WithStaticWorld` wraps a
model family (the affine subspaces) with one more hypothesis, the static world, whose residual
is that reprojection error: an RMS image distance per frame in pixels, the unit every model
shares. It has no parameter to fit, so the search cannot widen it to take in other motions; a
refit returns it when it explains its points at least as well as the family's own fit does.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from pearl_ros.core.errors import InputError
from pearl_ros.core.models.base import MotionModel

# The residual (px) given to a track whose triangulation fails (a degenerate or non-finite
# solution): far beyond any noise level.
_FAILED_PX = 1e4


def check_cameras(cameras: np.ndarray, num_frames: int) -> np.ndarray:
    """Validate ``cameras`` (F, 3, 4) projection matrices, one per frame, all NaN for a frame
    whose camera is not known (two at least must be); returns float64."""
    cameras = np.asarray(cameras, dtype=np.float64)
    if cameras.shape != (num_frames, 3, 4):
        raise InputError(f'cameras must have shape ({num_frames}, 3, 4), one per frame, got '
                         f'{cameras.shape}')
    unknown = np.isnan(cameras).all(axis=(1, 2))
    if not np.all(np.isfinite(cameras[~unknown])):
        raise InputError('cameras must be finite (all NaN for a frame whose camera is unknown)')
    if np.count_nonzero(~unknown) < 2:
        raise InputError('cameras must be known for two frames at least')
    return cameras


def static_residuals(cameras: np.ndarray, tracks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each track as one static point: RMS reprojection residual (px) and whether in front.

    Parameters
    ----------
    cameras : (F, 3, 4) float64, projection matrices (pixels from world) of the frames; all
        NaN for a frame whose camera is unknown (its coordinates are left out)
    tracks : (F, N, 2) float64, px; NaN where a track is not seen (a young track's frames
        before its birth), left out

    Returns
    -------
    residual : (N,) float64, RMS over the frames used of the reprojection error (px) of the
        point the linear (DLT) triangulation of each track finds, or, where that point lies
        behind a camera, of the point at infinity it finds if that one lies in front;
        ``_FAILED_PX`` where the triangulation fails or fewer than two frames are used
    in_front : (N,) bool, a point in front of every camera explains the track (the finite
        one, or the one at infinity)
    """
    tracks = np.asarray(tracks, dtype=np.float64)
    if tracks.ndim != 3 or tracks.shape[2] != 2 or np.isinf(tracks).any():
        raise InputError(f'tracks must have shape (F, N, 2), finite or NaN, got {tracks.shape}')
    cameras = check_cameras(cameras, tracks.shape[0])
    known = ~np.isnan(cameras).all(axis=(1, 2))
    cameras, tracks = cameras[known], tracks[known]
    seen = ~np.isnan(tracks).any(axis=2)  # (F, N)
    # The world's origin moved to the cameras' mean centre keeps the system well conditioned
    # however far from its origin the robot has driven.
    centres = -np.linalg.solve(cameras[:, :, :3], cameras[:, :, 3:])[..., 0]  # (F, 3)
    shift = np.eye(4)
    shift[:3, 3] = centres.mean(axis=0)
    cameras = cameras @ shift
    # Each frame gives two rows per track: u P3 - P1 and v P3 - P2 (times X = 0); none where
    # the track is not seen.
    filled = np.where(seen[..., None], tracks, 0.0)
    rows = np.concatenate([filled[..., 0:1] * cameras[:, None, 2] - cameras[:, None, 0],
                           filled[..., 1:2] * cameras[:, None, 2] - cameras[:, None, 1]],
                          axis=0) * np.concatenate([seen, seen])[..., None]
    # The least right singular vector of each track's rows, as the eigenvector of least
    # eigenvalue of their 4 x 4 normal matrix: one batched eigh, several times an SVD's speed.
    # (A finite point solved for with w = 1 weighs the rows otherwise: on the tests' driving
    # scene it let the crossing box pass for static points.)
    normal = np.matmul(np.transpose(rows, (1, 2, 0)), np.transpose(rows, (1, 0, 2)))
    residual, in_front = _reprojection(cameras, tracks, seen,
                                       np.linalg.eigh(normal)[1][:, :, 0])
    # A point at infinity (w = 0: far buildings, the horizon) is a static point too: where a
    # short track's parallax is below the noise, the finite solution may fall behind the
    # cameras while the point at infinity in front explains the track as well.
    behind = np.flatnonzero(~in_front)
    if behind.size:
        direction = np.linalg.eigh(normal[behind, :3, :3])[1][:, :, 0]
        far, far_in_front = _reprojection(cameras, tracks[:, behind], seen[:, behind],
                                          np.concatenate([direction,
                                                          np.zeros((behind.size, 1))], axis=1))
        residual[behind] = np.where(far_in_front, far, residual[behind])
        in_front[behind] = far_in_front
    few = seen.sum(axis=0) < 2
    residual[few], in_front[few] = _FAILED_PX, False
    return residual, in_front


def _reprojection(cameras: np.ndarray, tracks: np.ndarray, seen: np.ndarray,
                  points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """RMS reprojection error (px) of homogeneous ``points`` (N, 4), each up to sign, against
    ``tracks`` (F, N, 2) over the frames where ``seen`` (F, N), and whether the point (or its
    opposite) lies in front of every camera that sees it."""
    projected = points @ np.transpose(cameras, (0, 2, 1))  # (F, N, 3)
    with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
        offset = projected[..., :2] / projected[..., 2:] - tracks
        squares = np.where(seen, np.sum(np.square(offset), axis=2), 0.0)
        residual = np.sqrt(squares.sum(axis=0) / np.maximum(seen.sum(axis=0), 1))
    # A finite point's depth has the sign of z / w. A point at infinity is a direction, found
    # up to sign: it is in front where every camera sees it on one side, either one.
    sign = np.where(points[:, 3] != 0, np.sign(points[:, 3]), 1.0)
    depth = projected[..., 2] * sign
    in_front = (np.all((depth > 0) | ~seen, axis=0)
                | ((points[:, 3] == 0) & np.all((depth < 0) | ~seen, axis=0)))
    return np.where(np.isfinite(residual), residual, _FAILED_PX), in_front


def is_static(params: np.ndarray) -> bool:
    """Whether one hypothesis' ``params`` stand for the static world (all NaN)."""
    return bool(np.isnan(params).any())


def static_ties(weights: np.ndarray, edges: np.ndarray, static: np.ndarray, scale: float,
                contrast: float) -> np.ndarray:
    """Pair weights with the ties between points that differ in how well the static world
    explains them loosened.

    An edge whose ends' static residuals ``static`` (N,) px differ by ``d`` noise scales keeps
    ``exp(-(d / contrast)^2)`` of a positive weight (a tie); rewards (negative weights) stay.
    The local-subspace misses that set the weights compare a few points' motions over the
    window; the static residual compares each point with the camera's own motion, which sets
    a point of the static world apart from one of a body that moves, however alike their
    patches look. ``contrast`` 0 leaves the weights as they are.
    """
    if not contrast > 0 or edges.shape[0] == 0:
        return weights
    gap = np.abs(static[edges[:, 0]] - static[edges[:, 1]]) / (contrast * scale)
    kept: np.ndarray = np.where(weights > 0, weights * np.exp(-np.square(gap)), weights)
    return kept


class WithStaticWorld:
    """A model family plus the static world seen by known cameras.

    Data rows are the family's rows with one more column, each point's static residual (px).
    Params are the family's; the static world is the hypothesis whose params are all NaN.

    Parameters
    ----------
    base : MotionModel, the family, refitted in closed form, whose residuals are RMS pixels per
        frame (the affine subspaces)
    cameras : (F, 3, 4) float64, projection matrices of the frames of the tracks to be fitted
    """

    name: ClassVar[str] = 'static_world'
    # A refit chooses between the family's closed-form refit and the static world by the
    # inliers alone, whatever it starts from.
    refit_from_start: ClassVar[bool] = False

    def __init__(self, base: MotionModel, cameras: np.ndarray) -> None:
        if base.refit_from_start:
            raise InputError(f'cameras are used with the affine model only (its residuals are '
                             f'RMS pixels per frame, as the static world\'s), not {base.name!r}')
        self.base = base
        self.cameras = np.asarray(cameras, dtype=np.float64)
        self.min_samples = base.min_samples
        self._static: tuple[int, np.ndarray] | None = None  # data width, the static params

    def data(self, tracks: np.ndarray) -> np.ndarray:
        """The family's rows and each track's static residual; a track that only a point
        behind the cameras explains gets ``_FAILED_PX``."""
        rows = self.base.data(tracks)
        residual, in_front = static_residuals(self.cameras, tracks)
        # Over the F' frames whose cameras are known a static residual has (2F' - 3) / F' of
        # sigma^2 for its mean square; the family's, over all F, (2F - 3) / F: scaled to that.
        frames = tracks.shape[0]
        known = int(np.count_nonzero(~np.isnan(self.cameras).all(axis=(1, 2))))
        if known < frames:
            residual = residual * np.sqrt((2 * frames - 3) / frames / ((2 * known - 3) / known))
        residual = np.where(in_front, residual, _FAILED_PX)
        return np.concatenate([rows, residual[:, None]], axis=1)

    def static(self, data: np.ndarray) -> np.ndarray:
        """The static world's params: the shape of one of the family's, all NaN."""
        if self._static is None or self._static[0] != data.shape[1]:
            shape = self.base.fit_minimal(data[:, :-1],
                                          np.arange(self.min_samples)[None])[0].shape
            self._static = (data.shape[1], np.full(shape[1:], np.nan))
        params: np.ndarray = self._static[1].copy()
        return params

    def fixed_hypotheses(self, data: np.ndarray) -> np.ndarray:
        """Hypotheses offered with every batch of proposals: the static world."""
        return self.static(data)[None]

    def fit_minimal(self, data: np.ndarray, samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.base.fit_minimal(data[:, :-1], samples)

    def fit_groups(self, data: np.ndarray, groups: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.base.fit_groups(data[:, :-1], groups)

    def refit(self, data: np.ndarray, inliers: np.ndarray,
              params: np.ndarray) -> np.ndarray | None:
        """The family's refit of the inliers, or the static world where it explains them no
        worse: its median squared residual at most the fit's (a median, so that a few points
        of other motions among the inliers do not turn the static world into a fitted model
        that takes them in)."""
        rows = data[:, :-1]
        if not is_static(params):
            own = self.base.refit(rows, inliers, params)
        elif inliers.size >= self.min_samples:
            # The family's refit starts from a minimal fit of the inliers (a closed-form
            # refit does not depend on its start).
            own = self.base.refit(rows, inliers, self.base.fit_minimal(
                rows, inliers[None, :self.min_samples])[0][0])
        else:
            own = None
        static_sq = float(np.median(np.square(data[inliers, -1]))) if inliers.size else np.inf
        if own is None:
            return self.static(data) if static_sq < _FAILED_PX**2 else None
        own_sq = float(np.median(np.square(self.base.residuals(rows[inliers], own[None])[0])))
        return self.static(data) if static_sq <= own_sq else own

    def residuals(self, data: np.ndarray, params: np.ndarray) -> np.ndarray:
        params = np.asarray(params)
        if params.ndim == data.ndim:
            params = params[None]
        static = np.isnan(params.reshape(params.shape[0], -1)).any(axis=1)
        out = np.empty((params.shape[0], data.shape[0]))
        out[static] = data[:, -1]
        if np.any(~static):
            out[~static] = self.base.residuals(data[:, :-1], params[~static])
        return out

    def label_cost_weight(self, data: np.ndarray) -> float:
        return self.base.label_cost_weight(data[:, :-1])

    def residual_dof(self, data: np.ndarray) -> float:
        return self.base.residual_dof(data[:, :-1])
