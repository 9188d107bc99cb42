"""A KLT feature tracker that keeps the features of moving objects (ROS-free, OpenCV).

Shi-Tomasi corners (Shi & Tomasi 1994, ``cv2.goodFeaturesToTrack``) followed from frame to frame
by pyramidal Lucas-Kanade (Bouguet 2000, ``cv2.calcOpticalFlowPyrLK``), with a forward-backward
check (Kalal et al. 2010): a point tracked to the new frame and back must land within
``fb_threshold`` px of where it started, and the window must still look like itself
(``max_residual``). New corners are detected only to top the count up to ``max_features`` (when
it has fallen below ``top_up_share`` of it), at least ``min_distance`` px from every live
feature. Ids are integers counted up from 0 and never reused.

Unlike VINS-Mono's ``feature_tracker`` there is no epipolar (fundamental-matrix RANSAC) rejection:
it would delete the features of every independently moving object, which are what a motion
segmenter is for.

With a :class:`CameraModel` (from ``sensor_msgs/CameraInfo``: plumb_bob, rational_polynomial or
equidistant) each feature also gets its undistorted normalised coordinates ``K^-1 [u v 1]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from pearl_ros.core.config import check_fields, spec
from pearl_ros.core.errors import InputError

# distortion model (sensor_msgs/CameraInfo.distortion_model) -> allowed coefficient counts
DISTORTION_MODELS: dict[str, tuple[int, ...]] = {
    'none': (0,),
    'plumb_bob': (0, 4, 5, 8),
    'rational_polynomial': (8,),
    'equidistant': (4,),
}

_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)


@dataclass(frozen=True)
class TrackerConfig:
    """Settings of :class:`FeatureTracker`, with their units and ranges."""

    max_features: int = spec(300, 'target feature count; corners are detected only to top up',
                             low=1, high=100000)
    top_up_share: float = spec(
        0.9, 'new corners are detected, up to max_features, only in a frame where the count '
        'has fallen below this share of max_features (1 = whenever one is missing; detection '
        'costs about as much as tracking)', low=0.01, high=1.0)
    min_distance: float = spec(20.0, 'least distance of a new corner from any live feature, px',
                               low=0.0, high=10000.0)
    quality_level: float = spec(
        0.01, 'least Shi-Tomasi score of a corner, as a share of the best score in the image',
        low=1e-6, high=1.0)
    block_size: int = spec(3, 'side of the Shi-Tomasi gradient window, px', low=3, high=31)
    window_size: int = spec(15, 'side of the Lucas-Kanade window, px (odd)', low=5, high=101)
    pyramid_levels: int = spec(3, 'pyramid levels above the image Lucas-Kanade uses',
                               low=0, high=8)
    max_iterations: int = spec(30, 'most Lucas-Kanade iterations per pyramid level',
                               low=1, high=1000)
    epsilon: float = spec(0.01, 'Lucas-Kanade stops when the update is below this, px',
                          low=1e-6, high=10.0)
    fb_threshold: float = spec(
        1.0, 'most distance between a point and its forward-then-backward track, px; '
        '0 = no forward-backward check', low=0.0, high=1000.0)
    max_residual: float = spec(
        12.0, 'most mean absolute grey-level difference between a feature\'s window in the '
        'previous frame and where it is tracked to (Shi & Tomasi\'s dissimilarity: catches '
        'windows an occluding edge sweeps over); 0 = no check', low=0.0, high=255.0)
    min_template_ncc: float = spec(
        0.8, 'least normalised cross-correlation between a feature\'s window where it was first '
        'seen and where it is now (catches a slow drift off its surface, which each frame-to-frame'
        ' check passes); 0 = no check', low=0.0, high=1.0)
    border: int = spec(1, 'a track within this many px of the image edge is dropped',
                       low=0, high=1000)

    def __post_init__(self) -> None:
        check_fields(self)
        if self.window_size % 2 == 0:
            raise InputError(f'window_size must be odd, got {self.window_size!r}')


@dataclass(frozen=True, eq=False)
class CameraModel:
    """Pinhole intrinsics and lens distortion, as in ``sensor_msgs/CameraInfo``.

    Parameters
    ----------
    K : (3, 3) float64
        Intrinsic matrix, pixels.
    distortion : (D,) float64
        plumb_bob: k1 k2 p1 p2 [k3 [k4 k5 k6]]; rational_polynomial: 8 coefficients;
        equidistant: k1 k2 k3 k4 (Kannala & Brandt 2006, OpenCV's fisheye model); none: empty.
    model : str
        One of :data:`DISTORTION_MODELS`.
    """

    K: np.ndarray
    distortion: np.ndarray = field(default_factory=lambda: np.zeros(0))
    model: str = 'plumb_bob'

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=np.float64)
        dist = np.asarray(self.distortion, dtype=np.float64).ravel()
        if K.shape != (3, 3) or not np.all(np.isfinite(K)):
            raise InputError(f'K must be a finite (3, 3) matrix, got shape {K.shape}')
        if not (K[0, 0] > 0 and K[1, 1] > 0) or not np.allclose(K[2], (0, 0, 1)):
            raise InputError('K must have fx > 0, fy > 0 and last row (0, 0, 1) '
                             f'(an all-zero K is an uncalibrated camera), got {K.tolist()}')
        if self.model not in DISTORTION_MODELS:
            raise InputError(f'distortion model must be one of {tuple(DISTORTION_MODELS)}, '
                             f'got {self.model!r}')
        if dist.size not in DISTORTION_MODELS[self.model] or not np.all(np.isfinite(dist)):
            raise InputError(f'a {self.model} distortion needs {DISTORTION_MODELS[self.model]} '
                             f'finite coefficients, got {dist.tolist()}')
        object.__setattr__(self, 'K', K)
        object.__setattr__(self, 'distortion', dist)

    @classmethod
    def from_camera_info(cls, msg: Any) -> CameraModel:
        """From any object with ``sensor_msgs/CameraInfo``'s ``k``, ``d`` and ``distortion_model``
        (an empty model name with no coefficients is read as no distortion)."""
        coefficients = np.asarray(msg.d, dtype=np.float64)
        model = str(msg.distortion_model) or ('none' if coefficients.size == 0 else '')
        if model == 'none' and coefficients.size and not np.any(coefficients):
            coefficients = np.zeros(0)
        return cls(np.asarray(msg.k, dtype=np.float64).reshape(3, 3), coefficients, model)

    @property
    def distorted(self) -> bool:
        """Whether the lens has any non-zero distortion coefficient."""
        return bool(np.any(self.distortion))

    def undistort(self, uv: np.ndarray) -> np.ndarray:
        """Pixels ``(N, 2)`` of an ideal pinhole camera of the same ``K`` for pixels ``uv``
        ``(N, 2)``: where each would be without the lens's distortion."""
        xy = self.normalise(uv)
        pixels: np.ndarray = xy @ self.K[:2, :2].T + self.K[:2, 2]
        return pixels

    def normalise(self, uv: np.ndarray) -> np.ndarray:
        """Undistorted normalised coordinates ``(N, 2)`` of pixels ``uv`` ``(N, 2)``."""
        points = np.ascontiguousarray(uv, dtype=np.float64).reshape(-1, 1, 2)
        if len(points) == 0:
            return np.zeros((0, 2))
        if self.model == 'equidistant':
            out = cv2.fisheye.undistortPoints(points, self.K, self.distortion)
        elif not self.distorted:
            inv = np.linalg.inv(self.K)
            return np.asarray(points.reshape(-1, 2) @ inv[:2, :2].T + inv[:2, 2])
        else:
            # By default cv2.undistortPoints stops after 5 iterations, ~1e-4 off at the edge of
            # a strong lens: iterate to convergence.
            out = cv2.undistortPoints(points, self.K, self.distortion, None, np.eye(3),
                                      np.eye(3), criteria=_UNDISTORT_CRITERIA)
        return np.asarray(out, dtype=np.float64).reshape(-1, 2)


@dataclass(frozen=True, eq=False)
class Tracks:
    """The features alive in one frame.

    Attributes
    ----------
    ids : (N,) int64
        Persistent ids, never reused.
    uv : (N, 2) float64
        Positions, pixels (pixel centres at integers, as OpenCV).
    xy : (N, 2) float64 or None
        Undistorted normalised coordinates; None without a camera model.
    velocity : (N, 2) float64
        Image velocity, px per second when both this and the previous frame had a stamp, else
        px per frame; 0 for a feature new in this frame.
    xy_velocity : (N, 2) float64 or None
        The same for ``xy`` (normalised units per second or per frame), as VINS-Mono publishes.
    age : (N,) int64
        Frames the feature has been seen in, this one included (1 = new).
    per_second : bool
        Whether velocities are per second (True) or per frame.
    """

    ids: np.ndarray
    uv: np.ndarray
    xy: np.ndarray | None
    velocity: np.ndarray
    xy_velocity: np.ndarray | None
    age: np.ndarray
    per_second: bool = False

    def __len__(self) -> int:
        return int(self.ids.size)


def _patches(gray: np.ndarray, uv: np.ndarray, radius: int) -> np.ndarray:
    """The ``(2 radius + 1)^2`` grey levels around each point ``uv`` ``(N, 2)``, bilinear, as rows
    of an ``(N, P)`` float32 array."""
    if len(uv) == 0:
        return np.zeros((0, (2 * radius + 1) ** 2), np.float32)
    steps = np.arange(-radius, radius + 1, dtype=np.float32)
    dx, dy = np.meshgrid(steps, steps)
    cols = (uv[:, 0, None] + dx.ravel()).astype(np.float32)
    rows = (uv[:, 1, None] + dy.ravel()).astype(np.float32)
    # Sampled from the uint8 image (no float copy of it): levels rounded, enough for a correlation.
    sampled = cv2.remap(gray, cols, rows, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return np.asarray(sampled, dtype=np.float32)


def _ncc(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Normalised cross-correlation ``(N,)`` of the rows of ``a`` and ``b``."""
    a = a - a.mean(axis=1, keepdims=True)
    b = b - b.mean(axis=1, keepdims=True)
    denominator = np.sqrt(np.sum(a * a, axis=1) * np.sum(b * b, axis=1))
    return np.asarray(np.sum(a * b, axis=1) / np.maximum(denominator, 1e-9))


def to_gray(image: np.ndarray) -> np.ndarray:
    """An ``(H, W)`` uint8 image from ``(H, W)``, ``(H, W, 1)`` or BGR ``(H, W, 3)`` uint8."""
    image = np.asarray(image)
    if image.dtype != np.uint8:
        raise InputError(f'image must be uint8, got {image.dtype}')
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 3 and image.shape[2] == 3:
        return np.asarray(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))
    if image.ndim != 2 or min(image.shape) < 2:
        raise InputError(f'image must be of shape (H, W) or (H, W, 3), got {image.shape}')
    return np.ascontiguousarray(image)


class FeatureTracker:
    """Shi-Tomasi corners tracked by pyramidal Lucas-Kanade with a forward-backward check.

    Parameters
    ----------
    config : TrackerConfig, optional
        Settings; the defaults if None.
    camera : CameraModel, optional
        When given, :meth:`track` also returns undistorted normalised coordinates.
    mask : (H, W) ndarray, optional
        Nonzero where features may be; corners are not detected, and tracks are dropped, where it
        is zero. Its shape must match the images'.
    """

    def __init__(self, config: TrackerConfig | None = None, *,
                 camera: CameraModel | None = None, mask: np.ndarray | None = None) -> None:
        self.config = config if config is not None else TrackerConfig()
        self.camera = camera
        if mask is not None:
            mask = np.asarray(mask)
            if mask.ndim != 2:
                raise InputError(f'mask must be of shape (H, W), got {mask.shape}')
            mask = np.where(mask != 0, 255, 0).astype(np.uint8)
        self.mask = mask
        self._next_id = 0
        self._radius = self.config.window_size // 2
        self.reset()

    def reset(self) -> None:
        """Forget every track (ids still count on: none is ever reused)."""
        self._previous: np.ndarray | None = None
        self._shape: tuple[int, int] | None = None
        self._uv = np.zeros((0, 2), np.float32)
        self._ids = np.zeros(0, np.int64)
        self._age = np.zeros(0, np.int64)
        self._templates = _patches(np.zeros((1, 1), np.uint8), self._uv, self._radius)
        self._xy: np.ndarray | None = None
        self._stamp: int | None = None

    def _flow(self, src: np.ndarray, dst: np.ndarray,
              points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Lucas-Kanade from ``src`` to ``dst``: new positions ``(N, 2)`` and which passed."""
        # OpenCV's Python binding takes images here, not the pyramids of buildOpticalFlowPyramid.
        cfg = self.config
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, cfg.max_iterations,
                    cfg.epsilon)
        start = np.ascontiguousarray(points, dtype=np.float32).reshape(-1, 1, 2)
        moved, status, residual = cv2.calcOpticalFlowPyrLK(
            src, dst, start, start.copy(), winSize=(cfg.window_size, cfg.window_size),
            maxLevel=cfg.pyramid_levels, criteria=criteria)
        ok = status.ravel().astype(bool)
        if cfg.max_residual > 0:
            ok &= residual.ravel() <= cfg.max_residual
        return moved.reshape(-1, 2), ok

    def _inside(self, uv: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """Whether each point is at least ``border`` px inside the image and on the mask."""
        b = self.config.border
        height, width = shape
        ok = np.all(np.isfinite(uv), axis=1)
        ok &= (uv[:, 0] >= b) & (uv[:, 0] <= width - 1 - b)
        ok &= (uv[:, 1] >= b) & (uv[:, 1] <= height - 1 - b)
        if self.mask is not None and np.any(ok):
            cols = np.clip(np.rint(uv[ok, 0]).astype(int), 0, width - 1)
            rows = np.clip(np.rint(uv[ok, 1]).astype(int), 0, height - 1)
            ok[ok] = self.mask[rows, cols] != 0
        return ok

    def _follow(self, gray: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """Track the live points into the new frame; keep those that pass every check.

        Returns the previous positions of the survivors (float64), for their velocities.
        """
        previous = self._uv
        if self._previous is None or len(previous) == 0:
            return np.zeros((0, 2))
        moved, ok = self._flow(self._previous, gray, previous)
        ok &= self._inside(moved, shape)
        if self.config.fb_threshold > 0 and np.any(ok):
            back, back_ok = self._flow(gray, self._previous, moved[ok])
            error = np.linalg.norm(back - previous[ok], axis=1)
            ok[ok] = back_ok & (error <= self.config.fb_threshold)
        if self.config.min_template_ncc > 0 and np.any(ok):
            current = _patches(gray, moved[ok], self._radius)
            ok[ok] = _ncc(self._templates[ok], current) >= self.config.min_template_ncc
        self._uv, self._ids, self._age = moved[ok], self._ids[ok], self._age[ok] + 1
        if self.config.min_template_ncc > 0:
            self._templates = self._templates[ok]
        if self._xy is not None:
            self._xy = self._xy[ok]
        return previous[ok].astype(np.float64)

    def _detect(self, gray: np.ndarray) -> np.ndarray:
        """New corners ``(M, 2)`` float32 to top the count up, away from the live features."""
        cfg = self.config
        need = cfg.max_features - len(self._uv)
        if need <= 0 or len(self._uv) >= cfg.top_up_share * cfg.max_features:
            return np.zeros((0, 2), np.float32)
        mask = (self.mask.copy() if self.mask is not None
                else np.full(gray.shape, 255, np.uint8))
        radius = int(np.ceil(cfg.min_distance))
        if radius > 0:
            for u, v in np.rint(self._uv).astype(int):
                cv2.circle(mask, (int(u), int(v)), radius, 0, -1)
        corners = cv2.goodFeaturesToTrack(gray, need, cfg.quality_level, cfg.min_distance,
                                          mask=mask, blockSize=cfg.block_size)
        if corners is None:
            return np.zeros((0, 2), np.float32)
        corners = corners.reshape(-1, 2).astype(np.float32)
        if radius > 0 and len(self._uv):
            # The drawn disc is a pixel approximation: enforce the distance exactly.
            gap = np.linalg.norm(corners[:, None, :] - self._uv[None, :, :], axis=2)
            corners = corners[np.all(gap >= cfg.min_distance, axis=1)]
        shape = (int(gray.shape[0]), int(gray.shape[1]))
        return np.asarray(corners[self._inside(corners, shape)])

    def track(self, image: np.ndarray, stamp: int | None = None) -> Tracks:
        """Follow the features into ``image`` and top them up with new corners.

        Parameters
        ----------
        image : (H, W) or (H, W, 3) uint8
            Grey or BGR. A new size starts afresh (all tracks end).
        stamp : int, optional
            Time of the image, nanoseconds; with stamps on consecutive frames velocities are
            per second.

        Returns
        -------
        Tracks
            Survivors first (in their previous order), then the new features.
        """
        gray = to_gray(image)
        shape = (int(gray.shape[0]), int(gray.shape[1]))
        if self.mask is not None and self.mask.shape != shape:
            raise InputError(f'mask shape {self.mask.shape} does not match image shape {shape}')
        if self._shape != shape:
            self.reset()
        previous = self._follow(gray, shape)
        old = len(previous)
        new = self._detect(gray)
        self._uv = np.concatenate([self._uv, new]).astype(np.float32)
        self._ids = np.concatenate([self._ids, np.arange(self._next_id, self._next_id + len(new))])
        self._next_id += len(new)
        self._age = np.concatenate([self._age, np.ones(len(new), np.int64)])
        if self.config.min_template_ncc > 0:
            self._templates = np.concatenate([self._templates,
                                              _patches(gray, new, self._radius)])
        uv = self._uv.astype(np.float64)
        dt = None if stamp is None or self._stamp is None else (stamp - self._stamp) * 1e-9
        per_second = dt is not None and dt > 0
        scale = 1.0 / dt if per_second and dt is not None else 1.0
        velocity = np.zeros_like(uv)
        velocity[:old] = (uv[:old] - previous) * scale
        xy = xy_velocity = None
        if self.camera is not None:
            xy = self.camera.normalise(uv)
            xy_velocity = np.zeros_like(xy)
            if self._xy is not None:
                xy_velocity[:old] = (xy[:old] - self._xy) * scale
            self._xy = xy
        self._previous, self._shape, self._stamp = gray, shape, stamp
        return Tracks(self._ids.copy(), uv, xy, velocity, xy_velocity, self._age.copy(),
                      per_second)
