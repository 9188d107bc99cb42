"""ROS parameters of ``pearl_node``: declared from the configuration objects, validated on set.

Three groups, all declared with a description and a range (``ParameterDescriptor``):

- every field of :class:`~pearl_ros.core.config.PearlConfig` and
  :class:`~pearl_ros.online.config.OnlineConfig`, from
  :func:`~pearl_ros.core.config.parameter_specs` (the defaults are written once, there);
- the node's own parameters, :data:`NODE_SPECS` (input type, layout, QoS, caps...), in the same
  :class:`~pearl_ros.core.config.ParameterSpec` form. Those that shape a subscription are
  read-only after start-up.
"""

from __future__ import annotations

import sys
import textwrap
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node

from pearl_ros.bagio import decode
from pearl_ros.core.config import ParameterSpec, PearlConfig, check_value, parameter_specs
from pearl_ros.core.errors import InputError
from pearl_ros.online.config import OnlineConfig, build_configs

MSG_TYPES = ('PointCloud', 'PointCloud2')
QOS_CHOICES = ('sensor_data', 'reliable')

_INT64 = 2**63 - 1

# The node's own parameters. Read-only ones fix the subscription and the timers at start-up.
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
READ_ONLY = frozenset({'msg_type', 'qos', 'qos_depth', 'diagnostics_period'})
CONFIG_SPECS: tuple[ParameterSpec, ...] = parameter_specs(PearlConfig) + parameter_specs(
    OnlineConfig)
ALL_SPECS: tuple[ParameterSpec, ...] = CONFIG_SPECS + NODE_SPECS
CONFIG_NAMES = frozenset(item.name for item in CONFIG_SPECS)


@dataclass(frozen=True)
class NodeSettings:
    """The node's own parameter values (see :data:`NODE_SPECS` for meaning and units)."""

    msg_type: str
    layout: str
    camera_id: int
    qos: str
    qos_depth: int
    max_features: int
    background_motion: int
    diagnostics_period: float


def descriptor(item: ParameterSpec) -> ParameterDescriptor:
    """The ROS descriptor of one parameter: description, range, choices, read-only flag."""
    desc = ParameterDescriptor(
        name=item.name, description=item.doc, read_only=item.name in READ_ONLY
    )
    if item.choices is not None:
        desc.additional_constraints = 'one of: ' + ', '.join(item.choices)
    if item.type is float:
        low = -sys.float_info.max if item.low is None else float(item.low)
        high = sys.float_info.max if item.high is None else float(item.high)
        desc.floating_point_range = [FloatingPointRange(from_value=low, to_value=high, step=0.0)]
    elif item.type is int:
        low = -_INT64 - 1 if item.low is None else int(item.low)
        high = _INT64 if item.high is None else int(item.high)
        desc.integer_range = [IntegerRange(from_value=low, to_value=high, step=1)]
    return desc


def declare(node: Node) -> dict[str, Any]:
    """Declare every parameter on ``node``; returns name -> value (overrides applied).

    Raises
    ------
    rclpy.exceptions.ParameterException
        An override of the wrong type or outside its range (rclpy checks the descriptor).
    """
    values = {}
    for item in ALL_SPECS:
        values[item.name] = node.declare_parameter(item.name, item.default,
                                                   descriptor(item)).value
    return values


def defaults() -> dict[str, Any]:
    """Name -> default of every declared parameter (what ``config/pearl.yaml`` holds)."""
    return {item.name: item.default for item in ALL_SPECS}


def build(values: Mapping[str, Any], base: tuple[PearlConfig, OnlineConfig] | None = None
          ) -> tuple[PearlConfig, OnlineConfig, NodeSettings]:
    """The configuration objects and node settings from parameter values.

    Parameters
    ----------
    values : mapping
        Name -> value; names of both groups, all node names present (config names may be a
        subset: the others come from ``base``).
    base : (PearlConfig, OnlineConfig), optional

    Raises
    ------
    InputError
        A value of the wrong type, out of range or not among the choices, naming it.
    """
    config, online = build_configs({k: v for k, v in values.items() if k in CONFIG_NAMES}, base)
    node_values = {item.name: values[item.name] for item in NODE_SPECS}
    check_node_values(node_values.items())
    return config, online, NodeSettings(**node_values)


def check_node_values(items: Iterable[tuple[str, Any]]) -> None:
    """Raise InputError naming the first node parameter of the wrong type or out of range."""
    specs = {item.name: item for item in NODE_SPECS}
    for name, value in items:
        check_value(specs[name], value)


def defaults_yaml() -> str:
    """``config/pearl.yaml``: every parameter with its default and description, ROS format.

    Regenerate the file with ``python -m pearl_ros.ros.params > config/pearl.yaml``.
    """
    lines = [
        '# pearl_node parameters with their defaults (pearl_ros.core.config.PearlConfig,',
        "# pearl_ros.online.config.OnlineConfig and the node's own, pearl_ros.ros.params).",
        '# Generated by `python -m pearl_ros.ros.params > config/pearl.yaml`; a test checks it.',
        '# Floats keep their decimal point: ROS parameters are typed, and 1000 is an integer.',
        '# Use: pearl_node --ros-args --params-file config/pearl.yaml (or the launch file).',
        '/**:',
        '  ros__parameters:',
    ]
    groups = (
        ('The PEaRL energy and optimiser (PearlConfig)', parameter_specs(PearlConfig)),
        ('Streaming: window, warm start, budget (OnlineConfig)', parameter_specs(OnlineConfig)),
        ('The node (read-only ones are fixed at start-up)', NODE_SPECS),
    )
    for title, specs in groups:
        lines.append(f'    # {title}')
        for item in specs:
            doc = item.doc + (' [read-only]' if item.name in READ_ONLY else '')
            lines.extend(f'    # {line}' for line in textwrap.wrap(doc, 88))
            lines.append(f'    {item.name}: {_yaml_value(item.default)}')
    return '\n'.join(lines) + '\n'


def _yaml_value(value: Any) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, float):
        text = repr(value)
        # YAML 1.1 reads 1e-06 as a string: give the mantissa its point (1.0e-06).
        mantissa, e, exponent = text.partition('e')
        return (mantissa if '.' in mantissa else mantissa + '.0') + (e + exponent if e else '')
    return str(value)




def markdown_table() -> str:
    """The README's parameter table (a test checks that the README holds it verbatim)."""
    rows = ['| parameter | default | range | description |', '| --- | --- | --- | --- |']
    for item in ALL_SPECS:
        if item.choices is not None:
            allowed = ' \\| '.join(item.choices)
        elif item.low is not None or item.high is not None:
            allowed = f'{_number(item.low)} .. {_number(item.high)}'
        else:
            allowed = 'true \\| false' if item.type is bool else ''
        doc = item.doc.replace('|', '\\|') + (' (read-only)' if item.name in READ_ONLY else '')
        rows.append(f'| `{item.name}` | `{_yaml_value(item.default)}` | {allowed} | {doc} |')
    return '\n'.join(rows) + '\n'


def _number(value: float | None) -> str:
    if value is None:
        return ''
    if value == _INT64:
        return '2^63-1'
    return f'{value:g}'


if __name__ == '__main__':
    # python -m pearl_ros.ros.params > config/pearl.yaml; --markdown: the README's table.
    sys.stdout.write(markdown_table() if sys.argv[1:] == ['--markdown'] else defaults_yaml())
