"""ROS parameters of ``pearl_node``: declared from the configuration objects, checked at start-up.

Three groups, all declared with a description and a range (``ParameterDescriptor``):

- every field of :class:`~pearl_ros.core.config.PearlConfig` and
  :class:`~pearl_ros.online.config.OnlineConfig`, from
  :func:`~pearl_ros.core.config.parameter_specs` (the defaults are written once, there);
- the node's own parameters, :class:`~pearl_ros.pipeline.settings.NodeConfig` (input type,
  layout, QoS, caps, ``image_topic``...), in the same form. Those that shape a subscription
  are read-only after start-up.

Values are turned into settings by :func:`pearl_ros.pipeline.settings.build`, as
``pearl_replay`` and ``pearl_bench`` turn theirs.
"""

from __future__ import annotations

import sys
import textwrap
from collections.abc import Mapping, Sequence
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node
from rclpy.parameter import Parameter

from pearl_ros.core.config import ParameterSpec, PearlConfig, check_value, parameter_specs
from pearl_ros.core.errors import InputError
from pearl_ros.online.config import OnlineConfig, unknown_parameter
from pearl_ros.pipeline import settings as pipeline_settings
from pearl_ros.pipeline.settings import NODE_SPECS

_INT64 = 2**63 - 1

READ_ONLY = frozenset({'msg_type', 'qos', 'qos_depth', 'queue_policy', 'diagnostics_period',
                       'image_topic', 'pose_topic', 'pose_type', 'camera_info_topic'})
CONFIG_SPECS: tuple[ParameterSpec, ...] = parameter_specs(PearlConfig) + parameter_specs(
    OnlineConfig)
ALL_SPECS: tuple[ParameterSpec, ...] = CONFIG_SPECS + NODE_SPECS
NAMES: tuple[str, ...] = tuple(item.name for item in ALL_SPECS)
# ROS arguments that take a value (rcl's --ros-args syntax), to find --params-file among them.
_VALUED = frozenset({'-p', '--param', '-r', '--remap', '-e', '--enclave', '--log-level',
                     '--log-config-file', '--log-file-name', '--params-file'})


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


def declare(node: Node, overrides: Mapping[str, Parameter[Any]]) -> dict[str, Any]:
    """Declare every parameter on ``node``; returns name -> value (overrides applied).

    Parameters
    ----------
    node : Node
    overrides : mapping of str -> Parameter
        What rclpy gathered for the node from ``--params-file`` files, ``-p`` and the
        constructor's ``parameter_overrides``.

    Raises
    ------
    InputError
        An override of an unknown name (with the closest known one), of the wrong type (an
        integer for a float parameter is that float, as at runtime), out of range or not among
        the choices.
    """
    unknown = [name for name in overrides
               if name not in NAMES and not pipeline_settings.is_ros_parameter(name)]
    if unknown:
        raise unknown_parameter(unknown[0], NAMES)
    values = {}
    for item in ALL_SPECS:
        value = overrides[item.name].value if item.name in overrides else item.default
        if item.type is float and type(value) is int:
            value = float(value)
        check_value(item, value)
        # The override is applied here, checked: rclpy would refuse 300 for a float parameter.
        values[item.name] = node.declare_parameter(item.name, value, descriptor(item),
                                                   ignore_override=True).value
    return values


def check_params_files(paths: Sequence[str], node: str) -> None:
    """Raise InputError unless each ROS parameter file has an entry for ``node`` (its full
    name), with known names only (``pearl_node`` would silently ignore the others)."""
    for path in paths:
        values = pipeline_settings.load_file(path, node)
        unknown = [name for name in values if name not in NAMES]
        if unknown:
            raise InputError(f'parameter file {path}: {unknown_parameter(unknown[0], NAMES)}')


def params_files(args: Sequence[str]) -> list[str]:
    """The ``--params-file`` paths among command-line arguments, in ``--ros-args`` sections."""
    out, ros, skip = [], False, False
    for k, arg in enumerate(args):
        if skip:
            skip = False
        elif arg == '--ros-args':
            ros = True
        elif arg == '--' and ros:
            ros = False
        elif ros and arg in _VALUED:
            skip = True
            if arg == '--params-file' and k + 1 < len(args):
                out.append(args[k + 1])
    return out


def help_text() -> str:
    """Every parameter with its default, range and description, for ``pearl_node --help``."""
    lines = []
    for item in ALL_SPECS:
        notes = [note for note in (_allowed(item), 'read-only' * (item.name in READ_ONLY))
                 if note]
        lines.append(f'  {item.name}: {_yaml_value(item.default)}'
                     + (f'  ({", ".join(notes)})' if notes else ''))
        lines.extend(textwrap.wrap(item.doc, 95, initial_indent=' ' * 6,
                                   subsequent_indent=' ' * 6))
    return '\n'.join(lines)


def _allowed(item: ParameterSpec) -> str:
    if item.choices is not None:
        return 'one of ' + ' | '.join(item.choices)
    if item.low is not None or item.high is not None:
        return f'{_number(item.low)} .. {_number(item.high)}'
    return ''


def defaults() -> dict[str, Any]:
    """Name -> default of every declared parameter (what ``config/pearl.yaml`` holds)."""
    return {item.name: item.default for item in ALL_SPECS}


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
    if value == '':
        return "''"  # YAML reads nothing after the colon as null
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
