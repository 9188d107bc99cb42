"""Camera poses from a robot's odometry, as the segmenter takes them: projection matrices.

A robot that knows where its camera is (visual-inertial odometry such as VINS' ``camera_pose``,
wheel odometry composed with the camera's mounting, a localiser) publishes it as
``nav_msgs/msg/Odometry``, ``geometry_msgs/msg/PoseStamped`` or ``PoseWithCovarianceStamped``:
the pose of the camera's optical frame (z forward, x right, y down, REP 103's ``_optical``
frames) in a fixed world frame. With the camera's
intrinsics (pixels from the optical frame: parameters, or ``sensor_msgs/msg/CameraInfo``'s
``k``), each pose is one projection matrix ``K [R^T | -R^T c]``, where ``R`` and ``c`` are the
camera's orientation and position in the world. Poses and feature frames meet by stamp
(:class:`PoseBuffer`).

ROS-free: messages are read by attribute (rclpy's and rosbags' alike).
"""

from __future__ import annotations

import bisect
from collections import deque
from typing import TYPE_CHECKING, Any

import numpy as np

from pearl_ros.core.errors import InputError

if TYPE_CHECKING:  # OpenCV is loaded only where a lens distorts
    from pearl_ros.tracking.tracker import CameraModel

CAMERA_INFO = 'sensor_msgs/msg/CameraInfo'
POSE_TYPES = {'odometry': 'nav_msgs/msg/Odometry', 'pose_stamped': 'geometry_msgs/msg/PoseStamped',
              'pose_with_covariance_stamped': 'geometry_msgs/msg/PoseWithCovarianceStamped'}
# Poses kept for frames to find theirs: a second of 200 Hz odometry.
POSE_CAPACITY = 200


def intrinsics_matrix(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """The 3 x 3 camera matrix of focal lengths ``fx``, ``fy`` and principal point ``cx``,
    ``cy`` (pixels)."""
    if not (fx > 0 and fy > 0 and np.isfinite([fx, fy, cx, cy]).all()):
        raise InputError(f'camera intrinsics must be finite with fx, fy > 0, got fx={fx!r}, '
                         f'fy={fy!r}, cx={cx!r}, cy={cy!r}')
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def read_intrinsics(msg: Any) -> np.ndarray:
    """The 3 x 3 camera matrix ``k`` of a ``sensor_msgs/msg/CameraInfo`` message: finite,
    ``fx``, ``fy`` > 0 and last row (0, 0, 1) (an uncalibrated camera's all-zero ``k`` is
    refused), for the pixels of the binned, cropped image it describes (``binning_x``,
    ``binning_y``, ``roi``). Its lens distortion: :func:`read_lens`."""
    try:
        k = np.asarray(msg.k, dtype=np.float64)
    except AttributeError as err:
        raise InputError(f'not a sensor_msgs/msg/CameraInfo message: {err}') from err
    except (TypeError, ValueError) as err:
        raise InputError(f'camera_info k must be 9 numbers: {err}') from err
    if k.size != 9:
        raise InputError(f'camera_info k must be 9 numbers, got {k.size}')
    k = k.reshape(3, 3)
    if not np.array_equal(k[2], (0.0, 0.0, 1.0)):
        raise InputError(f'camera_info k must end in the row (0, 0, 1) (all zero: an '
                         f'uncalibrated camera), got {k.tolist()}')
    if not np.isfinite(k).all() or k[1, 0] != 0.0:
        raise InputError(f'camera_info k must be finite, [fx s cx; 0 fy cy; 0 0 1], got '
                         f'{k.tolist()}')
    intrinsics_matrix(float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]))  # checks
    # The pixels of a binned or cropped image (REP 104): shift by the region of interest, then
    # divide by the binning (0 means 1), as image_geometry does.
    bin_x = int(getattr(msg, 'binning_x', 0) or 1)
    bin_y = int(getattr(msg, 'binning_y', 0) or 1)
    roi = getattr(msg, 'roi', None)
    x0 = float(getattr(roi, 'x_offset', 0)) if roi is not None else 0.0
    y0 = float(getattr(roi, 'y_offset', 0)) if roi is not None else 0.0
    if (bin_x, bin_y, x0, y0) != (1, 1, 0.0, 0.0):
        k = k.copy()
        k[0, 2] -= x0
        k[1, 2] -= y0
        k[0] /= bin_x
        k[1] /= bin_y
    return k


def read_lens(msg: Any, intrinsics: np.ndarray) -> CameraModel | None:
    """The lens of a ``sensor_msgs/msg/CameraInfo`` (its ``distortion_model`` and ``d``) with
    the camera matrix ``intrinsics`` of :func:`read_intrinsics`, or None where it has no
    distortion (every coefficient 0, or none)."""
    from pearl_ros.tracking.tracker import CameraModel

    try:
        lens = CameraModel.from_camera_info(msg)
    except (AttributeError, TypeError, ValueError) as err:
        raise InputError(f'camera_info distortion cannot be read: {err}') from err
    if not lens.distorted:
        return None
    return CameraModel(intrinsics, lens.distortion, lens.model)


def rotation_matrix(quaternion: np.ndarray) -> np.ndarray:
    """The rotation (3, 3) of a quaternion ``(x, y, z, w)`` (normalised here)."""
    q = np.asarray(quaternion, dtype=np.float64)
    norm = float(np.linalg.norm(q))
    if q.shape != (4,) or not np.isfinite(norm) or norm < 1e-6:
        raise InputError(f'orientation must be a finite, non-zero quaternion, got {q.tolist()}')
    x, y, z, w = q / norm
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def quaternion(rotation: np.ndarray) -> np.ndarray:
    """The unit quaternion ``(x, y, z, w)``, ``w >= 0``, of a rotation matrix (3, 3)."""
    r = np.asarray(rotation, dtype=np.float64)
    # Shepperd's method: from the largest of the four squared components, for accuracy.
    squares = np.array([1 + r[0, 0] - r[1, 1] - r[2, 2], 1 - r[0, 0] + r[1, 1] - r[2, 2],
                        1 - r[0, 0] - r[1, 1] + r[2, 2], 1 + np.trace(r)])
    k = int(np.argmax(squares))
    big = 0.5 * np.sqrt(squares[k])
    quarter = 0.25 / big
    x_y, x_z, y_z = r[0, 1] + r[1, 0], r[0, 2] + r[2, 0], r[1, 2] + r[2, 1]
    z_y, x_z_w, y_x = r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]
    q = [np.array([big, x_y * quarter, x_z * quarter, z_y * quarter]),
         np.array([x_y * quarter, big, y_z * quarter, x_z_w * quarter]),
         np.array([x_z * quarter, y_z * quarter, big, y_x * quarter]),
         np.array([z_y * quarter, x_z_w * quarter, y_x * quarter, big])][k]
    unit: np.ndarray = q / np.linalg.norm(q)
    return unit if unit[3] >= 0 else -unit


def camera_matrix(position: np.ndarray, quaternion: np.ndarray,
                  intrinsics: np.ndarray) -> np.ndarray:
    """The projection matrix (3, 4), pixels from world points, of a camera at ``position``
    (3,) with orientation ``quaternion`` (x, y, z, w; world from the optical frame) and camera
    matrix ``intrinsics`` (3, 3)."""
    centre = np.asarray(position, dtype=np.float64)
    if centre.shape != (3,) or not np.all(np.isfinite(centre)):
        raise InputError(f'position must be 3 finite numbers, got {centre.tolist()}')
    to_camera = rotation_matrix(quaternion).T
    projection: np.ndarray = intrinsics @ np.hstack([to_camera, -to_camera @ centre[:, None]])
    return projection


def mounted(position: np.ndarray, orientation: np.ndarray, mount_position: np.ndarray,
            mount_orientation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pose (position, quaternion x, y, z, w) in the world of a camera mounted at
    ``mount_position`` / ``mount_orientation`` in a frame whose pose in the world is
    ``position`` / ``orientation``: the composition of the two transforms."""
    body = rotation_matrix(orientation)
    centre = np.asarray(position, dtype=np.float64) + body @ np.asarray(mount_position,
                                                                         dtype=np.float64)
    return centre, quaternion(body @ rotation_matrix(mount_orientation))


def read_pose(msg: Any, pose_type: str) -> tuple[np.ndarray, np.ndarray]:
    """The position (3,) and orientation quaternion (x, y, z, w) of an ``Odometry``
    (``pose_type`` 'odometry'), ``PoseStamped`` ('pose_stamped') or
    ``PoseWithCovarianceStamped`` ('pose_with_covariance_stamped') message; the covariance is
    not used."""
    if pose_type not in POSE_TYPES:
        raise InputError(f'pose_type must be one of {sorted(POSE_TYPES)}, got {pose_type!r}')
    try:
        pose = msg.pose if pose_type == 'pose_stamped' else msg.pose.pose
        p, q = pose.position, pose.orientation
        return (np.array([p.x, p.y, p.z], dtype=np.float64),
                np.array([q.x, q.y, q.z, q.w], dtype=np.float64))
    except AttributeError as err:
        raise InputError(f'not a {POSE_TYPES[pose_type]} message: {err}') from err


class PoseBuffer:
    """The latest cameras by stamp, for feature frames to find theirs.

    Parameters
    ----------
    tolerance_ns : int
        A frame takes the camera nearest its stamp, if within this.
    capacity : int
        Cameras kept (the newest).
    """

    def __init__(self, tolerance_ns: int, capacity: int = POSE_CAPACITY) -> None:
        self.tolerance_ns = int(tolerance_ns)
        self._stamps: deque[int] = deque(maxlen=capacity)
        self._cameras: deque[np.ndarray] = deque(maxlen=capacity)

    def __len__(self) -> int:
        return len(self._stamps)

    def clear(self) -> None:
        self._stamps.clear()
        self._cameras.clear()

    def add(self, stamp_ns: int, camera: np.ndarray) -> None:
        """Keep ``camera`` (3, 4) of ``stamp_ns``; an earlier stamp than the newest (a bag
        played again) first forgets the rest."""
        if self._stamps and stamp_ns < self._stamps[-1]:
            self.clear()
        self._stamps.append(int(stamp_ns))
        self._cameras.append(camera)

    def items(self) -> list[tuple[int, np.ndarray]]:
        """The ``(stamp_ns, camera)`` kept, oldest first."""
        return list(zip(self._stamps, self._cameras, strict=True))

    def find(self, stamp_ns: int) -> np.ndarray | None:
        """The camera nearest ``stamp_ns`` within the tolerance, or None."""
        if not self._stamps:
            return None
        stamps = list(self._stamps)
        at = bisect.bisect_left(stamps, stamp_ns)
        best, gap = None, self.tolerance_ns + 1
        for i in (at - 1, at):
            if 0 <= i < len(stamps) and abs(stamps[i] - stamp_ns) < gap:
                best, gap = i, abs(stamps[i] - stamp_ns)
        return None if best is None else self._cameras[best]
