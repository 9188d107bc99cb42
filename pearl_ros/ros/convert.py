"""rclpy message classes for the node's end of :mod:`pearl_ros.bagio.decode` and ``encode``."""

from __future__ import annotations

from typing import Any

import sensor_msgs.msg

from pearl_ros.bagio import encode

# The rclpy classes (and array.array conversions) the encoders build messages with.
TYPES = encode.MessageTypes.from_module(sensor_msgs.msg)

MSG_CLASSES: dict[str, Any] = {
    'PointCloud': sensor_msgs.msg.PointCloud,
    'PointCloud2': sensor_msgs.msg.PointCloud2,
}
# ROS type names as the graph reports them (get_publishers_info_by_topic).
TYPE_NAMES = {name: f'sensor_msgs/msg/{name}' for name in MSG_CLASSES}

