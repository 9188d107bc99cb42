"""Parameters of the front ends beyond the configuration objects: ``pearl_node``'s own.

ROS-free, so that ``pearl_replay`` reads the same names, defaults and ranges from a node
parameter file without importing rclpy; :mod:`pearl_ros.ros.params` declares them on the node.
"""

from __future__ import annotations

from pearl_ros.bagio import decode
from pearl_ros.core.config import ParameterSpec

MSG_TYPES = ('PointCloud', 'PointCloud2')
QOS_CHOICES = ('sensor_data', 'reliable')

_INT64 = 2**63 - 1

# The node's own parameters; pearl_ros.ros.params makes those that fix the subscription and the
# timers read-only after start-up.
NODE_SPECS: tuple[ParameterSpec, ...] = (
    ParameterSpec('msg_type', 'PointCloud', str,
                  'input message type on `features`: sensor_msgs/msg/PointCloud (VINS) or '
                  'PointCloud2 (fields id and u, v or x, y)', None, None, MSG_TYPES),
    ParameterSpec('layout', 'auto', str,
                  'PointCloud channel layout: vins_mono (channels by name), vins_fusion (by '
                  'index: id, camera, u, v, ...), auto (vins_mono if a channel is named '
                  'id_of_point)', None, None, decode.LAYOUTS),
    ParameterSpec('camera_id', 0, int,
                  'camera whose features are segmented (vins_fusion layout); the other '
                  "cameras' features pass to static_features untouched", 0, 1_000_000, None),
    ParameterSpec('qos', 'sensor_data', str,
                  'input QoS: sensor_data (best effort, keep last qos_depth) or reliable '
                  '(keep last qos_depth; VINS publishes reliable)', None, None, QOS_CHOICES),
    ParameterSpec('qos_depth', 5, int, 'messages, input queue depth', 1, 100_000, None),
    ParameterSpec('max_features', 2000, int,
                  'features per message fed to the segmenter; a larger message is subsampled '
                  'by a hash of the ids (the same ids kept every frame), the rest labelled -1',
                  1, 10_000_000, None),
    ParameterSpec('background_motion', -1, int,
                  'motion number published on static_features; -1 = the motion with the most '
                  'features (ties: the lowest number)', -1, _INT64, None),
    ParameterSpec('diagnostics_period', 1.0, float,
                  's, period of /diagnostics and of the check for publishers of another type '
                  'on `features`', 0.01, 3600.0, None),
)
