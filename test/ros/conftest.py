"""The ``ros`` fixture: one rclpy context, executor and namespace per test, always closed."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from ros_harness import Ros


@pytest.fixture
def ros() -> Iterator[Ros]:
    harness = Ros()
    try:
        yield harness
    finally:
        harness.close()
