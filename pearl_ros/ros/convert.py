"""rclpy messages <-> numpy: the node's end of :mod:`pearl_ros.bagio.decode` and ``encode``."""

from __future__ import annotations

from typing import Any

import geometry_msgs.msg
import numpy as np
import sensor_msgs.msg

from pearl_ros.bagio import decode, encode

# The rclpy classes (and array.array conversions) the encoders build messages with.
TYPES = encode.MessageTypes.from_modules(sensor_msgs.msg, geometry_msgs.msg)

MSG_CLASSES: dict[str, Any] = {
    'PointCloud': sensor_msgs.msg.PointCloud,
    'PointCloud2': sensor_msgs.msg.PointCloud2,
}
# ROS type names as the graph reports them (get_publishers_info_by_topic).
TYPE_NAMES = {name: f'sensor_msgs/msg/{name}' for name in MSG_CLASSES}


def read_features(msg: Any, msg_type: str, layout: str, camera_id: int
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Feature ids (N,) int64 and pixels (N, 2) float64 of an input message.

    Raises
    ------
    InputError
        Whatever :mod:`~pearl_ros.bagio.decode` refuses, PointCloud ids beyond float32's exact
        range, ids the uint32 output field cannot hold.
    """
    if msg_type == 'PointCloud2':
        ids, uv = decode.decode_pointcloud2(msg)
    else:
        ids, uv = decode.decode_pointcloud(msg, layout, camera_id)
        encode.check_float32_ids(ids)
    encode.check_label_ids(ids)
    return ids, uv
