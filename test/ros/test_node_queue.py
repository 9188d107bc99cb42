"""``queue_policy``: what pearl_node answers when it is slower than its input, and what it drops.

Real nodes on a real executor. The subscription callback hands each message to the node's worker
thread; a test holds the worker's pipeline lock to stand for a frame that outlasts a burst
(so what is dropped does not depend on the machine's speed), or sends large frames when the
worker must really be computing.
"""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from std_srvs.srv import Trigger

from pearl_ros.bagio import decode
from pearl_ros.core.errors import InputError
from pearl_ros.datasets.synthetic import StreamFrame, synthetic_stream
from pearl_ros.online.config import build_configs
from pearl_ros.online.segmenter import OnlineSegmenter
from pearl_ros.ros.node import Mailbox, PearlNode

from ros_harness import Probe, Ros, vins_cloud

# Births, deaths and a shuffled order every frame: each frame's ids differ from its
# neighbours', so an answer carrying another frame's features shows.
STREAM = list(synthetic_stream(num_features=120, frames=20, seed=3))
LARGE = list(synthetic_stream(num_features=1000, frames=8, seed=4))  # frames of 40-500 ms
# No time budget: the labels do not depend on the machine's speed, a segmenter run directly on
# the answered frames is the oracle.
EXACT = {'budget_ms': 0.0, 'qos': 'reliable'}


def cloud(frame: StreamFrame) -> Any:
    return vins_cloud(frame.stamp_ns, frame.ids, frame.uv)


def _start(ros: Ros, **overrides: Any) -> tuple[PearlNode, Probe]:
    node = ros.pearl(**overrides)
    probe = ros.probe()
    probe.wait_for(node)
    return node, probe


def _burst_while_busy(ros: Ros, node: PearlNode, probe: Probe,
                      frames: list[StreamFrame]) -> None:
    """Publish ``frames`` at once while the worker cannot finish a frame, and wait until the
    node took every one of them (the input QoS keeps the whole burst)."""
    with node._pipeline_lock:
        for frame in frames:
            probe.publisher.publish(cloud(frame))
        assert ros.spin_until(lambda: node.stats.received == len(frames), 10.0)


def _settled(ros: Ros, node: PearlNode, probe: Probe, sent: int) -> dict[str, str]:
    """Once every message sent is answered or dropped: the last diagnostics saying so."""
    def done(values: dict[str, str]) -> bool:
        answered = int(values['messages processed'])
        return (values['messages received'] == str(sent) and len(probe.labels) == answered
                and answered + int(values['messages dropped (late)']) == sent)
    return probe.diagnostics_where(done, 30.0)


def _check_answers(probe: Probe, frames: list[StreamFrame]) -> list[StreamFrame]:
    """Each answer is its own input's (stamp, ids, pixels in input order) and carries the
    labels a segmenter fed with the answered frames only gives; the answered frames."""
    by_stamp = {frame.stamp_ns: frame for frame in frames}
    stamps = [decode.stamp_ns(msg.header) for msg in probe.labels]
    assert stamps == sorted(stamps) and len(set(stamps)) == len(stamps), stamps
    answered = [by_stamp[stamp] for stamp in stamps]
    segmenter = OnlineSegmenter(*build_configs({'budget_ms': 0.0}))
    for frame, msg in zip(answered, probe.labels, strict=True):
        columns = decode.decode_fields(msg, ('id', 'u', 'v', 'label'))
        np.testing.assert_array_equal(columns['id'], frame.ids)
        np.testing.assert_allclose(np.column_stack((columns['u'], columns['v'])), frame.uv,
                                   atol=1e-3)
        expected = segmenter.process(frame.stamp_ns, frame.ids, frame.uv)
        np.testing.assert_array_equal(columns['label'], expected.labels)
    return answered


def test_mailbox_newest_keeps_one_item_and_all_keeps_the_newest_depth() -> None:
    newest, backlog = Mailbox('newest', 3), Mailbox('all', 3)
    assert [newest.put(k) for k in range(4)] == [None, 0, 1, 2]
    assert [backlog.put(k) for k in range(5)] == [None, None, None, 0, 1]
    assert newest.take() == 3 and len(newest) == 0
    assert [backlog.take() for _ in range(3)] == [2, 3, 4]
    backlog.put(9)
    backlog.close()
    assert backlog.take() is None and newest.put(5) is None


def test_mailbox_close_wakes_a_worker_that_waits() -> None:
    mailbox = Mailbox('newest', 1)
    taken: list[Any] = []
    worker = threading.Thread(target=lambda: taken.append(mailbox.take()))
    worker.start()
    mailbox.close()
    worker.join(10.0)
    assert not worker.is_alive() and taken == [None]


def test_newest_answers_the_last_message_of_a_burst_and_counts_the_ones_it_dropped(
    ros: Ros,
) -> None:
    # qos_depth holds the burst, so that DDS drops nothing: every message reaches the node and
    # is either answered or counted.
    node, probe = _start(ros, qos_depth=50, **EXACT)
    assert node.get_parameter('queue_policy').value == 'newest'  # the default
    _burst_while_busy(ros, node, probe, STREAM)
    values = _settled(ros, node, probe, len(STREAM))
    answered = _check_answers(probe, STREAM)
    assert answered[-1] is STREAM[-1]
    # The worker took at most one message before the burst; every other one but the newest
    # was replaced before it got to it.
    assert len(answered) <= 2
    assert int(values['messages dropped (late)']) == len(STREAM) - len(answered)
    assert values['internal errors'] == values['malformed messages'] == '0'
    late = probe.diagnostics_where(lambda v: 'dropped: the node is slower' in v['_message'])
    assert late['_level'] == DiagnosticStatus.WARN
    assert late['_message'].startswith(f'{len(STREAM) - len(answered)} message(s) dropped')
    assert ros.spin_until(lambda: probe.warnings('dropped unanswered'))
    assert 'queue_policy newest' in probe.warnings('dropped unanswered')[0]
    # Later messages are answered as before.
    follow = list(synthetic_stream(num_features=120, frames=22, seed=3))[20:]
    for frame in follow:
        probe.send(cloud(frame))


def test_all_answers_every_message_of_a_burst_in_order(ros: Ros) -> None:
    node, probe = _start(ros, qos_depth=50, queue_policy='all', **EXACT)
    _burst_while_busy(ros, node, probe, STREAM)
    values = _settled(ros, node, probe, len(STREAM))
    assert _check_answers(probe, STREAM) == STREAM
    assert values['messages dropped (late)'] == '0'


def test_all_drops_the_oldest_beyond_qos_depth_and_counts_it(ros: Ros) -> None:
    depth, sent = 5, STREAM[:12]
    node, probe = _start(ros, qos_depth=depth, queue_policy='all', **EXACT)
    with node._pipeline_lock:
        for k, frame in enumerate(sent):  # one at a time: DDS's own depth-5 history drops none
            probe.publisher.publish(cloud(frame))
            assert ros.spin_until(lambda k=k: node.stats.received == k + 1, 10.0)
    values = _settled(ros, node, probe, len(sent))
    answered = _check_answers(probe, sent)
    assert answered[-depth:] == sent[-depth:]  # the backlog: the newest qos_depth
    assert len(answered) <= depth + 1  # and the one the worker may have taken first
    assert int(values['messages dropped (late)']) == len(sent) - len(answered)
    assert ros.spin_until(lambda: probe.warnings('dropped unanswered'))
    assert '5 messages (qos_depth) were already waiting' in probe.warnings('dropped')[0]


def test_the_time_spent_publishing_comes_out_of_the_next_frames_budget(
        ros: Ros, monkeypatch: pytest.MonkeyPatch) -> None:
    # Publishing that takes 30 ms after each answer leaves the fits of the frames after at
    # most 20 ms of a 50 ms budget, counted from when the node took the message.
    from pearl_ros.online import segmenter as module

    real_fit, room = module.fit, []

    def timed_fit(tracks: Any, config: Any, rng: Any, **kwargs: Any) -> Any:
        room.append(kwargs['deadline'] - time.perf_counter())
        return real_fit(tracks, config, rng, **kwargs)

    monkeypatch.setattr(module, 'fit', timed_fit)
    node, probe = _start(ros, budget_ms=50.0, qos='reliable')
    publish = node._static_pub.publish

    def slow_publish(msg: Any) -> None:
        time.sleep(0.030)
        publish(msg)

    node._static_pub.publish = slow_publish  # type: ignore[method-assign]
    for frame in STREAM[:10]:
        probe.send(cloud(frame))
    assert len(room) > 4
    assert max(room) <= 0.020


def test_queue_policy_is_read_only_and_refuses_an_unknown_policy(ros: Ros) -> None:
    node, probe = _start(ros)
    result = node.set_parameters([Parameter('queue_policy', value='all')])[0]
    assert not result.successful and 'read-only' in result.reason
    with pytest.raises(InputError, match='queue_policy must be one of'):
        ros.pearl(queue_policy='oldest')
    del probe


def test_reset_and_a_parameter_change_while_the_worker_computes_apply_between_frames(
    ros: Ros,
) -> None:
    node, probe = _start(ros, qos_depth=50, queue_policy='all', budget_ms=0.0, qos='reliable')
    client = AsyncParameterClient(probe.node, f'{ros.ns}/pearl_node')
    assert client.wait_for_services(timeout_sec=10.0)
    reset = probe.node.create_client(Trigger, f'{ros.ns}/pearl_node/reset')
    assert reset.wait_for_service(timeout_sec=10.0)
    for frame in LARGE[:5]:  # several seconds of work waiting for the worker
        probe.publisher.publish(cloud(frame))
    assert ros.spin_until(lambda: node.stats.received == 5, 10.0)
    reset_done = reset.call_async(Trigger.Request())
    change_done = client.set_parameters([Parameter('label_cost', value=300.0),
                                         Parameter('window', value=4)])
    assert ros.spin_until(lambda: reset_done.done() and change_done.done(), 30.0)
    assert reset_done.result().success
    assert all(r.successful for r in change_done.result().results)
    assert node.settings.config.label_cost == 300.0
    assert ros.spin_until(lambda: len(probe.labels) == 5, 60.0)  # the backlog, answered
    stamps = [decode.stamp_ns(msg.header) for msg in probe.labels]
    assert stamps == [frame.stamp_ns for frame in LARGE[:5]]
    probe.send(cloud(LARGE[5]), timeout=30.0)
    values = probe.diagnostics_where(lambda v: v['messages processed'] == '6', 10.0)
    assert values['reset requests'] == '1' and values['internal errors'] == '0'
    assert int(values['frames in window']) <= 4


def test_destroy_node_while_the_worker_computes_returns_without_the_backlog(ros: Ros) -> None:
    node, probe = _start(ros, qos_depth=50, queue_policy='all', budget_ms=0.0, qos='reliable')
    for frame in LARGE:
        probe.publisher.publish(cloud(frame))
    assert ros.spin_until(lambda: node.stats.received == len(LARGE), 10.0)
    before = node.stats.processed
    ros.executor.remove_node(node)
    ros.nodes.remove(node)
    node.destroy_node()
    assert not node._worker.is_alive()
    # At most the frame it was on, and one it may have taken before it was told to stop.
    assert node.stats.processed <= before + 2
    assert node.stats.errors == 0


def test_a_context_shut_down_while_the_worker_computes_stops_the_worker(ros: Ros) -> None:
    node, probe = _start(ros, qos_depth=50, queue_policy='all', budget_ms=0.0, qos='reliable')
    for frame in LARGE:
        probe.publisher.publish(cloud(frame))
    assert ros.spin_until(lambda: node.stats.received == len(LARGE), 10.0)
    ros.context.try_shutdown()  # destroys the node: the worker ends its frame quietly
    assert not node._worker.is_alive()
    assert node.stats.errors == 0
