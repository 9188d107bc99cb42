"""The node process's runner: what it does once the node is made, before it spins."""

from __future__ import annotations

import gc
from typing import Any

import rclpy

from pearl_ros.ros import runner


def test_start_up_objects_are_out_of_the_collectors_full_scans_once_the_node_spins() -> None:
    # A list made with the node lives on; once the executor spins, a full collection (36-40 ms
    # over a started node's objects) no longer scans it, nor anything else start-up made.
    seen: dict[str, Any] = {}

    def make_node(files: list[str]) -> rclpy.node.Node:
        node = rclpy.create_node('freeze_probe')
        made_at_start = [node]

        def first_spin() -> None:
            seen['scanned'] = any(o is made_at_start for o in gc.get_objects())
            seen['frozen'] = gc.get_freeze_count()
            rclpy.shutdown()  # the runner's loop ends as after SIGINT

        seen['timer'] = node.create_timer(0.01, first_spin)
        seen['scanned before'] = any(o is made_at_start for o in gc.get_objects())
        return node

    try:
        assert runner.run(['freeze_probe'], 'freeze_probe', lambda: '', make_node) == 0
    finally:
        gc.unfreeze()
    assert seen['scanned before']  # the probe sees a tracked object as tracked
    assert not seen['scanned'] and seen['frozen'] > 10_000
