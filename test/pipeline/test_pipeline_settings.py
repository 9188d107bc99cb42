"""The one settings builder of every front end: files, NAME=VALUE, options; names checked."""

from __future__ import annotations

from pathlib import Path

import pytest

from pearl_ros.core.errors import InputError
from pearl_ros.online.config import user_names
from pearl_ros.pipeline import settings
from pearl_ros.pipeline.settings import Settings, build, from_sources, load_file


def write(tmp_path: Path, text: str, name: str = 'p.yaml') -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_the_defaults_round_trip_through_their_values() -> None:
    defaults = Settings()
    assert build(defaults.values()) == defaults
    # Every parameter; the solver's settings (solver.NAME) are not parameters of the node.
    assert set(defaults.values()) == set(user_names() + settings.NODE_NAMES)
    changed = build({'window': 4, 'max_features': 9}, defaults)
    assert (changed.online.window, changed.node.max_features) == (4, 9)
    assert build({'seed': 3}, changed).online.window == 4  # the base is kept


@pytest.mark.parametrize(('name', 'hint'), [
    ('label_cots', " (did you mean 'label_cost'?)"),
    ('windw', " (did you mean 'window'?)"),
    ('max_feature', " (did you mean 'max_features'?)"),  # the node's own names too
    ('solver.max_pases', " (did you mean 'solver.max_passes'?)"),
    ('zzzz', ''),
])
def test_an_unknown_name_is_refused_with_the_closest_known_one(name: str, hint: str) -> None:
    for attempt in (lambda: build({name: 1}), lambda: from_sources([], [f'{name}=1'])):
        with pytest.raises(InputError) as caught:
            attempt()
        assert str(caught.value) == f'unknown parameter {name!r}{hint}'


def test_a_refused_name_does_not_apply_to_the_command() -> None:
    with pytest.raises(InputError, match="parameter 'window' does not apply to this command"):
        settings.parse_assignments(['window=3'], refused=('window',))
    with pytest.raises(InputError, match=r"^unknown parameter 'windw'$"):
        settings.parse_assignments(['windw=3'], refused=('window',))  # not suggested either


def test_an_integer_is_taken_for_a_float_parameter_everywhere(tmp_path: Path) -> None:
    path = write(tmp_path, '/**:\n  ros__parameters:\n    label_cost: 300\n'
                 '    diagnostics_period: 2\n')
    for built in (from_sources([path]), from_sources([], ['label_cost=300',
                                                          'diagnostics_period=2'])):
        assert built.config.label_cost == 300.0 and type(built.config.label_cost) is float
        assert type(built.node.diagnostics_period) is float
    with pytest.raises(InputError, match='window must be of type int'):
        build({'window': 4.0})


def test_later_sources_win_and_unset_options_do_not_count(tmp_path: Path) -> None:
    first = write(tmp_path, 'window: 3\nseed: 1\nlayout: vins_mono\n', 'a.yaml')
    second = write(tmp_path, '/**:\n  ros__parameters:\n    window: 4\n', 'b.yaml')
    built = from_sources([first, second], ['seed=2'], {'layout': None, 'camera_id': 5})
    assert (built.online.window, built.online.seed) == (4, 2)
    assert (built.node.layout, built.node.camera_id) == ('vins_mono', 5)
    assert from_sources([first], [], {'layout': 'vins_fusion'}).node.layout == 'vins_fusion'


def test_a_file_takes_the_entries_for_this_node_merged_in_order(tmp_path: Path) -> None:
    path = write(tmp_path, '/**:\n  ros__parameters:\n    window: 3\n    use_sim_time: true\n'
                 'other:\n  ros__parameters:\n    window: 9\n'
                 'robot:\n  pearl_node:\n    ros__parameters:\n      window: 5\n'
                 '      seed: 7\n')
    assert load_file(path) == {'window': 3}  # /pearl_node; rclpy's own names left out
    assert load_file(path, '/robot/pearl_node') == {'window': 5, 'seed': 7}
    assert load_file(path, None) == {'window': 5, 'seed': 7}


@pytest.mark.parametrize(('text', 'flat', 'message'), [
    ('window: 3\n', False, 'is not a ROS parameter file'),
    ('window: [1, 2\n', True, 'is not valid YAML'),
    ('- window\n', True, 'must hold a mapping, got list'),
    ('pearl_node:\n  ros__parameters: 5\n', True, 'ros__parameters of /pearl_node must be a'),
    ('other:\n  ros__parameters:\n    window: 3\n', True,
     "has no parameters for /pearl_node: its entries are for /other (name the node as "
     "'pearl_node:' or '/**:')"),
])
def test_a_bad_parameter_file_is_refused_in_one_line(
    tmp_path: Path, text: str, flat: bool, message: str
) -> None:
    path = write(tmp_path, text)
    with pytest.raises(InputError) as caught:
        load_file(path, flat=flat)
    assert message in str(caught.value) and '\n' not in str(caught.value)
    with pytest.raises(InputError, match='cannot read parameter file'):
        load_file(tmp_path / 'none.yaml')


def test_a_misspelt_name_in_a_file_names_the_file(tmp_path: Path) -> None:
    path = write(tmp_path, 'pearl_node:\n  ros__parameters:\n    lable_cost: 3.0\n')
    with pytest.raises(InputError) as caught:
        from_sources([path])
    assert str(caught.value) == (f"parameter file {path}: unknown parameter 'lable_cost' "
                                 "(did you mean 'label_cost'?)")
