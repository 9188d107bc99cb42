"""The online segmenter answers alike whatever the tracks' pixel unit and origin.

A robot-like stream (0.5 px tracking noise, ten times the scale's floor ``min_noise``, the one
quantity in pixels) fed once as it is and once zoomed by 2.5 and moved by 1,500 px, as a camera
of another resolution and principal point would give it: every frame's motion numbers are the
same (test/core/test_units.py holds the batch fits to it).
"""

from __future__ import annotations

import numpy as np

from pearl_ros.datasets.robot import robot_stream
from pearl_ros.datasets.synthetic import FRAME_NS
from pearl_ros.online.config import OnlineConfig
from pearl_ros.online.segmenter import OnlineSegmenter

ZOOM, SHIFT = 2.5, np.array([1500.0, -700.0])


def test_a_stream_zoomed_and_moved_gets_the_same_motion_numbers():
    plain = OnlineSegmenter(online=OnlineConfig(budget_ms=0.0))
    zoomed = OnlineSegmenter(online=OnlineConfig(budget_ms=0.0))
    motions = set()
    for t, frame in enumerate(robot_stream(frames=40, seed=0)):
        stamp = 1_000_000_000 + t * FRAME_NS
        ours = plain.process(stamp, frame.ids, frame.uv)
        theirs = zoomed.process(stamp, frame.ids, frame.uv * ZOOM + SHIFT)
        assert np.array_equal(ours.labels, theirs.labels), f'frame {t}'
        motions.update(int(m) for m in ours.labels if m >= 0)
    # The stream is no trivial case: the answers hold more than one motion.
    assert len(motions) >= 2
