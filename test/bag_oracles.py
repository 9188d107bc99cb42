"""Independent bag reading for the tests: rosbags alone, not pearl_ros.bagio.reader."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore


def raw_messages(path: Path, topic: str) -> list[object]:
    """Messages of ``topic`` decoded by rosbags alone (independent of pearl_ros.bagio.reader)."""
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_KILTED)) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        return [
            reader.deserialize(raw, c.msgtype)
            for c, _, raw in reader.messages(connections=connections)
        ]


def as_float32(values: np.ndarray) -> np.ndarray:
    """``values`` rounded to float32 as a message carries them, back in float64."""
    return np.asarray(values, dtype=np.float32).astype(np.float64)
