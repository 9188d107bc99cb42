"""rclpy message classes for the node's end of :mod:`pearl_ros.bagio.decode` and ``encode``."""

from __future__ import annotations

from typing import Any

import geometry_msgs.msg
import nav_msgs.msg
import sensor_msgs.msg

from pearl_ros.bagio import encode
from pearl_ros.pipeline.poses import CAMERA_INFO, POSE_TYPES

# The rclpy classes (and array.array conversions) the encoders build messages with.
TYPES = encode.MessageTypes.from_module(sensor_msgs.msg)

MSG_CLASSES: dict[str, Any] = {
    'PointCloud': sensor_msgs.msg.PointCloud,
    'PointCloud2': sensor_msgs.msg.PointCloud2,
}
# ROS type names as the graph reports them (get_publishers_info_by_topic).
TYPE_NAMES = {name: f'sensor_msgs/msg/{name}' for name in MSG_CLASSES}

# The rclpy classes of the camera pose types (pose_type: POSE_TYPES) and of camera_info, by
# ROS type name.
POSE_CLASSES: dict[str, Any] = {POSE_TYPES[name]: kind for name, kind in (
    ('odometry', nav_msgs.msg.Odometry),
    ('pose_stamped', geometry_msgs.msg.PoseStamped),
    ('pose_with_covariance_stamped', geometry_msgs.msg.PoseWithCovarianceStamped))}
CAMERA_INFO_CLASSES: dict[str, Any] = {CAMERA_INFO: sensor_msgs.msg.CameraInfo}

