"""Bag I/O with rosbags only: tracked features and ground truth in, and out (no ROS import)."""

from __future__ import annotations

from pearl_ros.bagio.reader import (
    CopiedMessage,
    FeatureFrame,
    FeatureMessage,
    FeatureStream,
    decode_feature_message,
    open_feature_stream,
    read_feature_frames,
    read_features,
    read_ground_truth,
    read_ground_truth_frames,
    topics,
)
from pearl_ros.bagio.writer import OutputBag, open_output_bag, write_feature_bag

__all__ = [
    'CopiedMessage',
    'FeatureFrame',
    'FeatureMessage',
    'FeatureStream',
    'OutputBag',
    'decode_feature_message',
    'open_feature_stream',
    'open_output_bag',
    'read_feature_frames',
    'read_features',
    'read_ground_truth',
    'read_ground_truth_frames',
    'topics',
    'write_feature_bag',
]
