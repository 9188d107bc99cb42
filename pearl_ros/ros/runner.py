"""How a pearl_ros node process runs: arguments checked before ROS starts, ``--help``, a spin
loop that SIGINT and SIGTERM stop between callbacks, and one ``error:`` line for a user error.

``pearl_node`` and ``pearl_tracker`` both run through :func:`run`.
"""

from __future__ import annotations

import gc
import math
import signal
import sys
import threading
import time
from collections.abc import Callable, Mapping
from types import FrameType
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args
from std_msgs.msg import Header

from pearl_ros.core.errors import InputError, one_line
from pearl_ros.pipeline import settings as pipeline_settings
from pearl_ros.pipeline.threads import limit_blas_threads
from pearl_ros.ros import params

WARN_PERIOD_S = 5.0  # s, at most one warning of each kind this often


class Throttle:
    """One warning of each kind per :data:`WARN_PERIOD_S`, counting the
    suppressed ones. Thread-safe (pearl_node warns from its worker and its executor)."""

    def __init__(self, node: Node) -> None:
        self._node = node
        self._warned: dict[str, tuple[float, int]] = {}  # kind -> (last time, suppressed)
        self._lock = threading.Lock()

    def warn(self, kind: str, text: str) -> None:
        with self._lock:
            now = time.monotonic()
            last, suppressed = self._warned.get(kind, (-math.inf, 0))
            if now - last < WARN_PERIOD_S:
                self._warned[kind] = (last, suppressed + 1)
                return
            if suppressed:
                text += f' ({suppressed} more like it in the last {now - last:.0f} s)'
            self._warned[kind] = (now, 0)
            self._node.get_logger().warning(text)


class StopRequest:
    """SIGINT and SIGTERM ask the spin loop to stop between callbacks, never inside one.

    rclpy's own handlers shut the context down at once, under a callback that may be
    publishing; the loop in :func:`run` looks at :attr:`requested` between callbacks instead.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.requested = False
        self._previous = {sig: signal.signal(sig, self._on_signal) for sig in self.SIGNALS}

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        del signum, frame
        self.requested = True

    def restore(self) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)


def fail(err: BaseException | str) -> int:
    """One ``error:`` line on stderr (rcl's messages lose their source locations); 1."""
    text = one_line(err, None)
    print(f'error: {text.split(", at /")[0]}', file=sys.stderr)
    return 1


def run(args: list[str] | None, program: str, usage: Callable[[], str],
        make_node: Callable[[list[str]], Node]) -> int:
    """Run the node ``make_node(params_files)`` until SIGINT or SIGTERM, then return 0.

    ``args`` as ``sys.argv`` (the program first; default ``sys.argv``). Returns 1 after one
    ``error:`` line for a bad parameter, parameter file or argument; ``-h`` / ``--help``
    prints ``usage()`` and returns 0 without starting ROS.
    """
    argv = list(sys.argv if args is None else args)
    files = params.params_files(argv)
    try:
        for path in files:  # each readable and a ROS parameter file, before rcl parses it
            pipeline_settings.load_file(path, None)
        own = remove_ros_args(argv)[1:]
    except (InputError, RuntimeError) as err:  # RuntimeError: rclpy's RCLInvalidROSArgsError
        return fail(err)
    if own and own[0] in ('-h', '--help'):
        print(usage(), end='')
        return 0
    if own:
        return fail(f'unrecognized arguments: {" ".join(own)} (ROS arguments go after '
                    f'--ros-args; see {program} --help)')
    limit_blas_threads()
    stop = StopRequest()
    try:
        return _spin(argv, files, stop, make_node)
    finally:
        stop.restore()


def _spin(argv: list[str], files: list[str], stop: StopRequest,
          make_node: Callable[[list[str]], Node]) -> int:
    try:
        rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    except RuntimeError as err:  # rclpy's RCLError
        return fail(err)
    node = None
    try:
        node = make_node(files)
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        # What start-up made (numpy, scipy, rclpy, the node: some 80,000 objects) lives as long
        # as the process: out of the collector's reach, a full collection no longer scans it
        # (36-40 ms at a time, longer than a frame at 30 Hz).
        gc.freeze()
        while not stop.requested and rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
    except (InputError, ParameterException) as err:
        return fail(err)
    except ExternalShutdownException:
        pass
    except Exception:
        if rclpy.ok():  # a bug
            raise
        # else: the context was shut down under a callback; what rclpy raised then is noise
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


def diagnostics(node: Node, task: str, running: str, problems: list[str],
                values: Mapping[str, Any]) -> DiagnosticArray:
    """One ``/diagnostics`` message of ``node``: a status named after the node and its ``task``,
    WARN with the ``problems`` joined when there are any, else OK saying ``running``."""
    status = DiagnosticStatus(
        level=DiagnosticStatus.WARN if problems else DiagnosticStatus.OK,
        name=f'{node.get_name()}: {task}',
        message='; '.join(problems) if problems else running,
        hardware_id=node.get_fully_qualified_name(),
        values=[KeyValue(key=key, value=str(value)) for key, value in values.items()],
    )
    return DiagnosticArray(header=Header(stamp=node.get_clock().now().to_msg()),
                           status=[status])
