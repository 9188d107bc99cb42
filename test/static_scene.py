"""A driving scene of known geometry: a perspective camera moving forward and turning over a
static world, and a box crossing in front of it; tracks, truth and the cameras' projection
matrices (the static world as a robot with odometry sees it)."""

from __future__ import annotations

import numpy as np

FOCAL = 500.0
INTRINSICS = np.array([[FOCAL, 0.0, 320.0], [0.0, FOCAL, 240.0], [0.0, 0.0, 1.0]])


def _yaw(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    # Camera axes x right, y down, z forward; a turn about the camera's y axis.
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def static_scene(frames: int = 10, static: int = 120, moving: int = 40,
                 noise: float = 0.5, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A camera driving forward at 2 m/s and turning, 30 Hz; static points 6-40 m ahead and a
    box 10 m ahead crossing at 3 m/s. Returns tracks (F, N, 2), truth (N,) and cameras."""
    rng = np.random.default_rng(seed)
    world = np.column_stack([rng.uniform(-12, 12, static), rng.uniform(-3, 1.5, static),
                             rng.uniform(6, 40, static)])
    box = np.column_stack([rng.uniform(-1, 1, moving), rng.uniform(-1, 0.5, moving),
                           rng.uniform(9, 11, moving)])
    cameras, tracks = [], []
    for t in range(frames):
        rotation = _yaw(0.01 * t)  # world from camera
        centre = np.array([0.0, 0.0, 2.0 * t / 30])
        to_camera = rotation.T
        camera = INTRINSICS @ np.hstack([to_camera, -to_camera @ centre[:, None]])
        points = np.vstack([world, box + np.array([3.0 * t / 30, 0.0, 0.0])])
        homogeneous = np.hstack([points, np.ones((points.shape[0], 1))]) @ camera.T
        tracks.append(homogeneous[:, :2] / homogeneous[:, 2:])
        cameras.append(camera)
    uv = np.stack(tracks) + rng.normal(0.0, noise, (frames, static + moving, 2))
    truth = np.r_[np.zeros(static, int), np.ones(moving, int)]
    return uv, truth, np.stack(cameras)


def pose_of(camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The position (3,) and orientation quaternion (x, y, z, w; world from the optical frame)
    of a projection matrix ``INTRINSICS [R^T | -R^T c]`` of this scene."""
    from pearl_ros.pipeline.poses import quaternion

    to_camera = np.linalg.solve(INTRINSICS, camera)
    rotation = to_camera[:, :3].T
    return -rotation @ to_camera[:, 3], quaternion(rotation)


def camera_info(stamp_ns: int, k: np.ndarray, binning: tuple[int, int] = (0, 0),
                offset: tuple[int, int] = (0, 0), d=(0.0, 0.0, 0.0, 0.0, 0.0)):
    """A rosbags ``sensor_msgs/msg/CameraInfo`` of camera matrix ``k`` (3, 3), plumb_bob with
    coefficients ``d`` (none by default), ``binning_x``, ``binning_y`` and a region of
    interest at ``offset``."""
    from pearl_ros.bagio.reader import TYPESTORE
    from pearl_ros.bagio.writer import stamped_header

    types = TYPESTORE.types
    roi = types['sensor_msgs/msg/RegionOfInterest'](
        x_offset=offset[0], y_offset=offset[1], height=0, width=0, do_rectify=False)
    projection = np.hstack([np.asarray(k, dtype=np.float64), np.zeros((3, 1))])
    return types['sensor_msgs/msg/CameraInfo'](
        header=stamped_header(stamp_ns, 'camera'), height=480, width=640,
        distortion_model='plumb_bob', d=np.asarray(d, dtype=np.float64),
        k=np.asarray(k, dtype=np.float64).ravel(),
        r=np.eye(3).ravel(), p=projection.ravel(), binning_x=binning[0], binning_y=binning[1],
        roi=roi)


def radial(uv: np.ndarray, k1: float, k2: float) -> np.ndarray:
    """Pixels of this scene's pinhole camera seen through a lens of radial distortion ``k1``,
    ``k2`` (plumb_bob: ``x (1 + k1 r^2 + k2 r^4)`` in normalised coordinates)."""
    xy = (uv - INTRINSICS[:2, 2]) / FOCAL
    r2 = np.sum(np.square(xy), axis=-1, keepdims=True)
    return xy * (1.0 + k1 * r2 + k2 * r2 * r2) * FOCAL + INTRINSICS[:2, 2]


def write_scene_bag(path, frames: int, seed: int, pose_topic: str, static: int = 120,
                    moving: int = 40, extra=None, lens=None) -> np.ndarray:
    """The scene as a bag with VINS-like camera poses on ``pose_topic`` beside its features
    (``/feature_tracker/feature``) and ground truth, each pose logged just after its frame,
    and the ``extra`` messages of :func:`write_feature_bag`; returns the truth. With ``lens``
    (k1, k2) the features are those a lens of that radial distortion shows, the points within
    a normalised radius of 0.8 (where it does not fold the image) alone."""
    from pearl_ros.bagio.reader import FeatureFrame
    from pearl_ros.bagio.writer import write_feature_bag

    tracks, truth, cameras = static_scene(frames=frames, static=static, moving=moving, seed=seed)
    if lens is not None:
        inside = np.linalg.norm((tracks - INTRINSICS[:2, 2]) / FOCAL, axis=2).max(axis=0) < 0.8
        tracks, truth = radial(tracks[:, inside], *lens), truth[inside]
    ids = np.arange(truth.size)
    stamps = [1_000_000_000 + t * 33_333_333 for t in range(frames)]
    write_feature_bag(path, [FeatureFrame(s, ids, tracks[t]) for t, s in enumerate(stamps)],
                      [(s, ids, truth) for s in stamps],
                      poses=[(s + 1_000, *pose_of(cameras[t])) for t, s in enumerate(stamps)],
                      pose_topic=pose_topic, extra=extra)
    return truth
