"""Bag I/O with rosbags only: tracked features and ground truth in, and out (no ROS import)."""

from __future__ import annotations

from pearl_ros.bagio.reader import FeatureFrame, read_feature_frames, read_ground_truth, topics
from pearl_ros.bagio.writer import write_feature_bag

__all__ = [
    'FeatureFrame',
    'read_feature_frames',
    'read_ground_truth',
    'topics',
    'write_feature_bag',
]
