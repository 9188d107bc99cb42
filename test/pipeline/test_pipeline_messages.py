"""The per-message pipeline on rosbags messages, against the segmenter called directly."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pearl_ros.bagio.decode import decode_labels, decode_pointcloud
from pearl_ros.online.config import build_configs
from pearl_ros.online.segmenter import OnlineSegmenter
from pearl_ros.pipeline.messages import Labelled, MessagePipeline, Skipped
from pearl_ros.pipeline.settings import build

from bag_oracles import raw_messages

BAG = Path(__file__).resolve().parents[2] / 'bags' / '1R2RCR_g12'
MESSAGES = raw_messages(BAG, '/feature_tracker/feature')


def labelled(out: Labelled | Skipped) -> Labelled:
    assert isinstance(out, Labelled), out
    return out


def test_capped_messages_segment_the_same_ids_every_frame_as_the_segmenter_would() -> None:
    pipeline = MessagePipeline(build({'budget_ms': 0.0, 'max_features': 60}))
    segmenter = OnlineSegmenter(*build_configs({'budget_ms': 0.0}))
    kept = []
    for msg in MESSAGES[:6]:
        out = labelled(pipeline.process(msg))
        ids, uv = decode_pointcloud(msg)
        assert out.capped and int(out.segmented.sum()) == 60
        kept.append(set(ids[out.segmented].tolist()))
        expected = segmenter.process(out.stamp_ns, ids[out.segmented], uv[out.segmented])
        np.testing.assert_array_equal(out.labels[out.segmented], expected.labels)
        assert (out.labels[~out.segmented] == -1).all()
        label_ids, labels = decode_labels(out.labels_msg)
        np.testing.assert_array_equal(label_ids, ids)  # every feature, in input order
        np.testing.assert_array_equal(labels, out.labels)
    assert all(ids == kept[0] for ids in kept)  # the subsample follows the ids


@pytest.mark.parametrize('background', [-1, 0, 1])
def test_static_features_are_the_chosen_or_the_largest_motion(background: int) -> None:
    pipeline = MessagePipeline(build({'budget_ms': 0.0, 'background_motion': background}))
    for msg in MESSAGES[:5]:
        out = labelled(pipeline.process(msg))
    numbers, counts = np.unique(out.labels[out.labels >= 0], return_counts=True)
    assert numbers.size == 2
    chosen = numbers[np.argmax(counts)] if background < 0 else background
    np.testing.assert_array_equal(out.static, out.labels == chosen)
    ids, _ = decode_pointcloud(out.static_msg)
    np.testing.assert_array_equal(ids, out.ids[out.labels == chosen])


def test_a_skipped_message_says_why_and_leaves_the_window_alone() -> None:
    pipeline = MessagePipeline(build({'budget_ms': 0.0}))
    labelled(pipeline.process(MESSAGES[0]))
    repeated = pipeline.process(MESSAGES[0])
    assert isinstance(repeated, Skipped)
    assert (repeated.kind, repeated.malformed) == ('stamp', False)
    assert repeated.line.startswith('skipped (stamp): stamp ')
    broken = MESSAGES[1].__class__(header=MESSAGES[1].header, points=MESSAGES[1].points,
                                   channels=MESSAGES[1].channels[1:3])
    skip = pipeline.process(broken)
    assert isinstance(skip, Skipped) and skip.malformed and skip.kind == 'layout'
    assert pipeline.frames_in_window == 1
    labelled(pipeline.process(MESSAGES[1]))
    assert pipeline.frames_in_window == 2


def test_reconfigure_keeps_the_window_and_reset_empties_it() -> None:
    pipeline = MessagePipeline(build({'budget_ms': 0.0}))
    for msg in MESSAGES[:4]:
        labelled(pipeline.process(msg))
    pipeline.reconfigure(build({'budget_ms': 0.0, 'window': 3}))
    labelled(pipeline.process(MESSAGES[4]))
    assert pipeline.frames_in_window == 3 and pipeline.settings.online.window == 3
    pipeline.reset()
    out = labelled(pipeline.process(MESSAGES[5]))
    assert pipeline.frames_in_window == 1 and (out.labels == -1).all()


def test_the_outputs_carry_the_header_given() -> None:
    pipeline = MessagePipeline()
    header = MESSAGES[0].header.__class__(stamp=MESSAGES[0].header.stamp, frame_id='other')
    out = labelled(pipeline.process(MESSAGES[0], header))
    assert out.labels_msg.header is header and out.static_msg.header is header
