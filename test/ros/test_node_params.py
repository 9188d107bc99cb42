"""Parameters (declared, set at runtime through the services, defaults file), ~/reset and
/diagnostics of the node, seen from another node as a user's tools would see them."""

from __future__ import annotations

import ast
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticStatus
from rcl_interfaces.msg import ParameterType
from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient
from std_srvs.srv import Trigger

from pearl_ros.bagio import decode
from pearl_ros.bagio.reader import read_feature_frames
from pearl_ros.core.config import PearlConfig, parameter_specs
from pearl_ros.core.errors import InputError
from pearl_ros.online.config import OnlineConfig
from pearl_ros.pipeline.settings import load_file
from pearl_ros.ros import params
from pearl_ros.ros.node import PearlNode

from ros_harness import BAG, REPO, Probe, Ros, vins_cloud

FRAMES = list(read_feature_frames(BAG))
TYPES = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
         float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING}


def frame_msg(k: int) -> Any:
    return vins_cloud(FRAMES[k].stamp_ns, FRAMES[k].ids, FRAMES[k].uv)


def _client(ros: Ros, probe: Probe) -> AsyncParameterClient:
    client = AsyncParameterClient(probe.node, f'{ros.ns}/pearl_node')
    assert client.wait_for_services(timeout_sec=10.0)
    return client


def _call(ros: Ros, future: Any) -> Any:
    assert ros.spin_until(future.done, 5.0)
    return future.result()


def _start(ros: Ros, **overrides: Any) -> tuple[PearlNode, Probe]:
    node = ros.pearl(**overrides)
    probe = ros.probe()
    probe.wait_for(node)
    return node, probe


def test_every_config_field_is_a_parameter_with_its_description_and_range(ros: Ros) -> None:
    _, probe = _start(ros)
    specs = parameter_specs(PearlConfig) + parameter_specs(OnlineConfig)
    names = [item.name for item in specs] + ['msg_type', 'qos', 'max_features']
    client = _client(ros, probe)
    described = _call(ros, client.describe_parameters(names)).descriptors
    values = _call(ros, client.get_parameters(names)).values
    assert len(described) == len(values) == len(specs) + 3
    # The dataclass specs are the oracle.
    for item, desc, value in zip(specs, described[:-3], values[:-3], strict=True):
        assert desc.name == item.name
        assert desc.description == item.doc
        assert desc.type == TYPES[item.type] == value.type
        assert parameter_value_to_python(value) == item.default
        if item.type is float:
            assert (desc.floating_point_range[0].from_value,
                    desc.floating_point_range[0].to_value) == (item.low, item.high)
        elif item.type is int:
            assert (desc.integer_range[0].from_value,
                    desc.integer_range[0].to_value) == (item.low, item.high)
        if item.choices:
            assert all(choice in desc.additional_constraints for choice in item.choices)
        assert not desc.read_only
    msg_type, qos, max_features = described[-3:]
    assert msg_type.read_only and qos.read_only and not max_features.read_only
    assert 'PointCloud2' in msg_type.additional_constraints


@pytest.mark.parametrize(('name', 'value', 'reason'), [
    ('label_cost', -5.0, 'label_cost out of range'),  # rclpy checks the declared range
    ('window', 1, 'window out of range'),
    ('model', 'bogus', "model must be one of ('affine', 'fundamental', 'homography')"),
    ('two_view_model', 'affine', 'two_view_model must be one of'),  # build_configs checks
    ('layout', 'diagonal', 'layout must be one of'),
    ('msg_type', 'PointCloud2', 'read-only'),
    ('warm_start', 'yes', 'type'),
])
def test_invalid_value_is_rejected_with_its_reason_and_nothing_changes(
    ros: Ros, name: str, value: Any, reason: str
) -> None:
    _, probe = _start(ros)
    client = _client(ros, probe)
    before = _call(ros, client.get_parameters([name])).values[0]
    result = _call(ros, client.set_parameters([Parameter(name, value=value)])).results[0]
    assert not result.successful
    assert reason in result.reason
    assert _call(ros, client.get_parameters([name])).values[0] == before
    probe.send(frame_msg(0))  # still segmenting


def test_a_valid_change_applies_from_the_next_frame(ros: Ros) -> None:
    _, probe = _start(ros)
    client = _client(ros, probe)
    for k in range(5):
        probe.send(frame_msg(k))
    probe.diagnostics_where(lambda v: v['frames in window'] == '5')
    result = _call(ros, client.set_parameters([Parameter('window', value=3),
                                               Parameter('max_features', value=30)])).results
    assert all(r.successful for r in result), result
    answer = probe.send(frame_msg(5))
    values = probe.diagnostics_where(lambda v: v['messages processed'] == '6')
    assert values['frames in window'] == '3'  # the window shrank to the newest frames
    assert values['features segmented'] == '30'
    labels = decode.decode_fields(answer, ('label',))['label']
    assert 0 < np.count_nonzero(labels >= 0) <= 30


def test_an_integer_for_a_float_parameter_is_taken_as_that_float(ros: Ros) -> None:
    # `ros2 param set /pearl_node label_cost 500` sends an integer.
    _, probe = _start(ros)
    client = _client(ros, probe)
    result = _call(ros, client.set_parameters([Parameter('label_cost', value=500)])).results[0]
    assert result.successful, result.reason
    value = _call(ros, client.get_parameters(['label_cost'])).values[0]
    assert (value.type, value.double_value) == (ParameterType.PARAMETER_DOUBLE, 500.0)


@pytest.mark.parametrize(('overrides', 'reason'), [
    ({'model': 'bogus'},
     "model must be one of ('affine', 'fundamental', 'homography'), got 'bogus'"),
    ({'label_cost': -1.0}, 'label_cost must be >= 0.0, got -1.0'),
    ({'qos': 'fast'}, "qos must be one of ('sensor_data', 'reliable'), got 'fast'"),
    ({'window': 2.5}, 'window must be of type int, got 2.5'),
    ({'label_cots': 300.0}, "unknown parameter 'label_cots' (did you mean 'label_cost'?)"),
    ({'max_feature': 30}, "unknown parameter 'max_feature' (did you mean 'max_features'?)"),
])
def test_a_bad_start_up_value_stops_the_node_with_its_reason(
    ros: Ros, overrides: dict[str, Any], reason: str
) -> None:
    with pytest.raises(InputError) as caught:
        ros.pearl(**overrides)
    assert str(caught.value) == reason


def test_an_integer_for_a_float_parameter_is_taken_at_start_up_too(ros: Ros) -> None:
    # `-p label_cost:=300` is an integer override; rclpy alone would refuse it for a double.
    node = ros.pearl(label_cost=300, diagnostics_period=1)
    for name, expected in (('label_cost', 300.0), ('diagnostics_period', 1.0)):
        value = node.get_parameter(name)
        assert (value.type_, value.value) == (Parameter.Type.DOUBLE, expected)
    assert node.settings.config.label_cost == 300.0


def test_an_unknown_name_at_runtime_is_refused_naming_it(ros: Ros) -> None:
    _, probe = _start(ros)
    client = _client(ros, probe)
    results = _call(ros, client.set_parameters([Parameter('label_cots', value=5.0)])).results
    assert not results[0].successful
    assert results[0].reason == "unknown parameter 'label_cots' (did you mean 'label_cost'?)"
    # The atomic service too, and nothing of the batch is applied.
    future = client.set_parameters_atomically([Parameter('window', value=3),
                                               Parameter('no_such_thing', value=1)])
    result = _call(ros, future).result
    assert not result.successful and "'no_such_thing'" in result.reason
    assert (_call(ros, client.get_parameters(['window'])).values[0].integer_value
            == OnlineConfig().window)


def _params_file(tmp_path: Path, key: str, body: str = 'label_cost: 300.0') -> Path:
    path = tmp_path / 'p.yaml'
    path.write_text(f'{key}:\n  ros__parameters:\n    {body}\n')
    return path


def _with_file(ros: Ros, path: Path, name: str = 'pearl_node') -> PearlNode:
    return ros.add(PearlNode(name, context=ros.context, namespace=ros.ns,
                             cli_args=['--ros-args', '--params-file', str(path)]))


@pytest.mark.parametrize('key', ['/**', 'NS/pearl_node', '/**/pearl_node', 'NS/*'])
def test_a_parameter_file_for_this_node_applies(ros: Ros, tmp_path: Path, key: str) -> None:
    node = _with_file(ros, _params_file(tmp_path, key.replace('NS', ros.ns)))
    assert node.get_parameter('label_cost').value == 300.0  # and 300.0 reached the settings
    assert node.settings.config.label_cost == 300.0


@pytest.mark.parametrize('key', ['other_node', 'pearl_node', '/pearl_node'])
def test_a_parameter_file_for_another_node_is_refused_saying_so(
    ros: Ros, tmp_path: Path, key: str
) -> None:
    # The node lives in the test's namespace: `pearl_node:` names /pearl_node, not it (rcl).
    path = _params_file(tmp_path, key)
    with pytest.raises(InputError) as caught:
        _with_file(ros, path)
    assert str(caught.value) == (
        f'parameter file {path} has no parameters for {ros.ns}/pearl_node: its entries are for '
        f"/{key.strip('/')} (name the node as 'pearl_node:' or '/**:')")


def test_a_parameter_file_follows_the_remapped_node_name(ros: Ros, tmp_path: Path) -> None:
    node = _with_file(ros, _params_file(tmp_path, f'{ros.ns}/segmenter'), name='segmenter')
    assert node.get_parameter('label_cost').value == 300.0
    with pytest.raises(InputError, match=f'no parameters for {ros.ns}/other'):
        _with_file(ros, _params_file(tmp_path, f'{ros.ns}/segmenter'), name='other')


@pytest.mark.parametrize('sub', ['', '/robot'])
@pytest.mark.parametrize('key', [
    'pearl_node', '/pearl_node', '/**', '**', '/*', '/**/pearl_node', '/*/pearl_node',
    'NS/pearl_node', 'NS/*', 'NS/**', 'NS/robot/pearl_node', 'other', 'nested',
])
def test_which_parameter_file_entries_apply_is_decided_as_rclpy_decides(
    ros: Ros, tmp_path: Path, key: str, sub: str
) -> None:
    # rclpy itself is the oracle: does the entry reach a node of that name and namespace?
    if key == 'nested':  # the namespace as a mapping around the node's entry
        text = f'{ros.ns.strip("/")}:\n  pearl_node:\n    ros__parameters:\n      window: 3\n'
    else:
        text = f'"{key.replace("NS", ros.ns)}":\n  ros__parameters:\n    window: 3\n'
    path = tmp_path / 'p.yaml'
    path.write_text(text)
    node = Node('pearl_node', namespace=ros.ns + sub, context=ros.context,
                cli_args=['--ros-args', '--params-file', str(path)],
                allow_undeclared_parameters=True,
                automatically_declare_parameters_from_overrides=True)
    try:
        applied = node.has_parameter('window')
        fqn = node.get_fully_qualified_name()
    finally:
        node.destroy_node()
    try:
        ours = load_file(path, fqn) == {'window': 3}
    except InputError as err:
        assert 'has no parameters for' in str(err)
        ours = False
    assert ours == applied


def test_a_misspelt_name_in_a_parameter_file_is_refused(ros: Ros, tmp_path: Path) -> None:
    path = _params_file(tmp_path, '/**', 'lable_cost: 300.0')
    with pytest.raises(InputError) as caught:
        _with_file(ros, path)
    assert str(caught.value) == (
        f"parameter file {path}: unknown parameter 'lable_cost' (did you mean 'label_cost'?)")


def test_reset_service_empties_the_window(ros: Ros) -> None:
    _, probe = _start(ros, label_cost=300.0, budget_ms=0.0)
    for k in range(4):
        answer = probe.send(frame_msg(k))
    assert (decode.decode_fields(answer, ('label',))['label'] >= 0).all()
    client = probe.node.create_client(Trigger, f'{ros.ns}/pearl_node/reset')
    assert client.wait_for_service(timeout_sec=10.0)
    response = _call(ros, client.call_async(Trigger.Request()))
    assert response.success
    assert '4 frames' in response.message
    answer = probe.send(frame_msg(4))
    # One frame in the window: no motion can be fitted, every feature is undecided.
    assert (decode.decode_fields(answer, ('label',))['label'] == -1).all()
    values = probe.diagnostics_where(lambda v: v['messages processed'] == '5')
    assert (values['frames in window'], values['reset requests']) == ('1', '1')
    assert values['window resets (stamp went back)'] == '0'


def test_diagnostics_report_rate_latency_motions_and_features(ros: Ros) -> None:
    _, probe = _start(ros, label_cost=300.0, budget_ms=0.0)
    answers = [probe.send(frame_msg(k)) for k in range(12)]
    last = decode.decode_fields(answers[-1], ('label',))['label']
    values = probe.diagnostics_where(lambda v: v['messages processed'] == '12')
    assert values['motions'] == str(np.unique(last[last >= 0]).size) == '2'
    assert values['features'] == values['features segmented'] == '153'
    assert values['frames in window'] == str(min(12, OnlineConfig().window))  # the default
    assert values['messages received'] == '12'
    assert all(values[key] == '0' for key in (
        'malformed messages', 'skipped messages', 'capped messages', 'internal errors',
        'publishers of another type', 'publishers with incompatible QoS'))
    # Periods that took input and answered frames (a message that arrives at the end of one
    # period is answered in the next: that period has input but no latency yet).
    busy = [s for s in probe.diagnostics
            if float(_value(s, 'input rate (Hz)')) > 0 and _value(s, 'latency mean (ms)')]
    assert busy, 'no period saw input and answered it'
    for status in busy:
        assert status.level == DiagnosticStatus.OK, status.message
        assert float(_value(status, 'latency max (ms)')) >= float(
            _value(status, 'latency mean (ms)')) > 0
    assert probe.diagnostics[0].name == 'pearl_node: motion segmentation'
    # A period without input says so.
    quiet = probe.diagnostics_where(lambda v: v['input rate (Hz)'] == '0.00')
    assert quiet['_level'] == DiagnosticStatus.WARN and quiet['_message'] == 'no input'


def _value(status: DiagnosticStatus, key: str) -> str:
    return next(kv.value for kv in status.values if kv.key == key)


def test_defaults_file_holds_every_declared_parameter_with_its_default() -> None:
    path = REPO / 'config' / 'pearl.yaml'
    loaded = yaml.safe_load(path.read_text())['/**']['ros__parameters']
    expected = {item.name: item.default for item in params.ALL_SPECS}
    assert loaded == expected
    assert {k: type(v) for k, v in loaded.items()} == {k: type(v) for k, v in expected.items()}
    assert path.read_text() == params.defaults_yaml(), (
        'regenerate: python -m pearl_ros.ros.params > config/pearl.yaml')


def test_node_started_with_the_defaults_file_has_the_default_configuration(ros: Ros) -> None:
    path = REPO / 'config' / 'pearl.yaml'
    node = ros.add(PearlNode(context=ros.context, namespace=ros.ns,
                             cli_args=['--ros-args', '--params-file', str(path)]))
    for item in params.ALL_SPECS:
        value = node.get_parameter(item.name).value
        assert value == item.default and type(value) is item.type, item.name


def test_launch_file_remaps_features_to_the_tracker_and_loads_the_defaults() -> None:
    # launch and launch_ros are not on PyPI: check what the file says, not what it does.
    source = (REPO / 'launch' / 'pearl.launch.py').read_text()
    tree = ast.parse(source)
    strings = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant)}
    assert {'pearl_ros', 'pearl_node', 'features', '/feature_tracker/feature',
            'pearl.yaml', 'config'} <= strings
    functions = {n.name for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)}
    assert 'generate_launch_description' in functions
    calls = [n for n in ast.walk(tree) if isinstance(n, ast.Call)
             and getattr(n.func, 'id', '') == 'Node']
    assert len(calls) == 1
    keywords = {k.arg for k in calls[0].keywords}
    assert {'package', 'executable', 'parameters', 'remappings'} <= keywords
    assert Path(REPO / 'setup.py').read_text().count("glob('launch/*.launch.py')") == 1


def test_the_parameter_reference_lists_every_parameter_as_declared() -> None:
    # README keeps the few most used; docs/parameters.md holds the full table.
    reference = (REPO / 'docs' / 'parameters.md').read_text()
    assert params.markdown_table() in reference, (
        'regenerate: python -m pearl_ros.ros.params --markdown')
    for item in params.ALL_SPECS:
        assert f'| `{item.name}` |' in reference
